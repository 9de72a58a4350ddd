"""Where on the sensor board points were seen: figures for the advice, and a PNG for the operator.

Distortion is only measured where points were seen; beyond them it is extrapolated, which is what
goes wrong when every view holds the board in the middle of the image.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["CoverageStats", "coverage_image", "coverage_stats", "write_png"]

#: Grid columns over the sensor; rows follow the aspect ratio.
GRID_COLS = 8
#: A side of the image counts as reached when some point lies within this share of it.
EDGE_BAND = 0.15


@dataclass(frozen=True)
class CoverageStats:
    """How much of the sensor the board points covered.

    Attributes
    ----------
    cell_fraction : float
        Share of the cells of a ``GRID_COLS`` x rows grid holding at least one point.
    edges_missed : tuple of str
        Sides ("left", "right", "top", "bottom") no point came within ``EDGE_BAND`` of.
    grid : (rows, cols) int array
        Points per cell.
    """

    cell_fraction: float
    edges_missed: tuple[str, ...]
    grid: np.ndarray


def _grid_shape(width: int, height: int) -> tuple[int, int]:
    return max(2, round(GRID_COLS * height / width)), GRID_COLS


def coverage_stats(points: Sequence[np.ndarray], image_size: tuple[int, int]) -> CoverageStats:
    """Coverage of ``points`` (one (N, 2) pixel array per view) on a sensor of (width, height)."""
    width, height = int(image_size[0]), int(image_size[1])
    rows, cols = _grid_shape(width, height)
    allpts = (
        np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in points]) if points else None
    )
    grid = np.zeros((rows, cols), dtype=np.int64)
    if allpts is None or allpts.size == 0:
        return CoverageStats(0.0, ("left", "right", "top", "bottom"), grid)
    cx = np.clip(((allpts[:, 0] + 0.5) / width * cols).astype(int), 0, cols - 1)
    cy = np.clip(((allpts[:, 1] + 0.5) / height * rows).astype(int), 0, rows - 1)
    np.add.at(grid, (cy, cx), 1)
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    missed = []
    if lo[0] > EDGE_BAND * width:
        missed.append("left")
    if hi[0] < (1.0 - EDGE_BAND) * width:
        missed.append("right")
    if lo[1] > EDGE_BAND * height:
        missed.append("top")
    if hi[1] < (1.0 - EDGE_BAND) * height:
        missed.append("bottom")
    return CoverageStats(float(np.count_nonzero(grid)) / grid.size, tuple(missed), grid)


def coverage_image(
    points: Sequence[np.ndarray],
    image_size: tuple[int, int],
    outliers: Sequence[np.ndarray] = (),
    title: str = "",
) -> np.ndarray:
    """A BGR picture of the sensor: grid cells shaded by point count, each view's points and outline.

    Cells without a point are tinted red; outlier views (left out of the calibration) are drawn in red.
    """
    width, height = int(image_size[0]), int(image_size[1])
    scale = 960.0 / max(width, height)
    out_w, out_h = round(width * scale), round(height * scale)
    canvas = np.full((out_h, out_w, 3), 32, dtype=np.uint8)
    stats = coverage_stats(points, image_size)
    rows, cols = stats.grid.shape
    peak = max(int(stats.grid.max()), 1)
    for r in range(rows):
        for c in range(cols):
            x0, x1 = round(c * out_w / cols), round((c + 1) * out_w / cols)
            y0, y1 = round(r * out_h / rows), round((r + 1) * out_h / rows)
            n = int(stats.grid[r, c])
            colour = (35, 35, 75) if n == 0 else (40, int(60 + 100 * n / peak), 40)
            cv2.rectangle(canvas, (x0, y0), (x1 - 1, y1 - 1), colour, thickness=-1)
            cv2.rectangle(canvas, (x0, y0), (x1 - 1, y1 - 1), (70, 70, 70), thickness=1)
    palette = cv2.applyColorMap(np.linspace(0, 255, max(len(points), 1)).astype(np.uint8), cv2.COLORMAP_COOL)
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    for views, colours in ((points, palette.reshape(-1, 3)), (outliers, None)):
        for k, pts in enumerate(views):
            uv = (np.asarray(pts, dtype=np.float64).reshape(-1, 2) + 0.5) * scale - 0.5
            colour = (0, 0, 255) if colours is None else tuple(int(v) for v in colours[k])
            hull = cv2.convexHull(np.round(uv * (1 << shift)).astype(np.int32))
            cv2.polylines(canvas, [hull], True, colour, 1 if colours is not None else 2, cv2.LINE_AA, shift)
            for x, y in np.round(uv * (1 << shift)).astype(np.int32):
                cv2.circle(canvas, (int(x), int(y)), 2 << shift, colour, -1, cv2.LINE_AA, shift)
    lines = [
        title,
        f"{sum(len(p) for p in points)} points in {len(points)} views; "
        f"{100 * stats.cell_fraction:.0f}% of sensor cells covered (red cells: none)",
        f"sensor {width}x{height} px" + (f"; {len(outliers)} outlier views in red" if len(outliers) else ""),
    ]
    y = 22
    for text in (t for t in lines if t):
        (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.55, 1)
        cv2.rectangle(canvas, (6, y - h - 4), (14 + w, y + base + 2), (0, 0, 0), thickness=-1)
        cv2.putText(canvas, text, (10, y), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)
        y += 24
    return canvas


def write_png(path: Path, image: np.ndarray) -> None:
    """Write a PNG through a temporary file renamed at the end."""
    path = Path(path)
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {path}")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_bytes(data.tobytes())
        tmp.replace(path)
    except OSError:
        tmp.unlink(missing_ok=True)
        raise
