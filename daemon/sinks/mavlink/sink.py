"""The MAVLink output (docs/design.md §6.2): heartbeat, target messages, two-way commands, signing.

What goes out, all MAVLink 2 from our own system/component ids:

- HEARTBEAT once a second while the pipeline is healthy (see ``MavlinkSink.set_healthy``);
- TARGET_RELATIVE (511) per track update, in the sensor's FRD frame (``messages`` module);
- TARGET_ABSOLUTE (510) and ADSB_VEHICLE (246) per track update when the camera's geodetic pose
  is configured;
- GLOBAL_POSITION_INT (the sensor's own position) with the heartbeat, when the camera's geodetic
  pose is configured (``own_position``);
- replies to PING, commands (COMMAND_ACK for each one aimed at us), parameter requests (a few
  read-only parameters, ``parameters``) and MAVLink FTP (a NAK, ``ftp``): ``commands`` module.

What comes in is read only from admitted peers, and with signing on only when correctly signed and
newer than its stream's last message, which survives restarts (``connection``). Everything refused
is counted by reason and logged at a bounded rate (``refusals``).

Threads: the daemon's ``SinkWorker`` calls ``handle_update``; a housekeeping thread sends the
heartbeat, (re)opens the link with backoff and saves the signing timestamp; a receive thread parses
what ground stations send and answers. Nothing here blocks on the network: UDP sends never wait,
and a link that cannot be opened is retried in the background while messages for it are dropped
and counted.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Iterable, Mapping

import dronekey
from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.target_state import (
    DEFAULT_ICAO_BASE,
    PUBLISHED_STATUSES,
    unix_time_us,
    validate_icao_base,
    validate_statuses,
)
from dronekey.geometry.camera import CameraModel
from dronekey.types import Track, TrackStatus

from . import messages
from .commands import CommandHandler
from .connection import Connection
from .dialect import load_dialect
from .latest import LatestTrackMessages
from .own_position import global_position_int, home_position
from .parameters import ParameterServer, sensor_parameters
from .peers import PeerPolicy
from .refusals import Refusals
from .signing import SAVE_INTERVAL_S
from .streams import StreamRates
from .verify import DEFAULT_MAX_STREAMS

__all__ = ["MavlinkSink"]

log = logging.getLogger(__name__)

_TICK_S = 0.1
_RECV_POLL_S = 0.2


class MavlinkSink(Sink):
    """Publish tracks over MAVLink 2 and answer ground stations.

    Parameters
    ----------
    config : the ``mavlink`` section: ``url`` (a pymavlink connection string, ``link.validate_url``),
        our ``sysid`` and ``compid``, the ``signing_key`` file (None: unsigned) and ``allow``, who
        else may send commands (``peers``: ``"HOST"``, ``"HOST:PORT"`` or a network
        ``"10.0.0.0/24"``; empty: only the link's own peer or, on a listening link, the first heard).
    camera_geo : the camera's geodetic pose; TARGET_ABSOLUTE and ADSB_VEHICLE are sent only with it.
    simulated : set ADSB_VEHICLE's SIMULATED flag (for ``sim://`` sources).
    signing_state_dir : folder of the signing timestamp file
        (``mavlink-signing-<sysid>-<compid>.timestamp``); default ``$STATE_DIRECTORY`` or the key's folder.
    mav_type : HEARTBEAT's MAV_TYPE; default MAV_TYPE_ONBOARD_CONTROLLER (not taken for a vehicle).
    statuses : track statuses that are published (default confirmed and coasting).
    icao_base : first 24-bit ADS-B address of the tracks' block (``target_state.icao_address``).
    health_timeout_s : the heartbeat stops when neither a frame update nor ``set_healthy(True)``
        came for this long (a stalled or hung pipeline), s.
    heartbeat_period_s : seconds between heartbeats (1 Hz by MAVLink convention).
    dialect_cache_dir : where the generated dialect lives (``dialect.load_dialect``).
    max_signed_streams : incoming signed streams whose timestamps are kept (``verify``), oldest
        evicted first; their state file is ``mavlink-signing-<sysid>-<compid>.streams`` beside the
        signing timestamp.
    refusal_log_period_s : at most one log line about refused input per this many seconds.
    camera_id, camera, model_info : what the read-only parameters describe (``parameters``): the
        camera id, its intrinsics and the keypoint model (``sha256``); each may be None.

    Health: the daemon calls ``set_healthy(bool)`` when the pipeline's state changes, or puts
    ``"healthy": bool`` in the status dict it gives ``handle_status``; frame updates also count as
    signs of life. Heartbeats go out while the last word was healthy and a sign of life came within
    ``health_timeout_s``.
    """

    name = "mavlink"

    def __init__(
        self,
        config: MavlinkConfig,
        camera_geo: CameraGeo | None = None,
        *,
        simulated: bool = False,
        signing_state_dir: str | os.PathLike | None = None,
        mav_type: int | None = None,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
        icao_base: int = DEFAULT_ICAO_BASE,
        health_timeout_s: float = 5.0,
        heartbeat_period_s: float = 1.0,
        dialect_cache_dir: str | os.PathLike | None = None,
        max_signed_streams: int = DEFAULT_MAX_STREAMS,
        refusal_log_period_s: float = 60.0,
        camera_id: str | None = None,
        camera: CameraModel | None = None,
        model_info: Mapping | None = None,
    ) -> None:
        if camera_geo is not None and not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo or None, got {type(camera_geo).__name__}")
        if not health_timeout_s > 0:
            raise ValueError(f"health_timeout_s must be > 0, got {health_timeout_s!r}")
        if not heartbeat_period_s > 0:
            raise ValueError(f"heartbeat_period_s must be > 0, got {heartbeat_period_s!r}")
        sysid, compid = config.sysid, config.compid
        self._sysid, self._compid = sysid, compid
        self._geo = camera_geo
        self._statuses = validate_statuses(statuses)
        self._icao_base = validate_icao_base(icao_base)
        self._simulated = bool(simulated)
        self._health_timeout_ns = int(health_timeout_s * 1e9)
        self._heartbeat_period_s = float(heartbeat_period_s)
        self._refusals = Refusals(refusal_log_period_s)

        self._save_streams_soon = False

        self._d = load_dialect(dialect_cache_dir)
        self._mav_type = self._d.MAV_TYPE_ONBOARD_CONTROLLER if mav_type is None else int(mav_type)
        self._q_sensor = messages.sensor_quaternion(camera_geo)
        self._version = dronekey.__version__
        per_track = [messages.TARGET_RELATIVE]
        if camera_geo is not None:
            per_track += [messages.TARGET_ABSOLUTE, messages.ADSB_VEHICLE]
        self._rates = StreamRates(per_track)
        params = sensor_parameters(sysid, compid, self._version, camera_id, camera, model_info, camera_geo)
        self._handler = CommandHandler(
            self._d,
            sysid,
            compid,
            self._rates,
            self._request_message,
            self._default_interval_us,
            ParameterServer(self._d, sysid, compid, params),
        )
        self._link = Connection(
            config.url,
            self._d,
            sysid,
            compid,
            peers=PeerPolicy.for_url(config.url, config.allow),
            refusals=self._refusals,
            signing_key_file=config.signing_key,
            signing_state_dir=signing_state_dir,
            max_signed_streams=max_signed_streams,
        )

        self._state_lock = threading.Lock()  # health, counters
        self._healthy = True
        self._heartbeat_announced = False
        self._last_alive_ns: int | None = None
        self._latest = LatestTrackMessages()
        self._last_update_ns: int | None = None
        self._update_interval_us = 0.0
        self._commands = 0

        self._started_ns = time.monotonic_ns()
        self._stop = threading.Event()
        self._link.open_if_due()
        self._threads = [
            threading.Thread(target=self._housekeeping_loop, name="mavlink-housekeeping", daemon=True),
            threading.Thread(target=self._receive_loop, name="mavlink-receive", daemon=True),
        ]
        for t in self._threads:
            t.start()

    # ------------------------------------------------------------------ public API

    @property
    def sysid(self) -> int:
        return self._sysid

    @property
    def compid(self) -> int:
        return self._compid

    @property
    def dialect(self):
        """The generated dialect module in use."""
        return self._d

    def set_healthy(self, healthy: bool) -> None:
        """Tell the sink whether the pipeline is healthy; heartbeats go out only while it is."""
        with self._state_lock:
            # Said only once a heartbeat went out: before the first frame there is nothing to stop.
            if bool(healthy) != self._healthy and self._last_alive_ns is not None:
                if not healthy:
                    change = "stops (unhealthy)"
                else:
                    change = "resumes (pipeline healthy)" if self._heartbeat_announced else "starts"
                log.info("MAVLink heartbeat %s", change)
                self._heartbeat_announced = True
            self._healthy = bool(healthy)
            if healthy:
                self._last_alive_ns = time.monotonic_ns()

    def is_healthy(self) -> bool:
        """Whether a heartbeat would go out now."""
        with self._state_lock:
            return self._is_healthy_locked()

    def _is_healthy_locked(self) -> bool:
        alive = self._last_alive_ns
        return self._healthy and alive is not None and time.monotonic_ns() - alive <= self._health_timeout_ns

    def handle_status(self, status: dict) -> None:
        """Take ``status["healthy"]`` (bool) if the daemon's status carries it."""
        if isinstance(status, dict) and "healthy" in status:
            self.set_healthy(bool(status["healthy"]))

    def handle_update(self, update: FrameUpdate) -> None:
        """Send the target messages of the published tracks of one frame."""
        now = time.monotonic_ns()
        with self._state_lock:
            self._last_alive_ns = now
            if self._last_update_ns is not None:  # exponential average of the update interval
                dt_us = (now - self._last_update_ns) / 1000.0
                avg = self._update_interval_us
                self._update_interval_us = dt_us if avg == 0.0 else avg + 0.1 * (dt_us - avg)
            self._last_update_ns = now
        for track in update.tracks:
            if track.status == TrackStatus.LOST:
                self._forget(track.track_id)
            elif track.status in self._statuses:
                self._publish_track(track, now)
        for track_id in self._latest.evict_stale(now):
            self._rates.forget(track_id)

    def health(self) -> dict:
        """Link state and counters for the daemon's status message."""
        refused = self._refusals.counts()
        link = self._link.health()
        with self._state_lock:
            return {
                "url": link["url"],
                "link_open": link["link_open"],
                "last_link_error": link["last_link_error"],
                "heartbeat": self._is_healthy_locked(),
                "signing": link["signing"],
                "sent": link["sent"],
                "send_errors": link["send_errors"],
                "last_send_error": link["last_send_error"],
                "local": link["local"],
                "commands_from": self._link.peers.describe(),
                "refused": sum(refused.values()),
                "refusals": refused,
                "refused_unsigned": refused["unsigned"] + refused["bad_signature"] + refused["replay"],
                "signed_streams": len(self._link.streams),
                "commands": self._commands,
                "intervals_us": {
                    messages.TRACK_MESSAGE_NAMES[m]: self._rates.interval_us(m)
                    for m in self._rates.message_ids
                },
            }

    def failing(self) -> str | None:
        """Why nothing goes out right now (the link is not open), or None."""
        if not self._link.is_open and not self._stop.is_set():
            return f"link not open: {self._link.last_error or 'opening'}"
        return None

    def fault_counts(self) -> dict[str, int]:
        """Input refused since start (every reason of ``refusals.REASONS`` together)."""
        return {"refused": self._refusals.total()}

    def close(self) -> None:
        """Stop the threads, save the signing timestamp, close the link. Idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._link.stop()
        for t in self._threads:
            t.join(1.0)
        self._link.close()
        self._refusals.flush(float("inf"))  # whatever was refused since the last line

    # ------------------------------------------------------------------ publishing

    def _publish_track(self, track: Track, now_ns: int) -> None:
        try:
            out = messages.track_messages(
                self._d,
                track,
                unix_time_us(track.t_ns),
                self._q_sensor,
                self._geo,
                self._icao_base,
                self._simulated,
            )
        except (ValueError, FloatingPointError) as exc:
            log.debug("track %s not published: %s", track.track_id, exc)
            return
        self._latest.put(track.track_id, now_ns, dict(out))
        for msg_id, msg in out:
            if self._rates.should_send(msg_id, track.track_id, now_ns):
                self._link.send(msg)

    def _forget(self, track_id: int) -> None:
        self._latest.forget(track_id)
        self._rates.forget(track_id)

    def _request_message(self, message_id: int) -> list | None:
        """Messages for MAV_CMD_REQUEST_MESSAGE: None if we never send ``message_id``."""
        d = self._d
        if message_id == d.MAVLINK_MSG_ID_HEARTBEAT:
            return [messages.heartbeat(d, self._mav_type)] if self.is_healthy() else []
        if message_id == d.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            return [messages.autopilot_version(d, self._version)]
        if message_id == 300 and hasattr(d, "MAVLink_protocol_version_message"):
            # PROTOCOL_VERSION: only in pymavlink wheels older than its 2025 removal from common.xml.
            return [d.MAVLink_protocol_version_message(200, 200, 200, [0] * 8, [0] * 8)]
        if message_id in (d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, d.MAVLINK_MSG_ID_HOME_POSITION):
            return self._own_position(message_id)
        if self._rates.supports(message_id):
            return self._latest.of(message_id)
        return None

    def _own_position(self, message_id: int) -> list | None:
        """GLOBAL_POSITION_INT or HOME_POSITION of the sensor; None without ``--camera-geo``."""
        if self._geo is None:
            return None
        if message_id == self._d.MAVLINK_MSG_ID_HOME_POSITION:
            return [home_position(self._d, self._geo)]
        uptime_ms = (time.monotonic_ns() - self._started_ns) // 1_000_000
        return [global_position_int(self._d, self._geo, uptime_ms)]

    def _default_interval_us(self, message_id: int) -> int:
        with self._state_lock:
            return round(self._update_interval_us)

    # ------------------------------------------------------------------ threads

    def _housekeeping_loop(self) -> None:
        next_heartbeat = 0.0
        next_save = time.monotonic() + SAVE_INTERVAL_S
        while not self._stop.wait(_TICK_S):
            now = time.monotonic()
            try:
                self._link.open_if_due()
                if now >= next_heartbeat and self.is_healthy():
                    self._link.send(messages.heartbeat(self._d, self._mav_type))
                    for position in self._own_position(self._d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT) or ():
                        self._link.send(position)
                    next_heartbeat = now + self._heartbeat_period_s
                # A command's stream timestamp is on disk within a tick, so a capture of it is a
                # replay after a restart; other signed messages change nothing and wait for the rest.
                if self._save_streams_soon or now >= next_save:
                    self._save_streams_soon = False
                    self._link.streams.save()
                if now >= next_save:
                    self._link.save_signing_timestamp()
                    next_save = now + SAVE_INTERVAL_S
                self._refusals.flush()
            except Exception:  # a bug here must not silently end the heartbeat for good
                log.exception("MAVLink housekeeping failed; continuing")
                self._stop.wait(1.0)

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            if not self._link.is_open:
                self._stop.wait(_RECV_POLL_S)
                continue
            try:
                self._receive_once()
            except Exception:  # a bug in a handler must not end the two-way link for good
                log.exception("MAVLink receive failed; continuing")
                self._stop.wait(1.0)

    def _receive_once(self) -> None:
        """Wait up to ``_RECV_POLL_S`` for what an admitted peer sends, and answer what asks for it."""
        received = self._link.receive(_RECV_POLL_S)
        if received is None:
            return
        for msg in received.messages:
            replies = self._handler.handle(msg)
            if replies:
                with self._state_lock:
                    self._commands += 1
                self._save_streams_soon = self._link.key is not None
            for reply in replies:
                self._link.send(reply, reply_to=received.peer if received.datagram else None)
