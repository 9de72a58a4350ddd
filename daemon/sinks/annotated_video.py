"""The annotated video: every frame with its tracks drawn on it, encoded to H.264 through PyAV.

``H264Writer`` is the encoder (libx264, yuv420p, the source's frame rate, constant quality),
shared with ``dronekey-annotate``; ``AnnotatedVideoSink`` is the daemon's output
(``--annotated-video FILE``). The sink asks for every frame's image (``wants_image``) and runs on
its own ``SinkWorker`` behind a short queue (``annotated_video.queue_frames``): when encoding is
slower than the source the oldest waiting frames are dropped and counted (the worker's
``dropped``), and the pipeline never waits for the encoder.

MP4 files are written fragmented (a fragment per keyframe, every ``keyframe_interval_s``), so a
daemon killed with SIGKILL leaves a file that plays up to its last complete fragment.
Presentation times follow the frames' own timestamps, so dropped frames show as held frames and
the video keeps the source's timing.
"""

from __future__ import annotations

import logging
import math
import time
from fractions import Fraction
from pathlib import Path

import av
import numpy as np

from dronekey.daemon.config.annotated_video import AnnotatedVideoConfig
from dronekey.daemon.sinks.annotation_drawing import TrackOverlay, draw_tracks
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.geometry.camera import CameraModel

__all__ = ["AnnotatedVideoSink", "H264Writer", "fresh_video_path"]

log = logging.getLogger(__name__)

_DEFAULT_FPS = 30.0
_STARTED_NS = time.time_ns()  # files newer than this were written by this process


def fresh_video_path(path: Path) -> Path:
    """``path``, or ``stem.2.mp4``, ``stem.3.mp4``, ... when this process already wrote ``path``.

    The daemon rebuilds its outputs when the source's resolution changes; the new video must not
    overwrite the one recorded before. A file from an earlier run is replaced.
    """
    candidate, n = Path(path), 1
    while candidate.exists() and candidate.stat().st_mtime_ns >= _STARTED_NS:
        n += 1
        candidate = path.with_name(f"{path.stem}.{n}{path.suffix}")
    return candidate


class H264Writer:
    """Writes BGR frames to an H.264 video (libx264, yuv420p) with PyAV.

    Parameters
    ----------
    path : Path
        .mp4 (fragmented), .mkv or .mov; the folder must exist.
    width, height : int
        Frame size; odd sizes lose their last column or row (yuv420p needs even sizes).
    fps : float or None
        The source's frame rate (None: 30); the stream's time base is its inverse.
    crf, preset, threads, keyframe_interval_s :
        x264 settings (see ``AnnotatedVideoConfig``).

    Raises
    ------
    OSError
        The file cannot be created (missing folder, no permission).
    ValueError
        The size or rate is unusable.
    """

    def __init__(
        self,
        path: Path,
        width: int,
        height: int,
        fps: float | None,
        *,
        crf: int = 23,
        preset: str = "veryfast",
        threads: int = 2,
        keyframe_interval_s: float = 2.0,
    ) -> None:
        self.path = Path(path)
        self.width, self.height = int(width) // 2 * 2, int(height) // 2 * 2
        if self.width < 2 or self.height < 2:
            raise ValueError(f"video size must be at least 2x2, got {width}x{height}")
        fps = float(fps) if fps and math.isfinite(fps) and 0 < fps <= 1000 else _DEFAULT_FPS
        self.rate = Fraction(fps).limit_denominator(1001)
        if not self.path.parent.is_dir():
            raise OSError(f"{self.path.parent} is not a folder (for {self.path})")
        options = {"movflags": "frag_keyframe+empty_moov+default_base_moof"}
        self._container = av.open(
            str(self.path), mode="w", options=options if self.path.suffix.lower() == ".mp4" else {}
        )
        try:
            stream = self._container.add_stream("libx264", rate=self.rate)
            stream.width, stream.height, stream.pix_fmt = self.width, self.height, "yuv420p"
            stream.time_base = 1 / self.rate
            stream.options = {"crf": str(crf), "preset": preset}
            stream.codec_context.gop_size = max(1, round(float(self.rate) * keyframe_interval_s))
            stream.codec_context.thread_count = threads
        except Exception:
            self._container.close()
            raise
        self._stream = stream
        self._t0_ns: int | None = None
        self._last_pts = -1
        self.frames = 0
        self._closed = False

    def write(self, bgr: np.ndarray, t_ns: int | None = None) -> None:
        """Encode one BGR frame; ``t_ns`` (frame time, ns) sets its presentation time, else the next."""
        if self._closed:
            raise ValueError(f"{self.path} is closed")
        image = np.ascontiguousarray(bgr[: self.height, : self.width])
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"frame is {bgr.shape[1]}x{bgr.shape[0]}, the video {self.width}x{self.height}")
        pts = self._last_pts + 1
        if t_ns is not None:
            if self._t0_ns is None:
                self._t0_ns = int(t_ns)
            pts = max(pts, round((int(t_ns) - self._t0_ns) * self.rate / 1_000_000_000))
        frame = av.VideoFrame.from_ndarray(image, format="bgr24")
        frame.pts = pts
        self._last_pts = pts
        self._container.mux(self._stream.encode(frame))
        self.frames += 1

    def close(self) -> None:
        """Flush the encoder and finish the file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._container.mux(self._stream.encode(None))
        finally:
            self._container.close()


class AnnotatedVideoSink(Sink):
    """The daemon's annotated-video output (see the module docstring).

    Parameters
    ----------
    config : AnnotatedVideoConfig
        ``path`` must be set.
    camera : CameraModel
        Intrinsics at the source's resolution (the video's size; the axes' projection).
    frame_rate : float or None
        The source's frame rate.
    """

    name = "annotated_video"

    def __init__(self, config: AnnotatedVideoConfig, camera: CameraModel, frame_rate: float | None) -> None:
        if config.path is None:
            raise ValueError("annotated_video.path is not set")
        self._camera = camera
        self._writer = H264Writer(
            fresh_video_path(config.path),
            camera.width,
            camera.height,
            frame_rate,
            crf=config.crf,
            preset=config.preset,
            threads=config.threads,
            keyframe_interval_s=config.keyframe_interval_s,
        )
        self._without_image = 0
        log.info(
            "annotated video: %s (%dx%d, %s fps, H.264 crf %d)",
            self._writer.path,
            self._writer.width,
            self._writer.height,
            f"{float(self._writer.rate):g}",
            config.crf,
        )

    def wants_image(self, t_ns: int) -> bool:
        """Every frame: the video shows them all."""
        return True

    def handle_update(self, update: FrameUpdate) -> None:
        if update.image is None:
            self._without_image += 1
            return
        image = update.image.bgr().copy()  # the frame is shared read-only with the other outputs
        draw_tracks(image, [TrackOverlay.from_track(t) for t in update.tracks], self._camera)
        self._writer.write(image, update.t_ns)

    def health(self) -> dict:
        return {"file": str(self._writer.path), "frames": self._writer.frames}

    def fault_counts(self) -> dict[str, int]:
        return {"frames without an image": self._without_image}

    def close(self) -> None:
        self._writer.close()
        log.info("annotated video: %d frames in %s", self._writer.frames, self._writer.path)
