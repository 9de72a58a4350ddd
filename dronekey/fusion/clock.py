"""Each camera's clock put onto the fusion's clock.

Track times are the camera's own (docs/design.md §4): Unix epoch ns for live sources, stream PTS
for files. Daemons whose clocks are synchronised (NTP, PTP) can be trusted as they are; a file
replayed in real time, or a box without time sync, is not. The offset of a camera's clock is
estimated from when its messages arrive: ``arrival - t_ns`` is the offset plus a positive delay
(pipeline, network), so its minimum over a recent window is the offset plus the smallest delay,
the NTP-style estimate. The remaining error (the smallest delay's spread between cameras, tens of
milliseconds) is what ``FusionConfig.clock_std_s`` covers.

Modes: ``trust`` keeps every ``t_ns``; ``arrival`` always applies the estimated offset; ``auto``
(the default) trusts a camera whose ``t_ns`` lies within ``trust_window_s`` of the arrival time
(an epoch clock, synchronised) and estimates the offset of the others.
"""

from __future__ import annotations

from collections import deque

__all__ = ["CLOCK_MODES", "ClockAlignment"]

CLOCK_MODES = ("auto", "trust", "arrival")


class ClockAlignment:
    """Per-camera clock offsets (see the module docstring).

    Parameters
    ----------
    mode : "auto", "trust" or "arrival".
    window : arrivals per camera over which the smallest delay is taken.
    trust_window_s : in ``auto`` mode, a camera whose smallest ``arrival - t_ns`` is within
        [-trust_window_s, trust_window_s] keeps its own times.
    """

    def __init__(self, mode: str = "auto", window: int = 200, trust_window_s: float = 2.0) -> None:
        if mode not in CLOCK_MODES:
            raise ValueError(f"clock mode must be one of {CLOCK_MODES}, got {mode!r}")
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window!r}")
        if not trust_window_s > 0:
            raise ValueError(f"trust_window_s must be > 0, got {trust_window_s!r}")
        self._mode = mode
        self._window = int(window)
        self._trust_ns = int(trust_window_s * 1e9)
        self._delays: dict[str, deque[int]] = {}

    def observe(self, camera_id: str, t_ns: int, arrival_ns: int) -> int:
        """Record a message of ``camera_id`` stamped ``t_ns`` that arrived at ``arrival_ns`` (the
        fusion's clock) and return ``t_ns`` on the fusion's clock."""
        delays = self._delays.setdefault(camera_id, deque(maxlen=self._window))
        delays.append(int(arrival_ns) - int(t_ns))
        return self.to_fusion_clock(camera_id, t_ns)

    def offset_ns(self, camera_id: str) -> int:
        """What is added to ``camera_id``'s times to put them on the fusion's clock (0 when trusted
        or not yet seen)."""
        delays = self._delays.get(camera_id)
        if self._mode == "trust" or not delays:
            return 0
        smallest = min(delays)
        if self._mode == "auto" and abs(smallest) <= self._trust_ns:
            return 0
        return smallest

    def to_fusion_clock(self, camera_id: str, t_ns: int) -> int:
        """``t_ns`` of ``camera_id`` on the fusion's clock."""
        return int(t_ns) + self.offset_ns(camera_id)
