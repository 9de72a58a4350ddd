"""The image half of the association cost: how well a measurement's keypoints overlap where a
track's keypoints are expected (docs/pose-and-tracking.md, association).

The tracker knows no camera, so a track's expected keypoint box is its last measured one (the box
of its four hubs, full-frame px) moved by the box centre's image velocity, smoothed over its hits:
enough to tell two drones apart whose 3D gates overlap (one passing in front of another), cheap,
and neutral (0.5) for a track or a measurement without keypoints.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KeypointMotion", "box_iou", "keypoint_box"]

Box = tuple[float, float, float, float]  # x0, y0, x1, y1 (px)

NEUTRAL_IOU = 0.5  # the overlap assumed when either side has no keypoints
_VELOCITY_SMOOTHING = 0.5  # weight of the newest velocity estimate


def keypoint_box(keypoints_px: np.ndarray | None) -> Box | None:
    """Box (x0, y0, x1, y1) of the finite keypoints, or None without two of them."""
    if keypoints_px is None:
        return None
    kp = np.asarray(keypoints_px, dtype=np.float64).reshape(-1, 2)
    kp = kp[np.all(np.isfinite(kp), axis=1)]
    if len(kp) < 2:
        return None
    (x0, y0), (x1, y1) = kp.min(axis=0), kp.max(axis=0)
    return float(x0), float(y0), float(x1), float(y1)


def box_iou(a: Box | None, b: Box | None) -> float:
    """Intersection over union of two boxes; ``NEUTRAL_IOU`` when either is None."""
    if a is None or b is None:
        return NEUTRAL_IOU
    iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = iw * ih
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


class KeypointMotion:
    """A track's last keypoint box and the image velocity (px/s) of its centre."""

    def __init__(self) -> None:
        self.box: Box | None = None
        self.t_ns: int | None = None
        self.velocity_pxps = np.zeros(2)

    def observe(self, t_ns: int, keypoints_px: np.ndarray | None) -> None:
        """Fold in the keypoints of a hit at ``t_ns`` (None: nothing to learn)."""
        box = keypoint_box(keypoints_px)
        if box is None:
            return
        if self.box is not None and self.t_ns is not None and t_ns > self.t_ns:
            dt = (t_ns - self.t_ns) / 1e9
            shift = (np.add(box[:2], box[2:]) - np.add(self.box[:2], self.box[2:])) / 2
            a = _VELOCITY_SMOOTHING
            self.velocity_pxps = a * shift / dt + (1 - a) * self.velocity_pxps
        self.box, self.t_ns = box, t_ns

    def predicted_box(self, t_ns: int) -> Box | None:
        """The last box moved by the velocity to ``t_ns`` (None before any keypoints)."""
        if self.box is None or self.t_ns is None:
            return None
        dx, dy = self.velocity_pxps * ((t_ns - self.t_ns) / 1e9)
        x0, y0, x1, y1 = self.box
        return x0 + dx, y0 + dy, x1 + dx, y1 + dy
