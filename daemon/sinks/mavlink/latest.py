"""The latest target messages of each live track, for MAV_CMD_REQUEST_MESSAGE.

A ground station that asks for TARGET_RELATIVE (or TARGET_ABSOLUTE, ADSB_VEHICLE) gets the last one
of every track still alive. A track is forgotten when it is lost, or when it has not been updated
for ``stale_s`` (a track that left without a LOST update). Thread-safe: the sink's worker puts,
the receive thread reads.
"""

from __future__ import annotations

import threading

__all__ = ["LatestTrackMessages"]


class LatestTrackMessages:
    """``{track id: (monotonic ns of the update, {message id: message})}`` behind a lock."""

    def __init__(self, stale_s: float = 5.0) -> None:
        self._stale_ns = int(stale_s * 1e9)
        self._by_track: dict[int, tuple[int, dict[int, object]]] = {}
        self._lock = threading.Lock()

    def put(self, track_id: int, now_ns: int, messages: dict[int, object]) -> None:
        with self._lock:
            self._by_track[track_id] = (now_ns, dict(messages))

    def forget(self, track_id: int) -> None:
        with self._lock:
            self._by_track.pop(track_id, None)

    def evict_stale(self, now_ns: int) -> list[int]:
        """Forget the tracks not updated within ``stale_s`` of ``now_ns``; return their ids."""
        limit = now_ns - self._stale_ns
        with self._lock:
            stale = [tid for tid, (t, _) in self._by_track.items() if t < limit]
            for tid in stale:
                del self._by_track[tid]
        return stale

    def of(self, message_id: int) -> list:
        """The latest ``message_id`` of every live track that has one."""
        with self._lock:
            return [m[message_id] for _, m in self._by_track.values() if message_id in m]
