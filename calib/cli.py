"""``dronekey-calib``: camera intrinsics from pictures of a printed board, and a check of them.

    dronekey-calib --images 'shots/*.jpg' --pattern chessboard --cols 9 --rows 6 --square 0.025 \
        --out camera.yaml
    dronekey-calib --video wave.mp4 --pattern charuco --cols 7 --rows 5 --square 0.03 --marker 0.022 \
        --out camera.yaml
    dronekey-calib check --calib camera.yaml --images 'later/*.jpg' --pattern chessboard --cols 9 \
        --rows 6 --square 0.025

Exit status: 0 done; 1 bad input or no usable calibration (one line on stderr says why); 2 bad
command line; 3 ``check --max-rms`` exceeded.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from dronekey.calib.calibrate import MIN_VIEWS, CalibrationOptions, calibrate_rejecting_outliers
from dronekey.calib.calibration_file import load_calibration, write_calibration
from dronekey.calib.check import check_views
from dronekey.calib.collect import Collection, collect_from_images, collect_from_video
from dronekey.calib.coverage import coverage_image, coverage_stats, write_png
from dronekey.calib.errors import CalibInputError
from dronekey.calib.patterns import DEFAULT_DICTIONARY, PATTERN_KINDS, BoardDetector, BoardPattern
from dronekey.calib.report import advice, calibration_json, calibration_summary, check_json, check_summary

__all__ = ["main"]

PROG = "dronekey-calib"
EXIT_BAD_INPUT = 1
EXIT_CHECK_FAILED = 3

log = logging.getLogger("dronekey.calib")


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad command line in one line (``prog: error: ...``), not usage + error."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _add_source_and_board(parser: argparse.ArgumentParser) -> None:
    source = parser.add_argument_group("pictures (one of)")
    group = source.add_mutually_exclusive_group(required=True)
    group.add_argument(
        "--images", metavar="GLOB", help="image files, e.g. 'shots/*.jpg' (quote it; ** recurses)"
    )
    group.add_argument(
        "--video", metavar="FILE", type=Path, help="a video of the board moving in front of the camera"
    )
    source.add_argument(
        "--frames",
        type=int,
        default=200,
        metavar="N",
        help="--video: examine N evenly spaced frames (default 200)",
    )
    source.add_argument(
        "--max-views",
        type=int,
        default=30,
        metavar="N",
        help="--video: keep at most N sharp, diverse views (default 30)",
    )
    board = parser.add_argument_group("board")
    board.add_argument("--pattern", required=True, choices=PATTERN_KINDS, help="board type")
    board.add_argument(
        "--cols",
        type=int,
        required=True,
        help="points per row, as OpenCV's pattern size: inner corners (chessboard, ChArUco) or circles",
    )
    board.add_argument("--rows", type=int, required=True, help="rows of points (inner corners or circles)")
    board.add_argument(
        "--square",
        type=float,
        required=True,
        metavar="METRES",
        help="square side (chessboard, ChArUco) or grid spacing s (circle grids), metres; for acircles "
        "point (i, j) lies at ((2j + i mod 2) s, i s)",
    )
    board.add_argument("--marker", type=float, metavar="METRES", help="ChArUco: ArUco marker side, metres")
    board.add_argument(
        "--dictionary",
        default=DEFAULT_DICTIONARY,
        metavar="NAME",
        help=f"ChArUco: ArUco dictionary, e.g. DICT_4X4_50 (default {DEFAULT_DICTIONARY})",
    )
    board.add_argument(
        "--legacy-charuco",
        action="store_true",
        help="ChArUco board printed by OpenCV before 4.6 with an even number of square rows",
    )
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of the summary")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details to stderr")


def _calibrate_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog=PROG,
        description="Calibrate a camera from pictures of a printed board: writes the intrinsics YAML the "
        "daemon reads (OpenCV FileStorage, docs/design.md §5.2), a coverage image next to it, and advice. "
        f"To check a calibration against other pictures: {PROG} check --help.",
        epilog="Exit status: 0 done, 1 bad input (one line on stderr), 2 bad command line.",
    )
    _add_source_and_board(parser)
    model = parser.add_argument_group("model (what to hold fixed)")
    model.add_argument("--fix-aspect", action="store_true", help="hold fx/fy at 1 (square pixels)")
    model.add_argument(
        "--fix-principal-point",
        action="store_true",
        help="hold (cx, cy) at the image centre ((w-1)/2, (h-1)/2), or at --principal-point",
    )
    model.add_argument(
        "--principal-point",
        type=float,
        nargs=2,
        metavar=("CX", "CY"),
        help="with --fix-principal-point: where to hold it, pixels (e.g. 320 256 to repeat a 640x512 "
        "calibration by an older OpenCV, which held it at (w/2, h/2))",
    )
    model.add_argument("--zero-tangent", action="store_true", help="hold p1 = p2 = 0")
    model.add_argument("--fix-k3", action="store_true", help="hold k3 = 0")
    model.add_argument(
        "--fix-k4", action="store_true", help="hold k4 = 0 (already absent from the pinhole model)"
    )
    model.add_argument(
        "--fix-k5", action="store_true", help="hold k5 = 0 (already absent from the pinhole model)"
    )
    model.add_argument(
        "--fisheye", action="store_true", help="OpenCV's fisheye model (k1..k4) for wide lenses"
    )
    model.add_argument(
        "--max-view-rms",
        type=float,
        metavar="PX",
        help="leave out views above this RMS and calibrate again (default: 3x the median, at least 1 px)",
    )
    parser.add_argument(
        "--out", required=True, type=Path, metavar="FILE.yaml", help="calibration file to write"
    )
    return parser


def _check_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog=f"{PROG} check",
        description="Reprojection error of other board pictures against a calibration: each view's pose is "
        "solved with the calibration's intrinsics held fixed.",
        epilog="Exit status: 0 done, 1 bad input (one line on stderr), 2 bad command line, "
        "3 --max-rms exceeded.",
    )
    parser.add_argument("--calib", required=True, type=Path, metavar="FILE", help="calibration file to check")
    _add_source_and_board(parser)
    parser.add_argument(
        "--max-rms", type=float, metavar="PX", help="exit with status 3 if the RMS exceeds PX"
    )
    return parser


def _pattern(args: argparse.Namespace) -> BoardPattern:
    return BoardPattern(
        kind=args.pattern,
        cols=args.cols,
        rows=args.rows,
        square=args.square,
        marker=args.marker,
        dictionary=args.dictionary,
        legacy_charuco=args.legacy_charuco,
    )


def _collect(args: argparse.Namespace, detector: BoardDetector) -> Collection:
    if args.max_views < 1:
        raise CalibInputError(f"--max-views must be >= 1, got {args.max_views}")
    if args.images is not None:
        return collect_from_images(args.images, detector)
    return collect_from_video(args.video, detector, frames=args.frames, max_views=args.max_views)


def _run_calibrate(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() not in (".yaml", ".yml"):
        raise CalibInputError(f"--out {out} must end in .yaml or .yml (OpenCV FileStorage YAML)")
    if not out.parent.is_dir():
        raise CalibInputError(f"--out {out}: folder {out.parent} does not exist")
    if args.max_view_rms is not None and not args.max_view_rms > 0:
        raise CalibInputError(f"--max-view-rms must be positive, got {args.max_view_rms}")
    pattern = _pattern(args)
    options = CalibrationOptions(
        fix_aspect=args.fix_aspect,
        fix_principal_point=args.fix_principal_point,
        principal_point=tuple(args.principal_point) if args.principal_point else None,
        zero_tangent=args.zero_tangent,
        fix_k3=args.fix_k3,
        fix_k4=args.fix_k4,
        fix_k5=args.fix_k5,
        fisheye=args.fisheye,
    )
    collected = _collect(args, BoardDetector(pattern))
    log.info("%s", collected.summary)
    if len(collected.views) < MIN_VIEWS:
        raise CalibInputError(
            f"too few views: {collected.summary}; calibration needs at least {MIN_VIEWS} "
            "(15 or more is better)"
        )
    result, outliers = calibrate_rejecting_outliers(
        collected.views, collected.names, collected.image_size, options, args.max_view_rms
    )
    rejected = collected.rejected + outliers
    by_name = dict(zip(collected.names, collected.views, strict=True))
    coverage_path = out.with_suffix(".coverage.png")
    stats = coverage_stats(result.image_points, collected.image_size)
    picture = coverage_image(
        result.image_points,
        collected.image_size,
        outliers=[by_name[v.name].image_points for v in outliers],
        title=f"{out.name}: RMS {result.rms:.3f} px, {len(result.view_names)} views",
    )
    write_calibration(out, result, pattern)
    write_png(coverage_path, picture)
    log.info("wrote %s and %s", out, coverage_path)
    if args.json:
        print(json.dumps(calibration_json(result, rejected)))
    else:
        lines = advice(result, stats, outliers, str(coverage_path))
        print(
            calibration_summary(
                result,
                options,
                pattern.describe(),
                collected.summary,
                rejected,
                lines,
                str(out),
                str(coverage_path),
            )
        )
    return 0


def _run_check(args: argparse.Namespace) -> int:
    if args.max_rms is not None and not args.max_rms > 0:
        raise CalibInputError(f"--max-rms must be positive, got {args.max_rms}")
    camera, fisheye = load_calibration(args.calib)
    pattern = _pattern(args)
    collected = _collect(args, BoardDetector(pattern))
    result = check_views(camera, fisheye, collected.views, collected.names, collected.image_size)
    if args.json:
        print(
            json.dumps(
                check_json(result.names, result.per_view_rms, result.rms, collected.rejected, camera.rms_px)
            )
        )
    else:
        print(
            check_summary(
                str(args.calib),
                result.names,
                result.per_view_rms,
                result.rms,
                collected.rejected,
                camera.rms_px,
                collected.summary,
            )
        )
    if args.max_rms is not None and result.rms > args.max_rms:
        print(
            f"{PROG}: check failed: RMS {result.rms:.3f} px exceeds --max-rms {args.max_rms:g}",
            file=sys.stderr,
        )
        return EXIT_CHECK_FAILED
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``dronekey-calib``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    is_check = bool(argv) and argv[0] == "check"
    parser = _check_parser() if is_check else _calibrate_parser()
    try:
        args = parser.parse_args(argv[1:] if is_check else argv)
    except SystemExit as exc:  # --help, or a bad command line already reported in one line
        return int(exc.code or 0)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format=f"{PROG}: %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        return _run_check(args) if is_check else _run_calibrate(args)
    except CalibInputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f"{PROG}: error: {exc.strerror or exc}: {exc.filename or ''}".rstrip(": "), file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
