"""Why no board was found: the one-line explanation the CLI prints.

Runs only after detection failed on every picture, on a few sample pictures: it tries the board
sizes an operator most often gets wrong (squares counted instead of inner corners, one row or
column off, rows and columns swapped for an asymmetric grid, a symmetric grid taken for an
asymmetric one or the reverse) and, for ChArUco, whether markers of the given (or another)
dictionary are there at all.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import cv2
import numpy as np

from dronekey.calib.errors import CalibInputError
from dronekey.calib.patterns import BoardDetector, BoardPattern, aruco_dictionary_names

__all__ = ["explain_no_board"]


def explain_no_board(pattern: BoardPattern, samples: Sequence[np.ndarray], examined: str) -> str:
    """The message for "no board in any picture".

    Parameters
    ----------
    pattern : BoardPattern
        The board the operator described.
    samples : sequence of (H, W) uint8
        A few of the pictures (two are enough).
    examined : str
        What was searched, e.g. ``"any of the 12 images"``.
    """
    base = f"no {pattern.describe()} board found in {examined}"
    if not samples:
        return base
    if pattern.kind == "charuco":
        return f"{base}; {_charuco_hint(pattern, samples)}"
    hint = _size_hint(pattern, samples)
    if hint:
        return f"{base}, {hint}"
    return f"{base}; check --pattern, --cols and --rows, and that the board is in view"


def _other_sizes(pattern: BoardPattern) -> list[tuple[tuple[int, int], str]]:
    c, r = pattern.cols, pattern.rows
    sizes = [
        ((c - 1, r - 1), "--cols/--rows count inner corners or circles (points), not squares"),
        ((r, c), "--cols and --rows look swapped"),
        ((c - 1, r), "--cols is one too many"),
        ((c + 1, r), "--cols is one too few"),
        ((c, r - 1), "--rows is one too many"),
        ((c, r + 1), "--rows is one too few"),
    ]
    if pattern.kind != "acircles":
        sizes.pop(1)  # a chessboard or symmetric grid is found either way round
    return [(s, why) for s, why in sizes if min(s) >= 2 and s != pattern.size]


def _size_hint(pattern: BoardPattern, samples: Sequence[np.ndarray]) -> str | None:
    """ "but a ... board was: ..." for the first likely mistake that finds a board, else None."""
    tries = [
        (replace(pattern, cols=c, rows=r), f"{why} (try --cols {c} --rows {r})")
        for (c, r), why in _other_sizes(pattern)
    ]
    other_grid = {"circles": "acircles", "acircles": "circles"}.get(pattern.kind)
    if other_grid:
        tries.insert(0, (replace(pattern, kind=other_grid), f"try --pattern {other_grid}"))
    for candidate, why in tries:
        try:
            detector = BoardDetector(candidate)
        except CalibInputError:
            continue
        if any(detector.detect(gray) is not None for gray in samples):
            article = "an" if candidate.kind[0] in "aeiou" else "a"
            return f"but {article} {candidate.kind} {candidate.cols}x{candidate.rows} board was: {why}"
    return None


def _count_markers(dictionary_name: str, gray: np.ndarray) -> int:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary_name))
    _, ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(gray)
    return 0 if ids is None else len(ids)


def _charuco_hint(pattern: BoardPattern, samples: Sequence[np.ndarray]) -> str:
    name = pattern.dictionary_name
    found = max(_count_markers(name, gray) for gray in samples)
    if found >= 2:
        return (
            f"{found} {name} markers were seen but no {pattern.cols + 1}x{pattern.rows + 1}-square board "
            "fits them: check --cols/--rows (inner corners = squares - 1), --marker, and --legacy-charuco "
            "for boards printed by OpenCV before 4.6"
        )
    for other in aruco_dictionary_names():
        if other != name and _count_markers(other, samples[0]) >= 4:
            return f"no {name} markers were seen, but {other} markers were: try --dictionary {other}"
    return "no ArUco markers were seen at all: check focus, lighting and that the board is in view"
