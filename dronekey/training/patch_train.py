"""What the patch classifiers' training shares (front/back, drone verifier): the recipe, the
augmentation of everything that must not decide, the training loop and the checked ONNX export.

Recipe: AdamW, one-cycle learning rate, batches of front-up patches, binary cross-entropy with
labels smoothed. Every batch is augmented: the patch turned 180 degrees (for the front/back
classifier its label flips: it is the twin order; for the verifier it does not), mirrored
left/right (front stays front), colour channels permuted, grey on a fifth, brightness and
contrast, and shifts of up to 3 px (keypoint noise beyond the network's own).

A run keeps its whole state (weights, optimiser, learning-rate schedule, random streams, history)
in ``out/state.pt`` at every validation; ``resume=True`` continues a stopped run from there when
the recipe and the number of steps are the same, so that a run longer than a working session on
two cores can be finished by the next one, with the weights an uninterrupted run would have.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch
from torch import nn
from torch.nn import functional
from tqdm import tqdm

from dronekey import __version__
from dronekey.perception.patch_classifier import INPUT_NAME, PATCH_SIZE, patches_to_tensor
from dronekey.training.export import write_metadata

__all__ = [
    "STATE_FILE",
    "PatchRecipe",
    "augment",
    "export_patch_classifier",
    "patch_logits",
    "smoothed_bce",
    "train_patch_classifier",
]

LOG = logging.getLogger(__name__)

STATE_FILE = "state.pt"  # in a run's folder: everything a stopped run needs to go on


@dataclass(frozen=True)
class PatchRecipe:
    """How long and how fast a patch classifier trains, and the size of its net (``HeadingNet``'s
    ``channels`` and ``repeats``)."""

    epochs: float = 8.0
    batch: int = 256
    lr: float = 3e-3
    weight_decay: float = 1e-4
    label_smoothing: float = 0.02
    seed: int = 0
    validate_every: int = 1000  # steps between validations, each also a checkpoint (out/state.pt)
    channels: tuple[int, int, int, int] = (16, 32, 64, 96)
    repeats: int = 1
    gated: bool = False  # front/back only: a second, symmetric logit says whether there is a front


def patch_logits(model: nn.Module, patches: np.ndarray, batch: int = 1024) -> np.ndarray:
    """The model's logits (N,) on uint8 patches (N, P, P, 3), in eval mode, without gradients."""
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
    return logits


def augment(
    x: torch.Tensor, y: torch.Tensor, g: torch.Generator, turn_flips_label: bool = True
) -> tuple[torch.Tensor, torch.Tensor]:
    """Patches (B, 3, P, P) and labels (B,) with what must not decide randomised (module
    docstring); ``turn_flips_label``: a patch turned 180 degrees gets the opposite label."""
    B = x.shape[0]
    turn = torch.rand(B, generator=g) < 0.5
    x = torch.where(turn[:, None, None, None], torch.flip(x, dims=(2, 3)), x)
    if turn_flips_label:
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


def train_patch_classifier(
    net: nn.Module,
    model: nn.Module,
    draw: Callable[[np.random.Generator, int], tuple[np.ndarray, np.ndarray]],
    steps: int,
    validate: Callable[[nn.Module], dict],
    out: str | Path,
    recipe: PatchRecipe,
    turn_flips_label: bool,
    desc: str,
    progress: bool = False,
    resume: bool = False,
    objective: Callable[[torch.Tensor, torch.Tensor, float], torch.Tensor] | None = None,
) -> list[dict]:
    """Train ``net`` (the CNN inside the exported ``model`` wrapper) for ``steps``
    batches that ``draw(rng, batch)`` returns as (uint8 patches, labels); ``validate(model)``
    every ``recipe.validate_every`` steps and at the end; keep ``out/last.pt``,
    ``out/history.json`` and the run's state (``STATE_FILE``). ``resume``: go on from that state
    when it is of the same recipe and number of steps (else start anew, and say why).
    ``objective(net output, labels, label smoothing)``: the loss, by default binary cross-entropy
    of the one logit against the smoothed labels. Returns the history."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(recipe.seed)
    g = torch.Generator().manual_seed(recipe.seed)
    rng = np.random.default_rng(recipe.seed)
    opt = torch.optim.AdamW(net.parameters(), lr=recipe.lr, weight_decay=recipe.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=recipe.lr, total_steps=steps, pct_start=0.05)
    history: list[dict] = []
    start = 0
    if resume and (saved := _saved_state(out / STATE_FILE, recipe, steps)) is not None:
        net.load_state_dict(saved["net"])
        opt.load_state_dict(saved["optimizer"])
        sched.load_state_dict(saved["scheduler"])
        g.set_state(saved["generator"])
        torch.set_rng_state(saved["torch_rng"])
        rng.bit_generator.state = saved["numpy_rng"]
        history, start = saved["history"], saved["step"]
        LOG.info("resuming %s at step %d of %d", out, start, steps)
    t0 = time.time() - (history[-1]["seconds"] if history else 0)
    smooth = recipe.label_smoothing
    for step in tqdm(range(start, steps), desc=desc, initial=start, total=steps, disable=not progress):
        patches, labels = draw(rng, recipe.batch)
        x, y = augment(
            torch.from_numpy(patches_to_tensor(patches)), torch.from_numpy(labels), g, turn_flips_label
        )
        # f alone with the 180-degree turn as augmentation: half the work of the wrapper's pair
        loss = (objective or smoothed_bce)(net(x), y, smooth)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % recipe.validate_every == 0 or step + 1 == steps:
            entry = {"step": step + 1, "seconds": round(time.time() - t0), "loss": float(loss.detach())}
            entry.update(validate(model))
            history.append(entry)
            LOG.info("step %d/%d: %s", step + 1, steps, json.dumps(entry))
            torch.save(
                {"model": net.state_dict(), "recipe": asdict(recipe), "step": step + 1}, out / "last.pt"
            )
            (out / "history.json").write_text(json.dumps(history, indent=1))
            state = {
                "net": net.state_dict(),
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(),
                "generator": g.get_state(),
                "torch_rng": torch.get_rng_state(),
                "numpy_rng": rng.bit_generator.state,
                "history": history,
                "step": step + 1,
                "steps": steps,
                "recipe": asdict(recipe),
            }
            partial = out / (STATE_FILE + ".partial")  # a run stopped while writing keeps the last one
            torch.save(state, partial)
            partial.replace(out / STATE_FILE)
    model.eval()
    return history


def smoothed_bce(logits: torch.Tensor, labels: torch.Tensor, smooth: float) -> torch.Tensor:
    """Binary cross-entropy of ``logits`` against ``labels`` smoothed to ``smooth`` / ``1 - smooth``."""
    return functional.binary_cross_entropy_with_logits(logits, labels * (1 - 2 * smooth) + smooth)


def _saved_state(path: Path, recipe: PatchRecipe, steps: int) -> dict | None:
    """The run state in ``path`` if it is of ``recipe`` and ``steps``; None (and why, logged) if not."""
    if not path.is_file():
        LOG.info("nothing to resume in %s; starting a new run", path.parent)
        return None
    saved = torch.load(path, weights_only=False)
    if saved["recipe"] != asdict(recipe) or saved["steps"] != steps:
        LOG.warning(
            "%s is of another run (recipe %s, %d steps; now %s, %d steps): starting a new run",
            path,
            saved["recipe"],
            saved["steps"],
            asdict(recipe),
            steps,
        )
        return None
    return saved


def export_patch_classifier(
    model: nn.Module, path: str | Path, output_name: str, metadata: dict | None = None
) -> Path:
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
        output_names=[output_name],
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
