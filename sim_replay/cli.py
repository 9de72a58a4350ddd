"""``dronekey-sim``: render a 3DronePose-style sequence (video or frames + JSON + camera.yaml), list
the presets, or check a sequence JSON against its video or images.

Exit codes: 0 done; 1 a file could not be written while rendering; 2 bad input (argument, preset,
output folder, backgrounds folder, JSON, calibration, missing media), always as one line
``dronekey-sim: error: ...`` on stderr; 130 interrupted with Ctrl-C (no files left behind).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

import numpy as np
from tqdm import tqdm

from dronekey.geometry.camera import CalibrationError
from dronekey.geometry.drone_spec import DroneSpecError
from dronekey.sim_replay.drone_look import LED_MODES
from dronekey.sim_replay.flight import FLIGHT_MODELS
from dronekey.sim_replay.io.coco_pose import ROTATION_ENCODINGS, TRANSLATION_UNITS, CocoPoseEncoding
from dronekey.sim_replay.io.frames import FrameSourceError, iter_frames
from dronekey.sim_replay.io.h264_video import default_bitrate_bps
from dronekey.sim_replay.io.render_output import VIDEO_CODECS, write_sequence
from dronekey.sim_replay.io.rig_output import write_rig
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.io.validation import SequenceFormatError
from dronekey.sim_replay.presets import PRESETS
from dronekey.sim_replay.scene import DEFAULT_DRONES, MAX_CAMERAS, MAX_DRONES, build_scene
from dronekey.sim_replay.synthetic_sequence import BACKGROUND_KINDS, build_sequence

__all__ = ["main"]

PROG = "dronekey-sim"
EXIT_WRITE_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 1, 2, 130

log = logging.getLogger(__name__)


class UsageError(Exception):
    """Bad input from the user; printed as one ``dronekey-sim: error:`` line, exit code 2."""


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error as a single line instead of usage + message."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _bitrate(text: str) -> int:
    """A bitrate in bit/s: ``8000000``, ``8M``, ``800k`` (SI prefixes, as FFmpeg writes them)."""
    scale = {"k": 1e3, "m": 1e6}.get(text[-1:].lower(), 1.0)
    number = text[:-1] if scale != 1.0 else text
    try:
        value = float(number) * scale
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a bitrate such as 8M or 800k, got {text!r}") from None
    if not 10_000 <= value <= 1e9:
        raise argparse.ArgumentTypeError(f"must be between 10k and 1000M bit/s, got {text!r}")
    return round(value)


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog=PROG,
        description=(
            "Render a synthetic 3DronePose-style sequence: OUT/<preset>.mp4 (or the frame folder\n"
            "OUT/<preset>/ with --images), OUT/<preset>.json (COCO keypoints + 6DoF ground truth,\n"
            "docs/simulator.md) and OUT/camera.yaml. Or check a sequence JSON (ours, or a real\n"
            "2DroneKey / 3DronePose COCO file) against its video or images with --verify."
        ),
        epilog=(
            "examples:\n"
            "  dronekey-sim --preset seq13 --out out --frames 40\n"
            "  dronekey-sim --preset 2dronekey --out data --seed 7 --width 960 --height 540 --images\n"
            "  dronekey-sim --preset seq12 --out eval --style-seed 3 --leds off --range-scale 2.5\n"
            "  dronekey-sim --preset seq13 --out eval --flight coordinated --background photos\n"
            "  dronekey-sim --preset seq11 --out negatives --no-drone --background urban\n"
            "  dronekey-sim --preset swarm --drones 3 --out swarm --frames 150\n"
            "  dronekey-sim --preset far --cameras 2 --out far2   # far2/cam0/, far2/cam1/, far2/site.json\n"
            "  dronekey-sim --verify out/seq13.json\n"
            "  dronekey-sim --verify 3DronePose/seq13.json --media 3DronePose/images --calib camera.yaml\n"
            "\n"
            "Files are written under temporary names and renamed at the end: an interrupted run\n"
            "leaves no files. The same --seed gives byte-identical JSON. Exit codes: 0 done,\n"
            "1 a write failed, 2 bad input, 130 interrupted."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    mode = parser.add_argument_group("what to do (one of)")
    mode.add_argument("--preset", metavar="NAME", help="render this preset (see --list-presets)")
    mode.add_argument("--list-presets", action="store_true", help="list the presets and exit")
    mode.add_argument(
        "--verify", metavar="JSON", type=Path, help="read a sequence JSON and its frames, report"
    )

    render = parser.add_argument_group("rendering (--preset)")
    render.add_argument("--out", metavar="DIR", type=Path, help="output folder (created if missing)")
    render.add_argument(
        "--seed", metavar="N", type=_seed, help="random seed (default: the preset's); same seed, same output"
    )
    render.add_argument(
        "--frames", metavar="N", type=_positive_int, help="number of frames (default: the preset's)"
    )
    render.add_argument(
        "--width", metavar="W", type=_positive_int, help="frame width in pixels (with --height; default 1920)"
    )
    render.add_argument(
        "--height",
        metavar="H",
        type=_positive_int,
        help="frame height in pixels (with --width; default 1080)",
    )
    render.add_argument(
        "--backgrounds",
        metavar="DIR",
        type=Path,
        help="folder of background photos, used for 70%% of the seeds (not with --background photos)",
    )
    render.add_argument(
        "--images", action="store_true", help="write OUT/<preset>/NNNNNN.png instead of a video"
    )
    render.add_argument(
        "--drones",
        metavar="N",
        type=_positive_int,
        help=f"drones of the swarm preset (1-{MAX_DRONES}, default {DEFAULT_DRONES}): crossing paths, one "
        "passing in front of another, Mini 2 and Air 2S at 4-14 m; each has its instance_id in the JSON",
    )
    render.add_argument(
        "--airframe",
        metavar="NAME",
        help="every drone of the swarm preset this airframe (mini2 or air2s), on the same paths; "
        "default: the swarm's mix, which one camera cannot tell apart (it reads range from size)",
    )
    render.add_argument(
        "--cameras",
        metavar="N",
        type=_positive_int,
        default=1,
        help=f"cameras watching the same flight (1-{MAX_CAMERAS}, default 1): with N >= 2, "
        "OUT/cam0/ .. OUT/cam<N-1>/ (each as a single-camera render) and OUT/site.json, the cameras' "
        "poses 5-50 m apart (docs/design.md §5.4)",
    )
    render.add_argument(
        "--codec",
        choices=VIDEO_CODECS,
        help="video codec: h264 (default: libx264 through PyAV, yuv420p, a keyframe every 2 s, as a "
        "camera sends) or mp4v (OpenCV's writer: MPEG-4 Part 2, or H.264 where that OpenCV build "
        "encodes it)",
    )
    render.add_argument(
        "--bitrate",
        metavar="RATE",
        type=_bitrate,
        help="H.264 target bitrate in bit/s, e.g. 8M or 800k (default: 8M at 1920x1080 30 fps, scaled "
        "by width x height x fps: camera-like; 20M makes a heavy recording)",
    )

    conditions = parser.add_argument_group("conditions (--preset)")
    conditions.add_argument(
        "--style-seed",
        metavar="N",
        type=_seed,
        help="seed of the drone's look: random body, livery, LEDs and blinking (default: derived "
        "from --seed, recorded in the JSON); changes the drone, never its path",
    )
    conditions.add_argument(
        "--leds",
        choices=LED_MODES,
        default="random",
        help="drone LEDs: red-front (red front, green rear), green-front (the other way round), off "
        "(unlit) or random (default: the style's own; absent on 45%% of the drones); lit LEDs blink "
        "at 1-2 Hz on a quarter of the style seeds",
    )
    conditions.add_argument(
        "--cue-free",
        action="store_true",
        help="draw the drone's body with no front/back cue (no gimbal, nose, taper, battery bulge, "
        "dropped rear arms or half stripe): a symmetric drone whose heading nobody can tell, which "
        "the pipeline must publish as unsure",
    )
    conditions.add_argument(
        "--no-drone",
        action="store_true",
        help="drone-free sequence (no annotations): edge clutter, moving birds, flying objects and clouds",
    )
    conditions.add_argument(
        "--flight",
        choices=FLIGHT_MODELS,
        default="scripted",
        help="drone attitude: scripted (default: the preset's) or coordinated (nose along the velocity, "
        "tilted along the acceleration as a real quadcopter flies the same path)",
    )
    conditions.add_argument(
        "--background",
        choices=BACKGROUND_KINDS,
        default="procedural",
        help="background kind: procedural (default: skies, terrain, cities), sky, urban, or photos (the "
        "held-out packaged photos training never sees; needs scikit-image or scikit-learn)",
    )
    conditions.add_argument(
        "--range-scale",
        metavar="X",
        type=_positive_float,
        default=1.0,
        help="put the drone X times as far from the camera on the same bearing (default 1; 2.5 draws "
        "it about 30-60 px across at 1920x1080)",
    )

    verify = parser.add_argument_group("checking (--verify)")
    verify.add_argument(
        "--media", metavar="PATH", type=Path, help="video or image folder (default: from the JSON)"
    )
    verify.add_argument(
        "--calib", metavar="YAML", type=Path, help="camera calibration (real COCO files lack one)"
    )
    verify.add_argument("--drone", metavar="NAME|YAML", help="drone spec (mini2, air2s or a YAML file)")
    verify.add_argument(
        "--rotation-encoding",
        choices=("auto", *ROTATION_ENCODINGS),
        default="auto",
        metavar="ENC",
        help="how a real COCO file encodes rotation: auto (default: the encoding that reprojects the "
        f"keypoints), {', '.join(ROTATION_ENCODINGS)}",
    )
    verify.add_argument(
        "--translation-unit",
        choices=("auto", *TRANSLATION_UNITS),
        default="auto",
        help="unit of a real COCO file's translation (default auto)",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log more (INFO)")
    return parser


# ---------------------------------------------------------------------------------------- checks


def _check_output_folder(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise UsageError(f"output folder {out} is an existing file")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise UsageError(f"output folder {out} is not writable ({exc.strerror or exc})") from None


def _video_codec(args: argparse.Namespace, width: int, height: int) -> str:
    """The codec to write (``--codec``, h264 by default), after checking it fits the other flags."""
    if args.images and (args.bitrate is not None or args.codec is not None):
        raise UsageError("--codec and --bitrate set the video; --images writes PNG frames instead")
    codec = args.codec or "h264"
    if codec == "mp4v" and args.bitrate is not None:
        raise UsageError("--bitrate applies to --codec h264 (OpenCV's mp4v writer has no bitrate setting)")
    if not args.images and codec == "h264" and (width % 2 or height % 2):
        raise UsageError(f"--codec h264 needs an even --width and --height (yuv420p), got {width}x{height}")
    return codec


def _size(args: argparse.Namespace) -> tuple[int, int]:
    if (args.width is None) != (args.height is None):
        given = "--width" if args.width is not None else "--height"
        raise UsageError(f"{given} needs its partner: give both --width and --height, or neither")
    return (args.width, args.height) if args.width is not None else (1920, 1080)


# ---------------------------------------------------------------------------------------- modes


def _list_presets() -> int:
    for preset in PRESETS.values():
        print(f"{preset.name:10s} {preset.frames:5d} frames at {preset.fps:g} fps  {preset.description}")
    return 0


def _cli_message(message: str) -> str:
    """A build_sequence error in the CLI's words (option names instead of keyword names)."""
    return message.replace("background 'photos'", "--background photos").replace(
        "a backgrounds folder", "--backgrounds"
    )


def _scene_options(args: argparse.Namespace, width: int, height: int) -> dict:
    """The keywords ``build_sequence`` and ``build_scene`` share, from the command line."""
    return {
        "preset": args.preset,
        "seed": args.seed,
        "frames": args.frames,
        "width": width,
        "height": height,
        "backgrounds": args.backgrounds,
        "style_seed": args.style_seed,
        "leds": args.leds,
        "flight": args.flight,
        "background": args.background,
        "range_scale": args.range_scale,
        "cue_free": args.cue_free,
    }


def _render(args: argparse.Namespace) -> int:
    if args.preset not in PRESETS:
        raise UsageError(f"unknown preset {args.preset!r}; valid presets: {', '.join(PRESETS)}")
    if args.out is None:
        raise UsageError("--out DIR is required with --preset")
    width, height = _size(args)
    codec = _video_codec(args, width, height)
    if PRESETS[args.preset].multi_drone or args.cameras > 1 or args.drones is not None or args.airframe:
        return _render_scene(args, width, height, codec)
    try:
        seq = build_sequence(**_scene_options(args, width, height), no_drone=args.no_drone)
    except (ValueError, OSError, ImportError) as exc:  # build_sequence's own checks (sizes, frames, folders)
        raise UsageError(_cli_message(str(exc))) from None
    _check_output_folder(args.out)
    with tqdm(total=seq.n_frames, unit="frame", desc=seq.name, disable=None, leave=False) as bar:
        try:
            written = write_sequence(
                seq,
                args.out,
                images=args.images,
                on_frame=bar.update,
                codec=codec,
                bitrate_bps=args.bitrate,
            )
        except OSError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return EXIT_WRITE_FAILED
    video = ""
    if not args.images:
        video = (
            f"{codec}"
            + (
                f" {(args.bitrate or default_bitrate_bps((width, height), seq.fps)) / 1e6:.2f} Mbit/s"
                if codec == "h264"
                else ""
            )
            + ", "
        )
    print(
        f"wrote {written.n_frames} frames ({written.n_annotated} annotated) of {seq.name} at "
        f"{width}x{height}, {video}{written.frames_per_second:.1f} frames/s: {written.media_path}, "
        f"{written.json_path}, {written.camera_path}"
    )
    return 0


def _render_scene(args: argparse.Namespace, width: int, height: int, codec: str) -> int:
    """The swarm preset, or any preset seen by several cameras (``sim_replay.scene``)."""
    if args.no_drone:
        raise UsageError(
            "--no-drone renders one camera of a single-drone preset; not with --cameras or swarm"
        )
    try:
        scene = build_scene(
            **_scene_options(args, width, height),
            drones=args.drones,
            cameras=args.cameras,
            airframe=args.airframe,
        )
    except (ValueError, OSError, ImportError) as exc:
        message = str(exc)
        for option in ("drones", "cameras", "airframe"):
            message = message.replace(f"{option} must", f"--{option} must")
            message = message.replace(f"{option} applies", f"--{option} applies")
        raise UsageError(_cli_message(message)) from None
    _check_output_folder(args.out)
    first = scene.views[0]
    total = first.n_frames * len(scene.views)
    with tqdm(total=total, unit="frame", desc=first.name, disable=None, leave=False) as bar:
        try:
            video = dict(images=args.images, on_frame=bar.update, codec=codec, bitrate_bps=args.bitrate)
            if args.cameras == 1:
                written, site_path = [write_sequence(first, args.out, **video)], None
            else:
                written, site_path = write_rig(scene.views, scene.site, args.out, **video)
        except OSError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return EXIT_WRITE_FAILED
    for camera, w in zip(scene.site.cameras, written, strict=False):
        print(
            f"wrote {w.n_frames} frames ({w.n_annotated} annotated) of {first.name} with "
            f"{len(first.drones)} drone(s) at {width}x{height}, {w.frames_per_second:.1f} frames/s"
            + (f" [{camera.id}]" if site_path else "")
            + f": {w.media_path}, {w.json_path}, {w.camera_path}"
        )
    if site_path is not None:
        print(f"wrote {site_path} ({len(scene.site.cameras)} cameras)")
    return 0


def _verify(args: argparse.Namespace) -> int:
    encoding = CocoPoseEncoding(rotation=args.rotation_encoding, translation_unit=args.translation_unit)
    seq = load_sequence(args.verify, camera=args.calib, drone=args.drone, pose_encoding=encoding)
    n_frames = n_annotated = 0
    worst_px = 0.0
    source = args.media
    with tqdm(total=len(seq.frames), unit="frame", desc=seq.name, disable=None, leave=False) as bar:
        for frame in iter_frames(seq, source):
            n_frames += 1
            n_annotated += frame.record.drone is not None
            for drone in frame.record.drones:  # each with its own instance's hubs
                if drone.has_pose:
                    hubs = seq.instance(drone.instance_id).keypoints_3d
                    projected = seq.camera.project_body(hubs, drone.rotation, drone.translation)
                    labelled = drone.visibility > 0
                    error = np.linalg.norm(projected[labelled] - drone.keypoints_px[labelled], axis=1)
                    worst_px = max(worst_px, float(error.max(initial=0.0)))
            bar.update()
    pose = (
        f"keypoints vs projection of keypoints_3d through the pose: max {worst_px:.4f} px"
        if any(f.drone is not None and f.drone.has_pose for f in seq.frames)
        else "no 6DoF in the file"
    )
    width, height = seq.camera.size
    print(
        f"{args.verify}: {n_frames} frames ({n_annotated} annotated) of {width}x{height} read and checked; "
        + (
            f"{len(seq.instance_ids())} drones "
            f"({', '.join(f'{i}: {seq.instance(i).model}' for i in seq.instance_ids())}); "
            if seq.is_multi_drone
            else f"drone {seq.drone_model}; "
        )
        + pose
    )
    return 0


def _raise_terminated(signum: int, _frame: object) -> NoReturn:
    raise SystemExit(128 + signum)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``dronekey-sim``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format=f"{PROG}: %(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    modes = {"--preset": args.preset, "--list-presets": args.list_presets, "--verify": args.verify}
    chosen = [flag for flag, value in modes.items() if value]
    if len(chosen) != 1:
        parser.error(
            f"give exactly one of {', '.join(modes)}" + (f", got {' and '.join(chosen)}" if chosen else "")
        )
    in_main_thread = threading.current_thread() is threading.main_thread()
    previous_int, previous_term = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        if in_main_thread:
            # SIGTERM cleans up like Ctrl-C (the writer removes its temporaries). SIGINT is set too:
            # a process started from a background job (`cmd &` in a script) inherits it ignored, and
            # Python then keeps it so, but a SIGINT sent to a render must still stop it cleanly.
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, _raise_terminated)
        if args.list_presets:
            return _list_presets()
        if args.verify is not None:
            return _verify(args)
        return _render(args)
    except (
        UsageError,
        SequenceFormatError,
        FrameSourceError,
        CalibrationError,
        DroneSpecError,
        FileNotFoundError,
    ) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        cleaned = "; no partial files were left" if args.preset else ""
        print(f"\n{PROG}: interrupted{cleaned}", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        if in_main_thread:
            signal.signal(signal.SIGINT, previous_int)
            signal.signal(signal.SIGTERM, previous_term)


if __name__ == "__main__":
    sys.exit(main())
