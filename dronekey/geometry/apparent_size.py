"""A drone's size in the image, from its four keypoints: what the localiser frames its crops by,
the pose check scales its reprojection limit by, and the tracker may bound a heading's confidence by."""

from __future__ import annotations

import numpy as np

__all__ = ["keypoint_spread"]


def keypoint_spread(keypoints_px: np.ndarray) -> float:
    """Largest distance between two keypoints (px): the drone's apparent size."""
    kp = np.asarray(keypoints_px, dtype=np.float64)
    return float(max(np.linalg.norm(kp[i] - kp[j]) for i in range(len(kp)) for j in range(i + 1, len(kp))))
