"""What the operator reads: the ``--json`` object, the readable summary, and advice on the views.

The advice names concrete problems with concrete fixes: too few views, points only in the middle
of the sensor, no tilted views, a view whose error stands out (and which one), a high overall
error, a board distance that suggests ``--square`` is not in metres.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dronekey.calib.calibrate import CalibrationOptions, CalibrationResult
from dronekey.calib.coverage import CoverageStats
from dronekey.calib.views import RejectedView

__all__ = ["advice", "calibration_json", "calibration_summary", "check_json", "check_summary"]

#: Fewer views than this earns advice (the hard floor is ``calibrate.MIN_VIEWS``).
GOOD_VIEW_COUNT = 15
#: A view stands out above this multiple of the median per-view error ...
HIGH_VIEW_RATIO = 2.0
#: ... and above this absolute error, pixels.
HIGH_VIEW_FLOOR_PX = 0.2
#: An overall RMS above this (pixels) earns advice.
HIGH_RMS_PX = 1.0
#: Largest tilt (degrees) below which the views are called "all facing the camera".
MIN_GOOD_TILT_DEG = 20.0
#: Some views should reach this share of the sensor cells.
GOOD_CELL_FRACTION = 0.5


def _names(items: Sequence[str], limit: int = 3) -> str:
    shown = ", ".join(items[:limit])
    return shown + (f" and {len(items) - limit} more" if len(items) > limit else "")


def advice(
    result: CalibrationResult,
    coverage: CoverageStats,
    outliers: Sequence[RejectedView] = (),
    coverage_png: str | None = None,
) -> list[str]:
    """Advice lines for a calibration, most important first; empty when nothing stands out."""
    lines = []
    n = len(result.view_names)
    if n < GOOD_VIEW_COUNT:
        lines.append(
            f"only {n} views: {GOOD_VIEW_COUNT} to 40 views at different positions, distances and tilts "
            "give stable distortion figures"
        )
    if coverage.edges_missed or coverage.cell_fraction < GOOD_CELL_FRACTION:
        where = (
            f" and never near the {', '.join(coverage.edges_missed)} edge" if coverage.edges_missed else ""
        )
        see = f" (see {coverage_png})" if coverage_png else ""
        lines.append(
            f"board points cover {100 * coverage.cell_fraction:.0f}% of the sensor{where}: with points "
            "only in the centre the distortion at the edges is extrapolated; hold the board near the edges "
            f"and corners too{see}"
        )
    tilts = result.tilt_deg()
    if tilts.size and tilts.max() < MIN_GOOD_TILT_DEG:
        lines.append(
            f"every view faces the camera (largest tilt {tilts.max():.0f} deg): tilt the board 20-45 deg in "
            "some views; tilt is what separates focal length from distance"
        )
    median = float(np.median(result.per_view_rms))
    high = [
        (name, err)
        for name, err in zip(result.view_names, result.per_view_rms, strict=True)
        if err > max(HIGH_VIEW_RATIO * median, HIGH_VIEW_FLOOR_PX)
    ]
    for name, err in sorted(high, key=lambda item: -item[1])[:3]:
        lines.append(
            f"view {name} has {err:.2f} px RMS, {err / median:.1f}x the median {median:.2f} px: check it for "
            "blur, glare or a bent board, and remove it if so"
        )
    if outliers:
        lines.append(
            f"left out {len(outliers)} outlier view(s): {_names([v.name for v in outliers])} "
            f"({outliers[0].reason})"
        )
    if result.rms > HIGH_RMS_PX:
        lines.append(
            f"overall RMS {result.rms:.2f} px is high (a flat board in sharp images gives under 0.5 px): "
            "check focus, motion blur, board flatness, and --cols, --rows and --square"
        )
    distance = float(np.median(np.linalg.norm(result.tvecs, axis=1)))
    if not 0.05 <= distance <= 50.0:
        lines.append(f"the board appears {distance:.3g} m away: is --square in metres (20 mm = 0.02)?")
    return lines


def calibration_json(result: CalibrationResult, rejected: Sequence[RejectedView]) -> dict:
    """The ``--json`` object: exactly the keys docs/calibration.md lists.

    ``per_view_rms`` follows the order of the views used: the pictures in name order (video frames in
    time order) minus those in ``rejected``.
    """
    camera = result.camera
    return {
        "views_used": len(result.view_names),
        "rms_px": float(result.rms),
        "fx": camera.fx,
        "fy": camera.fy,
        "cx": camera.cx,
        "cy": camera.cy,
        "dist": [float(v) for v in camera.dist],
        "per_view_rms": [float(v) for v in result.per_view_rms],
        "rejected": [v.to_dict() for v in rejected],
    }


def _pm(value: float, std: float | None, fixed: bool) -> str:
    if fixed:
        return f"{value:.2f} (fixed)"
    return f"{value:.2f} ± {std:.2f}" if std is not None and std > 0 else f"{value:.2f}"


def calibration_summary(
    result: CalibrationResult,
    options: CalibrationOptions,
    pattern_text: str,
    collected: str,
    rejected: Sequence[RejectedView],
    advice_lines: Sequence[str],
    out_path: str,
    coverage_path: str,
) -> str:
    """The readable summary printed without ``--json``."""
    camera = result.camera
    std = result.std_intrinsics
    s = (lambda i: float(std[i])) if std is not None else (lambda i: None)
    per_view = result.per_view_rms
    model = "fisheye (k1..k4)" if result.fisheye else "pinhole (k1, k2, p1, p2, k3)"
    lines = [
        f"calibrated a {model} camera from {len(result.view_names)} views: {pattern_text}; {collected}",
        f"  RMS reprojection error  {result.rms:.4f} px  "
        f"(per view {per_view.min():.3f} .. {per_view.max():.3f}, median {np.median(per_view):.3f})",
        (
            f"  fx = fy {_pm(camera.fy, s(1), False)}   (aspect ratio fixed)"
            if options.fix_aspect
            else f"  fx {_pm(camera.fx, s(0), False)}   fy {_pm(camera.fy, s(1), False)}"
        ),
        f"  cx {_pm(camera.cx, s(2), options.fix_principal_point)}   "
        f"cy {_pm(camera.cy, s(3), options.fix_principal_point)}",
        "  dist "
        + "  ".join(f"{name} {value:+.5f}" for name, value in _dist_names(camera.dist, result.fisheye)),
    ]
    fixed = options.fixed_descriptions()
    if fixed:
        lines.append("  held fixed: " + ", ".join(fixed))
    missing = [v.name for v in rejected if not v.reason.startswith("outlier")]
    if missing:
        lines.append(f"  no board in {len(missing)} picture(s): {_names(missing)}")
    lines.append(f"wrote {out_path}")
    lines.append(f"wrote {coverage_path} (where on the sensor board points were seen)")
    if advice_lines:
        lines.append("advice:")
        lines.extend(f"  - {line}" for line in advice_lines)
    else:
        lines.append("advice: none, the views cover the sensor well and fit the model")
    return "\n".join(lines)


def _dist_names(dist: np.ndarray, fisheye: bool) -> list[tuple[str, float]]:
    names = ["k1", "k2", "k3", "k4"] if fisheye else ["k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"]
    return [(names[i] if i < len(names) else f"d{i}", float(v)) for i, v in enumerate(dist)]


def check_json(
    names: Sequence[str],
    per_view: np.ndarray,
    rms: float,
    rejected: Sequence[RejectedView],
    calib_rms: float | None,
) -> dict:
    """The ``check --json`` object."""
    return {
        "views_used": len(names),
        "rms_px": float(rms),
        "calibration_rms_px": None if calib_rms is None else float(calib_rms),
        "per_view_rms": [float(v) for v in per_view],
        "rejected": [v.to_dict() for v in rejected],
    }


def check_summary(
    calib_path: str,
    names: Sequence[str],
    per_view: np.ndarray,
    rms: float,
    rejected: Sequence[RejectedView],
    calib_rms: float | None,
    collected: str,
) -> str:
    """The readable summary of ``check``, with a verdict."""
    lines = [
        f"checked {calib_path} against {len(names)} views ({collected})",
        f"  RMS reprojection error  {rms:.4f} px  (per view {per_view.min():.3f} .. {per_view.max():.3f})"
        + (f"; the calibration's own: {calib_rms:.4f} px" if calib_rms else ""),
    ]
    if rejected:
        lines.append(f"  no board in {len(rejected)} picture(s): {_names([v.name for v in rejected])}")
    median = float(np.median(per_view))
    worst = [
        (n, e)
        for n, e in zip(names, per_view, strict=True)
        if e > max(HIGH_VIEW_RATIO * median, HIGH_VIEW_FLOOR_PX)
    ]
    for name, err in sorted(worst, key=lambda item: -item[1])[:3]:
        lines.append(f"  view {name} has {err:.2f} px RMS, {err / median:.1f}x the median")
    if rms > HIGH_RMS_PX or (calib_rms and rms > 3.0 * calib_rms and rms > 0.5):
        lines.append(
            "verdict: the calibration does not fit these pictures well: was the lens refocused or zoomed, "
            "the resolution changed, or the board described differently?"
        )
    else:
        lines.append("verdict: the calibration fits these pictures")
    return "\n".join(lines)
