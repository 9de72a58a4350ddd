"""``dronekey-train-heading``: render the front/back classifier's data, train it, export it.

Three steps, each resumable: shards of labelled patches per training seed (one process per seed,
``dronekey.training.heading_data``), the same for the validation seed, then training and export
(``dronekey.training.heading_train``). Shards already in ``--out/data`` are kept and not labelled
again (a seed's sampler stream is still drawn from its start: ``patch_shards``), and ``--shards``
can be raised later; training goes on from its
last checkpoint in ``--out`` (every 1,000 steps) when the recipe and the number of steps are the
same (other data or ``--epochs``: a new run). Bad arguments are one-line errors (exit status 2);
Ctrl-C stops with status 130.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import asdict, replace
from pathlib import Path

from dronekey.training.heading_data import SHARD_SIZE, load_shards, write_shards
from dronekey.training.heading_train import HEADING_RECIPES, export_heading_model, train_heading
from dronekey.training.patch_cli import RESUME_NOTE, add_patch_arguments, patch_usage_error, render_shards

__all__ = ["build_parser", "main"]

LOG = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-train-heading`` argument parser."""
    p = argparse.ArgumentParser(
        prog="dronekey-train-heading",
        description="Train the front/back classifier on the keypoint network's own keypoints over "
        "rendered drones (docs/model.md, 'Front/back classifier'), and export it to ONNX." + RESUME_NOTE,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", default="runs/heading", help="folder for data shards, checkpoint, history, model")
    add_patch_arguments(
        p,
        seeds=[31001, 31002],
        shards=118,
        shards_help=f"shards of {SHARD_SIZE} rendered crops per training seed",
        val_seed=31099,
        val_shards=6,
        epochs=None,
        epochs_help="passes over the training patches (default: the --net recipe's: 8, or 4 for deep)",
    )
    p.add_argument(
        "--net",
        choices=sorted(HEADING_RECIPES),
        default="gated",
        help="the classifier's net: gated (four convs and a second, symmetric logit that says whether "
        "the body shows a front at all and pulls the answer to 0.5 when it does not: the shipped "
        "dronekey_heading.onnx), small (the same without the gate, shipped until the twenty-first "
        "session), deep (six convs, the shipped opt-in dronekey_heading_deep.onnx: --seeds 31001 "
        "31002 31003 31004 --epochs 4) or deep-gated (the six convs with the gate, over the default "
        "seeds)",
    )
    p.add_argument("--export", default=None, help="ONNX file to write (default: OUT/heading.onnx)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if message := patch_usage_error(args):
        print(f"dronekey-train-heading: {message}", file=sys.stderr)
        return 2
    out = Path(args.out)
    try:
        train_paths, val_paths = render_shards(write_shards, args, out / "data")
        train, val = load_shards(train_paths), load_shards(val_paths)
        LOG.info(
            "training on %d patches (%.1f %% in order), validating on %d",
            len(train[1]),
            100 * train[1].mean(),
            len(val[1]),
        )
        recipe = HEADING_RECIPES[args.net]
        recipe = replace(recipe, epochs=args.epochs or recipe.epochs)
        model, history = train_heading(train, val, out, recipe, progress=True, resume=True)
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


if __name__ == "__main__":
    sys.exit(main())
