"""A folder of still images played as a video, in natural file-name order (frame_2 before frame_10).

Every frame of a video has one size, and the pipeline's intrinsics are scaled to it; so an image of
another size than the folder's first readable one is skipped with a warning and counted as corrupt,
like an undecodable one, rather than restarting (or, for another aspect ratio, stopping) the run.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import cv2

from dronekey.daemon.sources.base import FrameReader, ReadResult, SourceOpenError, valid_bgr
from dronekey.daemon.sources.sidecar import sidecar_camera
from dronekey.geometry.camera import CameraModel

__all__ = ["IMAGE_SUFFIXES", "ImageFolderReader"]

log = logging.getLogger(__name__)

# Odd-sized images named one by one in the log; past this, only the count (a folder of mixed sizes).
_SIZE_WARNINGS = 10

IMAGE_SUFFIXES = frozenset({".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm"})


def _natural_key(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


class ImageFolderReader(FrameReader):
    """Images of one folder; frame ``i`` is stamped ``i / fps`` seconds.

    Unreadable images, and images of another size than the first readable one, are corrupt.
    """

    live = False
    kind = "images"

    def __init__(self, folder: Path, fps: float) -> None:
        self.folder = Path(folder)
        self.description = str(self.folder)
        self._fps = float(fps)
        self._files: list[Path] = []
        self._next = 0
        self._size: tuple[int, int] | None = None
        self._odd_sized = 0

    @property
    def frame_rate(self) -> float | None:
        return self._fps

    @property
    def resolution(self) -> tuple[int, int] | None:
        return self._size

    def open(self) -> None:
        if not self.folder.is_dir():
            raise SourceOpenError(f"image folder not found: {self.folder}")
        files = [p for p in self.folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()]
        if not files:
            suffixes = " ".join(sorted(IMAGE_SUFFIXES))
            raise SourceOpenError(f"{self.folder} holds no image ({suffixes})")
        self._files = sorted(files, key=_natural_key)
        self._next = 0
        for path in self._files:
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if valid_bgr(img):
                self._size = (img.shape[1], img.shape[0])
                return
        raise SourceOpenError(f"{self.folder}: none of its {len(self._files)} images can be decoded")

    def read(self) -> ReadResult:
        corrupt = 0
        while self._next < len(self._files):
            index = self._next
            self._next += 1
            path = self._files[index]
            img = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if valid_bgr(img) and (img.shape[1], img.shape[0]) == self._size:
                return ReadResult(img, round(index * 1e9 / self._fps), corrupt=corrupt)
            if valid_bgr(img):
                self._warn_size(path, img.shape[1], img.shape[0])
            corrupt += 1
        return ReadResult(corrupt=corrupt, ended=True)

    def _warn_size(self, path: Path, width: int, height: int) -> None:
        self._odd_sized += 1
        if self._odd_sized <= _SIZE_WARNINGS:
            w, h = self._size
            more = "; further ones are skipped without a line" if self._odd_sized == _SIZE_WARNINGS else ""
            log.warning("%s is %dx%d, not the folder's %dx%d: skipped%s", path, width, height, w, h, more)

    def close(self) -> None:
        self._next = len(self._files)

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        return sidecar_camera(self.folder)
