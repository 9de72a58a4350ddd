"""Export a DroneKey network to fp32 ONNX for the runtime (``dronekey.perception.keypoint_model``),
with the metadata that carries its contract (``dronekey.training.quantize`` makes the int8 model,
``dronekey.training.export_cli`` is ``dronekey-export``).

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
(``dronekey.training.checkpoints.save_checkpoint``). Recognised meta keys: ``drone_spec`` (spec name
or path, e.g. "mini2"), ``crop_policy`` (``dronekey.geometry.crop.CropPolicy`` fields),
``trained_on``, ``figures``, ``epochs``; others are kept under ``meta``.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch

from dronekey import __version__
from dronekey.geometry.crop import CropPolicy
from dronekey.geometry.drone_spec import load_spec
from dronekey.nn.model import DroneKeyNet, count_parameters
from dronekey.perception.keypoint_model import (
    HEADING_OUTPUT,
    IMAGENET_MEAN,
    IMAGENET_STD,
    INPUT_NAME,
    OUTPUT_NAMES,
)

__all__ = ["ExportError", "build_metadata", "export_onnx", "output_names", "write_metadata"]

LOG = logging.getLogger(__name__)
OPSET = 18
FORMAT_VERSION = "1"
_KNOWN_META = ("drone_spec", "crop_policy", "trained_on", "figures")
_NOISY_LOGGERS = ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript", "onnx_ir")


class ExportError(RuntimeError):
    """Export or quantisation failed; the message names the file and the problem."""


# --------------------------------------------------------------------------------------------------
# Metadata
# --------------------------------------------------------------------------------------------------


def _drone_spec_entry(value: Any) -> dict | None:
    """The ``drone_spec`` metadata: the spec named in meta, loaded so the ONNX is self-contained."""
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
    model = onnx.load(str(path))
    del model.metadata_props[:]
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.save(model, str(path))


# --------------------------------------------------------------------------------------------------
# fp32 export
# --------------------------------------------------------------------------------------------------


def output_names(net: DroneKeyNet) -> list[str]:
    """The ONNX outputs of ``net``: keypoints, presence, gate, and heading with a front/back head."""
    return list(OUTPUT_NAMES) + ([HEADING_OUTPUT] if net.config.heading_head else [])


class _Exported(torch.nn.Module):
    """The network with ONNX-facing outputs: (keypoints, sigmoid(presence_logit), gate[,
    sigmoid(heading_logit)])."""

    def __init__(self, inner: DroneKeyNet) -> None:
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


def _name_batch_dimension(path: Path) -> None:
    """Call the dynamic batch dimension of the input and of every output ``batch``."""
    model = onnx.load(str(path))
    for value in [*model.graph.input, *model.graph.output]:
        dim = value.type.tensor_type.shape.dim[0]
        if dim.dim_param or not dim.HasField("dim_value"):
            dim.dim_param = "batch"
    onnx.save(model, str(path))


def export_onnx(
    net: DroneKeyNet,
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
    if opset < 17:
        raise ValueError(f"opset must be >= 17, got {opset}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    size = net.config.input_size
    wrapper = _Exported(net).eval()
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


def _verify_against_torch(
    wrapper: torch.nn.Module, path: Path, example: torch.Tensor, names: list[str], tolerance: float = 1e-3
) -> None:
    """Raise ``ExportError`` when the ONNX file's outputs on ``example`` depart from ``wrapper``'s."""
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
