"""The ONNX files ``dronekey-bench model`` times that it must make first (torch, ONNX tools).

- ``export PRESET OUT``: a randomly initialised preset network (``DroneKeyConfig.paper()`` /
  ``.edge()``) exported to fp32 ONNX;
- ``int8 FP32 OUT CROPS``: the fp32 file quantised to int8, calibrated on ``CROPS`` random crops
  (enough for speed, not for accuracy).

``dronekey-bench model`` runs this module in a child process (``python -m
dronekey.bench.model_files ...``) so torch, whose OpenMP threads keep spinning on the cores after
its last operation, stays out of the timing process.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np
import onnx
import torch

from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
from dronekey.training.export import export_onnx
from dronekey.training.quantize import quantize_int8

__all__ = ["PRESETS", "export_random", "main", "quantize_on_random_crops"]

PRESETS = ("paper", "edge")


def export_random(preset: str, out: str | Path) -> Path:
    """Export a randomly initialised preset network (``"paper"`` or ``"edge"``) to ``out``."""
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    logging.getLogger("dronekey.training.export").setLevel(logging.ERROR)
    torch.manual_seed(0)
    config = DroneKeyConfig.paper() if preset == "paper" else DroneKeyConfig.edge()
    meta = {"drone_spec": "mini2", "trained_on": "nothing: random weights for speed measurements"}
    return export_onnx(DroneKeyNet(config).eval(), out, meta, verify=False)


def quantize_on_random_crops(fp32_path: str | Path, out: str | Path, crops: int) -> Path:
    """Quantise ``fp32_path`` to int8 at ``out``, calibrated on ``crops`` random crops of its input size."""
    metadata = {p.key: p.value for p in onnx.load(str(fp32_path)).metadata_props}
    size = int(json.loads(metadata["input_size"])[0])
    random_crops = np.random.default_rng(0).integers(0, 256, (crops, size, size, 3), dtype=np.uint8)
    return quantize_int8(fp32_path, out, random_crops, crops)


def main(argv: list[str] | None = None) -> int:
    """``python -m dronekey.bench.model_files export PRESET OUT | int8 FP32 OUT CROPS``; exit status."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) == 3 and args[0] == "export":
        export_random(args[1], args[2])
    elif len(args) == 4 and args[0] == "int8":
        quantize_on_random_crops(args[1], args[2], int(args[3]))
    else:
        print(f"usage: export PRESET OUT | int8 FP32 OUT CROPS, got {args}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
