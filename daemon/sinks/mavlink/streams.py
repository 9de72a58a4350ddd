"""Per-message send intervals set by ground stations with MAV_CMD_SET_MESSAGE_INTERVAL.

The target messages (TARGET_RELATIVE, TARGET_ABSOLUTE, ADSB_VEHICLE) are sent on every track
update by default. A ground station may set, per message id, an interval in µs (each track then
gets at most one message per interval: the message's ``id`` is its instance), ``-1`` to stop the
message, or ``0`` to return to the default. Thread-safe: the receive thread sets intervals while
the sink's worker thread asks whether to send.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

__all__ = ["DEFAULT_INTERVAL", "DISABLED", "StreamRates"]

DEFAULT_INTERVAL = 0
DISABLED = -1


class StreamRates:
    """Intervals of a fixed set of streamable message ids, and the per-instance send schedule.

    Parameters
    ----------
    message_ids : the ids whose rate may be set (others are refused by ``set_interval``).
    """

    def __init__(self, message_ids: Iterable[int]) -> None:
        self._intervals_us: dict[int, int] = {int(m): DEFAULT_INTERVAL for m in message_ids}
        self._next_due_ns: dict[tuple[int, int], int] = {}
        self._lock = threading.Lock()

    @property
    def message_ids(self) -> tuple[int, ...]:
        return tuple(self._intervals_us)

    def supports(self, message_id: int) -> bool:
        return message_id in self._intervals_us

    def interval_us(self, message_id: int) -> int:
        """The configured interval: ``-1`` disabled, ``0`` default (every update), else µs."""
        with self._lock:
            return self._intervals_us[message_id]

    def set_interval(self, message_id: int, interval_us: int) -> None:
        """Set the interval of ``message_id`` (``-1`` disables it, ``0`` restores the default)."""
        if message_id not in self._intervals_us:
            raise KeyError(f"message id {message_id} is not a stream; streams: {sorted(self._intervals_us)}")
        if interval_us < DISABLED:
            raise ValueError(f"interval_us must be -1, 0 or positive, got {interval_us}")
        with self._lock:
            self._intervals_us[message_id] = int(interval_us)
            for key in [k for k in self._next_due_ns if k[0] == message_id]:
                del self._next_due_ns[key]

    def should_send(self, message_id: int, instance: int, now_ns: int) -> bool:
        """Whether to send ``message_id`` for ``instance`` (a track) at monotonic time ``now_ns``.

        With an interval the schedule advances by whole intervals, so the average rate is the one
        asked for even when updates arrive at a rate that is not a multiple of it.
        """
        with self._lock:
            interval = self._intervals_us[message_id]
            if interval == DISABLED:
                return False
            if interval == DEFAULT_INTERVAL:
                return True
            step = interval * 1000
            key = (message_id, instance)
            due = self._next_due_ns.get(key)
            if due is not None and now_ns < due:
                return False
            # Keep phase while on schedule; restart it after a gap longer than one interval.
            self._next_due_ns[key] = due + step if due is not None and now_ns - due < step else now_ns + step
            return True

    def forget(self, instance: int) -> None:
        """Drop the schedule of a finished instance (a lost track)."""
        with self._lock:
            for key in [k for k in self._next_due_ns if k[1] == instance]:
                del self._next_due_ns[key]
