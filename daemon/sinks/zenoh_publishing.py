"""What the Zenoh sink puts on the wire besides the payloads: attachments, cached publishers and the
per-track keys (docs/design.md §6.1, docs/outputs.md).

**Attachment** of every sample the sink sends (puts and deletes) and of every reply of the
live-tracks queryable: 16 bytes, little-endian, ``struct`` format ``<qQ``:

- int64 frame index: the source frame the sample belongs to (a status message: the last frame the
  sink had seen; -1 before the first one);
- uint64 sequence number: 0, 1, 2, ... per key expression, counting the samples this daemon run
  sent on that key, so a gap means a sample lost on the way (a gap in frame indices means frames
  the pipeline or the sink's queue dropped).

It is zenoh-ext's serialization of the tuple ``(Int64, UInt64)``: a reader decodes it with
``zenoh.ext.z_deserialize(tuple[Int64, UInt64], sample.attachment)`` or ``struct.unpack("<qQ", ...)``.

**Cached publishers** (zenoh-ext ``AdvancedPublisher``) keep the last ``history_depth`` samples of
their key, so an ``AdvancedSubscriber`` with ``HistoryConfig`` that joins late gets them at once;
they announce themselves (publisher detection) so a subscriber that was there first fetches the
history of a publisher that appears later; they number their samples for zenoh-ext's miss
detection. Puts and the cache's replies use congestion control DROP: a peer that never reads
costs dropped samples, never a blocked sink.

**Live tracks** (``LiveTracks``): one cached publisher per live track on
``dronekey/<camera_id>/tracks/<track_id>``, a DELETE there when the track is lost (or was not
updated for ``expiry_s``: its lost message was dropped on the way), and the answer of a queryable on
``dronekey/<camera_id>/tracks/*``, so a ``get`` or a storage holds exactly the live tracks.
"""

from __future__ import annotations

import logging
import struct
import threading
from dataclasses import dataclass

import zenoh
from zenoh import ext

__all__ = ["LiveTracks", "Sequenced", "declare_cached_publisher", "decode_attachment", "encode_attachment"]

log = logging.getLogger(__name__)

_ATTACHMENT = struct.Struct("<qQ")  # frame index (int64), sequence number (uint64)


def encode_attachment(frame_index: int, sequence: int) -> bytes:
    """The 16-byte attachment: frame index (int64, -1: none yet), sequence number (uint64), LE."""
    return _ATTACHMENT.pack(frame_index, sequence)


def decode_attachment(attachment: zenoh.ZBytes | bytes) -> tuple[int, int]:
    """``(frame_index, sequence)`` of an attachment made by ``encode_attachment``.

    Raises
    ------
    ValueError
        If it is not 16 bytes long.
    """
    data = attachment.to_bytes() if isinstance(attachment, zenoh.ZBytes) else bytes(attachment)
    if len(data) != _ATTACHMENT.size:
        raise ValueError(f"attachment must be {_ATTACHMENT.size} bytes, got {len(data)}")
    return _ATTACHMENT.unpack(data)


def declare_cached_publisher(
    session: zenoh.Session, key_expr: str, encoding: zenoh.Encoding, history_depth: int
) -> ext.AdvancedPublisher:
    """An advanced publisher on ``key_expr`` keeping its last ``history_depth`` samples for late
    joiners, with publisher detection and miss detection; puts and cache replies never block."""
    drop = zenoh.CongestionControl.DROP
    return ext.declare_advanced_publisher(
        session,
        key_expr,
        encoding=encoding,
        congestion_control=drop,
        cache=ext.CacheConfig(history_depth, replies_config=ext.RepliesConfig(congestion_control=drop)),
        sample_miss_detection=ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=None),
        publisher_detection=True,
    )


class Sequenced:
    """A publisher (plain or advanced) and the sequence number of its key; used by one thread."""

    def __init__(self, publisher: zenoh.Publisher | ext.AdvancedPublisher) -> None:
        self.publisher = publisher
        self.sequence = 0

    def put(self, payload: bytes, frame_index: int) -> bytes:
        """Publish ``payload`` with the attachment; returns the attachment."""
        attachment = self._next(frame_index)
        self.publisher.put(payload, attachment=attachment)
        return attachment

    def delete(self, frame_index: int) -> None:
        """Publish a DELETE of the key, with the attachment."""
        self.publisher.delete(attachment=self._next(frame_index))

    def undeclare(self) -> None:
        try:
            self.publisher.undeclare()
        except zenoh.ZError as exc:
            log.debug("zenoh undeclare failed: %s", exc)

    def _next(self, frame_index: int) -> bytes:
        attachment = encode_attachment(frame_index, self.sequence)
        self.sequence += 1
        return attachment


@dataclass
class _LiveTrack:
    publisher: Sequenced
    payload: bytes = b""
    attachment: bytes = b""
    updated_mono_ns: int = 0


class LiveTracks:
    """The per-track keys of one camera: ``<tracks_key>/<track_id>`` while the track lives.

    ``update``, ``expire`` and ``close`` are called from the sink's thread; ``answer`` (the
    queryable's callback) from Zenoh's, and reads a snapshot taken under a lock.

    Parameters
    ----------
    session : zenoh.Session
    tracks_key : str
        The stream key ``dronekey/<camera_id>/tracks``; per-track keys go below it.
    encoding : zenoh.Encoding
        Of the track messages.
    history_depth : int
        Samples each track's publisher keeps for late joiners.
    expiry_s : float
        A track not updated for this long (monotonic seconds) is deleted as if lost.
    """

    def __init__(
        self,
        session: zenoh.Session,
        tracks_key: str,
        encoding: zenoh.Encoding,
        history_depth: int,
        expiry_s: float,
    ) -> None:
        self._session = session
        self._prefix = tracks_key
        self._encoding = encoding
        self._history_depth = history_depth
        self._expiry_ns = int(expiry_s * 1e9)
        self._tracks: dict[int, _LiveTrack] = {}
        self._lock = threading.Lock()
        self.expired = 0  # tracks deleted because no update came for expiry_s
        self.replies = 0  # replies sent by ``answer``

    @property
    def key_pattern(self) -> str:
        """``dronekey/<camera_id>/tracks/*``: what the queryable answers."""
        return f"{self._prefix}/*"

    def key(self, track_id: int) -> str:
        return f"{self._prefix}/{track_id}"

    def __len__(self) -> int:
        return len(self._tracks)

    def update(self, track_id: int, lost: bool, payload: bytes, frame_index: int, now_mono_ns: int) -> None:
        """Publish a live track's message on its key, or delete the key of a lost one."""
        if lost:
            self._remove(track_id, frame_index)
            return
        live = self._tracks.get(track_id)
        if live is None:
            publisher = declare_cached_publisher(
                self._session, self.key(track_id), self._encoding, self._history_depth
            )
            live = _LiveTrack(Sequenced(publisher))
        attachment = live.publisher.put(payload, frame_index)
        with self._lock:
            live.payload, live.attachment, live.updated_mono_ns = payload, attachment, now_mono_ns
            self._tracks[track_id] = live

    def expire(self, now_mono_ns: int, frame_index: int) -> None:
        """Delete the keys of tracks not updated for ``expiry_s``."""
        stale = [tid for tid, t in self._tracks.items() if now_mono_ns - t.updated_mono_ns > self._expiry_ns]
        for track_id in stale:
            log.info(
                "zenoh: track %d not updated for %.1f s; deleting its key", track_id, self._expiry_ns / 1e9
            )
            self._remove(track_id, frame_index)
            self.expired += 1

    def close(self, frame_index: int) -> None:
        """Delete every live track's key (a storage keeps no track of a stopped daemon) and undeclare."""
        for track_id in list(self._tracks):
            try:
                self._remove(track_id, frame_index)
            except zenoh.ZError as exc:
                log.debug("zenoh delete of track %d failed: %s", track_id, exc)

    def answer(self, query: zenoh.Query) -> None:
        """Reply with the latest message of each live track whose key the query selects."""
        with self._lock:
            snapshot = [(self.key(tid), t.payload, t.attachment) for tid, t in self._tracks.items()]
        try:
            for key, payload, attachment in snapshot:
                if query.key_expr.intersects(zenoh.KeyExpr(key)):
                    query.reply(key, payload, encoding=self._encoding, attachment=attachment)
                    self.replies += 1
        except zenoh.ZError as exc:
            log.warning("zenoh live-tracks reply failed: %s", exc)

    def _remove(self, track_id: int, frame_index: int) -> None:
        with self._lock:
            live = self._tracks.pop(track_id, None)
        if live is None:
            return
        try:
            live.publisher.delete(frame_index)
        finally:
            live.publisher.undeclare()
