"""One camera's track, predicted to the fusion time, in the site frame.

A track is the filtered state of one camera at its own time ``t_ns`` (aligned to the fusion's clock
by ``ClockAlignment`` where the clocks differ). The fusion needs every camera at one common time:
the position is predicted with the track's velocity, and its covariance grows with the time
stepped over (velocity uncertainty) and with the clock alignment's uncertainty. The camera-frame
covariance of a PnP track is long along the viewing ray (depth comes from the keypoints' spread),
and is made at least as long as the depth's real uncertainty (``FusionConfig.depth_std_frac``);
rotated into the site frame it keeps that shape, which is what makes triangulation work.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dronekey.fusion.camera_pose import CameraPose
from dronekey.fusion.config import FusionConfig
from dronekey.geometry.rotations import quat_wxyz_to_matrix
from dronekey.types import Track, TrackStatus

__all__ = ["Observation", "observe"]


@dataclass(frozen=True)
class Observation:
    """A camera's track at the fusion time ``t_ns``, site frame, metres and seconds.

    position_m, velocity_mps : (3,) site frame.
    position_cov : (3, 3) site frame, m^2, floored and symmetric.
    R_site_body : (3, 3) body (FRD) -> site rotation.
    rotation_var_rad2 : mean variance of the orientation's rotation-vector components, rad^2.
    camera_centre_m : (3,) the camera's centre in the site frame (the ray's origin).
    track_t_ns : the track's own time, on the fusion's clock.
    """

    camera_id: str
    track_id: int
    t_ns: int
    track_t_ns: int
    status: TrackStatus
    position_m: np.ndarray
    velocity_mps: np.ndarray
    position_cov: np.ndarray
    R_site_body: np.ndarray
    rotation_var_rad2: float
    heading_confidence: float
    camera_centre_m: np.ndarray
    score: float
    range_m: float

    @property
    def key(self) -> tuple[str, int]:
        """(camera_id, track_id): one camera's track."""
        return (self.camera_id, self.track_id)

    @property
    def ray_direction(self) -> np.ndarray:
        """Unit vector from the camera centre towards the drone, site frame."""
        d = self.position_m - self.camera_centre_m
        n = float(np.linalg.norm(d))
        return d / n if n > 0 else np.array([0.0, 0.0, 1.0])


def _finite(values: np.ndarray, fallback: float) -> np.ndarray:
    return np.where(np.isfinite(values), values, fallback)


def _ray_floors(cov_cam: np.ndarray, p_cam: np.ndarray, config: FusionConfig) -> np.ndarray:
    """``cov_cam`` with its variance along the ray at least ``(depth_std_frac r)^2`` and across it
    at least ``(bearing_std_rad r)^2`` (see ``FusionConfig``)."""
    r = float(np.linalg.norm(p_cam))
    u = p_cam / r
    along = np.outer(u, u)
    across = np.eye(3) - along
    var_along = float(u @ cov_cam @ u)
    var_across = 0.5 * float(np.trace(across @ cov_cam))
    grow_along = max(0.0, (config.depth_std_frac * r) ** 2 - var_along)
    grow_across = max(0.0, (config.bearing_std_rad * r) ** 2 - var_across)
    return cov_cam + grow_along * along + grow_across * across


def _floored(cov: np.ndarray, min_std_m: float) -> np.ndarray:
    cov = 0.5 * (cov + cov.T)
    w, V = np.linalg.eigh(cov)
    w = np.maximum(w, min_std_m**2)
    return (V * w) @ V.T


def observe(
    track: Track,
    camera_id: str,
    pose: CameraPose,
    t_ns: int,
    config: FusionConfig,
    track_t_ns: int | None = None,
) -> Observation | None:
    """``track`` of ``camera_id`` predicted to ``t_ns`` in the site frame, or None when it cannot be
    used (a non-finite position, or older / newer than ``config.max_age_s``).

    ``track_t_ns`` is the track's time on the fusion's clock (default ``track.t_ns``: the cameras
    share a clock).
    """
    own_t = int(track.t_ns if track_t_ns is None else track_t_ns)
    dt = (int(t_ns) - own_t) * 1e-9
    if abs(dt) > config.max_age_s:
        return None
    p_cam = np.asarray(track.position_m, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(p_cam)) or p_cam[2] <= 0:
        return None
    v_cam = _finite(np.asarray(track.velocity_mps, dtype=np.float64).reshape(3), 0.0)
    cov_cam = np.asarray(track.position_cov, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(cov_cam)):
        cov_cam = np.eye(3) * max(float(np.dot(p_cam, p_cam)), 1.0)  # unknown: wide
    cov_cam = _ray_floors(0.5 * (cov_cam + cov_cam.T), p_cam, config)
    speed = float(np.linalg.norm(v_cam))
    growth = (config.velocity_std_mps * dt) ** 2 + (speed * config.clock_std_s) ** 2
    cov_site = _floored(pose.covariance_to_site(cov_cam) + growth * np.eye(3), config.min_std_m)
    position = pose.point_to_site(p_cam + v_cam * dt)
    rotation_std = _finite(np.asarray(track.rotation_std_rad, dtype=np.float64).reshape(3), np.pi / 2)
    q = np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(4)
    if np.all(np.isfinite(q)) and np.linalg.norm(q) > 0:
        R_cam_body = quat_wxyz_to_matrix(q)
    else:  # no orientation: any, with no weight in the fused orientation
        R_cam_body, rotation_std = np.eye(3), np.full(3, 1e3)
    heading = float(track.heading_confidence)
    return Observation(
        camera_id=camera_id,
        track_id=int(track.track_id),
        t_ns=int(t_ns),
        track_t_ns=own_t,
        status=TrackStatus(track.status),
        position_m=position,
        velocity_mps=pose.vector_to_site(v_cam),
        position_cov=cov_site,
        R_site_body=pose.R_site_cam @ R_cam_body,
        rotation_var_rad2=max(float(np.mean(rotation_std**2)), 1e-8),
        heading_confidence=heading if np.isfinite(heading) else 0.0,
        camera_centre_m=pose.centre_m,
        score=float(track.score) if np.isfinite(track.score) else 0.0,
        range_m=float(np.linalg.norm(p_cam)),
    )
