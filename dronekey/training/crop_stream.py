"""Where a training run's crops come from, and the endless batch stream that feeds the trainer.

By default every step draws fresh rendered crops (``dronekey.sim_replay.sampler``; ``backgrounds``
mixes photos in). With a COCO keypoint dataset instead (the real 2DroneKey, or sequences of ours
written with ``dronekey-sim --images``), ``dronekey.training.coco_crops`` cuts the same jittered
crops around the annotated boxes, plus drone-free crops and left/right mirrors; a folder's JSONs
named *train* / *val* are the splits.

A batch is (x (B, 3, S, S) float32 normalised RGB, keypoints (B, K, 2) in normalised crop units,
present (B,) bool, area (B,) float32).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from dronekey.geometry.crop import CropPolicy
from dronekey.perception.keypoint_model import IMAGENET_MEAN, IMAGENET_STD, preprocess_crops
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig
from dronekey.training.coco_crops import CocoCropSampler, CocoImage, find_coco_splits, load_coco_images

__all__ = ["CropSource", "CropStream", "batch_loader", "crop_sources", "describe_data"]

log = logging.getLogger(__name__)


class CropSource:
    """Where the crops come from: the renderer (default) or a COCO keypoint dataset.

    Picklable and cheap: each DataLoader worker builds its own sampler from it.
    """

    def __init__(
        self,
        crop: CropPolicy,
        backgrounds: str | None = None,
        coco_images: list[CocoImage] | None = None,
        side_view_boost: float = 0.0,
    ) -> None:
        self.crop, self.backgrounds, self.coco_images = crop, backgrounds, coco_images
        self.side_view_boost = side_view_boost

    def sampler(self, seed: int):
        """A sampler with ``sample() -> CropSample``, reproducible for ``seed``."""
        if self.coco_images is not None:
            return CocoCropSampler(self.coco_images, self.crop, seed=seed)
        config = SamplerConfig(crop=self.crop, side_view_boost=self.side_view_boost)
        return CropSampler(config, seed=seed, backgrounds=self.backgrounds)


class CropStream(torch.utils.data.IterableDataset):
    """Infinite stream of crops for a torch DataLoader; each worker has its own seed."""

    def __init__(self, seed: int, source: CropSource) -> None:
        super().__init__()
        self.seed, self.source = seed, source

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray, bool, np.float32]]:
        info = torch.utils.data.get_worker_info()
        wid = info.id if info is not None else 0
        sampler = self.source.sampler(self.seed * 1009 + wid)
        S = self.source.crop.input_size
        while True:
            s = sampler.sample()
            x = preprocess_crops(s.image, S, IMAGENET_MEAN, IMAGENET_STD)[0]
            yield x, s.keypoints, bool(s.present), np.float32(s.area)


def batch_loader(seed: int, source: CropSource, batch: int, workers: int) -> torch.utils.data.DataLoader:
    """Batches of ``batch`` crops from ``source``, rendered by ``workers`` processes (0: in this one)."""
    return torch.utils.data.DataLoader(
        CropStream(seed, source),
        batch_size=batch,
        num_workers=workers,
        persistent_workers=workers > 0,
        prefetch_factor=4 if workers else None,
    )


def crop_sources(
    crop: CropPolicy,
    coco: str | Path | None = None,
    backgrounds: str | None = None,
    side_view_boost: float = 0.0,
) -> tuple[CropSource, CropSource]:
    """Training and validation crop sources: the renderer (its own validation seed), or ``coco``.
    ``side_view_boost`` (``SamplerConfig``) weights the renderer's training stream only, so that the
    validation figures stay comparable between runs.

    With ``coco`` and no validation JSON, every tenth image is held out for validation (adjacent
    video frames are alike, so such a split flatters the figures: prefer a real validation file).
    """
    if not coco:
        validation = CropSource(crop, backgrounds=backgrounds)
        return CropSource(crop, backgrounds=backgrounds, side_view_boost=side_view_boost), validation
    train_files, val_files = find_coco_splits(coco)
    train_images = load_coco_images(train_files)
    if val_files:
        val_images = load_coco_images(val_files)
    else:
        val_images = train_images[9::10]
        train_images = [im for i, im in enumerate(train_images) if i % 10 != 9]
        log.warning("--coco %s: no validation JSON; holding out every tenth image", coco)
    log.info(
        "COCO data: %d training images (%s), %d validation images (%s)",
        len(train_images),
        ", ".join(map(str, train_files)),
        len(val_images),
        ", ".join(map(str, val_files)) or "held out",
    )
    return CropSource(crop, coco_images=train_images), CropSource(crop, coco_images=val_images)


def describe_data(coco: str | Path | None = None, backgrounds: str | None = None) -> str:
    """What a run trained on, in words (the checkpoints' ``trained_on``)."""
    if coco is not None:
        return f"COCO keypoint dataset {coco}"
    return "dronekey.sim_replay rendered crops" + (f" + photos from {backgrounds}" if backgrounds else "")
