"""Intrinsics from board views: OpenCV's pinhole or fisheye calibration, with outlier views dropped.

Pixel coordinates follow docs/design.md §4 (origin at the top-left pixel's centre), so "the image centre"
is ((w - 1) / 2, (h - 1) / 2). That is where the installed OpenCV (5.0) puts a principal point fixed
without a guess; older releases used (w / 2, h / 2) (the vendored reference calibration of
tests/data/calib-real has (320, 256) for 640 x 512), which ``principal_point`` reproduces.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from dronekey.calib.errors import CalibInputError
from dronekey.calib.views import BoardView, RejectedView
from dronekey.geometry.camera import CameraModel

__all__ = [
    "MIN_VIEWS",
    "CalibrationOptions",
    "CalibrationResult",
    "calibrate",
    "calibrate_rejecting_outliers",
    "default_max_view_rms",
    "reprojection_rms",
]

#: Fewest views a calibration accepts; a good one has 15 to 40 (see the advice in report.py).
MIN_VIEWS = 5

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, np.finfo(float).eps)
_FISHEYE_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass(frozen=True)
class CalibrationOptions:
    """Which parameters the calibration holds fixed (the CLI's ``--fix-*`` flags).

    Parameters
    ----------
    fix_aspect : bool
        Keep fx / fy at 1 (square pixels). Pinhole only.
    fix_principal_point : bool
        Keep (cx, cy) at the image centre, or at ``principal_point`` if given.
    principal_point : (float, float), optional
        Where to fix the principal point, pixels; needs ``fix_principal_point``.
    zero_tangent : bool
        p1 = p2 = 0. Pinhole only.
    fix_k3, fix_k4, fix_k5 : bool
        Hold that radial coefficient at 0. The pinhole model here has k1, k2, p1, p2, k3, so
        ``fix_k4`` / ``fix_k5`` only restate it (OpenCV's sample sets them; they appear in ``flags``).
        The fisheye model has k1..k4 and no k5.
    fisheye : bool
        Use OpenCV's fisheye (equidistant, Kannala-Brandt) model instead of the pinhole one.
    """

    fix_aspect: bool = False
    fix_principal_point: bool = False
    principal_point: tuple[float, float] | None = None
    zero_tangent: bool = False
    fix_k3: bool = False
    fix_k4: bool = False
    fix_k5: bool = False
    fisheye: bool = False

    def __post_init__(self) -> None:
        if self.principal_point is not None:
            if not self.fix_principal_point:
                raise CalibInputError("--principal-point needs --fix-principal-point")
            if not all(math.isfinite(v) for v in self.principal_point):
                raise CalibInputError(f"--principal-point must be finite, got {self.principal_point}")
        if self.fisheye:
            for flag, name in (
                (self.fix_aspect, "--fix-aspect"),
                (self.zero_tangent, "--zero-tangent"),
                (self.fix_k5, "--fix-k5"),
            ):
                if flag:
                    raise CalibInputError(
                        f"{name} does not apply to --fisheye (its model is fx, fy, cx, cy, k1..k4)"
                    )

    def opencv_flags(self) -> int:
        """The ``flags`` argument of ``cv2.calibrateCamera`` / ``cv2.fisheye.calibrate``."""
        flags = 0
        if self.fix_principal_point:
            flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
        if self.fix_k3:
            flags |= cv2.CALIB_FIX_K3
        if self.fix_k4:
            flags |= cv2.CALIB_FIX_K4
        if self.fisheye:
            return flags | cv2.CALIB_RECOMPUTE_EXTRINSIC | cv2.CALIB_FIX_SKEW
        if self.fix_aspect:
            flags |= cv2.CALIB_FIX_ASPECT_RATIO
        if self.zero_tangent:
            flags |= cv2.CALIB_ZERO_TANGENT_DIST
        if self.fix_k5:
            flags |= cv2.CALIB_FIX_K5
        return flags

    def fixed_descriptions(self) -> list[str]:
        """Plain-words list of what is held fixed, for the summary."""
        words = []
        if self.fix_aspect:
            words.append("aspect ratio fx/fy = 1")
        if self.fix_principal_point:
            where = (
                "the image centre"
                if self.principal_point is None
                else "({:g}, {:g})".format(*self.principal_point)
            )
            words.append(f"principal point at {where}")
        if self.zero_tangent:
            words.append("zero tangential distortion")
        fixed_k = [k for k, flag in (("k3", self.fix_k3), ("k4", self.fix_k4), ("k5", self.fix_k5)) if flag]
        if fixed_k:
            words.append(" = ".join(fixed_k) + " = 0")
        return words


@dataclass(frozen=True)
class CalibrationResult:
    """A calibration and how well each view fits it.

    Attributes
    ----------
    camera : CameraModel
        Intrinsics; ``dist`` is (k1, k2, p1, p2, k3) for the pinhole model and (k1, k2, k3, k4) for
        the fisheye model. ``camera.rms_px`` is the overall RMS reprojection error.
    fisheye : bool
        Which model ``camera.dist`` belongs to.
    flags : int
        OpenCV flags used.
    view_names : tuple of str
        One name per view used (file name, or ``video#frame``).
    per_view_rms : (N,) array
        RMS reprojection error of each view, pixels.
    rvecs, tvecs : (N, 3) arrays
        Board pose in the camera frame per view (Rodrigues vector, metres).
    std_intrinsics : (9,) array or None
        Standard deviations of (fx, fy, cx, cy, k1, k2, p1, p2, k3) (pinhole only); 0 where fixed.
    """

    camera: CameraModel
    fisheye: bool
    flags: int
    view_names: tuple[str, ...]
    per_view_rms: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    std_intrinsics: np.ndarray | None = None
    image_points: tuple[np.ndarray, ...] = field(default=(), repr=False)

    @property
    def rms(self) -> float:
        return float(self.camera.rms_px)

    def tilt_deg(self) -> np.ndarray:
        """Angle between each board's normal and the optical axis, degrees (0 = facing the camera)."""
        tilts = []
        for rvec in self.rvecs:
            R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
            tilts.append(math.degrees(math.acos(min(1.0, abs(R[2, 2])))))
        return np.asarray(tilts)


def _as_cv_lists(views: Sequence[BoardView], fisheye: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per-view object and image point arrays in the shapes OpenCV 5's calibrators accept.

    ``cv2.calibrateCamera`` takes (N, 1, 3) float32; ``cv2.fisheye.calibrate`` fails on (N, 1, 3)
    with a size-mismatch error and needs (1, N, 3) float64.
    """
    dtype, shape3, shape2 = (
        (np.float64, (1, -1, 3), (1, -1, 2)) if fisheye else (np.float32, (-1, 1, 3), (-1, 1, 2))
    )
    objs = [np.ascontiguousarray(v.object_points, dtype=dtype).reshape(shape3) for v in views]
    imgs = [np.ascontiguousarray(v.image_points, dtype=dtype).reshape(shape2) for v in views]
    return objs, imgs


def reprojection_rms(
    view: BoardView, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray, dist: np.ndarray, fisheye: bool
) -> float:
    """RMS distance (pixels) between a view's points and their projection through a pose and intrinsics."""
    obj = np.asarray(view.object_points, dtype=np.float64).reshape(-1, 1, 3)
    rvec = np.asarray(rvec, dtype=np.float64).reshape(3, 1)
    tvec = np.asarray(tvec, dtype=np.float64).reshape(3, 1)
    if fisheye:
        projected, _ = cv2.fisheye.projectPoints(obj, rvec, tvec, K, dist)
    else:
        projected, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
    diff = projected.reshape(-1, 2) - np.asarray(view.image_points, dtype=np.float64).reshape(-1, 2)
    return float(np.sqrt(np.mean(np.sum(diff * diff, axis=1))))


def calibrate(
    views: Sequence[BoardView],
    names: Sequence[str],
    image_size: tuple[int, int],
    options: CalibrationOptions,
) -> CalibrationResult:
    """Calibrate from ``views`` seen in images of ``image_size`` = (width, height) pixels.

    Raises
    ------
    CalibInputError
        Fewer than ``MIN_VIEWS`` views, or OpenCV could not solve (degenerate views).
    """
    if len(views) != len(names):
        raise ValueError(f"views and names differ in length: {len(views)} != {len(names)}")
    if len(views) < MIN_VIEWS:
        raise CalibInputError(
            f"too few views: {len(views)} usable, calibration needs at least {MIN_VIEWS} "
            "(15 or more is better)"
        )
    width, height = int(image_size[0]), int(image_size[1])
    objs, imgs = _as_cv_lists(views, options.fisheye)
    flags = options.opencv_flags()
    std = None
    try:
        if options.fisheye:
            K0, flags = _fisheye_initial_guess(options, flags, width, height)
            _, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
                objs, imgs, (width, height), K0, np.zeros(4), flags=flags, criteria=_FISHEYE_CRITERIA
            )
        else:
            K0 = None
            if options.principal_point is not None:
                K0 = cv2.initCameraMatrix2D(objs, imgs, (width, height), 1.0 if options.fix_aspect else 0.0)
                K0[0, 2], K0[1, 2] = options.principal_point
                flags |= cv2.CALIB_USE_INTRINSIC_GUESS
            _, K, dist, rvecs, tvecs, std_intr, _, _ = cv2.calibrateCameraExtended(
                objs, imgs, (width, height), K0, None, flags=flags, criteria=_CRITERIA
            )
            std = np.asarray(std_intr, dtype=np.float64).ravel()[:9]
    except cv2.error as exc:
        reason = (exc.err or str(exc)).strip().splitlines()[0]
        raise CalibInputError(f"OpenCV could not calibrate from these {len(views)} views: {reason}") from None
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    rvecs = np.asarray(rvecs, dtype=np.float64).reshape(-1, 3)
    tvecs = np.asarray(tvecs, dtype=np.float64).reshape(-1, 3)
    per_view = np.array(
        [
            reprojection_rms(v, r, t, K, dist, options.fisheye)
            for v, r, t in zip(views, rvecs, tvecs, strict=True)
        ]
    )
    counts = np.array([len(v) for v in views], dtype=np.float64)
    rms = float(np.sqrt(np.sum(per_view**2 * counts) / np.sum(counts)))
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and math.isfinite(rms)):
        raise CalibInputError(f"calibration diverged (non-finite result) on these {len(views)} views")
    camera = CameraModel(width, height, K, dist, rms)
    return CalibrationResult(
        camera=camera,
        fisheye=options.fisheye,
        flags=int(flags),
        view_names=tuple(names),
        per_view_rms=per_view,
        rvecs=rvecs,
        tvecs=tvecs,
        std_intrinsics=std,
        image_points=tuple(np.asarray(v.image_points) for v in views),
    )


def _fisheye_initial_guess(
    options: CalibrationOptions, flags: int, width: int, height: int
) -> tuple[np.ndarray, int]:
    """Initial K for the fisheye model; only needed to place a fixed principal point off-centre."""
    if options.principal_point is None:
        return np.eye(3), flags
    f = max(width, height) / math.pi  # what cv2.fisheye.calibrate starts from without a guess
    K0 = np.array(
        [[f, 0.0, options.principal_point[0]], [0.0, f, options.principal_point[1]], [0.0, 0.0, 1.0]]
    )
    return K0, flags | cv2.CALIB_USE_INTRINSIC_GUESS


def default_max_view_rms(per_view_rms: np.ndarray) -> float:
    """Outlier threshold for a view's RMS: three times the median, and never below 1 px."""
    return max(3.0 * float(np.median(per_view_rms)), 1.0)


def calibrate_rejecting_outliers(
    views: Sequence[BoardView],
    names: Sequence[str],
    image_size: tuple[int, int],
    options: CalibrationOptions,
    max_view_rms: float | None = None,
) -> tuple[CalibrationResult, list[RejectedView]]:
    """Calibrate, drop views whose RMS exceeds the threshold, and calibrate again once.

    A mis-ordered or mis-detected view (a flipped grid, a board bent in the wind) pulls every
    parameter; one pass of rejection removes it without eroding a good set. The threshold is
    ``max_view_rms`` pixels, or ``default_max_view_rms`` of the first pass. Views are only dropped
    while at least ``MIN_VIEWS`` remain.
    """
    first = calibrate(views, names, image_size, options)
    threshold = default_max_view_rms(first.per_view_rms) if max_view_rms is None else float(max_view_rms)
    bad = np.flatnonzero(first.per_view_rms > threshold)
    if bad.size == 0 or len(views) - bad.size < MIN_VIEWS:
        return first, []
    keep = [i for i in range(len(views)) if i not in set(bad.tolist())]
    rejected = [
        RejectedView(names[i], f"outlier: {first.per_view_rms[i]:.2f} px RMS > {threshold:.2f} px")
        for i in bad
    ]
    second = calibrate([views[i] for i in keep], [names[i] for i in keep], image_size, options)
    return second, rejected
