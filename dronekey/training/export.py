"""Export a trained DroneKey checkpoint to ONNX (fp32, optionally int8) for the runtime
(``dronekey.perception.keypoint_model``).

The ONNX contract (what ``dronekey.perception.keypoint_model.KeypointModel`` relies on):

- input ``image``: (batch, 3, S, S) float32, normalised RGB (see ``normalisation`` below); the batch
  dimension is dynamic and named ``batch``, S is fixed;
- outputs ``keypoints`` (batch, K, 2) in normalised crop units, ``presence`` (batch,) probability
  (the sigmoid is in the graph), ``gate`` (batch, N) per-layer gate weights;
- metadata_props (JSON strings): ``input_size`` [S, S], ``normalisation`` {color, scale, mean, std},
  ``keypoint_names``, ``drone_spec``, ``crop_policy``, ``trained_on``, ``figures``, ``config``,
  ``params``, ``precision`` ("fp32" | "int8"), ``meta`` (the rest of the checkpoint's meta),
  ``producer`` and ``format_version``.

The checkpoint is ``torch.save({"config": cfg.to_dict(), "model": state_dict, "meta": {...}})``
(``dronekey.nn.model.save_checkpoint``). Recognised meta keys: ``drone_spec`` (spec name or path, e.g.
"mini2"), ``crop_policy`` (``dronekey.geometry.crop.CropPolicy`` fields), ``trained_on``, ``figures``,
``epochs``; others are kept under ``meta``.

int8: static quantisation (QDQ, per-channel int8 weights, uint8 activations) with onnxruntime's
tools, calibrated on crops as the daemon sees them: an .npz file (key ``crops``, (N, S, S, 3) uint8
BGR), a callable, or by default crops rendered by the training sampler
(``dronekey.sim_replay.sampler.CropSampler``) with the model's crop policy.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import tempfile
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from dronekey import __version__
from dronekey.geometry.crop import CropPolicy
from dronekey.perception.keypoint_model import (
    HEADING_OUTPUT,
    IMAGENET_MEAN,
    IMAGENET_STD,
    INPUT_NAME,
    OUTPUT_NAMES,
    preprocess_crops,
)

__all__ = [
    "ExportError",
    "build_metadata",
    "calibration_crops_from_sampler",
    "export_checkpoint",
    "export_onnx",
    "load_calibration_npz",
    "main",
    "quantize_int8",
    "write_metadata",
]

LOG = logging.getLogger(__name__)
OPSET = 18
FORMAT_VERSION = "1"
CalibrationSource = np.ndarray | Callable[[int], np.ndarray] | None
_KNOWN_META = ("drone_spec", "crop_policy", "trained_on", "figures")
_NOISY_LOGGERS = ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript", "onnx_ir")


class ExportError(RuntimeError):
    """Export or quantisation failed; the message names the file and the problem."""


# --------------------------------------------------------------------------------------------------
# Metadata
# --------------------------------------------------------------------------------------------------


def _drone_spec_entry(value: Any) -> dict | None:
    """The ``drone_spec`` metadata: the spec named in meta, loaded so the ONNX is self-contained."""
    from dronekey.geometry.drone_spec import load_spec

    if value is None:
        return None
    if isinstance(value, Mapping):
        return dict(value)
    spec = load_spec(str(value))
    return {
        "name": spec.name,
        "display_name": spec.display_name,
        "keypoints_3d": spec.keypoints_3d.tolist(),
        "keypoint_names": list(spec.keypoint_names),
    }


def build_metadata(
    config_dict: Mapping[str, Any], meta: Mapping[str, Any], params: int, precision: str = "fp32"
) -> dict[str, str]:
    """The ONNX metadata_props of a DroneKey export (string -> JSON string)."""
    size = int(config_dict["input_size"])
    spec = _drone_spec_entry(meta.get("drone_spec"))
    if spec is None:
        LOG.warning("checkpoint meta has no drone_spec; keypoint names default to prop1..prop4")
    names = list(spec.get("keypoint_names", [])) if spec else []
    if len(names) != int(config_dict.get("num_keypoints", 4)):
        names = [f"prop{i + 1}" for i in range(int(config_dict.get("num_keypoints", 4)))]
    crop_policy = meta.get("crop_policy")
    if crop_policy is None:
        crop_policy = dataclasses.asdict(CropPolicy(input_size=size))
        LOG.warning(
            "checkpoint meta has no crop_policy; recording the default CropPolicy(input_size=%d)", size
        )
    extra = {k: v for k, v in meta.items() if k not in _KNOWN_META}
    entries = {
        "format_version": FORMAT_VERSION,
        "producer": f"dronekey {__version__}",
        "precision": precision,
        "input_size": [size, size],
        "normalisation": {
            "color": "RGB",
            "scale": 1.0 / 255.0,
            "mean": list(IMAGENET_MEAN),
            "std": list(IMAGENET_STD),
            "formula": "(rgb * scale - mean) / std",
        },
        "keypoint_names": names,
        "drone_spec": spec,
        "crop_policy": dict(crop_policy),
        "trained_on": meta.get("trained_on"),
        "figures": meta.get("figures"),
        "config": dict(config_dict),
        "params": int(params),
        "meta": extra,
    }
    return {key: json.dumps(value) for key, value in entries.items()}


def write_metadata(path: str | Path, metadata: Mapping[str, str]) -> None:
    """Replace the metadata_props of the ONNX file at ``path`` with ``metadata``."""
    import onnx

    model = onnx.load(str(path))
    del model.metadata_props[:]
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.save(model, str(path))


# --------------------------------------------------------------------------------------------------
# fp32 export
# --------------------------------------------------------------------------------------------------


def output_names(net) -> list[str]:
    """The ONNX outputs of ``net``: keypoints, presence, gate, and heading with a front/back head."""
    return list(OUTPUT_NAMES) + ([HEADING_OUTPUT] if net.config.heading_head else [])


def _export_wrapper(net):
    """The network with ONNX-facing outputs: (keypoints, sigmoid(presence_logit), gate[,
    sigmoid(heading_logit)])."""
    import torch

    class _Exported(torch.nn.Module):
        def __init__(self, inner: torch.nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, image: torch.Tensor):
            out = self.inner(image)
            if out.heading_logit is None:
                return out.keypoints, torch.sigmoid(out.presence_logit), out.gate
            return (
                out.keypoints,
                torch.sigmoid(out.presence_logit),
                out.gate,
                torch.sigmoid(out.heading_logit),
            )

    return _Exported(net).eval()


def _name_batch_dimension(path: Path) -> None:
    """Call the dynamic batch dimension of the input and of every output ``batch``."""
    import onnx

    model = onnx.load(str(path))
    for value in [*model.graph.input, *model.graph.output]:
        dim = value.type.tensor_type.shape.dim[0]
        if dim.dim_param or not dim.HasField("dim_value"):
            dim.dim_param = "batch"
    onnx.save(model, str(path))


def export_onnx(
    net,
    out: str | Path,
    meta: Mapping[str, Any] | None = None,
    opset: int = OPSET,
    verify: bool = True,
) -> Path:
    """Write ``net`` (a ``DroneKeyNet``) as fp32 ONNX with the metadata of ``build_metadata``.

    Uses torch's dynamo exporter (the TorchScript exporter mistranslates batch-first
    ``nn.TransformerEncoderLayer`` in this torch version). With ``verify``, runs the file in ONNX
    Runtime on a random batch and raises ``ExportError`` if it departs from torch by more than 1e-3.
    """
    import torch

    from dronekey.nn.model import count_parameters

    if opset < 17:
        raise ValueError(f"opset must be >= 17, got {opset}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    size = net.config.input_size
    wrapper = _export_wrapper(net)
    example = torch.randn(2, 3, size, size, generator=torch.Generator().manual_seed(0))
    quiet = [logging.getLogger(name) for name in _NOISY_LOGGERS]
    levels = [lg.level for lg in quiet]
    for lg in quiet:
        lg.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # the exporter's own deprecation notices
            torch.onnx.export(
                wrapper,
                (example,),
                str(out),
                input_names=[INPUT_NAME],
                output_names=output_names(net),
                opset_version=opset,
                dynamo=True,
                external_data=False,
                dynamic_shapes={"image": {0: torch.export.Dim("batch", min=1)}},
                verbose=False,
            )
    except Exception as exc:
        raise ExportError(f"{out}: torch.onnx.export failed ({type(exc).__name__}: {exc})") from exc
    finally:
        for lg, level in zip(quiet, levels, strict=True):
            lg.setLevel(level)
    _name_batch_dimension(out)
    write_metadata(out, build_metadata(net.config.to_dict(), dict(meta or {}), count_parameters(net)))
    if verify:
        _verify_against_torch(wrapper, out, example, output_names(net))
    return out


def _verify_against_torch(wrapper, path: Path, example, names: list[str], tolerance: float = 1e-3) -> None:
    import onnxruntime as ort
    import torch

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    with torch.no_grad():
        expected = [t.numpy() for t in wrapper(example)]
    got = session.run(names, {INPUT_NAME: example.numpy()})
    for name, a, b in zip(names, got, expected, strict=True):
        err = float(np.max(np.abs(a - b)))
        if a.shape != b.shape or err > tolerance:
            raise ExportError(
                f"{path}: ONNX output {name!r} departs from torch "
                f"(max |diff| {err:.2e}, shapes {a.shape} / {b.shape})"
            )
    LOG.info("verified %s against torch (max |diff| within %.0e)", path.name, tolerance)


# --------------------------------------------------------------------------------------------------
# int8
# --------------------------------------------------------------------------------------------------


def load_calibration_npz(path: str | Path) -> np.ndarray:
    """Calibration crops from an .npz file: key ``crops``, (N, S, S, 3) uint8 BGR."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file not found: {path}")
    with np.load(path) as data:
        if "crops" not in data:
            raise ValueError(f"{path}: no 'crops' array (keys: {sorted(data.files)})")
        crops = data["crops"]
    if crops.dtype != np.uint8 or crops.ndim != 4 or crops.shape[3] != 3:
        raise ValueError(f"{path}: 'crops' must be (N, S, S, 3) uint8 BGR, got {crops.dtype} {crops.shape}")
    return crops


def calibration_crops_from_sampler(
    n: int, input_size: int, seed: int = 0, crop_policy: Mapping[str, Any] | None = None
) -> np.ndarray:
    """``n`` calibration crops (n, S, S, 3) uint8 BGR from the training sampler
    (``dronekey.sim_replay.sampler.CropSampler``), framed by ``crop_policy`` (the model's, from its
    metadata) as the daemon frames them, with the sampler's share of drone-free crops."""
    try:
        from dronekey.sim_replay.sampler import CropSampler, SamplerConfig
    except ImportError as exc:
        raise ExportError(
            f"no calibration crops given and the training sampler is unavailable ({exc}); "
            "pass --calib-data FILE.npz (key 'crops', (N, S, S, 3) uint8 BGR)"
        ) from None
    try:
        policy = CropPolicy(**dict(crop_policy)) if crop_policy else CropPolicy(input_size=input_size)
    except TypeError as exc:
        raise ExportError(f"crop_policy metadata {dict(crop_policy)} is not a CropPolicy ({exc})") from None
    if policy.input_size != input_size:
        raise ExportError(f"crop_policy input_size {policy.input_size} differs from the model's {input_size}")
    LOG.info("rendering %d calibration crops with the training sampler (seed %d)", n, seed)
    return CropSampler(SamplerConfig(crop=policy), seed=seed).batch(n)["image"]


def _resolve_crops(
    source: CalibrationSource, num_crops: int, input_size: int, seed: int, crop_policy: Mapping | None
) -> np.ndarray:
    if source is None:
        crops = calibration_crops_from_sampler(num_crops, input_size, seed, crop_policy)
    elif callable(source):
        crops = np.asarray(source(num_crops))
    else:
        crops = np.asarray(source)[:num_crops]
    if crops.dtype != np.uint8 or crops.ndim != 4 or crops.shape[1:] != (input_size, input_size, 3):
        raise ValueError(
            f"calibration crops must be (N, {input_size}, {input_size}, 3) uint8 BGR, "
            f"got {crops.dtype} {crops.shape}"
        )
    if len(crops) == 0:
        raise ValueError("calibration needs at least one crop, got 0")
    return crops


def _calibration_reader(tensors: np.ndarray):
    from onnxruntime.quantization import CalibrationDataReader

    class _CropReader(CalibrationDataReader):
        """Feeds the preprocessed crops one at a time (batch 1, as the daemon runs)."""

        def __init__(self) -> None:
            self._items = iter(tensors)

        def get_next(self):
            item = next(self._items, None)
            return None if item is None else {INPUT_NAME: item[None]}

    return _CropReader()


def quantize_int8(
    fp32_path: str | Path,
    out: str | Path,
    crops: CalibrationSource = None,
    num_crops: int = 128,
    seed: int = 0,
) -> Path:
    """Static int8 quantisation (QDQ) of an fp32 DroneKey ONNX, calibrated on ``crops``.

    Parameters
    ----------
    fp32_path : path of the fp32 export (its metadata is copied, with ``precision`` = "int8").
    out : where to write the int8 model.
    crops : (N, S, S, 3) uint8 BGR array, a callable ``n -> array``, or None to render them with
        the training sampler (``calibration_crops_from_sampler``).
    num_crops : crops used for calibration (min-max of the activations).
    seed : for the sampler.
    """
    import onnx
    from onnxruntime.quantization import QuantFormat, QuantType, quantize_static
    from onnxruntime.quantization.shape_inference import quant_pre_process

    fp32_path, out = Path(fp32_path), Path(out)
    if num_crops < 1:
        raise ValueError(f"num_crops must be >= 1, got {num_crops}")
    fp32_model = onnx.load(str(fp32_path))
    metadata = {p.key: p.value for p in fp32_model.metadata_props}
    if "input_size" not in metadata or "normalisation" not in metadata:
        raise ExportError(f"{fp32_path}: not a dronekey export (no input_size / normalisation metadata)")
    size = int(json.loads(metadata["input_size"])[0])
    norm = json.loads(metadata["normalisation"])
    policy = json.loads(metadata["crop_policy"]) if "crop_policy" in metadata else None
    crops = _resolve_crops(crops, num_crops, size, seed, policy)
    tensors = preprocess_crops(crops, size, norm["mean"], norm["std"])
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="dronekey-int8-") as tmp:
        prepared = Path(tmp) / "prepared.onnx"
        quant_pre_process(str(fp32_path), str(prepared), skip_symbolic_shape=True)
        quantize_static(
            str(prepared),
            str(out),
            _calibration_reader(tensors),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["Conv", "MatMul", "Gemm"],
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
        )
    metadata["precision"] = json.dumps("int8")
    write_metadata(out, metadata)
    return out


# --------------------------------------------------------------------------------------------------
# Checkpoint -> ONNX, and the CLI
# --------------------------------------------------------------------------------------------------


def export_checkpoint(
    checkpoint: str | Path,
    out: str | Path,
    int8: bool = False,
    crops: CalibrationSource = None,
    num_crops: int = 128,
    opset: int = OPSET,
) -> Path:
    """Checkpoint -> ONNX at ``out`` (int8 when ``int8``, its fp32 stage in a temporary folder)."""
    from dronekey.nn.model import load_checkpoint

    net, meta = load_checkpoint(checkpoint)
    out = Path(out)
    if not int8:
        return export_onnx(net, out, meta, opset)
    with tempfile.TemporaryDirectory(prefix="dronekey-export-") as tmp:
        fp32 = export_onnx(net, Path(tmp) / "fp32.onnx", meta, opset)
        return quantize_int8(fp32, out, crops, num_crops)


def _parser() -> argparse.ArgumentParser:
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
    from dronekey.nn.model import CheckpointError

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
