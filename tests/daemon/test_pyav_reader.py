"""The PyAV readers against the same media as the OpenCV ones (tests/daemon/test_daemon_sources.py):
frames in order with their stream timestamps, corrupt MJPEG frames and damaged MPEG-TS packets
counted, variable frame rates, truncated files, loops; a real MPEG-TS server over 127.0.0.1 for the
stream reader; make_reader's choice (source.decoder) and its fallback to OpenCV; the thread rule."""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from daemon_media import (
    FPS,
    damage_mjpeg_frames,
    damage_ts_packets,
    encode_clip,
    free_port,
    pattern_frame,
    start_server,
    stop_process,
)
from test_daemon_sources import drain
from test_daemon_sources import media as media  # the same clips (a fixture, found by its name)

from dronekey.daemon.config.source import NetworkSettings, SourceConfig
from dronekey.daemon.sources import Capture, CaptureStats, SourceOpenError, SourceState, make_reader
from dronekey.daemon.sources.fallback import FirstThatOpens
from dronekey.daemon.sources.opencv_readers import NetworkStreamReader, V4l2Reader, VideoFileReader
from dronekey.daemon.sources.pyav_reader import (
    FAST_DECODE_OPTIONS,
    PyAVFileReader,
    PyAVStreamReader,
    image_from_frame,
    pyav_decode_threads,
)
from dronekey.frame_image import I420Image, as_frame_image
from dronekey.types import Frame


def drain_file(path: Path) -> tuple[list[Frame], CaptureStats]:
    capture = Capture(PyAVFileReader(path), SourceConfig(uri=str(path)))
    capture.start()
    frames = [item.frame for item in drain(capture)]
    return frames, capture.stats()


@pytest.mark.parametrize("name", ["h264.mp4", "mpeg4.mp4", "mjpeg.avi"])
def test_file_frames_in_order_with_stream_timestamps(media, name):
    frames, stats = drain_file(media / name)
    assert [f.index for f in frames] == list(range(30))
    t_ns = np.array([f.t_ns for f in frames])
    assert t_ns[0] == 0
    np.testing.assert_allclose(np.diff(t_ns), 1e9 / FPS, atol=1e6)
    assert frames[5].bgr.shape == (240, 320, 3) and frames[5].bgr.dtype == np.uint8
    assert np.abs(frames[5].bgr.astype(int) - pattern_frame(5)).mean() < 12  # the right picture, BGR
    assert (stats.frames, stats.dropped, stats.corrupt) == (30, 0, 0)


def test_same_pictures_and_timestamps_as_opencv(media):
    ours, _ = drain_file(media / "h264.mp4")
    capture = Capture(VideoFileReader(media / "h264.mp4"), SourceConfig(uri="x"))
    capture.start()
    theirs = [item.frame for item in drain(capture)]
    assert [f.t_ns for f in ours] == [f.t_ns for f in theirs]
    for a, b in zip(ours, theirs, strict=True):
        assert np.abs(a.bgr.astype(int) - b.bgr.astype(int)).mean() < 2  # swscale vs OpenCV's conversion


def test_fast_decode_skips_deblocking_and_stays_close_to_the_standard_decode(media):
    """source.fast_decode (the default) hands FFmpeg the no-deblocking options; the pictures stay
    within a grey level or two of a conformant decode, and false decodes to the standard."""
    import av

    with av.open(str(media / "h264.mp4")) as container:
        standard = [as_frame_image(image_from_frame(f)).bgr() for f in container.decode(video=0)]
    fast, _ = drain_file(media / "h264.mp4")
    capture = Capture(PyAVFileReader(media / "h264.mp4", fast_decode=False), SourceConfig(uri="x"))
    capture.start()
    conformant = [item.frame.bgr for item in drain(capture)]
    assert all(np.array_equal(a, b) for a, b in zip(conformant, standard, strict=True))
    diffs = [np.abs(a.bgr.astype(int) - b.astype(int)).mean() for a, b in zip(fast, standard, strict=True)]
    assert 0.0 < max(diffs) < 2.0  # the deblocking filter was skipped, and the picture is the same
    assert make_reader(SourceConfig(uri=str(media / "h264.mp4"), decoder="pyav")).fast_decode
    assert FAST_DECODE_OPTIONS == {"skip_loop_filter": "all", "flags2": "+fast"}


def test_planes_handed_over_match_swscale_and_other_formats_take_swscale(media):
    import av

    with av.open(str(media / "h264.mp4")) as container:
        frame = next(container.decode(video=0))
    assert frame.format.name == "yuv420p"
    swscale = frame.to_ndarray(format="bgr24")
    image = image_from_frame(frame)  # the planes, converted by OpenCV where a stage asks
    assert isinstance(image, I420Image) and image.size == (frame.width, frame.height)
    ours = image.bgr()
    assert ours.shape == swscale.shape and ours.dtype == np.uint8
    assert np.abs(ours.astype(int) - swscale.astype(int)).max() <= 3
    for other in (
        frame.reformat(format="yuvj420p"),
        frame.reformat(format="nv12"),
        frame.reformat(width=319),
    ):
        assert np.array_equal(image_from_frame(other), other.to_ndarray(format="bgr24"))


def test_the_reader_hands_the_pipeline_the_planes(media):
    frames, _ = drain_file(media / "h264.mp4")
    assert all(isinstance(f.image, I420Image) for f in frames)
    assert frames[3].size == (320, 240) and not frames[3].bgr.flags.writeable


def test_corrupt_mjpeg_frames_are_counted_and_skipped(media, tmp_path):
    damaged = damage_mjpeg_frames(media / "mjpeg.avi", tmp_path / "damaged.avi", [5, 11, 12, 20])
    frames, stats = drain_file(damaged)
    assert (stats.frames, stats.corrupt) == (26, 4)
    assert [f.index for f in frames] == [i for i in range(30) if i not in (5, 11, 12, 20)]
    after = next(f for f in frames if f.index == 13)
    assert after.t_ns == pytest.approx(13e9 / FPS, abs=1e6)
    assert np.abs(after.bgr.astype(int) - pattern_frame(13)).mean() < 12


def test_frames_lost_in_a_corrupt_mpeg_ts_are_counted(media, tmp_path):
    intact, stats = drain_file(media / "h264.ts")
    assert [f.index for f in intact] == list(range(60)) and stats.corrupt == 0
    packets = (media / "h264.ts").stat().st_size // 188
    for first in (5, packets // 3, packets // 2):
        damaged = damage_ts_packets(media / "h264.ts", tmp_path / "damaged.ts", first, 30)
        frames, stats = drain_file(damaged)
        assert 0 < stats.frames < 60 and stats.frames + stats.corrupt == 60, stats
        assert frames[-1].index == 59
        for f in frames:
            assert f.index == round(f.t_ns * FPS / 1e9)


def test_variable_frame_rate_gaps_are_not_lost_frames(tmp_path):
    clip = encode_clip(tmp_path / "vfr.mp4", "libx264", frames=30, intervals_ms=(20, 20, 60))
    frames, stats = drain_file(clip)
    assert (stats.frames, stats.corrupt) == (30, 0)
    assert [f.index for f in frames] == list(range(30))


def test_truncated_and_unreadable_files(media, tmp_path, caplog):
    def cut(name: str) -> Path:
        data = (media / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) // 2])
        return tmp_path / name

    with pytest.raises(SourceOpenError, match=r"h264.mp4: the file is truncated \(its mdat box"):
        PyAVFileReader(cut("h264.mp4")).open()
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="dronekey.daemon.sources.pyav_reader"):
        frames, _ = drain_file(cut("faststart.mp4"))
    assert 0 < len(frames) < 60 and "faststart.mp4 is truncated" in caplog.text
    with pytest.raises(SourceOpenError, match="not found"):
        PyAVFileReader(tmp_path / "absent.mp4").open()
    (tmp_path / "garbage.mp4").write_bytes(b"\x00" * 1000)
    with pytest.raises(SourceOpenError, match=r"cannot open .*garbage.mp4 as a video"):
        PyAVFileReader(tmp_path / "garbage.mp4").open()


def test_loop_keeps_timestamps_increasing(media):
    capture = Capture(PyAVFileReader(media / "h264.mp4"), SourceConfig(uri="x", loop=True))
    capture.start()
    frames = []
    while len(frames) < 75:
        item = capture.get(1.0)
        assert item is not None, capture.state
        frames.append(item.frame)
    capture.stop()
    t_ns = np.diff([f.t_ns for f in frames])
    np.testing.assert_allclose(t_ns, 1e9 / FPS, atol=1e6)
    assert capture.stats().corrupt == 0


def test_a_loop_takes_the_next_pass_opened_ahead_and_a_stop_closes_it(media):
    """A looping file's next pass is opened on a helper thread while the current one plays
    (``NextPass``), so the capture thread never reopens the file at the loop: the reader after the
    wrap-around is the spare, its first frame stamped one interval after the last; stopping closes
    the spare of the pass that would have come next."""
    path = media / "h264.mp4"
    auto = FirstThatOpens([PyAVFileReader(path, decode_threads=2), VideoFileReader(path)])
    assert auto.spare() is None  # nothing opened yet: no kind to follow
    auto.open()
    spare = auto.spare()
    assert isinstance(spare, PyAVFileReader) and spare is not auto.opened
    assert (spare.path, spare._configured_threads, spare.fast_decode) == (path, 2, True)
    assert VideoFileReader(path).spare() is None  # OpenCV reopens at the loop, as before
    auto.close()

    first = PyAVFileReader(path)
    capture = Capture(first, SourceConfig(uri="x", loop=True))
    capture.start()
    opened_ahead = []
    frames = []
    while len(frames) < 40:
        item = capture.get(1.0)
        assert item is not None, capture.state
        frames.append(item.frame)
        if len(frames) == 25:  # mid-pass: the next pass is already open, off the capture thread
            pending = capture._next_pass
            assert pending is not None and pending._thread is not None
            pending._thread.join(5.0)
            opened_ahead.append(pending._spare._container is not None)
    assert opened_ahead == [True]
    assert capture.reader is not first and first._container is None  # swapped in, the old pass closed
    t_ns = np.diff([f.t_ns for f in frames])
    np.testing.assert_allclose(t_ns, 1e9 / FPS, atol=1e6)  # no jump at the wrap-around
    waiting = capture._next_pass
    waiting._thread.join(5.0)
    spare = waiting._spare
    assert spare._container is not None
    capture.stop()
    assert spare._container is None and not capture._thread.is_alive()


def test_a_next_pass_discarded_while_it_opens_is_closed_once_opened(media):
    """A capture that stops while the helper is still opening the next pass: the helper closes the
    spare when it is done (no reader left open, no error on the helper thread)."""
    from dronekey.daemon.sources.next_pass import NextPass

    release = threading.Event()

    class SlowToOpen(PyAVFileReader):
        def open(self) -> None:
            release.wait(5.0)
            super().open()

    class Reader(PyAVFileReader):
        def spare(self) -> PyAVFileReader:
            return SlowToOpen(self.path)

    pending = NextPass(Reader(media / "h264.mp4"))
    spare = pending._spare
    pending.discard()  # still opening
    release.set()
    pending._thread.join(5.0)
    assert not pending._thread.is_alive() and spare._container is None and pending._error is None


def test_decoder_threads_by_pixel_rate():
    assert pyav_decode_threads((1920, 1080), 30, configured=3) == 3
    assert pyav_decode_threads((640, 480), 30, None) == 1
    assert pyav_decode_threads(None, None, None) == 1
    assert 1 <= pyav_decode_threads((3840, 2160), 30, None) <= 4


def test_make_reader_picks_the_decoder(media, tmp_path):
    def reader(uri: str, decoder: str = "auto"):
        return make_reader(SourceConfig(uri=uri, decoder=decoder))

    auto = reader(str(media / "h264.mp4"))
    assert isinstance(auto, FirstThatOpens)
    auto.open()
    assert isinstance(auto.opened, PyAVFileReader) and auto.read().image is not None
    auto.close()
    assert isinstance(reader(str(media / "h264.mp4"), "pyav"), PyAVFileReader)
    assert isinstance(reader(str(media / "h264.mp4"), "opencv"), VideoFileReader)
    assert isinstance(reader("tcp://127.0.0.1:5000"), PyAVStreamReader)
    assert isinstance(reader("tcp://127.0.0.1:5000", "opencv"), NetworkStreamReader)
    assert isinstance(reader("/dev/video0", "pyav"), V4l2Reader)  # V4L2 stays with OpenCV
    with pytest.raises(ValueError, match="decoder"):
        SourceConfig(uri="x", decoder="gstreamer")


def test_auto_falls_back_to_opencv_where_pyav_cannot_open(media, tmp_path):
    class RefusingReader(PyAVFileReader):
        def open(self) -> None:
            raise SourceOpenError("PyAV cannot")

    path = media / "h264.mp4"
    reader = FirstThatOpens([RefusingReader(path), VideoFileReader(path)])
    reader.open()
    assert isinstance(reader.opened, VideoFileReader) and reader.read().image.shape == (240, 320, 3)
    assert reader.frame_rate == pytest.approx(30) and reader.resolution == (320, 240)
    reader.close()
    both = FirstThatOpens([RefusingReader(path), RefusingReader(path)])
    with pytest.raises(SourceOpenError, match="PyAV cannot"):
        both.open()


@pytest.fixture
def ts_server():
    port = free_port()
    server = start_server(port)
    yield port
    stop_process(server)


def test_stream_reader_over_loopback(ts_server):
    config = SourceConfig(uri=f"tcp://127.0.0.1:{ts_server}", stall_timeout_s=2.0)
    reader = make_reader(config)
    assert isinstance(reader, PyAVStreamReader)
    capture = Capture(reader, config)
    capture.start()
    frames = []
    deadline = time.monotonic() + 20
    while len(frames) < 20 and time.monotonic() < deadline:
        item = capture.get(0.5)
        if item is not None:
            frames.append(item.frame)
    capture.stop()
    assert len(frames) == 20 and frames[0].bgr.shape == (240, 320, 3)
    assert abs(frames[-1].t_ns - time.time_ns()) < 10e9  # live: Unix time
    assert capture.state != SourceState.FAILED


def test_stream_reader_says_connection_refused():
    reader = PyAVStreamReader(
        f"tcp://127.0.0.1:{free_port()}", NetworkSettings(open_timeout_s=10.0), read_timeout_s=2.0
    )
    started = time.monotonic()
    with pytest.raises(SourceOpenError, match=r"cannot open stream tcp://127.0.0.1:\d+: .*refused"):
        reader.open()
    assert time.monotonic() - started < 10.0  # refused at once, not after the open timeout
