"""Resumable shards of front-up patches for the patch classifiers (front/back, drone verifier).

A shard is ``shard_size`` crops drawn from one training-sampler stream (``CropSampler``, a given
seed and share of drone-free crops), run through the keypoint network as the daemon runs it
(mirror-averaged, in its head's order), then labelled by the classifier's own ``label`` function
and written as ``{prefix}{seed}_{index:03d}.npz``. Shards already there are kept, so a stopped run
resumes and a folder can be extended with another seed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dronekey.perception.keypoint_model import KeypointModel, RawOutputs, in_heading_order, mirror_averaged
from dronekey.sim_replay.sampler import CropSample, CropSampler, SamplerConfig

__all__ = ["SHARD_SIZE", "network_outputs", "write_patch_shards", "write_seeds_in_parallel"]

LOG = logging.getLogger(__name__)

SHARD_SIZE = 1000

Label = Callable[[KeypointModel, list[CropSample]], dict[str, np.ndarray]]


def write_patch_shards(
    out: str | Path,
    seed: int,
    shards: int,
    label: Label,
    sampler_config: SamplerConfig | None = None,
    keypoint_model: str | Path | None = None,
    progress: bool = False,
    shard_size: int = SHARD_SIZE,
    prefix: str = "s",
) -> list[Path]:
    """Render ``shards`` shards of ``shard_size`` crops with sampler seed ``seed`` into ``out``.

    One sampler stream per seed, shard after shard. Shards already there are kept: when all are,
    nothing is rendered; otherwise the stream is drawn again from its start (so that every shard
    holds the same crops whichever run wrote it) and only the missing shards are written.
    ``label(model, samples)`` turns a shard's crops into the arrays to save; ``sampler_config`` is
    the sampler's (its share of drone-free crops, of cue-free bodies...; None: the defaults).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{prefix}{seed}_{index:03d}.npz" for index in range(shards)]
    if all(path.is_file() for path in paths):
        return paths
    sampler = CropSampler(sampler_config or SamplerConfig(), seed=seed)
    model = KeypointModel(keypoint_model, threads=1, mirror_average=True)
    for path in tqdm(paths, desc=f"shards of seed {seed}", disable=not progress):
        samples = [sampler.sample() for _ in range(shard_size)]
        if path.is_file():
            continue
        partial = path.with_name(path.name + ".partial")  # a stopped run leaves no half shard
        with partial.open("wb") as f:
            np.savez(f, **label(model, samples))
        partial.replace(path)
    return paths


def network_outputs(model: KeypointModel, crops: np.ndarray) -> RawOutputs:
    """The keypoint network's answers on uint8 crops (B, S, S, 3), mirror-averaged and in its
    head's order, as the daemon gets them; in batches of 64 (a batch of 2,000 crops takes
    gigabytes)."""
    parts = []
    for i in range(0, len(crops), 64):
        tensor = model.preprocess(crops[i : i + 64])
        raw = model.inference(np.concatenate([tensor, tensor[..., ::-1]]))
        parts.append(in_heading_order(mirror_averaged(raw, len(tensor))))
    heads = [p.heading for p in parts]
    return RawOutputs(
        np.concatenate([p.keypoints for p in parts]),
        np.concatenate([p.presence for p in parts]),
        np.concatenate([p.gate for p in parts]),
        None if any(h is None for h in heads) else np.concatenate(heads),
    )


def write_seeds_in_parallel(
    write: Callable[..., list[Path]],
    out: str | Path,
    jobs: list[tuple[int, int]],
    keypoint_model: str | Path | None,
    processes: int,
) -> list[list[Path]]:
    """``write(out, seed, shards, keypoint_model, progress)`` for each (seed, shards) of ``jobs``,
    ``processes`` at a time, the first with a progress bar; the shard paths per job, in order."""
    with ProcessPoolExecutor(max_workers=max(1, processes)) as pool:
        futures = [
            pool.submit(write, out, seed, n, keypoint_model, i == 0) for i, (seed, n) in enumerate(jobs)
        ]
        return [f.result() for f in futures]
