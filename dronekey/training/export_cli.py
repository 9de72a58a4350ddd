"""``dronekey-export``: a ``dronekey-train`` checkpoint -> ONNX for the daemon, fp32 or int8.

``export_checkpoint`` chains ``dronekey.training.export`` (fp32 with the runtime's metadata) and
``dronekey.training.quantize`` (int8); bad input is one line on stderr and exit status 1.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
from pathlib import Path

from dronekey.training.checkpoints import CheckpointError, load_checkpoint
from dronekey.training.export import OPSET, ExportError, export_onnx
from dronekey.training.quantize import CalibrationSource, load_calibration_npz, quantize_int8

__all__ = ["export_checkpoint", "main"]


def export_checkpoint(
    checkpoint: str | Path,
    out: str | Path,
    int8: bool = False,
    crops: CalibrationSource = None,
    num_crops: int = 128,
    opset: int = OPSET,
) -> Path:
    """Checkpoint -> ONNX at ``out`` (int8 when ``int8``, its fp32 stage in a temporary folder)."""
    net, meta = load_checkpoint(checkpoint)
    out = Path(out)
    if not int8:
        return export_onnx(net, out, meta, opset)
    with tempfile.TemporaryDirectory(prefix="dronekey-export-") as tmp:
        fp32 = export_onnx(net, Path(tmp) / "fp32.onnx", meta, opset)
        return quantize_int8(fp32, out, crops, num_crops)


def _parser() -> argparse.ArgumentParser:
    """The ``dronekey-export`` argument parser."""
    parser = argparse.ArgumentParser(
        prog="dronekey-export",
        description="Export a DroneKey training checkpoint to ONNX (opset >= 17) for the daemon.",
    )
    parser.add_argument(
        "--checkpoint", required=True, type=Path, help="checkpoint written by dronekey-train (.pt)"
    )
    parser.add_argument("--out", required=True, type=Path, help="ONNX file to write")
    parser.add_argument("--int8", action="store_true", help="write a statically quantised int8 model (QDQ)")
    parser.add_argument(
        "--calib-crops", type=int, default=128, metavar="N", help="crops used to calibrate int8 (default 128)"
    )
    parser.add_argument(
        "--calib-data",
        type=Path,
        metavar="FILE.npz",
        help="calibration crops: .npz with 'crops' (N, S, S, 3) uint8 BGR; default: render them with the "
        "training sampler",
    )
    parser.add_argument("--opset", type=int, default=OPSET, help=f"ONNX opset, >= 17 (default {OPSET})")
    return parser


def main(argv: list[str] | None = None) -> int:
    """``dronekey-export``: one line on stderr and exit status 1 on bad input, no traceback."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr)
    try:
        if args.calib_crops < 1:
            raise ValueError(f"--calib-crops must be >= 1, got {args.calib_crops}")
        crops = load_calibration_npz(args.calib_data) if args.calib_data is not None else None
        path = export_checkpoint(args.checkpoint, args.out, args.int8, crops, args.calib_crops, args.opset)
    except (CheckpointError, ExportError, FileNotFoundError, ValueError, OSError) as exc:
        print(f"dronekey-export: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    size_mb = path.stat().st_size / 1e6
    print(f"wrote {path} ({'int8' if args.int8 else 'fp32'}, {size_mb:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
