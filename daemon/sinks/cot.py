"""TAK Cursor-on-Target output (``--cot URL``): tracks, lost tracks and the sensor as CoT events.

Per published track (confirmed or coasting), at most every ``min_interval_s``, an event that
goes stale ``stale_s`` after the state's time; when a track is lost, its last event again with
``stale`` = now and, with ``send_delete``, a ``t-x-d-d`` delete; the sensor's own point every
``sensor_interval_s`` (and at start). Events are built by ``cot_events`` and sent by
``cot_transport`` (pytak, its own thread, bounded queue), so this sink never blocks its worker.

Needs the camera's geodetic pose (``--camera-geo``): an event is a point on the Earth, so without
it the constructor refuses with a line naming the setting.
"""

from __future__ import annotations

import math
import time
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterable

with warnings.catch_warnings():  # pytak warns at import that its optional aiohttp is missing; unused here
    warnings.simplefilter("ignore")
    import pytak

from dronekey.daemon import messages
from dronekey.daemon.config.cot import CotConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.cot_events import (
    delete_event,
    sensor_event,
    stale_event,
    track_event,
    track_uid,
)
from dronekey.daemon.sinks.cot_transport import CotTransport
from dronekey.daemon.sinks.target_state import (
    PUBLISHED_STATUSES,
    target_geodetic,
    unix_time_us,
    validate_statuses,
)
from dronekey.types import TrackStatus

__all__ = ["CotSink"]

_SENSOR_STALE_PERIODS = 3  # the sensor's point stays fresh for this many of its periods


class CotSink(Sink):
    """Send tracks to TAK (ATAK, WinTAK, iTAK, TAK Server) as Cursor-on-Target events.

    Parameters
    ----------
    config : the ``cot`` section (URL, TLS, stale times, types; docs/outputs.md).
    camera_id : the daemon's camera id (in every uid).
    camera_geo : the camera's geodetic pose (required).
    fov_deg : the camera's horizontal field of view, degrees, for the sensor's cone in ATAK; None: none.
    sensor_range_m : how far the sensor's cone reaches in ATAK, metres; None: not drawn to a range.
    statuses : track statuses that are published (default confirmed and coasting).
    max_queue : events waiting for the peer at most (the oldest dropped beyond).
    """

    name = "cot"

    def __init__(
        self,
        config: CotConfig,
        camera_id: str,
        camera_geo: CameraGeo | None,
        *,
        fov_deg: float | None = None,
        sensor_range_m: float | None = None,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
        max_queue: int = 64,
    ) -> None:
        if camera_geo is None:
            raise ValueError(
                "the CoT output (--cot) needs the camera's geodetic pose "
                "(--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL): its events are points on the Earth"
            )
        if not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo, got {type(camera_geo).__name__}")
        self._config = config
        self._camera_id = camera_id
        self._geo = camera_geo
        self._fov_deg = fov_deg
        self._sensor_range_m = sensor_range_m
        self._statuses = validate_statuses(statuses)
        self._min_interval_ns = int(config.min_interval_s * 1e9)
        self._sensor_period_ns = int(config.sensor_interval_s * 1e9)
        self._sensor_due_ns = 0
        self._last: dict[int, tuple[ET.Element, int]] = {}  # track id -> (last event, monotonic ns)
        self._events = {"tracks": 0, "lost": 0, "sensor": 0}
        self._transport = CotTransport(config, max_queue=max_queue)
        self._send_sensor(time.monotonic_ns())

    @property
    def transport(self) -> CotTransport:
        return self._transport

    def handle_update(self, update: FrameUpdate) -> None:
        """Queue the events of one frame's tracks (and the sensor's point when due); never blocks."""
        now = time.monotonic_ns()
        if now >= self._sensor_due_ns:
            self._send_sensor(now)
        for track in update.tracks:
            if track.status == TrackStatus.LOST:
                self._send_lost(track.track_id, unix_time_us(track.t_ns))
                continue
            if track.status not in self._statuses:
                continue
            previous = self._last.get(track.track_id)
            if previous is not None and now - previous[1] < self._min_interval_ns:
                continue
            state = target_geodetic(track, self._geo)
            if not all(map(math.isfinite, (state.lat_deg, state.lon_deg))):
                continue
            event = track_event(
                self._camera_id,
                track.track_id,
                state,
                messages.track_message(track, self._camera_id, self._geo),
                unix_time_us(track.t_ns),
                cot_type=self._config.track_type,
                sensor_type=self._config.sensor_type,
                stale_s=self._config.stale_s,
            )
            self._send(event)
            self._last[track.track_id] = (event, now)
            self._events["tracks"] += 1

    def handle_status(self, status: dict) -> None:
        """Keep the sensor's point fresh while no frames arrive."""
        now = time.monotonic_ns()
        if now >= self._sensor_due_ns:
            self._send_sensor(now)

    def health(self) -> dict:
        """The transport's state and counters, and the events built (tracks, lost, sensor)."""
        return self._transport.health() | {"events": dict(self._events), "tracks_shown": len(self._last)}

    def failing(self) -> str | None:
        """Why no event reaches the peer, while none does."""
        health = self._transport.health()
        if health["state"] != "open" and health["error"]:
            return f"not sending: {health['error']}"
        return None

    def fault_counts(self) -> dict[str, int]:
        """Events the peer did not get: dropped from a full queue or not sent."""
        counts = self._transport.counts
        return {"unsent": counts["not_sent"] + counts["dropped"]}

    def close(self) -> None:
        """Mark every shown track stale (a stopping sensor leaves no fresh marker), then close."""
        now_us = time.time_ns() // 1000
        for track_id in list(self._last):
            self._send_lost(track_id, now_us)
        self._transport.close()

    def _send_lost(self, track_id: int, unix_us: int) -> None:
        previous = self._last.pop(track_id, None)
        if previous is None:  # never shown: nothing to take down
            return
        self._send(stale_event(previous[0], unix_us))
        if self._config.send_delete:
            uid = track_uid(self._camera_id, track_id)
            self._send(delete_event(uid, self._config.track_type, unix_us))
        self._events["lost"] += 1

    def _send_sensor(self, now_ns: int) -> None:
        self._sensor_due_ns = now_ns + self._sensor_period_ns
        event = sensor_event(
            self._camera_id,
            self._geo,
            time.time_ns() // 1000,
            cot_type=self._config.sensor_type,
            stale_s=self._config.sensor_interval_s * _SENSOR_STALE_PERIODS,
            fov_deg=self._fov_deg,
            range_m=self._sensor_range_m,
        )
        self._send(event)
        self._events["sensor"] += 1

    def _send(self, event: ET.Element) -> None:
        self._transport.send(pytak.serialize_cot(event, xml_declaration=True, trailing_newline=True))
