"""Readers built on ``cv2.VideoCapture``: video files, V4L2 devices and network streams.

Files are decoded with OpenCV's FFmpeg backend (H.264/H.265 MP4 and MKV, MJPEG and MPEG-4 AVI, ...)
and stamped with the stream's presentation time (``CAP_PROP_POS_MSEC``). Network streams (rtsp,
http, tcp, udp) use the same backend with open and read timeouts, so a dead link returns control
to the capture thread, which reconnects. V4L2 devices get the configured size, pixel format and
rate and say so when the driver picks something else. Live frames are stamped with the Unix time
at which they were read (docs/design.md §4).

FFmpeg decodes files and streams on ``decode_threads`` threads, by default every core but one: the
pipeline thread (one ONNX Runtime thread, see ``model.threads``) keeps a core of its own instead of
fighting the decoder for every core (measurements in docs/performance.md).
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import cv2
import numpy as np

from dronekey.daemon.config.source import NetworkSettings, V4l2Settings
from dronekey.daemon.sources.base import FrameReader, ReadResult, SourceOpenError, valid_bgr
from dronekey.daemon.sources.file_timeline import FileTimeline, FirstFramePeek
from dronekey.daemon.sources.sidecar import sidecar_camera
from dronekey.daemon.sources.stream_errors import explain_open_failure
from dronekey.daemon.sources.truncation import truncation
from dronekey.geometry.camera import CameraModel

__all__ = [
    "NetworkStreamReader",
    "V4l2Reader",
    "VideoFileReader",
    "default_decode_threads",
    "quiet_native_logs",
    "redact_url",
]

log = logging.getLogger(__name__)

# A file read that fails this many times in a row is its end; fewer failures followed by a good
# frame were undecodable frames, counted as corrupt (OpenCV returns False for each of them).
_FILE_MAX_CONSECUTIVE_FAILURES = 50
# A live stream that fails this many reads in a row is lost (one bad packet is a corrupt frame).
_LIVE_MAX_CONSECUTIVE_FAILURES = 3


def default_decode_threads() -> int:
    """FFmpeg decoder threads when not configured: every CPU this process may use but one (at least
    one), so the pipeline thread always has a core and decoding never waits behind it."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    return max(1, cpus - 1)


def redact_url(url: str) -> str:
    """``url`` without its user name and password, for logs and status messages."""
    try:
        parts = urlsplit(url)
    except ValueError:
        return "<unparsable URL>"
    if parts.username is None and parts.password is None:
        return url
    host = parts.hostname or ""
    if parts.port is not None:
        host = f"{host}:{parts.port}"
    return urlunsplit((parts.scheme, f"***@{host}", parts.path, parts.query, parts.fragment))


class _CaptureReader(FrameReader):
    """Shared ``cv2.VideoCapture`` handling."""

    def __init__(self) -> None:
        self._cap: cv2.VideoCapture | None = None
        self._fps: float | None = None
        self._size: tuple[int, int] | None = None

    @property
    def frame_rate(self) -> float | None:
        return self._fps

    @property
    def resolution(self) -> tuple[int, int] | None:
        return self._size

    def _remember_format(self, cap: cv2.VideoCapture) -> None:
        fps = cap.get(cv2.CAP_PROP_FPS)
        self._fps = float(fps) if np.isfinite(fps) and 0 < fps < 1000 else None
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if w > 0 and h > 0:
            self._size = (w, h)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _read_live(self) -> ReadResult:
        """A live read: a few failures in a row mean the stream is lost."""
        assert self._cap is not None, "read() before open()"
        for failures in range(_LIVE_MAX_CONSECUTIVE_FAILURES):
            ok, img = self._cap.read()
            if ok and valid_bgr(img):
                return ReadResult(img, time.time_ns(), corrupt=failures)
        return ReadResult(lost=True)


class VideoFileReader(FirstFramePeek, _CaptureReader):
    """A recorded video file, read in order and stamped with its presentation timestamps."""

    live = False
    kind = "file"

    def __init__(self, path: Path, decode_threads: int | None = None) -> None:
        super().__init__()
        self.path = Path(path)
        self.decode_threads = decode_threads or default_decode_threads()
        self.description = str(self.path)
        self._peeked: ReadResult | None = None
        self._timeline = FileTimeline(str(self.path))  # PTS gaps (lost frames), increasing timestamps
        self._warned_truncated = False

    def open(self) -> None:
        self.close()
        if not self.path.is_file():
            raise SourceOpenError(f"video file not found: {self.path}")
        cut = truncation(self.path)
        cap = cv2.VideoCapture(str(self.path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_N_THREADS, self.decode_threads])
        if not cap.isOpened():
            if cut:
                raise SourceOpenError(f"cannot open {self.path}: the file is truncated ({cut})")
            raise SourceOpenError(
                f"cannot open {self.path} as a video: OpenCV's FFmpeg backend does not read it "
                "(use H.264 MP4, MJPEG or MPEG-4 AVI, or an image folder)"
            )
        self._cap = cap
        self._remember_format(cap)
        self._timeline.reset(self._fps)
        self._peek_first_frame(cut)

    def _decode_next(self) -> ReadResult:
        assert self._cap is not None, "read() before open()"
        failures = 0
        while failures < _FILE_MAX_CONSECUTIVE_FAILURES:
            ok, img = self._cap.read()
            if ok and valid_bgr(img):
                t_ns = round(self._cap.get(cv2.CAP_PROP_POS_MSEC) * 1e6)
                if self._timeline.in_counted_gap(t_ns):
                    continue  # a late B-frame after the decoder resynchronised: counted in the gap
                # Frames that failed to decode are inside the timestamp gap too: count them once.
                lost = max(failures, self._timeline.lost_before(t_ns))
                return ReadResult(img, self._timeline.stamp(t_ns), corrupt=lost)
            failures += 1
        return ReadResult(ended=True)

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        return sidecar_camera(self.path)


class NetworkStreamReader(_CaptureReader):
    """An rtsp/http/tcp/udp stream through OpenCV's FFmpeg backend, with open and read timeouts."""

    live = True
    kind = "network"

    def __init__(
        self, url: str, settings: NetworkSettings, read_timeout_s: float, decode_threads: int | None = None
    ) -> None:
        super().__init__()
        self.url = url
        self.decode_threads = decode_threads or default_decode_threads()
        self.description = redact_url(url)
        self._settings = settings
        self._read_timeout_ms = max(100, round(read_timeout_s * 1000))
        if url.lower().startswith("rtsp"):
            _set_rtsp_transport(settings.rtsp_transport)

    def open(self) -> None:
        self.close()
        params = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
            round(self._settings.open_timeout_s * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC,
            self._read_timeout_ms,
            cv2.CAP_PROP_N_THREADS,
            self.decode_threads,
        ]
        started = time.monotonic()
        cap = cv2.VideoCapture(self.url, cv2.CAP_FFMPEG, params)
        if not cap.isOpened():
            cap.release()
            why = explain_open_failure(self.url, time.monotonic() - started, self._settings.open_timeout_s)
            raise SourceOpenError(f"cannot open stream {self.description}: {why}")
        self._cap = cap
        self._remember_format(cap)

    def read(self) -> ReadResult:
        return self._read_live()


class V4l2Reader(_CaptureReader):
    """A V4L2 camera (``/dev/videoN`` or a stable ``/dev/v4l/by-id/...`` link)."""

    live = True
    kind = "v4l2"

    def __init__(self, device: str, settings: V4l2Settings) -> None:
        super().__init__()
        self.device = device
        self.description = device
        self._settings = settings

    def open(self) -> None:
        self.close()
        if not os.path.exists(self.device):
            raise SourceOpenError(f"{self.device} does not exist (camera unplugged?)")
        if not os.access(self.device, os.R_OK | os.W_OK):
            raise SourceOpenError(
                f"no permission to open {self.device}: run as a member of the 'video' group"
            )
        s = self._settings
        params: list[int] = []
        if s.fourcc:
            params += [cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*s.fourcc)]
        if s.width:
            params += [cv2.CAP_PROP_FRAME_WIDTH, s.width]
        if s.height:
            params += [cv2.CAP_PROP_FRAME_HEIGHT, s.height]
        if s.fps:
            params += [cv2.CAP_PROP_FPS, round(s.fps)]
        cap = cv2.VideoCapture(self.device, cv2.CAP_V4L2, params)
        if not cap.isOpened():
            cap.release()
            raise SourceOpenError(f"cannot open V4L2 device {self.device}")
        self._cap = cap
        self._remember_format(cap)
        self._report_format(cap)

    def _report_format(self, cap: cv2.VideoCapture) -> None:
        s = self._settings
        code = int(cap.get(cv2.CAP_PROP_FOURCC))
        fourcc = "".join(chr((code >> (8 * i)) & 0xFF) for i in range(4)) if code > 0 else "?"
        w, h = self._size or (0, 0)
        got = f"{w}x{h} {fourcc} {self._fps or 0:g} fps"
        wanted = (s.width, s.height, s.fourcc, s.fps)
        mismatch = (
            (s.width and s.width != w)
            or (s.height and s.height != h)
            or (s.fourcc and s.fourcc != fourcc)
            or (s.fps and self._fps and abs(s.fps - self._fps) > 0.5)
        )
        if mismatch:
            log.warning("%s: asked for %s, the device gives %s", self.device, wanted, got)
        else:
            log.info("%s: %s", self.device, got)

    def read(self) -> ReadResult:
        return self._read_live()


def _set_rtsp_transport(transport: str) -> None:
    """Tell OpenCV's FFmpeg backend the RTSP transport, unless the user set capture options already."""
    key = "OPENCV_FFMPEG_CAPTURE_OPTIONS"
    if key in os.environ:
        log.info("%s is set (%r); source.network.rtsp_transport not applied", key, os.environ[key])
        return
    os.environ[key] = f"rtsp_transport;{transport}"


def quiet_native_logs(verbose: bool) -> None:
    """Keep FFmpeg's and OpenCV's own stderr messages out of the log unless debugging.

    They bypass Python logging (and would break the terminal status line and journald priorities);
    what they report (undecodable frames, timeouts) is counted and logged by the capture thread.
    A user's own ``OPENCV_FFMPEG_LOGLEVEL`` is left as it is.
    """
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "24" if verbose else "-8")  # AV_LOG_WARNING / QUIET
    level = cv2.utils.logging.LOG_LEVEL_INFO if verbose else cv2.utils.logging.LOG_LEVEL_ERROR
    cv2.utils.logging.setLogLevel(level)
