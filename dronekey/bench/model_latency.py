"""Latency of one ONNX keypoint model in ONNX Runtime, batch 1 (no torch).

Used by ``dronekey-bench model`` and by the daemon's pipeline benchmark (its model-only pass), so
it imports the runtime's ``KeypointModel`` only.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from dronekey.perception.keypoint_model import KeypointModel

__all__ = ["time_model"]


def time_model(path: str | Path, runs: int = 200, warmup: int = 20, threads: int | None = None) -> dict:
    """Latency of one ONNX model in ``KeypointModel`` (``dronekey.perception``), batch 1, fixed input.

    Returns ``{"params", "input", "latency_ms_p50", "latency_ms_p99", "fps"}`` (fps = 1000 / mean
    latency, i.e. sequential throughput). Times ``inference`` only (preprocessing is excluded).
    """
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
