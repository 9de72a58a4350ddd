"""Readers built on PyAV (FFmpeg's own bindings): video files and network streams.

Why not only OpenCV: PyAV hands over the decoded frame itself (YUV planes as the decoder made
them), so colour can be converted only where it is needed, and the decoder's threading is set per
source; ``cv2.VideoCapture`` always converts the whole frame to BGR. Both are FFmpeg: a file or URL
that one opens, the other opens too, give or take the codecs each build carries; ``make_reader``
falls back to OpenCV for files PyAV cannot open (``source.decoder: auto``), and V4L2 cameras stay
with OpenCV.

Semantics match ``opencv_readers`` (the same tests run on both):

- Files: frames in order, stamped with their presentation time from the stream's start; frames the
  decoder rejects, and frames missing from a constant-rate file's PTS sequence (a damaged
  MPEG-TS), are counted as corrupt (``file_timeline.py``); 50 failures in a row are the end; a
  truncated file is called truncated (``truncation.py``).
- Network streams: open and read timeouts; a read that times out or a stream that ends is lost
  (the capture thread reconnects); 3 undecodable packets in a row are lost too; frames are stamped
  with the Unix time at which they were decoded (docs/design.md §4).

Decoder threads (``decode_threads``): ``source.decode_threads`` when set, else one thread per
1080p30 of pixel rate, between 1 and every core but one (``pyav_decode_threads``), with FFmpeg's
``AUTO`` thread type (frame threads where the codec has them, else slice threads). One camera at
1080p30 then decodes on one core and leaves the others to the pipeline and to other cameras;
measured in docs/performance.md ("Decoder threads").

Fast decoding (``source.fast_decode``, on by default): the decoder skips the H.264 / HEVC
deblocking filter and takes FFmpeg's non-conformant shortcuts (``FAST_DECODE_OPTIONS``). On the
camera-like 1080p clip that is about a quarter less decode CPU per frame; the frames differ from a
conformant decode by under one grey level on average (the unfiltered reference frames drift a little
until the next keyframe), and the pose figures stay within run-to-run noise (docs/performance.md,
"Decoding less"). The OpenCV readers always decode to the standard.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from dronekey.daemon.config.source import NetworkSettings
from dronekey.daemon.sources.base import FrameReader, ReadResult, SourceOpenError
from dronekey.daemon.sources.file_timeline import FileTimeline, FirstFramePeek
from dronekey.daemon.sources.opencv_readers import redact_url
from dronekey.daemon.sources.sidecar import sidecar_camera
from dronekey.daemon.sources.truncation import truncation
from dronekey.frame_image import I420Image
from dronekey.geometry.camera import CameraModel

__all__ = ["FAST_DECODE_OPTIONS", "PyAVFileReader", "PyAVStreamReader", "pyav_decode_threads"]

log = logging.getLogger(__name__)

_FILE_MAX_CONSECUTIVE_FAILURES = 50
_LIVE_MAX_CONSECUTIVE_FAILURES = 3
_PIXEL_RATE_PER_THREAD = 1920 * 1080 * 30.0
# FFmpeg decoder options of source.fast_decode: no deblocking, non-conformant speed-ups allowed.
FAST_DECODE_OPTIONS = {"skip_loop_filter": "all", "flags2": "+fast"}


def pyav_decode_threads(size: tuple[int, int] | None, fps: float | None, configured: int | None) -> int:
    """Decoder threads for a source of ``size`` (w, h) at ``fps``: the configured count, else one per
    1080p30 of pixel rate, at least 1 and at most every core this process may use but one."""
    if configured:
        return configured
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    if size is None:
        return 1
    rate = size[0] * size[1] * (fps or 30.0)
    return int(min(max(1, cpus - 1), max(1, round(rate / _PIXEL_RATE_PER_THREAD))))


class _PyAVReader(FrameReader):
    """Shared PyAV handling: open a container, set up the decoder, decode packet by packet."""

    def __init__(self, decode_threads: int | None, fast_decode: bool = True) -> None:
        self._configured_threads = decode_threads
        self.fast_decode = fast_decode
        self.decode_threads: int | None = decode_threads
        self._container: av.container.InputContainer | None = None
        self._stream: av.VideoStream | None = None
        self._packets: Iterator[av.Packet] | None = None
        self._pending: deque[av.VideoFrame] = deque()
        self._fps: float | None = None
        self._size: tuple[int, int] | None = None
        self._start = 0

    @property
    def frame_rate(self) -> float | None:
        return self._fps

    @property
    def resolution(self) -> tuple[int, int] | None:
        return self._size

    def _attach(self, container: av.container.InputContainer) -> None:
        """Take ``container``'s first video stream and set up its decoder (threads by resolution)."""
        if not container.streams.video:
            container.close()
            raise SourceOpenError(f"{self.description} holds no video stream")
        stream = container.streams.video[0]
        rate = stream.average_rate or stream.guessed_rate
        self._fps = float(rate) if rate and 0 < float(rate) < 1000 else None
        ctx = stream.codec_context
        self._size = (ctx.width, ctx.height) if ctx.width > 0 and ctx.height > 0 else None
        self.decode_threads = pyav_decode_threads(self._size, self._fps, self._configured_threads)
        ctx.thread_type = "AUTO"
        ctx.thread_count = self.decode_threads
        if self.fast_decode:
            ctx.options = dict(FAST_DECODE_OPTIONS)
        self._container, self._stream = container, stream
        self._start = stream.start_time or 0
        self._packets = container.demux(stream)
        self._pending.clear()

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
        self._container = self._stream = self._packets = None
        self._pending.clear()

    def _decode_one(self) -> tuple[av.VideoFrame | None, int]:
        """(the next decoded frame, or None at the end of the packets; packets rejected before it).

        Raises the demuxer's ``av.FFmpegError`` (a read timeout, a broken connection) as is.
        """
        assert self._stream is not None and self._packets is not None, "read() before open()"
        rejected = 0
        while not self._pending:
            try:
                packet = next(self._packets)
            except StopIteration:
                return None, rejected
            try:
                self._pending.extend(self._stream.codec_context.decode(packet))
            except av.InvalidDataError:
                rejected += 1
                if rejected >= self._max_failures:
                    return None, rejected
        return self._pending.popleft(), rejected

    _max_failures = _FILE_MAX_CONSECUTIVE_FAILURES

    def _stream_time_ns(self, frame: av.VideoFrame) -> int | None:
        """``frame``'s presentation time from the stream's start, ns (None when it has none)."""
        if frame.pts is None or frame.time_base is None:
            return None
        return round((frame.pts - self._start) * Fraction(frame.time_base) * 1_000_000_000)


# Colour tags under which swscale's default conversion (BT.601, limited range) applies, which
# OpenCV's I420 conversion matches: unspecified, or BT.601 (BT470BG, SMPTE 170M); not full range.
_BT601_SPACES = (2, 5, 6)  # AVCOL_SPC_UNSPECIFIED, AVCOL_SPC_BT470BG, AVCOL_SPC_SMPTE170M
_FULL_RANGE = 2  # AVCOL_RANGE_JPEG


def image_from_frame(frame: av.VideoFrame) -> I420Image | np.ndarray:
    """The frame's pixels for the pipeline.

    The common camera and encoder output, 4:2:0 planar YUV of even size tagged BT.601 or not at
    all, is handed over as its planes (``I420Image``): OpenCV converts to colour only the regions a
    stage needs (a whole 1080p frame costs about 1 ms of CPU on the 2-core box, and about 2 ms more
    through swscale; the same colours within 3 levels). Every other format becomes an (H, W, 3)
    uint8 BGR array through swscale.
    """
    if (
        frame.format.name == "yuv420p"
        and frame.width % 2 == 0
        and frame.height % 2 == 0
        and frame.colorspace in _BT601_SPACES
        and frame.color_range != _FULL_RANGE
    ):
        return I420Image(frame.to_ndarray())
    return frame.to_ndarray(format="bgr24")


class PyAVFileReader(FirstFramePeek, _PyAVReader):
    """A recorded video file through PyAV, read in order and stamped with its presentation times."""

    live = False
    kind = "file"

    def __init__(self, path: Path, decode_threads: int | None = None, fast_decode: bool = True) -> None:
        super().__init__(decode_threads, fast_decode)
        self.path = Path(path)
        self.description = str(self.path)
        self._timeline = FileTimeline(str(self.path))
        self._peeked: ReadResult | None = None
        self._warned_truncated = False

    def open(self) -> None:
        self.close()
        if not self.path.is_file():
            raise SourceOpenError(f"video file not found: {self.path}")
        cut = truncation(self.path)
        try:
            container = av.open(str(self.path))
        except (av.FFmpegError, OSError) as exc:
            if cut:
                raise SourceOpenError(f"cannot open {self.path}: the file is truncated ({cut})") from None
            raise SourceOpenError(f"cannot open {self.path} as a video: FFmpeg (PyAV) says {exc}") from None
        self._attach(container)
        self._timeline.reset(self._fps)
        self._peek_first_frame(cut)

    def _decode_next(self) -> ReadResult:
        failures = 0
        while failures < _FILE_MAX_CONSECUTIVE_FAILURES:
            try:
                frame, rejected = self._decode_one()
            except av.FFmpegError as exc:  # a damaged container: resume demuxing after it
                log.debug("%s: demuxer error %s", self.path, exc)
                failures += 1
                assert self._container is not None and self._stream is not None
                self._packets = self._container.demux(self._stream)
                continue
            failures += rejected
            if frame is None:
                break
            t_ns = self._stream_time_ns(frame)
            if t_ns is None:  # no PTS: stepped by the nominal frame interval
                return ReadResult(image_from_frame(frame), self._timeline.stamp(None), corrupt=failures)
            if self._timeline.in_counted_gap(t_ns):
                continue
            lost = max(failures, self._timeline.lost_before(t_ns))
            return ReadResult(image_from_frame(frame), self._timeline.stamp(t_ns), corrupt=lost)
        return ReadResult(ended=True)

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        return sidecar_camera(self.path)

    def spare(self) -> PyAVFileReader:
        """The same file with the same decoder settings, unopened (the next pass of a loop); a truncation
        already reported is not reported again."""
        other = PyAVFileReader(self.path, self._configured_threads, self.fast_decode)
        other._warned_truncated = self._warned_truncated
        return other


class PyAVStreamReader(_PyAVReader):
    """An rtsp/http/tcp/udp stream through PyAV, with open and read timeouts."""

    live = True
    kind = "network"
    _max_failures = _LIVE_MAX_CONSECUTIVE_FAILURES

    def __init__(
        self,
        url: str,
        settings: NetworkSettings,
        read_timeout_s: float,
        decode_threads: int | None = None,
        fast_decode: bool = True,
    ) -> None:
        super().__init__(decode_threads, fast_decode)
        self.url = url
        self.description = redact_url(url)
        self._settings = settings
        self._read_timeout_s = read_timeout_s

    def open(self) -> None:
        self.close()
        options = (
            {"rtsp_transport": self._settings.rtsp_transport} if self.url.lower().startswith("rtsp") else {}
        )
        try:
            container = av.open(
                self.url, options=options, timeout=(self._settings.open_timeout_s, self._read_timeout_s)
            )
        except (av.FFmpegError, OSError) as exc:
            raise SourceOpenError(f"cannot open stream {self.description}: {_reason(exc)}") from None
        self._attach(container)

    def read(self) -> ReadResult:
        try:
            frame, rejected = self._decode_one()
        except (av.FFmpegError, OSError) as exc:
            log.info("%s: %s", self.description, _reason(exc))
            return ReadResult(lost=True)
        if frame is None:
            return ReadResult(lost=True)
        return ReadResult(image_from_frame(frame), time.time_ns(), corrupt=rejected)


def _reason(exc: BaseException) -> str:
    """FFmpeg's own words for a failure (``Connection refused``, ``Immediate exit requested``: a
    timeout), without PyAV's errno prefix and the URL it repeats."""
    text = getattr(exc, "strerror", None) or str(exc)
    if "Immediate exit requested" in text or isinstance(exc, TimeoutError):
        return "timed out"
    return text
