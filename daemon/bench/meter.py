"""The daemon's pipeline behind a frame counter that stamps wall clock, CPU time and memory."""

from __future__ import annotations

import math
import resource
import sys
import threading
import time
from collections import Counter
from typing import NamedTuple

import numpy as np
import psutil
from tqdm import tqdm

from dronekey.daemon.app import default_pipeline_factory
from dronekey.daemon.bench.errors import BenchError
from dronekey.daemon.bench.slowest_frames import FrameTiming
from dronekey.daemon.sinks.latency_histogram import LatencyHistogram

__all__ = ["MIB", "Meter", "Stamp", "growth_percent", "peak_rss_mb", "trend_percent"]

MIB = float(1 << 20)


def growth_percent(start_mb: float, end_mb: float) -> float:
    """Resident-set growth from ``start_mb`` to ``end_mb``, percent of the start, 2 decimals."""
    return round(100.0 * (end_mb - start_mb) / start_mb, 2)


def trend_percent(stamps: list[Stamp]) -> float:
    """Resident-set growth along the least-squares line through ``stamps`` (RSS against wall
    clock), from the first stamp's time to the last's, percent of the line's value at the first;
    NaN with fewer than three stamps. Unlike ``growth_percent`` of two single samples, it is not
    decided by where the allocator's swing (+-2.5 % from one sample to the next, docs/performance.md)
    happens to stand at the two ends."""
    if len(stamps) < 3 or stamps[-1].wall_s <= stamps[0].wall_s:
        return math.nan
    t = np.array([s.wall_s for s in stamps]) - stamps[0].wall_s
    slope, intercept = np.polyfit(t, [s.rss_mb for s in stamps], 1)
    return round(100.0 * slope * t[-1] / intercept, 2)


def peak_rss_mb() -> float:
    """Peak resident set of this process so far, MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / MIB  # ru_maxrss is KiB on Linux


class Stamp(NamedTuple):
    """Where a run stood: frames processed, wall clock (s), process CPU time (s), resident set (MiB)."""

    frames: int
    wall_s: float
    cpu_s: float
    rss_mb: float


class Meter:
    """The daemon's pipeline behind a pipeline factory that counts frames and stamps a window.

    ``pipeline_cpu_s`` sums the CPU time of ``TrackingPipeline.process`` alone (its thread's, so the
    decoder and the outputs are not in it) over the frames after the warm-up; ``network_cpu_s`` the
    part of it spent in the networks' ONNX Runtime calls (``KeypointModel.network_cpu_s``).

    ``process`` forwards to ``TrackingPipeline.process`` and stamps (``Stamp``) the end of frame
    ``warmup`` (``start``) and of the last frame (``end``); with ``rss`` the stamps hold the resident
    set and every 100th frame is stamped too (``last``, what an interrupted soak reports; from
    ``settled`` on they are kept in ``rss_stamps``, the samples a memory trend is fitted to), and
    the end of frame ``settle`` (``settled``: where a long run's memory growth is counted from, past
    the first minutes' one-off allocations). With ``seconds``, the end is stamped at the first frame
    that many seconds after the start if ``frames`` have not come by then (a camera that cannot
    keep up with its clip), and ``stop`` (the daemon's stop event) is set: the run lasts its time.

    With ``record_frames`` each frame of the window is kept in ``frame_timings`` (``FrameTiming``:
    its wait from arrival to the pipeline, read from the app's ``frame_arrival_mono_ns``, its time in
    the pipeline, mode and stages), for ``slowest_frames``.

    ``app`` (set by ``run_daemon``) is the daemon whose outputs' latency histograms are copied at
    the ``start`` stamp (``latency_start``), so that a run's percentiles leave the warm-up out.
    """

    def __init__(
        self,
        frames: int,
        warmup: int,
        desc: str,
        rss: bool = False,
        settle: int | None = None,
        seconds: float | None = None,
        stop: threading.Event | None = None,
        record_frames: bool = False,
    ) -> None:
        self.total = frames
        self.warmup = warmup
        self.frames = 0
        self.modes: Counter[str] = Counter()
        self.start: Stamp | None = None
        self.end: Stamp | None = None
        self.last: Stamp | None = None
        self.settled: Stamp | None = None
        self.rss_stamps: list[Stamp] = []  # every 100th frame's stamp from ``settled`` to ``end``
        self.out_of_time = False  # the end was stamped at ``seconds``, before ``frames``
        self._settle = settle
        self._seconds = seconds
        self._stop = stop
        self.pipeline = None
        self.app = None  # the DaemonApp this meter runs in (run_daemon sets it)
        self.latency_start: dict[str, LatencyHistogram] = {}  # each output's, at the start stamp
        self.pipeline_cpu_s = 0.0  # CPU time in process() (its thread and helpers), after warm-up
        self.network_cpu_s = 0.0  # the part of it in ONNX Runtime's calls (KeypointModel.network_cpu_s)
        self._rss = rss
        self._record_frames = record_frames
        self.frame_timings: list[FrameTiming] = []  # with record_frames: each frame of the window
        self._process = psutil.Process()
        self._bar = tqdm(total=frames, desc=desc, unit="frame", file=sys.stderr, leave=False)

    def factory(self, camera, config):
        """``DaemonApp``'s pipeline factory: the daemon's default pipeline, metered."""
        self.pipeline = default_pipeline_factory(camera, config)
        return self

    def info(self) -> dict:
        return self.pipeline.info()

    def process(self, frame, late=False):
        started, helpers = time.thread_time(), getattr(self.pipeline, "helper_cpu_s", 0.0)
        networks = self._network_cpu_s()
        taken_ns = time.monotonic_ns()
        output = self.pipeline.process(frame, late=late)
        if self.start is not None and self.end is None:
            # the pipeline thread's CPU and its helper threads' (the early saliency pass)
            helpers = getattr(self.pipeline, "helper_cpu_s", 0.0) - helpers
            self.pipeline_cpu_s += time.thread_time() - started + helpers
            self.network_cpu_s += self._network_cpu_s() - networks
            if self._record_frames:
                self._record(taken_ns, output)
        self.frames += 1
        self.modes[output.mode] += 1
        if self.frames == self.warmup:
            self.start = self._stamp()
            outputs = self.app.outputs if self.app is not None else {}
            self.latency_start = {name: w.stats.latency_histogram.copy() for name, w in outputs.items()}
        if self.frames == self._settle:
            self.settled = self._stamp()
            self.rss_stamps.append(self.settled)
        if self.frames == self.total:
            self.end = self._stamp()
            self._keep_rss(self.end)
        elif self._past_time():
            self.end = self._stamp()
            self._keep_rss(self.end)
            self.out_of_time = True
            if self._stop is not None:
                self._stop.set()
        elif self._rss and self.frames % 100 == 0:
            self.last = self._stamp()
            self._keep_rss(self.last)
        self._bar.update(1)
        return output

    def _network_cpu_s(self) -> float:
        model = getattr(self.pipeline, "model", None)
        return getattr(model, "network_cpu_s", 0.0)

    def _record(self, taken_ns: int, output) -> None:
        """Keep the frame's wait (from its arrival, as the daemon app saw it) and pipeline time."""
        arrival_ns = getattr(self.app, "frame_arrival_mono_ns", None)
        wait_ms = (taken_ns - arrival_ns) / 1e6 if arrival_ns is not None else math.nan
        pipeline_ms = (time.monotonic_ns() - taken_ns) / 1e6
        self.frame_timings.append(FrameTiming(wait_ms, pipeline_ms, output.mode, dict(output.timings_ms)))

    def _keep_rss(self, stamp: Stamp) -> None:
        """Keep a stamp taken after ``settled`` and up to ``end`` for the memory trend."""
        after_settle = self.settled is not None and stamp.frames > self.settled.frames
        if self._rss and after_settle and (self.end is None or stamp is self.end):
            self.rss_stamps.append(stamp)

    def _past_time(self) -> bool:
        """Whether ``seconds`` have gone by since the start stamp while the end is still to come."""
        return (
            self._seconds is not None
            and self.start is not None
            and self.end is None
            and time.perf_counter() - self.start.wall_s >= self._seconds
        )

    def _stamp(self) -> Stamp:
        rss = self._process.memory_info().rss / MIB if self._rss else math.nan
        return Stamp(self.frames, time.perf_counter(), time.process_time(), rss)

    def close(self) -> None:
        self._bar.close()

    def window(self) -> tuple[int, float, float]:
        """Frames, wall seconds and CPU seconds from the end of warm-up to ``end``."""
        if self.start is None or self.end is None:
            raise BenchError(f"the daemon stopped after {self.frames} of {self.total} frames")
        return (
            self.end.frames - self.start.frames,
            self.end.wall_s - self.start.wall_s,
            self.end.cpu_s - self.start.cpu_s,
        )
