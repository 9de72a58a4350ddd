"""Decode the network's propeller maps: snap regressed keypoints to propeller peaks, read the front.

The DroneKey head regresses the four keypoints in order from the token mean (paper eq. 2-6): it
knows which propeller is which, but on drones without marker LEDs it places them coarsely. The
edge network also predicts two stride-8 maps (``DroneKeyConfig.propeller_maps``): where any
propeller is, and where the front two are. This module fuses the two readings, as a keypoint codec
would:

1. ``refine_keypoints``: each regressed keypoint moves to the propeller peak it is matched to (a
   one-to-one assignment within ``radius``), at the peak's sub-cell centroid; a keypoint without a
   peak near it keeps its regressed place. The order stays the regression's.
2. ``front_probability``: the probability that the keypoints are in the spec's order rather than the
   180-degree twin, from how much more "front" the map sees at keypoints 1 and 4 (front right, front
   left) than at 2 and 3. Near 0.5 when the map cannot tell.

Frames and units: keypoints (K, 2) or (B, K, 2) in normalised crop units (0 = the crop's left/top
edge, 1 = its right/bottom edge, ``dronekey.crop``); maps (B, 2, G, G) probabilities, cell (i, j)
covering [j/G, (j+1)/G) x [i/G, (i+1)/G).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["PEAK_MIN", "REFINE_RADIUS", "find_peaks", "front_probability", "refine_keypoints"]

PEAK_MIN = 0.3  # a map cell must reach this probability to count as a propeller peak
REFINE_RADIUS = 0.15  # of the crop side (19 px of 128): farther peaks are not this keypoint's
FRONT_EPS = 0.05  # keeps the front probability near 0.5 where the map sees no front at all
FRONT_KEYPOINTS = (0, 3)  # front right, front left in the spec's order (1 FR, 2 RR, 3 RL, 4 FL)
REAR_KEYPOINTS = (1, 2)


def find_peaks(heat: np.ndarray, threshold: float = PEAK_MIN) -> np.ndarray:
    """Local maxima (3 x 3) of one map (G, G) at or above ``threshold``, as (N, 2) sub-cell centroids
    in normalised crop units, strongest first."""
    g = heat.shape[-1]
    padded = np.pad(heat, 1, constant_values=-1.0)
    neighbours = np.stack([padded[i : i + g, j : j + g] for i in range(3) for j in range(3)])
    rows, cols = np.nonzero((heat >= neighbours.max(axis=0)) & (heat >= threshold))
    order = np.argsort(-heat[rows, cols])
    peaks = np.empty((len(order), 2), dtype=np.float64)
    for n, (r, c) in enumerate(zip(rows[order], cols[order], strict=True)):
        r0, r1, c0, c1 = max(r - 1, 0), min(r + 2, g), max(c - 1, 0), min(c + 2, g)
        w = heat[r0:r1, c0:c1]
        rr, cc = np.mgrid[r0:r1, c0:c1]
        peaks[n] = ((cc * w).sum() / w.sum() + 0.5) / g, ((rr * w).sum() / w.sum() + 0.5) / g
    return peaks


def refine_keypoints(keypoints: np.ndarray, every: np.ndarray, radius: float = REFINE_RADIUS) -> np.ndarray:
    """``keypoints`` (K, 2) moved onto the peaks of the all-propeller map ``every`` (G, G) they are
    assigned to (minimum total distance, one keypoint per peak, only pairs closer than ``radius``)."""
    peaks = find_peaks(every)
    out = np.array(keypoints, dtype=np.float64, copy=True)
    if not len(peaks):
        return out.astype(keypoints.dtype)
    dist = np.linalg.norm(out[:, None, :] - peaks[None, :, :], axis=2)
    cost = np.where(dist < radius, dist, 1e3)
    for k, p in zip(*linear_sum_assignment(cost), strict=True):
        if dist[k, p] < radius:
            out[k] = peaks[p]
    return out.astype(keypoints.dtype)


def _sample(heat: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear values of ``heat`` (G, G) at ``points`` (N, 2) normalised crop units (edge-clamped)."""
    g = heat.shape[-1]
    x = np.clip(points[:, 0] * g - 0.5, 0, g - 1)
    y = np.clip(points[:, 1] * g - 0.5, 0, g - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, g - 1), np.minimum(y0 + 1, g - 1)
    fx, fy = x - x0, y - y0
    top = heat[y0, x0] * (1 - fx) + heat[y0, x1] * fx
    bottom = heat[y1, x0] * (1 - fx) + heat[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def front_probability(keypoints: np.ndarray, front: np.ndarray) -> float:
    """P(``keypoints`` (K, 2) are in the spec's order, not the twin) from the front map (G, G)."""
    values = _sample(front, np.asarray(keypoints, dtype=np.float64))
    f = float(values[list(FRONT_KEYPOINTS)].mean())
    r = float(values[list(REAR_KEYPOINTS)].mean())
    return (f + FRONT_EPS) / (f + r + 2 * FRONT_EPS)
