"""A looping file's next pass, opened on a helper thread while the current pass plays.

Reopening a file at its end costs 70-90 ms on the 2-core box (PyAV: ``av.open``'s stream probe about
35 ms, then the decoder's start and the first frame about 40 ms). A paced replay stands in for a
camera, which never reopens; charged to the next pass's first frames, the reopen showed as their
latency (one camera, 1,800 paced frames of a 400-frame clip: each pass's first three frames were a
third of the slowest 2 %, docs/performance.md). ``NextPass`` opens a fresh reader of the same file
(``FrameReader.spare``) in the background, and ``Capture`` swaps it in at the loop. A reader that
cannot make a spare (OpenCV, image folders, the simulator) reopens itself at the loop as before.
"""

from __future__ import annotations

import logging
import threading

from dronekey.daemon.sources.base import FrameReader

__all__ = ["NextPass"]

log = logging.getLogger(__name__)


class NextPass:
    """Opens ``reader.spare()`` on a daemon thread at once; ``take`` hands it over opened.

    Parameters
    ----------
    reader : FrameReader
        The reader of the pass now playing; only its ``spare`` is called, on the calling thread.
    """

    def __init__(self, reader: FrameReader) -> None:
        self._spare = reader.spare()
        self._error: BaseException | None = None
        self._lock = threading.Lock()
        self._opened = False  # the helper is done with the spare (opened or failed)
        self._discarded = False
        self._thread: threading.Thread | None = None
        if self._spare is not None:
            self._thread = threading.Thread(target=self._open, name="capture-next-pass", daemon=True)
            self._thread.start()

    def _open(self) -> None:
        spare = self._spare  # held here: ``discard`` may drop the attribute meanwhile
        assert spare is not None
        try:
            spare.open()
        except Exception as exc:  # the capture reopens its own reader and reports what that says
            self._error = exc
        with self._lock:
            self._opened = True
            if self._discarded:
                spare.close()

    def take(self) -> FrameReader | None:
        """The next pass's reader, opened (waits for the helper if it is still opening), or None when
        there is none or it failed to open: the capture then reopens its own reader."""
        if self._thread is None or self._spare is None:
            return None
        self._thread.join()
        spare, self._spare = self._spare, None
        if self._error is not None:
            log.debug("%s: the next pass failed to open ahead (%s)", spare.description, self._error)
            spare.close()
            return None
        return spare

    def discard(self) -> None:
        """Close the spare, now or once its helper finishes opening it (the capture is stopping)."""
        with self._lock:
            self._discarded = True
            spare, self._spare = self._spare, None
            if spare is not None and self._opened:  # else the helper closes it when it is done
                spare.close()
