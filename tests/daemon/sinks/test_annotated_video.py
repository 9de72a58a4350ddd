"""The annotated video: what is drawn (keypoints in order, axes, label), the H.264 file PyAV reads
back (codec, pixel format, rate, frame count), frames dropped and counted instead of stalling the
pipeline, and the daemon's --annotated-video plus dronekey-annotate on its MCAP, end to end."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import av
import numpy as np
import pytest
from factories import make_track

from dronekey.daemon.annotate import annotate
from dronekey.daemon.config.annotated_video import AnnotatedVideoConfig
from dronekey.daemon.errors import ExitCode
from dronekey.daemon.sinks.annotated_video import AnnotatedVideoSink, H264Writer, fresh_video_path
from dronekey.daemon.sinks.annotation_drawing import (
    KEYPOINT_COLOURS_BGR,
    TrackOverlay,
    draw_tracks,
    track_label,
)
from dronekey.daemon.sinks.base import FrameUpdate, SinkWorker
from dronekey.geometry.camera import CameraModel

CAMERA = CameraModel.from_fov(640, 480, 60)
KEYPOINTS = np.array([[340.0, 230.0], [340.0, 250.0], [300.0, 250.0], [300.0, 230.0]])


def probe(path: Path) -> tuple[str, str, float, int]:
    """(codec, pixel format, average frame rate, decoded frames) as PyAV reads the file."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = sum(1 for _ in container.decode(stream))
        return stream.codec_context.name, stream.codec_context.pix_fmt, float(stream.average_rate), frames


def near(image: np.ndarray, uv, colour, radius: int = 2) -> bool:
    u, v = (int(round(c)) for c in uv)
    patch = image[v - radius : v + radius + 1, u - radius : u + radius + 1].reshape(-1, 3).astype(int)
    return bool(np.any(np.abs(patch - np.array(colour)).sum(axis=1) < 60))


# ------------------------------------------------------------------------------ drawing
def test_keypoints_axes_and_label_are_drawn():
    track = make_track(3, position_m=(0.0, 0.0, 10.0), keypoints_px=KEYPOINTS, heading_confidence=0.82)
    image = np.zeros((480, 640, 3), np.uint8)
    draw_tracks(image, [TrackOverlay.from_track(track)], CAMERA)
    for uv, colour in zip(KEYPOINTS, KEYPOINT_COLOURS_BGR, strict=True):
        assert near(image, uv, colour), f"keypoint at {uv} not drawn in {colour}"
    # identity attitude (body axes = camera axes), 10 m ahead: x (red) right, y (green) down, z (blue) away
    image = np.zeros((480, 640, 3), np.uint8)
    draw_tracks(image, [TrackOverlay.from_track(make_track(3, position_m=(0.0, 0.0, 10.0)))], CAMERA)
    centre = CAMERA.project(np.array([[0.0, 0.0, 10.0]]))[0]
    right = image[int(centre[1]) - 1 : int(centre[1]) + 2, int(centre[0]) + 15 : int(centre[0]) + 40]
    below = image[int(centre[1]) + 15 : int(centre[1]) + 40, int(centre[0]) - 1 : int(centre[0]) + 2]
    assert (right[..., 2] > 150).any() and (right[..., 1] < 100).all(), "x axis (red) points right"
    assert (below[..., 1] > 150).any() and (below[..., 2] < 100).all(), "y axis (green) points down"
    assert track_label(TrackOverlay.from_track(track)) == "#3 confirmed 10.0 m  heading 0.82"
    unsure = make_track(4, position_m=(0.0, 0.0, 10.0), heading_confidence=0.3)
    assert track_label(TrackOverlay.from_track(unsure)).endswith("heading ?")
    unknown = make_track(5, position_m=(0.0, 0.0, 10.0), heading_confidence=math.nan)
    assert track_label(TrackOverlay.from_track(unknown)).endswith("heading ?")


def test_a_track_message_draws_like_its_track():
    from dronekey.daemon.messages import to_json_bytes, track_message

    track = make_track(3, position_m=(0.5, -0.2, 12.0), keypoints_px=KEYPOINTS, heading_confidence=0.9)
    import json

    message = json.loads(to_json_bytes(track_message(track, "cam0")))
    from_track, from_message = (np.zeros((480, 640, 3), np.uint8) for _ in range(2))
    draw_tracks(from_track, [TrackOverlay.from_track(track)], CAMERA)
    draw_tracks(from_message, [TrackOverlay.from_message(message)], CAMERA)
    assert np.array_equal(from_track, from_message)


# ------------------------------------------------------------------------------ encoding
def test_h264_file_reads_back_with_the_source_rate(tmp_path):
    writer = H264Writer(tmp_path / "v.mp4", 641, 480, 25.0)  # odd width: cut to 640
    frame = np.full((480, 641, 3), 90, np.uint8)
    for i in range(20):
        writer.write(frame, i * 40_000_000)
    writer.close()
    assert probe(tmp_path / "v.mp4") == ("h264", "yuv420p", 25.0, 20)


def test_a_second_video_of_one_run_does_not_overwrite_the_first(tmp_path):
    first = tmp_path / "out.mp4"
    first.write_bytes(b"written by this process")
    assert fresh_video_path(first) == tmp_path / "out.2.mp4"


def test_slow_encoding_drops_and_counts_frames_without_stalling(tmp_path):
    camera = CameraModel.from_fov(1920, 1080, 70)
    config = AnnotatedVideoConfig(path=tmp_path / "a.mp4", preset="medium", threads=1, queue_frames=2)
    worker = SinkWorker(AnnotatedVideoSink(config, camera, 30.0), max_queue=config.queue_frames)
    rng = np.random.default_rng(0)
    frame = rng.integers(0, 255, (1080, 1920, 3), dtype=np.uint8)  # noise: the slowest to encode
    frame.flags.writeable = False
    for i in range(40):
        worker.submit_update(FrameUpdate("cam0", i, i * 33_333_333, time.monotonic_ns(), image=frame))
    worker.close(timeout_s=30)
    stats = worker.stats
    # Frames were dropped, not waited for: a submit that waited for the encoder would never drop one.
    assert stats.dropped > 0 and stats.published + stats.dropped == 40
    assert probe(tmp_path / "a.mp4")[3] == stats.published


# ------------------------------------------------------------------------------ end to end
@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """dronekey-daemon on sim://seq13 (shipped model), 20 frames, with --annotated-video and MCAP."""
    folder = tmp_path_factory.mktemp("run")
    result = subprocess.run(
        [sys.executable, "-m", "dronekey.daemon.cli", "--source", "sim://seq13", "--max-frames", "20",
         "--no-zenoh", "--no-mavlink", "--mcap-dir", str(folder / "mcap"),
         "--annotated-video", str(folder / "live.mp4")],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert result.returncode == ExitCode.OK, result.stderr
    assert "annotated_video 20 published 0 dropped" in result.stderr, result.stderr
    return folder


def test_daemon_writes_every_frame_as_h264(recorded):
    assert probe(recorded / "live.mp4") == ("h264", "yuv420p", 30.0, 20)


def test_dronekey_annotate_draws_the_mcap_onto_its_source(recorded, tmp_path):
    (mcap,) = (recorded / "mcap").glob("*.mcap")
    out = tmp_path / "offline.mp4"
    counts = annotate(mcap, "sim://seq13", out, max_frames=20)
    assert counts["frames"] == 20 and counts["matched_times"] == counts["track_times"] > 0
    assert counts["frames_with_tracks"] > 0
    assert probe(out) == ("h264", "yuv420p", 30.0, 20)
    with av.open(str(out)) as offline, av.open(str(recorded / "live.mp4")) as live:
        a = [f.to_ndarray(format="bgr24").astype(int) for f in offline.decode(video=0)]
        b = [f.to_ndarray(format="bgr24").astype(int) for f in live.decode(video=0)]
    # the same drawing from the same tracks: equal up to the encoder's noise
    assert np.mean([np.abs(x - y).mean() for x, y in zip(a, b, strict=True)]) < 2.0


def test_dronekey_annotate_bad_output_name_is_one_line(recorded, tmp_path):
    (mcap,) = (recorded / "mcap").glob("*.mcap")
    result = subprocess.run(
        [sys.executable, "-m", "dronekey.daemon.annotate", "--mcap", str(mcap), "--video", "sim://seq13",
         "--out", str(tmp_path / "x.avi")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert result.returncode == ExitCode.USAGE
    errors = [line for line in result.stderr.splitlines() if line.startswith("ERROR")]
    assert len(errors) == 1 and "--out" in errors[0] and ".mp4" in errors[0], result.stderr
