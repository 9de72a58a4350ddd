"""Static int8 quantisation of an fp32 DroneKey ONNX export (``dronekey.training.export``).

QDQ format, per-channel int8 weights, uint8 activations, with onnxruntime's tools, calibrated on
crops as the daemon sees them: an .npz file (key ``crops``, (N, S, S, 3) uint8 BGR), a callable, or
by default crops rendered by the training sampler (``dronekey.sim_replay.sampler.CropSampler``)
with the model's crop policy. The fp32 model's metadata is copied, with ``precision`` = "int8".
"""

from __future__ import annotations

import json
import logging
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process

from dronekey.geometry.crop import CropPolicy
from dronekey.perception.keypoint_model import INPUT_NAME, preprocess_crops
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig
from dronekey.training.export import ExportError, write_metadata

__all__ = ["CalibrationSource", "calibration_crops_from_sampler", "load_calibration_npz", "quantize_int8"]

LOG = logging.getLogger(__name__)
CalibrationSource = np.ndarray | Callable[[int], np.ndarray] | None


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


class _CropReader(CalibrationDataReader):
    """Feeds the preprocessed crops (N, 3, S, S) one at a time (batch 1, as the daemon runs)."""

    def __init__(self, tensors: np.ndarray) -> None:
        self._items = iter(tensors)

    def get_next(self) -> dict[str, np.ndarray] | None:
        item = next(self._items, None)
        return None if item is None else {INPUT_NAME: item[None]}


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
            _CropReader(tensors),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["Conv", "MatMul", "Gemm"],
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
        )
    metadata["precision"] = json.dumps("int8")
    write_metadata(out, metadata)
    return out
