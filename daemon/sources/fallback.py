"""A reader that is the first of several that opens: PyAV first, OpenCV where PyAV cannot open a file.

``source.decoder: auto`` reads files through PyAV and falls back to OpenCV's FFmpeg backend for a
file PyAV's build does not read (both are FFmpeg, with different codec sets). The choice is made at
each open, so a reopened (``--loop``) file stays with the reader that opened it before, unless that
one stops opening.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from dronekey.daemon.sources.base import FrameReader, ReadResult, SourceOpenError
from dronekey.geometry.camera import CameraModel

__all__ = ["FirstThatOpens"]

log = logging.getLogger(__name__)


class FirstThatOpens(FrameReader):
    """Delegates to the first of ``readers`` whose ``open`` succeeds (all of one kind and liveness)."""

    def __init__(self, readers: Sequence[FrameReader]) -> None:
        if not readers:
            raise ValueError("FirstThatOpens needs at least one reader")
        self.readers = list(readers)
        self.opened: FrameReader | None = None
        first = self.readers[0]
        self.live, self.kind, self.description = first.live, first.kind, first.description

    @property
    def decode_threads(self) -> int | None:
        """The opened reader's decoder threads (what the benchmarks report)."""
        return getattr(self.opened or self.readers[0], "decode_threads", None)

    def open(self) -> None:
        self.close()
        errors: list[SourceOpenError] = []
        ordered = sorted(self.readers, key=lambda r: r is not self.opened)  # the one that opened last, first
        for reader in ordered:
            try:
                reader.open()
            except SourceOpenError as exc:
                errors.append(exc)
                continue
            if reader is not self.readers[0] and self.opened is None:
                log.info("%s: %s; read with %s instead", self.description, errors[0], type(reader).__name__)
            self.opened = reader
            return
        raise errors[0]

    def read(self) -> ReadResult:
        assert self.opened is not None, "read() before open()"
        return self.opened.read()

    def close(self) -> None:
        for reader in self.readers:
            reader.close()

    def spare(self) -> FrameReader | None:
        """The spare of the reader that opened (the next pass stays with it), or None before any did."""
        return self.opened.spare() if self.opened is not None else None

    @property
    def frame_rate(self) -> float | None:
        return self.opened.frame_rate if self.opened else None

    @property
    def resolution(self) -> tuple[int, int] | None:
        return self.opened.resolution if self.opened else None

    def bundled_camera(self) -> tuple[CameraModel, str] | None:
        return self.readers[0].bundled_camera()
