"""Where calibration pictures come from: a glob of image files, or evenly spaced frames of a video."""

from __future__ import annotations

import glob
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dronekey.calib.errors import CalibInputError

__all__ = ["VideoSampler", "expand_image_glob", "read_gray"]


def expand_image_glob(pattern: str) -> list[Path]:
    """Files matching ``pattern`` (``**`` recurses), sorted by name; an error if there are none."""
    paths = sorted(Path(p) for p in glob.glob(str(Path(pattern).expanduser()), recursive=True))
    files = [p for p in paths if p.is_file()]
    if not files:
        raise CalibInputError(f"no files match --images {pattern!r}")
    return files


def read_gray(path: Path) -> np.ndarray:
    """Decode one image file to 8-bit grey (H, W); 16-bit images are stretched to their own range.

    The stretch keeps 10- and 12-bit sensor data (stored in 16-bit files) usable for detection.
    """
    data = np.fromfile(str(path), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None:
        raise CalibInputError(f"cannot read {path}: not an image file OpenCV can decode")
    if image.dtype == np.uint16:
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX, cv2.CV_8U)
    elif image.dtype != np.uint8:
        raise CalibInputError(f"cannot use {path}: pixel type {image.dtype} (need 8- or 16-bit)")
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    return image


@dataclass
class VideoSampler:
    """Evenly spaced frames of a video file, decoded in order (no seeking, which codecs do badly).

    Parameters
    ----------
    path : Path
        The video file.
    frames : int
        How many frames to examine at most; the step between them follows from the frame count.
    """

    path: Path
    frames: int = 200

    def __post_init__(self) -> None:
        if self.frames < 1:
            raise CalibInputError(f"--frames must be >= 1, got {self.frames}")
        if not Path(self.path).is_file():
            raise CalibInputError(f"video not found: {self.path}")
        capture = cv2.VideoCapture(str(self.path))
        try:
            if not capture.isOpened():
                raise CalibInputError(f"cannot open video {self.path}: not a video file OpenCV can decode")
            self.frame_count = max(int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
        finally:
            capture.release()
        self.step = max(1, math.ceil(self.frame_count / self.frames)) if self.frame_count else 1

    @property
    def expected(self) -> int:
        """Number of frames the iteration will yield, as far as the container's frame count tells."""
        return min(self.frames, math.ceil(self.frame_count / self.step)) if self.frame_count else self.frames

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (frame index, grey frame) for every ``step``-th frame, at most ``frames`` of them."""
        capture = cv2.VideoCapture(str(self.path))
        try:
            index, yielded = 0, 0
            while yielded < self.frames:
                if index % self.step == 0:
                    ok, frame = capture.read()
                    if not ok:
                        break
                    if frame.ndim == 3:
                        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
                    yield index, frame
                    yielded += 1
                elif not capture.grab():
                    break
                index += 1
        finally:
            capture.release()
