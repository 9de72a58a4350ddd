"""A camera's pose in the shared site frame.

The site frame is any right-handed Cartesian frame in metres that all cameras of a fusion share:
``dronekey-sim --cameras N`` writes ENU at a site origin (x east, y north, z up), ``dronekey-fuse``
uses ENU at its reference origin. The camera frame is OpenCV's (x right, y down, z forward;
docs/design.md §4), and ``p_site = R_site_cam @ p_cam + t_site_cam_m``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CameraPose"]

_ORTHONORMAL_TOLERANCE = 1e-6


@dataclass(frozen=True)
class CameraPose:
    """Rotation camera -> site and the camera centre in the site frame (m).

    Raises
    ------
    ValueError
        Naming ``R_site_cam`` or ``t_site_cam_m`` when a shape is wrong, a value is not finite, or
        the rotation is not orthonormal with determinant +1.
    """

    R_site_cam: np.ndarray
    t_site_cam_m: np.ndarray

    def __post_init__(self) -> None:
        R = np.asarray(self.R_site_cam, dtype=np.float64)
        t = np.asarray(self.t_site_cam_m, dtype=np.float64).reshape(-1)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError(f"R_site_cam must be 3x3 finite numbers, got {R.tolist()}")
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"t_site_cam_m must be 3 finite numbers, got {t.tolist()}")
        if np.abs(R.T @ R - np.eye(3)).max() > _ORTHONORMAL_TOLERANCE or np.linalg.det(R) < 0:
            raise ValueError(f"R_site_cam must be a rotation (orthonormal, det +1), got {R.tolist()}")
        object.__setattr__(self, "R_site_cam", R)
        object.__setattr__(self, "t_site_cam_m", t)

    @property
    def centre_m(self) -> np.ndarray:
        """The camera centre in the site frame, m."""
        return self.t_site_cam_m

    def point_to_site(self, p_cam: np.ndarray) -> np.ndarray:
        """A camera-frame point (m) in the site frame."""
        return self.R_site_cam @ np.asarray(p_cam, dtype=np.float64).reshape(3) + self.t_site_cam_m

    def vector_to_site(self, v_cam: np.ndarray) -> np.ndarray:
        """A camera-frame vector (a velocity, an offset) rotated into the site frame."""
        return self.R_site_cam @ np.asarray(v_cam, dtype=np.float64).reshape(3)

    def covariance_to_site(self, cov_cam: np.ndarray) -> np.ndarray:
        """A camera-frame 3x3 covariance rotated into the site frame."""
        R = self.R_site_cam
        return R @ np.asarray(cov_cam, dtype=np.float64).reshape(3, 3) @ R.T
