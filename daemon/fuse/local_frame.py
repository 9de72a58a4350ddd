"""The fuser's frame: East-North-Up at a reference origin, and cameras' poses put into it.

Each daemon publishes its camera pose on its ``info`` queryable (``camera_pose``: ECEF, and the
site placement when it came from an extrinsics file). The fuser works in ENU at one reference
origin (``--origin``, else the first site origin it sees, else the first camera's position): with
one site file for all cameras, that is exactly the site frame. Conversions are exact through ECEF
(``daemon/geo.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from dronekey.daemon.geo import ecef_from_lla, ecef_from_ned_rotation, lla_from_ecef
from dronekey.fusion import CameraPose
from dronekey.sim_replay.io.site import enu_from_ned

__all__ = ["LocalFrame", "PoseUnavailableError", "camera_ecef_pose", "origin_hint"]


class PoseUnavailableError(ValueError):
    """A daemon's info reply without a usable camera pose; the message says what to configure."""


@dataclass(frozen=True)
class LocalFrame:
    """ENU at (lat_deg, lon_deg, alt_m): x east, y north, z up, metres."""

    lat_deg: float
    lon_deg: float
    alt_m: float

    @property
    def origin_ecef_m(self) -> np.ndarray:
        return ecef_from_lla(self.lat_deg, self.lon_deg, self.alt_m)

    @property
    def R_enu_ecef(self) -> np.ndarray:
        """Rotation from ECEF axes to this frame's ENU axes."""
        return (ecef_from_ned_rotation(self.lat_deg, self.lon_deg) @ enu_from_ned.T).T

    def camera_pose(self, position_ecef_m: np.ndarray, R_ecef_cam: np.ndarray) -> CameraPose:
        """A camera's ECEF pose as a pose in this frame."""
        R = self.R_enu_ecef
        return CameraPose(R @ R_ecef_cam, R @ (np.asarray(position_ecef_m) - self.origin_ecef_m))

    def geodetic(self, p_enu: np.ndarray) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_m) of a point of this frame."""
        return lla_from_ecef(self.origin_ecef_m + self.R_enu_ecef.T @ np.asarray(p_enu, dtype=np.float64))

    def to_message(self) -> dict:
        return {"name": "ENU", "origin": {"lat": self.lat_deg, "lon": self.lon_deg, "alt_m": self.alt_m}}


def camera_ecef_pose(info: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(position_ecef_m, R_ecef_cam) from a daemon's info message.

    Raises
    ------
    PoseUnavailableError
        The daemon publishes no camera pose (neither camera.geo nor camera.extrinsics set), or a
        malformed one.
    """
    camera_id = info.get("camera_id", "?")
    pose = info.get("camera_pose")
    if not isinstance(pose, Mapping) or not isinstance(pose.get("ecef"), Mapping):
        raise PoseUnavailableError(
            f"camera {camera_id!r} publishes no camera pose: start its daemon with --camera-extrinsics FILE "
            "or --camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL (and a DroneKey version that publishes it)"
        )
    try:
        position = np.asarray(pose["ecef"]["position_m"], dtype=np.float64).reshape(3)
        R = np.asarray(pose["ecef"]["R_ecef_cam"], dtype=np.float64).reshape(3, 3)
    except (KeyError, TypeError, ValueError) as exc:
        raise PoseUnavailableError(f"camera {camera_id!r}: malformed camera_pose.ecef ({exc})") from None
    return position, R


def origin_hint(info: Mapping[str, Any]) -> LocalFrame | None:
    """A reference origin from a daemon's info: its site origin if it has one, else its camera's
    position; None without a pose."""
    pose = info.get("camera_pose")
    if not isinstance(pose, Mapping):
        return None
    site = pose.get("site")
    if isinstance(site, Mapping) and isinstance(site.get("origin"), Mapping):
        o = site["origin"]
        return LocalFrame(float(o["lat"]), float(o["lon"]), float(o["alt_m"]))
    try:
        position, _ = camera_ecef_pose(info)
    except PoseUnavailableError:
        return None
    return LocalFrame(*lla_from_ecef(position))
