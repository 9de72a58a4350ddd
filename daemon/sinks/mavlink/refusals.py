"""Counting what the MAVLink link refused, and saying so at a bounded rate.

Refused input is attacker-controlled: logging each refusal lets a flood of forged packets become a
flood of log lines (60,000 wrong-key packets once wrote 119,998 lines). So refusals are counted by
reason, and at most one summary line per ``period_s`` reports them: the first refusal at once, the
rest when the period has passed (``flush``, called by the sink's housekeeping, reports what arrived
since even when nothing more comes).

Reasons: ``peer`` (not an admitted sender, ``peers``), ``unsigned``, ``bad_signature`` (wrong key or
corrupted), ``replay`` (a signing timestamp not newer than the stream's last, ``verify``), and
``malformed`` (a datagram with bytes that are not a whole valid message).
"""

from __future__ import annotations

import logging
import threading
import time

__all__ = ["REASONS", "Refusals"]

log = logging.getLogger(__name__)

REASONS = ("peer", "unsigned", "bad_signature", "replay", "malformed")
_WHY = {
    "peer": "not an admitted peer",
    "unsigned": "unsigned",
    "bad_signature": "wrong signature",
    "replay": "replayed or old signing timestamp",
    "malformed": "malformed datagram",
}


class Refusals:
    """Thread-safe counters of refused input, by reason, with a rate-limited summary log.

    Parameters
    ----------
    period_s : at most one summary line per this many seconds.
    """

    def __init__(self, period_s: float = 60.0) -> None:
        if not period_s > 0:
            raise ValueError(f"refusal log period_s must be > 0, got {period_s!r}")
        self._period_s = float(period_s)
        self._counts = dict.fromkeys(REASONS, 0)
        self._unreported = dict.fromkeys(REASONS, 0)
        self._last: tuple[str, str | None] | None = None
        self._last_log = -float("inf")
        self._lock = threading.Lock()

    def note(self, reason: str, source: str | None = None) -> None:
        """Count one refusal (``source``: who sent it, e.g. ``"10.0.0.7:14550"``)."""
        if reason not in self._counts:
            raise ValueError(f"refusal reason {reason!r} is not one of {REASONS}")
        with self._lock:
            self._counts[reason] += 1
            self._unreported[reason] += 1
            self._last = (reason, source)
        self.flush()

    def flush(self, now: float | None = None) -> None:
        """Log the unreported refusals if there are any and the period since the last line has passed."""
        now = time.monotonic() if now is None else now
        with self._lock:
            if not any(self._unreported.values()) or now - self._last_log < self._period_s:
                return
            self._last_log = now
            parts = ", ".join(f"{r} {n}" for r, n in self._unreported.items() if n)
            n_new = sum(self._unreported.values())
            total = sum(self._counts.values())
            reason, source = self._last
            self._unreported = dict.fromkeys(REASONS, 0)
        log.warning(
            "MAVLink refused %d message%s (%s; the last%s: %s); %d in all, at most one such line per %g s",
            n_new,
            "" if n_new == 1 else "s",
            parts,
            f" from {source}" if source else "",
            _WHY[reason],
            total,
            self._period_s,
        )

    def counts(self) -> dict[str, int]:
        """Refusals so far, by reason."""
        with self._lock:
            return dict(self._counts)

    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())
