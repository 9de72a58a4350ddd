"""The capture thread: runs one ``FrameReader`` and feeds a bounded queue to the pipeline.

Policy depends only on whether the source is live:

- **live** (V4L2, network): the queue drops its oldest frame when the pipeline falls behind (the
  daemon never lags real time) and counts the drop; a watchdog marks the source *stalled* when no
  frame arrived for ``stall_timeout_s``; a lost source is reopened with exponential backoff
  (``reconnect_initial_s`` doubling up to ``reconnect_max_s``), and after ``max_reconnects`` failed
  attempts in a row it is *failed*.
- **finite** (file, image folder, sim): every frame is delivered in order; the reader waits for
  room in the queue (back-pressure, no drops), paces itself at the stream's rate with ``realtime``,
  and restarts at its end with ``loop`` (timestamps keep increasing across passes; the next pass
  is opened ahead while the current one plays where the reader can, ``next_pass``). Paced frames
  are released from the first frame read on, or, with ``realtime_phase``, on the frame-rate grid
  of the system's monotonic clock (one clock for every process: several replayed cameras on one
  box then deliver in a phase that is chosen, not left to when each process started). A paced
  frame arrives (its latency origin) when it is due, and is decoded only then, as a camera's
  compressed stream is, unless ``realtime_decode_ahead`` lets the file decode it beforehand.

Corrupt frames (undecodable or malformed) are counted and skipped. ``busy_for_s`` tells how long
the thread has been inside one reader call, so the runner can stop petting the systemd watchdog
when a driver call hangs for good.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

from dronekey.daemon.config.source import SourceConfig
from dronekey.daemon.sources.base import (
    CapturedFrame,
    FrameReader,
    ReadResult,
    SourceOpenError,
    SourceState,
)
from dronekey.daemon.sources.next_pass import NextPass
from dronekey.types import Frame

__all__ = ["Capture", "CaptureStats", "FrameQueue", "pace_start"]

log = logging.getLogger(__name__)


def pace_start(now_s: float, interval_ns: int, phase: float | None) -> float:
    """When a paced source releases its first frame, on the monotonic clock (s): ``now_s``, or with
    ``phase`` (a fraction of a frame interval, ``SourceConfig.realtime_phase``) the first instant
    at or after it that lies ``phase`` of an interval into one of the grid's intervals, the grid
    being the multiples of ``interval_ns`` from the clock's zero."""
    if phase is None:
        return now_s
    interval_s = interval_ns / 1e9
    offset_s = phase * interval_s
    return offset_s + math.ceil((now_s - offset_s) / interval_s) * interval_s


def _due_s(pace_origin: tuple[float, int], t_ns: int) -> float:
    """When a paced frame of stream time ``t_ns`` is due on the monotonic clock (s), given the
    pacing origin (monotonic s, stream time ns of the first frame)."""
    return pace_origin[0] + (t_ns - pace_origin[1]) / 1e9


class FrameQueue:
    """Bounded frame queue: drop-oldest (live) or blocking (finite) when full.

    Parameters
    ----------
    maxsize : int
    drop_oldest : bool
    """

    def __init__(self, maxsize: int, drop_oldest: bool) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self._items: collections.deque[CapturedFrame] = collections.deque()
        self._maxsize = maxsize
        self._drop_oldest = drop_oldest
        self._cond = threading.Condition()
        self.dropped = 0

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: CapturedFrame, stop: threading.Event) -> bool:
        """Queue ``item``; a blocking queue waits for room. False if ``stop`` was set while waiting."""
        with self._cond:
            while len(self._items) >= self._maxsize:
                if self._drop_oldest:
                    self._items.popleft()
                    self.dropped += 1
                    break
                if stop.is_set():
                    return False
                self._cond.wait(0.1)
            self._items.append(item)
            self._cond.notify_all()
            return True

    def wait_for_room(self, stop: threading.Event) -> bool:
        """Block until a ``put`` would not wait; False if ``stop`` was set meanwhile."""
        with self._cond:
            while len(self._items) >= self._maxsize:
                if stop.is_set():
                    return False
                self._cond.wait(0.1)
            return True

    def get(self, timeout: float) -> CapturedFrame | None:
        """The oldest frame, or None after ``timeout`` seconds without one."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
            if not self._items:
                return None
            item = self._items.popleft()
            self._cond.notify_all()
            return item

    def wake(self) -> None:
        """Wake a waiting ``get`` (the source ended or failed)."""
        with self._cond:
            self._cond.notify_all()


@dataclass(frozen=True)
class CaptureStats:
    """A snapshot of the capture counters, for the status message."""

    state: SourceState
    frames: int  # frames decoded and queued (live drops included)
    dropped: int  # live frames dropped because the pipeline was behind
    corrupt: int  # undecodable or malformed frames skipped
    reconnects: int  # successful reopenings after a loss
    last_error: str | None
    seconds_since_frame: float | None  # None before the first frame
    open_attempts: int = 0  # live: times the source was (re)opened, failed attempts included
    opened: int = 0  # live: ... and how many of them succeeded


class Capture:
    """One source on its own thread behind a ``FrameQueue`` (see the module docstring).

    Parameters
    ----------
    reader : FrameReader
    config : SourceConfig
    """

    def __init__(self, reader: FrameReader, config: SourceConfig) -> None:
        self.reader = reader
        self.config = config
        self.queue = FrameQueue(config.queue_size, drop_oldest=reader.live)
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._state = SourceState.CONNECTING
        self._frames = 0
        self._corrupt = 0
        self._reconnects = 0
        self._open_attempts = 0
        self._opened_count = 0
        self._last_error: str | None = None
        self._last_frame_mono: float | None = None
        self._busy_since: float | None = None
        self._next_index = 0
        self._gave_up = False
        self._crashed = False
        self._opened = False
        self._next_pass: NextPass | None = None
        self._thread = threading.Thread(target=self._run, name="capture", daemon=True)
        self._watchdog = threading.Thread(target=self._watch, name="capture-watchdog", daemon=True)

    # ------------------------------------------------------------------------------ control
    def open(self) -> None:
        """Open a finite source now (``SourceOpenError`` if unreadable); live ones open on the thread."""
        if not self.reader.live:
            self.reader.open()
            self._opened = True

    def start(self) -> None:
        """Start the capture thread (opening a finite source first if ``open`` was not called)."""
        if not self.reader.live and not self._opened:
            self.open()
        self._thread.start()
        if self.reader.live:
            self._watchdog.start()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Ask the thread to finish; returns after ``timeout_s`` even if a reader call still hangs."""
        self._stop.set()
        self.queue.wake()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning("capture thread still inside a %s call; leaving it behind", self.reader.kind)
        else:
            self.reader.close()

    def get(self, timeout_s: float) -> CapturedFrame | None:
        """The next frame, or None after ``timeout_s`` (check ``finished``)."""
        return self.queue.get(timeout_s)

    # ------------------------------------------------------------------------------ state
    @property
    def state(self) -> SourceState:
        return self._state

    @property
    def finished(self) -> bool:
        """True once the source ended or failed and every queued frame was taken."""
        return self._state in (SourceState.ENDED, SourceState.FAILED) and not len(self.queue)

    @property
    def gave_up(self) -> bool:
        """True when a live source failed ``max_reconnects`` attempts in a row."""
        return self._gave_up

    @property
    def crashed(self) -> bool:
        """True when the capture thread died on an unexpected exception (a bug)."""
        return self._crashed

    @property
    def last_error(self) -> str | None:
        return self._last_error

    def busy_for_s(self) -> float:
        """Seconds spent inside the current reader call (0 when not inside one)."""
        since = self._busy_since
        return 0.0 if since is None else time.monotonic() - since

    def stats(self) -> CaptureStats:
        last = self._last_frame_mono
        return CaptureStats(
            state=self._state,
            frames=self._frames,
            dropped=self.queue.dropped,
            corrupt=self._corrupt,
            reconnects=self._reconnects,
            last_error=self._last_error,
            seconds_since_frame=None if last is None else time.monotonic() - last,
            open_attempts=self._open_attempts,
            opened=self._opened_count,
        )

    def _set_state(self, state: SourceState, detail: str = "") -> None:
        with self._lock:
            if state == self._state:
                return
            previous, self._state = self._state, state
        message = f"source {self.reader.description}: {previous} -> {state}"
        if detail:
            message += f" ({detail})"
        level = logging.WARNING if state in (SourceState.STALLED, SourceState.FAILED) else logging.INFO
        log.log(level, message)

    @contextlib.contextmanager
    def _busy(self) -> Iterator[None]:
        self._busy_since = time.monotonic()
        try:
            yield
        finally:
            self._busy_since = None

    # ------------------------------------------------------------------------------ thread
    def _run(self) -> None:
        try:
            if self.reader.live:
                self._run_live()
            else:
                self._run_finite()
        except SourceOpenError as exc:  # a looping file that vanished
            self._last_error = str(exc)
            self._gave_up = True
            self._set_state(SourceState.FAILED, self._last_error)
        except Exception as exc:  # a reader bug must end the daemon visibly, not hang it
            log.exception("capture thread failed")
            self._last_error = f"{type(exc).__name__}: {exc}"
            self._crashed = True
            self._set_state(SourceState.FAILED, self._last_error)
        finally:
            self.queue.wake()

    def _accept(
        self, result: ReadResult, t_offset_ns: int = 0, due_mono_ns: int | None = None
    ) -> CapturedFrame:
        """The read frame numbered and stamped: it arrives now, or at ``due_mono_ns`` (a paced
        frame's due time, ``CapturedFrame``)."""
        self._corrupt += result.corrupt
        self._next_index += result.corrupt  # keep indices equal to the source's frame numbers
        frame = Frame(self._next_index, result.t_ns + t_offset_ns, result.image)
        self._next_index += 1
        self._frames += 1
        self._last_frame_mono = time.monotonic()
        return CapturedFrame(frame, time.monotonic_ns() if due_mono_ns is None else due_mono_ns)

    def _wait_until(self, when_s: float) -> bool:
        """Sleep until ``when_s`` on the monotonic clock; False when stopped meanwhile."""
        delay = when_s - time.monotonic()
        return not (delay > 0 and self._stop.wait(delay))

    def _run_finite(self) -> None:
        self._set_state(SourceState.STREAMING)
        decode_when_due = self.config.realtime and not self.config.realtime_decode_ahead
        # The next pass opens while this one plays: a camera never reopens (next_pass.py).
        self._next_pass = NextPass(self.reader) if self.config.loop else None
        try:
            self._play_finite(decode_when_due)
        finally:
            if self._next_pass is not None:
                self._next_pass.discard()

    def _play_finite(self, decode_when_due: bool) -> None:
        """``_run_finite``'s passes over the source (see the module docstring)."""
        interval_ns = round(1e9 / (self.reader.frame_rate or 30.0))
        t_offset_ns = 0
        restarted = False
        passes = 0
        last_t_ns: int | None = None
        pace_origin: tuple[float, int] | None = None  # (monotonic s, frame t_ns) of the first frame
        while not self._stop.is_set():
            # A camera's compressed frame arrives when it is due: decode it then, not ahead.
            next_due_s = None
            if decode_when_due and pace_origin is not None and last_t_ns is not None:
                next_due_s = _due_s(pace_origin, last_t_ns + interval_ns)
            if next_due_s is not None and not self._wait_until(next_due_s):
                return
            with self._busy():
                result = self.reader.read()
            if result.image is None:
                self._corrupt += result.corrupt
                if not self.config.loop:
                    self._set_state(SourceState.ENDED, f"{self._frames} frames, {self._corrupt} corrupt")
                    return
                if self._frames == 0:
                    raise SourceOpenError(f"{self.reader.description} gave no frame to loop over")
                with self._busy():  # the helper may still be opening it
                    opened = self._next_pass.take() if self._next_pass is not None else None
                self.reader.close()
                if opened is not None:
                    self.reader = opened
                else:
                    with self._busy():
                        self.reader.open()
                self._next_pass = NextPass(self.reader)
                restarted = True
                passes += 1
                level = logging.INFO if passes == 1 else logging.DEBUG
                log.log(
                    level, "source %s: looping to its start (pass %d)", self.reader.description, passes + 1
                )
                continue
            if restarted and last_t_ns is not None:
                t_offset_ns = last_t_ns + interval_ns - result.t_ns
                restarted = False
            t_ns = result.t_ns + t_offset_ns
            due_mono_ns = None
            if self.config.realtime:  # release the frame when a camera would have delivered it
                if pace_origin is None:
                    start = pace_start(time.monotonic(), interval_ns, self.config.realtime_phase)
                    pace_origin = (start, t_ns)
                due_s = _due_s(pace_origin, t_ns)
                due_mono_ns = round(due_s * 1e9)  # the latency origin: a late decoder or queue counts
                if not self._wait_until(due_s):
                    return
            # Back-pressure: wait for room first, so that an unpaced frame's latency origin is when it
            # is handed over, not how far the decoder ran ahead of the pipeline.
            if not self.queue.wait_for_room(self._stop):
                return
            last_t_ns = t_ns
            self.queue.put(self._accept(result, t_offset_ns, due_mono_ns), self._stop)

    def _run_live(self) -> None:
        failures = 0
        first = True
        while not self._stop.is_set():
            self._set_state(SourceState.CONNECTING if first else SourceState.RECONNECTING)
            self._open_attempts += 1
            try:
                with self._busy():
                    self.reader.open()
            except SourceOpenError as exc:
                self._last_error = str(exc)
                failures += 1
                if not self._wait_before_retry(failures, str(exc)):
                    return
                continue
            self._opened_count += 1
            if not first:
                self._reconnects += 1
            first = False
            self._last_frame_mono = time.monotonic()
            self._set_state(SourceState.STREAMING)
            frames_before = self._frames
            reason = self._stream_live()
            self.reader.close()
            if self._stop.is_set():
                return
            self._last_error = reason
            # A stream that opened but delivered nothing counts as a failed attempt (no hot loop).
            failures = 0 if self._frames > frames_before else failures + 1
            if not self._wait_before_retry(max(failures, 1), reason):
                return

    def _stream_live(self) -> str:
        """Read until the stream is lost or the daemon stops; returns why it ended."""
        while not self._stop.is_set():
            with self._busy():
                result = self.reader.read()
            if result.image is None:
                self._corrupt += result.corrupt
                return "stream lost (timeout or disconnection)" if result.lost else "stream ended"
            self.queue.put(self._accept(result), self._stop)
            if self._state == SourceState.STALLED:
                self._set_state(SourceState.STREAMING, "frames again")
        return "stopping"

    def _wait_before_retry(self, failures: int, reason: str) -> bool:
        """Back off before the next attempt; False when giving up or stopping."""
        limit = self.config.max_reconnects
        if limit is not None and failures > limit:
            self._gave_up = True
            self._set_state(SourceState.FAILED, f"{reason}; gave up after {failures} attempts")
            return False
        self._set_state(SourceState.RECONNECTING)
        delay = min(self.config.reconnect_initial_s * 2 ** (failures - 1), self.config.reconnect_max_s)
        log.warning("source %s: %s; retrying in %.1f s", self.reader.description, reason, delay)
        return not self._stop.wait(delay)

    def _watch(self) -> None:
        """Live sources: mark the source stalled when no frame arrived for ``stall_timeout_s``."""
        timeout = self.config.stall_timeout_s
        period = min(0.5, timeout / 4)
        while not self._stop.wait(period):
            last = self._last_frame_mono
            if self._state == SourceState.STREAMING and last is not None:
                silent = time.monotonic() - last
                if silent > timeout:
                    self._last_error = f"no frame for {silent:.1f} s"
                    self._set_state(SourceState.STALLED, self._last_error)
