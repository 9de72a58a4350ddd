"""``dronekey-annotate``: draw an MCAP's tracks onto its source video and write H.264.

    dronekey-annotate --mcap run.mcap --video seq13.mp4 --out seq13_annotated.mp4
    dronekey-annotate --mcap run.mcap --video sim://seq13 --out seq13_annotated.mp4

The same picture as ``dronekey-daemon --annotated-video`` (``sinks/annotation_drawing.py``), made
afterwards from a recording. The track messages on ``/dronekey/tracks`` carry the time of the frame
they belong to (``t_ns``: the stream's presentation time for files, the frame time for ``sim://``);
the video is read with the daemon's own readers, so each frame gets the tracks stamped with its time
(within a quarter of a frame interval). A recording of a live source is stamped with Unix time and
cannot be matched to a file this way; the tool says so.

Intrinsics for the body axes: ``--calib FILE``, else the MCAP's ``/camera/calibration`` (JSON or
protobuf), else what travels with the video (sequence JSON, camera.yaml, the sim preset's camera);
without any, only keypoints and labels are drawn. A truncated MCAP (a killed daemon) is read up to
where it ends.
"""

from __future__ import annotations

import argparse
import bisect
import json
import logging
import sys
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader

from dronekey.daemon.calibration import camera_at_resolution
from dronekey.daemon.config.annotated_video import VIDEO_SUFFIXES
from dronekey.daemon.config.source import SourceConfig
from dronekey.daemon.errors import ExitCode, UsageError
from dronekey.daemon.sinks.annotated_video import H264Writer
from dronekey.daemon.sinks.annotation_drawing import TrackOverlay, draw_tracks
from dronekey.daemon.sources import FrameReader, SourceOpenError, make_reader
from dronekey.frame_image import as_frame_image
from dronekey.geometry.camera import CalibrationError, CameraModel

__all__ = ["Recording", "annotate", "main", "read_recording"]

log = logging.getLogger("dronekey.annotate")

TRACKS_TOPIC = "/dronekey/tracks"
CALIBRATION_TOPIC = "/camera/calibration"
_MATCH_SHARE = 0.25  # a frame takes the tracks stamped within this share of a frame interval


class Recording:
    """What the tool needs of an MCAP: track messages by frame time, and the first calibration."""

    def __init__(self) -> None:
        self.tracks: dict[int, list[TrackOverlay]] = defaultdict(list)
        self.calibration: CameraModel | None = None
        self.truncated: str | None = None

    @property
    def times(self) -> list[int]:
        return sorted(self.tracks)


def _decode(schema: Any, channel: Any, data: bytes) -> dict:
    """A message as a dict: JSON directly, protobuf through the schema's own descriptors."""
    if channel.message_encoding == "json":
        return json.loads(data)
    if channel.message_encoding == "protobuf" and schema is not None:
        pool = descriptor_pool.DescriptorPool()
        for proto in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
            pool.Add(proto)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        return json_format.MessageToDict(cls.FromString(data), preserving_proto_field_name=True)
    raise ValueError(f"cannot decode {channel.topic}: message encoding {channel.message_encoding!r}")


def _calibration(message: dict) -> CameraModel:
    K = [message["K"][i : i + 3] for i in (0, 3, 6)]  # row-major 9 values (foxglove.CameraCalibration)
    return CameraModel(int(message["width"]), int(message["height"]), K, message.get("D") or [])


def read_recording(path: Path) -> Recording:
    """Track messages and the first calibration of an MCAP file (read to its end or where it breaks).

    Raises
    ------
    UsageError
        The file cannot be opened or is not an MCAP.
    """
    recording = Recording()
    try:
        stream = open(path, "rb")  # noqa: SIM115 - closed below, after a partial read too
    except OSError as exc:
        raise UsageError(f"--mcap {path}: {exc.strerror or exc}") from None
    with stream:
        messages = NonSeekingReader(stream).iter_messages(topics=[TRACKS_TOPIC, CALIBRATION_TOPIC])
        try:
            for schema, channel, message in messages:
                decoded = _decode(schema, channel, message.data)
                if channel.topic == TRACKS_TOPIC:
                    recording.tracks[int(decoded["t_ns"])].append(TrackOverlay.from_message(decoded))
                elif recording.calibration is None:
                    recording.calibration = _calibration(decoded)
        except (McapError, EOFError) as exc:
            if not recording.tracks and recording.calibration is None:
                raise UsageError(f"--mcap {path}: not a readable MCAP file ({exc})") from None
            recording.truncated = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        except (KeyError, ValueError, CalibrationError) as exc:
            raise UsageError(f"--mcap {path}: a {channel.topic} message is malformed ({exc})") from None
    return recording


def _frames(reader: FrameReader) -> Iterator[tuple[int, Any]]:
    """(t_ns, BGR image) of every frame the reader delivers, in order."""
    while True:
        result = reader.read()
        if result.image is None:
            return
        yield int(result.t_ns), as_frame_image(result.image).bgr().copy()  # drawn on


def _camera(calib: Path | None, recording: Recording, reader: FrameReader, size: tuple[int, int]):
    """The intrinsics at the video's size and where they came from, or (None, why not)."""
    try:
        if calib is not None:
            camera, origin = CameraModel.load(calib), str(calib)
        elif recording.calibration is not None:
            camera, origin = recording.calibration, f"the MCAP's {CALIBRATION_TOPIC}"
        else:
            bundled = reader.bundled_camera()
            if bundled is None:
                return None, "no calibration (--calib, the MCAP or beside the video)"
            camera, origin = bundled
    except CalibrationError as exc:
        raise UsageError(f"calibration: {exc}") from None
    return camera_at_resolution(camera, *size), origin


def annotate(
    mcap: Path,
    video: str,
    out: Path,
    *,
    calib: Path | None = None,
    crf: int = 23,
    preset: str = "veryfast",
    max_frames: int | None = None,
) -> dict:
    """Draw ``mcap``'s tracks onto ``video``'s frames into ``out``; returns the counts it logs.

    Raises
    ------
    UsageError
        A file is missing or unreadable, or no track time matches a frame of the video.
    """
    if out.suffix.lower() not in VIDEO_SUFFIXES:
        raise UsageError(f"--out {out}: must end in {', '.join(VIDEO_SUFFIXES)}")
    recording = read_recording(mcap)
    if recording.truncated:
        log.warning(
            "%s ends early (%s): using the %d frame times it holds",
            mcap,
            recording.truncated,
            len(recording.tracks),
        )
    times = recording.times
    reader = make_reader(SourceConfig(uri=video))
    try:
        reader.open()
    except SourceOpenError as exc:
        raise UsageError(f"--video: {exc}") from None
    try:
        frames = _frames(reader)
        first = next(frames, None)
        if first is None:
            raise UsageError(f"--video {video}: no frame")
        height, width = first[1].shape[:2]
        camera, origin = _camera(calib, recording, reader, (width, height))
        if camera is None:
            log.warning("%s: drawing keypoints and labels without the body axes", origin)
        else:
            log.info("calibration: %s", origin)
        fps = reader.frame_rate
        tolerance_ns = _MATCH_SHARE * 1e9 / (fps or 30.0)
        try:
            writer = H264Writer(out, width, height, fps, crf=crf, preset=preset, threads=0)
        except (OSError, ValueError) as exc:
            raise UsageError(f"--out {out}: {exc}") from None
        counts = {"frames": 0, "frames_with_tracks": 0, "track_times": len(times), "matched_times": 0}
        try:
            for t_ns, image in _chain(first, frames):
                i = bisect.bisect_left(times, t_ns - tolerance_ns)
                overlays = []
                if i < len(times) and abs(times[i] - t_ns) <= tolerance_ns:
                    overlays = recording.tracks[times[i]]
                    counts["matched_times"] += 1
                    counts["frames_with_tracks"] += any(o.status != "lost" for o in overlays)
                draw_tracks(image, overlays, camera)
                writer.write(image, t_ns)
                counts["frames"] += 1
                if max_frames is not None and counts["frames"] >= max_frames:
                    break
        finally:
            writer.close()
    finally:
        reader.close()
    if times and not counts["matched_times"]:
        raise UsageError(
            f"no track time in {mcap} ({times[0] / 1e9:.3f} .. {times[-1] / 1e9:.3f} s) matches a frame "
            f"of {video}: was it recorded from another source? (a live source is stamped with Unix time)"
        )
    return counts


def _chain(first, rest):
    yield first
    yield from rest


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dronekey-annotate",
        description="Draw the tracks of a dronekey-daemon MCAP (/dronekey/tracks) onto the video it was "
        "recorded from and write H.264: keypoints 1-4, body axes (x forward red, y right green, "
        "z down blue), track id, range and heading confidence.",
        epilog="example:\n  dronekey-daemon --source seq13.mp4 --mcap-dir runs\n"
        "  dronekey-annotate --mcap runs/dronekey_cam0_*.mcap --video seq13.mp4 --out seq13_annotated.mp4",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--mcap", metavar="FILE", type=Path, required=True, help="the daemon's MCAP recording")
    p.add_argument(
        "--video",
        metavar="SOURCE",
        required=True,
        help="its source: a video file, image folder or sim://PRESET",
    )
    p.add_argument(
        "--out", metavar="FILE", type=Path, required=True, help="H.264 video to write (.mp4, .mkv, .mov)"
    )
    p.add_argument(
        "--calib",
        metavar="FILE",
        type=Path,
        help="OpenCV calibration YAML (default: the MCAP's, else beside the video)",
    )
    p.add_argument("--max-frames", metavar="N", type=int, help="stop after the first N frames (a preview)")
    p.add_argument(
        "--crf", metavar="N", type=int, default=23, choices=range(52), help="x264 quality, 0-51 (default 23)"
    )
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``dronekey-annotate``; exit 0, or 2 with one line naming the bad argument."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    from dronekey.daemon.sources.opencv_readers import quiet_native_logs

    quiet_native_logs(verbose=False)
    try:
        counts = annotate(
            args.mcap, args.video, args.out, calib=args.calib, crf=args.crf, max_frames=args.max_frames
        )
    except UsageError as exc:
        log.error("%s", exc)
        return ExitCode.USAGE
    log.info(
        "%s: %d frames, %d with tracks drawn; %d of %d track times matched a frame",
        args.out,
        counts["frames"],
        counts["frames_with_tracks"],
        counts["matched_times"],
        counts["track_times"],
    )
    return ExitCode.OK


if __name__ == "__main__":
    sys.exit(main())
