"""One camera of ``dronekey-bench cameras``: a daemon process as a ``dronekey@camN`` unit runs it.

Run as ``python -m dronekey.daemon.bench.camera_worker JSON`` by ``cameras.py``; JSON holds the
bench's setup (``BenchSetup.to_json``: source, calibration, model and the overrides), camera id,
frames, warm-up, the clip's frame rate and the camera's phase. The daemon reads
the clip paced at its frame rate (``source.realtime``, looping) with every output on (local
endpoints) and stops after ``frames``; the worker prints one JSON line with this camera's figures:

- ``fps``: frames processed per second after the warm-up;
- ``dropped``: frames a camera at the clip's rate would have sent in that time but the daemon did
  not take (the file source waits instead of dropping, so the shortfall is counted);
- ``latency_ms_p50`` / ``p99``: frame due (when a camera would have delivered it, ``CapturedFrame``)
  -> update published, of the slowest output, over
  every frame of the measured window; ``outputs``: each output's own (and what it published,
  dropped and failed), which says which one is the slowest;
- ``cpu_ms_per_frame``: the process's CPU per frame (decoder, pipeline, outputs), and
  ``pipeline_cpu_ms_per_frame``: ``TrackingPipeline.process`` alone;
- ``rss_mb``: resident set at the end (MiB); ``rss_mb_settled``: ``SETTLE_S`` of the clip's frames
  into the measured window (at its start for a run shorter than twice that), and
  ``rss_growth_percent`` from there to the end (a soak's figure), and ``rss_trend_percent`` the
  same along the line fitted to the resident set of every 100th frame from there to the end (not
  decided by the allocator's swing at two single samples);
- ``modes``: the pipeline's frames by ``PipelineOutput.mode``, the warm-up's included ("late": taken
  later than ``tracking.late_after_ms`` and predicted);
- ``malloc_arenas``: the cap on glibc's malloc arenas in force, as the daemon's entry point sets it
  (``dronekey.daemon.malloc_arenas``; null where the C library is not glibc).

The measured window ends after its frames or after its seconds, whichever comes first: a camera that
falls behind its clip is stopped at the run's time (a 1-hour soak of cameras at 19 FPS against a
30 FPS clip had been on course for 95 minutes), and its shortfall counts as dropped frames.
"""

from __future__ import annotations

import json
import logging
import sys

from dronekey.daemon.bench.bench_setup import BenchSetup
from dronekey.daemon.bench.daemon_run import local_endpoints, run_daemon, signal_monitor
from dronekey.daemon.bench.errors import BenchError
from dronekey.daemon.bench.meter import Meter, growth_percent, trend_percent
from dronekey.daemon.bench.pipeline import worst_latency
from dronekey.daemon.malloc_arenas import limit_malloc_arenas
from dronekey.daemon.messages import jsonable
from dronekey.daemon.sources.opencv_readers import quiet_native_logs

__all__ = ["SETTLE_S", "run_camera"]

SETTLE_S = 60.0  # a long run's memory growth counts from this far into the measured window


def run_camera(
    setup: BenchSetup,
    camera_id: str,
    frames: int,
    warmup: int,
    clip_fps: float,
    realtime_phase: float | None = None,
) -> dict:
    """Run one paced daemon for ``frames`` frames of a clip at ``clip_fps``, delivering
    ``realtime_phase`` of a frame interval into the monotonic clock's frame-rate grid
    (``source.realtime_phase``; None: from its first frame); this camera's figures (module
    docstring)."""
    measured = frames - warmup
    settle = warmup + (round(SETTLE_S * clip_fps) if measured >= 2 * SETTLE_S * clip_fps else 0)
    signals = signal_monitor(install=True)
    # A camera that cannot keep up with its clip stops at the run's time, not after its frames.
    meter = Meter(
        frames, warmup, camera_id, rss=True, settle=settle, seconds=measured / clip_fps, stop=signals.stop
    )
    with local_endpoints() as outputs:
        config = setup.config(frames, outputs, realtime=True, realtime_phase=realtime_phase)
        config = config.model_copy(update={"camera": config.camera.model_copy(update={"id": camera_id})})
        app = run_daemon(config, meter, signals)
    n, wall_s, cpu_s = meter.window()
    p50, p99, outputs = worst_latency(app, meter)
    return {
        "camera": camera_id,
        "frames": n,
        "fps": round(n / wall_s, 2),
        "clip_fps": round(clip_fps, 3),
        "realtime_phase": realtime_phase,
        "dropped": max(0, round(wall_s * clip_fps) - n),
        "latency_ms_p50": round(p50, 2),
        "latency_ms_p99": round(p99, 2),
        "cpu_ms_per_frame": round(1e3 * cpu_s / n, 2),
        "pipeline_cpu_ms_per_frame": round(1e3 * meter.pipeline_cpu_s / n, 2),
        "rss_mb": round(meter.end.rss_mb, 1),
        "rss_mb_settled": round(meter.settled.rss_mb, 1),
        "rss_growth_percent": growth_percent(meter.settled.rss_mb, meter.end.rss_mb),
        "rss_trend_percent": jsonable(trend_percent(meter.rss_stamps)),  # null for a short run
        "outputs": jsonable(outputs),
        "modes": dict(meter.modes),
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point of the child process; prints one JSON line, or one error line (exit 1)."""
    arenas = limit_malloc_arenas()  # as the daemon's entry point does
    args = json.loads((argv or sys.argv[1:])[0])
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    quiet_native_logs(verbose=False)
    setup = BenchSetup.from_json(args["setup"])
    try:
        phase = args.get("realtime_phase")
        report = run_camera(setup, args["camera"], args["frames"], args["warmup"], args["clip_fps"], phase)
    except BenchError as exc:
        print(f"{args['camera']}: {exc}", file=sys.stderr)
        return 1
    report["malloc_arenas"] = arenas
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
