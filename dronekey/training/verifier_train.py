"""Train and export the drone verifier (``dronekey-train-verifier``).

Recipe (``patch_train``): AdamW (weight decay 1e-4), one-cycle learning rate up to 3e-3, batches of
256 patches, half drones and half drone-free (the shards hold several drones per false detection,
and a cascade stage must learn the rare class), binary cross-entropy with labels smoothed to 0.02
/ 0.98, augmented with what must not decide (the 180-degree turn keeps its label: the verdict does
not depend on the keypoints' order). The exported graph is ``Symmetric(HeadingNet)``: input
``patch`` (batch, 3, 64, 64) float32 (``patches_to_tensor``), output ``drone_logit`` (batch,).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from dronekey.nn.heading_net import HeadingNet, Symmetric
from dronekey.perception.drone_verifier import OUTPUT_NAME
from dronekey.training.patch_train import (
    PatchRecipe,
    export_patch_classifier,
    patch_logits,
    train_patch_classifier,
)

__all__ = ["evaluate_verifier", "export_verifier", "train_verifier"]

# The verifier's recipe: the patch classifiers' shared one, longer (a pass over the rarer
# drone-free patches is short).
VERIFIER_RECIPE = PatchRecipe(epochs=20.0)


def evaluate_verifier(
    model: torch.nn.Module, patches: np.ndarray, labels: np.ndarray, presence: np.ndarray
) -> dict:
    """Figures of the verifier at p = 0.5 on uint8 patches with labels 1 (drone) / 0: drones kept,
    drone-free patches rejected (all of them, and those the network scored 0.9 or more), AUC; a figure
    with nothing to average is None (strict JSON in history.json and the model's metadata)."""
    p = 1.0 / (1.0 + np.exp(-patch_logits(model, patches)))
    drone, free = labels > 0.5, labels <= 0.5
    hard = free & (presence >= 0.9)
    out = {
        "drones": int(drone.sum()),
        "drone_free": int(free.sum()),
        "drones_kept": float((p[drone] >= 0.5).mean()) if drone.any() else None,
        "drone_free_rejected": float((p[free] < 0.5).mean()) if free.any() else None,
        "hard_drone_free": int(hard.sum()),
        "hard_drone_free_rejected": float((p[hard] < 0.5).mean()) if hard.any() else None,
    }
    if drone.any() and free.any():  # AUC: the chance a drone outscores a drone-free patch
        ranks = np.argsort(np.argsort(p)) + 1.0
        out["auc"] = float(
            (ranks[drone].sum() - drone.sum() * (drone.sum() + 1) / 2) / (drone.sum() * free.sum())
        )
    return out


def train_verifier(
    train: tuple[np.ndarray, np.ndarray, np.ndarray],
    val: tuple[np.ndarray, np.ndarray, np.ndarray],
    out: str | Path,
    recipe: PatchRecipe | None = None,
    progress: bool = False,
    resume: bool = False,
) -> tuple[Symmetric, list[dict]]:
    """Train on ``train`` (patches, labels, presence) in batches balanced between drones and
    drone-free patches; validate on ``val`` every ``recipe.validate_every`` steps and at the end;
    keep ``out/last.pt``, ``out/history.json`` and the run's state (``resume``: go on from it;
    ``patch_train.train_patch_classifier``). Returns the symmetric model and the history."""
    recipe = recipe or VERIFIER_RECIPE
    patches, labels, _ = train
    drones, free = np.flatnonzero(labels > 0.5), np.flatnonzero(labels <= 0.5)
    if len(drones) < 2 or len(free) < 2:
        raise ValueError(
            f"train needs drone and drone-free patches, got {len(drones)} and {len(free)}: render more shards"
        )
    torch.manual_seed(recipe.seed)  # the net's initial weights
    net = HeadingNet(recipe.channels, patches.shape[1], recipe.repeats)
    model = Symmetric(net)

    def draw(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
        idx = np.concatenate([rng.choice(drones, n // 2), rng.choice(free, n - n // 2)])
        return patches[idx], labels[idx]

    # an epoch is a pass over the drone-free patches, which each batch holds half of
    steps = max(1, int(recipe.epochs * 2 * len(free) / recipe.batch))
    history = train_patch_classifier(
        net,
        model,
        draw,
        steps,
        lambda m: evaluate_verifier(m, *val),
        out,
        recipe,
        turn_flips_label=False,
        desc="drone verifier",
        progress=progress,
        resume=resume,
    )
    return model, history


def export_verifier(model: Symmetric, path: str | Path, metadata: dict | None = None) -> Path:
    """Write the drone verifier as ONNX with JSON metadata, checked against torch."""
    return export_patch_classifier(model, path, OUTPUT_NAME, metadata)
