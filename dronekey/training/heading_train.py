"""Train and export the front/back classifier (``dronekey-train-heading``).

Recipe (``patch_train``): AdamW (weight decay 1e-4), one-cycle learning rate up to 3e-3, batches of
256 patches drawn from the loaded shards, binary cross-entropy with labels smoothed to 0.02 /
0.98, augmented with what must not decide (the patch turned 180 degrees with its label flipped:
the twin). The exported graph has input ``patch`` (batch, 3, 64, 64) float32 (``patches_to_tensor``)
and output ``logit`` (batch,). With the default "gated" recipe it is
``GatedAntisymmetric(HeadingNet(outputs=2))``: a second logit, trained on whether the patch has an
answer at all (``gated_objective``), pulls the answer to 0.5 where that gate is shut; the "small"
and "deep" recipes export ``Antisymmetric(HeadingNet)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dronekey.nn.heading_net import Antisymmetric, GatedAntisymmetric, HeadingNet
from dronekey.perception.heading_model import OUTPUT_NAME
from dronekey.training.heading_data import NO_ANSWER
from dronekey.training.patch_train import (
    PatchRecipe,
    export_patch_classifier,
    patch_logits,
    smoothed_bce,
    train_patch_classifier,
)

__all__ = [
    "HEADING_RECIPE",
    "HEADING_RECIPES",
    "evaluate",
    "export_heading_model",
    "gated_objective",
    "train_heading",
]

# The front/back classifiers' recipes. "gated" gives the shipped default classifier (the runtime's
# "gated" in ``heading_model.SHIPPED_HEADING_MODELS``, dronekey_heading.onnx; twenty-first session):
# the four-conv net with a second, symmetric logit that says whether the body shows a front
# (177,682 parameters, 8 epochs over two seeds' patches). "small" is the same net without the gate,
# the default until then (177,617 parameters). "deep" has two convs at 16 and at 8 px, 128 wide at
# the end (413,585 parameters), is meant for four seeds' patches over 4 epochs and gives the opt-in
# dronekey_heading_deep.onnx. The small net was right on 78 % of its own training patches, as on
# held-out ones: it underfitted, and twice the data did not move it; the deep one reaches 81 % held
# out (docs/model.md). "deep-gated" is the deep net with the gate, over the gated recipe's two seeds
# for its 8 epochs (the same number of steps as "deep" over four seeds; twenty-seventh session).
HEADING_RECIPES = {
    "gated": PatchRecipe(gated=True),
    "small": PatchRecipe(),
    "deep": PatchRecipe(epochs=4.0, channels=(16, 32, 64, 128), repeats=2),
    "deep-gated": PatchRecipe(channels=(16, 32, 64, 128), repeats=2, gated=True),
}
HEADING_RECIPE = HEADING_RECIPES["gated"]


def evaluate(model: torch.nn.Module, patches: np.ndarray, labels: np.ndarray, batch: int = 1024) -> dict:
    """On uint8 patches with labels 1 (nose at the top), 0, or ``NO_ANSWER`` (the body shows no front):
    over the answerable ones, accuracy, negative log-likelihood, and the share of confident answers
    (|2p - 1| >= 0.5) and of confident wrong ones; over the others (``no_answer_*``, None when there
    are none), their count, the mean |2p - 1| and the share answered confidently, which should
    both be small. A figure with nothing to average is None (null in history.json and the model's
    metadata, which strict JSON readers accept; NaN they refuse)."""
    logits = patch_logits(model, patches, batch)
    p = 1.0 / (1.0 + np.exp(-logits))
    answerable = labels != NO_ANSWER
    p_a, y_a = p[answerable], labels[answerable]
    right = (p_a > 0.5) == (y_a > 0.5)
    confident = np.abs(2 * p_a - 1) >= 0.5
    nll = -np.mean(y_a * np.log(p_a + 1e-7) + (1 - y_a) * np.log(1 - p_a + 1e-7))
    sure_of_nothing = np.abs(2 * p[~answerable] - 1)
    return {
        "samples": int(answerable.sum()),
        "accuracy": float(right.mean()),
        "nll": float(nll),
        "confident": float(confident.mean()),
        "confident_wrong": float((confident & ~right).mean()),
        "confident_accuracy": float(right[confident].mean()) if confident.any() else None,
        "no_answer_samples": int((~answerable).sum()),
        "no_answer_certainty": float(sure_of_nothing.mean()) if len(sure_of_nothing) else None,
        "no_answer_confident": float((sure_of_nothing >= 0.5).mean()) if len(sure_of_nothing) else None,
    }


def train_heading(
    train: tuple[np.ndarray, np.ndarray],
    val: tuple[np.ndarray, np.ndarray],
    out: str | Path,
    recipe: PatchRecipe | None = None,
    progress: bool = False,
    resume: bool = False,
) -> tuple[Antisymmetric | GatedAntisymmetric, list[dict]]:
    """Train on ``train`` (patches, labels), validate on ``val`` every ``recipe.validate_every``
    steps and at the end, keep ``out/last.pt``, ``out/history.json`` and the run's state
    (``resume``: go on from it; ``patch_train.train_patch_classifier``); returns the antisymmetric
    model (gated with ``recipe.gated``) and the history."""
    recipe = recipe or HEADING_RECIPE
    patches, labels = train
    if len(patches) < recipe.batch:
        raise ValueError(f"train has {len(patches)} patches, fewer than one batch of {recipe.batch}")
    torch.manual_seed(recipe.seed)  # the net's initial weights
    net = HeadingNet(recipe.channels, patches.shape[1], recipe.repeats, outputs=2 if recipe.gated else 1)
    if recipe.gated:  # two logits: the order and the gate, each with its loss
        model, objective = GatedAntisymmetric(net), gated_objective
    else:
        model, objective = Antisymmetric(net), None

    def draw(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        idx = rng.integers(0, len(patches), n)
        return patches[idx], labels[idx]

    steps = max(1, int(recipe.epochs * len(patches) / recipe.batch))
    history = train_patch_classifier(
        net,
        model,
        draw,
        steps,
        lambda m: evaluate(m, *val),
        out,
        recipe,
        turn_flips_label=True,
        desc="front/back classifier",
        progress=progress,
        resume=resume,
        objective=objective,
    )
    return model, history


def gated_objective(out: torch.Tensor, labels: torch.Tensor, smooth: float) -> torch.Tensor:
    """The loss of a gated net's two logits (``GatedAntisymmetric``): the order logit against the
    labels as the plain classifier's (no-answer patches towards 0.5), plus the gate against whether
    the patch has an answer at all."""
    shows_front = (labels != NO_ANSWER).to(out.dtype)
    return smoothed_bce(out[:, 0], labels, smooth) + smoothed_bce(out[:, 1], shows_front, smooth)


def export_heading_model(
    model: Antisymmetric | GatedAntisymmetric, path: str | Path, metadata: dict | None = None
) -> Path:
    """Write the front/back classifier as ONNX with JSON metadata, checked against torch."""
    return export_patch_classifier(model, path, OUTPUT_NAME, metadata)
