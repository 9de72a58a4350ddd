"""A recorded file's frame timestamps: frames lost in PTS gaps, and timestamps that always increase.

Shared by the file readers (OpenCV's and PyAV's) so both count corrupt frames the same way:

- FFmpeg drops a frame whose MPEG-TS packets are damaged without a decode error: the next good frame
  comes back, and only its timestamp shows what is missing. In a constant-rate file, a step of k
  frame intervals means k - 1 frames were lost (``lost_before``).
- A step off that grid means a variable frame rate: gaps are no longer counted.
- A jump longer than ``MAX_COUNTED_GAP_S`` is a discontinuity (a concatenated or restarted
  stream), not lost frames.
- Timestamps that do not increase (some containers carry none) are replaced by steps of the nominal
  frame interval (``stamp``).
"""

from __future__ import annotations

import logging
from pathlib import Path

from dronekey.daemon.sources.base import ReadResult, SourceOpenError

__all__ = ["MAX_COUNTED_GAP_S", "PTS_GRID_TOLERANCE", "FileTimeline", "FirstFramePeek"]

log = logging.getLogger(__name__)

# Timestamps that step by k frame intervals (within this share of one) lost k - 1 frames.
PTS_GRID_TOLERANCE = 0.2
MAX_COUNTED_GAP_S = 10.0


class FileTimeline:
    """The timestamp bookkeeping of one pass over a file (``reset`` at each open).

    ``name``: the file, for log lines. ``fps``: its nominal frame rate, or None when unknown (then
    no gap is counted).
    """

    def __init__(self, name: str) -> None:
        self.name = name
        self.fps: float | None = None
        self._last_t_ns: int | None = None
        self._gap = (0, 0)  # (after, before) t_ns of the last counted gap: frames inside it were lost
        self._variable_rate = False
        self._warned_pts = False

    def reset(self, fps: float | None) -> None:
        """A new pass over the file (open, or reopen for ``--loop``) at nominal rate ``fps``."""
        self.fps = fps
        self._last_t_ns = None
        self._gap = (0, 0)

    def in_counted_gap(self, t_ns: int) -> bool:
        """A frame stamped ``t_ns`` that the decoder hands over late, after it resynchronised past the
        damage (a B-frame): out of order, and already counted among the frames of that gap."""
        return self._gap[0] < t_ns < self._gap[1]

    def lost_before(self, t_ns: int) -> int:
        """Frames missing before the one stamped ``t_ns`` (ns from the stream's start).

        Timestamps start at 0, so frames lost before the first good one count too.
        """
        if not self.fps or self._variable_rate:
            return 0
        last = self._last_t_ns if self._last_t_ns is not None else -round(1e9 / self.fps)
        if t_ns <= last:
            return 0
        gap_ns = t_ns - last
        steps = gap_ns * self.fps / 1e9
        if abs(steps - round(steps)) > PTS_GRID_TOLERANCE:
            self._variable_rate = True
            log.info("%s: variable frame rate; frames lost in timestamp gaps are not counted", self.name)
            return 0
        if gap_ns > MAX_COUNTED_GAP_S * 1e9:
            log.warning("%s: timestamps jump by %.1f s; not counted as lost frames", self.name, gap_ns / 1e9)
            return 0
        lost = round(steps) - 1
        if lost:
            self._gap = (last, t_ns)
        return lost

    def stamp(self, t_ns: int | None) -> int:
        """The timestamp to publish for a frame whose PTS gives ``t_ns`` (None: it has none):
        strictly increasing."""
        if t_ns is None:
            t_ns = -1 if self._last_t_ns is not None else 0
        if self._last_t_ns is not None and t_ns <= self._last_t_ns:
            if not self._warned_pts:
                log.warning("%s: presentation timestamps do not increase; using the frame rate", self.name)
                self._warned_pts = True
            t_ns = self._last_t_ns + round(1e9 / (self.fps or 30.0))
        self._last_t_ns = t_ns
        return t_ns


class FirstFramePeek:
    """The file readers' first frame, decoded at ``open`` and handed out by the first ``read``.

    Decoding it at open gives the frame size before the pipeline is built, and turns a file that
    holds no decodable frame into an open error. The reader provides ``path``, ``close()`` and
    ``_decode_next()``, and sets ``_peeked = None`` and ``_warned_truncated = False`` at init.
    """

    path: Path
    _peeked: ReadResult | None
    _warned_truncated: bool
    _size: tuple[int, int] | None

    def _peek_first_frame(self, cut: str | None) -> None:
        """Decode the first frame; ``cut`` is the file's truncation, if any (``truncation``)."""
        first = self._decode_next()
        if first.image is None:
            self.close()
            why = f": the file is truncated ({cut})" if cut else ""
            raise SourceOpenError(f"{self.path} holds no decodable video frame{why}")
        if cut and not self._warned_truncated:  # said once, not on every pass of --loop
            log.warning("%s is truncated (%s): reading the frames it holds", self.path, cut)
            self._warned_truncated = True
        self._size = (first.image.shape[1], first.image.shape[0])
        self._peeked = first

    def read(self) -> ReadResult:
        if self._peeked is not None:
            result, self._peeked = self._peeked, None
            return result
        return self._decode_next()
