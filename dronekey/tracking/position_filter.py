"""Constant-velocity Kalman filter on a 3D position (the translational half of a drone track).

State x = [p (3), v (3)]: position (m) and velocity (m/s) in the camera frame (OpenCV: x right,
y down, z forward). The time step is the real one between frames (seconds from ``t_ns``), so
dropped frames and irregular sources keep the right velocity scale. Process noise is filterpy's
discrete white-noise acceleration model: the acceleration is constant over one step, zero-mean with
standard deviation ``accel_std_mps2``, which adds ``a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` per
axis.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter

from dronekey.tracking.motion_model import transition, white_noise_acceleration

__all__ = ["ConstantVelocityFilter"]

_H = np.hstack([np.eye(3), np.zeros((3, 3))])


class ConstantVelocityFilter:
    """Position and velocity of one target from position measurements with known covariance.

    Parameters
    ----------
    position_m : (3,) first measured position, camera frame.
    position_cov : (3, 3) its covariance, m^2.
    velocity_std_mps : prior standard deviation of each velocity component (the first measurement
        says nothing about velocity).
    accel_std_mps2 : standard deviation of the white acceleration (process noise).
    """

    def __init__(
        self, position_m: np.ndarray, position_cov: np.ndarray, velocity_std_mps: float, accel_std_mps2: float
    ) -> None:
        self.accel_std_mps2 = float(accel_std_mps2)
        self._kf = KalmanFilter(dim_x=6, dim_z=3)
        self._kf.x = np.concatenate([np.asarray(position_m, dtype=np.float64).reshape(3), np.zeros(3)])
        P = np.zeros((6, 6))
        P[:3, :3] = position_cov
        P[3:, 3:] = velocity_std_mps**2 * np.eye(3)
        self._kf.P = P
        self._kf.H = _H

    # ------------------------------------------------------------------ state
    @property
    def position_m(self) -> np.ndarray:
        return self._kf.x[:3].copy()

    @property
    def velocity_mps(self) -> np.ndarray:
        return self._kf.x[3:].copy()

    @property
    def covariance(self) -> np.ndarray:
        """(6, 6) covariance of [p, v]."""
        return self._kf.P.copy()

    # ------------------------------------------------------------------ filter
    def _process_noise(self, dt: float) -> np.ndarray:
        return white_noise_acceleration(dt, self.accel_std_mps2**2)

    def predicted(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) after ``dt`` seconds, without changing the filter."""
        if dt <= 0.0:
            return self._kf.x.copy(), self._kf.P.copy()
        F = transition(dt)
        return F @ self._kf.x, F @ self._kf.P @ F.T + self._process_noise(dt)

    def predict(self, dt: float) -> None:
        """Advance the state by ``dt`` seconds (no-op for dt <= 0)."""
        if dt > 0.0:
            self._kf.predict(F=transition(dt), Q=self._process_noise(dt))

    def innovation(self, z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Innovation y = z - p and its covariance S = P_pp + R for a position measurement z."""
        y = np.asarray(z, dtype=np.float64).reshape(3) - self._kf.x[:3]
        return y, self._kf.P[:3, :3] + R

    def mahalanobis_sq(self, z: np.ndarray, R: np.ndarray) -> float:
        """Squared Mahalanobis distance of the innovation, chi-square with 3 dof under the model."""
        y, S = self.innovation(z, R)
        return float(y @ np.linalg.solve(S, y))

    def update(self, z: np.ndarray, R: np.ndarray) -> None:
        self._kf.update(np.asarray(z, dtype=np.float64).reshape(3), R=R)
