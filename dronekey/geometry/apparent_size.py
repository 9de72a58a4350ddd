"""A drone's size in the image, from its four keypoints: what the localiser frames its crops by,
the pose check scales its reprojection limit by, and the tracker may bound a heading's confidence by."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["keypoint_spread"]


def keypoint_spread(keypoints_px: np.ndarray) -> float:
    """Largest distance between two keypoints (px): the drone's apparent size. Computed on Python
    floats: numpy's ``norm`` of each pair to the bit, at a third of its cost (it runs several times
    for every crop of every frame)."""
    kp = np.asarray(keypoints_px, dtype=np.float64).tolist()
    pairs = ((a[0] - b[0], a[1] - b[1]) for i, a in enumerate(kp) for b in kp[i + 1 :])
    return math.sqrt(max(dx * dx + dy * dy for dx, dy in pairs))
