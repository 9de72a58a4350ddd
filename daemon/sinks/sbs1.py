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
constructor refuses. Clients connect and only read; several may be connected. A listen address
without a host (``30003``, ``:30003``) binds 127.0.0.1: serving the network is explicit, and logged
as a warning (the lines are unauthenticated and tell anyone where the drones are).

Writes never block the caller: each client has a bounded buffer. A client that falls behind by more
than ``max_pending_bytes``, or that accepts no byte for ``idle_timeout_s`` while data waits for it
(it stopped reading: its receive buffer and our socket buffer are full), is disconnected, so clients
that connect and never read cannot hold the slots for long. When every slot is taken, a newcomer
replaces the client that has been stuck longest, if any is; otherwise it is refused. A client that
never reads is noticed only once its kernel buffers are full: TCP gives the server no other sign.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import ipaddress
import logging
import math
import selectors
import socket
import threading
import time
from collections.abc import Iterable

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.mavlink.messages import unix_time_us
from dronekey.daemon.sinks.target_state import (
    DEFAULT_ICAO_BASE,
    PUBLISHED_STATUSES,
    TargetGeodetic,
    callsign,
    icao_address,
    target_geodetic,
    validate_icao_base,
    validate_statuses,
)
from dronekey.types import TrackStatus

__all__ = ["Sbs1Sink", "is_loopback", "parse_listen_address", "sbs1_lines"]

log = logging.getLogger(__name__)

FT_PER_M = 1.0 / 0.3048
KT_PER_MPS = 3600.0 / 1852.0
FPM_PER_MPS = 60.0 * FT_PER_M
_POLL_S = 0.5
_CLIENT_SNDBUF = 64 * 1024
DEFAULT_HOST = "127.0.0.1"
DEFAULT_IDLE_TIMEOUT_S = 10.0
_EVICT_AFTER_S = 1.0  # a client stuck this long may be replaced by a newcomer when every slot is taken


def parse_listen_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``[IPV6]:PORT``, ``:PORT`` or ``PORT`` -> (host, port); no host is 127.0.0.1.

    Port 0 picks a free one.
    """
    text = str(text).strip()
    host, _, port = text.rpartition(":")
    bracketed = host.startswith("[") and host.endswith("]")
    host = host[1:-1] if bracketed else host
    if (
        not port.isdigit()
        or not 0 <= int(port) < 65536
        or (bracketed and not host)
        or (":" in host) != bracketed
    ):
        raise ValueError(
            f"sbs1.listen = {text!r}: must be PORT, :PORT (both on 127.0.0.1) or HOST:PORT "
            "with a port in 0-65535, e.g. 30003 or 0.0.0.0:30003 (the network)"
        )
    return host or DEFAULT_HOST, int(port)


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``: addresses only this machine reaches."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


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
    listen : ``PORT`` or ``:PORT`` (127.0.0.1), or ``HOST:PORT`` (``0.0.0.0:30003``: every
        interface); 30003 is the usual port, 0 picks a free one.
    camera_geo : the camera's geodetic pose (required).
    statuses : track statuses that are published (default confirmed and coasting).
    icao_base : first 24-bit address of the tracks' block (same as the MAVLink sink's).
    max_clients : connections accepted at once; more are closed at once.
    max_pending_bytes : a client further behind than this is disconnected.
    callsign_period_s : how often a track's MSG,1 (callsign) line is repeated, s.
    idle_timeout_s : a client that accepts no byte for this long while data waits is disconnected.
    """

    name = "sbs1"

    def __init__(
        self,
        listen: str,
        camera_geo: CameraGeo | None,
        *,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
        icao_base: int = DEFAULT_ICAO_BASE,
        max_clients: int = 16,
        max_pending_bytes: int = 64 * 1024,
        callsign_period_s: float = 5.0,
        idle_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S,
    ) -> None:
        if camera_geo is None:
            raise ValueError(
                "the SBS-1 output (--sbs1-listen) needs the camera's geodetic pose "
                "(--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL): its lines carry latitude and longitude"
            )
        if not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo, got {type(camera_geo).__name__}")
        if max_clients < 1:
            raise ValueError(f"max_clients must be >= 1, got {max_clients}")
        if max_pending_bytes < 1024:
            raise ValueError(f"max_pending_bytes must be >= 1024, got {max_pending_bytes}")
        if not 0 < idle_timeout_s <= 3600:
            raise ValueError(f"sbs1.idle_timeout_s must be in (0, 3600] s, got {idle_timeout_s}")
        host, port = parse_listen_address(listen)
        self._geo = camera_geo
        self._statuses = validate_statuses(statuses)
        self._icao_base = validate_icao_base(icao_base)
        self._max_clients = max_clients
        self._max_pending = max_pending_bytes
        self._callsign_period_ns = int(callsign_period_s * 1e9)
        self._idle_timeout_s = float(idle_timeout_s)
        try:
            family = socket.AF_INET6 if ":" in host else socket.AF_INET
            self._server = socket.create_server((host, port), family=family, backlog=8)
        except OSError as exc:
            raise OSError(exc.errno, f"SBS-1 output cannot listen on {listen!r}: {exc.strerror}") from None
        self._server.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)

        self._lock = threading.Lock()
        self._pending: dict[socket.socket, bytearray] = {}
        # monotonic s since which data has waited for a client that accepted none of it
        self._stuck_since: dict[socket.socket, float] = {}
        self._to_drop: set[socket.socket] = set()
        self._callsign_due: dict[int, int] = {}
        self._stats = {
            "lines": 0,
            "clients_total": 0,
            "clients_dropped_slow": 0,
            "clients_dropped_idle": 0,
            "clients_refused": 0,
        }
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="sbs1-server", daemon=True)
        self._thread.start()
        bound = "{}:{}".format(*self.address[:2])
        if is_loopback(host):
            log.info("SBS-1 output listening on %s (this machine only)", bound)
        else:
            log.warning(
                "SBS-1 output listening on %s: open to the network, unauthenticated (sbs1.listen = %r)",
                bound,
                listen,
            )

    @property
    def address(self) -> tuple:
        """The bound socket address (host, port, ...)."""
        return self._server.getsockname()

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
        waiting_since = time.monotonic()
        with self._lock:
            self._stats["lines"] += len(lines)
            for client, buf in self._pending.items():
                if client in self._to_drop:
                    continue
                if buf and len(buf) + len(data) > self._max_pending:  # behind by more than allowed
                    self._to_drop.add(client)
                    self._stats["clients_dropped_slow"] += 1
                else:
                    if not buf:  # data waits from now on; a send that makes progress resets this
                        self._stuck_since[client] = waiting_since
                    buf += data
        self._wake()

    def health(self) -> dict:
        with self._lock:
            return {
                "listen": "{}:{}".format(*self.address[:2]),
                "clients": len(self._pending),
                "clients_stalled": len(self._stuck_since),  # accepting nothing while data waits
                **self._stats,
            }

    def close(self) -> None:
        """Stop serving and disconnect every client. Idempotent."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._wake()
        self._thread.join(2.0)
        with self._lock:
            clients = list(self._pending)
            self._pending.clear()
        for s in (*clients, self._server, self._wake_r, self._wake_w):
            s.close()

    # ------------------------------------------------------------------ server thread

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # a full wake-up pipe means the server is awake already
            self._wake_w.send(b"\0")

    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._server, selectors.EVENT_READ)
        sel.register(self._wake_r, selectors.EVENT_READ)
        try:
            while not self._stop.is_set():
                self._mark_idle()
                self._drop_marked(sel)
                with self._lock:
                    for client, buf in self._pending.items():
                        events = selectors.EVENT_READ | (selectors.EVENT_WRITE if buf else 0)
                        sel.modify(client, events)
                for key, mask in sel.select(_POLL_S):
                    if key.fileobj is self._server:
                        self._accept(sel)
                    elif key.fileobj is self._wake_r:
                        self._drain_wake()
                    else:
                        self._service(key.fileobj, mask)
        except Exception:
            if not self._stop.is_set():
                log.exception("SBS-1 server failed; the output is stopped")
        finally:
            sel.close()

    def _drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except OSError:
            pass

    def _accept(self, sel: selectors.BaseSelector) -> None:
        while True:
            try:
                client, peer = self._server.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. out of file descriptors: try again on the next event
                log.warning("SBS-1 output cannot accept a client: %s", exc)
                return
            with self._lock:
                full = len(self._pending) - len(self._to_drop) >= self._max_clients
                if full and self._evict_stuck():
                    full = False
                if full:
                    self._stats["clients_refused"] += 1
                else:
                    client.setblocking(False)
                    # Bound what the kernel holds too, so a stalled client is noticed while its
                    # data is seconds old, not megabytes later (ample for SBS-1's few kB/s).
                    client.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, _CLIENT_SNDBUF)
                    self._pending[client] = bytearray()
                    self._stats["clients_total"] += 1
            if full:
                log.warning("SBS-1 output refused %s: already %d clients", peer, self._max_clients)
                client.close()
                continue
            sel.register(client, selectors.EVENT_READ)
            log.info("SBS-1 client connected from %s", peer)

    def _service(self, client: socket.socket, mask: int) -> None:
        if mask & selectors.EVENT_READ:
            try:
                data = client.recv(4096)  # clients have nothing to say; read to notice them leave
            except (BlockingIOError, InterruptedError):
                data = b"-"
            except OSError:
                data = b""
            if not data:
                self._mark_drop(client)
                return
        if mask & selectors.EVENT_WRITE:
            with self._lock:
                buf = self._pending.get(client)
                if not buf:
                    return
                try:
                    sent = client.send(buf)
                except (BlockingIOError, InterruptedError):
                    sent = 0
                except OSError:
                    self._to_drop.add(client)
                    return
                del buf[:sent]
                if not buf:
                    self._stuck_since.pop(client, None)
                elif sent:  # progress restarts the idle clock
                    self._stuck_since[client] = time.monotonic()

    def _mark_idle(self) -> None:
        """Mark for dropping the clients that accepted nothing for ``idle_timeout_s`` while data waited."""
        now = time.monotonic()
        with self._lock:
            idle = [
                (client, now - since)
                for client, since in self._stuck_since.items()
                if now - since >= self._idle_timeout_s and client not in self._to_drop
            ]
            self._to_drop.update(client for client, _ in idle)
            self._stats["clients_dropped_idle"] += len(idle)
        for client, seconds in idle:
            log.warning(
                "SBS-1 client %s read nothing for %.1f s (sbs1.idle_timeout_s = %g): disconnecting",
                _peer(client),
                seconds,
                self._idle_timeout_s,
            )

    def _evict_stuck(self) -> bool:
        """Every slot is taken: drop the client stuck longest to make room (caller holds the lock)."""
        # Stuck for a moment is normal (data is sent within milliseconds); a second is not.
        cutoff = time.monotonic() - min(_EVICT_AFTER_S, self._idle_timeout_s)
        stuck = [
            (since, c) for c, since in self._stuck_since.items() if since <= cutoff and c not in self._to_drop
        ]
        if not stuck:
            return False
        _, client = min(stuck, key=lambda item: item[0])
        self._to_drop.add(client)
        self._stats["clients_dropped_idle"] += 1
        log.warning("SBS-1 client %s reads nothing and every slot is taken: disconnecting", _peer(client))
        return True

    def _mark_drop(self, client: socket.socket) -> None:
        with self._lock:
            self._to_drop.add(client)

    def _drop_marked(self, sel: selectors.BaseSelector) -> None:
        with self._lock:
            dropped, self._to_drop = self._to_drop, set()
            for client in dropped:
                self._pending.pop(client, None)
                self._stuck_since.pop(client, None)
        for client in dropped:
            peer = _peer(client)
            with contextlib.suppress(KeyError, ValueError):
                sel.unregister(client)
            client.close()
            log.info("SBS-1 client %s disconnected", peer)


def _peer(client: socket.socket) -> object:
    try:
        return client.getpeername()
    except OSError:
        return "?"
