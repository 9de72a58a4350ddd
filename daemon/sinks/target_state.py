"""A track as air-traffic tools see it: WGS84 position, NED velocity, course, aircraft-style ids, time.

Shared by the MAVLink messages (TARGET_ABSOLUTE, ADSB_VEHICLE) and the SBS-1 output, so both
report the same position, the same 24-bit address, the same callsign and the same time for a track.

Altitude is in the datum of ``--camera-geo``'s altitude (``CameraGeo`` treats it as height above
the WGS84 ellipsoid; give the camera's altitude above mean sea level instead and the output is AMSL
to well under a metre over the ranges a camera sees).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from dronekey.daemon.geo import CameraGeo
from dronekey.types import PUBLISHED_STATUSES, Track, TrackStatus

__all__ = [
    "DEFAULT_ICAO_BASE",
    "MIN_COURSE_SPEED_MPS",
    "PUBLISHED_STATUSES",
    "TargetGeodetic",
    "callsign",
    "icao_address",
    "target_geodetic",
    "unix_time_us",
    "validate_icao_base",
    "validate_statuses",
]


# 24-bit addresses 0x000001..0x003FFF: below the first block ICAO allocates to a state (0x004000),
# so a track does not take a registered aircraft's address (0x000000 is never valid), and the block
# that MAVProxy's adsb module draws as a drone (it draws 0xA00000 and above, 0xF00000 included, as a
# plane). Track ids 1..16383 keep their number (track 7 is 0x000007); ids wrap every 16383.
DEFAULT_ICAO_BASE = 0x000000
_ICAO_BLOCK = 0x4000

# Below this ground speed the direction of motion is noise: no course is reported.
MIN_COURSE_SPEED_MPS = 0.5

# Timestamps before 2001-09-09 are stream times (file PTS), not Unix time.
_MIN_UNIX_NS = 1_000_000_000 * 1_000_000_000


@dataclass(frozen=True)
class TargetGeodetic:
    """Where a track is on the Earth.

    lat_deg, lon_deg : WGS84 degrees.
    alt_m : metres, in the datum of the camera's configured altitude.
    velocity_ned_mps : (3,) north, east, down, m/s.
    position_cov_ned : (3, 3) position covariance in local NED at the camera, m^2.
    ground_speed_mps : horizontal speed, m/s.
    course_deg : direction of horizontal motion, degrees clockwise from true north in [0, 360),
        or None below ``MIN_COURSE_SPEED_MPS``.
    climb_rate_mps : vertical speed, positive up, m/s.
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    velocity_ned_mps: np.ndarray
    position_cov_ned: np.ndarray
    ground_speed_mps: float
    course_deg: float | None
    climb_rate_mps: float


def target_geodetic(track: Track, geo: CameraGeo) -> TargetGeodetic:
    """The geodetic state of ``track`` (camera-frame position and velocity) seen from ``geo``."""
    lat, lon, alt = geo.geodetic(np.asarray(track.position_m, dtype=np.float64))
    v_ned = geo.ned_from_cam(np.asarray(track.velocity_mps, dtype=np.float64))
    if not np.all(np.isfinite(v_ned)):
        v_ned = np.zeros(3)
    R = geo.R_ned_cam
    cov = np.asarray(track.position_cov, dtype=np.float64).reshape(3, 3)
    speed = float(math.hypot(v_ned[0], v_ned[1]))
    course = math.degrees(math.atan2(v_ned[1], v_ned[0])) % 360.0 if speed >= MIN_COURSE_SPEED_MPS else None
    return TargetGeodetic(
        lat_deg=lat,
        lon_deg=lon,
        alt_m=alt,
        velocity_ned_mps=v_ned,
        position_cov_ned=R @ cov @ R.T,
        ground_speed_mps=speed,
        course_deg=course,
        climb_rate_mps=float(-v_ned[2]),
    )


def unix_time_us(t_ns: int) -> int:
    """The time of a track state as air-traffic messages stamp it: ``t_ns`` in µs if it is Unix time
    (live sources), else the current Unix time (file PTS, which is no time of day)."""
    return int(t_ns) // 1000 if int(t_ns) >= _MIN_UNIX_NS else time.time_ns() // 1000


def validate_icao_base(base: int) -> int:
    """Check that ``base`` starts a block of 16384 24-bit addresses; return it."""
    if not isinstance(base, int) or not 0 <= base < 1 << 24 or base % _ICAO_BLOCK:
        raise ValueError(f"icao_base must be a multiple of 0x4000 below 0x1000000, got {base!r}")
    return base


def validate_statuses(statuses: Iterable[TrackStatus | str]) -> frozenset[TrackStatus]:
    """The track statuses to publish, as ``TrackStatus`` values (names or values accepted)."""
    try:
        out = frozenset(TrackStatus(s) for s in statuses)
    except ValueError:
        allowed = [s.value for s in TrackStatus]
        raise ValueError(f"statuses must be among {allowed}, got {list(statuses)!r}") from None
    return out


def icao_address(track_id: int, base: int = DEFAULT_ICAO_BASE) -> int:
    """The 24-bit address of a track: ``base`` + 1..16383 (track ids 1..16383 as they are, then wrapping),
    never ``base`` itself (0x000000 is no valid address)."""
    return base + 1 + (int(track_id) - 1) % (_ICAO_BLOCK - 1)


def callsign(track_id: int) -> str:
    """An 8-character callsign for a track, e.g. ``DK000042`` (ids wrap every million)."""
    return f"DK{int(track_id) % 1_000_000:06d}"
