"""``Trainer``: one training run of a ``Recipe`` into a run folder, epoch by epoch.

Each epoch trains on the crop stream (``dronekey.training.crop_stream``) with the recipe's loss
(``dronekey.training.objective``) and ends with a validation (``dronekey.training.validation``); the
best checkpoint by AP is kept, training stops early after ``patience`` epochs without improvement,
a stopped run continues from its folder (``resume``, ``dronekey.training.checkpoints``), and the
plots (``dronekey.training.plots``) are rewritten each epoch. After the epochs comes the presence
stage (``dronekey.training.presence_refit``).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from dronekey.geometry.crop import CropPolicy
from dronekey.nn.heatmap_aux import PropellerHeatmaps
from dronekey.nn.loss import build_loss
from dronekey.nn.model import DroneKeyConfig, DroneKeyNet, count_parameters
from dronekey.training.checkpoints import (
    RunFolder,
    load_checkpoint,
    load_run_state,
    save_checkpoint,
    save_run_state,
)
from dronekey.training.crop_stream import batch_loader, crop_sources, describe_data
from dronekey.training.objective import batch_loss
from dronekey.training.onnx_weights import frozen_batchnorm
from dronekey.training.plots import write_plots
from dronekey.training.presence_refit import refit_presence
from dronekey.training.recipe import Recipe, lr_factor, resumed_recipe, schedule_time, with_overrides
from dronekey.training.validation import VALIDATION_SEED, evaluate, figures, validation_set
from dronekey.training.warm_start import warm_start

__all__ = ["PRECISIONS", "Trainer", "cpu_has_bf16", "train_mode"]

log = logging.getLogger(__name__)

PRECISIONS = ("auto", "bf16", "fp32")
GRAD_CLIP_NORM = 2.0
DRONE_SPEC = "mini2"  # the daemon's default drone; the renders mix Mini 2 and Air 2S


def cpu_has_bf16() -> bool:
    """Whether oneDNN has native bfloat16 kernels here (AVX512-BF16 / AMX): then autocast pays off."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def train_mode(net: torch.nn.Module, recipe: Recipe) -> None:
    """``net.train()``, with the BatchNorm layers left in eval mode under ``recipe.frozen_batchnorm``."""
    net.train()
    if recipe.frozen_batchnorm:
        frozen_batchnorm(net)


@dataclass
class _Run:
    """The live parts of a run between epochs."""

    recipe: Recipe
    net: DroneKeyNet
    heatmaps: PropellerHeatmaps | None
    params: list[torch.nn.Parameter]
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LambdaLR
    keypoint_loss: torch.nn.Module
    batches: Iterator
    val: dict[str, np.ndarray]
    history: list[dict]
    best_ap: float
    start_epoch: int
    steps_per_epoch: int
    total_steps: int
    use_bf16: bool


class Trainer:
    """One training run of ``recipe`` with its outputs in folder ``out``.

    Parameters
    ----------
    recipe : Recipe
        The run's recipe, e.g. ``presets()["edge"]``.
    out : path
        Run folder for checkpoints, state, history, validation crops and plots (created).
    recipe_name : str
        What the checkpoints' meta and the log call the recipe (the preset's name).
    overrides : mapping, optional
        Recipe fields to replace (None values ignored); they also win over a resumed run's saved
        recipe, so that e.g. more ``epochs`` extends a run.
    resume : bool
        Continue the run in ``out`` from its last epoch (a new run when there is none).
    init_from : path, optional
        Start a new run from the matching weights of this checkpoint (.pt) or exported model
        (.onnx; its BatchNorm then stays frozen). Ignored when resuming.
    coco : path, optional
        Train on this COCO keypoint JSON or folder instead of rendered crops.
    backgrounds : path, optional
        Folder of photos mixed into the rendered crops.
    seed : int
        Seed of torch and of the training stream (validation uses its own).
    workers : int
        Rendering processes feeding the trainer (0: render in this one).
    threads : int
        torch threads (0: torch's default).
    precision : {"auto", "bf16", "fp32"}
        bf16: bfloat16 autocast with fp32 weights; auto: bf16 where the CPU has native support.
    """

    def __init__(
        self,
        recipe: Recipe,
        out: str | Path,
        *,
        recipe_name: str,
        overrides: Mapping[str, Any] | None = None,
        resume: bool = False,
        init_from: str | Path | None = None,
        coco: str | Path | None = None,
        backgrounds: str | None = None,
        seed: int = 0,
        workers: int = 1,
        threads: int = 0,
        precision: str = "auto",
    ) -> None:
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        if workers < 0:
            raise ValueError(f"workers must be >= 0, got {workers}")
        if threads < 0:
            raise ValueError(f"threads must be >= 0, got {threads}")
        self.preset = recipe
        self.overrides = {k: v for k, v in (overrides or {}).items() if v is not None}
        self.recipe = with_overrides(recipe, self.overrides)
        self.folder = RunFolder(Path(out))
        self.recipe_name = recipe_name
        self.resume, self.init_from = resume, init_from
        self.coco, self.backgrounds = coco, backgrounds
        self.seed, self.workers, self.threads, self.precision = seed, workers, threads, precision

    # ------------------------------------------------------------------------------------- setup
    def _network(self) -> tuple[Recipe, DroneKeyNet, dict | None]:
        """(recipe, network, saved run state or None): the resumed run's, or a new network."""
        folder, recipe = self.folder, self.recipe
        if self.resume and folder.resumable():
            net, _meta = load_checkpoint(folder.last)
            state = load_run_state(folder.state)
            recipe = resumed_recipe(state["recipe"], recipe, self.overrides)
            log.info(
                "resuming %s at epoch %d (best AP %.2f)", folder.root, state["epoch"] + 1, state["best_ap"]
            )
            return recipe, net, state
        if self.resume:
            log.info("nothing to resume in %s; starting a new run", folder.root)
        net = DroneKeyNet(DroneKeyConfig.from_dict(recipe.model))
        if self.init_from and warm_start(net, self.init_from):
            recipe = replace(recipe, frozen_batchnorm=True)
        return recipe, net, None

    def _start(self) -> _Run:
        """Seed, build or resume the network, its optimiser, loss, data and validation crops."""
        self.folder.root.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(self.seed)
        if self.threads:
            torch.set_num_threads(self.threads)
        recipe, net, state = self._network()
        # The run's own crop policy (a resumed run keeps the framing it was started with, e.g. a
        # wider --crop-jitter-scale) over the given recipe's, fields CropPolicy no longer has dropped.
        known = {f.name for f in fields(CropPolicy)}
        crop = CropPolicy(**{**self.recipe.crop, **{k: v for k, v in recipe.crop.items() if k in known}})
        net = net.to(memory_format=torch.channels_last)  # faster convolutions in oneDNN
        use_bf16 = self.precision == "bf16" or (self.precision == "auto" and cpu_has_bf16())
        log.info("mixed precision: %s", "bfloat16 autocast (fp32 weights)" if use_bf16 else "off (fp32)")
        train_mode(net, recipe)
        params = [p for p in net.parameters() if p.requires_grad]
        heatmaps = None
        if recipe.heatmap_weight and net.config.backbone == "edge":
            heatmaps = PropellerHeatmaps(net.backbone, net.config.edge_widths, net.config.edge_depths)
            heatmaps = heatmaps.to(memory_format=torch.channels_last).train()
            if state is not None and "heatmaps" in state:
                heatmaps.load_state_dict(state["heatmaps"])
            params += list(heatmaps.parameters())
        if recipe.optimizer == "adam":
            optimizer = torch.optim.Adam(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
        else:
            optimizer = torch.optim.AdamW(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
        steps_per_epoch = max(1, recipe.samples_per_epoch // recipe.batch_size)
        total_steps = steps_per_epoch * recipe.epochs

        def lr_at(step: int) -> float:  # a plain function: LambdaLR then keeps nothing of it in state.pt
            return lr_factor(recipe, step, total_steps)

        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lr_at)
        if state is not None:
            optimizer.load_state_dict(state["optimizer"])
            scheduler.load_state_dict(state["scheduler"])
        keypoint_loss = build_loss(
            recipe.loss, recipe.schedule, recipe.alpha, recipe.D, total_epochs=100, eps=recipe.eps
        )
        train_source, val_source = crop_sources(crop, self.coco, self.backgrounds, recipe.side_view_boost)
        val = validation_set(
            self.folder.validation_cache(recipe.val_samples, crop.input_size, coco=bool(self.coco)),
            recipe.val_samples,
            VALIDATION_SEED,
            val_source,
        )
        start_epoch = state["epoch"] + 1 if state is not None else 0
        loader = batch_loader(self.seed + 7 * start_epoch, train_source, recipe.batch_size, self.workers)
        return _Run(
            recipe=recipe,
            net=net,
            heatmaps=heatmaps,
            params=params,
            optimizer=optimizer,
            scheduler=scheduler,
            keypoint_loss=keypoint_loss,
            batches=iter(loader),
            val=val,
            history=state["history"] if state is not None else [],
            best_ap=state["best_ap"] if state is not None else -1.0,
            start_epoch=start_epoch,
            steps_per_epoch=steps_per_epoch,
            total_steps=total_steps,
            use_bf16=use_bf16,
        )

    # ------------------------------------------------------------------------------------- run
    def fit(self) -> dict[str, Any]:
        """Train, validate and checkpoint epoch by epoch, then refit the presence head.

        Returns {"best_ap": AP^kp of ``best.pt`` in percent, "history": one entry per epoch}.
        """
        run = self._start()
        recipe, folder = run.recipe, self.folder
        log.info(
            "training %s (%.2f M parameters) for %d epochs x %d steps of %d crops; output in %s",
            self.recipe_name,
            count_parameters(run.net) / 1e6,
            recipe.epochs,
            run.steps_per_epoch,
            recipe.batch_size,
            folder.root,
        )
        stale = 0  # epochs since the best AP
        if run.history:
            best_epoch = max(run.history, key=lambda h: h["val"]["ap_kp"])["epoch"]
            stale = run.history[-1]["epoch"] - best_epoch
        t_start = time.time()
        for epoch in range(run.start_epoch, recipe.epochs):
            losses, train_s = self._train_epoch(run, epoch)
            improved = self._end_epoch(run, epoch, losses, train_s)
            stale = 0 if improved else stale + 1
            if stale >= recipe.patience:
                log.info("no AP improvement for %d epochs: stopping early", stale)
                break
        if recipe.presence_steps and folder.best.is_file():
            refit_ap = refit_presence(folder.best, run.batches, recipe.presence_steps, run.val)
            if refit_ap is not None:
                run.best_ap = refit_ap
        log.info(
            "done in %.1f min; best AP %.2f; checkpoints %s, %s",
            (time.time() - t_start) / 60,
            run.best_ap,
            folder.best,
            folder.last,
        )
        return {"best_ap": run.best_ap, "history": run.history}

    def _train_epoch(self, run: _Run, epoch: int) -> tuple[list[float], float]:
        """One epoch of optimiser steps; returns the steps' losses and the seconds it took."""
        recipe, net = run.recipe, run.net
        train_mode(net, recipe)
        losses, t0 = [], time.time()
        bar = tqdm(
            range(run.steps_per_epoch),
            desc=f"epoch {epoch + 1}/{recipe.epochs}",
            unit="step",
            leave=False,
            disable=not sys.stderr.isatty(),  # logs get one line per epoch instead
        )
        for i in bar:
            x, kp, present, _area = next(run.batches)
            step = epoch * run.steps_per_epoch + i
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=run.use_bf16):
                out = net(x.contiguous(memory_format=torch.channels_last))
                maps = run.heatmaps() if run.heatmaps is not None else None
            loss = batch_loss(
                recipe, run.keypoint_loss, out, kp, present, maps, x.shape[-1], step, run.total_steps
            )
            run.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(run.params, GRAD_CLIP_NORM)
            run.optimizer.step()
            run.scheduler.step()
            losses.append(float(loss.item()))
            scale = run.keypoint_loss.scale(schedule_time(step, run.total_steps))
            bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}", S=f"{scale:.3f}")
        return losses, time.time() - t0

    def _end_epoch(self, run: _Run, epoch: int, losses: list[float], train_s: float) -> bool:
        """Validate, record, checkpoint and plot epoch ``epoch`` (0-based); True when AP improved."""
        recipe, folder = run.recipe, self.folder
        metrics = evaluate(run.net, run.val)
        entry = {
            "epoch": epoch + 1,
            "train_loss": float(np.mean(losses)),
            "scale": run.keypoint_loss.scale(
                schedule_time((epoch + 1) * run.steps_per_epoch, run.total_steps)
            ),
            "lr": float(run.scheduler.get_last_lr()[0]),
            "train_s": train_s,
            "samples_per_s": run.steps_per_epoch * recipe.batch_size / train_s,
            "val": metrics,
        }
        run.history.append(entry)
        improved = metrics["ap_kp"] > run.best_ap
        meta = {
            "trained_on": describe_data(self.coco, self.backgrounds),
            "drone_spec": DRONE_SPEC,
            "recipe": self.recipe_name,
            "epochs": epoch + 1,
            "figures": figures(metrics),
            "crop_policy": recipe.crop,
            "train_seconds": float(sum(h["train_s"] for h in run.history)),
        }
        save_checkpoint(folder.last, run.net, meta)
        if improved:
            run.best_ap = metrics["ap_kp"]
            save_checkpoint(folder.best, run.net, meta)
        save_run_state(
            folder.state,
            recipe,
            epoch,
            run.history,
            run.best_ap,
            run.optimizer,
            run.scheduler,
            run.heatmaps,
        )
        folder.write_history(run.history)
        write_plots(run.history, folder.root)
        log.info(
            "epoch %d: loss %.4f S %.3f | AP %.2f SR90 %.2f SR95 %.2f AUC %.2f | median %.2f px"
            " (either order %.2f px) p90 %.2f px"
            " swap %.2f%% heading wrong %.2f%% (confident %.2f%%) | %.0f crops/s%s",
            epoch + 1,
            entry["train_loss"],
            entry["scale"],
            metrics["ap_kp"],
            metrics["sr90"],
            metrics["sr95"],
            metrics["presence_auc"],
            metrics["median_err_px"],
            metrics["median_err_either_order_px"],
            metrics["p90_err_px"],
            metrics["swap_rate"],
            metrics.get("heading_wrong", float("nan")),
            metrics.get("heading_confident_wrong", float("nan")),
            entry["samples_per_s"],
            " (best)" if improved else "",
        )
        return improved
