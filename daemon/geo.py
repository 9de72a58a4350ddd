"""The camera's geodetic pose, and camera-frame positions to WGS84 latitude, longitude, altitude.

``--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL`` places the camera on the Earth: WGS84 degrees, metres
above the ellipsoid, and the mount's attitude in degrees: yaw is the heading of the optical axis
(0 = north, 90 = east), pitch its elevation above the horizon (positive up), roll about the optical
axis (positive clockwise as seen from behind the camera). With all three zero the camera looks north,
level: camera x (right) is east, y (down) is down, z (forward) is north.

Conversions are exact on the WGS84 ellipsoid (through ECEF), not a flat-Earth approximation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dronekey.geometry.rotations import ned_from_camera

__all__ = ["CameraGeo", "GeoError", "ecef_from_lla", "ecef_from_ned_rotation", "lla_from_ecef"]

_A = 6378137.0  # WGS84 semi-major axis, m
_F = 1 / 298.257223563
_E2 = _F * (2 - _F)


class GeoError(ValueError):
    """A camera geodetic pose that cannot be used; the message names the bad value."""


def ecef_from_lla(lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
    """WGS84 latitude, longitude (degrees) and height above the ellipsoid (m) -> ECEF (m)."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    n = _A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
    return np.array(
        [
            (n + alt_m) * math.cos(lat) * math.cos(lon),
            (n + alt_m) * math.cos(lat) * math.sin(lon),
            (n * (1 - _E2) + alt_m) * math.sin(lat),
        ]
    )


def lla_from_ecef(p: np.ndarray) -> tuple[float, float, float]:
    """ECEF (m) -> WGS84 (lat_deg, lon_deg, alt_m)."""
    x, y, z = (float(v) for v in p)
    lon = math.atan2(y, x)
    r = math.hypot(x, y)
    lat = math.atan2(z, r * (1 - _E2))
    for _ in range(6):  # converges to < 1e-12 rad within a few iterations near the surface
        n = _A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
        alt = r / math.cos(lat) - n
        lat = math.atan2(z, r * (1 - _E2 * n / (n + alt)))
    n = _A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
    alt = r / math.cos(lat) - n
    return math.degrees(lat), math.degrees(lon), alt


def ecef_from_ned_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rotation from local North-East-Down at (lat, lon) to ECEF axes."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    return np.array([[-sl * co, -so, -cl * co], [-sl * so, co, -cl * so], [cl, 0.0, -sl]])


@dataclass(frozen=True)
class CameraGeo:
    """Geodetic pose of the camera (see module docstring for the angle conventions)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def __post_init__(self) -> None:
        vals = (self.lat_deg, self.lon_deg, self.alt_m, self.yaw_deg, self.pitch_deg, self.roll_deg)
        if not all(math.isfinite(v) for v in vals):
            raise GeoError(f"camera geo values must be finite, got {vals}")
        if not -90 <= self.lat_deg <= 90:
            raise GeoError(f"latitude must be in [-90, 90] degrees, got {self.lat_deg}")
        if not -180 <= self.lon_deg <= 180:
            raise GeoError(f"longitude must be in [-180, 180] degrees, got {self.lon_deg}")
        if not -90 <= self.pitch_deg <= 90:
            raise GeoError(f"pitch must be in [-90, 90] degrees, got {self.pitch_deg}")

    @classmethod
    def parse(cls, text: str) -> CameraGeo:
        """Parse ``LAT,LON,ALT_M,YAW,PITCH,ROLL`` (degrees and metres; the three angles optional)."""
        parts = [p.strip() for p in str(text).split(",")]
        if len(parts) not in (3, 6):
            raise GeoError(f"camera geo must be LAT,LON,ALT_M[,YAW,PITCH,ROLL], got {text!r}")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise GeoError(f"camera geo must be numbers, got {text!r}") from None
        return cls(*vals)

    @property
    def R_ned_cam(self) -> np.ndarray:
        """Rotation from the camera frame to local North-East-Down at the camera."""
        return ned_from_camera(self.yaw_deg, self.pitch_deg, self.roll_deg)

    def ned_from_cam(self, v_cam: np.ndarray) -> np.ndarray:
        """Rotate a camera-frame vector (position offset or velocity) into local NED."""
        return self.R_ned_cam @ np.asarray(v_cam, dtype=np.float64).reshape(3)

    @property
    def ecef_m(self) -> np.ndarray:
        """The camera centre in ECEF, m."""
        return ecef_from_lla(self.lat_deg, self.lon_deg, self.alt_m)

    @property
    def R_ecef_cam(self) -> np.ndarray:
        """Rotation from the camera frame to ECEF axes."""
        return ecef_from_ned_rotation(self.lat_deg, self.lon_deg) @ self.R_ned_cam

    def geodetic(self, p_cam: np.ndarray) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_m) of a camera-frame point in metres."""
        ned = self.ned_from_cam(p_cam)
        ecef = (
            ecef_from_lla(self.lat_deg, self.lon_deg, self.alt_m)
            + ecef_from_ned_rotation(self.lat_deg, self.lon_deg) @ ned
        )
        return lla_from_ecef(ecef)
