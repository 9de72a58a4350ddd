"""``dronekey-train-heading``: render the front/back classifier's data, train it, export it.

Three steps, each resumable: shards of labelled patches per training seed (one process per seed,
``dronekey.training.heading_data``), the same for the validation seed, then training and export
(``dronekey.training.heading_train``). Shards already in ``--out/data`` are kept, so a stopped run
starts again where it stopped and ``--shards`` can be raised later. Bad arguments are one-line
errors (exit status 2); Ctrl-C stops with status 130.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

import torch

from dronekey.training.heading_data import SHARD_SIZE, load_shards, write_shards
from dronekey.training.heading_train import HeadingRecipe, export_heading_model, train_heading

__all__ = ["build_parser", "main"]

LOG = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-train-heading`` argument parser."""
    p = argparse.ArgumentParser(
        prog="dronekey-train-heading",
        description="Train the front/back classifier on the keypoint network's own keypoints over "
        "rendered drones (docs/model.md, 'Front/back classifier'), and export it to ONNX.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="runs/heading", help="folder for data shards, checkpoint, history, model")
    p.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        default=[31001, 31002],
        help="training sampler seeds, one process each",
    )
    p.add_argument(
        "--shards", type=int, default=118, help=f"shards of {SHARD_SIZE} rendered crops per training seed"
    )
    p.add_argument("--val-seed", type=int, default=31099, help="validation sampler seed (never trained on)")
    p.add_argument("--val-shards", type=int, default=6, help="validation shards")
    p.add_argument("--keypoint-model", default=None, help="keypoint network whose keypoints it learns on")
    p.add_argument(
        "--epochs", type=float, default=HeadingRecipe.epochs, help="passes over the training patches"
    )
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument("--export", default=None, help="ONNX file to write (default: OUT/heading.onnx)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    for name in ("shards", "val_shards"):
        if getattr(args, name) < 1:
            print(
                f"dronekey-train-heading: --{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}",
                file=sys.stderr,
            )
            return 2
    if args.val_seed in args.seeds:
        print(f"dronekey-train-heading: --val-seed {args.val_seed} is also a training seed", file=sys.stderr)
        return 2
    if args.epochs <= 0:
        print(f"dronekey-train-heading: --epochs must be > 0, got {args.epochs}", file=sys.stderr)
        return 2
    out = Path(args.out)
    data = out / "data"
    try:
        jobs = [(s, args.shards) for s in args.seeds] + [(args.val_seed, args.val_shards)]
        with ProcessPoolExecutor(max_workers=len(args.seeds)) as pool:
            futures = [
                pool.submit(write_shards, data, seed, n, args.keypoint_model, i == 0)
                for i, (seed, n) in enumerate(jobs)
            ]
            paths = [f.result() for f in futures]
        if args.threads:
            torch.set_num_threads(args.threads)
        train, val = load_shards([p for seed_paths in paths[:-1] for p in seed_paths]), load_shards(paths[-1])
        LOG.info(
            "training on %d patches (%.1f %% in order), validating on %d",
            len(train[1]),
            100 * train[1].mean(),
            len(val[1]),
        )
        recipe = HeadingRecipe(epochs=args.epochs)
        model, history = train_heading(train, val, out, recipe, progress=True)
    except KeyboardInterrupt:
        print("dronekey-train-heading: stopped; run the same command again to resume", file=sys.stderr)
        return 130
    except (FileNotFoundError, ValueError) as exc:
        print(f"dronekey-train-heading: {exc}", file=sys.stderr)
        return 2
    final = history[-1]
    trained_on = {
        "sampler_seeds": list(args.seeds),
        "shards_per_seed": args.shards,
        "shard_size": SHARD_SIZE,
        "patches": int(len(train[1])),
        "val_seed": args.val_seed,
        "keypoint_model": args.keypoint_model or "shipped",
        "recipe": asdict(recipe),
    }
    path = export_heading_model(
        model, args.export or out / "heading.onnx", {"trained_on": trained_on, "figures": final}
    )
    print(json.dumps({"model": str(path), "validation": final}, indent=1))
    return 0
