"""Frame-to-publish latencies of a whole run at constant memory: counts in log-spaced bins.

A sink worker's status keeps the last 2,048 latencies (the live view); a benchmark's p99 "over
five minutes" or "over an hour" needs every frame of the run, which a list of values would hold
with memory growing by the frame (a soak measures that growth). The histogram's bins are 0.2 %
wide from 0.01 ms to 1,000 s (9,212 of them, 74 KB), so a percentile read from it is within
0.1 % of the exact one.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["LatencyHistogram"]

_LOW_MS = 0.01  # the first bin's lower edge; shorter latencies count in it
_RATIO = 1.002  # each bin's upper edge over its lower one
_LOG_RATIO = math.log(_RATIO)
_BINS = math.ceil(math.log(1e6 / _LOW_MS) / _LOG_RATIO)  # up to 1,000 s; longer count in the last


class LatencyHistogram:
    """Counts of latencies (ms) in log-spaced bins; ``percentile`` over every one added.

    ``since(earlier)`` gives the latencies added after a ``copy()`` taken earlier (a benchmark's
    window after its warm-up).
    """

    def __init__(self) -> None:
        self.counts = np.zeros(_BINS, dtype=np.int64)

    @property
    def count(self) -> int:
        """Latencies added."""
        return int(self.counts.sum())

    def add(self, latency_ms: float) -> None:
        """Count one latency, ms (a NaN is ignored)."""
        if latency_ms != latency_ms:
            return
        if latency_ms <= _LOW_MS:
            index = 0
        else:
            index = min(int(math.log(latency_ms / _LOW_MS) / _LOG_RATIO), _BINS - 1)
        self.counts[index] += 1

    def copy(self) -> LatencyHistogram:
        """A snapshot (its counts are not changed by later ``add``)."""
        out = LatencyHistogram()
        out.counts = self.counts.copy()
        return out

    def since(self, earlier: LatencyHistogram) -> LatencyHistogram:
        """The latencies added after ``earlier`` (a ``copy()`` of this histogram) was taken."""
        out = LatencyHistogram()
        out.counts = self.counts - earlier.counts
        if np.any(out.counts < 0):
            raise ValueError("earlier must be a copy of this histogram taken before, not another's")
        return out

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0-100) in ms, at its bin's geometric middle; NaN when empty.

        The rank is numpy's default (linear): of n latencies, the one at rank ``q / 100 * (n - 1)``
        counted from 0, rounded up to a whole latency.
        """
        if not 0.0 <= q <= 100.0:
            raise ValueError(f"q must be within 0-100, got {q!r}")
        n = self.count
        if n == 0:
            return math.nan
        rank = math.ceil(q / 100.0 * (n - 1))
        index = int(np.searchsorted(np.cumsum(self.counts), rank + 1))
        return _LOW_MS * _RATIO ** (index + 0.5)
