"""Where a track is, in the terms a SAPIENT DetectionReport uses, with 1-sigma errors from its covariance.

Two frames, as the node declares in its Registration:

- **platform** (always): range (m), azimuth (degrees, positive right of the optical axis) and
  elevation (degrees, positive above it) in the camera frame (docs/design.md §4: x right, y down,
  z forward); ``RANGE_BEARING_DATUM_PLATFORM``. Velocity "ENU" then means right, forward, up.
- **geodetic** (with ``--camera-geo``): WGS84 latitude, longitude (degrees) and altitude (metres,
  the datum of ``--camera-geo``, the ellipsoid); velocity east, north, up (m/s).

Errors are the standard deviations of the track's position covariance carried through the
Jacobian of each conversion: range and metres stay metres, angles become degrees, latitude and
longitude errors are degrees (the units of their coordinates, as Location's errors are).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.messages import check_heading_confidence
from dronekey.geometry.rotations import quat_wxyz_to_matrix
from dronekey.types import Track

__all__ = [
    "HEADING_CONFIDENCE_MIN",
    "Geodetic",
    "RangeBearing",
    "geodetic_of",
    "heading_deg",
    "range_bearing_of",
    "velocity_enu",
    "wrap_deg",
]

HEADING_CONFIDENCE_MIN = 0.5  # below this the front may be the back: no heading is reported
_A = 6378137.0  # WGS84 semi-major axis, m
_E2 = (1 / 298.257223563) * (2 - 1 / 298.257223563)


@dataclass(frozen=True, slots=True)
class RangeBearing:
    """Camera-frame spherical position: metres and degrees, each with its 1-sigma error."""

    range_m: float
    azimuth_deg: float
    elevation_deg: float
    range_error_m: float
    azimuth_error_deg: float
    elevation_error_deg: float


@dataclass(frozen=True, slots=True)
class Geodetic:
    """WGS84 position (degrees, metres) with 1-sigma errors (degrees, degrees, metres)."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    lat_error_deg: float
    lon_error_deg: float
    alt_error_m: float


def wrap_deg(angle: float) -> float:
    """``angle`` in (-180, 180] degrees."""
    wrapped = math.fmod(angle + 180.0, 360.0)
    return (wrapped + 360.0 if wrapped <= 0.0 else wrapped) - 180.0


def _std(jacobian: np.ndarray, cov: np.ndarray) -> np.ndarray:
    variances = np.einsum("ij,jk,ik->i", jacobian, cov, jacobian)
    return np.sqrt(np.clip(variances, 0.0, None))


def _vector(values, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (3,):
        raise ValueError(f"track.{name} must have 3 values, got shape {arr.shape}")
    return arr


def _covariance(track: Track) -> np.ndarray:
    cov = np.asarray(track.position_cov, dtype=np.float64)
    if cov.shape != (3, 3):
        raise ValueError(f"track.position_cov must be 3x3, got shape {cov.shape}")
    return cov


def range_bearing_of(track: Track) -> RangeBearing | None:
    """The track's camera-frame range, azimuth and elevation, or None when its position is not finite
    or on the camera's vertical axis (no azimuth)."""
    x, y, z = _vector(track.position_m, "position_m")
    horizontal2 = x * x + z * z
    if not all(map(math.isfinite, (x, y, z))) or horizontal2 <= 0.0:
        return None
    horizontal = math.sqrt(horizontal2)
    r2 = horizontal2 + y * y
    r = math.sqrt(r2)
    jacobian = np.array(
        [
            [x / r, y / r, z / r],
            [z / horizontal2, 0.0, -x / horizontal2],
            [y * x / (horizontal * r2), -horizontal / r2, y * z / (horizontal * r2)],
        ]
    )
    std = _std(jacobian, _covariance(track))
    return RangeBearing(
        range_m=r,
        azimuth_deg=math.degrees(math.atan2(x, z)),
        elevation_deg=math.degrees(math.atan2(-y, horizontal)),
        range_error_m=float(std[0]),
        azimuth_error_deg=math.degrees(std[1]),
        elevation_error_deg=math.degrees(std[2]),
    )


def geodetic_of(track: Track, camera_geo: CameraGeo) -> Geodetic | None:
    """The track's WGS84 position with errors, or None when its position is not finite."""
    p = _vector(track.position_m, "position_m")
    if not np.all(np.isfinite(p)):
        return None
    lat, lon, alt = camera_geo.geodetic(p)
    rotation = camera_geo.R_ned_cam
    north_std, east_std, down_std = np.sqrt(
        np.clip(np.diag(rotation @ _covariance(track) @ rotation.T), 0, None)
    )
    sin_lat = math.sin(math.radians(lat))
    w = math.sqrt(1.0 - _E2 * sin_lat * sin_lat)
    meridian_radius = _A * (1.0 - _E2) / w**3 + alt
    prime_vertical_radius = (_A / w + alt) * max(math.cos(math.radians(lat)), 1e-9)
    return Geodetic(
        lat_deg=lat,
        lon_deg=lon,
        alt_m=alt,
        lat_error_deg=math.degrees(north_std / meridian_radius),
        lon_error_deg=math.degrees(east_std / prime_vertical_radius),
        alt_error_m=float(down_std),
    )


def velocity_enu(track: Track, camera_geo: CameraGeo | None) -> tuple[float, float, float] | None:
    """(east, north, up) in m/s; in the platform frame (right, forward, up) without a camera geo."""
    v = _vector(track.velocity_mps, "velocity_mps")
    if not np.all(np.isfinite(v)):
        return None
    if camera_geo is None:
        return float(v[0]), float(v[2]), float(-v[1])
    north, east, down = camera_geo.ned_from_cam(v)
    return float(east), float(north), float(-down)


def heading_deg(track: Track, camera_geo: CameraGeo | None) -> tuple[float, float] | None:
    """(heading, 1-sigma error) in degrees of the drone's nose, or None until it is trustworthy.

    Heading is from true north (clockwise) with a camera geo, else from the optical axis (positive
    right); it is reported only once ``heading_confidence`` >= 0.5 (front told from back) and the
    nose is not pointing straight up or down. The error is the largest orientation standard deviation.
    """
    confidence = check_heading_confidence(track.heading_confidence)
    if not confidence >= HEADING_CONFIDENCE_MIN:  # NaN (unknown) included
        return None
    q = np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(-1)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or not np.linalg.norm(q) > 0:
        return None
    nose_cam = quat_wxyz_to_matrix(q / np.linalg.norm(q))[:, 0]  # body x (forward) in the camera frame
    if camera_geo is None:
        right, forward = nose_cam[0], nose_cam[2]
    else:
        forward, right, _ = camera_geo.ned_from_cam(nose_cam)
    if math.hypot(right, forward) < 1e-6:
        return None
    heading = math.degrees(math.atan2(right, forward))
    heading = heading % 360.0 if camera_geo is not None else heading
    std = np.asarray(track.rotation_std_rad, dtype=np.float64).reshape(-1)
    error = math.degrees(float(np.max(std))) if std.size and np.all(np.isfinite(std)) else math.nan
    return heading, error
