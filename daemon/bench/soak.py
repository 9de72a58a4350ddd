"""``dronekey-bench soak``: the daemon looping over a video flat out; resident memory over time.

The source loops through the daemon for ``frames`` frames while the resident set is sampled; the
start figure is taken after ``warmup`` frames (allocator arenas, queues, MCAP chunk buffers and the
decoder reopened at the clip's end have reached their working size: one step of about 10 MiB at
the first loop of a 1080p clip), the end figure at the last frame; ``rss_mb_per_1000_frames`` is the
slope of the samples after the warm-up. A run stopped by SIGINT / SIGTERM reports the frames up to
the last 100 (``stopped_early``, ``exit_code``).
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import psutil

from dronekey.daemon.bench.bench_setup import BenchSetup
from dronekey.daemon.bench.daemon_run import local_endpoints, run_daemon, signal_monitor
from dronekey.daemon.bench.errors import BenchError, BenchInterruptedError
from dronekey.daemon.bench.meter import MIB, Meter, growth_percent, peak_rss_mb
from dronekey.daemon.signals import SignalMonitor

__all__ = ["run_soak"]


class _RssSampler:
    """Samples the process's resident set (MiB) and the frame count every ``period_s`` seconds."""

    def __init__(self, meter: Meter, period_s: float) -> None:
        self.samples: list[dict] = []
        self._meter = meter
        self._period_s = period_s
        self._process = psutil.Process()
        self._t0 = time.perf_counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-rss", daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        rss = self._process.memory_info().rss / MIB
        self.samples.append(
            {
                "t_s": round(time.perf_counter() - self._t0, 2),
                "frames": self._meter.frames,
                "rss_mb": round(rss, 1),
            }
        )

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            self._sample()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._sample()


def run_soak(
    setup: BenchSetup,
    *,
    frames: int,
    warmup: int = 1000,
    sample_s: float = 5.0,
    signals: SignalMonitor | None = None,
) -> dict:
    """Loop the source through the daemon for ``frames`` frames flat out; RSS over time (module
    docstring). ``signals``: the command's ``SignalMonitor`` (default: a fresh one, not installed)."""
    setup.check()
    signals = signals or signal_monitor()
    if frames <= warmup:
        raise BenchError(f"--frames ({frames}) must exceed --warmup ({warmup})")
    meter = Meter(frames, warmup, "soak", rss=True)
    sampler = _RssSampler(meter, sample_s)
    interrupted: BenchInterruptedError | None = None
    outputs_stats = {}
    try:
        with local_endpoints() as outputs:
            try:
                app = run_daemon(setup.config(frames, outputs), meter, signals)
                outputs_stats = app.outputs
            except BenchInterruptedError as exc:
                if meter.last is None or meter.start is None or meter.last.frames <= meter.start.frames:
                    raise
                interrupted = exc
                meter.end = meter.last  # report the frames done so far
    finally:
        sampler.close()
    n, wall_s, cpu_s = meter.window()
    start_mb, end_mb = meter.start.rss_mb, meter.end.rss_mb
    tail = [s for s in sampler.samples if s["frames"] >= warmup]
    slope = (
        float(np.polyfit([s["frames"] for s in tail], [s["rss_mb"] for s in tail], 1)[0]) * 1000
        if len(tail) >= 3 and tail[-1]["frames"] > tail[0]["frames"]
        else math.nan
    )
    return {
        "frames": meter.end.frames,
        "stopped_early": None if interrupted is None else str(interrupted),
        "exit_code": 0 if interrupted is None else interrupted.exit_code,
        "warmup_frames": warmup,
        "seconds": round(sampler.samples[-1]["t_s"], 1),
        "fps": round(n / wall_s, 2),
        "cpu_percent": round(100.0 * cpu_s / wall_s, 1),
        "rss_mb_start": round(start_mb, 1),
        "rss_mb_end": round(end_mb, 1),
        "rss_growth_percent": growth_percent(start_mb, end_mb),
        "rss_mb_per_1000_frames": round(slope, 3),
        "rss_mb_peak": round(peak_rss_mb(), 1),
        "outputs": {
            name: {"published": w.stats.published, "dropped": w.stats.dropped, "errors": w.stats.errors}
            for name, w in outputs_stats.items()
        },
        "samples": sampler.samples,
    }
