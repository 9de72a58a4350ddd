"""``dronekey-eval``: measure the keypoint model and the 6DoF pipeline.

    dronekey-eval keypoints --preset 2dronekey --frames N --seed S [--model FILE] [--json]
    dronekey-eval pose --sequence DIR/seq13.json [--video FILE] [--model FILE] [--plot FILE.png] [--json]
    dronekey-eval pose --all DIR [--json]            # seq11-13 in DIR, the paper's Tab. VI
    dronekey-eval pose ... --oracle-noise PX         # ground-truth keypoints + noise: PnP and filter only
    dronekey-eval mot --sequence DIR/swarm.json [--gate M] [--dither SEED] [--json]  # MOTA, IDF1, switches
    dronekey-eval fusion DIR [--gate M] [--json]     # dronekey-sim --cameras N: each camera vs fused
    dronekey-eval robustness --out DIR [--json] [--frames N] [--seeds N ...] [--tuning] [--quick]
                                                     # LEDs x backgrounds x motions, far drones, drone-free
    dronekey-eval compare --base A.json ... --candidate B.json ... [--moved DEG] [--json]
                                                     # robustness runs side by side, sequences moved

Figures are percentages (keypoints) and degrees / metres (pose), as in the paper.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from collections.abc import Iterator
from pathlib import Path

from dronekey.evaluation.config_overrides import (
    OverrideError,
    config_with_overrides,
    describe_pipeline_changes,
    parse_overrides,
    pipeline_changes,
)
from dronekey.evaluation.fusion import evaluate_fusion, fusion_table
from dronekey.evaluation.keypoints import evaluate_keypoints
from dronekey.evaluation.mot import DEFAULT_GATE_M, evaluate_mot, mot_table, pooled_table, pooled_to_dict
from dronekey.evaluation.pose import evaluate_sequence, rounded, table_vi, weighted_average
from dronekey.evaluation.pose_plot import plot_sequence
from dronekey.evaluation.robustness.compare import compare_reports, load_report
from dronekey.evaluation.robustness.dither import FrameDither, describe_dither
from dronekey.evaluation.robustness.matrix import (
    BACKGROUNDS,
    DEFAULT_FRAMES,
    DRONE_FREE_SEQUENCES,
    QUICK_BACKGROUNDS,
    QUICK_DRONE_FREE,
    QUICK_FRAMES,
)
from dronekey.evaluation.robustness.run import run_robustness
from dronekey.perception.heading_model import heading_model_path
from dronekey.perception.localizer import LocalizerConfig
from dronekey.sim_replay.annotations import SequenceAnnotations
from dronekey.sim_replay.io.frames import SequenceFrame, iter_frames
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.presets import PRESETS
from dronekey.tracking.tracker_config import TrackerConfig

log = logging.getLogger("dronekey.eval")

EXIT_BAD_INPUT = 2


class _UsageError(Exception):
    """Bad input the user can fix; printed as one line."""


def _cmd_keypoints(args: argparse.Namespace) -> int:
    if args.preset not in PRESETS:
        raise _UsageError(f"unknown preset {args.preset!r}; available: {', '.join(PRESETS)}")
    if args.frames <= 0:
        raise _UsageError(f"--frames must be positive, got {args.frames}")
    if PRESETS[args.preset].multi_drone:
        raise _UsageError(f"keypoints scores one drone per frame; preset {args.preset!r} flies several")
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


def _load(json_path: Path, video: str | None) -> tuple[SequenceAnnotations, Iterator[SequenceFrame]]:
    if not json_path.is_file():
        raise _UsageError(f"sequence file not found: {json_path}")
    seq = load_sequence(json_path)
    return seq, iter_frames(seq, video)


def _cmd_pose(args: argparse.Namespace) -> int:
    if (args.sequence is None) == (args.all is None):
        raise _UsageError("give exactly one of --sequence FILE.json or --all DIR")
    _check_oracle_noise(args)
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
    localizer, tracker = _pipeline_configs(args, {}, {})
    results = []
    for path in paths:
        seq, frames = _load(path, args.video if args.sequence else None)
        seq.require_single_drone("dronekey-eval pose")
        res = evaluate_sequence(
            seq,
            frames,
            args.model,
            args.oracle_noise,
            progress=sys.stderr.isatty(),
            mirror_average=not args.no_mirror_average,
            tracker=tracker,
            localizer=localizer,
        )
        results.append(res)
        if args.plot:
            plot_sequence(res, args.plot)
    changed = pipeline_changes(localizer, tracker)
    settings = describe_pipeline_changes(changed)
    if settings and not args.json:
        print("settings: " + "; ".join(settings) + "\n")
    if args.sequence:
        out = results[0].to_dict()
        if args.oracle_noise is not None:
            out["oracle_noise_px"] = args.oracle_noise
        if args.json:
            print(json.dumps({**out, "settings": changed}))
        else:
            print(table_vi(results))
            print(f"AP^kp {out['ap_kp']}  SR90 {out['sr90']}  SR95 {out['sr95']}  {out['fps']} fps")
        return 0
    if args.json:
        avg = {}
        for key in (
            "mae_angle_deg",
            "rmse_m",
            "mae_abs_m",
            "mae_angle_up_to_twin_deg",
            "confident_wrong_pct",
        ):
            for kind in ("filtered", "raw"):
                errs = [getattr(getattr(r, kind), key) for r in results]
                weights = [getattr(r, kind).frames for r in results]
                avg.setdefault(kind, {})[key] = rounded(weighted_average(errs, weights, rms=key == "rmse_m"))
        print(json.dumps({"sequences": [r.to_dict() for r in results], "average": avg, "settings": changed}))
    else:
        print(table_vi(results))
    return 0


def _cmd_fusion(args: argparse.Namespace) -> int:
    if not Path(args.folder).is_dir():
        raise _UsageError(f"fusion folder not found: {args.folder}")
    if not args.gate > 0:
        raise _UsageError(f"--gate must be a positive distance in metres, got {args.gate}")
    result = evaluate_fusion(args.folder, args.model, gate_m=args.gate, max_frames=args.frames)
    print(json.dumps(result.to_dict()) if args.json else fusion_table(result))
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    if len(args.base) != len(args.candidate):
        raise _UsageError(
            f"give as many --candidate files as --base files (the same seed sets in the same order), "
            f"got {len(args.base)} and {len(args.candidate)}"
        )
    if not (math.isfinite(args.moved) and args.moved >= 0):
        raise _UsageError(f"--moved must be a finite number of degrees >= 0, got {args.moved}")
    for path in (*args.base, *args.candidate):
        if not Path(path).is_file():
            raise _UsageError(f"report not found: {path}")
    comparison = compare_reports(
        [load_report(f) for f in args.base],
        [load_report(f) for f in args.candidate],
        moved_deg=args.moved,
        names=list(args.candidate),
    )
    print(json.dumps(comparison.to_dict()) if args.json else comparison.table())
    return 0


def _cmd_mot(args: argparse.Namespace) -> int:
    if not args.gate > 0:
        raise _UsageError(f"--gate must be a positive distance in metres, got {args.gate}")
    if args.video is not None and len(args.sequence) > 1:
        raise _UsageError("--video names one sequence's video: give one --sequence with it")
    _check_dither(args)
    localizer, tracker = _pipeline_configs(args, {}, {})
    changed = {**pipeline_changes(localizer, tracker), "dither": args.dither}
    results = []
    for path in args.sequence:
        seq, frames = _load(Path(path), args.video)
        results.append(
            evaluate_mot(
                seq,
                frames,
                args.model,
                gate_m=args.gate,
                progress=sys.stderr.isatty(),
                mirror_average=not args.no_mirror_average,
                tracker=tracker,
                localizer=localizer,
                dither=None if args.dither is None else FrameDither(args.dither),
            )
        )
    if args.json:
        out = results[0].to_dict() if len(results) == 1 else pooled_to_dict(results)
        print(json.dumps({**out, "settings": changed}))
        return 0
    settings = describe_pipeline_changes(changed)
    if args.dither is not None:
        settings.append(describe_dither(args.dither))
    if settings:
        print("settings: " + "; ".join(settings) + "\n")
    print(mot_table(results[0]) if len(results) == 1 else pooled_table(results))
    return 0


def _parse_size(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` (pixels) of ``--size``."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise _UsageError(f"--size must be WIDTHxHEIGHT in pixels (e.g. 1920x1080), got {text!r}") from None
    if w <= 0 or h <= 0:
        raise _UsageError(f"--size must be positive, got {text!r}")
    return w, h


def _cmd_robustness(args: argparse.Namespace) -> int:
    frames = args.frames if args.frames is not None else (QUICK_FRAMES if args.quick else DEFAULT_FRAMES)
    if frames <= 0:
        raise _UsageError(f"--frames must be positive, got {frames}")
    if args.drone_free is not None and args.drone_free < 0:
        raise _UsageError(f"--drone-free must be >= 0, got {args.drone_free}")
    _check_dither(args)
    if args.acquire_recut is not None and not args.acquire_recut > 0:
        raise _UsageError(f"--acquire-recut must be > 0, got {args.acquire_recut}")
    if args.confirm_max_outliers < 0:
        raise _UsageError(f"--confirm-max-outliers must be >= 0, got {args.confirm_max_outliers}")
    if not 0 <= args.heading_full_spread < math.inf:
        spread = args.heading_full_spread
        raise _UsageError(f"--heading-full-spread must be a finite number >= 0, got {spread}")
    if args.measure_every < 1:
        raise _UsageError(f"--measure-every must be >= 1, got {args.measure_every}")
    _check_oracle_noise(args)
    if args.seeds is not None:
        negative = [s for s in args.seeds if s < 0]
        if negative:
            raise _UsageError(f"--seeds must be >= 0, got {negative[0]}")
    width, height = _parse_size(args.size)
    localizer, tracker = _robustness_configs(args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise _UsageError(f"--out must be a folder, got the file {out}")
    if args.model is not None and not Path(args.model).is_file():
        raise _UsageError(f"--model not found: {args.model}")
    if args.front_back is not None and not heading_model_path(args.front_back).is_file():
        raise _UsageError(f"--front-back not found: {args.front_back}")
    if args.verifier is not None and not Path(args.verifier).is_file():
        raise _UsageError(f"--verifier not found: {args.verifier}")
    try:
        report = run_robustness(
            out,
            frames=frames,
            seeds=args.seeds,
            tuning=args.tuning,
            model_path=args.model,
            backgrounds=QUICK_BACKGROUNDS if args.quick else BACKGROUNDS,
            drone_free=args.drone_free
            if args.drone_free is not None
            else (QUICK_DRONE_FREE if args.quick else DRONE_FREE_SEQUENCES),
            width=width,
            height=height,
            mirror_average=not args.no_mirror_average,
            front_back=args.front_back or True,
            verifier=False if args.no_verifier else (args.verifier or True),
            progress=sys.stderr.isatty(),
            select=args.select,
            dither=args.dither,
            cue_free=args.cue_free,
            localizer=localizer,
            tracker=tracker,
            measure_every=args.measure_every,
            oracle_noise_px=args.oracle_noise,
        )
    except ImportError as exc:  # --background photos without scikit-image / scikit-learn
        raise _UsageError(str(exc)) from None
    print(json.dumps(report.to_dict()) if args.json else report.table())
    return 0


def _robustness_configs(args: argparse.Namespace) -> tuple[LocalizerConfig, TrackerConfig]:
    """The localiser's and tracker's settings: the shipped ones, the dedicated flags', then every
    ``--localizer`` / ``--tracker KEY=VALUE`` (which win)."""
    return _pipeline_configs(
        args,
        {"acquire_recut": args.acquire_recut},
        {
            "confirm_max_outliers": args.confirm_max_outliers,
            "heading_full_spread_px": args.heading_full_spread,
        },
    )


def _pipeline_configs(
    args: argparse.Namespace, localizer_base: dict, tracker_base: dict
) -> tuple[LocalizerConfig, TrackerConfig]:
    """``LocalizerConfig`` and ``TrackerConfig`` from ``*_base`` and ``--localizer`` / ``--tracker
    KEY=VALUE`` (which win); a bad pair is a usage error naming the flag, the key and the value."""
    try:
        localizer = config_with_overrides(
            LocalizerConfig,
            parse_overrides(args.localizer or [], LocalizerConfig, "--localizer"),
            "--localizer",
            **localizer_base,
        )
        tracker = config_with_overrides(
            TrackerConfig,
            parse_overrides(args.tracker or [], TrackerConfig, "--tracker"),
            "--tracker",
            **tracker_base,
        )
    except OverrideError as exc:
        raise _UsageError(str(exc)) from None
    return localizer, tracker


# Flags of the network and the search, which --oracle-noise replaces: (attribute, flag, its default).
_NETWORK_FLAGS = (
    ("model", "--model", None),
    ("no_mirror_average", "--no-mirror-average", False),
    ("localizer", "--localizer", None),
    ("front_back", "--front-back", None),
    ("verifier", "--verifier", None),
    ("no_verifier", "--no-verifier", False),
    ("acquire_recut", "--acquire-recut", None),
    ("measure_every", "--measure-every", 1),
    ("dither", "--dither", None),
)


def _check_oracle_noise(args: argparse.Namespace) -> None:
    """--oracle-noise is a finite number >= 0 px, and no flag of the network it replaces is given
    beside it (it would be silently without effect)."""
    if args.oracle_noise is None:
        return
    if not 0 <= args.oracle_noise < math.inf:
        raise _UsageError(f"--oracle-noise must be a finite number >= 0 px, got {args.oracle_noise}")
    given = [flag for attr, flag, default in _NETWORK_FLAGS if getattr(args, attr, default) != default]
    if given:
        raise _UsageError(f"--oracle-noise runs no network, so {', '.join(given)} would do nothing: drop it")


def _add_dither_flag(parser: argparse.ArgumentParser) -> None:
    """``--dither SEED`` (``_check_dither`` validates it)."""
    parser.add_argument(
        "--dither",
        type=int,
        metavar="SEED",
        help="add -1, 0 or +1 grey level of seeded noise to every frame before the pipeline: the "
        "figures' change against a run without is the evaluation's noise floor",
    )


def _check_dither(args: argparse.Namespace) -> None:
    if args.dither is not None and args.dither < 0:
        raise _UsageError(f"--dither must be >= 0, got {args.dither}")


def _add_override_flags(parser: argparse.ArgumentParser) -> None:
    """``--tracker`` and ``--localizer KEY=VALUE``, repeatable (``_pipeline_configs`` reads them)."""
    parser.add_argument(
        "--tracker",
        action="append",
        metavar="KEY=VALUE",
        help="measure any tracker setting (a field of TrackerConfig, e.g. confirm_min_presence=0.9; "
        "repeat for several); the report's settings list what was changed",
    )
    parser.add_argument(
        "--localizer",
        action="append",
        metavar="KEY=VALUE",
        help="measure any localiser setting (a field of LocalizerConfig, e.g. max_candidates=4; repeat "
        "for several)",
    )


_ROBUSTNESS_HELP = """\
Render a fixed matrix of sequences into --out (reused on a rerun when their JSON info, the
renderer's name included, frame count and size match), run the daemon's pipeline over each and
print one table.

matrix (dronekey.evaluation.robustness):
  drone sequences   LEDs red-front, green-front, off, random
                    x backgrounds sky (procedural skies), photos (held-out packaged photographs,
                      never used in training; needs scikit-image or scikit-learn), urban
                    x motions seq11, seq12, seq13 (the paper's Tab. I), scripted attitudes;
                    one motion of every (LED, background) cell 2.5x as far (about 35-60 px across)
  drone-free        20 sequences (birds, flying objects, clouds, edge clutter) over the same scenes
  --frames frames each (150: 5,400 drone frames + 3,000 drone-free); --quick: sky only, 40
  frames, 5 drone-free sequences (a smoke test, not a figure)

seeds: reporting scene seeds 7001+ (drone-free 7501+), tuning seeds 6001+ (drone-free 6501+,
  --tuning); style seed = scene seed + 10000. Training uses the sampler's streams (seeds 0, 1, ...),
  its validation seed 7919; the two sets are kept apart and neither may hold 7919.

metrics per row (frames pooled): MAE-angle (deg), RMSE (m), MAE-absolute (m) of the drone's track
  (the best published track within max(0.5 m, 25 % of the range) of the truth), detected % (frames
  with such a track), AP^kp of the pipeline's detections (%), frames with a false track (a
  published track that is not the drone's) per 1,000 frames and their distinct ids, the same for
  false tracks off the drone's line of sight (off-sight: clutter, or a track that coasted away;
  the rest is the drone read at a wrong range), and wrong heading % (the drone's track > 90 deg
  off while heading_confidence >= 0.5).

noise floor: --dither SEED scores the same renders with a grey level of seeded noise on every
  frame; the change of each figure against a run without is how far it moves on noise alone, the
  least difference between two pipelines that the matrix can tell apart.
"""


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
    q.add_argument("--sequence", help="sequence JSON (docs/design.md §5.1)")
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
    _add_override_flags(q)
    q.add_argument("--json", action="store_true", help="print one JSON object")
    q.set_defaults(func=_cmd_pose)
    m = sub.add_parser(
        "mot",
        help="CLEAR-MOT and identity metrics (motmetrics) on a sequence with one or more drones",
        description="Run the daemon's pipeline over a sequence (dronekey-sim --preset swarm writes one) "
        "and match its published tracks with the ground-truth drones on 3D distance in the camera "
        "frame: MOTA, MOTP (m), IDF1, ID switches, FP, FN, mostly tracked / lost, and per drone the "
        "Tab. VI errors over its matched frames (docs/evaluation.md).",
    )
    m.add_argument(
        "--sequence",
        required=True,
        nargs="+",
        metavar="JSON",
        help="sequence JSON (docs/design.md §5.1); several: each one's table, then their matches "
        "added up (one 300-frame swarm's IDF1 moves by hundredths on any perturbation)",
    )
    m.add_argument("--video", help="video or image folder (default: from the JSON's file names)")
    m.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    m.add_argument(
        "--gate",
        type=float,
        default=DEFAULT_GATE_M,
        metavar="M",
        help=f"a track matches a drone only within this 3D distance, metres (default {DEFAULT_GATE_M:g})",
    )
    m.add_argument(
        "--no-mirror-average", action="store_true", help="run each crop once (the daemon's default averages)"
    )
    _add_override_flags(m)
    _add_dither_flag(m)
    m.add_argument("--json", action="store_true", help="print one JSON object")
    m.set_defaults(func=_cmd_mot)
    f = sub.add_parser(
        "fusion",
        help="each camera's pipeline and the fuser on a multi-camera render: single vs fused",
        description="Run each camera's pipeline over a dronekey-sim --cameras N render (site.json and a "
        "folder per camera), fuse the tracks (dronekey.fusion, poses from site.json) and print, per "
        "camera and fused, RMSE, MAE-absolute and MAE-angle in the site frame, and MOTA, IDF1 and ID "
        "switches (motmetrics, matched within --gate) (docs/evaluation.md).",
    )
    f.add_argument("folder", metavar="DIR", help="the folder dronekey-sim --cameras N wrote")
    f.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    f.add_argument("--frames", type=int, default=None, metavar="N", help="only the first N frames")
    f.add_argument(
        "--gate", type=float, default=2.0, metavar="M", help="MOT match distance, metres (default 2)"
    )
    f.add_argument("--json", action="store_true", help="print one JSON object")
    f.set_defaults(func=_cmd_fusion)
    c = sub.add_parser(
        "compare",
        help="a candidate's robustness runs against a baseline's: pooled rows, sequences moved",
        description="Read runs of 'dronekey-eval robustness --json' (a baseline and a candidate on the same "
        "renders, one file per seed set) and print every row pooled over the sets, baseline -> "
        "candidate (MAE-angle and RMSE over the detected frames, detected %, AP^kp as the mean of "
        "the sets, confidently wrong and sure-and-right shares, false-track frames), then the "
        "sequences whose MAE-angle moved by more than --moved degrees, better and worse. Which way "
        "round a hard drone is read is decided per sequence, so count those before trusting a "
        "pooled mean (docs/evaluation.md).",
    )
    c.add_argument(
        "--base", nargs="+", required=True, metavar="JSON", help="the baseline's runs, one per seed set"
    )
    c.add_argument(
        "--candidate",
        nargs="+",
        required=True,
        metavar="JSON",
        help="the candidate's runs, in the same order",
    )
    c.add_argument(
        "--moved",
        type=float,
        default=10.0,
        metavar="DEG",
        help="a sequence's MAE-angle change that counts (default 10)",
    )
    c.add_argument("--json", action="store_true", help="print one JSON object")
    c.set_defaults(func=_cmd_compare)
    r = sub.add_parser(
        "robustness",
        help="the pipeline under LED, background, motion and range changes, and on drone-free sequences",
        description=_ROBUSTNESS_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    r.add_argument("--out", required=True, help="folder for the rendered sequences (created if missing)")
    r.add_argument("--frames", type=int, help="frames per sequence (default 150; 40 with --quick)")
    r.add_argument(
        "--seeds",
        type=int,
        nargs="+",
        metavar="N",
        help="base scene seeds, one matrix each (default 7001, or 6001 with --tuning)",
    )
    r.add_argument("--tuning", action="store_true", help="use (or name with --seeds) the tuning seed set")
    r.add_argument("--model", default=None, help="ONNX model (default: the shipped one)")
    r.add_argument(
        "--front-back",
        default=None,
        help="ONNX front/back classifier, or the name of a shipped one: gated (the default) or deep",
    )
    r.add_argument("--verifier", default=None, help="ONNX drone verifier (default: the shipped one, if any)")
    r.add_argument("--no-verifier", action="store_true", help="run without a drone verifier")
    _add_dither_flag(r)
    r.add_argument(
        "--acquire-recut",
        type=float,
        metavar="F",
        help="measure the localiser's opt-in search recut (LocalizerConfig.acquire_recut, off as "
        "shipped): a search reading whose keypoints ask for a crop more than 1 + F times off its "
        "own is read again there",
    )
    r.add_argument(
        "--confirm-max-outliers",
        type=int,
        default=0,
        metavar="N",
        help="measure a confirmation rule that may leave out up to N hits whose range disagrees with "
        "the rest of the window's (TrackerConfig.confirm_max_outliers, 0 as shipped)",
    )
    r.add_argument(
        "--heading-full-spread",
        type=float,
        default=0.0,
        metavar="PX",
        help="measure a heading confidence bounded by the drone's size: none below hubs PX / 2 apart, "
        "sure allowed from PX (TrackerConfig.heading_full_spread_px, 0 as shipped)",
    )
    _add_override_flags(r)
    r.add_argument(
        "--measure-every",
        type=int,
        default=1,
        metavar="N",
        help="measure a measurement stride: while every live track is confirmed and the network sure of "
        "its last crop, the drones are measured on every N-th frame only and the tracks predicted between "
        "(TrackingPipeline's "
        "measure_every, the daemon's tracking.measure_every; 1 as shipped); AP^kp then counts the "
        "measured frames",
    )
    r.add_argument(
        "--oracle-noise",
        type=float,
        metavar="PX",
        help="no network: every drone's true keypoints plus Gaussian noise of PX per coordinate through "
        "the pipeline's PnP and tracker (the filter told PX): the RMSE and MAE-angle the pose stage alone "
        "reaches at that precision, a yardstick for a detector (detection and false tracks are not measured)",
    )
    r.add_argument(
        "--cue-free",
        action="store_true",
        help="draw every drone with no front/back cue (same seeds; folders end in -cuefree): whose "
        "heading nobody can tell, so conf>90 must stay near 0 and 'sure ok' is the doubt's cost",
    )
    r.add_argument("--quick", action="store_true", help="reduced matrix for a smoke test (see above)")
    r.add_argument(
        "--drone-free",
        type=int,
        metavar="N",
        help="drone-free sequences in the matrix (default 20; 5 with --quick); the j-th keeps its seed",
    )
    r.add_argument(
        "--select",
        nargs="+",
        metavar="GLOB",
        help="only the sequences whose name matches one of these patterns, with their matrix seeds "
        "(e.g. '*nodrone*' for the drone-free part alone, 's70??-seq11-off-*')",
    )
    r.add_argument("--size", default="1920x1080", help="image size WIDTHxHEIGHT (figures use the default)")
    r.add_argument(
        "--no-mirror-average", action="store_true", help="run each crop once (the daemon's default averages)"
    )
    r.add_argument("--json", action="store_true", help="print one JSON object (every row and every sequence)")
    r.set_defaults(func=_cmd_robustness)
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
