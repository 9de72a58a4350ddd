"""Read a DroneKey network's weights back out of an exported ONNX model, to fine-tune from it.

Checkpoints stay outside git (they are large and machine-local); the exported model is what ships.
Fine-tuning from the shipped model (``dronekey-train --init-from dronekey_edge.onnx``) therefore
needs its weights as a ``state_dict``. The exporter (``dronekey.training.export``) writes them in two ways:

- as inputs of nodes whose ``pkg.torch.onnx.name_scopes`` metadata names the module: backbone
  convolutions with their BatchNorm folded in (W' = W gamma / sigma, b' = beta - gamma mu / sigma),
  linear weights transposed next to a MatMul, biases next to an Add, LayerNorm and Gemm inputs;
- as constants of nodes without a module scope: the attention's q, k, v projections (sliced out
  of ``in_proj_weight`` / ``in_proj_bias``, in that order, before the layer's ``out_proj``).

Folded BatchNorm cannot be unfolded (gamma and sigma come out only as their ratio), so each BN
becomes the identity plus b' (weight 1, bias b', running mean 0, running variance 1 - eps) and
must stay in eval mode while training (``frozen_batchnorm``): in train mode it would normalise by
batch statistics and lose b'. ``weights_from_onnx`` checks the rebuilt network against ONNX
Runtime on a probe batch before returning.
"""

from __future__ import annotations

import ast
import copy
import logging
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import numpy_helper
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
            return list(ast.literal_eval(prop.value))
    return []


def weights_from_onnx(path: str | Path, net: nn.Module) -> dict[str, torch.Tensor]:
    """A ``state_dict`` for ``net`` (a ``DroneKeyNet`` of the same architecture) from the export at
    ``path``; tensors the export lacks (e.g. a head it has not) are left out. BatchNorm layers come
    back folded (see the module docstring): train with ``frozen_batchnorm``.

    The graph is walked node by node and each constant is given to the module its node's name
    scope names, whatever the constant is called: the exporter shares one initializer between equal
    tensors (all-zero biases of an untrained network) and folds some slices, so names alone do not
    say whose a constant is.
    """

    path = Path(path)
    if not path.is_file():
        raise OnnxWeightsError(f"model not found: {path}")
    try:
        model = onnx.load(str(path))
    except Exception as exc:
        raise OnnxWeightsError(f"{path}: not a readable ONNX model ({exc})") from None
    init = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    own = net.state_dict()
    modules = dict(net.named_modules())
    out: dict[str, torch.Tensor] = {}

    def put(key: str, value: np.ndarray) -> None:
        if key not in own or tuple(own[key].shape) != tuple(value.shape):
            raise OnnxWeightsError(
                f"{path}: {key} {tuple(value.shape)} does not fit this network "
                f"({tuple(own[key].shape) if key in own else 'no such tensor'})"
            )
        out[key] = torch.from_numpy(np.array(value, order="C"))  # a writable copy: ONNX arrays are read-only

    def folded_bn(conv: str, bias: np.ndarray) -> None:
        parent, index = conv.rsplit(".", 1)
        bn = f"{parent}.{int(index) + 1}"
        if not isinstance(modules.get(bn), nn.modules.batchnorm._BatchNorm):
            raise OnnxWeightsError(f"{path}: no BatchNorm after {conv} in this network")
        put(f"{bn}.weight", np.ones_like(bias))
        put(f"{bn}.bias", bias)
        put(f"{bn}.running_mean", np.zeros_like(bias))
        put(f"{bn}.running_var", np.full_like(bias, 1.0 - modules[bn].eps))

    anonymous: dict[str, list[np.ndarray]] = {"MatMul": [], "Add": []}  # q, k, v of the next layer
    for node in model.graph.node:
        consts = {j: init[i] for j, i in enumerate(node.input) if i in init}
        scope = _scope(node)
        module = next((s[len(PREFIX) :] for s in reversed(scope) if s.startswith(PREFIX)), None)
        op = node.op_type
        if op == "Slice" and node.input[0].endswith(".self_attn.in_proj_weight"):
            key = node.input[0][len(PREFIX) :]
            if key not in out:
                put(key, init[node.input[0]])
            continue
        if not consts or (module is None and op not in anonymous):
            continue
        if module is None:  # q, k or v projection of the layer whose out_proj comes next
            if op == "MatMul" and 1 in consts and consts[1].ndim == 2:
                anonymous["MatMul"].append(consts[1].T)
            elif op == "Add" and consts and next(iter(consts.values())).ndim == 1:
                anonymous["Add"].append(next(iter(consts.values())))
            continue
        if module.endswith(".self_attn.out_proj"):
            layer = module[: -len(".out_proj")]
            weights, biases = anonymous["MatMul"], anonymous["Add"]
            if len(weights) == 3:
                put(f"{layer}.in_proj_weight", np.concatenate(weights))
            if len(biases) == 3:
                put(f"{layer}.in_proj_bias", np.concatenate(biases))
            elif f"{layer}.in_proj_bias" not in out:
                raise OnnxWeightsError(
                    f"{path}: found {len(biases)} attention biases for {layer} (expected 3)"
                )
            anonymous = {"MatMul": [], "Add": []}
        if op == "Conv":
            # a folded conv's scope may name its BatchNorm; the weight's own name names the conv
            weight_name = node.input[1]
            if weight_name.startswith(PREFIX) and weight_name.endswith(".weight"):
                module = weight_name[len(PREFIX) : -len(".weight")]
            put(f"{module}.weight", consts[1])
            if 2 in consts:
                if f"{module}.bias" in own:
                    put(f"{module}.bias", consts[2])
                else:
                    folded_bn(module, consts[2])
        elif op == "MatMul" and 1 in consts:
            put(f"{module}.weight", consts[1].T)
        elif op == "Add" and f"{module}.bias" in own:
            put(f"{module}.bias", next(iter(consts.values())))
        elif op == "Gemm":
            trans_b = next((a.i for a in node.attribute if a.name == "transB"), 0)
            put(f"{module}.weight", consts[1] if trans_b else consts[1].T)
            if 2 in consts:
                put(f"{module}.bias", consts[2])
        elif op == "LayerNormalization":
            put(f"{module}.weight", consts[1])
            if 2 in consts:
                put(f"{module}.bias", consts[2])
    _check_against_runtime(path, net, out)
    return out


def _check_against_runtime(path: Path, net: nn.Module, weights: dict[str, torch.Tensor]) -> None:
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
