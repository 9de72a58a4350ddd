"""The TCP side of the SBS-1 output: every client gets the same lines, and none can block the sender.

Clients connect and only read; several may be connected. A listen address without a host binds
127.0.0.1 (``Sbs1Config``): serving the network is explicit, and logged as a warning (the lines are
unauthenticated and tell anyone where the drones are).

Writes never block the caller: each client has a bounded buffer. A client that falls behind by more
than ``max_pending_bytes``, or that accepts no byte for ``idle_timeout_s`` while data waits for it
(it stopped reading: its receive buffer and our socket buffer are full), is disconnected, so clients
that connect and never read cannot hold the slots for long. When every slot is taken, a newcomer
replaces the client that has been stuck longest, if any is; otherwise it is refused. A client that
never reads is noticed only once its kernel buffers are full: TCP gives the server no other sign.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import selectors
import socket
import threading
import time

from dronekey.daemon.config.sbs1 import Sbs1Config

__all__ = ["Sbs1Server", "is_loopback"]

log = logging.getLogger(__name__)

_POLL_S = 0.5
_CLIENT_SNDBUF = 64 * 1024
_EVICT_AFTER_S = 1.0  # a client stuck this long may be replaced by a newcomer when every slot is taken


def is_loopback(host: str) -> bool:
    """True for 127.0.0.0/8, ::1 and ``localhost``: addresses only this machine reaches."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


class Sbs1Server:
    """Serve bytes to every connected TCP client from a thread of its own (see the module docstring).

    Parameters
    ----------
    config : the ``sbs1`` section: ``listen`` (where; port 0 picks a free one) and ``idle_timeout_s``
        (a client that accepts no byte for this long while data waits is disconnected).
    max_clients : connections accepted at once; more are closed at once.
    max_pending_bytes : a client further behind than this is disconnected.

    Raises
    ------
    ValueError
        If ``config.listen`` is not set, or naming ``max_clients`` or ``max_pending_bytes``.
    OSError
        Naming the address, if it cannot be listened on.
    """

    def __init__(
        self, config: Sbs1Config, *, max_clients: int = 16, max_pending_bytes: int = 64 * 1024
    ) -> None:
        if max_clients < 1:
            raise ValueError(f"max_clients must be >= 1, got {max_clients}")
        if max_pending_bytes < 1024:
            raise ValueError(f"max_pending_bytes must be >= 1024, got {max_pending_bytes}")
        host, port = config.address()
        self._max_clients = max_clients
        self._max_pending = max_pending_bytes
        self._idle_timeout_s = config.idle_timeout_s
        try:
            family = socket.AF_INET6 if ":" in host else socket.AF_INET
            self._server = socket.create_server((host, port), family=family, backlog=8)
        except OSError as exc:
            raise OSError(
                exc.errno, f"SBS-1 output cannot listen on {config.listen!r}: {exc.strerror}"
            ) from None
        self._server.setblocking(False)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)

        self._lock = threading.Lock()
        self._pending: dict[socket.socket, bytearray] = {}
        # monotonic s since which data has waited for a client that accepted none of it
        self._stuck_since: dict[socket.socket, float] = {}
        self._to_drop: set[socket.socket] = set()
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
                config.listen,
            )

    @property
    def address(self) -> tuple:
        """The bound socket address (host, port, ...)."""
        return self._server.getsockname()

    def broadcast(self, data: bytes, lines: int) -> None:
        """Queue ``data`` (``lines`` SBS-1 lines) for every client; never blocks."""
        waiting_since = time.monotonic()
        with self._lock:
            self._stats["lines"] += lines
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
        """``listen`` address, ``clients`` connected and ``clients_stalled``, and the counters."""
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
