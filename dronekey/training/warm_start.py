"""Start a new run from another network's weights (``dronekey-train --init-from``): a checkpoint
(.pt) or an exported model (.onnx, e.g. the shipped one). Tensors whose names and shapes match are
copied; heads the source lacks start fresh."""

from __future__ import annotations

import logging
from pathlib import Path

import torch

from dronekey.nn.model import DroneKeyNet
from dronekey.training.onnx_weights import OnnxWeightsError, weights_from_onnx

__all__ = ["WarmStartError", "warm_start"]

log = logging.getLogger(__name__)


class WarmStartError(ValueError):
    """``--init-from`` names no readable DroneKey checkpoint or model; the message says which and why."""


def warm_start(net: DroneKeyNet, path: str | Path) -> bool:
    """Copy into ``net`` the weights of checkpoint or exported model ``path`` whose names and shapes
    match. Returns True when they came from an ONNX export (its BatchNorm folded: keep it frozen)."""
    if str(path).endswith(".onnx"):
        try:
            weights = weights_from_onnx(path, net)
        except OnnxWeightsError as exc:
            raise WarmStartError(f"--init-from: {exc}") from None
        net.load_state_dict(weights, strict=False)
        log.info("initialised from the exported model %s; BatchNorm frozen (folded in the export)", path)
        return True
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        weights = payload["model"]
    except FileNotFoundError:
        raise WarmStartError(f"--init-from: checkpoint not found: {path}") from None
    except Exception as exc:
        raise WarmStartError(f"--init-from {path}: not a DroneKey checkpoint ({exc})") from None
    own = net.state_dict()
    usable = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape}
    net.load_state_dict(usable, strict=False)
    log.info(
        "initialised %d of %d tensors from %s (fresh: %s)",
        len(usable),
        len(own),
        path,
        ", ".join(sorted({k.split(".")[0] for k in set(own) - set(usable)})) or "none",
    )
    return False
