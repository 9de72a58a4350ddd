"""The MAVLink output (docs/design.md §6.2): heartbeat, target messages, two-way commands, signing.

What goes out, all MAVLink 2 from our own system/component ids:

- HEARTBEAT once a second while the pipeline is healthy (see ``MavlinkSink.set_healthy``);
- TARGET_RELATIVE (511) per track update, in the sensor's FRD frame (``messages`` module);
- TARGET_ABSOLUTE (510) and ADSB_VEHICLE (246) per track update when the camera's geodetic pose
  is configured;
- replies to PING, MAV_CMD_REQUEST_MESSAGE and MAV_CMD_SET_MESSAGE_INTERVAL (``commands`` module).

What comes in is read only from admitted peers (``peers``: the link's own peer, the first one heard,
or ``allow``), one UDP datagram at a time (``framing``), and with signing on only when correctly
signed and newer than its stream's last message, which survives restarts (``verify``). Everything
refused is counted by reason and logged at a bounded rate (``refusals``).

Threads: the daemon's ``SinkWorker`` calls ``handle_update``; a housekeeping thread sends the
heartbeat, (re)opens the link with backoff and saves the signing timestamp; a receive thread parses
what ground stations send and answers. One lock serialises the pymavlink encoder/parser, whose
sequence numbers and signing state are not thread-safe. Nothing here blocks on the network: UDP
sends never wait, and a link that cannot be opened (TCP peer absent, serial device missing) is
retried in the background while messages for it are dropped and counted.
"""

from __future__ import annotations

import collections
import contextlib
import importlib.metadata
import logging
import os
import socket
import threading
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.target_state import (
    DEFAULT_ICAO_BASE,
    PUBLISHED_STATUSES,
    target_geodetic,
    validate_icao_base,
    validate_statuses,
)
from dronekey.types import Track, TrackStatus

from . import messages
from .commands import CommandHandler
from .dialect import load_dialect
from .framing import parse_datagram
from .link import (
    is_datagram,
    local_address,
    open_link,
    read_datagram,
    send_datagram_to,
    validate_url,
)
from .peers import PeerPolicy
from .refusals import Refusals
from .signing import (
    SAVE_INTERVAL_S,
    SigningTimestampStore,
    default_state_dir,
    now_signing_timestamp,
    read_signing_key,
)
from .streams import StreamRates
from .verify import DEFAULT_MAX_STREAMS, SignatureCheck, StreamTimestamps

__all__ = ["DEFAULT_COMPID", "DEFAULT_SYSID", "DEFAULT_URL", "MavlinkSink"]

log = logging.getLogger(__name__)

DEFAULT_URL = "udpout:127.0.0.1:14550"
DEFAULT_SYSID = 42
DEFAULT_COMPID = 191  # MAV_COMP_ID_ONBOARD_COMPUTER

_TICK_S = 0.1
_RECV_POLL_S = 0.2
_RETRY_MIN_S, _RETRY_MAX_S = 1.0, 30.0
_TRACK_STALE_S = 5.0
_MAX_UDP_CLIENTS = 16  # a listening link sends to at most this many admitted peers, last heard kept
_MSG_TARGET_ABSOLUTE, _MSG_TARGET_RELATIVE, _MSG_ADSB_VEHICLE = 510, 511, 246
_STREAM_NAMES = {510: "TARGET_ABSOLUTE", 511: "TARGET_RELATIVE", 246: "ADSB_VEHICLE"}


def _package_version() -> str:
    try:
        return importlib.metadata.version("dronekey")
    except importlib.metadata.PackageNotFoundError:
        return "0.0.0"


class MavlinkSink(Sink):
    """Publish tracks over MAVLink 2 and answer ground stations.

    Parameters
    ----------
    url : pymavlink connection string (``link.validate_url`` lists the accepted forms).
    sysid : our MAVLink system id, 1..254 (255 is the ground stations' and pymavlink's default).
    compid : our component id, 1..255 (default 191, MAV_COMP_ID_ONBOARD_COMPUTER).
    signing_key_file : file with the 32-byte signing key; signing is off when None.
    camera_geo : the camera's geodetic pose; TARGET_ABSOLUTE and ADSB_VEHICLE are sent only with it.
    signing_state_dir : folder of the signing timestamp file
        (``mavlink-signing-<sysid>-<compid>.timestamp``); default ``$STATE_DIRECTORY`` or the key's folder.
    mav_type : HEARTBEAT's MAV_TYPE; default MAV_TYPE_ONBOARD_CONTROLLER (not taken for a vehicle).
    statuses : track statuses that are published (default confirmed and coasting).
    icao_base : first 24-bit ADS-B address of the tracks' block (``target_state.icao_address``).
    simulated : set ADSB_VEHICLE's SIMULATED flag (for ``sim://`` sources).
    health_timeout_s : the heartbeat stops when neither a frame update nor ``set_healthy(True)``
        came for this long (a stalled or hung pipeline), s.
    heartbeat_period_s : seconds between heartbeats (1 Hz by MAVLink convention).
    dialect_cache_dir : where the generated dialect lives (``dialect.load_dialect``).
    allow : who else may send commands (``peers``): ``"HOST"``, ``"HOST:PORT"`` or a network
        ``"10.0.0.0/24"``; empty: only the link's own peer (or, on a listening link, the first heard).
    max_signed_streams : incoming signed streams whose timestamps are kept (``verify``), oldest
        evicted first; their state file is ``mavlink-signing-<sysid>-<compid>.streams`` beside the
        signing timestamp.
    refusal_log_period_s : at most one log line about refused input per this many seconds.

    Health: the daemon calls ``set_healthy(bool)`` when the pipeline's state changes, or puts
    ``"healthy": bool`` in the status dict it gives ``handle_status``; frame updates also count as
    signs of life. Heartbeats go out while the last word was healthy and a sign of life came within
    ``health_timeout_s``.
    """

    name = "mavlink"

    def __init__(
        self,
        url: str = DEFAULT_URL,
        sysid: int = DEFAULT_SYSID,
        compid: int = DEFAULT_COMPID,
        signing_key_file: str | os.PathLike | None = None,
        camera_geo: CameraGeo | None = None,
        *,
        signing_state_dir: str | os.PathLike | None = None,
        mav_type: int | None = None,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
        icao_base: int = DEFAULT_ICAO_BASE,
        simulated: bool = False,
        health_timeout_s: float = 5.0,
        heartbeat_period_s: float = 1.0,
        dialect_cache_dir: str | os.PathLike | None = None,
        allow: Iterable[str] = (),
        max_signed_streams: int = DEFAULT_MAX_STREAMS,
        refusal_log_period_s: float = 60.0,
    ) -> None:
        self._url = validate_url(url)
        scheme = self._url.partition(":")[0]
        if isinstance(allow, str):
            raise TypeError(f"allow must be a list of HOST or HOST:PORT strings, got the string {allow!r}")
        # Links that name no peer pin the first one heard; tcpin by host, as a reconnecting client
        # comes from a new port.
        self._peers = PeerPolicy(
            allow, pin_first=scheme in ("udpin", "udp", "udpbcast", "tcpin"), pin_port=scheme != "tcpin"
        )
        self._refusals = Refusals(refusal_log_period_s)
        if not isinstance(sysid, int) or not 1 <= sysid <= 254:
            raise ValueError(f"sysid must be an integer in 1..254, got {sysid!r}")
        if not isinstance(compid, int) or not 1 <= compid <= 255:
            raise ValueError(f"compid must be an integer in 1..255, got {compid!r}")
        if camera_geo is not None and not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo or None, got {type(camera_geo).__name__}")
        if not health_timeout_s > 0:
            raise ValueError(f"health_timeout_s must be > 0, got {health_timeout_s!r}")
        if not heartbeat_period_s > 0:
            raise ValueError(f"heartbeat_period_s must be > 0, got {heartbeat_period_s!r}")
        self._sysid, self._compid = sysid, compid
        self._geo = camera_geo
        self._statuses = validate_statuses(statuses)
        self._icao_base = validate_icao_base(icao_base)
        self._simulated = bool(simulated)
        self._health_timeout_ns = int(health_timeout_s * 1e9)
        self._heartbeat_period_s = float(heartbeat_period_s)

        self._key: bytes | None = None
        self._ts_store: SigningTimestampStore | None = None
        self._streams = StreamTimestamps(None, max_signed_streams)
        if signing_key_file is not None:
            self._key = read_signing_key(signing_key_file)
            state_dir = (
                Path(signing_state_dir)
                if signing_state_dir is not None
                else default_state_dir(signing_key_file)
            )
            stem = state_dir / f"mavlink-signing-{sysid}-{compid}"
            self._ts_store = SigningTimestampStore(stem.with_suffix(".timestamp"))
            self._streams = StreamTimestamps(stem.with_suffix(".streams"), max_signed_streams)
        self._check = SignatureCheck(self._streams, self._note_signing_refusal)
        self._source: str | None = None  # sender of the datagram being parsed (under _io_lock)
        self._save_streams_soon = False
        self._local: str | None = None

        self._d = load_dialect(dialect_cache_dir)
        self._mav_type = self._d.MAV_TYPE_ONBOARD_CONTROLLER if mav_type is None else int(mav_type)
        self._q_sensor = messages.sensor_quaternion(camera_geo)
        self._version = _package_version()
        streams = [_MSG_TARGET_RELATIVE] + ([_MSG_TARGET_ABSOLUTE, _MSG_ADSB_VEHICLE] if camera_geo else [])
        self._rates = StreamRates(streams)
        self._handler = CommandHandler(
            self._d, sysid, compid, self._rates, self._request_message, self._default_interval_us
        )

        self._io_lock = threading.Lock()  # the connection and its pymavlink encoder/parser
        self._state_lock = threading.Lock()  # health, latest messages, counters
        self._conn = None
        self._retry_s = _RETRY_MIN_S
        self._next_open_mono = 0.0
        self._last_link_error: str | None = None
        self._last_signing_ts = 0
        self._healthy = True
        self._last_alive_ns: int | None = None
        self._latest: dict[int, tuple[int, dict[int, object]]] = {}
        self._last_update_ns: int | None = None
        self._update_interval_us = 0.0
        self._sent: collections.Counter = collections.Counter()
        self._send_errors = 0
        self._last_send_error: str | None = None
        self._commands = 0

        self._stop = threading.Event()
        self._open_link()
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
            if bool(healthy) != self._healthy:
                log.info(
                    "MAVLink heartbeat %s", "resumes (pipeline healthy)" if healthy else "stops (unhealthy)"
                )
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
        self._evict_stale(now)

    def health(self) -> dict:
        """Link state and counters for the daemon's status message."""
        refused = self._refusals.counts()
        with self._state_lock:
            return {
                "url": self._url,
                "link_open": self._conn is not None,
                "last_link_error": self._last_link_error,
                "heartbeat": self._is_healthy_locked(),
                "signing": self._key is not None,
                "sent": dict(self._sent),
                "send_errors": self._send_errors,
                "last_send_error": self._last_send_error,
                "local": self._local,
                "commands_from": self._peers.describe(),
                "refused": sum(refused.values()),
                "refusals": refused,
                "refused_unsigned": refused["unsigned"] + refused["bad_signature"] + refused["replay"],
                "signed_streams": len(self._streams),
                "commands": self._commands,
                "intervals_us": {
                    _STREAM_NAMES[m]: self._rates.interval_us(m) for m in self._rates.message_ids
                },
            }

    def failing(self) -> str | None:
        """Why nothing goes out right now (the link is not open), or None."""
        with self._state_lock:
            if self._conn is None and not self._stop.is_set():
                return f"link not open: {self._last_link_error or 'opening'}"
        return None

    def fault_counts(self) -> dict[str, int]:
        """Input refused since start (every reason of ``refusals.REASONS`` together)."""
        return {"refused": self._refusals.total()}

    def close(self) -> None:
        """Stop the threads, save the signing timestamp, close the link. Idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        for t in self._threads:
            t.join(1.0)
        with self._io_lock:
            self._save_signing_timestamp()
            conn, self._conn = self._conn, None
        self._streams.save()
        self._refusals.flush(float("inf"))  # whatever was refused since the last line
        if conn is not None:
            try:
                conn.close()
            except Exception as exc:
                log.debug("closing the MAVLink link: %s", exc)

    # ------------------------------------------------------------------ publishing

    def _publish_track(self, track: Track, now_ns: int) -> None:
        try:
            out = self._encode_track(track)
        except (ValueError, FloatingPointError) as exc:
            log.debug("track %s not published: %s", track.track_id, exc)
            return
        with self._state_lock:
            self._latest[track.track_id] = (now_ns, dict(out))
        for msg_id, msg in out:
            if self._rates.should_send(msg_id, track.track_id, now_ns):
                self._send(msg)

    def _encode_track(self, track: Track) -> list[tuple[int, object]]:
        if not np.all(np.isfinite(np.asarray(track.position_m, dtype=np.float64))):
            raise ValueError("position is not finite")
        t_us = messages.unix_time_us(track.t_ns)
        out = [(_MSG_TARGET_RELATIVE, messages.target_relative(self._d, track, self._q_sensor, t_us))]
        if self._geo is not None:
            state = target_geodetic(track, self._geo)
            out.append(
                (_MSG_TARGET_ABSOLUTE, messages.target_absolute(self._d, track, state, self._geo, t_us))
            )
            out.append(
                (
                    _MSG_ADSB_VEHICLE,
                    messages.adsb_vehicle(self._d, track, state, self._icao_base, self._simulated),
                )
            )
        return out

    def _forget(self, track_id: int) -> None:
        with self._state_lock:
            self._latest.pop(track_id, None)
        self._rates.forget(track_id)

    def _evict_stale(self, now_ns: int) -> None:
        limit = now_ns - int(_TRACK_STALE_S * 1e9)
        with self._state_lock:
            stale = [tid for tid, (t, _) in self._latest.items() if t < limit]
        for tid in stale:
            self._forget(tid)

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
        if self._rates.supports(message_id):
            with self._state_lock:
                return [m[message_id] for _, m in self._latest.values() if message_id in m]
        return None

    def _default_interval_us(self, message_id: int) -> int:
        with self._state_lock:
            return round(self._update_interval_us)

    # ------------------------------------------------------------------ link and I/O

    def _send(self, msg, reply_to: tuple[str, int] | None = None) -> bool:
        """Send ``msg`` on the link; a reply on a UDP link that sends to one destination goes to
        ``reply_to`` instead (an allow-listed station that is not the udpout target)."""
        with self._io_lock:
            conn = self._conn
            if conn is None:
                self._count_send_error("link not open")
                return False
            try:
                if self._key is not None:
                    sig = conn.mav.signing
                    sig.timestamp = max(sig.timestamp, now_signing_timestamp())
                if reply_to is not None and is_datagram(conn) and not conn.udp_server:
                    send_datagram_to(conn, msg, reply_to)
                else:
                    conn.mav.send(msg)
                if self._key is not None:
                    self._last_signing_ts = conn.mav.signing.timestamp
            except Exception as exc:  # pymavlink's writers swallow socket errors; serial ones may not
                self._count_send_error(f"{type(exc).__name__}: {exc}")
                if isinstance(exc, OSError) and reply_to is None:
                    self._drop_link_locked(exc)
                return False
        with self._state_lock:
            self._sent[msg.get_type()] += 1
        return True

    def _count_send_error(self, what: str) -> None:
        with self._state_lock:
            self._send_errors += 1
            self._last_send_error = what

    def _open_link(self) -> None:
        """Open the link if it is closed and its retry time has come; never raises."""
        with self._io_lock:
            if self._conn is not None or self._stop.is_set() or time.monotonic() < self._next_open_mono:
                return
            try:
                self._peers.resolve(_named_peer(self._url))
                conn = open_link(self._url, self._d, self._sysid, self._compid)
            except Exception as exc:
                msg = f"{type(exc).__name__}: {exc}"
                if msg != self._last_link_error:
                    log.warning(
                        "MAVLink link %s cannot be opened (%s); retrying in the background", self._url, msg
                    )
                self._last_link_error = msg
                self._next_open_mono = time.monotonic() + self._retry_s
                self._retry_s = min(self._retry_s * 2, _RETRY_MAX_S)
                return
            if self._key is not None:
                start = max(self._ts_store.initial_timestamp(), self._last_signing_ts + 1)
                conn.setup_signing(
                    self._key,
                    sign_outgoing=True,
                    allow_unsigned_callback=self._check.refuse,
                    initial_timestamp=start,
                    link_id=1,
                )
                self._check.install(conn.mav)
                self._last_signing_ts = start
            self._conn = conn
            self._local = local_address(conn)
            self._retry_s = _RETRY_MIN_S
            self._last_link_error = None
        log.info(
            "MAVLink on %s%s as system %d component %d, signing %s; commands only from %s",
            self._url,
            f" (socket {self._local})" if self._local else "",
            self._sysid,
            self._compid,
            "on" if self._key is not None else "off",
            self._peers.describe(),
        )

    def _drop_link_locked(self, exc: BaseException) -> None:
        """Close a failed link (caller holds ``_io_lock``); the housekeeping thread reopens it."""
        self._save_signing_timestamp()
        self._streams.save()
        conn, self._conn = self._conn, None
        self._last_link_error = f"{type(exc).__name__}: {exc}"
        log.warning(
            "MAVLink link %s failed (%s); reopening in the background", self._url, self._last_link_error
        )
        self._next_open_mono = time.monotonic() + self._retry_s
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()

    def _note_signing_refusal(self, reason: str) -> None:
        """``SignatureCheck``'s report (called while parsing, under ``_io_lock``)."""
        self._refusals.note(reason, self._source)

    def _save_signing_timestamp(self) -> None:
        if self._ts_store is not None and self._last_signing_ts:
            self._ts_store.save(self._last_signing_ts)

    def _housekeeping_loop(self) -> None:
        next_heartbeat = 0.0
        next_save = time.monotonic() + SAVE_INTERVAL_S
        while not self._stop.wait(_TICK_S):
            now = time.monotonic()
            try:
                self._open_link()
                if now >= next_heartbeat and self.is_healthy():
                    self._send(messages.heartbeat(self._d, self._mav_type))
                    next_heartbeat = now + self._heartbeat_period_s
                # A command's stream timestamp is on disk within a tick, so a capture of it is a
                # replay after a restart; other signed messages change nothing and wait for the rest.
                if self._save_streams_soon or now >= next_save:
                    self._save_streams_soon = False
                    self._streams.save()
                if now >= next_save:
                    with self._io_lock:
                        self._save_signing_timestamp()
                    next_save = now + SAVE_INTERVAL_S
                self._refusals.flush()
            except Exception:  # a bug here must not silently end the heartbeat for good
                log.exception("MAVLink housekeeping failed; continuing")
                self._stop.wait(1.0)

    def _receive_loop(self) -> None:
        while not self._stop.is_set():
            conn = self._conn
            if conn is None:
                self._stop.wait(_RECV_POLL_S)
                continue
            try:
                self._receive_once(conn)
            except Exception:  # a bug in a handler must not end the two-way link for good
                log.exception("MAVLink receive failed; continuing")
                self._stop.wait(1.0)

    def _receive_once(self, conn) -> None:
        """Wait up to ``_RECV_POLL_S`` for data on ``conn``, parse it and answer what asks for it."""
        from pymavlink import mavutil

        datagram = is_datagram(conn)
        try:
            if not conn.select(_RECV_POLL_S):
                return
            if datagram:
                data, peer = read_datagram(conn)
            else:
                data, peer = conn.recv(), _stream_peer(conn)
        except Exception as exc:
            if not self._stop.is_set():
                with self._io_lock:
                    if self._conn is conn:
                        self._drop_link_locked(exc)
            return
        if not data:
            if isinstance(conn, mavutil.mavtcp) or getattr(conn, "portdead", False):
                with self._io_lock:  # readable and empty: the stream peer closed
                    if self._conn is conn:
                        self._drop_link_locked(ConnectionError("peer closed the connection"))
            return
        source = f"{peer[0]}:{peer[1]}" if peer is not None else None
        if peer is not None and not self._peers.admits(peer):
            self._refusals.note("peer", source)
            if isinstance(conn, mavutil.mavtcpin):
                self._drop_tcp_client(conn)
            return
        with self._io_lock:
            if self._conn is not conn:
                return
            self._source = source
            try:
                if datagram:
                    received, malformed = parse_datagram(conn.mav, data)
                else:
                    received, malformed = conn.mav.parse_buffer(data) or [], False
            finally:
                self._source = None
        if malformed:
            self._refusals.note("malformed", source)
        valid = [m for m in received if m.get_type() != "BAD_DATA"]
        if not valid:
            return
        if peer is not None:
            self._peers.confirm(peer)
            if datagram:
                self._remember_client(conn, peer)
        for msg in valid:
            replies = self._handler.handle(msg)
            if replies:
                with self._state_lock:
                    self._commands += 1
                self._save_streams_soon = self._key is not None
            for reply in replies:
                self._send(reply, reply_to=peer if datagram else None)

    def _remember_client(self, conn, peer: tuple[str, int]) -> None:
        """An admitted peer was heard: a listening link sends to it, a broadcast link switches to it."""
        with self._io_lock:
            if self._conn is not conn:
                return
            if conn.udp_server:
                conn.clients.add(peer)
                conn.clients_last_alive[peer] = time.time()
                while len(conn.clients) > _MAX_UDP_CLIENTS:
                    oldest = min(conn.clients, key=lambda a: conn.clients_last_alive.get(a, 0.0))
                    conn.clients.discard(oldest)
                    conn.clients_last_alive.pop(oldest, None)
            elif conn.broadcast:
                conn.last_address = peer

    def _drop_tcp_client(self, conn) -> None:
        """Hang up on a tcpin client that is not admitted; the link keeps listening."""
        with self._io_lock:
            if self._conn is conn and conn.port is not None:
                with contextlib.suppress(OSError):
                    conn.port.close()
                conn.port = None
                conn.fd = conn.listen.fileno()


def _named_peer(url: str) -> tuple[str, int] | None:
    """The peer a URL names (udpout and tcp targets), resolved; None for listening and serial links."""
    scheme, _, rest = url.partition(":")
    if scheme not in ("udpout", "tcp"):
        return None
    host, _, port = rest.rpartition(":")
    return socket.gethostbyname(host), int(port)


def _stream_peer(conn) -> tuple[str, int] | None:
    """The client of a tcpin link (checked against the peers); None for tcp and serial links."""
    from pymavlink import mavutil

    if isinstance(conn, mavutil.mavtcpin) and conn.port is not None:
        try:
            return conn.port.getpeername()[:2]
        except OSError:
            return None
    return None
