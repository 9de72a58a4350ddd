"""Train and export the front/back classifier (``dronekey-train-heading``).

Recipe: AdamW (weight decay 1e-4), one-cycle learning rate up to 3e-3, batches of 256 patches
drawn from the loaded shards, binary cross-entropy with labels smoothed to 0.02 / 0.98. Every
batch is augmented with what must not decide: the patch turned 180 degrees with its label
flipped (the twin), mirrored left/right (front stays front), colour channels permuted, grey on a
fifth, brightness and contrast, and shifts of up to 3 px (keypoint noise beyond the network's own).
The exported graph is ``Antisymmetric(HeadingNet)``: input ``patch`` (batch, 3, 64, 64) float32
(``patches_to_tensor``), output ``logit`` (batch,).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
from torch.nn import functional
from tqdm import tqdm

from dronekey import __version__
from dronekey.nn.heading_net import Antisymmetric, HeadingNet
from dronekey.perception.heading_model import INPUT_NAME, OUTPUT_NAME, PATCH_SIZE, patches_to_tensor
from dronekey.training.export import write_metadata

__all__ = ["HeadingRecipe", "evaluate", "export_heading_model", "train_heading"]

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class HeadingRecipe:
    """How long and how fast the classifier trains."""

    epochs: float = 8.0
    batch: int = 256
    lr: float = 3e-3
    weight_decay: float = 1e-4
    label_smoothing: float = 0.02
    seed: int = 0


def evaluate(model: torch.nn.Module, patches: np.ndarray, labels: np.ndarray, batch: int = 1024) -> dict:
    """Accuracy, negative log-likelihood, and the share of confident answers (|2p - 1| >= 0.5) and of
    confident wrong ones, on uint8 patches with labels 1 (nose at the top) / 0."""
    was_training = model.training
    model.eval()
    with torch.no_grad():
        logits = torch.cat(
            [
                model(torch.from_numpy(patches_to_tensor(patches[i : i + batch])))
                for i in range(0, len(patches), batch)
            ]
        ).numpy()
    model.train(was_training)
    p = 1.0 / (1.0 + np.exp(-logits))
    right = (p > 0.5) == (labels > 0.5)
    confident = np.abs(2 * p - 1) >= 0.5
    nll = -np.mean(labels * np.log(p + 1e-7) + (1 - labels) * np.log(1 - p + 1e-7))
    return {
        "samples": int(len(labels)),
        "accuracy": float(right.mean()),
        "nll": float(nll),
        "confident": float(confident.mean()),
        "confident_wrong": float((confident & ~right).mean()),
        "confident_accuracy": float(right[confident].mean()) if confident.any() else float("nan"),
    }


def _augment(x: torch.Tensor, y: torch.Tensor, g: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    B = x.shape[0]
    turn = torch.rand(B, generator=g) < 0.5
    x = torch.where(turn[:, None, None, None], torch.flip(x, dims=(2, 3)), x)
    y = torch.where(turn, 1 - y, y)
    mirror = torch.rand(B, generator=g) < 0.5
    x = torch.where(mirror[:, None, None, None], torch.flip(x, dims=(3,)), x)
    perm = torch.argsort(torch.rand(B, 3, generator=g), dim=1)
    x = torch.gather(x, 1, perm[:, :, None, None].expand_as(x))
    grey = torch.rand(B, generator=g) < 0.2
    x = torch.where(grey[:, None, None, None], x.mean(1, keepdim=True).expand_as(x), x)
    x = x * (1 + 0.3 * (torch.rand(B, 1, 1, 1, generator=g) - 0.5)) + 0.3 * (
        torch.rand(B, 1, 1, 1, generator=g) - 0.5
    )
    dy, dx = (int(v) for v in torch.randint(-3, 4, (2,), generator=g))
    return torch.roll(x, shifts=(dy, dx), dims=(2, 3)), y


def train_heading(
    train: tuple[np.ndarray, np.ndarray],
    val: tuple[np.ndarray, np.ndarray],
    out: str | Path,
    recipe: HeadingRecipe | None = None,
    progress: bool = False,
) -> tuple[Antisymmetric, list[dict]]:
    """Train on ``train`` (patches, labels), validate on ``val`` every 1,000 steps and at the end,
    keep ``out/last.pt`` and ``out/history.json``; returns the antisymmetric model and the history."""
    recipe = recipe or HeadingRecipe()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    patches, labels = train
    if len(patches) < recipe.batch:
        raise ValueError(f"train has {len(patches)} patches, fewer than one batch of {recipe.batch}")
    torch.manual_seed(recipe.seed)
    g = torch.Generator().manual_seed(recipe.seed)
    rng = np.random.default_rng(recipe.seed)
    net = HeadingNet(patch_size=patches.shape[1])
    model = Antisymmetric(net)
    steps = max(1, int(recipe.epochs * len(patches) / recipe.batch))
    opt = torch.optim.AdamW(net.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=recipe.lr, total_steps=steps, pct_start=0.05)
    history: list[dict] = []
    t0 = time.time()
    smooth = recipe.label_smoothing
    for step in tqdm(range(steps), desc="front/back classifier", disable=not progress):
        idx = rng.integers(0, len(patches), recipe.batch)
        x, y = _augment(torch.from_numpy(patches_to_tensor(patches[idx])), torch.from_numpy(labels[idx]), g)
        # f alone with the 180-degree turn as augmentation: half the work of the antisymmetric pair
        loss = functional.binary_cross_entropy_with_logits(net(x), y * (1 - 2 * smooth) + smooth)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % 1000 == 0 or step + 1 == steps:
            entry = {"step": step + 1, "seconds": round(time.time() - t0), "loss": float(loss.detach())}
            entry.update(evaluate(model, *val))
            history.append(entry)
            LOG.info("step %d/%d: %s", step + 1, steps, json.dumps(entry))
            torch.save(
                {"model": net.state_dict(), "recipe": asdict(recipe), "step": step + 1}, out / "last.pt"
            )
            (out / "history.json").write_text(json.dumps(history, indent=1))
    model.eval()
    return model, history


def export_heading_model(model: Antisymmetric, path: str | Path, metadata: dict | None = None) -> Path:
    """Write ``model`` as ONNX (opset 18, dynamic batch) with JSON metadata (``trained_on``,
    ``figures`` ...), and check that ONNX Runtime answers as torch does."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model.eval()
    x = torch.randn(2, 3, PATCH_SIZE, PATCH_SIZE)
    torch.onnx.export(
        model,
        (x,),
        str(path),
        input_names=[INPUT_NAME],
        output_names=[OUTPUT_NAME],
        opset_version=18,
        dynamo=True,
        external_data=False,
        dynamic_shapes={"x": {0: torch.export.Dim("batch", min=1)}},
        verbose=False,
    )
    meta = {"producer": f"dronekey {__version__}", "patch_size": PATCH_SIZE, **(metadata or {})}
    write_metadata(path, {key: json.dumps(value) for key, value in meta.items()})
    with torch.no_grad():
        expected = model(x).numpy()
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(
        None, {INPUT_NAME: x.numpy()}
    )[0]
    if not np.allclose(got, expected, atol=1e-4):
        raise RuntimeError(
            f"{path}: ONNX Runtime's logits differ from torch's by {np.abs(got - expected).max()}"
        )
    return path
