"""Training data of the front/back classifier: rendered crops, the keypoint network's own keypoints,
and whether their order is the drone's.

Each sample is a drone crop from the training sampler (``dronekey.sim_replay.sampler``: random
bodies, liveries, LEDs or none, backgrounds), run through the shipped keypoint network as the
daemon runs it (mirror-averaged, in its head's order), then warped front-up around those keypoints
(``canonical_patches``). Its label says whether the network's order is the labelled one (1) or its
180-degree twin (0), whichever is nearer the ground truth. Training on the network's keypoints,
not the labels, gives the classifier the same patches, with the same errors, that it sees at run
time.

A drone whose body shows no front from where the camera sees it (``BodyShape.shows_front``: no
nose gimbal, taper, nose cone, dropped rear arms, and seen from below no battery, half stripe or
top gimbal) has no answer, so its label is 0.5: the classifier learns to say it cannot tell rather
than read noise as a front. ``CUE_FREE_FRACTION`` of the rendered drones are drawn without any
cue, so that such bodies are common enough to learn from (about 1 % of random bodies have none,
and a few percent more only on top). ``END_SENSOR_FRACTION`` of them carry obstacle-sensor pods at
the front, the rear or both (``BodyShape.end_sensors``): a dark box at an end of the body, like the
nose gimbal or a body LED's housing, that marks neither end, so the classifier cannot take one for
a nose.

Shards of ``SHARD_SIZE`` drawn crops are written as ``s{seed}_{index:03d}.npz`` (``patch`` uint8
(N, P, P, 3), ``y`` bool, ``ratio`` the front axis over the hub radius, ``err`` / ``err_twin`` the
mean keypoint error of the order and of its twin, px of the crop, ``cue`` bool whether the body
shows its front; shards written before ``cue`` existed count as all showing it), so a stopped run
resumes and a folder can be extended with another seed.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from dronekey.perception.keypoint_model import HEADING_TWIN, KeypointModel
from dronekey.perception.patch_classifier import PATCH_SIZE, canonical_patches
from dronekey.sim_replay.sampler import SamplerConfig
from dronekey.training.patch_shards import SHARD_SIZE, network_outputs, write_patch_shards

__all__ = [
    "CUE_FREE_FRACTION",
    "END_SENSOR_FRACTION",
    "NO_ANSWER",
    "SHARD_SIZE",
    "load_shards",
    "write_shards",
]

LOG = logging.getLogger(__name__)

CUE_FREE_FRACTION = 0.2  # rendered drones drawn with no front/back cue
END_SENSOR_FRACTION = 0.3  # rendered drones given obstacle-sensor pods at the front, rear or both
NO_ANSWER = 0.5  # the label of a patch whose body shows no front


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
    return write_patch_shards(
        out,
        seed,
        shards,
        _label,
        SamplerConfig(
            negative_fraction=0.0,
            cue_free_fraction=CUE_FREE_FRACTION,
            end_sensor_fraction=END_SENSOR_FRACTION,
        ),
        keypoint_model=keypoint_model,
        progress=progress,
        shard_size=shard_size,
    )


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
        "cue": np.array([s.front_visible for s in samples]),
    }


def load_shards(
    paths: list[Path], decided: float = 0.6, min_axis_ratio: float = 0.15
) -> tuple[np.ndarray, np.ndarray]:
    """Patches (N, P, P, 3) uint8 and labels (N,) float32 of the shards, keeping the samples whose
    order the ground truth decides (the nearer order's error below ``decided`` times the other's)
    and whose front axis points somewhere (``min_axis_ratio``, as at run time). The label is 1 or 0,
    or ``NO_ANSWER`` where the body shows no front."""
    patches, labels = [], []
    for path in paths:
        with np.load(path) as d:
            near, far = np.minimum(d["err"], d["err_twin"]), np.maximum(d["err"], d["err_twin"])
            keep = (near < decided * far) & (d["ratio"] >= min_axis_ratio)
            cue = d["cue"] if "cue" in d.files else np.ones(len(keep), bool)
            patches.append(d["patch"][keep])
            labels.append(np.where(cue, d["y"], NO_ANSWER)[keep].astype(np.float32))
    if not patches:
        raise ValueError("no shards to load")
    return np.concatenate(patches), np.concatenate(labels)
