"""Training data of the front/back classifier: rendered crops, the keypoint network's own keypoints,
and whether their order is the drone's.

Each sample is a drone crop from the training sampler (``dronekey.sim_replay.sampler``: random
bodies, liveries, LEDs or none, backgrounds), run through the shipped keypoint network as the
daemon runs it (mirror-averaged, in its head's order), then warped front-up around those keypoints
(``canonical_patches``). Its label says whether the network's order is the labelled one (1) or its
180-degree twin (0), whichever is nearer the ground truth. Training on the network's keypoints,
not the labels, gives the classifier the same patches, with the same errors, that it sees at run
time.

Shards of ``SHARD_SIZE`` drawn crops are written as ``s{seed}_{index:03d}.npz`` (``patch`` uint8
(N, P, P, 3), ``y`` bool, ``ratio`` the front axis over the hub radius, ``err`` / ``err_twin`` the
mean keypoint error of the order and of its twin, px of the crop), so a stopped run resumes and a
folder can be extended with another seed.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from dronekey.perception.keypoint_model import HEADING_TWIN, KeypointModel
from dronekey.perception.patch_classifier import PATCH_SIZE, canonical_patches
from dronekey.training.patch_shards import SHARD_SIZE, network_outputs, write_patch_shards

__all__ = ["SHARD_SIZE", "load_shards", "write_shards"]

LOG = logging.getLogger(__name__)


def write_shards(
    out: str | Path,
    seed: int,
    shards: int,
    keypoint_model: str | Path | None = None,
    progress: bool = False,
    shard_size: int = SHARD_SIZE,
) -> list[Path]:
    """Render ``shards`` shards of ``shard_size`` drone crops with sampler seed ``seed`` into ``out``
    (``patch_shards.write_patch_shards``: resumable, one sampler stream per seed)."""
    return write_patch_shards(out, seed, shards, _label, 0.0, keypoint_model, progress, shard_size)


def _label(model: KeypointModel, samples: list) -> dict[str, np.ndarray]:
    samples = [s for s in samples if s.present]
    crops = np.stack([s.image for s in samples])
    S = model.input_size
    kp = network_outputs(model, crops).keypoints
    patches, ratios = canonical_patches(crops, kp, PATCH_SIZE)
    truth = np.stack([s.keypoints for s in samples])
    err = np.abs(kp - truth).sum(-1).mean(-1) * S
    err_twin = np.abs(kp[:, HEADING_TWIN] - truth).sum(-1).mean(-1) * S
    return {
        "patch": patches,
        "ratio": ratios,
        "y": err < err_twin,
        "err": err.astype(np.float32),
        "err_twin": err_twin.astype(np.float32),
    }


def load_shards(
    paths: list[Path], decided: float = 0.6, min_axis_ratio: float = 0.15
) -> tuple[np.ndarray, np.ndarray]:
    """Patches (N, P, P, 3) uint8 and labels (N,) float32 of the shards, keeping the samples whose
    order the ground truth decides (the nearer order's error below ``decided`` times the other's)
    and whose front axis points somewhere (``min_axis_ratio``, as at run time)."""
    patches, labels = [], []
    for path in paths:
        with np.load(path) as d:
            near, far = np.minimum(d["err"], d["err_twin"]), np.maximum(d["err"], d["err_twin"])
            keep = (near < decided * far) & (d["ratio"] >= min_axis_ratio)
            patches.append(d["patch"][keep])
            labels.append(d["y"][keep].astype(np.float32))
    if not patches:
        raise ValueError("no shards to load")
    return np.concatenate(patches), np.concatenate(labels)
