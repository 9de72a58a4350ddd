"""``dronekey-bench pipeline``: the daemon end to end against its decode and model ceilings.

Four passes over the same file, one report:

1. *decode*: the daemon's reader for the file alone (same decoder threads), flat out -> ``decode_fps``;
2. *flat out*: the daemon with the source unpaced (back-pressure, no drops) -> ``fps`` and
   ``cpu_percent`` (process CPU time over wall time; 100 = one core busy; ``details`` also gives the
   CPU milliseconds per frame, the figure least disturbed by other load on the machine);
3. *paced*: the daemon with ``source.realtime`` (frames released at the clip's frame rate, as a camera
   delivers them) -> ``latency_ms_p50`` / ``latency_ms_p99``, from the frame leaving the decoder to
   its update being published, of the slowest output (as the daemon's status message reports it),
   and where its slowest 2 % of frames spent their time (``details.paced.slowest``,
   ``slowest_frames.py``: waiting to be taken or in the pipeline, searches, stages);
4. *model*: ``KeypointModel.inference`` alone at batch 1 and the model's input size, with the
   pipeline's intra-op threads -> ``model_fps``.

``efficiency = fps / min(decode_fps, model_fps)``; ``cpu_limit_fps`` is the CPU-bound limit
(``cpu_limit.py``) from the decode pass's CPU per frame and the flat-out pass's pipeline CPU per
frame, and ``efficiency_vs_cpu_limit = fps / cpu_limit_fps``. ``network_limit_fps`` is the same limit
with the pipeline's CPU replaced by its networks' alone (``details.network_cpu_ms_per_frame``: ONNX
Runtime's calls, keypoint network and patch classifiers, on the pipeline thread): what the cores could
do were everything of the pipeline but its networks free, so no end-to-end figure can pass it with
these networks and this decoder (at ``model.threads`` 1; with more, ONNX Runtime's pool threads are
not counted and it reads high). ``rss_mb`` is the peak resident set
of the process over all passes (MiB, as every ``*_mb`` figure here). The first ``warmup`` frames
of each daemon pass (ONNX Runtime's first runs, the Zenoh session opening) are left out of its
figures. The source loops, so ``frames`` may exceed the clip's length.
"""

from __future__ import annotations

import logging
import math
import sys
import time

import psutil
from tqdm import tqdm

from dronekey.bench.model_latency import time_model
from dronekey.daemon.app import DaemonApp
from dronekey.daemon.bench.bench_setup import BenchSetup
from dronekey.daemon.bench.cpu_limit import cpu_limit_fps, usable_cores
from dronekey.daemon.bench.daemon_run import check_signals, local_endpoints, run_daemon, signal_monitor
from dronekey.daemon.bench.errors import BenchError
from dronekey.daemon.bench.meter import Meter, peak_rss_mb
from dronekey.daemon.bench.slowest_frames import slowest_frames
from dronekey.daemon.signals import SignalMonitor
from dronekey.daemon.sources import FrameReader, SourceOpenError, make_reader

__all__ = ["measure_decode", "run_pipeline_bench", "worst_latency"]

LOG = logging.getLogger(__name__)


def measure_decode(
    setup: BenchSetup, frames: int, signals: SignalMonitor | None = None
) -> tuple[float, FrameReader, float]:
    """Frames per second of the daemon's reader for the source alone (same settings, flat out,
    looping), the reader (closed: its resolution and decoder threads), and the process CPU time per
    frame, ms (every decoder thread's)."""
    reader = make_reader(setup.config(frames).source)
    try:
        reader.open()
    except SourceOpenError as exc:
        raise BenchError(f"--source: {exc}") from None
    try:
        done = 0
        start, start_cpu = time.perf_counter(), time.process_time()
        with tqdm(total=frames, desc="decode", unit="frame", file=sys.stderr, leave=False) as bar:
            while done < frames:
                if signals is not None:
                    check_signals(signals, done)
                result = reader.read()
                if result.image is None:
                    if done == 0 or not result.ended:
                        raise BenchError(f"--source: {setup.source} stopped delivering frames after {done}")
                    reader.close()
                    reader.open()
                    continue
                done += 1
                bar.update(1)
        cpu_ms = 1e3 * (time.process_time() - start_cpu) / frames
        return frames / (time.perf_counter() - start), reader, cpu_ms
    finally:
        reader.close()


def worst_latency(app: DaemonApp, meter: Meter) -> tuple[float, float, dict]:
    """Worst p50 and p99 over the outputs (frame arrived -> published, of every update after ``meter``'s
    start stamp: the whole measured window, ``SinkStats.latency_histogram``), and per output."""
    per_sink = {}
    for name, worker in app.outputs.items():
        stats = worker.stats
        window = stats.latency_histogram
        if name in meter.latency_start:
            window = window.since(meter.latency_start[name])
        p50, p99 = window.percentile(50), window.percentile(99)
        per_sink[name] = {
            "published": stats.published,
            "dropped": stats.dropped,
            "errors": stats.errors,
            "latency_ms_p50": round(p50, 2),
            "latency_ms_p99": round(p99, 2),
        }
    worst50 = max((s["latency_ms_p50"] for s in per_sink.values()), default=math.nan)
    worst99 = max((s["latency_ms_p99"] for s in per_sink.values()), default=math.nan)
    return worst50, worst99, per_sink


def run_pipeline_bench(
    setup: BenchSetup,
    *,
    frames: int = 600,
    latency_frames: int = 300,
    warmup: int = 30,
    model_runs: int = 500,
    signals: SignalMonitor | None = None,
) -> dict:
    """The four passes of ``dronekey-bench pipeline`` (module docstring); returns the report.

    ``signals``: the command's ``SignalMonitor`` (default: a fresh one, not installed).
    """
    setup.check()
    for name, n in (("--frames", frames), ("--latency-frames", latency_frames)):
        if n <= warmup:
            raise BenchError(f"{name} ({n}) must exceed --warmup ({warmup})")

    LOG.info("decode pass: %d frames", frames)
    signals = signals or signal_monitor()
    decode_fps, reader, decode_cpu_ms = measure_decode(setup, frames, signals)

    LOG.info("flat-out pass: %d frames", frames)
    flat = Meter(frames, warmup, "flat out")
    with local_endpoints() as outputs:
        flat_app = run_daemon(setup.config(frames, outputs), flat, signals)
    n, wall_s, cpu_s = flat.window()
    fps = n / wall_s
    pipeline_cpu_ms = 1e3 * flat.pipeline_cpu_s / n
    network_cpu_ms = 1e3 * flat.network_cpu_s / n
    cores = usable_cores()
    limit = cpu_limit_fps(decode_cpu_ms, pipeline_cpu_ms, cores)
    network_limit = cpu_limit_fps(decode_cpu_ms, network_cpu_ms, cores)

    LOG.info("paced pass: %d frames at the clip's frame rate", latency_frames)
    paced = Meter(latency_frames, warmup, "paced", record_frames=True)
    with local_endpoints() as outputs:
        paced_app = run_daemon(setup.config(latency_frames, outputs, realtime=True), paced, signals)
    p50, p99, per_sink = worst_latency(paced_app, paced)
    pn, pwall_s, pcpu_s = paced.window()

    keypoints = flat.pipeline.model
    LOG.info("model pass: %d runs", model_runs)
    model_fps = float(
        time_model(keypoints.path, runs=model_runs, warmup=20, threads=keypoints.threads)["fps"]
    )

    return {
        "frames": n,
        "fps": round(fps, 2),
        "latency_ms_p50": round(p50, 2),
        "latency_ms_p99": round(p99, 2),
        "decode_fps": round(decode_fps, 2),
        "model_fps": round(model_fps, 1),
        "efficiency": round(fps / min(decode_fps, model_fps), 3),
        "cpu_limit_fps": round(limit, 1),
        "efficiency_vs_cpu_limit": round(fps / limit, 3),
        "network_limit_fps": round(network_limit, 1),
        "cpu_percent": round(100.0 * cpu_s / wall_s, 1),
        "rss_mb": round(peak_rss_mb(), 1),
        "details": {
            "source": str(setup.source),
            "resolution": list(reader.resolution) if reader.resolution else None,
            "decode_threads": getattr(reader, "decode_threads", None),
            "model": str(keypoints.path),
            "model_input": keypoints.input_size,
            "model_threads": keypoints.threads,
            "front_back": str(keypoints.heading_model.path) if keypoints.heading_model else None,
            "mirror_average": keypoints.mirror_average,
            "measure_every": flat.pipeline.measure_every,
            "decode_ahead": setup.decode_ahead,
            "late_after_ms": setup.late_after_ms,
            "cpus": psutil.cpu_count(),
            "warmup_frames": warmup,
            "modes": dict(flat.modes),
            "cpu_ms_per_frame": round(1e3 * cpu_s / n, 2),
            "decode_cpu_ms_per_frame": round(decode_cpu_ms, 2),
            "pipeline_cpu_ms_per_frame": round(pipeline_cpu_ms, 2),
            "network_cpu_ms_per_frame": round(network_cpu_ms, 2),
            "cores": cores,
            "dropped_by_outputs": {name: w.stats.dropped for name, w in flat_app.outputs.items()},
            "paced": {
                "frames": pn,
                "fps": round(pn / pwall_s, 2),
                "cpu_percent": round(100.0 * pcpu_s / pwall_s, 1),
                "outputs": per_sink,
                "slowest": slowest_frames(paced.frame_timings),
            },
        },
    }
