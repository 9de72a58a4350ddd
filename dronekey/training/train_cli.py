"""``dronekey-train``: train the DroneKey network on rendered crops or on a COCO keypoint folder.

The command line of ``Trainer`` (``dronekey.training.trainer``): ``--preset`` picks a recipe
(``dronekey.training.recipe``, whose docstring describes edge, paper and tiny), the recipe-override
flags replace its fields, ``--resume`` continues the run in ``--out``, ``--init-from`` starts a new
one from another network's weights. Bad arguments and unreadable data are one-line errors (exit
status 2); Ctrl-C stops with status 130, and ``--resume`` continues from the last finished epoch.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from dronekey.training.coco_crops import CocoDataError
from dronekey.training.recipe import PRESET_NAMES, presets
from dronekey.training.trainer import PRECISIONS, Trainer
from dronekey.training.warm_start import WarmStartError

__all__ = ["build_parser", "main"]

# Recipe-override flags (argparse dest) -> the Recipe field each replaces.
OVERRIDES = {
    "epochs": "epochs",
    "samples_per_epoch": "samples_per_epoch",
    "batch": "batch_size",
    "lr": "lr",
    "loss": "loss",
    "schedule": "schedule",
    "alpha": "alpha",
    "D": "D",
    "val_samples": "val_samples",
    "patience": "patience",
    "presence_steps": "presence_steps",
    "heading_weight": "heading_weight",
    "side_view_boost": "side_view_boost",
}


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-train`` argument parser."""
    p = argparse.ArgumentParser(
        prog="dronekey-train",
        description="Train the DroneKey keypoint network (see the module docstring for the recipes).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--preset", choices=list(PRESET_NAMES), default="edge", help="training recipe")
    p.add_argument("--out", default="runs/edge", help="folder for checkpoints, history and plots")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last epoch")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the training stream (validation uses its own)"
    )
    p.add_argument("--backgrounds", default=None, help="folder of background photos mixed into the renders")
    p.add_argument(
        "--coco",
        default=None,
        metavar="PATH",
        help="train on a COCO keypoint dataset instead of renders: a JSON file, or a folder (the "
        "2DroneKey layout) whose JSONs named *train* / *val* are the splits; images beside the JSON "
        "or in an images/ folder next to it",
    )
    p.add_argument("--workers", type=int, default=1, help="rendering processes feeding the trainer")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument(
        "--precision",
        choices=list(PRECISIONS),
        default="auto",
        help="bf16: bfloat16 autocast with fp32 weights (about 2x faster on CPUs with AVX512-BF16); "
        "auto: bf16 where the CPU has native support",
    )
    g = p.add_argument_group("recipe overrides (default: the preset's)")
    g.add_argument("--epochs", type=int)
    g.add_argument("--samples-per-epoch", type=int)
    g.add_argument("--batch", type=int)
    g.add_argument("--lr", type=float)
    g.add_argument("--loss", choices=["pose", "gaussian", "mse"])
    g.add_argument("--schedule", choices=["exp", "linear", "fixed"])
    g.add_argument("--alpha", type=float)
    g.add_argument("--D", type=float)
    g.add_argument("--val-samples", type=int)
    g.add_argument("--patience", type=int)
    g.add_argument("--presence-steps", type=int, help="head-only presence steps after the epochs (0: none)")
    g.add_argument("--heading-weight", type=float, help="weight of the front/back head's nose loss")
    g.add_argument(
        "--crop-jitter-scale",
        type=float,
        metavar="J",
        help="crop side drawn log-uniform in [1 - J, 1 + J] times the policy's framing (CropPolicy."
        "jitter_scale): wider teaches the network to read a drone's size inside a crop cut too small or "
        "too large instead of from the crop itself",
    )
    g.add_argument(
        "--side-view-boost",
        type=float,
        metavar="B",
        help="draw again this share of the rendered drones that are not seen side-on (left/right axis "
        "foreshortened until the front/back sides look longer), so the network learns the body's axes "
        "where the longer side is not left/right (training stream only; 0 keeps the plain mix)",
    )
    p.add_argument(
        "--init-from",
        default=None,
        metavar="CHECKPOINT",
        help="start a new run from the weights of this checkpoint (.pt) or exported model (.onnx, e.g. "
        "the shipped one; its BatchNorm then stays frozen), those whose names and shapes match; heads "
        "it lacks start fresh",
    )
    return p


def _check(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """One-line ``parser.error`` for values the parser's types let through."""
    for name in ("epochs", "samples_per_epoch", "batch", "val_samples", "patience"):
        v = getattr(args, name)
        if v is not None and v <= 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {v}")
    if args.presence_steps is not None and args.presence_steps < 0:
        parser.error(f"--presence-steps must be >= 0, got {args.presence_steps}")
    if args.side_view_boost is not None and not 0.0 <= args.side_view_boost < 1.0:
        parser.error(f"--side-view-boost must be in [0, 1), got {args.side_view_boost}")
    if args.crop_jitter_scale is not None and not 0.0 <= args.crop_jitter_scale < 1.0:
        parser.error(f"--crop-jitter-scale must be in [0, 1), got {args.crop_jitter_scale}")
    if args.workers < 0:
        parser.error(f"--workers must be >= 0, got {args.workers}")
    if args.backgrounds is not None and not Path(args.backgrounds).is_dir():
        parser.error(f"--backgrounds folder not found: {args.backgrounds}")
    if args.coco is not None and args.backgrounds is not None:
        parser.error("--backgrounds mixes photos into renders; it does not apply to --coco")
    if args.coco is not None and args.side_view_boost:
        parser.error("--side-view-boost weights the renderer's drawings; it does not apply to --coco")


def main(argv: list[str] | None = None) -> int:
    """``dronekey-train``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", stream=sys.stderr)
    _check(parser, args)
    recipe = presets()[args.preset]
    overrides = {field: getattr(args, dest) for dest, field in OVERRIDES.items()}
    if args.crop_jitter_scale is not None:
        overrides["crop"] = {**recipe.crop, "jitter_scale": args.crop_jitter_scale}
    trainer = Trainer(
        recipe,
        args.out,
        recipe_name=args.preset,
        overrides=overrides,
        resume=args.resume,
        init_from=args.init_from,
        coco=args.coco,
        backgrounds=args.backgrounds,
        seed=args.seed,
        workers=args.workers,
        threads=args.threads,
        precision=args.precision,
    )
    try:
        trainer.fit()
    except (CocoDataError, WarmStartError) as exc:
        print(f"dronekey-train: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("dronekey-train: interrupted; resume with --resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
