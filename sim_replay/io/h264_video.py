"""H.264 video for rendered sequences: libx264 through PyAV (FFmpeg's own bindings), yuv420p.

Cameras send H.264 (or H.265) at a few Mbit/s, so benchmarks and the daemon's tests should decode
what a camera sends, not MPEG-4 Part 2 from OpenCV's writer. The encoder is set up like a camera's:

- a target bitrate (``--bitrate``; by default ``DEFAULT_BITRATE_BPS`` at 1920x1080 and 30 fps,
  scaled by the pixel rate, so 480x270 at 30 fps gets 0.5 Mbit/s), capped by a one-second VBV
  buffer at 1.5 times the target as a camera's rate control does;
- a keyframe every two seconds (``g``), as the usual camera default;
- libx264's ``fast`` preset (a camera encoder has a fixed budget; ``medium`` takes twice as long
  for little gain at these bitrates);
- the same frames give the same bytes, so a seed's render reproduces: one encoder thread (with
  frame threads, libx264 plans each frame's VBV budget from frames still being encoded) and no
  rate-control lookahead (``rc-lookahead=0``: with it, the first encode in a process still came
  out differently; a camera's low-latency encoder has none either). A render is bound by drawing,
  not encoding: 60 frames of seq11 at 1080p in 12.9-13.9 s on the idle box.

The file is an MP4 whose frames carry presentation timestamps ``index / fps``.
"""

from __future__ import annotations

import logging
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

__all__ = ["DEFAULT_BITRATE_BPS", "H264VideoSink", "default_bitrate_bps", "probe_video"]

log = logging.getLogger(__name__)

# Camera-like: about 8 Mbit/s for 1080p30 (a 4 MP IP camera's main stream is typically 4-8 Mbit/s).
DEFAULT_BITRATE_BPS = 8_000_000
_REFERENCE_PIXEL_RATE = 1920 * 1080 * 30.0
_KEYFRAME_INTERVAL_S = 2.0
_MAXRATE_FACTOR = 1.5


def default_bitrate_bps(size: tuple[int, int], fps: float) -> int:
    """``DEFAULT_BITRATE_BPS`` scaled by the pixel rate (width x height x fps) against 1080p30, bit/s."""
    width, height = size
    return max(100_000, round(DEFAULT_BITRATE_BPS * width * height * fps / _REFERENCE_PIXEL_RATE))


def _frame_rate(fps: float) -> Fraction:
    """``fps`` as the exact fraction a container stores (29.97 -> 30000/1001)."""
    return Fraction(fps).limit_denominator(1001)


class H264VideoSink:
    """Writes BGR frames to an H.264 MP4 through libx264; ``verify`` decodes it back with PyAV."""

    codec = "h264"

    def __init__(self, path: Path, fps: float, size: tuple[int, int], bitrate_bps: int | None = None) -> None:
        self.path = path
        width, height = size
        if width % 2 or height % 2:
            raise ValueError(f"H.264 in yuv420p needs an even width and height, got {width}x{height}")
        self.bitrate_bps = bitrate_bps or default_bitrate_bps(size, fps)
        rate = _frame_rate(fps)
        self._container = av.open(str(path), "w", format="mp4")
        try:
            options = {
                "preset": "fast",
                "g": str(max(1, round(_KEYFRAME_INTERVAL_S * fps))),
                "maxrate": str(round(self.bitrate_bps * _MAXRATE_FACTOR)),
                "bufsize": str(self.bitrate_bps),
                "x264-params": "rc-lookahead=0",
            }
            self._stream = self._container.add_stream("libx264", rate=rate, options=options)
            self._stream.width, self._stream.height = width, height
            self._stream.pix_fmt = "yuv420p"
            self._stream.bit_rate = self.bitrate_bps
            self._stream.codec_context.time_base = 1 / rate
            # One encoder thread (the module's notes). PyAV hands the codec its own thread_count
            # (0: auto) over an options-dict "threads", so it is set here.
            self._stream.codec_context.thread_count = 1
        except BaseException:
            self._container.close()
            raise
        log.debug("H.264 %dx%d at %s fps, %.2f Mbit/s: %s", width, height, rate, self.bitrate_bps / 1e6, path)

    def write(self, index: int, bgr: np.ndarray, name: str) -> str:
        frame = av.VideoFrame.from_ndarray(bgr, format="bgr24")
        frame.pts = index
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        return f"{name}.mp4#{index}"

    def close(self) -> None:
        if self._container is None:
            return
        try:
            for packet in self._stream.encode():
                self._container.mux(packet)
        finally:
            self._container.close()
            self._container = None

    def verify(self, n_frames: int, size: tuple[int, int]) -> None:
        codec, count, got = probe_video(self.path, decode=False)
        if codec != "h264" or count != n_frames or got != size:
            raise OSError(
                f"the encoded video {self.path} reads back as {count} {codec} frames of {got[0]}x{got[1]}, "
                f"expected {n_frames} h264 frames of {size[0]}x{size[1]}"
            )


def probe_video(path: Path, *, decode: bool = True) -> tuple[str, int, tuple[int, int]]:
    """(codec name, frame count, (width, height)) of the first video stream.

    ``decode``: count the frames the decoder returns; else count the stream's packets (one per
    frame for H.264 in MP4; a fraction of the time, used right after writing).
    """
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        if decode:
            count = sum(1 for _ in container.decode(stream))
        else:
            count = sum(1 for packet in container.demux(stream) if packet.size)
        return stream.codec_context.name, count, (stream.codec_context.width, stream.codec_context.height)
