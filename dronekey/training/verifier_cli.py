"""``dronekey-train-verifier``: render the drone verifier's data, train it, export it.

Three steps, each resumable: shards of the keypoint network's detections on mostly drone-free
rendered crops per training seed (one process per seed, ``dronekey.training.verifier_data``), the
same for the validation seed, then training and export (``dronekey.training.verifier_train``).
Shards already in ``--out/data`` are kept and not labelled again (a seed's sampler stream is still
drawn from its start: ``patch_shards``), and ``--shards`` can be raised later; training goes on
from its last checkpoint in ``--out`` (every
1,000 steps) when the recipe and the number of steps are the same (other data or ``--epochs``: a
new run). Bad arguments are one-line errors (exit status 2); Ctrl-C stops with status 130.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from dataclasses import asdict, replace
from pathlib import Path

from dronekey.training.patch_cli import RESUME_NOTE, add_patch_arguments, patch_usage_error, render_shards
from dronekey.training.patch_shards import SHARD_SIZE
from dronekey.training.verifier_data import NEGATIVE_FRACTION, load_verifier_shards, write_verifier_shards
from dronekey.training.verifier_train import VERIFIER_RECIPE, export_verifier, train_verifier

__all__ = ["build_parser", "main"]

LOG = logging.getLogger(__name__)


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-train-verifier`` argument parser."""
    p = argparse.ArgumentParser(
        prog="dronekey-train-verifier",
        description="Train the drone verifier (docs/model.md, 'Drone verifier') on the keypoint "
        "network's own detections of rendered drones and drone-free clutter, and export it to ONNX."
        + RESUME_NOTE,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument(
        "--out", default="runs/verifier", help="folder for data shards, checkpoint, history, model"
    )
    add_patch_arguments(
        p,
        seeds=[41001, 41002],
        shards=24,
        shards_help=f"shards of {SHARD_SIZE} rendered crops ({100 * NEGATIVE_FRACTION:.0f} %% drone-free) "
        "per training seed",
        val_seed=41099,
        val_shards=3,
        epochs=VERIFIER_RECIPE.epochs,
        epochs_help="passes over the drone-free patches (each batch is half drones, half drone-free)",
    )
    p.add_argument("--export", default=None, help="ONNX file to write (default: OUT/verifier.onnx)")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if message := patch_usage_error(args):
        print(f"dronekey-train-verifier: {message}", file=sys.stderr)
        return 2
    out = Path(args.out)
    recipe = replace(VERIFIER_RECIPE, epochs=args.epochs)
    try:
        train_paths, val_paths = render_shards(write_verifier_shards, args, out / "data")
        train, val = load_verifier_shards(train_paths), load_verifier_shards(val_paths)
        LOG.info(
            "training on %d patches (%d drone-free), validating on %d (%d drone-free)",
            len(train[1]),
            int((train[1] < 0.5).sum()),
            len(val[1]),
            int((val[1] < 0.5).sum()),
        )
        model, history = train_verifier(train, val, out, recipe, progress=True, resume=True)
    except KeyboardInterrupt:
        print("dronekey-train-verifier: stopped; run the same command again to resume", file=sys.stderr)
        return 130
    except (FileNotFoundError, ValueError) as exc:
        print(f"dronekey-train-verifier: {exc}", file=sys.stderr)
        return 2
    final = history[-1]
    trained_on = {
        "sampler_seeds": list(args.seeds),
        "shards_per_seed": args.shards,
        "shard_size": SHARD_SIZE,
        "negative_fraction": NEGATIVE_FRACTION,
        "patches": int(len(train[1])),
        "drone_free_patches": int((train[1] < 0.5).sum()),
        "val_seed": args.val_seed,
        "keypoint_model": args.keypoint_model or "shipped",
        "recipe": asdict(recipe),
    }
    path = export_verifier(
        model, args.export or out / "verifier.onnx", {"trained_on": trained_on, "figures": final}
    )
    print(json.dumps({"model": str(path), "validation": final}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
