"""Test data shared by test modules: ``from factories import make_track``.

A plain module, not a fixture, so that module-level helpers and subprocess scripts can build
tracks too (pytest's prepend import mode puts ``tests/`` on ``sys.path``).
"""

from __future__ import annotations

import time

import numpy as np

from dronekey.geometry.rotations import matrix_to_quat_wxyz
from dronekey.types import Track, TrackStatus


def make_track(
    track_id: int = 7,
    *,
    t_ns: int | None = None,
    status: TrackStatus = TrackStatus.CONFIRMED,
    position_m=(1.0, -2.0, 30.0),
    velocity_mps=(2.0, 0.0, 1.0),
    position_cov=None,
    attitude=None,
    rotation_std_rad=(0.01, 0.02, 0.03),
    heading_confidence: float = 1.0,
    **fields,
) -> Track:
    """A track 30 m ahead of the camera, confirmed, stamped now; every field can be given.

    Parameters
    ----------
    track_id : int
    t_ns : int, optional
        Timestamp, ns; None: ``time.time_ns()`` (Unix time, as from a live source).
    status : TrackStatus
    position_m, velocity_mps : (3,) camera frame (x right, y down, z forward), m and m/s.
    position_cov : (3, 3), optional
        m^2; None: ``diag(0.01, 0.04, 0.25)`` (standard deviations 0.1, 0.2 and 0.5 m).
    attitude : (3, 3) rotation matrix or (4,) quaternion wxyz, optional
        Body -> camera; None: the identity.
    rotation_std_rad : (3,)
    heading_confidence : float
    **fields
        Any other ``Track`` field (``keypoints_px``, ``score``, ``reprojection_px``, ``hits``, ``age_s``).
    """
    attitude = np.eye(3) if attitude is None else np.asarray(attitude, dtype=np.float64)
    quaternion = matrix_to_quat_wxyz(attitude) if attitude.shape == (3, 3) else attitude
    return Track(
        track_id=track_id,
        t_ns=time.time_ns() if t_ns is None else t_ns,
        status=status,
        position_m=np.array(position_m, dtype=np.float64),
        velocity_mps=np.array(velocity_mps, dtype=np.float64),
        position_cov=np.diag([0.01, 0.04, 0.25]) if position_cov is None else np.asarray(position_cov),
        quaternion_wxyz=quaternion,
        rotation_std_rad=np.array(rotation_std_rad, dtype=np.float64),
        heading_confidence=heading_confidence,
        **fields,
    )
