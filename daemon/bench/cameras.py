"""``dronekey-bench cameras``: N cameras on one box, as deployed, against the CPU-bound limit.

As deployed means one daemon process per camera (the ``dronekey@camN`` systemd template unit):
each is ``camera_worker.py`` in its own process, reading the clip paced at its frame rate (a camera
delivers frames at its rate, not faster) with every output on, its own camera id. They start
together and run ``seconds`` each, delivering frames in the phase ``phase`` names (``PHASES``;
``source.realtime_phase``): a camera's latency depends on whether the others' frames arrive at the
same instant, which a run paced from each process's own start left to chance (measured, the phase
moves the p99 less than the box's own speed does, which the decode pass below shows:
docs/performance.md, thirty-second session). Each frame is decoded once it is due, as a camera's
compressed stream is, so its decode counts in the latency (``decode_ahead``: before it is due,
every paced figure before the thirty-third session). Before them, in the same run, a decode-only pass
measures the reader's CPU per frame; the workers measure the pipeline's. The report:

- ``cameras``: per camera, achieved ``fps``, ``dropped`` frames, ``latency_ms_p50`` / ``p99``
  (frame due -> published), CPU and RSS (``camera_worker.py``);
- in total: ``decode_cpu_ms_per_frame`` (decode-only pass), ``pipeline_cpu_ms_per_frame`` (mean over
  the cameras), ``cpu_ms_per_frame`` (whole processes, outputs included), ``rss_mb`` (the sum),
  ``rss_growth_percent_worst`` (the largest camera's growth from a minute in to the end: a soak)
  and ``rss_trend_percent_worst`` (the same along each camera's fitted line; null when no camera
  ran long enough to fit one);
- ``cpu_limit_fps``: frames per second the cores can do given those two figures (``cpu_limit.py``),
  and ``fps_total`` / ``cpu_limit_fps`` as ``load_vs_cpu_limit``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import subprocess
import sys
import tempfile
import time

from dronekey.daemon.bench.bench_setup import BenchSetup
from dronekey.daemon.bench.cpu_limit import cpu_limit_fps, usable_cores
from dronekey.daemon.bench.errors import BenchError, BenchInterruptedError
from dronekey.daemon.bench.pipeline import measure_decode
from dronekey.daemon.signals import SignalMonitor

__all__ = ["PHASES", "camera_phases", "run_cameras_bench"]

LOG = logging.getLogger(__name__)
_DECODE_FRAMES = 300
_START_GRACE_S = 120.0  # model load, Zenoh session, first frames: per worker, on a loaded box
# When each camera delivers its frames: all at the same instant (genlocked cameras, the worst
# case), evenly spread over a frame interval, or paced from each process's start (chance).
PHASES = ("aligned", "staggered", "free")


def camera_phases(phase: str, count: int) -> list[float | None]:
    """Each camera's ``source.realtime_phase`` (a fraction of a frame interval) for a ``PHASES``
    mode: 0 for every camera (aligned), k / count for camera k (staggered), None (free)."""
    if phase not in PHASES:
        raise ValueError(f"phase must be one of {', '.join(PHASES)}, got {phase!r}")
    if phase == "free":
        return [None] * count
    return [0.0 if phase == "aligned" else k / count for k in range(count)]


def _worker_command(
    setup: BenchSetup,
    camera_id: str,
    frames: int,
    warmup: int,
    clip_fps: float,
    realtime_phase: float | None,
) -> list[str]:
    args = {
        "setup": setup.to_json(),
        "camera": camera_id,
        "frames": frames,
        "warmup": warmup,
        "clip_fps": clip_fps,
        "realtime_phase": realtime_phase,
    }
    return [sys.executable, "-m", "dronekey.daemon.bench.camera_worker", json.dumps(args)]


def _run_workers(commands: dict[str, list[str]], deadline_s: float, signals: SignalMonitor) -> list[dict]:
    """Start one worker process per camera, wait for them all (or stop them on a signal or at the
    deadline), and return each one's JSON report, in ``commands``' order.

    Their output goes to files, not pipes: nobody reads a pipe while the workers run, and a worker
    whose log filled its 64 KiB pipe blocked there until the deadline (a 5-minute run of three
    cameras stalled so).
    """
    with contextlib.ExitStack() as files:
        outputs = {
            cam: (
                files.enter_context(tempfile.TemporaryFile("w+")),
                files.enter_context(tempfile.TemporaryFile("w+")),
            )
            for cam in commands
        }
        procs = {
            cam: subprocess.Popen(command, stdout=outputs[cam][0], stderr=outputs[cam][1], text=True)
            for cam, command in commands.items()
        }
        deadline = time.monotonic() + deadline_s
        try:
            while any(p.poll() is None for p in procs.values()):
                if signals.exit_code is not None:
                    raise BenchInterruptedError(
                        f"stopped by {signals.exit_code.name}", int(signals.exit_code)
                    )
                if time.monotonic() > deadline:
                    raise BenchError(f"the cameras did not finish within {deadline_s:.0f} s")
                time.sleep(0.2)
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.terminate()
                p.wait()
        reports = []
        for cam, proc in procs.items():
            out, err = outputs[cam]
            out.seek(0)
            err.seek(0)
            out_text, err_text = out.read(), err.read()
            if proc.returncode != 0 or not out_text.strip():
                last = (err_text.strip().splitlines() or ["no output"])[-1]
                raise BenchError(f"camera {cam} failed (exit {proc.returncode}): {last}")
            reports.append(json.loads(out_text.strip().splitlines()[-1]))
        return reports


def run_cameras_bench(
    setup: BenchSetup,
    *,
    count: int,
    seconds: float,
    phase: str = "aligned",
    warmup_s: float = 2.0,
    signals: SignalMonitor,
) -> dict:
    """Run ``count`` paced cameras for ``seconds`` each (after ``warmup_s``), delivering in
    ``phase`` (``PHASES``); the report (module docstring)."""
    phases = camera_phases(phase, count)
    setup.check()
    LOG.info("decode pass: %d frames", _DECODE_FRAMES)
    _, reader, decode_cpu_ms = measure_decode(setup, _DECODE_FRAMES, signals)
    clip_fps = reader.frame_rate or 30.0
    warmup = max(1, round(warmup_s * clip_fps))
    frames = warmup + max(1, round(seconds * clip_fps))
    commands = {
        f"cam{i}": _worker_command(setup, f"cam{i}", frames, warmup, clip_fps, realtime_phase)
        for i, realtime_phase in enumerate(phases)
    }
    cameras = _run_workers(commands, frames / clip_fps * 3 + _START_GRACE_S, signals)
    pipeline_ms = sum(c["pipeline_cpu_ms_per_frame"] for c in cameras) / count
    cores = usable_cores()
    limit = cpu_limit_fps(decode_cpu_ms, pipeline_ms, cores)
    fps_total = sum(c["fps"] for c in cameras)
    return {
        "count": count,
        "seconds": seconds,
        "clip_fps": round(clip_fps, 3),
        "phase": phase,
        "decode_ahead": setup.decode_ahead,
        "late_after_ms": setup.late_after_ms,
        "cameras": cameras,
        "fps_total": round(fps_total, 2),
        "dropped_total": sum(c["dropped"] for c in cameras),
        "latency_ms_p99_worst": max(c["latency_ms_p99"] for c in cameras),
        "decode_cpu_ms_per_frame": round(decode_cpu_ms, 2),
        "pipeline_cpu_ms_per_frame": round(pipeline_ms, 2),
        "cpu_ms_per_frame": round(sum(c["cpu_ms_per_frame"] for c in cameras) / count, 2),
        "rss_mb": round(sum(c["rss_mb"] for c in cameras), 1),
        "rss_growth_percent_worst": max(c["rss_growth_percent"] for c in cameras),
        "rss_trend_percent_worst": max(
            (c["rss_trend_percent"] for c in cameras if c["rss_trend_percent"] is not None), default=None
        ),
        "cores": cores,
        "cpu_limit_fps": round(limit, 1) if math.isfinite(limit) else None,
        "load_vs_cpu_limit": round(fps_total / limit, 3) if math.isfinite(limit) else None,
        "decode_threads": getattr(reader, "decode_threads", None),
    }
