"""Planar PnP: the two IPPE solutions for four coplanar keypoints, refined, and one's covariance.

``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE)`` on the undistorted keypoints returns the two poses
that planar (4 coplanar points) PnP cannot tell apart well; a solution IPPE puts behind the camera
is replaced by its point reflection, which is in front and has the same image. Both are refined
with Levenberg-Marquardt on the *distorted* pixels, where the keypoint noise lives. The covariance
of [t, rotation vector] propagates isotropic keypoint noise to first order. Which solution to
keep is :class:`~dronekey.perception.pose.PoseEstimator`'s business.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.types import PoseRejection, RejectionCode

__all__ = ["PlanarPnP", "PnPCandidate"]

log = logging.getLogger(__name__)

_LM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-10)
# Central differences of the covariance Jacobian: step of the rotation vector (rad); the translation
# step is the same times max(1 m, range).
_STEP_ROTATION_RAD = 1e-6
_SIGNED_AXES = np.concatenate([np.eye(3), -np.eye(3)])
_SMALL_ROTATIONS = np.stack([cv2.Rodrigues(_STEP_ROTATION_RAD * a)[0] for a in _SIGNED_AXES])


@dataclass(frozen=True, slots=True)
class PnPCandidate:
    """One PnP solution: body (FRD) -> camera rotation R, body origin t (m, camera frame)."""

    R: np.ndarray
    t: np.ndarray
    sq_error_px2: float  # sum over keypoints of the squared reprojection distance

    @property
    def rms_px(self) -> float:
        return math.sqrt(self.sq_error_px2 / 4.0)


class PlanarPnP:
    """IPPE and its covariance for one set of coplanar body points seen by one camera.

    Parameters
    ----------
    camera : CameraModel
        Intrinsics at the resolution of the keypoints (full-frame pixels).
    points_body : (4, 3) float64 array
        The keypoints in the body frame (m), coplanar (checked by the caller).
    """

    def __init__(self, camera: CameraModel, points_body: np.ndarray) -> None:
        self.camera = camera
        self._X = points_body
        _, _, Vt = np.linalg.svd(points_body - points_body.mean(axis=0))
        self._plane_mirror = np.eye(3) - 2.0 * np.outer(Vt[2], Vt[2])  # reflection about the hub plane

    def solve(self, uv: np.ndarray, refine: bool) -> list[PnPCandidate] | PoseRejection:
        """Both IPPE solutions for the distorted keypoints ``uv`` (4, 2), each in front of the
        camera on average, refined with LM when ``refine``; a rejection when no finite one exists."""
        try:
            und = self.camera.undistort_points(uv)
        except cv2.error as exc:
            return PoseRejection(RejectionCode.SOLVER_FAILED, f"undistortPoints failed: {exc.err}")
        if not np.all(np.isfinite(und)):
            return PoseRejection(RejectionCode.NON_FINITE, "undistortion of the keypoints gave NaN or inf")
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                self._X, np.ascontiguousarray(und), self.camera.K, None, flags=cv2.SOLVEPNP_IPPE
            )
        except cv2.error as exc:
            return PoseRejection(RejectionCode.SOLVER_FAILED, f"solvePnPGeneric(IPPE) failed: {exc.err}")
        if n < 1:
            return PoseRejection(RejectionCode.SOLVER_FAILED, "solvePnPGeneric(IPPE) returned no solution")
        candidates = []
        for rvec, tvec in zip(rvecs, tvecs, strict=True):
            rvec, tvec = rvec.reshape(3, 1).copy(), tvec.reshape(3, 1).copy()
            if np.mean((self._X @ cv2.Rodrigues(rvec)[0].T + tvec.ravel())[:, 2]) < 0.0:
                rvec, tvec = self._mirrored(rvec, tvec)
            if refine:
                try:
                    rvec, tvec = cv2.solvePnPRefineLM(
                        self._X, uv, self.camera.K, self.camera.dist, rvec, tvec, _LM_CRITERIA
                    )
                except cv2.error as exc:
                    log.debug("solvePnPRefineLM failed, keeping the IPPE solution: %s", exc.err)
            if not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
                continue
            R = cv2.Rodrigues(rvec)[0]
            t = tvec.ravel()
            proj = self.camera.project_body(self._X, R, t)
            candidates.append(PnPCandidate(R, t, float(np.sum((proj - uv) ** 2))))
        if not candidates:
            return PoseRejection(RejectionCode.SOLVER_FAILED, "PnP gave no finite solution")
        return candidates

    def _mirrored(self, rvec: np.ndarray, tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pose whose keypoints are the point reflection through the camera centre of (rvec, tvec)'s.

        Points P and -P have the same image, and for a planar target -P is again a rigid pose:
        with M the reflection about the hub plane (M X = X on the plane), -(R X + t) = R' X + t' with
        R' = -R M (det +1) and t' = -t - R (I - M) c, c the plane's centroid. IPPE can return the
        behind-camera branch when noise makes the quadrilateral inconsistent with a planar target in
        front of the camera (typically concave); its reflection is in front with the same
        reprojection error and refinement takes it from there.
        """
        R = cv2.Rodrigues(rvec)[0]
        R_front = -R @ self._plane_mirror
        t_front = -tvec.ravel() - R @ (np.eye(3) - self._plane_mirror) @ self._X.mean(axis=0)
        return cv2.Rodrigues(R_front)[0], t_front.reshape(3, 1)

    def covariance(self, c: PnPCandidate, keypoint_sigma_px: float) -> np.ndarray | None:
        """First-order covariance of [t, rotation vector] (camera frame) from isotropic pixel noise
        of ``keypoint_sigma_px`` per coordinate; None when the pose is not observable.

        The residuals r = project(exp([d_theta]x) R X + t + d_t) - uv live in distorted pixels; the
        Jacobian J (8 x 6) over (d_t, d_theta) is taken by central differences, the pose perturbed
        on the left so that d_theta is a rotation vector in the camera frame. Gauss-Newton gives
        cov = sigma^2 (J^T J)^-1. It describes one solution's basin; it knows nothing of the IPPE
        ambiguity (the other solution is a separate hypothesis, ``alternative``).
        """
        RX = self._X @ c.R.T  # (4, 3) body points rotated into the camera frame
        h_t = _STEP_ROTATION_RAD * max(1.0, float(np.linalg.norm(c.t)))
        shifted = RX[None] + c.t + h_t * _SIGNED_AXES[:, None, :]  # (6, 4, 3): +x +y +z -x -y -z
        turned = np.einsum("sij,kj->ski", _SMALL_ROTATIONS, RX) + c.t  # (6, 4, 3)
        proj = self.camera.project(np.concatenate([shifted, turned]).reshape(-1, 3)).reshape(2, 2, 3, 8)
        d_t = (proj[0, 0] - proj[0, 1]) / (2.0 * h_t)  # (3, 8): d residuals / d t_i
        d_r = (proj[1, 0] - proj[1, 1]) / (2.0 * _STEP_ROTATION_RAD)
        J = np.concatenate([d_t, d_r]).T  # (8, 6)
        info = J.T @ J
        eig = np.linalg.eigvalsh(info)
        if not np.all(np.isfinite(eig)) or eig[0] <= 1e-12 * eig[-1]:
            return None
        cov = np.linalg.inv(info) * keypoint_sigma_px**2
        return 0.5 * (cov + cov.T)
