"""Frame sources on the capture thread, with real decoding: H.264 / MPEG-4 / MJPEG files with their
presentation timestamps, corrupt frames skipped and counted (MJPEG, and frames lost in a damaged
MPEG-TS), truncated files called truncated, image folders (odd-sized images skipped), looping,
realtime pacing, back-pressure for files, drop-oldest for live queues, sidecar calibrations."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from daemon_media import FPS, damage_mjpeg_frames, damage_ts_packets, encode_clip, pattern_frame

from dronekey.daemon.config.source import SourceConfig
from dronekey.daemon.errors import UsageError
from dronekey.daemon.sources import (
    Capture,
    CapturedFrame,
    CaptureStats,
    FrameQueue,
    SourceOpenError,
    SourceState,
    make_reader,
)
from dronekey.daemon.sources.capture import pace_start
from dronekey.daemon.sources.image_folder import ImageFolderReader
from dronekey.daemon.sources.opencv_readers import (
    NetworkStreamReader,
    V4l2Reader,
    VideoFileReader,
    redact_url,
)
from dronekey.daemon.sources.sim import SimReader
from dronekey.daemon.sources.truncation import truncation
from dronekey.geometry.camera import CameraModel
from dronekey.types import Frame


def drain(capture: Capture, timeout_s: float = 30.0, delay_s: float = 0.0) -> list[CapturedFrame]:
    """Every frame until the source ends (a consumer that takes ``delay_s`` per frame)."""
    frames = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        item = capture.get(0.1)
        if item is not None:
            frames.append(item)
            time.sleep(delay_s)
        elif capture.finished:
            return frames
    raise AssertionError(f"source did not end within {timeout_s} s (state {capture.state})")


def take(capture: Capture, n: int) -> list[CapturedFrame]:
    """The first ``n`` frames of a started capture (each within a second), then stop it."""
    items = []
    while len(items) < n:
        item = capture.get(1.0)
        assert item is not None, capture.state
        items.append(item)
    capture.stop()
    return items


@pytest.fixture(scope="module")
def media(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("media")
    encode_clip(folder / "h264.mp4", "libx264", frames=30)
    encode_clip(folder / "mpeg4.mp4", "mpeg4", frames=30)
    encode_clip(folder / "mjpeg.avi", "mjpeg", frames=30)
    encode_clip(folder / "h264.ts", "libx264", frames=60, options={"g": "10"})
    encode_clip(folder / "faststart.mp4", "libx264", frames=60, container_options={"movflags": "faststart"})
    return folder


@pytest.mark.parametrize("name", ["h264.mp4", "mpeg4.mp4", "mjpeg.avi"])
def test_file_frames_in_order_with_stream_timestamps(media, name):
    capture = Capture(VideoFileReader(media / name), SourceConfig(uri=name))
    capture.start()
    frames = drain(capture)
    assert [f.frame.index for f in frames] == list(range(30))
    t_ns = np.array([f.frame.t_ns for f in frames])
    np.testing.assert_allclose(np.diff(t_ns), 1e9 / FPS, atol=1e6)  # PTS, 33.3 ms apart
    assert t_ns[0] == 0
    assert frames[5].frame.bgr.shape == (240, 320, 3)
    assert capture.state == SourceState.ENDED
    stats = capture.stats()
    assert (stats.frames, stats.dropped, stats.corrupt) == (30, 0, 0)


def test_corrupt_frames_in_a_file_are_counted_and_skipped(media, tmp_path):
    damaged = damage_mjpeg_frames(media / "mjpeg.avi", tmp_path / "damaged.avi", [5, 11, 12, 20])
    capture = Capture(VideoFileReader(damaged), SourceConfig(uri=str(damaged)))
    capture.start()
    frames = drain(capture)
    stats = capture.stats()
    assert stats.corrupt == 4 and stats.frames == 26
    assert capture.state == SourceState.ENDED
    indices = [f.frame.index for f in frames]
    assert indices == [i for i in range(30) if i not in (5, 11, 12, 20)]  # indices stay frame numbers
    # the frame after a damaged one is the right picture, with its own timestamp
    after = next(f for f in frames if f.frame.index == 13)
    assert after.frame.t_ns == pytest.approx(13e9 / FPS, abs=1e6)
    assert np.abs(after.frame.bgr.astype(int) - pattern_frame(13)).mean() < 12


def test_frames_lost_in_a_corrupt_mpeg_ts_are_counted(media, tmp_path):
    intact = drain_file(media / "h264.ts")
    assert [f.index for f in intact[0]] == list(range(60)) and intact[1].corrupt == 0
    packets = (media / "h264.ts").stat().st_size // 188
    # At the start (the first keyframe), and mid-way (B-frames: some come out late, after the hole).
    for first in (5, packets // 3, packets // 2):
        damaged = damage_ts_packets(media / "h264.ts", tmp_path / "damaged.ts", first, 30)
        frames, stats = drain_file(damaged)
        assert 0 < stats.frames < 60 and stats.frames + stats.corrupt == 60, stats  # all accounted for
        assert frames[-1].index == 59
        for f in frames:  # in order, and indices stay frame numbers across the hole
            assert f.index == round(f.t_ns * FPS / 1e9)
        assert truncation(damaged) is None  # damaged, not cut short


def test_variable_frame_rate_gaps_are_not_lost_frames(tmp_path):
    # 20, 20, 60 ms: about 30 fps on average, so each 60 ms step looks like one frame lost.
    clip = encode_clip(tmp_path / "vfr.mp4", "libx264", frames=30, intervals_ms=(20, 20, 60))
    frames, stats = drain_file(clip)
    assert (stats.frames, stats.corrupt) == (30, 0)
    assert [f.index for f in frames] == list(range(30))


def drain_file(path: Path) -> tuple[list[Frame], CaptureStats]:
    """Every frame of a video file, and the capture's counters at its end."""
    capture = Capture(VideoFileReader(path), SourceConfig(uri=str(path)))
    capture.start()
    frames = [item.frame for item in drain(capture)]
    return frames, capture.stats()


def test_truncated_files_are_called_truncated(media, tmp_path, caplog):
    for name in ("h264.mp4", "mpeg4.mp4", "mjpeg.avi", "h264.ts", "faststart.mp4"):
        assert truncation(media / name) is None, name

    def cut(name: str) -> Path:
        data = (media / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) // 2])
        return tmp_path / name

    # The MP4 index (moov) is written last: half a file cannot be opened, and says why.
    with pytest.raises(
        SourceOpenError, match=r"h264.mp4: the file is truncated \(its mdat box at byte \d+ needs"
    ):
        VideoFileReader(cut("h264.mp4")).open()
    # With the index first (faststart) or in an AVI, the frames it holds are read, with a warning.
    for name, whole in (("faststart.mp4", 60), ("mjpeg.avi", 30)):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="dronekey.daemon.sources.opencv_readers"):
            frames, _ = drain_file(cut(name))
        assert 0 < len(frames) < whole
        assert f"{name} is truncated" in caplog.text and "reading the frames it holds" in caplog.text
    ts = cut("h264.ts")
    if ts.stat().st_size % 188:
        assert "inside an MPEG-TS packet" in truncation(ts)


def test_file_back_pressure_never_drops(media):
    capture = Capture(VideoFileReader(media / "h264.mp4"), SourceConfig(uri="x", queue_size=1))
    capture.start()
    frames = drain(capture, delay_s=0.01)  # slower consumer than the decoder
    assert len(frames) == 30 and capture.stats().dropped == 0


def test_loop_keeps_timestamps_increasing_and_realtime_paces(media):
    config = SourceConfig(uri="x", loop=True, realtime=True)
    capture = Capture(VideoFileReader(media / "h264.mp4"), config)
    started = time.monotonic()
    capture.start()
    frames = [item.frame for item in take(capture, 45)]
    elapsed = time.monotonic() - started
    t_ns = np.array([f.t_ns for f in frames])
    assert np.all(np.diff(t_ns) > 0)
    np.testing.assert_allclose(np.diff(t_ns), 1e9 / FPS, atol=1e6)  # no jump at the wrap-around
    assert [f.index for f in frames] == list(range(45))
    assert elapsed >= 1.2  # 44 frame intervals at 30 fps is 1.47 s; without pacing this takes ~0.2 s


@pytest.mark.parametrize("phase", [0.0, 0.5])
def test_realtime_phase_releases_frames_on_the_monotonic_clocks_frame_grid(media, phase):
    """``realtime_phase``: every paced frame leaves the capture ``phase`` of a frame interval into
    the monotonic clock's frame-rate grid (the median offset within a few ms: the release is a
    timed wait), whenever the capture started."""
    interval_ns = round(1e9 / FPS)
    config = SourceConfig(uri="x", realtime=True, realtime_phase=phase)
    capture = Capture(VideoFileReader(media / "h264.mp4"), config)
    time.sleep(0.0137)  # start off the grid
    capture.start()
    released = [item.t_arrival_mono_ns for item in take(capture, 20)]
    offsets = (np.array(released) - round(phase * interval_ns)) % interval_ns
    offsets = np.where(offsets > interval_ns / 2, offsets - interval_ns, offsets)  # wrapped to +-half
    assert abs(np.median(offsets)) < 5e6, offsets / 1e6


def test_a_paced_frame_arrives_when_it_is_due_however_late_it_is_handed_over(media):
    """A paced frame's latency origin is its due time on the pacing clock: behind a consumer three
    times slower than the clip, the origins stay one frame interval apart while the frames are
    handed over ever later, so the lateness counts in the latency instead of moving its origin."""
    config = SourceConfig(uri="x", realtime=True, queue_size=1)
    capture = Capture(VideoFileReader(media / "h264.mp4"), config)
    capture.start()
    frames = drain(capture, delay_s=3 / FPS)
    origins = np.array([item.t_arrival_mono_ns for item in frames])
    np.testing.assert_allclose(np.diff(origins), 1e9 / FPS, atol=1e3)  # the grid, not the hand-over
    assert time.monotonic_ns() - origins[-1] > 0.5e9  # the last frame was due long before it was taken


class _TimedReader(VideoFileReader):
    """A file reader that notes when each decode starts (``time.monotonic_ns()``)."""

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        self.read_starts: list[int] = []

    def read(self):
        self.read_starts.append(time.monotonic_ns())
        return super().read()


@pytest.mark.parametrize("ahead", [False, True])
def test_a_paced_frame_is_decoded_once_it_is_due_unless_decoded_ahead(media, ahead):
    """A paced frame is decoded once it is due, as a camera's compressed stream is, so its decode
    counts in the latency; ``realtime_decode_ahead`` decodes it a frame interval before instead."""
    reader = _TimedReader(media / "h264.mp4")
    capture = Capture(reader, SourceConfig(uri="x", realtime=True, realtime_decode_ahead=ahead))
    capture.start()
    items = take(capture, 12)
    lead_ms = (np.array([item.t_arrival_mono_ns for item in items[1:]]) - reader.read_starts[1:12]) / 1e6
    if ahead:
        assert np.all(lead_ms > 10), lead_ms  # decoded while the previous frame waited its turn
    else:
        assert np.all(lead_ms <= 0.5), lead_ms  # decoded only once due


def test_pace_start_is_the_next_grid_instant_of_the_phase_or_now_without_one():
    interval_ns = 33_333_333
    assert pace_start(12.3456, interval_ns, None) == 12.3456
    start = pace_start(12.3456, interval_ns, 0.25)
    assert 12.3456 <= start < 12.3456 + interval_ns / 1e9
    assert (start / (interval_ns / 1e9) - 0.25) % 1.0 == pytest.approx(0.0, abs=1e-6)
    assert pace_start(1.0, 500_000_000, 0.0) == 1.0  # already on the grid


def test_realtime_phase_outside_a_frame_interval_is_refused():
    for bad in (-0.1, 1.0, 1.5):
        with pytest.raises(ValueError, match="realtime_phase"):
            SourceConfig(uri="x", realtime=True, realtime_phase=bad)


def test_image_folder_in_natural_order_with_a_corrupt_image(tmp_path):
    for i in (1, 2, 10):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), pattern_frame(i))
    (tmp_path / "frame_3.png").write_bytes(b"not a png")
    (tmp_path / "notes.txt").write_text("ignored")
    capture = Capture(ImageFolderReader(tmp_path, fps=10.0), SourceConfig(uri=str(tmp_path)))
    capture.start()
    frames = drain(capture)
    assert [f.frame.index for f in frames] == [0, 1, 3]  # frame_1, frame_2, (frame_3 corrupt), frame_10
    assert [f.frame.t_ns for f in frames] == [0, 100_000_000, 300_000_000]
    assert np.array_equal(frames[2].frame.bgr, pattern_frame(10))
    assert capture.stats().corrupt == 1


def test_odd_sized_image_in_a_folder_is_skipped_with_a_warning(tmp_path, caplog):
    for i in range(5):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), pattern_frame(i))
    cv2.imwrite(str(tmp_path / "frame_2.png"), pattern_frame(2, width=160, height=120))  # same aspect
    cv2.imwrite(str(tmp_path / "frame_3.png"), pattern_frame(3, width=200, height=240))  # another one
    capture = Capture(ImageFolderReader(tmp_path, fps=10.0), SourceConfig(uri=str(tmp_path)))
    with caplog.at_level(logging.WARNING, logger="dronekey.daemon.sources.image_folder"):
        capture.start()
        frames = drain(capture)
    assert [f.frame.index for f in frames] == [0, 1, 4] and capture.state == SourceState.ENDED
    assert all(f.frame.bgr.shape == (240, 320, 3) for f in frames)
    assert capture.stats().corrupt == 2
    assert "frame_2.png is 160x120, not the folder's 320x240: skipped" in caplog.text
    assert "frame_3.png is 200x240" in caplog.text


def test_unreadable_sources_fail_to_open(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "garbage.mp4").write_bytes(b"\x00" * 1000)
    for reader, message in [
        (VideoFileReader(tmp_path / "absent.mp4"), "not found"),
        (VideoFileReader(tmp_path / "garbage.mp4"), "cannot open"),
        (ImageFolderReader(tmp_path / "empty", fps=30), "holds no image"),
    ]:
        capture = Capture(reader, SourceConfig(uri="x"))
        with pytest.raises(Exception, match=message):
            capture.open()


def test_live_queue_drops_the_oldest():
    queue = FrameQueue(2, drop_oldest=True)
    stop = threading.Event()
    for i in range(5):
        queue.put(CapturedFrame(Frame(i, i, np.zeros((1, 1, 3), np.uint8)), 0), stop)
    assert queue.dropped == 3
    assert [queue.get(0.01).frame.index for _ in range(2)] == [3, 4]
    assert queue.get(0.01) is None


def test_make_reader_picks_the_reader(tmp_path, media):
    def reader(uri: str):  # the OpenCV readers; source.decoder auto/pyav: tests/daemon/test_pyav_reader.py
        return make_reader(SourceConfig(uri=uri, decoder="opencv"))

    assert isinstance(reader("sim://seq13"), SimReader)
    assert isinstance(reader("rtsp://user:secret@cam.local:554/stream"), NetworkStreamReader)
    assert isinstance(reader("tcp://127.0.0.1:5000"), NetworkStreamReader)
    assert reader("rtsp://user:secret@cam.local:554/stream").description == "rtsp://***@cam.local:554/stream"
    assert isinstance(reader("/dev/video0"), V4l2Reader) and reader("2").description == "/dev/video2"
    assert isinstance(reader(str(tmp_path)), ImageFolderReader)
    assert isinstance(reader(str(media / "h264.mp4")), VideoFileReader)
    assert isinstance(reader(f"file://{media / 'h264.mp4'}"), VideoFileReader)
    with pytest.raises(UsageError, match="unknown scheme"):
        reader("gopher://x")
    with pytest.raises(UsageError, match="no source"):
        make_reader(SourceConfig())
    assert redact_url("http://host/x") == "http://host/x"


def test_sidecar_calibration_beside_the_video(tmp_path, media):
    from dronekey.sim_replay.annotations import SequenceAnnotations
    from dronekey.sim_replay.io.sequence_writer import save_sequence

    clip = tmp_path / "seq.mp4"
    clip.write_bytes((media / "h264.mp4").read_bytes())
    assert VideoFileReader(clip).bundled_camera() is None
    CameraModel.from_fov(640, 480, 60).save_yaml(tmp_path / "camera.yaml")
    camera, origin = VideoFileReader(clip).bundled_camera()
    assert camera.width == 640 and "camera.yaml" in origin
    sequence_camera = CameraModel.from_fov(320, 240, 50)
    save_sequence(
        SequenceAnnotations("seq", sequence_camera, "mini2", np.zeros((4, 3)), 30.0), tmp_path / "seq.json"
    )
    camera, origin = VideoFileReader(clip).bundled_camera()  # the sequence JSON comes first
    assert camera.width == 320 and camera.fx == pytest.approx(sequence_camera.fx) and "seq.json" in origin


def test_sim_source_renders_the_preset():
    from dronekey.daemon.config.source import SimSettings

    reader = SimReader("seq13", SimSettings(frames=2))
    camera, _ = reader.bundled_camera()
    capture = Capture(reader, SourceConfig(uri="sim://seq13"))
    capture.start()
    frames = drain(capture, timeout_s=60)
    assert len(frames) == 2 and frames[0].frame.bgr.shape == (camera.height, camera.width, 3)
    assert frames[1].frame.t_ns == pytest.approx(1e9 / 30, abs=1)
    with pytest.raises(Exception, match="unknown preset"):
        SimReader("seq99", SimSettings()).open()
