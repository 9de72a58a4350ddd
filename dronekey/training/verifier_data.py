"""Training data of the drone verifier: what the keypoint network calls a drone, and whether it is.

Crops come from the training sampler (``dronekey.sim_replay.sampler``) with most of them drone-free
(``NEGATIVE_FRACTION``): random crops, crops past the frame edge, the localiser's own proposals on
drone-free frames, with birds, flying objects, clouds, building edges, trees and wires drawn in.
Each is run through the keypoint network as the daemon runs it; only the crops it scores at least
``HEADING_MIN_PRESENCE`` are kept (the only ones the verifier sees at run time), warped front-up
around the network's keypoints (``canonical_patches``). So the negatives are the network's own
false detections, the hard cases a cascade stage exists for, and the positives its detections of
drones with the errors it makes.

Shards (``patch_shards.write_patch_shards``, prefix ``v``) hold ``patch`` uint8 (N, P, P, 3), ``y``
bool (a drone is in the crop) and ``presence`` (the network's score).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dronekey.perception.keypoint_model import HEADING_MIN_PRESENCE, KeypointModel
from dronekey.perception.patch_classifier import PATCH_SIZE, canonical_patches
from dronekey.sim_replay.sampler import CropSample, SamplerConfig
from dronekey.training.patch_shards import SHARD_SIZE, network_outputs, write_patch_shards

__all__ = ["NEGATIVE_FRACTION", "load_verifier_shards", "write_verifier_shards"]

# Of the drawn crops, this share is drone-free: the network keeps about one in seven of them, so
# three in four drawn make a balanced shard.
NEGATIVE_FRACTION = 0.75


def write_verifier_shards(
    out: str | Path,
    seed: int,
    shards: int,
    keypoint_model: str | Path | None = None,
    progress: bool = False,
    shard_size: int = SHARD_SIZE,
) -> list[Path]:
    """Render ``shards`` shards of ``shard_size`` drawn crops with sampler seed ``seed`` into
    ``out`` (resumable, one sampler stream per seed)."""
    return write_patch_shards(
        out,
        seed,
        shards,
        _label,
        SamplerConfig(negative_fraction=NEGATIVE_FRACTION),
        keypoint_model,
        progress,
        shard_size,
        prefix="v",
    )


def _label(model: KeypointModel, samples: list[CropSample]) -> dict[str, np.ndarray]:
    crops = np.stack([s.image for s in samples])
    raw = network_outputs(model, crops)
    keep = raw.presence >= HEADING_MIN_PRESENCE
    patches, _ = canonical_patches(crops[keep], raw.keypoints[keep], PATCH_SIZE)
    return {
        "patch": patches,
        "y": np.array([s.present for s in samples], dtype=bool)[keep],
        "presence": raw.presence[keep].astype(np.float32),
    }


def load_verifier_shards(paths: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Patches (N, P, P, 3) uint8, labels (N,) float32 (1: drone) and presence scores (N,)."""
    if not paths:
        raise ValueError("no shards to load")
    patches, labels, presence = [], [], []
    for path in paths:
        with np.load(path) as d:
            patches.append(d["patch"])
            labels.append(d["y"].astype(np.float32))
            presence.append(d["presence"])
    return np.concatenate(patches), np.concatenate(labels), np.concatenate(presence)
