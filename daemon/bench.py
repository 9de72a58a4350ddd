"""``dronekey-bench pipeline`` and ``dronekey-bench soak``: the daemon's own pipeline, end to end.

Both run ``dronekey.daemon.app.DaemonApp``, the service's runner (capture thread, ``TrackingPipeline``,
one ``SinkWorker`` per output), on a video file with every output on, so they measure the product:

- Zenoh: a peer listening on 127.0.0.1 only, multicast scouting off;
- MAVLink: ``udpout`` to a UDP port on 127.0.0.1 that the benchmark reads and discards;
- MCAP: into a temporary folder (deleted afterwards), images at the configured default rate.

``pipeline`` makes four passes over the same file and prints one JSON object (or a table):

1. *decode*: the daemon's reader for the file alone (same decoder threads), flat out -> ``decode_fps``;
2. *flat out*: the daemon with the source unpaced (back-pressure, no drops) -> ``fps`` and
   ``cpu_percent`` (process CPU time over wall time; 100 = one core busy; ``details`` also gives the
   CPU milliseconds per frame, the figure least disturbed by other load on the machine);
3. *paced*: the daemon with ``source.realtime`` (frames released at the clip's frame rate, as a camera
   delivers them) -> ``latency_ms_p50`` / ``latency_ms_p99``, from the frame leaving the decoder to
   its update being published, of the slowest output (as the daemon's status message reports it);
4. *model*: ``KeypointModel.inference`` alone at batch 1 and the model's input size, with the
   pipeline's intra-op threads -> ``model_fps``.

``efficiency = fps / min(decode_fps, model_fps)``; ``rss_mb`` is the peak resident set of the process
over all passes (MiB, as every ``*_mb`` figure here). The first ``--warmup`` frames of each daemon
pass (ONNX Runtime's first runs, the Zenoh session opening) are left out of its figures. The source
loops, so ``--frames`` may exceed the clip's length.

SIGINT / SIGTERM stop either command the daemon's way (outputs closed, temporary folder removed,
exit status 130 / 143); an interrupted soak still prints its figures up to the last 100 frames.

``soak`` loops the source flat out through the same daemon for ``--frames`` frames and samples the
resident set over time; the start figure is taken after ``--warmup`` frames (allocator arenas,
queues, MCAP chunk buffers and the decoder reopened at the clip's end have reached their working
size: one step of about 10 MiB at the first loop of a 1080p clip), the end figure at the last
frame; ``rss_mb_per_1000_frames`` is the slope of the samples after the warm-up.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import math
import resource
import socket
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import psutil
from tqdm import tqdm

__all__ = [
    "BenchError",
    "BenchSetup",
    "add_pipeline_command",
    "add_soak_command",
    "run_pipeline_bench",
    "run_soak",
]

LOG = logging.getLogger(__name__)
_MIB = float(1 << 20)
_MAX_LATENCY_FRAMES = 2000  # SinkStats keeps the last 2048 latencies


class BenchError(Exception):
    """Bad input (source, calibration, model) or a daemon run that failed; the message says which."""


# --------------------------------------------------------------------------------------------------
# plumbing shared by both commands
# --------------------------------------------------------------------------------------------------


class _UdpDrain:
    """A UDP socket on 127.0.0.1 standing in for a ground station: reads and discards datagrams."""

    def __init__(self) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.settimeout(0.2)
        self.port = self._sock.getsockname()[1]
        self.datagrams = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-udp-drain", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._sock.recv(65536)
                self.datagrams += 1
            except TimeoutError:
                continue
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self._sock.close()


class _Stamp(NamedTuple):
    """Where a run stood: frames processed, wall clock (s), process CPU time (s), resident set (MiB)."""

    frames: int
    wall_s: float
    cpu_s: float
    rss_mb: float


class _Meter:
    """The daemon's pipeline behind a pipeline factory that counts frames and stamps a window.

    ``process`` forwards to ``TrackingPipeline.process`` and stamps (``_Stamp``) the end of frame
    ``warmup`` (``start``) and of the last frame (``end``); with ``rss`` the stamps hold the resident
    set and every 100th frame is stamped too (``last``, what an interrupted soak reports).
    """

    def __init__(self, frames: int, warmup: int, desc: str, rss: bool = False) -> None:
        self.total = frames
        self.warmup = warmup
        self.frames = 0
        self.modes: Counter[str] = Counter()
        self.start: _Stamp | None = None
        self.end: _Stamp | None = None
        self.last: _Stamp | None = None
        self.pipeline = None
        self._rss = rss
        self._process = psutil.Process()
        self._bar = tqdm(total=frames, desc=desc, unit="frame", file=sys.stderr, leave=False)

    def factory(self, camera, config):
        """``DaemonApp``'s pipeline factory: the daemon's default pipeline, metered."""
        from dronekey.daemon.app import default_pipeline_factory

        self.pipeline = default_pipeline_factory(camera, config)
        return self

    def info(self) -> dict:
        return self.pipeline.info()

    def process(self, frame):
        output = self.pipeline.process(frame)
        self.frames += 1
        self.modes[output.mode] += 1
        if self.frames == self.warmup:
            self.start = self._stamp()
        if self.frames == self.total:
            self.end = self._stamp()
        elif self._rss and self.frames % 100 == 0:
            self.last = self._stamp()
        self._bar.update(1)
        return output

    def _stamp(self) -> _Stamp:
        rss = self._process.memory_info().rss / _MIB if self._rss else math.nan
        return _Stamp(self.frames, time.perf_counter(), time.process_time(), rss)

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


@dataclass(frozen=True)
class BenchSetup:
    """What a benchmark run is about: the source and the daemon settings it may override.

    source : video file (looped). calib, model : files (default: beside the video, the shipped
    model). decode_threads, model_threads : override ``source.decode_threads`` and ``model.threads``.
    """

    source: Path
    calib: Path | None = None
    model: Path | None = None
    decode_threads: int | None = None
    model_threads: int | None = None

    def check(self) -> None:
        """Raise ``BenchError`` naming the first missing input file."""
        if not self.source.is_file():
            raise BenchError(f"--source: no such file: {self.source}")
        if self.calib is not None and not self.calib.is_file():
            raise BenchError(f"--calib: no such file: {self.calib}")
        if self.model is not None and not self.model.is_file():
            raise BenchError(f"--model: no such file: {self.model}")
        if self.model is None:
            from dronekey.perception.keypoint_model import default_model_path

            if not default_model_path().is_file():
                raise BenchError(
                    f"the shipped model {default_model_path()} is not built yet; pass --model FILE "
                    "(an ONNX file written by dronekey-export)"
                )

    def config(self, frames: int, outputs: tuple[Path, int] | None = None, realtime: bool = False):
        """The daemon configuration: defaults, the source looping and stopping after ``frames``
        (paced at its frame rate with ``realtime``) and, with ``outputs = (mcap_dir, udp_port)``,
        every output on with local endpoints (else every output off)."""
        from dronekey.daemon.config import ConfigError, load_config

        overrides = {
            "source.uri": (str(self.source), "--source"),
            "source.loop": (True, "loop"),
            "source.realtime": (realtime, "realtime"),
            "source.max_frames": (frames, "--frames"),
            "log.level": ("WARNING", "log"),
        }
        optional = {
            "camera.calibration": (self.calib, "--calib"),
            "model.path": (self.model, "--model"),
            "source.decode_threads": (self.decode_threads, "--decode-threads"),
            "model.threads": (self.model_threads, "--model-threads"),
        }
        overrides.update(
            {key: (str(v) if isinstance(v, Path) else v, flag) for key, (v, flag) in optional.items() if v}
        )
        if outputs is not None:
            mcap_dir, udp_port = outputs
            overrides.update(
                {
                    "zenoh.mode": ("peer", "zenoh"),
                    "zenoh.scouting": (False, "zenoh"),
                    "zenoh.listen": (["tcp/127.0.0.1:0"], "zenoh"),
                    "mavlink.url": (f"udpout:127.0.0.1:{udp_port}", "mavlink"),
                    "mcap.dir": (str(mcap_dir), "mcap"),
                }
            )
        for output in ("zenoh", "mavlink", "mcap"):
            overrides[f"{output}.enabled"] = (outputs is not None, output)
        try:
            return load_config(None, overrides)
        except ConfigError as exc:
            raise BenchError(str(exc).splitlines()[0]) from None


class BenchInterruptedError(BenchError):
    """SIGINT or SIGTERM stopped the run; ``exit_code`` is 130 or 143 (as for the daemon)."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def _signal_monitor(install: bool = False):
    """The daemon's SIGINT / SIGTERM handling for a whole command (installed from the main thread)."""
    from dronekey.daemon.signals import SignalMonitor

    signals = SignalMonitor(deadline_s=30.0)
    if install:
        signals.install()
    return signals


def _check_signals(signals, frames: int) -> None:
    if signals.exit_code is not None:
        name = signals.exit_code.name
        raise BenchInterruptedError(f"stopped by {name} after {frames} frames", int(signals.exit_code))


def _run_daemon(config, meter: _Meter, signals):
    """Run ``DaemonApp`` to its end with ``meter`` as the pipeline; returns the app (for its outputs).

    A signal seen by ``signals`` (``SignalMonitor``) stops it the daemon's way (outputs closed) and
    raises ``BenchInterruptedError``.
    """
    from dronekey.daemon.app import DaemonApp
    from dronekey.daemon.errors import DaemonError, ExitCode
    from dronekey.daemon.systemd import SystemdNotifier

    app = DaemonApp(
        config, signals=signals, notifier=SystemdNotifier(environ={}), pipeline_factory=meter.factory
    )
    try:
        code = app.run()
    except DaemonError as exc:
        raise BenchError(str(exc)) from None
    finally:
        meter.close()
    _check_signals(signals, meter.frames)
    if code != ExitCode.OK:
        raise BenchError(
            f"the daemon stopped with exit code {int(code)} ({code.name}) after {meter.frames} frames"
        )
    return app


@contextlib.contextmanager
def _local_endpoints():
    """A temporary MCAP folder and a drained local UDP port, for one daemon run."""
    drain = _UdpDrain()
    try:
        with tempfile.TemporaryDirectory(prefix="dronekey-bench-mcap-") as tmp:
            yield Path(tmp), drain.port
    finally:
        drain.close()


def _quiet_native_logs() -> None:
    """Keep FFmpeg's and OpenCV's own messages off stderr, as the daemon does."""
    from dronekey.daemon.sources.opencv_readers import quiet_native_logs

    quiet_native_logs(verbose=False)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024 / _MIB  # ru_maxrss is KiB on Linux


# --------------------------------------------------------------------------------------------------
# pipeline
# --------------------------------------------------------------------------------------------------


def measure_decode(setup: BenchSetup, frames: int, signals=None) -> tuple[float, object]:
    """Frames per second of the daemon's reader for the source alone (same settings, flat out,
    looping), and the reader (closed: its resolution and decoder threads)."""
    from dronekey.daemon.sources import SourceOpenError, make_reader

    reader = make_reader(setup.config(frames).source)
    try:
        reader.open()
    except SourceOpenError as exc:
        raise BenchError(f"--source: {exc}") from None
    try:
        done = 0
        start = time.perf_counter()
        with tqdm(total=frames, desc="decode", unit="frame", file=sys.stderr, leave=False) as bar:
            while done < frames:
                if signals is not None:
                    _check_signals(signals, done)
                result = reader.read()
                if result.bgr is None:
                    if done == 0 or not result.ended:
                        raise BenchError(f"--source: {setup.source} stopped delivering frames after {done}")
                    reader.close()
                    reader.open()
                    continue
                done += 1
                bar.update(1)
        return frames / (time.perf_counter() - start), reader
    finally:
        reader.close()


def _latency(app, warmup: int) -> tuple[float, float, dict]:
    """Worst p50 and p99 over the outputs (decoded -> published, after ``warmup`` updates), and per output."""
    per_sink = {}
    for name, worker in app.outputs.items():
        stats = worker.stats
        values = np.fromiter(stats.latencies_ms, dtype=np.float64)
        keep = max(0, stats.published - warmup)
        values = values[len(values) - min(keep, len(values)) :]
        p50, p99 = (
            (float(np.percentile(values, 50)), float(np.percentile(values, 99)))
            if values.size
            else (math.nan,) * 2
        )
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
    signals=None,
) -> dict:
    """The four passes of ``dronekey-bench pipeline`` (module docstring); returns the report.

    ``signals``: the command's ``SignalMonitor`` (default: a fresh one, not installed).
    """
    from dronekey.bench.cli import time_model

    setup.check()
    for name, n in (("--frames", frames), ("--latency-frames", latency_frames)):
        if n <= warmup:
            raise BenchError(f"{name} ({n}) must exceed --warmup ({warmup})")
    if latency_frames > _MAX_LATENCY_FRAMES:
        raise BenchError(f"--latency-frames must be <= {_MAX_LATENCY_FRAMES}, got {latency_frames}")

    LOG.info("decode pass: %d frames", frames)
    signals = signals or _signal_monitor()
    decode_fps, reader = measure_decode(setup, frames, signals)

    LOG.info("flat-out pass: %d frames", frames)
    flat = _Meter(frames, warmup, "flat out")
    with _local_endpoints() as outputs:
        flat_app = _run_daemon(setup.config(frames, outputs), flat, signals)
    n, wall_s, cpu_s = flat.window()
    fps = n / wall_s

    LOG.info("paced pass: %d frames at the clip's frame rate", latency_frames)
    paced = _Meter(latency_frames, warmup, "paced")
    with _local_endpoints() as outputs:
        paced_app = _run_daemon(setup.config(latency_frames, outputs, realtime=True), paced, signals)
    p50, p99, per_sink = _latency(paced_app, warmup)
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
        "cpu_percent": round(100.0 * cpu_s / wall_s, 1),
        "rss_mb": round(_peak_rss_mb(), 1),
        "details": {
            "source": str(setup.source),
            "resolution": list(reader.resolution) if reader.resolution else None,
            "decode_threads": getattr(reader, "decode_threads", None),
            "model": str(keypoints.path),
            "model_input": keypoints.input_size,
            "model_threads": keypoints.threads,
            "cpus": psutil.cpu_count(),
            "warmup_frames": warmup,
            "modes": dict(flat.modes),
            "cpu_ms_per_frame": round(1e3 * cpu_s / n, 2),
            "dropped_by_outputs": {name: w.stats.dropped for name, w in flat_app.outputs.items()},
            "paced": {
                "frames": pn,
                "fps": round(pn / pwall_s, 2),
                "cpu_percent": round(100.0 * pcpu_s / pwall_s, 1),
                "outputs": per_sink,
            },
        },
    }


def _pipeline_table(report: dict) -> str:
    keys = (
        "frames",
        "fps",
        "latency_ms_p50",
        "latency_ms_p99",
        "decode_fps",
        "model_fps",
        "efficiency",
        "cpu_percent",
        "rss_mb",
    )
    return "\n".join(f"{key:16s} {report[key]}" for key in keys)


def _setup(args: argparse.Namespace) -> BenchSetup:
    return BenchSetup(args.source, args.calib, args.model, args.decode_threads, args.model_threads)


def _run_pipeline_command(args: argparse.Namespace) -> int:
    _quiet_native_logs()
    signals = _signal_monitor(install=True)
    try:
        report = run_pipeline_bench(
            _setup(args),
            frames=args.frames,
            latency_frames=args.latency_frames,
            warmup=args.warmup,
            signals=signals,
        )
    except BenchError as exc:
        print(f"dronekey-bench pipeline: error: {exc}", file=sys.stderr)
        return exc.exit_code if isinstance(exc, BenchInterruptedError) else 1
    finally:
        signals.finished()
    print(json.dumps(report, indent=2) if args.json else _pipeline_table(report))
    return 0


# --------------------------------------------------------------------------------------------------
# soak
# --------------------------------------------------------------------------------------------------


class _RssSampler:
    """Samples the process's resident set (MiB) and the frame count every ``period_s`` seconds."""

    def __init__(self, meter: _Meter, period_s: float) -> None:
        self.samples: list[dict] = []
        self._meter = meter
        self._period_s = period_s
        self._process = psutil.Process()
        self._t0 = time.perf_counter()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-rss", daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        rss = self._process.memory_info().rss / _MIB
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
    setup: BenchSetup, *, frames: int, warmup: int = 1000, sample_s: float = 5.0, signals=None
) -> dict:
    """Loop the source through the daemon for ``frames`` frames flat out; RSS over time (module
    docstring). ``signals``: the command's ``SignalMonitor`` (default: a fresh one, not installed)."""
    setup.check()
    signals = signals or _signal_monitor()
    if frames <= warmup:
        raise BenchError(f"--frames ({frames}) must exceed --warmup ({warmup})")
    meter = _Meter(frames, warmup, "soak", rss=True)
    sampler = _RssSampler(meter, sample_s)
    interrupted: BenchInterruptedError | None = None
    outputs_stats = {}
    try:
        with _local_endpoints() as outputs:
            try:
                app = _run_daemon(setup.config(frames, outputs), meter, signals)
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
        "rss_growth_percent": round(100.0 * (end_mb - start_mb) / start_mb, 2),
        "rss_mb_per_1000_frames": round(slope, 3),
        "rss_mb_peak": round(_peak_rss_mb(), 1),
        "outputs": {
            name: {"published": w.stats.published, "dropped": w.stats.dropped, "errors": w.stats.errors}
            for name, w in outputs_stats.items()
        },
        "samples": sampler.samples,
    }


def _run_soak_command(args: argparse.Namespace) -> int:
    _quiet_native_logs()
    signals = _signal_monitor(install=True)
    try:
        report = run_soak(
            _setup(args), frames=args.frames, warmup=args.warmup, sample_s=args.sample_s, signals=signals
        )
    except BenchError as exc:
        print(f"dronekey-bench soak: error: {exc}", file=sys.stderr)
        return exc.exit_code if isinstance(exc, BenchInterruptedError) else 1
    finally:
        signals.finished()
    report["max_growth_percent"] = args.max_growth
    report["ok"] = report["rss_growth_percent"] <= args.max_growth
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        keys = ("frames", "seconds", "fps", "rss_mb_start", "rss_mb_end", "rss_growth_percent", "rss_mb_peak")
        print("\n".join(f"{key:20s} {report[key]}" for key in keys))
    if report["stopped_early"]:
        print(f"dronekey-bench soak: {report['stopped_early']} (figures up to there)", file=sys.stderr)
        return report["exit_code"]
    if not report["ok"]:
        print(
            f"dronekey-bench soak: RSS grew {report['rss_growth_percent']:.2f}% (> {args.max_growth}%)",
            file=sys.stderr,
        )
        return 1
    return 0


# --------------------------------------------------------------------------------------------------
# parsers
# --------------------------------------------------------------------------------------------------


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _positive_float(text: str) -> float:
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def _common_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--source", type=Path, required=True, help="video file (looped as needed)")
    parser.add_argument(
        "--calib", type=Path, default=None, help="calibration YAML (default: the one beside the video)"
    )
    parser.add_argument(
        "--model", type=Path, default=None, help="ONNX keypoint model (default: the shipped one)"
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument(
        "--decode-threads",
        type=_positive_int,
        default=None,
        help="FFmpeg decoder threads (default: the daemon's, every core but one)",
    )
    parser.add_argument(
        "--model-threads",
        type=_positive_int,
        default=None,
        help="ONNX Runtime intra-op threads (default: the daemon's, 1)",
    )


def add_pipeline_command(subparsers) -> None:
    """Register ``pipeline``: the daemon end to end against its decode and model ceilings."""
    parser = subparsers.add_parser(
        "pipeline",
        help="the daemon end to end (all outputs on) against its decode and model ceilings",
        description="Run the daemon's pipeline on a video with every output on (Zenoh on 127.0.0.1, "
        "MAVLink to a local UDP port, MCAP to a temporary folder) and report end-to-end fps (flat "
        "out), latency p50/p99 (paced at the clip's frame rate), decode-only and model-only fps, "
        "efficiency = fps / min(decode_fps, model_fps), CPU and peak RSS.",
    )
    _common_arguments(parser)
    parser.add_argument(
        "--frames",
        type=_positive_int,
        default=600,
        help="frames of the decode and flat-out passes (default 600)",
    )
    parser.add_argument(
        "--latency-frames",
        type=_positive_int,
        default=300,
        help=f"frames of the paced latency pass, <= {_MAX_LATENCY_FRAMES} (default 300: 10 s at 30 fps)",
    )
    parser.add_argument(
        "--warmup",
        type=_positive_int,
        default=30,
        help="first frames of each daemon pass not measured (default 30)",
    )
    parser.set_defaults(handler=_run_pipeline_command)


def add_soak_command(subparsers) -> None:
    """Register ``soak``: the daemon looping over a video; resident memory over time."""
    parser = subparsers.add_parser(
        "soak",
        help="loop a video through the daemon (all outputs on) and report RSS growth",
        description="Loop a video flat out through the daemon's pipeline with every output on for "
        "--frames frames, sample the resident set over time and report it at the start (after "
        "--warmup frames) and the end. Exit status 1 when it grew more than --max-growth percent.",
    )
    _common_arguments(parser)
    parser.add_argument("--frames", type=_positive_int, required=True, help="frames to run (e.g. 20000)")
    parser.add_argument(
        "--warmup",
        type=_positive_int,
        default=1000,
        help="frames before the start figure; cover a loop of the clip (default 1000)",
    )
    parser.add_argument(
        "--sample-s", type=_positive_float, default=5.0, help="seconds between RSS samples (default 5)"
    )
    parser.add_argument(
        "--max-growth", type=float, default=5.0, help="allowed RSS growth, percent (default 5)"
    )
    parser.set_defaults(handler=_run_soak_command)
