"""The ``source`` section: where frames come from and how the capture thread treats them."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from dronekey.daemon.config.section import Seconds, Section

__all__ = ["NetworkSettings", "SimSettings", "SourceConfig", "V4l2Settings"]


class V4l2Settings(Section):
    """Capture settings applied to ``/dev/videoN`` sources (ignored by other sources)."""

    width: int | None = Field(None, gt=0, le=16384, description="requested frame width, px")
    height: int | None = Field(None, gt=0, le=16384, description="requested frame height, px")
    fps: float | None = Field(None, gt=0, le=1000, description="requested frame rate")
    fourcc: str | None = Field(None, description="pixel format, e.g. MJPG, YUYV, H264")

    @field_validator("fourcc")
    @classmethod
    def _four_chars(cls, v: str | None) -> str | None:
        if v is not None and (len(v) != 4 or not v.isascii()):
            raise ValueError("must be 4 ASCII characters such as MJPG, YUYV or H264")
        return v


class NetworkSettings(Section):
    """Settings of rtsp/http/tcp/udp sources (OpenCV's FFmpeg backend)."""

    open_timeout_s: Seconds = Field(10.0, description="give up one connection attempt after this")
    rtsp_transport: Literal["tcp", "udp"] = Field("tcp", description="RTSP over TCP survives lossy links")


class SimSettings(Section):
    """Settings of ``sim://<preset>`` sources."""

    seed: int | None = Field(None, ge=0, description="random seed; null: the preset's own (11, 12, 13)")
    frames: int | None = Field(None, gt=0, description="frames to render; null: the preset's length")


class SourceConfig(Section):
    """Where frames come from and how the capture thread treats them."""

    uri: str | None = Field(
        None, description="video file, image folder, /dev/videoN, rtsp|http|tcp|udp URL or sim://preset"
    )
    realtime: bool = Field(False, description="pace files, image folders and sim at their frame rate")
    realtime_phase: float | None = Field(
        None,
        ge=0.0,
        lt=1.0,
        description="with realtime: release frames on the frame-rate grid of the system's monotonic "
        "clock, this fraction of a frame interval into each (replayed cameras on one box then deliver "
        "in a known phase: 0 for all, together, as genlocked cameras do; k/N for N cameras, evenly "
        "spread); null: paced from the first frame read, so in whatever phase the process started",
    )
    realtime_decode_ahead: bool = Field(
        False,
        description="with realtime: decode each frame before it is due and hand it over when it is due "
        "(a file's privilege: its decode is not in the latency; the behaviour before the thirty-third "
        "session); false: decode a frame only once it is due, as a camera's compressed stream arrives, so "
        "that its decode counts in the frame-to-publish latency as it would for that camera",
    )
    loop: bool = Field(False, description="restart a file, image folder or sim at its end")
    queue_size: int = Field(2, ge=1, le=256, description="frames buffered from live sources (drop oldest)")
    stall_timeout_s: Seconds = Field(
        5.0, description="live source with no frame for this long is stalled; reconnected after twice that"
    )
    reconnect_initial_s: Seconds = Field(0.5, description="first reconnection delay (doubles each try)")
    reconnect_max_s: Seconds = Field(30.0, description="longest reconnection delay")
    max_reconnects: int | None = Field(
        None, ge=0, description="failed attempts in a row before exit 3; null: retry forever"
    )
    image_fps: float = Field(30.0, gt=0, le=1000, description="frame rate of image folders (timestamps)")
    max_frames: int | None = Field(None, gt=0, description="stop (exit 0) after this many frames")
    decode_threads: int | None = Field(
        None,
        ge=1,
        le=64,
        description="FFmpeg decoder threads (files, network); null: PyAV one per 1080p30 of pixel rate, "
        "OpenCV all cores but one",
    )
    fast_decode: bool = Field(
        True,
        description="PyAV: skip H.264/HEVC deblocking and allow FFmpeg's non-conformant speed-ups "
        "(skip_loop_filter all, flags2 +fast): about a quarter less decode CPU on a camera-like 1080p "
        "clip, images within 1 grey level on average, pose accuracy within noise "
        "(docs/performance.md); false: decode to the standard",
    )
    decoder: Literal["auto", "pyav", "opencv"] = Field(
        "auto",
        description="files and network streams: pyav (FFmpeg through PyAV), opencv (cv2.VideoCapture), or "
        "auto: PyAV, and OpenCV for a file PyAV cannot open; V4L2 always uses OpenCV",
    )
    v4l2: V4l2Settings = Field(default_factory=V4l2Settings)
    network: NetworkSettings = Field(default_factory=NetworkSettings)
    sim: SimSettings = Field(default_factory=SimSettings)

    @field_validator("uri")
    @classmethod
    def _not_blank(cls, v: str | None) -> str | None:
        if v is not None and not v.strip():
            raise ValueError("must not be empty")
        return v
