"""Square crops: the one place that decides where the keypoint network looks.

The training sampler, the keypoint evaluation and the daemon's localiser all crop through this
module, so the network is trained on exactly the framing it sees at run time.

A crop is an integer square ``roi = (x0, y0, side)`` of the full frame: the column and row of its
top-left pixel and its side in pixels. It is resized to ``input_size``; parts outside the frame are
black. Keypoints inside the network live in normalised crop units, 0 at the crop's left/top edge and
1 at its right/bottom edge:

    n = (u - x0 + 0.5) / side        u = n * side + x0 - 0.5

(u in full-frame pixels with the origin at the centre of the top-left pixel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.frame_image import FrameImage, region_bgr

__all__ = ["CropPolicy", "crop_square", "from_normalised", "roi_around_box", "to_normalised"]

ROI = tuple[int, int, int]


@dataclass(frozen=True)
class CropPolicy:
    """How a drone box becomes a crop.

    Parameters
    ----------
    input_size : int
        Side of the network input in pixels.
    scale : float
        Crop side divided by the longer side of the drone's box.
    min_side : int
        Smallest crop side in full-frame pixels (tiny drones are upsampled at most this much).
    jitter_shift : float
        Training / evaluation jitter of the crop centre, as a fraction of the box's longer side
        (uniform in [-j, j] per axis); stands in for the localiser's error.
    jitter_scale : float
        Training / evaluation jitter of the crop side, log-uniform in [1 - j, 1 + j].
    """

    input_size: int = 128
    scale: float = 1.3
    min_side: int = 32
    jitter_shift: float = 0.08
    jitter_scale: float = 0.15

    def roi(self, box_xywh, rng: np.random.Generator | None = None) -> ROI:
        """Crop for a drone box (x, y, w, h) in full-frame pixels; jittered when ``rng`` is given."""
        x, y, w, h = (float(v) for v in box_xywh)
        cx, cy, size = x + w / 2.0, y + h / 2.0, max(w, h, 1.0)
        side = self.scale * size
        if rng is not None:
            cx += rng.uniform(-self.jitter_shift, self.jitter_shift) * size
            cy += rng.uniform(-self.jitter_shift, self.jitter_shift) * size
            side *= math.exp(rng.uniform(math.log(1 - self.jitter_scale), math.log(1 + self.jitter_scale)))
        return roi_around_box(cx, cy, max(side, self.min_side))


def roi_around_box(cx: float, cy: float, side: float) -> ROI:
    """The integer square of about ``side`` pixels centred on the pixel coordinate (cx, cy)."""
    s = max(1, round(side))
    x0 = round(cx + 0.5 - s / 2.0)
    y0 = round(cy + 0.5 - s / 2.0)
    return int(x0), int(y0), int(s)


def crop_square(image: np.ndarray | FrameImage, roi: ROI, out_size: int) -> np.ndarray:
    """Cut ``roi`` out of ``image`` (black outside it) and resize it to ``out_size`` square.

    ``image``: an array (H, W[, C]), or a frame's ``FrameImage``, of which only the region inside
    the frame is converted to BGR. Downscaling uses area averaging (no aliasing of small
    propellers), upscaling bilinear; both keep the pixel-centre convention, so ``to_normalised``
    maps keypoints exactly.
    """
    x0, y0, side = roi
    h, w = image.shape[:2]
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + side, w), min(y0 + side, h)
    if xa >= xb or ya >= yb:
        dtype = np.uint8 if isinstance(image, FrameImage) else image.dtype
        return np.zeros((out_size, out_size, *image.shape[2:]), dtype=dtype)
    patch = region_bgr(image, xa, ya, xb, yb)
    if (xa, ya, xb, yb) != (x0, y0, x0 + side, y0 + side):
        patch = cv2.copyMakeBorder(
            patch, ya - y0, y0 + side - yb, xa - x0, x0 + side - xb, cv2.BORDER_CONSTANT, value=0
        )
    if side == out_size:
        return np.ascontiguousarray(patch)
    interp = cv2.INTER_AREA if side > out_size else cv2.INTER_LINEAR
    return cv2.resize(patch, (out_size, out_size), interpolation=interp)


def to_normalised(uv_px: np.ndarray, roi: ROI) -> np.ndarray:
    """Full-frame pixels (N, 2) -> normalised crop units (N, 2)."""
    x0, y0, side = roi
    uv = np.asarray(uv_px, dtype=np.float64)
    return (uv - np.array([x0, y0]) + 0.5) / side


def from_normalised(n: np.ndarray, roi: ROI) -> np.ndarray:
    """Normalised crop units (N, 2) -> full-frame pixels (N, 2)."""
    x0, y0, side = roi
    return np.asarray(n, dtype=np.float64) * side + np.array([x0, y0]) - 0.5
