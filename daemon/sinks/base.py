"""The one small interface every output implements, and the thread that keeps it off the hot path.

The pipeline thread hands each ``FrameUpdate`` to every ``SinkWorker``; a worker queues it (bounded,
dropping the oldest when full) and its own thread calls the sink. A slow, blocked or absent
consumer therefore never stalls tracking (docs/design.md §3), and each worker counts what it dropped,
its queue depth and its frame-to-publish latency for the status messages.
"""

from __future__ import annotations

import collections
import dataclasses
import logging
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from dronekey.daemon.sinks.latency_histogram import LatencyHistogram
from dronekey.frame_image import FrameImage, as_frame_image
from dronekey.types import KeypointDetection, Track

__all__ = ["FrameUpdate", "Sink", "SinkStats", "SinkWorker"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class FrameUpdate:
    """What the pipeline produced for one frame.

    camera_id : the daemon's camera id (Zenoh key segment, MCAP frame ids).
    frame_index : source frame number.
    t_ns : frame timestamp, integer ns (Unix epoch for live sources, stream PTS for files).
    t_arrival_mono_ns : ``time.monotonic_ns()`` when the frame arrived (latency origin): when it left
        the decoder, or for a paced file when a camera would have delivered it (``CapturedFrame``).
    tracks : the tracks updated or predicted at this frame (possibly empty).
    detection : the keypoint model's answer on this frame, or None when it reported no drone.
    image : the frame's pixels (``dronekey.frame_image``; a BGR array is wrapped), read-only and
        shared with the other outputs, or None; ``image.bgr()`` converts the decoder's YUV to colour
        on the sink's own thread, once per frame whichever sink asks first.
    """

    camera_id: str
    frame_index: int
    t_ns: int
    t_arrival_mono_ns: int
    tracks: tuple[Track, ...] = ()
    detection: KeypointDetection | None = None
    image: FrameImage | None = None

    def __post_init__(self) -> None:
        if self.image is not None:
            object.__setattr__(self, "image", as_frame_image(self.image))


class Sink(ABC):
    """One output. Methods are called from the sink's own worker thread, never concurrently."""

    name: str = "sink"

    @abstractmethod
    def handle_update(self, update: FrameUpdate) -> None:
        """Publish one frame's tracks (and whatever else this output keeps)."""

    def handle_status(self, status: dict) -> None:  # noqa: B027 - optional hook
        """Publish the daemon's status (about 1 Hz); ignored by sinks that have no status channel."""

    def health(self) -> dict:
        """Sink-specific state for the status message (e.g. ``{"writable": False}``)."""
        return {}

    def failing(self) -> str | None:
        """Why this output is not doing its job right now, in a few words; None while it is.

        An output that takes every update but records or sends none of them (a full disk, no
        route) must not look healthy: this goes into the status line, the status message
        (``sinks[].failing``) and the totals. Called from other threads; keep it a cheap read.
        """
        return None

    def fault_counts(self) -> dict[str, int]:
        """What did not get through since start, in this output's words, e.g.
        ``{"not recorded": 451}`` (MCAP), ``{"unsent": 12}`` (Zenoh), ``{"refused": 3}`` (MAVLink
        commands refused). Non-zero counts are shown in the status line and the totals, and sent
        as ``sinks[].faults``; the worker's ``published`` only counts updates the sink took.
        """
        return {}

    def wants_image(self, t_ns: int) -> bool:
        """Whether the update of the frame at ``t_ns`` should carry the image (default: never).

        Called on the pipeline thread, once per frame and in frame order, before the update is
        queued; updates queue without the frame otherwise, so a backlog holds no full frames.
        """
        return False

    @abstractmethod
    def close(self) -> None:
        """Flush and release everything; must return within a second or two."""


@dataclass
class SinkStats:
    """Counters of one worker, read by the status publisher: the recent latencies (ms, the last
    2,048, for the status messages) and a histogram of every one (for benchmarks of a whole run)."""

    published: int = 0
    dropped: int = 0
    errors: int = 0
    last_error: str | None = None
    latencies_ms: collections.deque = field(default_factory=lambda: collections.deque(maxlen=2048))
    latency_histogram: LatencyHistogram = field(default_factory=LatencyHistogram)  # the whole run's

    def latency_percentiles(self) -> tuple[float, float]:
        """(p50, p99) of frame-decoded-to-published latency in ms over the recent window."""
        if not self.latencies_ms:
            return float("nan"), float("nan")
        arr = np.fromiter(self.latencies_ms, dtype=np.float64)
        return float(np.percentile(arr, 50)), float(np.percentile(arr, 99))


class SinkWorker:
    """Runs one ``Sink`` on its own thread behind a bounded drop-oldest queue.

    Parameters
    ----------
    sink : Sink
    max_queue : int
        Updates waiting at most; when full, the oldest is dropped and counted.
    """

    def __init__(self, sink: Sink, max_queue: int = 64) -> None:
        if max_queue < 1:
            raise ValueError(f"max_queue must be >= 1, got {max_queue}")
        self.sink = sink
        self.stats = SinkStats()
        self._queue: collections.deque = collections.deque()
        self._max_queue = max_queue
        self._cond = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=f"sink-{sink.name}", daemon=True)
        self._thread.start()

    @property
    def depth(self) -> int:
        return len(self._queue)

    def submit_update(self, update: FrameUpdate) -> None:
        """Queue a frame update (with its image only if the sink wants it); never blocks."""
        if update.image is not None and not self.sink.wants_image(update.t_ns):
            update = dataclasses.replace(update, image=None)
        self._put(("update", update))

    def submit_status(self, status: dict) -> None:
        """Queue a status message; never blocks."""
        self._put(("status", status))

    def _put(self, item: tuple) -> None:
        with self._cond:
            if self._closing:
                return
            if len(self._queue) >= self._max_queue:
                self._queue.popleft()
                self.stats.dropped += 1
            self._queue.append(item)
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue and self._closing:
                    return
                kind, payload = self._queue.popleft()
            try:
                if kind == "update":
                    self.sink.handle_update(payload)
                    self.stats.published += 1
                    lat = (time.monotonic_ns() - payload.t_arrival_mono_ns) / 1e6
                    self.stats.latencies_ms.append(lat)
                    self.stats.latency_histogram.add(lat)
                else:
                    self.sink.handle_status(payload)
            except Exception as exc:  # a sink failure must never take the daemon down
                self.stats.errors += 1
                msg = f"{type(exc).__name__}: {exc}"
                if msg != self.stats.last_error:
                    log.warning("sink %s failed: %s", self.sink.name, msg)
                self.stats.last_error = msg

    def close(self, timeout_s: float = 3.0, grace_s: float = 1.0) -> None:
        """Publish what is queued (within ``timeout_s``), then close the sink.

        A sink that cannot drain in time loses what is still queued: it is counted in
        ``stats.dropped`` and logged, never lost silently. The sink is closed only after its worker
        has returned from the call it is in (waiting up to ``grace_s`` more), so nothing reaches a
        closed sink: a SAPIENT session's GOODBYE stays its last word. Only a call blocked past the
        grace is left running while the sink closes, and that is logged too.
        """
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            with self._cond:
                abandoned = len(self._queue)
                self._queue.clear()
                self.stats.dropped += abandoned
            log.warning(
                "sink %s did not drain within %.1f s; dropped the %d messages still queued",
                self.sink.name, timeout_s, abandoned,
            )  # fmt: skip
            self._thread.join(grace_s)
            if self._thread.is_alive():
                log.warning(
                    "sink %s is still in a call %.1f s later; closing it anyway", self.sink.name, grace_s
                )
        try:
            self.sink.close()
        except Exception as exc:
            log.warning("sink %s failed to close: %s", self.sink.name, exc)
