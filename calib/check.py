"""How well a calibration fits another set of board pictures.

Each view's board pose is solved with the calibration's intrinsics held fixed (planar PnP, IPPE,
then Levenberg-Marquardt on the pixel error for the pinhole model), and the points are reprojected.
Only six pose parameters per view are fitted, so an error near the calibration's own RMS means
the intrinsics carry over to these pictures; a much larger one means they do not (refocused or
zoomed lens, another resolution, another camera).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.calib.calibrate import reprojection_rms
from dronekey.calib.errors import CalibInputError
from dronekey.calib.views import BoardView
from dronekey.geometry.camera import CalibrationError, CameraModel

__all__ = ["CheckResult", "check_views"]


@dataclass(frozen=True)
class CheckResult:
    """Reprojection error of each view (pixels) and overall (RMS over all points)."""

    names: tuple[str, ...]
    per_view_rms: np.ndarray
    rms: float


def _solve_pose(
    view: BoardView, K: np.ndarray, dist: np.ndarray, fisheye: bool
) -> tuple[np.ndarray, np.ndarray]:
    obj = np.asarray(view.object_points, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(view.image_points, dtype=np.float64).reshape(-1, 2)
    if fisheye:
        ok, rvec, tvec = cv2.fisheye.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
    else:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
        if ok:
            rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, dist, rvec, tvec)
    if not ok:
        raise CalibInputError("PnP failed on a board view (degenerate points)")
    return rvec, tvec


def check_views(
    camera: CameraModel,
    fisheye: bool,
    views: Sequence[BoardView],
    names: Sequence[str],
    image_size: tuple[int, int],
) -> CheckResult:
    """Reproject ``views`` (seen at ``image_size`` = (width, height)) through ``camera``.

    A calibration made at another resolution of the same aspect ratio is scaled to this one first.

    Raises
    ------
    CalibInputError
        No views, or the resolution cannot be matched.
    """
    if not views:
        raise CalibInputError("no board views to check")
    try:
        camera = camera.scaled_to(*image_size)
    except CalibrationError as exc:
        raise CalibInputError(str(exc)) from None
    per_view = []
    for view in views:
        rvec, tvec = _solve_pose(view, camera.K, camera.dist, fisheye)
        per_view.append(reprojection_rms(view, rvec, tvec, camera.K, camera.dist, fisheye))
    per_view = np.asarray(per_view)
    counts = np.array([len(v) for v in views], dtype=np.float64)
    rms = float(np.sqrt(np.sum(per_view**2 * counts) / np.sum(counts)))
    return CheckResult(tuple(names), per_view, rms)
