"""Rotation helpers: matrix <-> unit quaternion (w, x, y, z), geodesic angle, small utilities.

Quaternions are scalar-first (w, x, y, z) everywhere in DroneKey (MAVLink and Foxglove order);
scipy's ``Rotation`` is scalar-last, so conversions go through here and nowhere else.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "canonical_quat",
    "geodesic_angle_deg",
    "matrix_to_quat_wxyz",
    "ned_from_camera",
    "quat_wxyz_to_matrix",
    "rotation_from_euler_deg",
]

# Camera frame (x right, y down, z forward) -> FRD frame of the camera mount (forward = optical axis).
_FRD_FROM_CAMERA = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) with w >= 0 of a 3x3 rotation matrix."""
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R, assume_valid=_surely_valid(R)).as_quat()  # x, y, z, w
    return canonical_quat(np.array([q[3], q[0], q[1], q[2]]))


_EYE3 = np.eye(3)
_SURELY_ORTHOGONAL = 0.5e-12  # stricter than scipy's own test (1e-12 off the diagonal, 1e-5 on it)


def _surely_valid(R: np.ndarray) -> bool:
    """True when scipy's ``from_matrix`` would find ``R`` a proper rotation as it is (positive
    determinant, ``R R^T`` within its tolerance of the identity), so its check can be skipped: the
    quaternion is then the same to the bit, at a quarter of the cost (a track's orientation is
    published every frame). A matrix this stricter test leaves out gets scipy's full treatment."""
    if R.shape != (3, 3):
        return False
    return bool(np.abs(R @ R.T - _EYE3).max() <= _SURELY_ORTHOGONAL and np.linalg.det(R) > 0.0)


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of a quaternion (w, x, y, z); the quaternion is normalised first."""
    q = np.asarray(q, dtype=np.float64).ravel()
    if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
        raise ValueError(f"q must be 4 finite numbers with non-zero norm, got {q.tolist()}")
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def canonical_quat(q: np.ndarray) -> np.ndarray:
    """The unit quaternion with w >= 0 (q and -q are the same rotation)."""
    q = np.asarray(q, dtype=np.float64).ravel()
    q = q / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def geodesic_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Angle of the rotation R_a^T R_b in degrees, in [0, 180] (docs/design.md §4, MAE-angle)."""
    R_rel = np.asarray(R_a, dtype=np.float64).T @ np.asarray(R_b, dtype=np.float64)
    return float(np.degrees(Rotation.from_matrix(R_rel).magnitude()))


def rotation_from_euler_deg(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation matrix from intrinsic z-y'-x'' (yaw, pitch, roll) angles in degrees (aerospace order)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()


def ned_from_camera(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """Rotation from the OpenCV camera frame to local North-East-Down for a camera whose optical axis
    has heading ``yaw`` (0 = north, 90 = east), elevation ``pitch`` (positive up) and ``roll`` about
    the axis, in degrees. With all zero the camera looks north, level: x east, y down, z north."""
    return rotation_from_euler_deg(yaw_deg, pitch_deg, roll_deg) @ _FRD_FROM_CAMERA
