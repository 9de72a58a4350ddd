"""The sensor's own position, from ``--camera-geo``: GLOBAL_POSITION_INT and HOME_POSITION.

A ground station works out distances to ADS-B traffic from its vehicle's GLOBAL_POSITION_INT
(MAVProxy's ``adsb`` module and map labels use the last one it received from any component), and
shows HOME_POSITION as the home marker. The sensor stands still, so both say the camera's position:
latitude and longitude in degE7, altitude in mm in the datum of ``--camera-geo``'s altitude,
velocities zero, heading the mount's yaw (where the optical axis points, clockwise from true north),
home at the sensor itself (relative altitude 0, local offsets 0, identity orientation).
"""

from __future__ import annotations

import time

from dronekey.daemon.geo import CameraGeo

__all__ = ["global_position_int", "home_position"]


def _deg_e7(deg: float) -> int:
    return round(deg * 1e7)


def global_position_int(dialect, geo: CameraGeo, time_boot_ms: int):
    """GLOBAL_POSITION_INT (33) of the sensor; ``time_boot_ms`` is the sink's uptime, ms (wraps at 2^32)."""
    return dialect.MAVLink_global_position_int_message(
        int(time_boot_ms) & 0xFFFFFFFF,
        _deg_e7(geo.lat_deg),
        _deg_e7(geo.lon_deg),
        round(geo.alt_m * 1000.0),
        0,  # relative_alt: the sensor is its own home
        0,
        0,
        0,
        round(geo.yaw_deg * 100.0) % 36000,
    )


def home_position(dialect, geo: CameraGeo, time_usec: int | None = None):
    """HOME_POSITION (242) of the sensor: home is where the camera stands."""
    return dialect.MAVLink_home_position_message(
        _deg_e7(geo.lat_deg),
        _deg_e7(geo.lon_deg),
        round(geo.alt_m * 1000.0),
        0.0,
        0.0,
        0.0,
        [1.0, 0.0, 0.0, 0.0],
        0.0,
        0.0,
        0.0,
        time.time_ns() // 1000 if time_usec is None else int(time_usec),
    )
