"""Picking calibration views from many video frames: sharp ones, spread over position, size and tilt.

Consecutive frames of a calibration video are near-duplicates and some are motion-blurred. A good
set spans the sensor (the edges constrain distortion), distances (board sizes) and tilts (which
separate focal length from distance). Each frame with a board gets a descriptor

    (x, y, size, tilt_x, tilt_y)

with x, y the board's centre as a fraction of the image, size the square root of the board's area
fraction, and tilt the board's vanishing line in image axes (about tan of the tilt toward x and
y; 0 for a board facing the camera). Frames blurrier than half the median are dropped, then views
are picked greedily by farthest-point sampling on the descriptor, weighted toward sharper frames,
until ``max_views`` or until what remains repeats what was picked.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.calib.views import BoardView

__all__ = ["ViewCandidate", "board_sharpness", "pose_descriptor", "select_diverse"]

#: A frame is blurred when its sharpness is below this share of the median frame's.
BLUR_RATIO = 0.5
#: Picking stops when the most novel remaining frame is this close (descriptor units) to a picked one.
MIN_NOVELTY = 0.05


@dataclass(frozen=True)
class ViewCandidate:
    """A frame with a board: its name, points, sharpness and descriptor."""

    name: str
    view: BoardView
    sharpness: float
    descriptor: np.ndarray


def board_sharpness(gray: np.ndarray, view: BoardView) -> float:
    """Variance of the Laplacian over the board's bounding box (padded by 5 %), grey levels².

    Measured on the board, not the whole frame, so a sharp background cannot hide a blurred board.
    """
    pts = np.asarray(view.image_points, dtype=np.float64).reshape(-1, 2)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * (hi - lo) + 2.0
    x0, y0 = np.maximum(np.floor(lo - pad).astype(int), 0)
    x1, y1 = np.ceil(hi + pad).astype(int) + 1
    roi = gray[y0:y1, x0:x1]
    if roi.size < 9:
        return 0.0
    return float(cv2.Laplacian(roi, cv2.CV_64F).var())


def pose_descriptor(view: BoardView, image_size: tuple[int, int]) -> np.ndarray:
    """(x, y, size, tilt_x, tilt_y) of a board view in an image of (width, height) pixels.

    The tilt is the board plane's vanishing line ``l`` (the last row of the image-to-board homography,
    with image coordinates centred and divided by the half diagonal): ``(l1, l2) / l3``, about
    ``tan(tilt)`` times half-diagonal / focal length; clipped to [-1, 1].
    """
    width, height = float(image_size[0]), float(image_size[1])
    img = np.asarray(view.image_points, dtype=np.float64).reshape(-1, 2)
    obj = np.asarray(view.object_points, dtype=np.float64).reshape(-1, 3)[:, :2]
    centre = img.mean(axis=0)
    hull = cv2.convexHull(img.astype(np.float32))
    area = float(cv2.contourArea(hull))
    size = np.sqrt(area / (width * height))
    tilt = np.zeros(2)
    half_diag = 0.5 * np.hypot(width, height)
    centred = (img - [0.5 * (width - 1), 0.5 * (height - 1)]) / half_diag
    H, _ = cv2.findHomography(obj, centred, 0)
    if H is not None and abs(np.linalg.det(H)) > 1e-12:
        line = np.linalg.inv(H)[2]
        if abs(line[2]) > 1e-12:
            tilt = np.clip(line[:2] / line[2], -1.0, 1.0)
    return np.array([centre[0] / width, centre[1] / height, size, tilt[0], tilt[1]])


def select_diverse(
    candidates: Sequence[ViewCandidate],
    max_views: int,
    blur_ratio: float = BLUR_RATIO,
    min_novelty: float = MIN_NOVELTY,
) -> list[int]:
    """Indices (ascending) of at most ``max_views`` sharp, mutually different candidates.

    Parameters
    ----------
    candidates : sequence of ViewCandidate
        Frames with a board, in any order.
    max_views : int
        Most views to return.
    blur_ratio : float
        Candidates with sharpness below ``blur_ratio`` times the median are never picked.
    min_novelty : float
        Stop when the best remaining candidate is closer than this to a picked one.
    """
    if max_views < 1:
        raise ValueError(f"max_views must be >= 1, got {max_views}")
    if not candidates:
        return []
    sharp = np.array([c.sharpness for c in candidates], dtype=np.float64)
    desc = np.stack([np.asarray(c.descriptor, dtype=np.float64) for c in candidates])
    eligible = sharp >= blur_ratio * np.median(sharp)
    weight = 0.5 + 0.5 * sharp / max(sharp.max(), 1e-12)
    first = int(np.argmax(np.where(eligible, sharp, -np.inf)))
    picked = [first]
    nearest = np.linalg.norm(desc - desc[first], axis=1)
    while len(picked) < max_views:
        score = np.where(eligible, nearest * weight, -np.inf)
        score[picked] = -np.inf
        best = int(np.argmax(score))
        if not np.isfinite(score[best]) or nearest[best] < min_novelty:
            break
        picked.append(best)
        nearest = np.minimum(nearest, np.linalg.norm(desc - desc[best], axis=1))
    return sorted(picked)
