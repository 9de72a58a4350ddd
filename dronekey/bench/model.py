"""``dronekey-bench model``: ONNX Runtime latency of the keypoint network, batch 1.

Times the paper configuration (random weights) and the shipped edge model (a randomly initialised
one until it exists; the output says which), fp32 and int8. The random-weight exports and the int8
files are made by ``dronekey.bench.model_files`` in child processes, so neither torch nor the ONNX
tools enter this process: it only times, in ONNX Runtime.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import onnxruntime as ort
from tqdm import tqdm

from dronekey.bench.arguments import positive_int
from dronekey.bench.model_latency import time_model
from dronekey.perception.keypoint_model import default_model_path, physical_cores

__all__ = ["MODEL_NAMES", "PRECISIONS", "add_model_command"]

LOG = logging.getLogger(__name__)
MODEL_NAMES = ("paper", "edge")
PRECISIONS = ("fp32", "int8")


def _in_child(*args: str) -> str | None:
    """Run ``python -m dronekey.bench.model_files ARGS`` (torch and the ONNX tools stay out of this
    process). Returns None on success, else the child's last line of error output."""
    command = [sys.executable, "-m", "dronekey.bench.model_files", *args]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode == 0:
        return None
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {done.returncode}"


def _run_model_command(args: argparse.Namespace) -> int:
    edge_path = args.edge_model if args.edge_model is not None else default_model_path()
    if args.edge_model is not None and not edge_path.is_file():
        print(f"dronekey-bench model: error: --edge-model not found: {edge_path}", file=sys.stderr)
        return 1
    results = []
    with tempfile.TemporaryDirectory(prefix="dronekey-bench-") as tmp:
        # 1. fp32 models: the shipped edge file, or random-weight exports (in a child process).
        fp32: dict[str, tuple[Path, str]] = {}
        to_export = []
        for name in args.models:
            if name == "edge" and edge_path.is_file():
                fp32[name] = (Path(edge_path), "shipped" if args.edge_model is None else "file")
            else:
                to_export.append(name)
        if to_export:
            if importlib.util.find_spec("torch") is None:  # not imported: torch stays out of this process
                print(
                    "dronekey-bench model: error: exporting random-weight models needs torch "
                    "(pip install 'dronekey[train]')",
                    file=sys.stderr,
                )
                return 1
            for name in tqdm(to_export, desc="export (random weights)", file=sys.stderr):
                out = Path(tmp) / f"{name}-fp32.onnx"
                error = _in_child("export", name, str(out))
                if error is None and not out.is_file():
                    error = f"no file written at {out}"
                if error:
                    print(f"dronekey-bench model: error: exporting {name} failed: {error}", file=sys.stderr)
                    return 1
                fp32[name] = (out, "random")
        # 2. int8 variants, calibrated on random crops (enough for speed; see docs/model.md).
        models: list[tuple[str, str, Path, str]] = []
        for name in args.models:
            path, weights = fp32[name]
            for precision in args.precisions:
                if precision == "fp32":
                    models.append((name, precision, path, weights))
                    continue
                out = Path(tmp) / f"{name}-int8.onnx"
                LOG.info("quantising %s to int8 (calibration: %d random crops)", name, args.calib_crops)
                error = _in_child("int8", str(path), str(out), str(args.calib_crops))
                if error:
                    print(f"dronekey-bench model: error: quantising {name} failed: {error}", file=sys.stderr)
                    return 1
                models.append((name, precision, out, weights))
        # 3. timing.
        for name, precision, path, weights in tqdm(models, desc="timing", file=sys.stderr):
            entry = {"name": name, "precision": precision, "weights": weights}
            entry.update(time_model(path, args.runs, args.warmup, args.threads))
            results.append(entry)
    report = {
        "models": results,
        "batch": 1,
        "runs": args.runs,
        "machine": _machine(args.threads),
    }
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(_table(results))
    return 0


def _machine(threads: int | None) -> dict:
    return {
        "cpu": platform.processor() or platform.machine(),
        "physical_cores": physical_cores(),
        "threads": threads or physical_cores(),
        "onnxruntime": ort.__version__,
    }


def _table(results: list[dict]) -> str:
    header = (
        f"{'model':6s} {'prec':5s} {'weights':8s} {'params':>11s} {'input':>8s} "
        f"{'p50 ms':>8s} {'p99 ms':>8s} {'fps':>7s}"
    )
    lines = [header, "-" * len(header)]
    for r in results:
        size = f"{r['input'][0]}x{r['input'][1]}"
        lines.append(
            f"{r['name']:6s} {r['precision']:5s} {r['weights']:8s} {r['params']:>11,d} {size:>8s} "
            f"{r['latency_ms_p50']:8.2f} {r['latency_ms_p99']:8.2f} {r['fps']:7.1f}"
        )
    return "\n".join(lines)


def add_model_command(subparsers) -> None:
    """Register ``model``: latency of the keypoint network in ONNX Runtime, batch 1."""
    parser = subparsers.add_parser(
        "model",
        help="keypoint network latency in ONNX Runtime (paper and edge, fp32 and int8)",
        description="Time the DroneKey network in ONNX Runtime at batch 1: the paper configuration "
        "(random weights) and the shipped edge model (random weights until it exists), fp32 and int8.",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument("--runs", type=positive_int, default=200, help="timed runs per model (default 200)")
    parser.add_argument("--warmup", type=positive_int, default=20, help="untimed runs first (default 20)")
    parser.add_argument(
        "--threads", type=positive_int, default=None, help="ORT intra-op threads (default: physical cores)"
    )
    parser.add_argument(
        "--models",
        nargs="+",
        choices=MODEL_NAMES,
        default=list(MODEL_NAMES),
        help="which models (default both)",
    )
    parser.add_argument(
        "--precisions", nargs="+", choices=PRECISIONS, default=list(PRECISIONS), help="default both"
    )
    parser.add_argument(
        "--edge-model", type=Path, default=None, help="edge ONNX to time instead of the shipped one"
    )
    parser.add_argument(
        "--calib-crops", type=positive_int, default=16, help="random crops calibrating int8 (default 16)"
    )
    parser.set_defaults(handler=_run_model_command)
