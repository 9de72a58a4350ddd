"""Accepting an incoming signed MAVLink 2 message: signature first, then the stream's replay window.

Why this replaces pymavlink's ``MAVLink.check_signature``: pymavlink stores a packet's timestamp as
its stream's (link id, system, component) latest *before* it checks the signature. One packet with
a wrong key and the timestamp 2^48-2 on a ground station's stream then makes every later,
correctly signed message of that station "old", refused until restart. Its stream table also grows
with every forged (link, system, component), and it logs each new stream and mismatch at INFO. Here:

1. the signature (the first 6 bytes of SHA-256 over key + packet without them) is compared in
   constant time, and a mismatch is refused without touching any state;
2. only then is the timestamp checked against the stream's last accepted one (newer passes; a new
   stream passes if at most one minute behind our own signing timestamp, as pymavlink and the
   MAVLink spec say) and recorded.

The per-stream timestamps (``StreamTimestamps``) are kept in a JSON state file beside the outgoing
signing timestamp, so a packet captured in one run is still "old" in the next (a replay across a
restart). At most ``max_streams`` streams are kept, the least recently accepted evicted first;
only correctly signed packets add streams, so only a key holder can fill the table. An evicted
stream falls back to the new-stream rule.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import os
import threading
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

from .signing import write_atomically

__all__ = ["DEFAULT_MAX_STREAMS", "NEW_STREAM_WINDOW", "SignatureCheck", "StreamTimestamps"]

log = logging.getLogger(__name__)

DEFAULT_MAX_STREAMS = 256
NEW_STREAM_WINDOW = 6_000_000  # one minute in 10 µs units: how far behind ours a new stream may start
_TIMESTAMP_MAX = (1 << 48) - 1
StreamKey = tuple[int, int, int]  # (link id, system id, component id)


class StreamTimestamps:
    """The last accepted signing timestamp of each incoming stream: capped, persisted, thread-safe.

    Parameters
    ----------
    path : the JSON state file (loaded now if it exists; written by ``save``), or None to keep the
        state in memory only.
    max_streams : at most this many streams; the least recently accepted is evicted first.
    """

    def __init__(self, path: str | os.PathLike | None, max_streams: int = DEFAULT_MAX_STREAMS) -> None:
        if not isinstance(max_streams, int) or max_streams < 1:
            raise ValueError(f"max_streams must be a positive integer, got {max_streams!r}")
        self.path = Path(path) if path is not None else None
        self.max_streams = max_streams
        self._last: OrderedDict[StreamKey, int] = OrderedDict()
        self._lock = threading.Lock()
        self._dirty = False
        self._warned = False
        if self.path is not None:
            self._load()

    def __len__(self) -> int:
        with self._lock:
            return len(self._last)

    def snapshot(self) -> dict[StreamKey, int]:
        """The streams and their timestamps, least recently accepted first."""
        with self._lock:
            return dict(self._last)

    def accept(self, key: StreamKey, timestamp: int, our_timestamp: int) -> bool:
        """Record ``timestamp`` for ``key`` if it is acceptable (call only after the signature passed)."""
        with self._lock:
            last = self._last.get(key)
            if last is not None:
                if timestamp <= last:
                    return False
            elif timestamp + NEW_STREAM_WINDOW < our_timestamp:
                return False
            self._last[key] = timestamp
            self._last.move_to_end(key)
            while len(self._last) > self.max_streams:
                self._last.popitem(last=False)
            self._dirty = True
            return True

    def save(self) -> bool:
        """Write the table if it changed since the last save; False if writing failed."""
        if self.path is None:
            return True
        with self._lock:
            if not self._dirty:
                return True
            rows = [[*key, ts] for key, ts in self._last.items()]
            self._dirty = False
        try:
            write_atomically(self.path, json.dumps({"version": 1, "streams": rows}) + "\n")
        except OSError as exc:
            with self._lock:
                self._dirty = True
            if not self._warned:
                self._warned = True
                log.warning(
                    "cannot save the MAVLink incoming signing timestamps to %s (%s); after a restart, "
                    "messages captured in this run may be accepted again",
                    self.path,
                    exc.strerror,
                )
            return False
        return True

    def _load(self) -> None:
        try:
            data = json.loads(self.path.read_text())
            rows = data["streams"]
            table = OrderedDict()
            for row in rows:
                link, sysid, compid, ts = (int(v) for v in row)
                if not (max(link, sysid, compid) <= 255 and min(link, sysid, compid) >= 0):
                    raise ValueError(f"stream {row!r} out of range")
                if not 0 <= ts <= _TIMESTAMP_MAX:
                    raise ValueError(f"stream {row!r} out of range")
                table[(link, sysid, compid)] = ts
        except FileNotFoundError:
            return
        except OSError as exc:
            log.warning("cannot read the MAVLink incoming signing timestamps %s: %s", self.path, exc.strerror)
            return
        except (ValueError, TypeError, KeyError) as exc:
            log.warning("ignoring a corrupt MAVLink incoming signing timestamps file %s (%s)", self.path, exc)
            return
        while len(table) > self.max_streams:
            table.popitem(last=False)
        self._last = table


class SignatureCheck:
    """Stands in for pymavlink's signature check on one or more parsers (``install``).

    Parameters
    ----------
    streams : where accepted timestamps are recorded.
    on_refusal : ``f(reason)`` for each refused message, reason ``"unsigned"``, ``"bad_signature"``
        or ``"replay"`` (``refusals.REASONS``).

    pymavlink calls ``check`` for a signed packet, then, if it failed or the packet is unsigned, the
    link's ``allow_unsigned_callback``; pass ``refuse`` as that callback so every refusal is
    reported once, with its reason.
    """

    def __init__(self, streams: StreamTimestamps, on_refusal: Callable[[str], None]) -> None:
        self._streams = streams
        self._on_refusal = on_refusal
        self._pending: str | None = None

    def install(self, mav) -> None:
        """Make ``mav`` (a dialect ``MAVLink`` with its secret key set) use this check.

        ``MAVLink.decode`` calls ``self.check_signature(...)``; an instance attribute takes
        precedence over the class's method, so only this parser is affected.
        """
        mav.check_signature = lambda msgbuf, sysid, compid: self.check(mav, msgbuf, sysid, compid)

    def check(self, mav, msgbuf, src_system: int, src_component: int) -> bool:
        """Whether the signed packet ``msgbuf`` (header to signature) is genuine and new."""
        key = mav.signing.secret_key
        packet = bytes(msgbuf)
        expected = hashlib.sha256(key + packet[:-6]).digest()[:6]
        if not hmac.compare_digest(expected, packet[-6:]):
            self._pending = "bad_signature"
            return False
        link_id = packet[-13]
        timestamp = int.from_bytes(packet[-12:-6], "little")
        if not self._streams.accept((link_id, src_system, src_component), timestamp, mav.signing.timestamp):
            self._pending = "replay"
            return False
        # As pymavlink does: what we send next is stamped at least as late as what we accepted.
        mav.signing.timestamp = max(mav.signing.timestamp, timestamp)
        return True

    def refuse(self, mav, msg_id: int) -> bool:
        """pymavlink's ``allow_unsigned_callback``: refuse (False), reporting why once."""
        reason, self._pending = self._pending or "unsigned", None
        self._on_refusal(reason)
        return False
