"""The presence stage of a run: the best network's presence head refit alone, kept if it helps.

After the epochs, the best network's presence head is refit alone for ``presence_steps`` steps on
the frozen network (``fit_presence_head``), and kept only if its validation AUC is at least the
jointly trained head's (``refit_presence``). It exists for networks whose head read the last
layer's IR, which with the edge encoder hardly varies between crops (the head collapsed); the edge
preset's head reads the projected-token mean (``DroneKeyConfig.presence_input``) and trains well
jointly, so the refit is a safeguard.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from dronekey.nn.model import DroneKeyNet
from dronekey.training.checkpoints import load_checkpoint, save_checkpoint
from dronekey.training.validation import evaluate, figures

__all__ = ["fit_presence_head", "refit_presence"]

log = logging.getLogger(__name__)


def fit_presence_head(net: DroneKeyNet, batches: Iterator, steps: int, lr: float = 3e-3) -> None:
    """Refit the presence head alone, on the frozen network, reading the projected tokens.

    Why a separate stage: trained jointly, the presence term is a small share of the loss and, with
    the head on the last IR, sees an input that hardly varies across crops (``DroneKeyConfig``,
    ``presence_input``); the keypoint epochs ended with the presence probability equal to the share
    of drone crops everywhere (AUC < 50 %). The head is a linear map of d features: a few hundred
    steps fit it, and nothing else in the network changes. ``net.config`` is switched to
    ``presence_input="tokens"`` so that the checkpoint and its ONNX export compute what was fitted.
    ``batches`` yields (x, keypoints, present, area) as ``dronekey.training.crop_stream`` does.
    """
    if net.config.presence_input != "tokens":
        log.info(
            "presence head: switching its input from %s to the projected tokens", net.config.presence_input
        )
        net.config = replace(net.config, presence_input="tokens")
    net.eval()  # BatchNorm running statistics, as at inference
    head = net.presence
    torch.nn.init.zeros_(head.weight)
    torch.nn.init.zeros_(head.bias)
    opt = torch.optim.Adam(head.parameters(), lr=lr)
    bce = torch.nn.BCEWithLogitsLoss()
    for _ in tqdm(range(steps), desc="presence head", unit="step", disable=not sys.stderr.isatty()):
        x, _kp, present, _area = next(batches)
        with torch.no_grad():
            features = net.project(x).mean(dim=1)  # (B, d): what forward() gives the head
        loss = bce(head(features).squeeze(-1), present.float())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()


def refit_presence(
    best_path: Path, batches: Iterator, steps: int, val: dict[str, np.ndarray]
) -> float | None:
    """Refit the presence head of the checkpoint at ``best_path`` for ``steps`` steps and rewrite the
    checkpoint if its AUC on the validation crops ``val`` did not drop. Returns the new AP^kp
    (percent) when the refit was kept, None when it was discarded."""
    best, meta = load_checkpoint(best_path)
    before = evaluate(best, val)
    fit_presence_head(best, batches, steps)
    metrics = evaluate(best, val)
    kept = metrics["presence_auc"] >= before["presence_auc"]
    log.info(
        "presence head refit (%d steps): AUC %.3f -> %.3f, AP %.2f -> %.2f: %s",
        steps,
        before["presence_auc"],
        metrics["presence_auc"],
        before["ap_kp"],
        metrics["ap_kp"],
        "kept" if kept else "discarded (the jointly trained head was better)",
    )
    if not kept:
        return None
    meta["figures"] = figures(metrics)
    meta["presence_steps"] = steps
    save_checkpoint(best_path, best, meta)
    return metrics["ap_kp"]
