"""The ``pipeline`` and ``soak`` subcommands of ``dronekey-bench``: parsers, tables, exit statuses.

Registered through the ``dronekey.bench`` entry points (``pyproject.toml``). Errors are one line on
stderr with exit status 1 (130 / 143 after SIGINT / SIGTERM); results go to stdout, a table or JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from dronekey.bench.arguments import positive_float, positive_int
from dronekey.daemon.bench.bench_setup import BenchSetup
from dronekey.daemon.bench.cameras import PHASES, run_cameras_bench
from dronekey.daemon.bench.daemon_run import signal_monitor
from dronekey.daemon.bench.errors import BenchError, BenchInterruptedError
from dronekey.daemon.bench.pipeline import run_pipeline_bench
from dronekey.daemon.bench.slowest_frames import slowest_line
from dronekey.daemon.bench.soak import run_soak
from dronekey.daemon.malloc_arenas import limit_malloc_arenas
from dronekey.daemon.sources.opencv_readers import quiet_native_logs

__all__ = ["add_cameras_command", "add_pipeline_command", "add_soak_command"]

PIPELINE_TABLE_KEYS = (
    "frames",
    "fps",
    "latency_ms_p50",
    "latency_ms_p99",
    "decode_fps",
    "model_fps",
    "efficiency",
    "cpu_limit_fps",
    "efficiency_vs_cpu_limit",
    "network_limit_fps",
    "cpu_percent",
    "rss_mb",
)
SOAK_TABLE_KEYS = (
    "frames",
    "seconds",
    "fps",
    "rss_mb_start",
    "rss_mb_end",
    "rss_growth_percent",
    "rss_mb_peak",
)


def _table(report: dict, keys: tuple[str, ...], width: int) -> str:
    """One ``key value`` line per key, keys left-aligned in ``width`` characters."""
    return "\n".join(f"{key:{width}s} {report[key]}" for key in keys)


def _setup(args: argparse.Namespace) -> BenchSetup:
    return BenchSetup(
        args.source,
        args.calib,
        args.model,
        args.decode_threads,
        args.model_threads,
        not args.no_front_back,
        not args.no_mirror_average,
        args.front_back,
        args.measure_every,
        args.decode_ahead,
        args.late_after,
    )


def _run_bench(name: str, run: Callable) -> tuple[dict | None, int]:
    """``run(signals)`` with FFmpeg's and OpenCV's own messages off stderr (as in the daemon) and
    SIGINT / SIGTERM watched: (its report, 0), or (None, exit status) after one error line. Malloc
    arenas are capped as the daemon's own entry point caps them (``daemon.malloc_arenas``)."""
    limit_malloc_arenas()
    quiet_native_logs(verbose=False)
    signals = signal_monitor(install=True)
    try:
        return run(signals), 0
    except BenchError as exc:
        print(f"dronekey-bench {name}: error: {exc}", file=sys.stderr)
        return None, exc.exit_code if isinstance(exc, BenchInterruptedError) else 1
    finally:
        signals.finished()


def _run_pipeline_command(args: argparse.Namespace) -> int:
    report, status = _run_bench(
        "pipeline",
        lambda signals: run_pipeline_bench(
            _setup(args),
            frames=args.frames,
            latency_frames=args.latency_frames,
            warmup=args.warmup,
            signals=signals,
        ),
    )
    if report is None:
        return status
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(_table(report, PIPELINE_TABLE_KEYS, 23))
        print(slowest_line(report["details"]["paced"]["slowest"]))
    return 0


def _run_soak_command(args: argparse.Namespace) -> int:
    report, status = _run_bench(
        "soak",
        lambda signals: run_soak(
            _setup(args), frames=args.frames, warmup=args.warmup, sample_s=args.sample_s, signals=signals
        ),
    )
    if report is None:
        return status
    report["max_growth_percent"] = args.max_growth
    report["ok"] = report["rss_growth_percent"] <= args.max_growth
    print(json.dumps(report, indent=2) if args.json else _table(report, SOAK_TABLE_KEYS, 20))
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
        type=positive_int,
        default=None,
        help="FFmpeg decoder threads (default: the daemon's, every core but one)",
    )
    parser.add_argument(
        "--model-threads",
        type=positive_int,
        default=None,
        help="ONNX Runtime intra-op threads (default: the daemon's, 1)",
    )
    parser.add_argument(
        "--no-front-back",
        action="store_true",
        help="run without the front/back classifier (model.front_back false), to measure its cost",
    )
    parser.add_argument(
        "--front-back",
        type=Path,
        default=None,
        metavar="FILE",
        help="ONNX front/back classifier to run instead of the shipped one (model.front_back_path), "
        "to measure what another one costs",
    )
    parser.add_argument(
        "--no-mirror-average",
        action="store_true",
        help="run each crop once, not also mirrored (model.mirror_average false), to measure what "
        "the averaging costs",
    )
    parser.add_argument(
        "--measure-every",
        type=positive_int,
        default=None,
        metavar="N",
        help="measure steadily tracked drones on every N-th frame only, the tracks predicted between "
        "(tracking.measure_every; default: the daemon's, 1)",
    )
    parser.add_argument(
        "--late-after",
        type=positive_float,
        default=None,
        metavar="MS",
        help="predict instead of measure a frame the pipeline takes this many ms after it arrived "
        "(tracking.late_after_ms; default: the daemon's)",
    )
    parser.add_argument(
        "--decode-ahead",
        action="store_true",
        help="paced runs: decode each frame before it is due, so its decode is not in the latency "
        "(source.realtime_decode_ahead; every paced figure before the thirty-third session was taken "
        "so); default: decoded once due, as a camera's compressed stream is",
    )


def add_pipeline_command(subparsers) -> None:
    """Register ``pipeline``: the daemon end to end against its decode and model ceilings."""
    parser = subparsers.add_parser(
        "pipeline",
        help="the daemon end to end (all outputs on) against its decode and model ceilings",
        description="Run the daemon's pipeline on a video with every output on (Zenoh on 127.0.0.1, "
        "MAVLink to a local UDP port, MCAP to a temporary folder) and report end-to-end fps (flat "
        "out), latency p50/p99 (paced at the clip's frame rate), decode-only and model-only fps, "
        "efficiency = fps / min(decode_fps, model_fps), the CPU-bound limit (cores * 1000 / the decode "
        "and pipeline CPU ms a frame) and fps against it, the networks' limit (the same with the "
        "networks' CPU in place of the pipeline's: no end-to-end figure passes it), CPU and peak RSS.",
    )
    _common_arguments(parser)
    parser.add_argument(
        "--frames",
        type=positive_int,
        default=600,
        help="frames of the decode and flat-out passes (default 600)",
    )
    parser.add_argument(
        "--latency-frames",
        type=positive_int,
        default=300,
        help="frames of the paced latency pass (default 300: 10 s at 30 fps)",
    )
    parser.add_argument(
        "--warmup",
        type=positive_int,
        default=30,
        help="first frames of each daemon pass not measured (default 30)",
    )
    parser.set_defaults(handler=_run_pipeline_command)


def _percent_or_dash(value: float | None) -> str:
    return f"{value:8.2f}" if value is not None else f"{'-':>8s}"


def _camera_lines(report: dict) -> str:
    """The cameras report as a table: one line per camera, then the totals."""
    heads = ("fps", "dropped", "p50 ms", "p99 ms", "cpu ms", "rss MB", "rss +%", "trend +%")
    lines = [f"{'camera':8s} " + " ".join(f"{h:>8s}" for h in heads)]
    for c in report["cameras"]:
        lines.append(
            f"{c['camera']:8s} {c['fps']:8.2f} {c['dropped']:8d} {c['latency_ms_p50']:8.2f} "
            f"{c['latency_ms_p99']:8.2f} {c['cpu_ms_per_frame']:8.2f} {c['rss_mb']:8.1f} "
            f"{c['rss_growth_percent']:8.2f} {_percent_or_dash(c['rss_trend_percent'])}"
        )
    keys = (
        "phase",
        "decode_ahead",
        "late_after_ms",
        "fps_total",
        "dropped_total",
        "decode_cpu_ms_per_frame",
        "pipeline_cpu_ms_per_frame",
        "cpu_ms_per_frame",
        "rss_mb",
        "rss_growth_percent_worst",
        "rss_trend_percent_worst",
        "cores",
        "cpu_limit_fps",
        "load_vs_cpu_limit",
    )
    return "\n".join(lines) + "\n" + _table(report, keys, 25)


def _run_cameras_command(args: argparse.Namespace) -> int:
    report, status = _run_bench(
        "cameras",
        lambda signals: run_cameras_bench(
            _setup(args), count=args.count, seconds=args.seconds, phase=args.phase, signals=signals
        ),
    )
    if report is None:
        return status
    print(json.dumps(report, indent=2) if args.json else _camera_lines(report))
    return 0


def add_cameras_command(subparsers) -> None:
    """Register ``cameras``: N paced cameras on this box, one daemon process each."""
    parser = subparsers.add_parser(
        "cameras",
        help="N cameras as deployed (one daemon process each, paced at the clip's rate) vs the CPU limit",
        description="Run --count daemons at once, one per camera as the dronekey@.service template "
        "deploys them, each reading --source paced at its frame rate with every output on, for "
        "--seconds. Per camera: achieved fps, dropped frames, latency p50/p99 (frame due -> published), "
        "CPU per frame, RSS. In total: decode-only and pipeline-only CPU per frame (measured in the same "
        "run), RSS, and the CPU-bound limit: frames per second the cores can do given those two.",
    )
    _common_arguments(parser)
    parser.add_argument("--count", type=positive_int, default=1, help="cameras to run (default 1)")
    parser.add_argument(
        "--seconds", type=positive_float, default=60.0, help="seconds each camera runs (default 60)"
    )
    parser.add_argument(
        "--phase",
        choices=PHASES,
        default="aligned",
        help="when the cameras deliver their frames: aligned (all at the same instant, as genlocked "
        "cameras do: the worst case, the default), staggered (evenly spread over a frame interval) "
        "or free (paced from each process's start: a phase drawn by chance, as before)",
    )
    parser.set_defaults(handler=_run_cameras_command)


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
    parser.add_argument("--frames", type=positive_int, required=True, help="frames to run (e.g. 20000)")
    parser.add_argument(
        "--warmup",
        type=positive_int,
        default=1000,
        help="frames before the start figure; cover a loop of the clip (default 1000)",
    )
    parser.add_argument(
        "--sample-s", type=positive_float, default=5.0, help="seconds between RSS samples (default 5)"
    )
    parser.add_argument(
        "--max-growth", type=float, default=5.0, help="allowed RSS growth, percent (default 5)"
    )
    parser.set_defaults(handler=_run_soak_command)
