"""A constructed two-camera site for the fusion tests: known camera poses, a true drone pose, and
camera tracks with noise drawn from a PnP-like covariance (long along the ray, narrow across it)."""

from __future__ import annotations

import numpy as np

from dronekey.fusion import CameraPose
from dronekey.geometry.rotations import matrix_to_quat_wxyz, rotation_from_euler_deg
from dronekey.types import Track, TrackStatus

# Site frame ENU (x east, y north, z up). A camera looking along +y (north), level: camera x (right)
# is east, y (down) is -up, z (forward) is north.
_R_SITE_CAM_NORTH = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def looking_at(centre, target) -> CameraPose:
    """A level camera at ``centre`` whose optical axis points at ``target`` (site frame)."""
    d = np.asarray(target, float) - np.asarray(centre, float)
    yaw = np.arctan2(d[0], d[1])  # clockwise from north
    pitch = np.arctan2(d[2], np.hypot(d[0], d[1]))
    c, s = np.cos(yaw), np.sin(yaw)
    R_yaw = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])  # turns north towards east
    cp, sp = np.cos(pitch), np.sin(pitch)
    R_pitch = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])  # camera x axis: tilt up
    return CameraPose(R_yaw @ _R_SITE_CAM_NORTH @ R_pitch, np.asarray(centre, float))


def ray_covariance(p_cam, along_frac: float, across_frac: float) -> np.ndarray:
    """Camera-frame covariance with std ``along_frac * range`` along the ray and
    ``across_frac * range`` across it."""
    p = np.asarray(p_cam, float)
    r = np.linalg.norm(p)
    u = p / r
    return (along_frac * r) ** 2 * np.outer(u, u) + (across_frac * r) ** 2 * (np.eye(3) - np.outer(u, u))


def camera_track(
    pose: CameraPose,
    p_site,
    *,
    track_id: int = 1,
    t_ns: int = 0,
    rng: np.random.Generator | None = None,
    along_frac: float = 0.08,
    across_frac: float = 0.002,
    v_site=(0.0, 0.0, 0.0),
    R_site_body=None,
    heading_confidence: float = 1.0,
    rotation_std_rad=(0.05, 0.05, 0.05),
    status: TrackStatus = TrackStatus.CONFIRMED,
) -> Track:
    """The track a camera at ``pose`` reports for a drone at ``p_site``, with noise when ``rng``."""
    R, t = pose.R_site_cam, pose.t_site_cam_m
    p_cam = R.T @ (np.asarray(p_site, float) - t)
    cov = ray_covariance(p_cam, along_frac, across_frac)
    if rng is not None:
        p_cam = rng.multivariate_normal(p_cam, cov)
    R_body = np.eye(3) if R_site_body is None else np.asarray(R_site_body, float)
    return Track(
        track_id=track_id,
        t_ns=t_ns,
        status=status,
        position_m=p_cam,
        velocity_mps=R.T @ np.asarray(v_site, float),
        position_cov=cov,
        quaternion_wxyz=matrix_to_quat_wxyz(R.T @ R_body),
        rotation_std_rad=np.asarray(rotation_std_rad, float),
        heading_confidence=heading_confidence,
        score=0.9,
        hits=10,
    )


def heading(yaw_deg: float) -> np.ndarray:
    """A level body (FRD) -> site (ENU) rotation with the nose ``yaw_deg`` clockwise from north."""
    R_enu_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    return R_enu_ned @ rotation_from_euler_deg(yaw_deg, 0.0, 0.0)
