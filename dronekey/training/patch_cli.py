"""What ``dronekey-train-heading`` and ``dronekey-train-verifier`` share on their command lines: the
data arguments (sampler seeds, shards, validation seed, keypoint network, epochs, threads) and
their one-line checks."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import torch

from dronekey.training.patch_shards import write_seeds_in_parallel

__all__ = ["RESUME_NOTE", "add_patch_arguments", "patch_usage_error", "render_shards"]

# The end of both commands' --help description
RESUME_NOTE = (
    " A stopped run resumes: run the same command again (shards in OUT/data are kept, and training "
    "goes on from OUT/state.pt, written every 1,000 steps, when the data and --epochs are the same)."
    " A seed stopped part-way draws its sampler stream again from the start, so its kept shards cost "
    "their rendering once more (not their labelling); --shards N, N the shards each seed has, trains "
    "on what is there instead."
)


def add_patch_arguments(
    p: argparse.ArgumentParser,
    seeds: list[int],
    shards: int,
    shards_help: str,
    val_seed: int,
    val_shards: int,
    epochs: float | None,
    epochs_help: str,
) -> None:
    """Add ``--seeds --shards --val-seed --val-shards --keypoint-model --epochs --threads``."""
    p.add_argument(
        "--seeds", type=int, nargs="+", default=seeds, help="training sampler seeds, one process each"
    )
    p.add_argument("--shards", type=int, default=shards, help=shards_help)
    p.add_argument(
        "--val-seed", type=int, default=val_seed, help="validation sampler seed (never trained on)"
    )
    p.add_argument("--val-shards", type=int, default=val_shards, help="validation shards")
    p.add_argument("--keypoint-model", default=None, help="keypoint network whose outputs it learns on")
    p.add_argument("--epochs", type=float, default=epochs, help=epochs_help)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")


def patch_usage_error(args: argparse.Namespace) -> str | None:
    """The first thing wrong with those arguments, in one line; None when they are fine."""
    for name in ("shards", "val_shards"):
        if getattr(args, name) < 1:
            return f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}"
    if args.val_seed in args.seeds:
        return f"--val-seed {args.val_seed} is also a training seed"
    if args.epochs is not None and args.epochs <= 0:
        return f"--epochs must be > 0, got {args.epochs}"
    if args.threads < 0:
        return f"--threads must be >= 0, got {args.threads}"
    return None


def render_shards(
    write: Callable[..., list[Path]], args: argparse.Namespace, data: Path
) -> tuple[list[Path], list[Path]]:
    """Render (or find) the training seeds' and the validation seed's shards in ``data``, one
    process per training seed, then set torch's threads for training; returns (training shard
    paths, validation shard paths)."""
    jobs = [(s, args.shards) for s in args.seeds] + [(args.val_seed, args.val_shards)]
    paths = write_seeds_in_parallel(write, data, jobs, args.keypoint_model, len(args.seeds))
    if args.threads:
        torch.set_num_threads(args.threads)
    return [p for seed_paths in paths[:-1] for p in seed_paths], paths[-1]
