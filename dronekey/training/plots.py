"""A training run's plots, rewritten each epoch from its history: loss and S(t) per epoch (paper
Fig. 5), the mean gate weight per encoder layer (Fig. 8) and the validation figures per epoch."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt

__all__ = ["write_plots"]


def write_plots(history: list[dict], out_dir: Path) -> None:
    """``loss_scale.png``, ``gate_weights.png`` and ``validation.png`` in ``out_dir`` from ``history``
    (the entries of the run's ``history.json``); nothing for an empty history."""
    if not history:
        return
    ep = [h["epoch"] for h in history]
    fig, ax1 = plt.subplots(figsize=(6, 3.5))
    ax1.plot(ep, [h["train_loss"] for h in history], "r--", label="loss")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("training loss", color="r")
    ax2 = ax1.twinx()
    ax2.plot(ep, [h["scale"] for h in history], "b-", label="S(t)")
    ax2.set_ylabel("scale S(t)", color="b")
    fig.tight_layout()
    fig.savefig(out_dir / "loss_scale.png", dpi=120)
    plt.close(fig)

    gate = history[-1]["val"]["gate"]
    fig, ax = plt.subplots(figsize=(5, 3))
    colours = ["tab:pink"] * (len(gate) - 1) + ["tab:orange"]
    ax.bar(range(1, len(gate) + 1), gate, color=colours)
    ax.set_xlabel("encoder layer")
    ax.set_ylabel("mean gate weight")
    ax.set_title(f"gate weights, epoch {history[-1]['epoch']}")
    fig.tight_layout()
    fig.savefig(out_dir / "gate_weights.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for key in ("ap_kp", "sr90", "sr95"):
        ax.plot(ep, [h["val"][key] for h in history], label=key)
    ax.set_xlabel("epoch")
    ax.set_ylabel("%")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / "validation.png", dpi=120)
    plt.close(fig)
