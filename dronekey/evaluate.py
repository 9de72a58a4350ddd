"""``dronekey-eval``: measure the keypoint model and the 6DoF pipeline.

    dronekey-eval keypoints --preset 2dronekey --frames N --seed S [--model FILE] [--json]
    dronekey-eval pose --sequence DIR/seq13.json [--video FILE] [--model FILE] [--plot FILE.png] [--json]
    dronekey-eval pose --all DIR [--json]            # seq11-13 in DIR, the paper's Tab. VI
    dronekey-eval pose ... --oracle-noise PX         # ground-truth keypoints + noise: PnP and filter only

Figures are percentages (keypoints) and degrees / metres (pose), as in the paper.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

log = logging.getLogger("dronekey.eval")

EXIT_BAD_INPUT = 2


class _UsageError(Exception):
    """Bad input the user can fix; printed as one line."""


def _cmd_keypoints(args: argparse.Namespace) -> int:
    from dronekey.eval_keypoints import evaluate_keypoints
    from dronekey.sim_replay.presets import PRESETS

    if args.preset not in PRESETS:
        raise _UsageError(f"unknown preset {args.preset!r}; available: {', '.join(PRESETS)}")
    if args.frames <= 0:
        raise _UsageError(f"--frames must be positive, got {args.frames}")
    result = evaluate_keypoints(
        args.preset,
        args.frames,
        args.seed,
        args.model,
        progress=sys.stderr.isatty(),
        mirror_average=not args.no_mirror_average,
    )
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{result['frames']} frames of {args.preset} (seed {args.seed}): AP^kp {result['ap_kp']:.2f}  "
            f"SR90 {result['sr90']:.2f}  SR95 {result['sr95']:.2f}  presence AUC {result['presence_auc']}  "
            f"median error {result['median_err_px']:.2f} px  front/back swaps {result['swap_rate']:.2f}%"
        )
    return 0


def _load(json_path: Path, video: str | None):
    from dronekey.sim_replay.frames import iter_frames
    from dronekey.sim_replay.sequence_io import load_sequence

    if not json_path.is_file():
        raise _UsageError(f"sequence file not found: {json_path}")
    seq = load_sequence(json_path)
    return seq, iter_frames(seq, video)


def _cmd_pose(args: argparse.Namespace) -> int:
    from dronekey.eval_pose import evaluate_sequence, plot_sequence, table_vi, weighted_average

    if (args.sequence is None) == (args.all is None):
        raise _UsageError("give exactly one of --sequence FILE.json or --all DIR")
    if args.oracle_noise is not None and args.oracle_noise < 0:
        raise _UsageError(f"--oracle-noise must be >= 0 px, got {args.oracle_noise}")
    if args.plot:
        if args.sequence is None:
            raise _UsageError("--plot draws one sequence: use it with --sequence")
        try:
            import matplotlib  # noqa: F401  (checked before a long run, not after it)
        except ImportError:
            raise _UsageError("--plot needs matplotlib: pip install 'dronekey[plot]'") from None
    if args.sequence is not None:
        paths = [Path(args.sequence)]
    else:
        folder = Path(args.all)
        if not folder.is_dir():
            raise _UsageError(f"--all folder not found: {folder}")
        paths = [folder / f"seq{n}.json" for n in (11, 12, 13)]
        missing = [p.name for p in paths if not p.is_file()]
        if missing:
            raise _UsageError(
                f"{folder} lacks {', '.join(missing)}; render them with: "
                f"for s in seq11 seq12 seq13; do dronekey-sim --preset $s --seed 101 --out {folder}; done"
            )
    results = []
    for path in paths:
        seq, frames = _load(path, args.video if args.sequence else None)
        res = evaluate_sequence(
            seq,
            frames,
            args.model,
            args.oracle_noise,
            progress=sys.stderr.isatty(),
            mirror_average=not args.no_mirror_average,
        )
        results.append(res)
        if args.plot:
            plot_sequence(res, args.plot)
    if args.sequence:
        out = results[0].to_dict()
        if args.oracle_noise is not None:
            out["oracle_noise_px"] = args.oracle_noise
        if args.json:
            print(json.dumps(out))
        else:
            print(table_vi(results))
            print(f"AP^kp {out['ap_kp']}  SR90 {out['sr90']}  SR95 {out['sr95']}  {out['fps']} fps")
        return 0
    if args.json:
        avg = {}
        for key, attr in (
            ("mae_angle_deg", "mae_angle_deg"),
            ("rmse_m", "rmse_m"),
            ("mae_abs_m", "mae_abs_m"),
        ):
            for kind in ("filtered", "raw"):
                errs = [getattr(getattr(r, kind), attr) for r in results]
                weights = [getattr(r, kind).frames for r in results]
                avg.setdefault(kind, {})[key] = round(weighted_average(errs, weights, rms=key == "rmse_m"), 4)
        print(json.dumps({"sequences": [r.to_dict() for r in results], "average": avg}))
    else:
        print(table_vi(results))
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dronekey-eval",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__.split("\n\n", 1)[1],
    )
    p.add_argument("--log-level", default="WARNING", help="logging level (DEBUG, INFO, WARNING)")
    sub = p.add_subparsers(dest="command", required=True)
    k = sub.add_parser(
        "keypoints",
        help="AP^kp, SR90, SR95 and presence AUC on freshly rendered frames",
        description="Render FRAMES fresh frames, crop around each drone as the localiser does (the "
        "model's jitter and scale policy), run the ONNX model and score its keypoints in full-frame "
        "pixels: AP^kp, SR90, SR95 (percent) and the presence AUC (drone-free crops included).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    k.add_argument("--preset", default="2dronekey", help="sim_replay preset to render")
    k.add_argument("--frames", type=int, default=200, help="frames to render")
    k.add_argument("--seed", type=int, default=1234, help="render seed (use one never used in training)")
    k.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    k.add_argument(
        "--no-mirror-average",
        action="store_true",
        help="run each crop once (the daemon also runs its mirror and averages, model.mirror_average)",
    )
    k.add_argument("--json", action="store_true", help="print one JSON object")
    k.set_defaults(func=_cmd_keypoints)
    q = sub.add_parser(
        "pose",
        help="6DoF errors of the pipeline on sequences (paper Tab. VI)",
        description="Run the daemon's pipeline over rendered sequences and compare its 6DoF tracks "
        "with the ground truth: MAE-angle, RMSE, MAE-absolute, filtered and raw PnP. --sequence for "
        "one file (with --plot), --all for the paper's Tab. VI over seq11-13.",
    )
    q.add_argument("--sequence", help="sequence JSON (DESIGN.md §5.1)")
    q.add_argument("--all", help="folder holding seq11.json, seq12.json, seq13.json and their videos")
    q.add_argument("--video", help="video or image folder (default: from the JSON's file names)")
    q.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    q.add_argument("--plot", help="write a PNG of ground truth against the estimate (with --sequence)")
    q.add_argument(
        "--oracle-noise", type=float, help="use ground-truth keypoints plus this Gaussian noise (px)"
    )
    q.add_argument(
        "--no-mirror-average", action="store_true", help="run each crop once (the daemon's default averages)"
    )
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=_cmd_pose)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except _UsageError as exc:
        print(f"dronekey-eval: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    except (ValueError, OSError, RuntimeError) as exc:  # bad files: sequence, video, model
        print(f"dronekey-eval: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
