"""Calibration boards: their object points and how to find them in a grey image.

Four kinds, sized the way OpenCV sizes them (``cols`` points per row, ``rows`` rows of points):

``chessboard``
    inner corners; point (i, j) at (j s, i s, 0). Found with OpenCV's classic detector, or the
    sector-based one (``findChessboardCornersSB``) where the classic one fails, then refined with
    ``cornerSubPix``.
``circles``
    symmetric circle grid; point (i, j) at (j s, i s, 0).
``acircles``
    asymmetric circle grid; point (i, j) at ((2 j + i mod 2) s, i s, 0) (OpenCV's convention, so a
    "4 x 11, 20 mm" board has 40 mm between circles of one row).
``charuco``
    ChArUco board with ``cols`` x ``rows`` inner chessboard corners, i.e. (cols + 1) x (rows + 1)
    squares, markers of ``marker`` metres from an ArUco dictionary. Views may show part of it.

The board frame is the board's plane with z = 0; lengths are metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.calib.errors import CalibInputError
from dronekey.calib.views import BoardView

__all__ = [
    "DEFAULT_DICTIONARY",
    "PATTERN_KINDS",
    "BoardDetector",
    "BoardPattern",
    "aruco_dictionary_names",
]

PATTERN_KINDS = ("chessboard", "circles", "acircles", "charuco")
DEFAULT_DICTIONARY = "DICT_5X5_100"

#: Fewest points a partial (ChArUco) view must show to constrain a homography well.
MIN_CHARUCO_CORNERS = 8

_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)


def aruco_dictionary_names() -> list[str]:
    """OpenCV's predefined ArUco dictionary names, smallest first in each family (``DICT_4X4_50``...)."""
    names = [
        name
        for name in dir(cv2.aruco)
        if name.startswith("DICT_") and name == name.upper() and isinstance(getattr(cv2.aruco, name), int)
    ]

    def family_then_size(name: str) -> tuple[str, int]:
        family, _, size = name.rpartition("_")
        return (family, int(size)) if size.isdigit() else (name, 0)

    return sorted(names, key=family_then_size)


def _dictionary_id(name: str) -> int:
    key = name.strip().upper()
    if not key.startswith("DICT_"):
        key = "DICT_" + key
    value = getattr(cv2.aruco, key, None)
    if not isinstance(value, int):
        raise CalibInputError(
            f"--dictionary {name!r} is not an OpenCV ArUco dictionary; use one of "
            + ", ".join(aruco_dictionary_names())
        )
    return value


@dataclass(frozen=True)
class BoardPattern:
    """A calibration board as printed.

    Parameters
    ----------
    kind : str
        One of ``PATTERN_KINDS``.
    cols, rows : int
        Points per row and rows of points (OpenCV's pattern size; for ChArUco the inner corners).
    square : float
        Square side (chessboard, ChArUco) or grid spacing ``s`` (circle grids), metres.
    marker : float, optional
        ArUco marker side, metres (ChArUco only).
    dictionary : str
        ArUco dictionary name (ChArUco only), with or without the ``DICT_`` prefix.
    legacy_charuco : bool
        Board printed by OpenCV before 4.6 with an even number of square rows (ChArUco only).
    """

    kind: str
    cols: int
    rows: int
    square: float
    marker: float | None = None
    dictionary: str = DEFAULT_DICTIONARY
    legacy_charuco: bool = False

    def __post_init__(self) -> None:
        if self.kind not in PATTERN_KINDS:
            raise CalibInputError(f"--pattern {self.kind!r} is not one of {', '.join(PATTERN_KINDS)}")
        for name, value in (("--cols", self.cols), ("--rows", self.rows)):
            if int(value) != value or value < 2:
                raise CalibInputError(f"{name} must be an integer >= 2 (points, not squares), got {value}")
        if self.kind == "acircles" and self.rows < 3:
            raise CalibInputError(f"--rows must be >= 3 for an asymmetric circle grid, got {self.rows}")
        if not (math.isfinite(self.square) and self.square > 0):
            raise CalibInputError(f"--square must be a positive length in metres, got {self.square}")
        if self.square > 1.0:
            raise CalibInputError(
                f"--square {self.square} is over a metre: give the square size in metres (20 mm = 0.02)"
            )
        if self.kind == "charuco":
            if self.marker is None:
                raise CalibInputError(
                    "--marker (ArUco marker side in metres) is required for --pattern charuco"
                )
            if not (math.isfinite(self.marker) and 0 < self.marker < self.square):
                raise CalibInputError(
                    f"--marker must be positive and smaller than --square {self.square}, got {self.marker}"
                )
            _dictionary_id(self.dictionary)
        elif self.marker is not None:
            raise CalibInputError(f"--marker only applies to --pattern charuco, not {self.kind}")

    @property
    def size(self) -> tuple[int, int]:
        """OpenCV pattern size (points per row, rows)."""
        return int(self.cols), int(self.rows)

    @property
    def point_count(self) -> int:
        return int(self.cols) * int(self.rows)

    def object_points(self) -> np.ndarray:
        """All (cols * rows, 3) board points in metres, in OpenCV's detection order (row-major)."""
        s = float(self.square)
        i, j = np.mgrid[0 : self.rows, 0 : self.cols]
        i, j = i.ravel().astype(np.float64), j.ravel().astype(np.float64)
        if self.kind == "acircles":
            x = (2.0 * j + i % 2) * s
        elif self.kind == "charuco":
            x = (j + 1.0) * s  # ChArUco corner ids count inner corners from the first square's corner
        else:
            x = j * s
        y = (i + 1.0) * s if self.kind == "charuco" else i * s
        return np.column_stack([x, y, np.zeros_like(x)]).astype(np.float32)

    def describe(self) -> str:
        """Short human description, e.g. ``acircles 4x11, 20.0 mm``."""
        text = f"{self.kind} {self.cols}x{self.rows}, {self.square * 1000:g} mm"
        if self.kind == "charuco":
            text += f", markers {self.marker * 1000:g} mm {self.dictionary_name}"
        return text

    @property
    def dictionary_name(self) -> str:
        key = self.dictionary.strip().upper()
        return key if key.startswith("DICT_") else "DICT_" + key


class BoardDetector:
    """Finds one board of a given pattern in 8-bit grey images.

    Parameters
    ----------
    pattern : BoardPattern
        The board to look for.
    """

    def __init__(self, pattern: BoardPattern) -> None:
        self.pattern = pattern
        self._grid = pattern.object_points()
        self._charuco = None
        if pattern.kind == "charuco":
            dictionary = cv2.aruco.getPredefinedDictionary(_dictionary_id(pattern.dictionary))
            board = cv2.aruco.CharucoBoard(
                (pattern.cols + 1, pattern.rows + 1), float(pattern.square), float(pattern.marker), dictionary
            )
            board.setLegacyPattern(bool(pattern.legacy_charuco))
            self._charuco_board = board
            self._charuco = cv2.aruco.CharucoDetector(board)
            self._grid = np.asarray(board.getChessboardCorners(), dtype=np.float32).reshape(-1, 3)

    def detect(self, gray: np.ndarray) -> BoardView | None:
        """The board in ``gray`` (H, W) uint8, or None where it is not (fully, for grids) visible."""
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise ValueError(f"gray must be a 2-D uint8 image, got shape {gray.shape} dtype {gray.dtype}")
        kind = self.pattern.kind
        if kind == "chessboard":
            points = self._find_chessboard(gray)
        elif kind in ("circles", "acircles"):
            points = self._find_circles(gray)
        else:
            return self._find_charuco(gray)
        if points is None:
            return None
        return BoardView(points.reshape(-1, 2).astype(np.float32), self._grid)

    # ------------------------------------------------------------------ chessboard
    def _find_chessboard(self, gray: np.ndarray) -> np.ndarray | None:
        size = self.pattern.size
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        found, corners = cv2.findChessboardCorners(gray, size, flags=flags)
        if not found:
            found, corners = cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not found:
            return None
        corners = np.ascontiguousarray(corners.reshape(-1, 1, 2), dtype=np.float32)
        half = _subpix_half_window(corners.reshape(-1, 2), size)
        return cv2.cornerSubPix(gray, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)

    # ------------------------------------------------------------------ circle grids
    def _find_circles(self, gray: np.ndarray) -> np.ndarray | None:
        flags = (
            cv2.CALIB_CB_ASYMMETRIC_GRID if self.pattern.kind == "acircles" else cv2.CALIB_CB_SYMMETRIC_GRID
        )
        blobs = _circle_blob_detector(gray.shape, self.pattern.point_count)
        for image in (gray, 255 - gray):  # dark circles on white, then white circles on black
            found, centres = cv2.findCirclesGrid(image, self.pattern.size, flags=flags, blobDetector=blobs)
            if found:
                return centres
        return None

    # ------------------------------------------------------------------ ChArUco
    def _find_charuco(self, gray: np.ndarray) -> BoardView | None:
        corners, ids, _, _ = self._charuco.detectBoard(gray)
        if corners is None or ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        ids = ids.reshape(-1)
        if self._charuco_board.checkCharucoCornersCollinear(ids):
            return None
        return BoardView(corners.reshape(-1, 2).astype(np.float32), self._grid[ids])


def _subpix_half_window(corners: np.ndarray, size: tuple[int, int]) -> int:
    """Half window for ``cornerSubPix``: a third of the smallest corner spacing, 2..11 px.

    A window that reaches the next corner biases the refinement, one much smaller than a square
    throws away edge pixels.
    """
    grid = corners.reshape(size[1], size[0], 2)
    along_rows = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    along_cols = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    spacing = float(min(along_rows.min(), along_cols.min()))
    return int(np.clip(round(spacing / 3.0), 2, 11))


def _circle_blob_detector(shape: tuple[int, ...], count: int) -> cv2.SimpleBlobDetector:
    """Blob detector for a circle grid: OpenCV's defaults, with the largest blob area scaled to the image.

    OpenCV's default ``maxArea`` (5000 px²) misses the circles of a board that fills a high-resolution
    frame; a circle can be no larger than the image divided among the grid's points. The smallest
    area stays at OpenCV's 25 px²: smaller lets speckle in and breaks the grid ordering.
    """
    params = cv2.SimpleBlobDetector_Params()
    params.maxArea = max(5000.0, float(shape[0] * shape[1]) / max(count, 1))
    return cv2.SimpleBlobDetector_create(params)
