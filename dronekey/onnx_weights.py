"""Read a DroneKey network's weights back out of an exported ONNX model, to fine-tune from it.

Checkpoints stay outside git (they are large and machine-local); the exported model is what ships.
Fine-tuning from the shipped model (``dronekey-train --init-from dronekey_edge.onnx``) therefore
needs its weights as a ``state_dict``. The exporter (``dronekey.export``) writes them in two ways:

- by name (``inner.<parameter>``): most parameters, and every backbone convolution, whose
  BatchNorm the exporter folded in (``<conv>.weight`` W' = W gamma / sigma, ``<conv>.weight_bias``
  b' = beta - gamma mu / sigma);
- as anonymous constants: the transformer's linear weights (transposed, next to a MatMul whose
  ``pkg.torch.onnx.name_scopes`` metadata names the module) and the attention's q, k, v biases
  (slices of ``in_proj_bias`` added in that order, layer by layer).

Folded BatchNorm cannot be unfolded (gamma and sigma come out only as their ratio), so each BN
becomes the identity plus b' (weight 1, bias b', running mean 0, running variance 1 - eps) and
must stay in eval mode while training (``frozen_batchnorm``): in train mode it would normalise by
batch statistics and lose b'. ``weights_from_onnx`` checks the rebuilt network against ONNX
Runtime on a probe batch before returning.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from torch import nn

__all__ = ["OnnxWeightsError", "frozen_batchnorm", "weights_from_onnx"]

log = logging.getLogger(__name__)

PREFIX = "inner."  # the exporter's wrapper module holds the network as ``inner``
MAX_ABS_DIFF = 1e-3  # the rebuilt network must agree with ONNX Runtime this closely (normalised units)


class OnnxWeightsError(ValueError):
    """The ONNX file is not a DroneKey export whose weights this network can take; says why."""


def _scope(node) -> list[str]:
    for prop in node.metadata_props:
        if prop.key == "pkg.torch.onnx.name_scopes":
            import ast

            return list(ast.literal_eval(prop.value))
    return []


def weights_from_onnx(path: str | Path, net: nn.Module) -> dict[str, torch.Tensor]:
    """A ``state_dict`` for ``net`` (a ``DroneKeyNet`` of the same architecture) from the export at
    ``path``; tensors the export lacks (e.g. a head it has not) are left out. BatchNorm layers come
    back folded (see the module docstring): train with ``frozen_batchnorm``."""
    import onnx
    from onnx import numpy_helper

    path = Path(path)
    if not path.is_file():
        raise OnnxWeightsError(f"model not found: {path}")
    try:
        model = onnx.load(str(path))
    except Exception as exc:
        raise OnnxWeightsError(f"{path}: not a readable ONNX model ({exc})") from None
    init = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    own = net.state_dict()
    out: dict[str, torch.Tensor] = {}
    for name, value in init.items():
        if not name.startswith(PREFIX):
            continue
        key = name[len(PREFIX) :]
        if key.endswith(".weight_bias"):  # folded BN of the conv: the next module is its BatchNorm
            conv = key[: -len(".weight_bias")]
            parent, index = conv.rsplit(".", 1)
            bn = f"{parent}.{int(index) + 1}"
            if f"{bn}.running_var" not in own:
                raise OnnxWeightsError(f"{path}: no BatchNorm after {conv} in this network")
            eps = dict(net.named_modules())[bn].eps
            out[f"{bn}.weight"] = torch.ones_like(own[f"{bn}.weight"])
            out[f"{bn}.bias"] = torch.from_numpy(value.copy())
            out[f"{bn}.running_mean"] = torch.zeros_like(own[f"{bn}.running_mean"])
            out[f"{bn}.running_var"] = torch.full_like(own[f"{bn}.running_var"], 1.0 - eps)
        elif key in own:
            out[key] = torch.from_numpy(value.copy())
    q_k_v_biases: list[np.ndarray] = []
    for node in model.graph.node:
        consts = [i for i in node.input if i in init and not i.startswith(PREFIX)]
        if not consts:
            continue
        scope = _scope(node)
        module = next((s[len(PREFIX) :] for s in reversed(scope) if s.startswith(PREFIX)), None)
        if node.op_type == "MatMul" and module and f"{module}.weight" in own:
            out[f"{module}.weight"] = torch.from_numpy(init[consts[0]].T.copy())
        elif node.op_type == "Add" and module is None and consts[0].startswith("slice"):
            q_k_v_biases.append(init[consts[0]])
    layers = [k[: -len(".self_attn.in_proj_bias")] for k in own if k.endswith(".self_attn.in_proj_bias")]
    if len(q_k_v_biases) != 3 * len(layers):
        raise OnnxWeightsError(
            f"{path}: found {len(q_k_v_biases)} attention biases for {len(layers)} layers (expected 3 each)"
        )
    for n, layer in enumerate(layers):
        q, k, v = q_k_v_biases[3 * n : 3 * n + 3]
        out[f"{layer}.self_attn.in_proj_bias"] = torch.from_numpy(np.concatenate([q, k, v]))
    bad = [k for k, v in out.items() if k not in own or tuple(own[k].shape) != tuple(v.shape)]
    if bad:
        raise OnnxWeightsError(f"{path}: weights that do not fit this network: {bad[:5]}")
    _check_against_runtime(path, net, out)
    return out


def _check_against_runtime(path: Path, net: nn.Module, weights: dict[str, torch.Tensor]) -> None:
    import copy

    import onnxruntime as ort

    probe = copy.deepcopy(net).eval()
    probe.load_state_dict(weights, strict=False)
    size = probe.config.input_size
    x = np.random.default_rng(0).normal(0, 1, (2, 3, size, size)).astype(np.float32)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    expected = session.run(None, {session.get_inputs()[0].name: x})[0]
    with torch.no_grad():
        got = probe(torch.from_numpy(x)).keypoints.numpy()
    diff = float(np.abs(got - expected).max())
    if not diff <= MAX_ABS_DIFF:
        raise OnnxWeightsError(f"{path}: rebuilt network disagrees with ONNX Runtime by {diff:.3g}")
    log.info("weights read back from %s (keypoints agree with ONNX Runtime within %.1e)", path, diff)


def frozen_batchnorm(net: nn.Module) -> int:
    """Put every BatchNorm of ``net`` in eval mode (fixed affine); returns how many. Call after
    each ``net.train()``."""
    n = 0
    for m in net.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm):
            m.eval()
            n += 1
    return n
