"""``dronekey-sim --codec`` / ``--bitrate``: the H.264 file decodes with PyAV (frame count, codec,
pixel format, size, timestamps, bitrate near the target), mp4v stays OpenCV's writer, and bad
combinations are one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from test_sim_cli import run_cli

from dronekey.sim_replay.io.h264_video import H264VideoSink, default_bitrate_bps, probe_video

SMALL = ["--width", "480", "--height", "270"]
FRAMES = 30


@pytest.fixture(scope="module")
def h264_clip(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("h264")
    assert run_cli(["--preset", "seq13", "--out", str(out), "--frames", str(FRAMES), *SMALL]) == 0
    return out


def test_default_is_h264_that_pyav_decodes_frame_by_frame(h264_clip, capsys):
    video = h264_clip / "seq13.mp4"
    assert probe_video(video) == ("h264", FRAMES, (480, 270))
    with av.open(str(video)) as container:
        stream = container.streams.video[0]
        frames = list(container.decode(stream))
        assert stream.codec_context.pix_fmt == "yuv420p"
        assert round(float(stream.average_rate)) == 30
        pts_s = [float(f.pts * f.time_base) for f in frames]
    assert pts_s == pytest.approx([i / 30 for i in range(FRAMES)], abs=1e-3)
    doc = json.loads((h264_clip / "seq13.json").read_text())
    assert [img["file_name"] for img in doc["images"]][-1] == f"seq13.mp4#{FRAMES - 1}"
    # OpenCV (the daemon's fallback reader) decodes it too.
    cap = cv2.VideoCapture(str(video))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == FRAMES
    cap.release()


def test_the_same_seed_gives_the_same_video_bytes(h264_clip, tmp_path):
    # libx264's frame threads plan VBV from frames still in flight, so a threaded encode differs
    # from run to run (and so did every figure measured on a fresh render of "the same" seed).
    assert run_cli(["--preset", "seq13", "--out", str(tmp_path), "--frames", str(FRAMES), *SMALL]) == 0
    assert (tmp_path / "seq13.mp4").read_bytes() == (h264_clip / "seq13.mp4").read_bytes()


def test_the_encoder_gives_the_same_bytes_every_time(tmp_path):
    # Threaded, libx264 gave two or three different files in eight encodes of the same frames.
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, (270, 480, 3), dtype=np.uint8)
    frames = [np.roll(base, 4 * k, axis=1) for k in range(40)]  # texture in motion
    files = []
    for run in range(6):
        sink = H264VideoSink(tmp_path / f"run{run}.mp4", 30.0, (480, 270))
        for k, frame in enumerate(frames):
            sink.write(k, frame, "run")
        sink.close()
        files.append((tmp_path / f"run{run}.mp4").read_bytes())
    assert all(f == files[0] for f in files)


def test_bitrate_follows_the_flag(tmp_path, capsys):
    low, high = tmp_path / "low", tmp_path / "high"
    for out, rate in ((low, "150k"), (high, "3M")):
        argv = ["--preset", "seq13", "--out", str(out), "--frames", "60", *SMALL, "--bitrate", rate]
        assert run_cli(argv) == 0
    assert "480x270, h264 3.00 Mbit/s, " in capsys.readouterr().out
    size_low, size_high = ((d / "seq13.mp4").stat().st_size for d in (low, high))
    seconds = 60 / 30
    # Rate control lands near the target over two seconds (the small first GOP aside).
    assert size_low * 8 / seconds < 400_000
    assert size_high > 3 * size_low


def test_default_bitrate_scales_with_pixel_rate():
    assert default_bitrate_bps((1920, 1080), 30) == 8_000_000
    assert default_bitrate_bps((480, 270), 30) == 500_000
    assert default_bitrate_bps((1920, 1080), 60) == 16_000_000


def test_mp4v_is_kept(tmp_path):
    argv = ["--preset", "seq13", "--out", str(tmp_path), "--frames", "8", *SMALL, "--codec", "mp4v"]
    assert run_cli(argv) == 0
    codec, count, size = probe_video(tmp_path / "seq13.mp4")
    assert (codec, count, size) == ("mpeg4", 8, (480, 270))


@pytest.mark.parametrize(
    ("extra", "codec"), [([], "h264"), (["--codec", "mp4v"], "mpeg4"), (["--cameras", "2"], "h264")]
)
def test_swarms_and_camera_rigs_take_the_codec_too(tmp_path, extra, codec):
    # Until the forty-first session a scene (swarm, --cameras, --drones) wrote mp4v whatever was asked.
    argv = ["--preset", "swarm", "--drones", "2", "--out", str(tmp_path), "--frames", "6", *SMALL, *extra]
    assert run_cli(argv) == 0
    videos = sorted(tmp_path.rglob("*.mp4"))
    assert len(videos) == (2 if "--cameras" in extra else 1)
    assert [probe_video(v)[0] for v in videos] == [codec] * len(videos)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--codec", "vp9"], "argument --codec: invalid choice: 'vp9'"),
        (["--bitrate", "fast"], "argument --bitrate: must be a bitrate such as 8M or 800k, got 'fast'"),
        (["--bitrate", "5"], "argument --bitrate: must be between 10k and 1000M bit/s, got '5'"),
        (["--codec", "mp4v", "--bitrate", "8M"], "--bitrate applies to --codec h264"),
        (["--images", "--codec", "h264"], "--images writes PNG frames instead"),
        (["--width", "481", "--height", "270"], "--codec h264 needs an even --width and --height"),
    ],
)
def test_bad_codec_flags_are_one_line_errors(tmp_path, capsys, extra, message):
    argv = ["--preset", "seq13", "--out", str(tmp_path), "--frames", "2", *extra]
    if "--width" not in extra:
        argv += SMALL
    assert run_cli(argv) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not list(tmp_path.iterdir())
