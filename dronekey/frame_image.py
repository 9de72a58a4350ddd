"""A decoded frame's pixels, converted to BGR only where a stage needs colour.

A decoder hands over 4:2:0 planar YUV (I420); converting a whole 1080p frame to BGR costs about
1 ms of CPU on the 2-core box, yet the pipeline needs colour only in the crops the network sees
(a few 128 px squares), the search's downscaled copy (480 px wide) and the frames a sink asks for
(MCAP images at 2 Hz, the annotated video). ``I420Image`` keeps the planes and converts just those
regions, with OpenCV's own I420 conversion (nearest chroma, BT.601 limited range): a region cut on
even coordinates comes out bit for bit as the same region of the whole frame's conversion.
``BgrImage`` wraps a frame that is BGR already (OpenCV readers, V4L2, rendered frames).

Coordinates are full-frame pixels: column x, row y; regions are half-open ``[x0, x1) x [y0, y1)``.
Both kinds are read-only once made (their arrays are frozen): a frame is shared between the pipeline
and the outputs' threads.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod

import cv2
import numpy as np

__all__ = ["BgrImage", "FrameImage", "I420Image", "as_frame_image", "downscaled_bgr", "region_bgr"]


class FrameImage(ABC):
    """One frame's pixels; ``width`` x ``height`` full-frame pixels."""

    width: int
    height: int

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), px."""
        return self.width, self.height

    @property
    def shape(self) -> tuple[int, int, int]:
        """(height, width, 3): the shape of ``bgr()``, known without converting."""
        return self.height, self.width, 3

    @abstractmethod
    def bgr(self) -> np.ndarray:
        """The whole frame, (H, W, 3) uint8 BGR, read-only (converted once, then kept)."""

    @abstractmethod
    def region_bgr(self, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """BGR of the region ``[x0, x1) x [y0, y1)`` (inside the frame, non-empty), (y1 - y0, x1 - x0, 3)
        uint8; may be a read-only view."""

    @abstractmethod
    def downscaled_bgr(self, width: int, height: int) -> np.ndarray:
        """The whole frame area-averaged to ``width`` x ``height`` (no larger than the frame), BGR."""


class BgrImage(FrameImage):
    """A frame that is BGR already: regions are views."""

    def __init__(self, bgr: np.ndarray) -> None:
        bgr = np.asarray(bgr)
        if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
            raise ValueError(f"bgr must be an (H, W, 3) uint8 array, got {bgr.dtype} {bgr.shape}")
        self._bgr = bgr.view()  # read-only through this image; the caller's array is left as it was
        self._bgr.flags.writeable = False
        self.height, self.width = bgr.shape[:2]

    def bgr(self) -> np.ndarray:
        return self._bgr

    def region_bgr(self, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        return region_bgr(self._bgr, x0, y0, x1, y1)

    def downscaled_bgr(self, width: int, height: int) -> np.ndarray:
        return downscaled_bgr(self._bgr, width, height)


class I420Image(FrameImage):
    """A 4:2:0 planar YUV frame of even size, BT.601 limited range (what ``cv2.COLOR_YUV2BGR_I420``
    assumes), as the (H * 3 / 2, W) uint8 array FFmpeg and PyAV lay it out: the luma plane's H rows,
    then the U and V planes (H / 2 x W / 2 each) packed behind it."""

    def __init__(self, i420: np.ndarray) -> None:
        i420 = np.asarray(i420)
        rows, width = i420.shape if i420.ndim == 2 else (0, 0)
        height = rows * 2 // 3
        if i420.dtype != np.uint8 or rows != height * 3 // 2 or height % 2 or width % 2 or not height:
            raise ValueError(
                f"i420 must be an (H * 3 / 2, W) uint8 array with H and W even, got {i420.dtype} {i420.shape}"
            )
        i420 = np.ascontiguousarray(i420)
        i420.flags.writeable = False
        self._i420 = i420
        self.width, self.height = width, height
        chroma = i420[height:].reshape(2, height // 2, width // 2)
        self.luma = i420[:height]  # (H, W): the Y plane, a view
        self._u, self._v = chroma[0], chroma[1]
        self._bgr: np.ndarray | None = None
        self._lock = threading.Lock()

    def bgr(self) -> np.ndarray:
        with self._lock:  # the pipeline and an output's thread may both ask
            if self._bgr is None:
                bgr = cv2.cvtColor(self._i420, cv2.COLOR_YUV2BGR_I420)
                bgr.flags.writeable = False
                self._bgr = bgr
            return self._bgr

    def region_bgr(self, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        if self._bgr is not None:
            return self._bgr[y0:y1, x0:x1]
        ex0, ey0 = x0 & ~1, y0 & ~1  # out to the chroma grid, so the conversion is the whole frame's
        ex1, ey1 = min(x1 + (x1 & 1), self.width), min(y1 + (y1 & 1), self.height)
        bgr = _i420_to_bgr(
            self.luma[ey0:ey1, ex0:ex1],
            self._u[ey0 // 2 : ey1 // 2, ex0 // 2 : ex1 // 2],
            self._v[ey0 // 2 : ey1 // 2, ex0 // 2 : ex1 // 2],
        )
        return bgr[y0 - ey0 : y1 - ey0, x0 - ex0 : x1 - ex0]

    def downscaled_bgr(self, width: int, height: int) -> np.ndarray:
        if self._bgr is not None or width % 2 or height % 2:
            return downscaled_bgr(self.bgr(), width, height)
        half = (width // 2, height // 2)
        return _i420_to_bgr(
            cv2.resize(self.luma, (width, height), interpolation=cv2.INTER_AREA),
            cv2.resize(self._u, half, interpolation=cv2.INTER_AREA),
            cv2.resize(self._v, half, interpolation=cv2.INTER_AREA),
        )


def _i420_to_bgr(y: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """BGR of planes (h, w), (h / 2, w / 2), (h / 2, w / 2) with h and w even."""
    h, w = y.shape
    packed = np.concatenate([y.ravel(), u.ravel(), v.ravel()]).reshape(h * 3 // 2, w)
    return cv2.cvtColor(packed, cv2.COLOR_YUV2BGR_I420)


def as_frame_image(image: FrameImage | np.ndarray) -> FrameImage:
    """``image`` as a ``FrameImage``: an (H, W, 3) uint8 BGR array is wrapped (and frozen), a
    ``FrameImage`` is returned as it is."""
    if isinstance(image, FrameImage):
        return image
    return BgrImage(image)


def region_bgr(image: FrameImage | np.ndarray, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
    """``image.region_bgr`` for a ``FrameImage``, the slice ``[y0:y1, x0:x1]`` of an array (any
    dtype or channels: the training and evaluation code crops arrays)."""
    if isinstance(image, FrameImage):
        return image.region_bgr(x0, y0, x1, y1)
    return image[y0:y1, x0:x1]


def downscaled_bgr(image: FrameImage | np.ndarray, width: int, height: int) -> np.ndarray:
    """``image.downscaled_bgr`` for a ``FrameImage``, area averaging for an array (any dtype)."""
    if isinstance(image, FrameImage):
        return image.downscaled_bgr(width, height)
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
