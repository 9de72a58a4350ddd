"""Training recipes: the ``Recipe`` dataclass, the edge / paper / tiny presets and their overrides.

Presets (``dronekey-train --preset``):

- ``edge`` (default): the shipped model. The edge network (``DroneKeyConfig.edge()``) on 128 px
  crops streamed from ``sim_replay.sampler`` (fresh renders every step, no files), AdamW with a
  warm-up and cosine decay, the pose-adaptive Mahalanobis loss with the paper's exponential scale
  schedule (alpha 5, D 10) plus 4 x L1. Sized to finish on two CPU cores in about two hours.
  Why the L1 term: trained from scratch (no ImageNet weights here), the pose-adaptive loss alone
  leaves the network predicting the mean keypoints for hundreds of steps while S(t) is large (its
  tolerance then spans the whole crop); an over-fitting probe on 128 crops gave a median error of
  29 px after 150 steps with the loss alone at S = 10, 8.7 px with L1 alone and 8.2 px with
  L1 x 4 + the loss. As S(t) shrinks, the Mahalanobis term's gradient grows (1 / sqrt(S)) and
  dominates the refinement, which is where the paper places its benefit. An order-free L1
  (``dronekey.training.objective.symmetric_l1``) helps the network find the propellers before it
  can order them, and fades out over the first quarter of the run.
- ``paper``: the paper's settings: ResNet-50, d 1024, N 6, 8 heads, feed-forward 2048, 224 px,
  Adam, learning rate 1e-5, batch 8, 100 epochs, alpha 5, D 10 (a GPU job).
- ``tiny``: a minute-long smoke run for tests.

Schedule time. The paper's S(t) = D exp(-0.01 alpha t) runs over t = 0..100 epochs. A recipe with
another number of epochs follows the same curve over its whole run: the loss is evaluated at
``t = 100 * progress`` (progress = step / total steps, ``schedule_time``), so S goes from 10 to
0.067 in every recipe.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from dronekey.geometry.crop import CropPolicy
from dronekey.nn.model import DroneKeyConfig

__all__ = [
    "PRESET_NAMES",
    "Recipe",
    "lr_factor",
    "presets",
    "resumed_recipe",
    "schedule_time",
    "with_overrides",
]

PRESET_NAMES = ("edge", "paper", "tiny")


@dataclass(frozen=True)
class Recipe:
    """Everything that defines a training run besides the data source.

    Stored as a plain dict in the run's ``state.pt`` (``dataclasses.asdict``), so that ``--resume``
    continues with the recipe the run started with.
    """

    model: dict
    epochs: int
    samples_per_epoch: int
    batch_size: int
    lr: float
    optimizer: str = "adamw"
    weight_decay: float = 1e-4
    warmup_steps: int = 300
    cosine: bool = True
    loss: str = "pose"
    schedule: str = "exp"
    alpha: float = 5.0
    D: float = 10.0
    eps: float = 1e-4
    l1_weight: float = 0.0  # + l1_weight x mean |pred - gt| (normalised crop units), see the edge recipe
    symmetric_weight: float = 0.0  # + w x (1 - progress / symmetric_until) x order-free L1, see below
    symmetric_until: float = 0.25
    presence_weight: float = 0.25
    heading_weight: float = (
        1.0  # nose_loss of the front/back head (networks with DroneKeyConfig.heading_head)
    )
    # + w x (L1 to the labelled order - L1 to the aligned one): the pull towards the labelled front,
    # kept below the aligned L1's own weight so that a crop whose front cannot be told is still
    # cheaper at one of the two orders than at their mean (see objective.align_to_twin)
    order_weight: float = 0.0
    # + w x the training-only propeller heatmap loss on the backbone's stride-8/16 maps
    # (dronekey.nn.heatmap_aux: teaches the CNN where the propellers and the front are)
    heatmap_weight: float = 0.0
    # BatchNorm layers kept in eval mode (fixed affine): set when a run starts from an exported
    # model, whose BatchNorm the exporter folded into the convolutions (dronekey.training.onnx_weights)
    frozen_batchnorm: bool = False
    # head-only presence steps on the best network after the epochs (dronekey.training.presence_refit)
    presence_steps: int = 0
    val_samples: int = 1500
    patience: int = 12
    # the training stream's SamplerConfig.side_view_boost (validation keeps the plain mix)
    side_view_boost: float = 0.0
    crop: dict = field(default_factory=lambda: asdict(CropPolicy()))


def presets() -> dict[str, Recipe]:
    """The presets by name (``PRESET_NAMES``), freshly built (a Recipe's dicts are its own)."""
    edge = DroneKeyConfig.edge()
    paper = DroneKeyConfig.paper()
    tiny = replace(edge, d_model=32, num_layers=2, num_heads=2, ff_dim=64, edge_widths=(8, 16, 16, 24, 32))
    return {
        "edge": Recipe(
            model=edge.to_dict(),
            epochs=30,
            samples_per_epoch=16384,
            batch_size=64,
            lr=2e-3,
            warmup_steps=100,
            l1_weight=4.0,
            symmetric_weight=4.0,
            order_weight=2.0,
            heatmap_weight=1.0,
            presence_steps=300,
        ),
        "paper": Recipe(
            model=paper.to_dict(),
            epochs=100,
            samples_per_epoch=7000,
            batch_size=8,
            lr=1e-5,
            optimizer="adam",
            weight_decay=0.0,
            warmup_steps=0,
            cosine=False,
            crop=asdict(CropPolicy(input_size=paper.input_size)),
        ),
        "tiny": Recipe(
            model=tiny.to_dict(),
            epochs=2,
            samples_per_epoch=64,
            batch_size=16,
            lr=2e-3,
            val_samples=64,
            warmup_steps=2,
            heatmap_weight=1.0,  # so the tests exercise the auxiliary heads and their resume
        ),
    }


def with_overrides(recipe: Recipe, overrides: Mapping[str, Any] | None) -> Recipe:
    """``recipe`` with the fields of ``overrides`` that are not None replaced."""
    return replace(recipe, **{k: v for k, v in (overrides or {}).items() if v is not None})


def resumed_recipe(saved: Mapping[str, Any], preset: Recipe, overrides: Mapping[str, Any] | None) -> Recipe:
    """The recipe of a resumed run: its ``saved`` fields (``state.pt``), fields a newer version added
    taken from ``preset``, and ``overrides`` on top (more ``--epochs`` extends a run)."""
    return with_overrides(Recipe(**{**asdict(preset), **saved}), overrides)


def schedule_time(step: int, total_steps: int) -> float:
    """The paper's epoch t in [0, 100] at which the loss schedule S(t) is read (module docstring)."""
    return 100.0 * step / total_steps


def lr_factor(recipe: Recipe, step: int, total_steps: int) -> float:
    """Learning-rate multiplier at ``step``: linear warm-up over ``recipe.warmup_steps``, then cosine
    decay to 1 % at ``total_steps`` (``recipe.cosine``) or constant."""
    if step < recipe.warmup_steps:
        return (step + 1) / recipe.warmup_steps
    if not recipe.cosine:
        return 1.0
    p = (step - recipe.warmup_steps) / max(1, total_steps - recipe.warmup_steps)
    return 0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(p, 1.0)))
