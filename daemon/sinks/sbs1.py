"""SBS-1 (BaseStation) output: tracks as ADS-B style "MSG" lines on a TCP server (``--sbs1-listen``).

QGroundControl draws ADSB_VEHICLE only from the vehicle it is connected to, so a ground-based
sensor also serves the BaseStation text format (the one ``dump1090 --net`` serves on port 30003),
which QGroundControl's "ADSB server" input and common ADS-B tools read (docs/design.md §6.2).

Per published track update, CRLF-terminated lines of 22 comma-separated fields:

- ``MSG,3`` position: 24-bit hex address, altitude in feet (integer), latitude, longitude (degrees);
- ``MSG,4`` velocity: ground speed in knots, track (course over ground, degrees; empty when the
  drone hovers) and vertical rate in ft/min;
- ``MSG,1`` identification: the callsign, when a track first appears and every ``callsign_period_s``.

Address and callsign are those of MAVLink's ADSB_VEHICLE (``dronekey.daemon.sinks.target_state``);
dates and times are UTC. Altitude is in the datum of ``--camera-geo`` (see ``target_state``).

Needs the camera's geodetic pose: without it there is no latitude or longitude to send, and the
constructor refuses. The lines go to every TCP client without ever blocking the caller
(``sbs1_server``: bounded buffers, slow and idle clients disconnected, loopback by default).
"""

from __future__ import annotations

import datetime as dt
import math
import time
from collections.abc import Iterable

from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.sbs1_server import Sbs1Server
from dronekey.daemon.sinks.target_state import (
    DEFAULT_ICAO_BASE,
    PUBLISHED_STATUSES,
    TargetGeodetic,
    callsign,
    icao_address,
    target_geodetic,
    unix_time_us,
    validate_icao_base,
    validate_statuses,
)
from dronekey.types import TrackStatus

__all__ = ["Sbs1Sink", "sbs1_lines"]

FT_PER_M = 1.0 / 0.3048
KT_PER_MPS = 3600.0 / 1852.0
FPM_PER_MPS = 60.0 * FT_PER_M


def _line(kind: int, address: int, when: dt.datetime, values: dict[int, str]) -> str:
    """One MSG line; ``values`` maps 0-based field indices (10 callsign ... 17 squawk) to text."""
    date, clock = when.strftime("%Y/%m/%d"), when.strftime("%H:%M:%S.%f")[:-3]
    f = [""] * 22
    f[0:10] = ["MSG", str(kind), "1", "1", f"{address:06X}", "1", date, clock, date, clock]
    for index, value in values.items():
        f[index] = value
    f[18:22] = ["0", "0", "0", "0"]  # alert, emergency, SPI, on ground: all false
    return ",".join(f) + "\r\n"


def sbs1_lines(
    track_id: int, state: TargetGeodetic, when: dt.datetime, icao_base: int, with_callsign: bool
) -> list[str]:
    """The BaseStation lines of one track update (module docstring), CRLF-terminated."""
    address = icao_address(track_id, icao_base)
    lines = []
    if with_callsign:
        lines.append(_line(1, address, when, {10: callsign(track_id)}))
    position = {
        11: str(round(state.alt_m * FT_PER_M)),
        14: f"{state.lat_deg:.6f}",
        15: f"{state.lon_deg:.6f}",
    }
    velocity = {
        12: f"{state.ground_speed_mps * KT_PER_MPS:.1f}",
        13: "" if state.course_deg is None else f"{state.course_deg:.1f}",
        16: str(round(state.climb_rate_mps * FPM_PER_MPS)),
    }
    lines.append(_line(3, address, when, position))
    lines.append(_line(4, address, when, velocity))
    return lines


class Sbs1Sink(Sink):
    """Serve published tracks as SBS-1 lines to every connected TCP client.

    Parameters
    ----------
    config : the ``sbs1`` section: ``listen`` (``127.0.0.1:PORT``, or ``HOST:PORT``, ``0.0.0.0:30003``
        for every interface; 30003 is the usual port, 0 picks a free one) and ``idle_timeout_s``.
    camera_geo : the camera's geodetic pose (required).
    statuses : track statuses that are published (default confirmed and coasting).
    icao_base : first 24-bit address of the tracks' block (same as the MAVLink sink's).
    max_clients : connections accepted at once; more are closed at once.
    max_pending_bytes : a client further behind than this is disconnected.
    callsign_period_s : how often a track's MSG,1 (callsign) line is repeated, s.
    """

    name = "sbs1"

    def __init__(
        self,
        config: Sbs1Config,
        camera_geo: CameraGeo | None,
        *,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
        icao_base: int = DEFAULT_ICAO_BASE,
        max_clients: int = 16,
        max_pending_bytes: int = 64 * 1024,
        callsign_period_s: float = 5.0,
    ) -> None:
        if camera_geo is None:
            raise ValueError(
                "the SBS-1 output (--sbs1-listen) needs the camera's geodetic pose "
                "(--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL): its lines carry latitude and longitude"
            )
        if not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo, got {type(camera_geo).__name__}")
        self._geo = camera_geo
        self._statuses = validate_statuses(statuses)
        self._icao_base = validate_icao_base(icao_base)
        self._callsign_period_ns = int(callsign_period_s * 1e9)
        self._callsign_due: dict[int, int] = {}
        self._server = Sbs1Server(config, max_clients=max_clients, max_pending_bytes=max_pending_bytes)

    @property
    def address(self) -> tuple:
        """The bound socket address (host, port, ...)."""
        return self._server.address

    def handle_update(self, update: FrameUpdate) -> None:
        """Queue the lines of the published tracks of one frame for every client; never blocks."""
        now = time.monotonic_ns()
        lines: list[str] = []
        for track in update.tracks:
            if track.status == TrackStatus.LOST:
                self._callsign_due.pop(track.track_id, None)
                continue
            if track.status not in self._statuses:
                continue
            state = target_geodetic(track, self._geo)
            if not all(map(math.isfinite, (state.lat_deg, state.lon_deg, state.alt_m))):
                continue
            when = dt.datetime.fromtimestamp(unix_time_us(track.t_ns) / 1e6, tz=dt.UTC)
            due = self._callsign_due.get(track.track_id, now)
            with_callsign = now >= due
            if with_callsign:
                self._callsign_due[track.track_id] = now + self._callsign_period_ns
            lines += sbs1_lines(track.track_id, state, when, self._icao_base, with_callsign)
        if not lines:
            return
        data = "".join(lines).encode("ascii")
        self._server.broadcast(data, len(lines))

    def health(self) -> dict:
        """The server's address, clients and counters (``Sbs1Server.health``)."""
        return self._server.health()

    def close(self) -> None:
        """Stop serving and disconnect every client. Idempotent."""
        self._server.close()
