"""Error-state (multiplicative) Kalman filter on a 3D orientation with a (damped) angular velocity.

Filtering a rotation with a linear Kalman filter on Euler angles or quaternion components jumps at
+-180 deg and at quaternion sign flips. Here the orientation is split into a reference rotation
``R_ref`` (body -> camera, a matrix, so there is no sign ambiguity) and a small error
``d_theta`` on the right, ``R = R_ref exp([d_theta]x)``, i.e. a rotation vector in the body frame.
A filterpy Kalman filter runs on x = [d_theta (3, rad), omega (3, rad/s)] with omega the body
angular velocity:

- predict: d_theta += omega dt (constant angular velocity), process noise from a white angular
  acceleration of standard deviation ``angular_accel_std_radps2`` (filterpy's discrete model); or,
  with a time constant ``tau`` (``angular_velocity_tau_s``), omega relaxes toward zero as a
  first-order Gauss-Markov process, ``omega <- a omega`` with ``a = exp(-dt / tau)`` and
  ``d_theta += tau (1 - a) omega``: a drone does not keep spinning, so a run of poor rotation
  readings cannot wind up an angular velocity that then turns the track on its own (the process
  noise keeps the white-acceleration model, close for steps much shorter than ``tau``);
- measurement R_meas: z = log(R_ref^T R_meas), a rotation vector that stays small while the filter
  follows the drone, whatever the absolute angles are;
- after each predict and update the error is folded into the reference,
  ``R_ref <- R_ref exp([d_theta]x)``, ``d_theta <- 0`` (the covariance is kept as it is: the reset
  Jacobian is the identity to first order, the usual MEKF approximation).

Measurement covariances arrive as rotation vectors in the camera frame (left perturbation,
``exp([e]x) R``); the body-frame equivalent is ``R^T C R``.
"""

from __future__ import annotations

import cv2
import numpy as np
from filterpy.kalman import KalmanFilter

from dronekey.tracking.motion_model import transition, white_noise_acceleration

__all__ = ["OrientationFilter", "rotation_exp", "rotation_log"]

_H = np.hstack([np.eye(3), np.zeros((3, 3))])


def rotation_exp(rotvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (rad)."""
    return cv2.Rodrigues(np.asarray(rotvec, dtype=np.float64).reshape(3, 1))[0]


def rotation_log(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad, norm in [0, pi]) of a rotation matrix."""
    return cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel()


class OrientationFilter:
    """Orientation and angular velocity of one target from rotation measurements.

    Parameters
    ----------
    R : (3, 3) first measured body -> camera rotation.
    rotation_cov_cam : (3, 3) its covariance as a camera-frame rotation vector, rad^2.
    angular_velocity_std_radps : prior standard deviation of each angular velocity component.
    angular_accel_std_radps2 : standard deviation of the white angular acceleration.
    angular_velocity_tau_s : time constant (s) with which the angular velocity relaxes toward zero;
        0 (the default): none, constant angular velocity.
    """

    def __init__(
        self,
        R: np.ndarray,
        rotation_cov_cam: np.ndarray,
        angular_velocity_std_radps: float,
        angular_accel_std_radps2: float,
        angular_velocity_tau_s: float = 0.0,
    ) -> None:
        if not angular_velocity_tau_s >= 0.0:
            raise ValueError(f"angular_velocity_tau_s must be >= 0 s, got {angular_velocity_tau_s!r}")
        self.angular_accel_std_radps2 = float(angular_accel_std_radps2)
        self.angular_velocity_tau_s = float(angular_velocity_tau_s)
        self._R_ref = np.asarray(R, dtype=np.float64).copy()
        self._rotation: np.ndarray | None = None  # ``rotation``, until the state next changes
        self._kf = KalmanFilter(dim_x=6, dim_z=3)
        self._kf.x = np.zeros(6)
        P = np.zeros((6, 6))
        P[:3, :3] = self._to_body(rotation_cov_cam)
        P[3:, 3:] = angular_velocity_std_radps**2 * np.eye(3)
        self._kf.P = P
        self._kf.H = _H

    # ------------------------------------------------------------------ state
    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) body -> camera rotation (computed once per state: a track reads it many times a
        frame)."""
        if self._rotation is None:
            self._rotation = self._R_ref @ rotation_exp(self._kf.x[:3])
        return self._rotation.copy()

    @property
    def angular_velocity_body_radps(self) -> np.ndarray:
        return self._kf.x[3:].copy()

    @property
    def covariance_body(self) -> np.ndarray:
        """(6, 6) covariance of [d_theta, omega], body frame."""
        return self._kf.P.copy()

    @property
    def rotation_cov_cam(self) -> np.ndarray:
        """(3, 3) orientation covariance as a camera-frame rotation vector, rad^2."""
        R = self.rotation
        return R @ self._kf.P[:3, :3] @ R.T

    # ------------------------------------------------------------------ filter
    def _to_body(self, cov_cam: np.ndarray) -> np.ndarray:
        return self._R_ref.T @ np.asarray(cov_cam, dtype=np.float64) @ self._R_ref

    def _process_noise(self, dt: float) -> np.ndarray:
        return white_noise_acceleration(dt, self.angular_accel_std_radps2**2)

    def _recentre(self) -> None:
        """Fold the error into the reference; every change of the state (predict, update) ends here."""
        self._R_ref = self._R_ref @ rotation_exp(self._kf.x[:3])
        self._kf.x[:3] = 0.0
        self._rotation = None  # the state has just changed

    def predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Body -> camera rotation after ``dt`` seconds and its covariance (camera-frame rotation
        vector, rad^2), without changing the filter."""
        dt = max(dt, 0.0)
        F = transition(dt, self.angular_velocity_tau_s)
        R = self._R_ref @ rotation_exp((F @ self._kf.x)[:3])
        P = F @ self._kf.P @ F.T + (self._process_noise(dt) if dt > 0.0 else 0.0)
        return R, R @ P[:3, :3] @ R.T

    def predict(self, dt: float) -> None:
        """Advance the state by ``dt`` seconds (no-op for dt <= 0)."""
        if dt > 0.0:
            self._kf.predict(F=transition(dt, self.angular_velocity_tau_s), Q=self._process_noise(dt))
            self._recentre()

    def innovation(self, R_meas: np.ndarray, rotation_cov_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Innovation log(R^T R_meas) (body rotation vector, rad) and its covariance S."""
        y = rotation_log(self.rotation.T @ np.asarray(R_meas, dtype=np.float64))
        return y, self._kf.P[:3, :3] + self._to_body(rotation_cov_cam)

    def mahalanobis_sq(self, R_meas: np.ndarray, rotation_cov_cam: np.ndarray) -> float:
        """Squared Mahalanobis distance of the innovation, chi-square with 3 dof under the model."""
        y, S = self.innovation(R_meas, rotation_cov_cam)
        return float(y @ np.linalg.solve(S, y))

    def update(self, R_meas: np.ndarray, rotation_cov_cam: np.ndarray) -> None:
        self._recentre()
        z = rotation_log(self._R_ref.T @ np.asarray(R_meas, dtype=np.float64))
        self._kf.update(z, R=self._to_body(rotation_cov_cam))
        self._recentre()
