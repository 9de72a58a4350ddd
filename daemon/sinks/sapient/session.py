"""The TCP session of a SAPIENT sensor node: connect, register, report, take tasks, reconnect.

One thread owns the socket. On each connection it sends the Registration and waits for the
RegistrationAck; only once accepted do detection reports go out (``accepting()``). It answers every
Task with a TaskAck, applies the accepted ones to ``NodeState`` (reporting on or off, regions of
interest), sends a StatusReport every ``status_interval_s`` and a GOODBYE one on close, its last
word (queued reports go out before it, no status after it).

Nothing here blocks the caller: ``send_report`` puts an encoded frame on a bounded queue (the
oldest report is dropped when it is full) and returns. A peer that takes no bytes for
``send_timeout_s`` while some wait, or sends no RegistrationAck within ``registration_timeout_s``,
is disconnected; the session reconnects after a delay that doubles per failure (``reconnect_min_s``
to ``reconnect_max_s``) and registers again. Reports queued for an earlier connection are dropped.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import logging
import selectors
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from sapient_msg.bsi_flex_335_v2_0.sapient_message_pb2 import SapientMessage

from dronekey.daemon.config.sapient import SapientConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.sapient.framing import FrameDecoder, encode_frame
from dronekey.daemon.sinks.sapient.messages import task_ack_message
from dronekey.daemon.sinks.sapient.tasks import Region, TaskOutcome, interpret_task

__all__ = ["NodeState", "SapientSession"]

log = logging.getLogger(__name__)

_CONTROL_QUEUE = 64  # Registration, StatusReport, TaskAck waiting at most
_SEND_CHUNK = 64 * 1024
_GOODBYE_FLUSH_S = 1.0


@dataclass(frozen=True, slots=True)
class NodeState:
    """What the decision node has set: read by the sink thread, replaced whole by the session thread."""

    registered: bool = False
    reporting: bool = True
    regions: tuple[Region, ...] = ()
    active_task_id: str | None = None
    generation: int = 0


class _DisconnectError(Exception):
    """End this connection (the reason is the message) and reconnect after the backoff."""


class SapientSession:
    """Client side of one SAPIENT TCP connection, kept up on its own thread.

    Parameters
    ----------
    config : the ``sapient`` section (address, timings, queue size).
    node_id : this node's UUID.
    registration : builds the Registration message (called on every connection).
    status : ``status(new, active_task_id, goodbye)`` builds a StatusReport.
    camera_geo : the camera's geodetic pose, for tasks with lat/lon or true-north regions.
    """

    def __init__(
        self,
        config: SapientConfig,
        node_id: str,
        registration: Callable[[], SapientMessage],
        status: Callable[[bool, str | None, bool], SapientMessage],
        camera_geo: CameraGeo | None,
    ) -> None:
        self._config = config
        self._address = config.address()
        self._node_id = node_id
        self._registration = registration
        self._status = status
        self._geo = camera_geo
        self.state = NodeState()
        self.counts: collections.Counter[str] = collections.Counter()
        self.problem: str | None = "connecting"
        self._lock = threading.Lock()
        self._reports: collections.deque[tuple[int, bytes]] = collections.deque()
        self._control: collections.deque[bytes] = collections.deque(maxlen=_CONTROL_QUEUE)
        self._closing = threading.Event()
        self._wake_recv, self._wake_send = socket.socketpair()
        self._wake_recv.setblocking(False)
        self._wake_send.setblocking(False)
        self._thread = threading.Thread(target=self._run, name="sapient-session", daemon=True)
        self._thread.start()

    @property
    def peer(self) -> str:
        return f"{self._address[0]}:{self._address[1]}"

    # ------------------------------------------------------------------ caller side (sink thread)
    def accepting(self) -> bool:
        """Whether detection reports go out now: registered and reporting."""
        state = self.state
        return state.registered and state.reporting

    def send_report(self, message: SapientMessage, generation: int) -> None:
        """Queue a DetectionReport or Alert built under ``generation``; never blocks."""
        frame = encode_frame(message)
        with self._lock:
            if len(self._reports) >= self._config.max_queue:
                self._reports.popleft()
                self.counts["dropped"] += 1
            self._reports.append((generation, frame))
        self._wake()

    def close(self, timeout_s: float = 2.0) -> None:
        """Say GOODBYE (if registered, within a second), close the socket, stop the thread."""
        self._closing.set()
        self._wake()
        self._thread.join(timeout_s)
        self._wake_recv.close()
        self._wake_send.close()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):  # full (a wake is already pending) or closed
            self._wake_send.send(b"\0")

    # ------------------------------------------------------------------ session thread
    def _set_state(self, **changes) -> None:
        self.state = dataclasses.replace(self.state, **changes)

    def _queue_control(self, message: SapientMessage) -> None:
        with self._lock:
            self._control.append(encode_frame(message))
        self.counts[message.WhichOneof("content")] += 1

    def _run(self) -> None:
        delay = self._config.reconnect_min_s
        last_logged = None
        while not self._closing.is_set():
            try:
                sock = socket.create_connection(self._address, timeout=min(self._config.send_timeout_s, 5.0))
            except OSError as exc:
                self.problem = f"no SAPIENT node at {self.peer} ({exc.strerror or exc})"
            else:
                self.counts["connections"] += 1
                log.info("sapient: connected to %s", self.peer)
                try:
                    self._serve(sock)
                    reason = None
                except (_DisconnectError, OSError, ValueError) as exc:
                    reason = str(exc)
                finally:
                    sock.close()
                    was_registered = self.state.registered
                    self._set_state(registered=False)
                if reason is None:
                    return
                self.problem = f"disconnected from {self.peer}: {reason}"
                if was_registered:
                    delay = self._config.reconnect_min_s
            if self.problem != last_logged:
                log.warning("sapient: %s; retrying in %.1f s (and on)", self.problem, delay)
                last_logged = self.problem
            self._closing.wait(delay)
            delay = min(delay * 2.0, self._config.reconnect_max_s)

    def _serve(self, sock: socket.socket) -> None:
        """One connection, until the peer fails (raises) or the session closes (returns)."""
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        generation = self.state.generation + 1
        self._set_state(registered=False, generation=generation)
        with self._lock:
            self._reports.clear()
            self._control.clear()
        self._queue_control(self._registration())
        self.problem = f"waiting for the RegistrationAck of {self.peer}"
        decoder = FrameDecoder()
        pending = bytearray()
        now = time.monotonic()
        ack_deadline = now + self._config.registration_timeout_s
        last_progress = now
        next_status = None
        goodbye_deadline = None
        with selectors.DefaultSelector() as selector:
            selector.register(sock, selectors.EVENT_READ)
            selector.register(self._wake_recv, selectors.EVENT_READ)
            while True:
                now = time.monotonic()
                if self._closing.is_set() and goodbye_deadline is None:
                    if not self.state.registered:
                        return
                    self._queue_reports_as_control(generation)  # the goodbye is the last word
                    self._queue_control(self._status(False, self.state.active_task_id, True))
                    goodbye_deadline = now + _GOODBYE_FLUSH_S
                if (
                    goodbye_deadline is None
                    and self.state.registered
                    and next_status is not None
                    and now >= next_status
                ):
                    self._queue_control(self._status(False, self.state.active_task_id, False))
                    next_status = now + self._config.status_interval_s
                self._fill(pending, generation)
                if goodbye_deadline is not None and (not pending or now >= goodbye_deadline):
                    return
                if not pending:
                    last_progress = now
                elif now - last_progress > self._config.send_timeout_s:
                    raise _DisconnectError(f"the peer took no data for {self._config.send_timeout_s:g} s")
                if not self.state.registered and now > ack_deadline:
                    raise _DisconnectError(
                        f"no RegistrationAck within {self._config.registration_timeout_s:g} s"
                    )
                events = selectors.EVENT_READ | (selectors.EVENT_WRITE if pending else 0)
                selector.modify(sock, events)
                for key, mask in selector.select(timeout=0.2):
                    if key.fileobj is self._wake_recv:
                        self._drain_wake()
                        continue
                    if mask & selectors.EVENT_WRITE and pending:
                        sent = sock.send(pending[:_SEND_CHUNK])
                        del pending[:sent]
                        if sent:
                            last_progress = time.monotonic()
                    if mask & selectors.EVENT_READ:
                        data = sock.recv(_SEND_CHUNK)
                        if not data:
                            raise _DisconnectError("the peer closed the connection")
                        for message in decoder.feed(data):
                            registered_now = self._handle(message)
                            if registered_now:  # the first StatusReport of a registration says INFO_NEW
                                self._queue_control(self._status(True, self.state.active_task_id, False))
                                next_status = time.monotonic() + self._config.status_interval_s
                            if not self.state.registered and registered_now is None:
                                ack_deadline = time.monotonic() + self._config.registration_timeout_s

    def _drain_wake(self) -> None:
        with contextlib.suppress(OSError):
            while self._wake_recv.recv(4096):
                pass

    def _next_report(self, generation: int) -> bytes | None:
        """The next queued report of this connection (``generation``), counted as sent; reports of
        earlier connections on the way are dropped. None when none is left. Call with the lock held."""
        while self._reports:
            frame_generation, frame = self._reports.popleft()
            if frame_generation == generation:
                self.counts["reports sent"] += 1
                return frame
        return None

    def _queue_reports_as_control(self, generation: int) -> None:
        """Move this connection's queued reports behind the control messages, so that they go out
        before a control message queued next (the GOODBYE) instead of after it."""
        with self._lock:
            while (frame := self._next_report(generation)) is not None:
                self._control.append(frame)

    def _fill(self, pending: bytearray, generation: int) -> None:
        """Move queued frames into the send buffer: control messages first, then this connection's reports."""
        with self._lock:
            while self._control and len(pending) < _SEND_CHUNK:
                pending += self._control.popleft()
            if not self.state.registered:
                return
            while len(pending) < _SEND_CHUNK and (frame := self._next_report(generation)) is not None:
                pending += frame

    def _handle(self, message: SapientMessage) -> bool | None:
        """Act on one received message. Returns True when it was an accepting RegistrationAck, None
        when a Task asked to register again, else False."""
        if message.HasField("destination_id") and message.destination_id not in ("", self._node_id):
            return False  # addressed to another node
        kind = message.WhichOneof("content")
        self.counts[f"received {kind}"] += 1
        if kind == "registration_ack":
            ack = message.registration_ack
            if not ack.acceptance:
                reasons = "; ".join(ack.ack_response_reason) or "no reason given"
                raise _DisconnectError(f"registration refused: {reasons}")
            if self.state.registered:
                return False
            self._set_state(registered=True)
            self.problem = None
            log.info("sapient: registered with %s as node %s", self.peer, self._node_id)
            return True
        if kind == "task":
            outcome = interpret_task(message.task, self._geo)
            self._queue_control(
                task_ack_message(self._node_id, outcome.task_id, outcome.accepted, list(outcome.reasons))
            )
            if not outcome.accepted:
                log.warning("sapient: task %s rejected: %s", outcome.task_id, "; ".join(outcome.reasons))
                return False
            return self._apply(outcome)
        if kind == "error":
            log.warning("sapient: the peer reports an error: %s", "; ".join(message.error.error_message))
        return False

    def _apply(self, outcome: TaskOutcome) -> bool | None:
        changes: dict = {}
        if outcome.reporting is not None:
            changes["reporting"] = outcome.reporting
        if outcome.regions is not None:
            changes["regions"] = outcome.regions
        if outcome.active_task_id is not None:
            changes["active_task_id"] = outcome.active_task_id or None
        if outcome.end_task and self.state.active_task_id == outcome.task_id:
            changes.update(regions=(), active_task_id=None)
        self._set_state(**changes)
        log.info("sapient: task %s accepted: %s", outcome.task_id, changes or "no change")
        if outcome.register_again:
            self._set_state(registered=False)
            self._queue_control(self._registration())
            return None
        if outcome.send_status and self.state.registered:
            self._queue_control(self._status(False, self.state.active_task_id, False))
        return False
