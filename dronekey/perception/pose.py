"""6DoF pose of a drone from its four propeller keypoints (docs/design.md §3 PoseEstimator, paper §III-D).

The pose follows docs/design.md §4: ``p_cam = R @ p_body + t`` with R the body (FRD) -> camera (OpenCV)
rotation and t the body origin (centroid of the hubs) in the camera frame, metres.

Pipeline of :meth:`PoseEstimator.estimate`:

1. validate the keypoints (shape, finite, inside the frame give or take a margin, no near-duplicate
   or collinear points);
2. undistort them with the camera model and solve ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)``,
   which returns the two poses that planar (4 coplanar points) PnP cannot tell apart well; a
   solution IPPE puts behind the camera is replaced by its point reflection, which is in front
   and has the same image;
3. refine both with Levenberg-Marquardt on the *distorted* pixels, where the keypoint noise lives;
4. drop solutions with a keypoint behind the camera; reject keypoints whose quadrilateral crosses
   itself when no pose explains them within noise (swapped keypoints); then choose: with a prior
   (the tracker's prediction), the solution nearest to it in rotation unless the data clearly
   favour the other; without one, the lower reprojection error. The other solution is kept as
   ``alternative``;
5. propagate the keypoint noise to a 6x6 covariance of [t, rotation vector] in the camera frame.

Steps 2, 3 and 5 are :class:`~dronekey.perception.planar_pnp.PlanarPnP`; ``method="paper"`` forms
the rotation with the paper's construction (:mod:`dronekey.perception.paper_frame`). See
docs/pose-and-tracking.md for the reasoning and measured behaviour.

Bad data never raises: :meth:`PoseEstimator.estimate` returns a
:class:`~dronekey.types.PoseRejection` with a reason.
"""

from __future__ import annotations

import logging
import math
from enum import StrEnum

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec
from dronekey.perception.paper_frame import paper_basis_in_body, paper_frame
from dronekey.perception.planar_pnp import PlanarPnP, PnPCandidate
from dronekey.types import PoseMeasurement, PoseRejection, RejectionCode

__all__ = ["PoseEstimator", "PoseMethod"]

log = logging.getLogger(__name__)

# Chi-square, 2 degrees of freedom (8 residuals - 6 pose parameters), 99.9 %: the largest summed
# squared reprojection error, in keypoint_sigma_px^2, that noise explains.
_CROSSED_CHI2 = 13.8


class PoseMethod(StrEnum):
    """How the rotation is formed from the PnP solution.

    IPPE: R and t straight from IPPE (+ refinement).
    PAPER: the paper's construction (centroid, v1 = Y2 - YO, v2 = Y3 - YO, v3 = v1 x v2,
    orthonormalised), mapped back to the FRD body frame; see
    :func:`~dronekey.perception.paper_frame.paper_basis_in_body`.
    """

    IPPE = "ippe"
    PAPER = "paper"


def _cross2(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """z of (a - o) x (b - o): > 0 when o -> a -> b turns counter-clockwise (x right, y up)."""
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def _segments_cross(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> bool:
    """True when the segments p1-p2 and q1-q2 properly cross (each separates the other's ends)."""
    return _cross2(p1, p2, q1) * _cross2(p1, p2, q2) < 0.0 and _cross2(q1, q2, p1) * _cross2(q1, q2, p2) < 0.0


def _quad_is_crossed(points: np.ndarray) -> bool:
    """True when the quadrilateral 1-2-3-4 (4, 2) is self-intersecting (a 'bow tie')."""
    p = points
    return _segments_cross(p[0], p[1], p[2], p[3]) or _segments_cross(p[1], p[2], p[3], p[0])


class PoseEstimator:
    """Planar PnP for one drone model seen by one calibrated camera.

    Parameters
    ----------
    camera : CameraModel
        Intrinsics at the resolution of the keypoints (full-frame pixels).
    spec : DroneSpec
        The drone's propeller hubs in the FRD body frame; they must be coplanar (IPPE).
    keypoint_sigma_px : float
        Standard deviation of each keypoint coordinate (px), isotropic and independent; sets the
        measurement covariance and the ambiguity test.
    method : "ippe" or "paper"
        See :class:`PoseMethod`.
    refine : bool
        Refine both IPPE solutions with ``cv2.solvePnPRefineLM`` on the distorted pixels.
    frame_margin_frac : float
        Keypoints may lie outside the image by this fraction of its larger side (a propeller at the
        edge); further out they are rejected (and the distortion model is not trusted there).
    min_separation_px : float
        Two keypoints closer than this are treated as one (rejected).
    min_aspect : float
        Ratio of the smallest to the largest singular value of the centred keypoints below which
        they count as collinear (an edge-on drone; about sin(elevation) of the view).
    check_order : bool
        Reject keypoints whose quadrilateral in spec order crosses itself (a "bow tie") unless the
        best pose reprojects them within noise. The hubs form a simple quadrilateral and so does
        any view of it, so a crossed one means two keypoints swapped (the pose then misfits by many
        pixels and would be about 180 deg wrong) or noise that pushed a keypoint of a small or
        oblique drone past another (the pose fits within noise and is as good as any other). The
        noise test is chi-square with 2 degrees of freedom at 99.9 %: summed squared reprojection
        error <= 13.8 keypoint_sigma_px^2.
    min_depth_m : float
        Every keypoint of a solution must be at least this far in front of the camera (z).
    ambiguity_chi2 : float
        With a prior, the prior decides between the two IPPE solutions unless their summed squared
        reprojection errors differ by more than ``ambiguity_chi2 * keypoint_sigma_px**2``; then the
        data decide (the prior may be stale).
    prior_max_offset_frac : float
        A prior whose translation is further from the solution than this fraction of the smaller of
        their two ranges (or 0.5 m, whichever is larger) is treated as belonging to something else
        and ignored.
    max_reprojection_px : float or None
        Reject solutions whose RMS reprojection error exceeds this; None disables the test.
    """

    def __init__(
        self,
        camera: CameraModel,
        spec: DroneSpec,
        keypoint_sigma_px: float = 2.0,
        *,
        method: PoseMethod | str = PoseMethod.IPPE,
        refine: bool = True,
        frame_margin_frac: float = 0.1,
        min_separation_px: float = 1.0,
        min_aspect: float = 0.01,
        check_order: bool = True,
        min_depth_m: float = 0.05,
        ambiguity_chi2: float = 9.0,
        prior_max_offset_frac: float = 0.5,
        max_reprojection_px: float | None = None,
    ) -> None:
        if not isinstance(camera, CameraModel):
            raise TypeError(f"camera must be a CameraModel, got {type(camera).__name__}")
        _require_positive("keypoint_sigma_px", keypoint_sigma_px)
        _require_non_negative("frame_margin_frac", frame_margin_frac)
        _require_non_negative("min_separation_px", min_separation_px)
        _require_non_negative("min_aspect", min_aspect)
        _require_non_negative("min_depth_m", min_depth_m)
        _require_positive("ambiguity_chi2", ambiguity_chi2)
        _require_positive("prior_max_offset_frac", prior_max_offset_frac)
        if max_reprojection_px is not None:
            _require_positive("max_reprojection_px", max_reprojection_px)
        try:
            self.method = PoseMethod(method)
        except ValueError:
            raise ValueError(
                f"method must be one of {[m.value for m in PoseMethod]}, got {method!r}"
            ) from None

        X = np.ascontiguousarray(spec.keypoints_3d, dtype=np.float64)
        sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
        if sv[2] > 1e-6 * sv[0]:
            raise ValueError(
                f"spec {spec.name!r}: keypoints_3d must be coplanar for IPPE; their out-of-plane "
                f"spread is {sv[2]:.3g} m"
            )
        _, _, Vt = np.linalg.svd(X - X.mean(axis=0))
        if check_order and _quad_is_crossed((X - X.mean(axis=0)) @ Vt[:2].T):
            raise ValueError(
                f"spec {spec.name!r}: keypoints_3d in keypoint order form a crossed quadrilateral; "
                "list them around the drone or pass check_order=False"
            )
        self.camera = camera
        self.spec = spec
        self.keypoint_sigma_px = float(keypoint_sigma_px)
        self.refine = bool(refine)
        self.frame_margin_px = float(frame_margin_frac) * max(camera.width, camera.height)
        self.min_separation_px = float(min_separation_px)
        self.min_aspect = float(min_aspect)
        self.check_order = bool(check_order)
        self.min_depth_m = float(min_depth_m)
        self.ambiguity_chi2 = float(ambiguity_chi2)
        self.prior_max_offset_frac = float(prior_max_offset_frac)
        self.max_reprojection_px = None if max_reprojection_px is None else float(max_reprojection_px)
        self._X = X
        self._pnp = PlanarPnP(camera, X)
        self._paper_B = paper_basis_in_body(spec)

    # ------------------------------------------------------------------ public
    def estimate(
        self,
        keypoints_px: np.ndarray,
        prior: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> PoseMeasurement | PoseRejection:
        """Pose of the drone from its four keypoints.

        Parameters
        ----------
        keypoints_px : (4, 2) array
            Full-frame distorted pixel coordinates in spec order.
        prior : (R (3, 3), t (3,)) or None
            Predicted pose (body -> camera, metres), e.g. from ``Tracker.predict``; used to pick
            between the two IPPE solutions.

        Returns
        -------
        PoseMeasurement or PoseRejection
            A rejection (falsy) says why no pose could be formed; nothing here raises for bad
            keypoints. A malformed ``prior`` is a programming error and raises ValueError.
        """
        prior_checked = None if prior is None else _check_prior(prior)
        uv = np.asarray(keypoints_px, dtype=np.float64) if _is_numeric(keypoints_px) else None
        if uv is None or uv.shape != (4, 2):
            shape = None if uv is None else uv.shape
            return PoseRejection(RejectionCode.BAD_SHAPE, f"keypoints_px must have shape (4, 2), got {shape}")
        problem = self._validate(uv)
        if problem is not None:
            return problem

        candidates = self._pnp.solve(uv, self.refine)
        if isinstance(candidates, PoseRejection):
            return candidates
        in_front = [c for c in candidates if self._in_front(c)]
        if not in_front:
            depths = ", ".join(f"{np.min((self._X @ c.R.T + c.t)[:, 2]):.3f}" for c in candidates)
            return PoseRejection(
                RejectionCode.BEHIND_CAMERA,
                f"every PnP solution puts a keypoint behind the camera (nearest keypoint z = {depths} m)",
            )
        best_fit = min(in_front, key=lambda c: c.sq_error_px2)
        if (
            self.check_order
            and best_fit.sq_error_px2 > _CROSSED_CHI2 * self.keypoint_sigma_px**2
            and _quad_is_crossed(uv)
        ):
            return PoseRejection(
                RejectionCode.CROSSED,
                "the keypoints in spec order form a crossed quadrilateral that no pose explains "
                f"(best reprojection {best_fit.rms_px:.1f} px RMS): two keypoints are swapped or misplaced",
            )
        chosen, other = self._choose(in_front, prior_checked)
        if self.max_reprojection_px is not None and chosen.rms_px > self.max_reprojection_px:
            return PoseRejection(
                RejectionCode.REPROJECTION,
                f"reprojection error {chosen.rms_px:.2f} px exceeds max_reprojection_px="
                f"{self.max_reprojection_px:g} (keypoints inconsistent with the drone's shape)",
            )
        covariance = self._pnp.covariance(chosen, self.keypoint_sigma_px)
        if covariance is None:
            return PoseRejection(
                RejectionCode.UNOBSERVABLE,
                "the pose is not observable from these keypoints (rank-deficient reprojection Jacobian)",
            )
        R, t = self._output_pose(chosen)
        alternative = None
        if other is not None:
            R_alt, t_alt = self._output_pose(other)
            alternative = (R_alt, t_alt, other.rms_px)
        return PoseMeasurement(
            R=R,
            t=t,
            reprojection_px=chosen.rms_px,
            covariance=covariance,
            alternative=alternative,
            method=self.method.value,
            keypoint_sigma_px=self.keypoint_sigma_px,
        )

    def reprojection_px(self, keypoints_px: np.ndarray, R: np.ndarray, t: np.ndarray) -> float:
        """RMS distance (px) between the keypoints and the spec projected through (R, t)."""
        proj = self.camera.project_body(self._X, R, t)
        return float(np.sqrt(np.mean(np.sum((proj - np.asarray(keypoints_px)) ** 2, axis=1))))

    # ------------------------------------------------------------------ steps
    def _validate(self, uv: np.ndarray) -> PoseRejection | None:
        if not np.all(np.isfinite(uv)):
            return PoseRejection(RejectionCode.NON_FINITE, f"keypoints_px holds NaN or inf: {uv.tolist()}")
        m = self.frame_margin_px
        lo = np.array([-0.5 - m, -0.5 - m])
        hi = np.array([self.camera.width - 0.5 + m, self.camera.height - 0.5 + m])
        outside = np.any((uv < lo) | (uv > hi), axis=1)
        if np.any(outside):
            k = int(np.argmax(outside))
            return PoseRejection(
                RejectionCode.OUTSIDE_FRAME,
                f"keypoint {k + 1} at ({uv[k, 0]:.1f}, {uv[k, 1]:.1f}) px is more than {m:.0f} px outside "
                f"the {self.camera.width}x{self.camera.height} frame",
            )
        d = np.linalg.norm(uv[:, None, :] - uv[None, :, :], axis=2)
        d[np.diag_indices(4)] = np.inf
        i, j = np.unravel_index(np.argmin(d), d.shape)
        if d[i, j] < self.min_separation_px:
            return PoseRejection(
                RejectionCode.DUPLICATE,
                f"keypoints {min(i, j) + 1} and {max(i, j) + 1} are {d[i, j]:.2f} px apart "
                f"(min_separation_px={self.min_separation_px:g})",
            )
        sv = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False)
        aspect = sv[1] / sv[0]
        if aspect < self.min_aspect:
            return PoseRejection(
                RejectionCode.COLLINEAR,
                f"keypoints are nearly collinear (aspect {aspect:.4f} < min_aspect={self.min_aspect:g}): "
                "the drone is seen edge-on or the points are wrong",
            )
        return None

    def _in_front(self, c: PnPCandidate) -> bool:
        return bool(np.all((self._X @ c.R.T + c.t)[:, 2] >= self.min_depth_m))

    def _choose(
        self, candidates: list[PnPCandidate], prior: tuple[np.ndarray, np.ndarray] | None
    ) -> tuple[PnPCandidate, PnPCandidate | None]:
        by_error = sorted(candidates, key=lambda c: c.sq_error_px2)
        best = by_error[0]
        other = by_error[1] if len(by_error) > 1 else None
        if other is None or prior is None:
            return best, other
        R_prior, t_prior = prior
        offset = float(np.linalg.norm(best.t - t_prior))
        limit = max(0.5, self.prior_max_offset_frac * min(np.linalg.norm(t_prior), np.linalg.norm(best.t)))
        if offset > limit:
            log.debug(
                "prior ignored: its translation is %.2f m from the solution (limit %.2f m)", offset, limit
            )
            return best, other
        margin = (other.sq_error_px2 - best.sq_error_px2) / self.keypoint_sigma_px**2
        if margin > self.ambiguity_chi2:
            return best, other  # the data are not ambiguous: the prior may be stale
        if _rotation_angle_rad(R_prior, other.R) < _rotation_angle_rad(R_prior, best.R):
            return other, best
        return best, other

    def _output_pose(self, c: PnPCandidate) -> tuple[np.ndarray, np.ndarray]:
        if self.method is PoseMethod.IPPE:
            return c.R, c.t
        # The paper (eq. 2 writes the inverse, a typo for our convention): Y_k = R Y_obj_k + t.
        Y = self._X @ c.R.T + c.t
        R_pose = paper_frame(Y)
        return R_pose @ self._paper_B.T, Y.mean(axis=0)


# ---------------------------------------------------------------------- helpers
def _rotation_angle_rad(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle of R_a^T R_b from its trace (coarse near 0, which is fine for ranking)."""
    return math.acos(min(1.0, max(-1.0, (float(np.sum(R_a * R_b)) - 1.0) / 2.0)))


def _is_numeric(a) -> bool:
    try:
        return np.asarray(a).dtype.kind in "biuf"
    except (TypeError, ValueError):
        return False


def _check_prior(prior) -> tuple[np.ndarray, np.ndarray]:
    try:
        R, t = prior
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f"prior must be (R (3, 3), t (3,)), got {prior!r}") from None
    if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError(f"prior must be finite (R (3, 3), t (3,)), got R {R.shape}, t {t.shape}")
    return R, t


def _require_positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")


def _require_non_negative(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ValueError(f"{name} must be a non-negative finite number, got {value!r}")
