"""``dronekey-bench``: speed measurements of the product, one subcommand each.

- ``dronekey-bench model [--json]``: ONNX Runtime latency of the keypoint network, batch 1, for the
  paper configuration (random weights, exported to a temporary folder) and the shipped edge model
  (a randomly initialised one until it exists; the output says which), fp32 and int8.
- ``dronekey-bench pipeline --source FILE [--json]``: the daemon end to end with every output on,
  against its decode and model ceilings (``dronekey.daemon.bench``).
- ``dronekey-bench soak --source FILE --frames N [--json]``: the daemon looping over a video;
  resident memory at the start and the end (``dronekey.daemon.bench``).

Adding a subcommand: write ``add_<name>_command(subparsers)`` that creates its parser and sets
``handler=`` to a function ``(args) -> exit status``, and append it to ``SUBCOMMANDS``. Progress goes
to stderr; results (a table, or JSON with ``--json``) to stdout.
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
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

__all__ = ["SUBCOMMANDS", "add_model_command", "build_parser", "main", "time_model"]

LOG = logging.getLogger(__name__)
MODEL_NAMES = ("paper", "edge")
PRECISIONS = ("fp32", "int8")


# --------------------------------------------------------------------------------------------------
# model
# --------------------------------------------------------------------------------------------------


def time_model(path: str | Path, runs: int = 200, warmup: int = 20, threads: int | None = None) -> dict:
    """Latency of one ONNX model in ``KeypointModel`` (``dronekey.perception``), batch 1, fixed input.

    Returns ``{"params", "input", "latency_ms_p50", "latency_ms_p99", "fps"}`` (fps = 1000 / mean
    latency, i.e. sequential throughput). Times ``inference`` only (preprocessing is excluded).
    """
    from dronekey.perception.keypoint_model import KeypointModel

    model = KeypointModel(path, threads=threads)
    size = model.input_size
    crop = np.random.default_rng(0).integers(0, 256, (size, size, 3), dtype=np.uint8)
    tensor = model.preprocess(crop)
    for _ in range(warmup):
        model.inference(tensor)
    latencies = np.empty(runs)
    for i in range(runs):
        start = time.perf_counter()
        model.inference(tensor)
        latencies[i] = time.perf_counter() - start
    latencies *= 1e3
    return {
        "params": int(model.metadata.get("params", 0)),
        "input": [size, size],
        "latency_ms_p50": round(float(np.percentile(latencies, 50)), 3),
        "latency_ms_p99": round(float(np.percentile(latencies, 99)), 3),
        "fps": round(1e3 / float(latencies.mean()), 1),
    }


def _export_random_in_child(preset: str, out: Path) -> str | None:
    """Export a randomly initialised preset network in a child Python process, so torch (whose
    OpenMP threads keep spinning on the cores after its last operation) stays out of the timing
    process. Returns None on success, else the child's last line of error output."""
    code = f"from dronekey.bench.cli import _export_random; _export_random({preset!r}, {str(out)!r})"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    if done.returncode == 0 and out.is_file():
        return None
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    return lines[-1] if lines else f"exit status {done.returncode}"


def _export_random(preset: str, out: str) -> str:
    """Export a randomly initialised preset network (``DroneKeyConfig.paper()`` / ``.edge()``)."""
    import torch

    from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
    from dronekey.training.export import export_onnx

    logging.getLogger("dronekey.training.export").setLevel(logging.ERROR)
    torch.manual_seed(0)
    config = DroneKeyConfig.paper() if preset == "paper" else DroneKeyConfig.edge()
    meta = {"drone_spec": "mini2", "trained_on": "nothing: random weights for speed measurements"}
    export_onnx(DroneKeyNet(config).eval(), out, meta, verify=False)
    return out


def _random_crops(n: int, size: int) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 256, (n, size, size, 3), dtype=np.uint8)


def _run_model_command(args: argparse.Namespace) -> int:
    from dronekey.perception.keypoint_model import default_model_path
    from dronekey.training.export import quantize_int8

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
                error = _export_random_in_child(name, out)
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
                import onnx

                size = json.loads(
                    {p.key: p.value for p in onnx.load(str(path)).metadata_props}["input_size"]
                )[0]
                out = Path(tmp) / f"{name}-int8.onnx"
                LOG.info("quantising %s to int8 (calibration: %d random crops)", name, args.calib_crops)
                quantize_int8(path, out, _random_crops(args.calib_crops, int(size)), args.calib_crops)
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
    import onnxruntime as ort

    from dronekey.perception.keypoint_model import physical_cores

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


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def add_model_command(subparsers) -> None:
    """Register ``model``: latency of the keypoint network in ONNX Runtime, batch 1."""
    parser = subparsers.add_parser(
        "model",
        help="keypoint network latency in ONNX Runtime (paper and edge, fp32 and int8)",
        description="Time the DroneKey network in ONNX Runtime at batch 1: the paper configuration "
        "(random weights) and the shipped edge model (random weights until it exists), fp32 and int8.",
    )
    parser.add_argument("--json", action="store_true", help="print JSON instead of a table")
    parser.add_argument("--runs", type=_positive_int, default=200, help="timed runs per model (default 200)")
    parser.add_argument("--warmup", type=_positive_int, default=20, help="untimed runs first (default 20)")
    parser.add_argument(
        "--threads", type=_positive_int, default=None, help="ORT intra-op threads (default: physical cores)"
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
        "--calib-crops", type=_positive_int, default=16, help="random crops calibrating int8 (default 16)"
    )
    parser.set_defaults(handler=_run_model_command)


# --------------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------------


def _add_pipeline_commands(subparsers) -> None:
    from dronekey.daemon.bench import add_pipeline_command, add_soak_command

    add_pipeline_command(subparsers)
    add_soak_command(subparsers)


def _add_sampler_command(subparsers) -> None:
    from dronekey.bench.sampler import add_sampler_command

    add_sampler_command(subparsers)


SUBCOMMANDS: list[Callable] = [add_model_command, _add_pipeline_commands, _add_sampler_command]


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-bench`` parser with every registered subcommand."""
    parser = argparse.ArgumentParser(prog="dronekey-bench", description="Speed measurements of DroneKey.")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for register in SUBCOMMANDS:
        register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``dronekey-bench``; returns the exit status."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    return int(args.handler(args))


if __name__ == "__main__":
    sys.exit(main())
