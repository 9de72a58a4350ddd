"""The files of a training run: network checkpoints, the run state that ``--resume`` reads, history.

A run folder holds ``last.pt`` and ``best.pt`` (network checkpoints, ``save_checkpoint``),
``state.pt`` (recipe, epoch, history, best AP, optimiser and scheduler state and the training-only
heatmap heads, ``save_run_state``), ``history.json`` (one entry per epoch), the cached validation
crops and the plots.

A network checkpoint is ``torch.save({"config": cfg.to_dict(), "model": state_dict, "meta": meta})``,
read back with ``weights_only=True``; ``dronekey-export`` turns it into the shipped ONNX model.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch

from dronekey.nn.model import DroneKeyConfig, DroneKeyNet
from dronekey.training.recipe import Recipe

__all__ = [
    "CheckpointError",
    "RunFolder",
    "load_checkpoint",
    "load_run_state",
    "save_checkpoint",
    "save_run_state",
]


class CheckpointError(ValueError):
    """A checkpoint file is missing or does not hold a DroneKey network; the message says which."""


def save_checkpoint(path: str | Path, net: DroneKeyNet, meta: Mapping[str, Any] | None = None) -> Path:
    """Write ``{"config": ..., "model": state_dict, "meta": meta}`` with ``torch.save``.

    ``meta`` is free-form but must hold only plain Python values (str, int, float, bool, lists,
    dicts) so that ``load_checkpoint`` can read it with ``weights_only=True``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"config": net.config.to_dict(), "model": net.state_dict(), "meta": dict(meta or {})}
    torch.save(payload, path)
    return path


def load_checkpoint(path: str | Path, map_location: str = "cpu") -> tuple[DroneKeyNet, dict[str, Any]]:
    """Rebuild the network of a checkpoint written as ``save_checkpoint`` does.

    Returns the network (in eval mode) and the checkpoint's ``meta`` dict. Raises
    ``CheckpointError`` naming the path and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # torch raises many types for a corrupt / foreign file
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"{path}: not a readable checkpoint ({reason})") from None
    if not isinstance(payload, dict) or not {"config", "model"} <= set(payload):
        keys = sorted(payload) if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"{path}: expected a dict with 'config' and 'model', got {keys}")
    try:
        config = DroneKeyConfig.from_dict(payload["config"])
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: bad config ({exc})") from None
    net = DroneKeyNet(config)
    try:
        net.load_state_dict(payload["model"])
    except RuntimeError as exc:
        raise CheckpointError(f"{path}: weights do not match its config ({exc})") from None
    return net.eval(), dict(payload.get("meta") or {})


@dataclass(frozen=True)
class RunFolder:
    """The paths of a run's files in folder ``root``."""

    root: Path

    @property
    def last(self) -> Path:
        """The network after the latest epoch."""
        return self.root / "last.pt"

    @property
    def best(self) -> Path:
        """The network of the best epoch by validation AP (after the presence refit, if kept)."""
        return self.root / "best.pt"

    @property
    def state(self) -> Path:
        """The run state ``--resume`` continues from (``save_run_state``)."""
        return self.root / "state.pt"

    @property
    def history(self) -> Path:
        """One JSON entry per epoch: losses, S(t), learning rate, speed and validation metrics."""
        return self.root / "history.json"

    def resumable(self) -> bool:
        """Whether a run has left both its last network and its state here."""
        return self.last.is_file() and self.state.is_file()

    def validation_cache(self, n: int, input_size: int, coco: bool) -> Path:
        """Where the ``n`` validation crops of side ``input_size`` px are cached (.npz)."""
        return self.root / f"val_{'coco_' if coco else ''}{n}_{input_size}.npz"

    def write_history(self, history: list[dict]) -> None:
        """Rewrite ``history.json``."""
        self.history.write_text(json.dumps(history, indent=1))


def save_run_state(
    path: Path,
    recipe: Recipe,
    epoch: int,
    history: list[dict],
    best_ap: float,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    heatmaps: torch.nn.Module | None = None,
) -> None:
    """Write what ``--resume`` needs after ``epoch`` (0-based) to ``path`` with ``torch.save``:
    ``{"recipe": asdict(recipe), "epoch", "history", "best_ap", "optimizer", "scheduler"}`` plus
    ``"heatmaps"`` (the heatmap heads' weights) when the run has them."""
    torch.save(
        {
            "recipe": asdict(recipe),
            "epoch": epoch,
            "history": history,
            "best_ap": best_ap,
            "optimizer": optimizer.state_dict(),
            "scheduler": scheduler.state_dict(),
            **({"heatmaps": heatmaps.state_dict()} if heatmaps is not None else {}),
        },
        path,
    )


def load_run_state(path: Path) -> dict[str, Any]:
    """The dict ``save_run_state`` wrote (optimiser state included, hence not ``weights_only``)."""
    return torch.load(path, weights_only=False)
