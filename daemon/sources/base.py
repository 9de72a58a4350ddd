"""What every frame reader implements, and the values the capture thread passes on.

A ``FrameReader`` knows one kind of source (video file, V4L2 device, network stream, image folder,
simulator); ``Capture`` (``capture.py``) runs it on a thread with the queueing, pacing, watchdog and
reconnection policy that depends only on whether the source is live.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from dronekey.frame_image import FrameImage
from dronekey.geometry.camera import CameraModel
from dronekey.types import Frame

__all__ = ["CapturedFrame", "FrameReader", "ReadResult", "SourceOpenError", "SourceState", "valid_bgr"]


class SourceState(StrEnum):
    """Lifecycle of a source, as shown in the status messages."""

    CONNECTING = "connecting"  # first open attempt
    STREAMING = "streaming"  # frames arrive
    STALLED = "stalled"  # live source: no frame for source.stall_timeout_s
    RECONNECTING = "reconnecting"  # live source: waiting for or making another open attempt
    ENDED = "ended"  # finite source: no more frames
    FAILED = "failed"  # gave up (max_reconnects) or the capture thread crashed


class SourceOpenError(Exception):
    """The source could not be opened; the message says why (shown to the user as is)."""


@dataclass(frozen=True, slots=True)
class ReadResult:
    """One ``FrameReader.read`` answer.

    image : the decoded frame, or None when there is none (see the flags): an (H, W, 3) uint8 BGR
        array, or a ``FrameImage`` (the PyAV readers hand over the decoder's YUV planes, converted
        to colour only where the pipeline or an output needs it).
    t_ns : the frame's timestamp (stream PTS for files, Unix epoch for live sources).
    corrupt : frames skipped as undecodable or malformed before this answer.
    ended : a finite source has no more frames.
    lost : a live source stopped delivering (timeout, disconnection); reconnect.
    """

    image: FrameImage | np.ndarray | None = None
    t_ns: int = 0
    corrupt: int = 0
    ended: bool = False
    lost: bool = False


@dataclass(frozen=True, slots=True)
class CapturedFrame:
    """A frame and the ``time.monotonic_ns()`` at which it arrived (the latency origin).

    A live source's frame arrives when it leaves the decoder; a paced (``realtime``) finite source's
    when a camera would have delivered it, its due time on the pacing clock, so that a decoder or a
    queue running late counts in the latency rather than moving its origin."""

    frame: Frame
    t_arrival_mono_ns: int


def valid_bgr(img: object) -> bool:
    """True for a non-empty (H, W, 3) uint8 image, the only shape the pipeline accepts."""
    return (
        isinstance(img, np.ndarray)
        and img.dtype == np.uint8
        and img.ndim == 3
        and img.shape[2] == 3
        and img.shape[0] > 0
        and img.shape[1] > 0
    )


class FrameReader(ABC):
    """One source of frames; ``open``/``read``/``close`` are called from the capture thread only.

    Attributes
    ----------
    live : bool
        Live sources drop the oldest frame when the pipeline falls behind and reconnect when lost;
        finite ones (files, folders, sim) are read in order with back-pressure and end.
    description : str
        Short human-readable name for logs (no credentials).
    kind : str
        ``file``, ``v4l2``, ``network``, ``images`` or ``sim``.
    """

    live: bool = False
    kind: str = "file"
    description: str = ""

    @abstractmethod
    def open(self) -> None:
        """Open (or reopen) the source; raises ``SourceOpenError`` with a clear message."""

    @abstractmethod
    def read(self) -> ReadResult:
        """Return the next frame, or say that the source ended or was lost."""

    @abstractmethod
    def close(self) -> None:
        """Release the source; safe to call when not open."""

    @property
    def frame_rate(self) -> float | None:
        """Nominal frame rate (frames per second), or None when unknown."""
        return None

    @property
    def resolution(self) -> tuple[int, int] | None:
        """(width, height) once known (after ``open`` for most readers), else None."""
        return None

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        """A calibration that comes with the source (sidecar file, simulator camera) and where from."""
        return None

    def spare(self) -> FrameReader | None:
        """A new, unopened reader of the same source with the same settings, or None: a looping
        capture opens it ahead of the pass's end (``dronekey.daemon.sources.next_pass``), so that the
        loop costs no reopen; None (the default) reopens this reader at the loop instead."""
        return None
