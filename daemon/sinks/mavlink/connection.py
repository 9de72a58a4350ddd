"""The MAVLink sink's link: opened and reopened in the background, signed, and guarded on input.

``Connection`` owns the pymavlink connection and the one lock around its encoder and parser, whose
sequence numbers and signing state are not thread-safe. Opening never raises: a link that cannot be
opened (TCP peer absent, serial device missing) is retried with backoff (1 s doubling to 30 s) while
sends fail and are counted. With a signing key every message out is signed with a timestamp that
never goes back, across reconnections and (through ``SigningTimestampStore``) restarts.

Input is read only from admitted peers (``peers``: the link's own peer, the first one heard, or
``allow``), one UDP datagram at a time (``framing``), and with signing on only when correctly
signed and newer than its stream's last message (``verify``). Everything refused is counted by
reason (``refusals``).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import socket
import threading
import time
from pathlib import Path

from pymavlink import mavutil

from .framing import parse_datagram
from .link import is_datagram, local_address, open_link, read_datagram, send_datagram_to
from .peers import PeerPolicy
from .refusals import Refusals
from .signing import SigningTimestampStore, default_state_dir, now_signing_timestamp, read_signing_key
from .verify import DEFAULT_MAX_STREAMS, SignatureCheck, StreamTimestamps

__all__ = ["Connection", "Received"]

log = logging.getLogger(__name__)

_RETRY_MIN_S, _RETRY_MAX_S = 1.0, 30.0
_MAX_UDP_CLIENTS = 16  # a listening link sends to at most this many admitted peers, last heard kept

Address = tuple[str, int]


class Received(collections.namedtuple("Received", "messages peer datagram")):
    """Valid messages of one read from an admitted peer (``peer`` None on tcp and serial links);
    ``datagram``: a UDP link, where replies go back to ``peer``."""


class Connection:
    """One pymavlink link as our system and component (see the module docstring).

    Parameters
    ----------
    url : a validated connection string (``link.validate_url``).
    dialect : the generated dialect module (``dialect.load_dialect``).
    sysid, compid : our MAVLink system and component ids.
    peers : who may send us anything.
    refusals : where refused input is counted.
    signing_key_file : file with the 32-byte signing key; None: unsigned.
    signing_state_dir : folder of the signing state files, ``mavlink-signing-<sysid>-<compid>``
        ``.timestamp`` (ours) and ``.streams`` (the accepted timestamps of incoming signed streams);
        default ``$STATE_DIRECTORY`` or the key's folder.
    max_signed_streams : incoming signed streams whose timestamps are kept, oldest evicted first.
    """

    def __init__(
        self,
        url: str,
        dialect,
        sysid: int,
        compid: int,
        *,
        peers: PeerPolicy,
        refusals: Refusals,
        signing_key_file: str | os.PathLike | None = None,
        signing_state_dir: str | os.PathLike | None = None,
        max_signed_streams: int = DEFAULT_MAX_STREAMS,
    ) -> None:
        self.url = url
        self._d = dialect
        self._sysid, self._compid = sysid, compid
        self.peers = peers
        self._refusals = refusals
        self.key: bytes | None = None
        self._ts_store: SigningTimestampStore | None = None
        self.streams = StreamTimestamps(None, max_signed_streams)
        if signing_key_file is not None:
            self.key = read_signing_key(signing_key_file)
            state_dir = (
                Path(signing_state_dir)
                if signing_state_dir is not None
                else default_state_dir(signing_key_file)
            )
            stem = state_dir / f"mavlink-signing-{sysid}-{compid}"
            self._ts_store = SigningTimestampStore(stem.with_suffix(".timestamp"))
            self.streams = StreamTimestamps(stem.with_suffix(".streams"), max_signed_streams)
        self._check = SignatureCheck(self.streams, self._note_signing_refusal)
        self._source: str | None = None  # sender of the datagram being parsed (under lock)

        self.lock = threading.Lock()  # the connection and its pymavlink encoder/parser
        self._counts_lock = threading.Lock()
        self._conn = None
        self._closed = False
        self._retry_s = _RETRY_MIN_S
        self._next_open_mono = 0.0
        self._last_signing_ts = 0
        self.last_error: str | None = None
        self.local: str | None = None
        self._sent: collections.Counter = collections.Counter()
        self._send_errors = 0
        self._last_send_error: str | None = None

    @property
    def is_open(self) -> bool:
        return self._conn is not None

    def health(self) -> dict:
        """The link's part of the sink's health: state, local socket, what was sent and what failed."""
        with self._counts_lock:
            return {
                "url": self.url,
                "link_open": self._conn is not None,
                "last_link_error": self.last_error,
                "signing": self.key is not None,
                "sent": dict(self._sent),
                "send_errors": self._send_errors,
                "last_send_error": self._last_send_error,
                "local": self.local,
            }

    # ------------------------------------------------------------------ opening and closing

    def open_if_due(self) -> None:
        """Open the link if it is closed and its retry time has come; never raises."""
        with self.lock:
            if self._conn is not None or self._closed or time.monotonic() < self._next_open_mono:
                return
            try:
                self.peers.resolve(_named_peer(self.url))
                conn = open_link(self.url, self._d, self._sysid, self._compid)
            except Exception as exc:
                msg = f"{type(exc).__name__}: {exc}"
                if msg != self.last_error:
                    log.warning(
                        "MAVLink link %s cannot be opened (%s); retrying in the background", self.url, msg
                    )
                self.last_error = msg
                self._next_open_mono = time.monotonic() + self._retry_s
                self._retry_s = min(self._retry_s * 2, _RETRY_MAX_S)
                return
            if self.key is not None:
                start = max(self._ts_store.initial_timestamp(), self._last_signing_ts + 1)
                conn.setup_signing(
                    self.key,
                    sign_outgoing=True,
                    allow_unsigned_callback=self._check.refuse,
                    initial_timestamp=start,
                    link_id=1,
                )
                self._check.install(conn.mav)
                self._last_signing_ts = start
            self._conn = conn
            self.local = local_address(conn)
            self._retry_s = _RETRY_MIN_S
            self.last_error = None
        log.info(
            "MAVLink on %s%s as system %d component %d, signing %s; commands only from %s",
            self.url,
            f" (socket {self.local})" if self.local else "",
            self._sysid,
            self._compid,
            "on" if self.key is not None else "off",
            self.peers.describe(),
        )

    def save_signing_timestamp(self) -> None:
        """Write our signing timestamp to its file (with a key), so a restart continues after it."""
        with self.lock:
            self._save_signing_timestamp_locked()

    def stop(self) -> None:
        """Closing has begun: the link is not reopened, and a failed read no longer drops it."""
        self._closed = True

    def close(self) -> None:
        """Save the signing state and close the link; it is not reopened. Idempotent."""
        self.stop()
        with self.lock:
            self._save_signing_timestamp_locked()
            conn, self._conn = self._conn, None
        self.streams.save()
        if conn is not None:
            try:
                conn.close()
            except Exception as exc:
                log.debug("closing the MAVLink link: %s", exc)

    def _save_signing_timestamp_locked(self) -> None:
        if self._ts_store is not None and self._last_signing_ts:
            self._ts_store.save(self._last_signing_ts)

    def _drop_locked(self, exc: BaseException) -> None:
        """Close a failed link (caller holds ``lock``); ``open_if_due`` reopens it."""
        self._save_signing_timestamp_locked()
        self.streams.save()
        conn, self._conn = self._conn, None
        self.last_error = f"{type(exc).__name__}: {exc}"
        log.warning("MAVLink link %s failed (%s); reopening in the background", self.url, self.last_error)
        self._next_open_mono = time.monotonic() + self._retry_s
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()

    # ------------------------------------------------------------------ sending

    def send(self, msg, reply_to: Address | None = None) -> bool:
        """Send ``msg`` on the link; a reply on a UDP link that sends to one destination goes to
        ``reply_to`` instead (an allow-listed station that is not the udpout target)."""
        with self.lock:
            conn = self._conn
            if conn is None:
                self._count_send_error("link not open")
                return False
            try:
                if self.key is not None:
                    sig = conn.mav.signing
                    sig.timestamp = max(sig.timestamp, now_signing_timestamp())
                if reply_to is not None and is_datagram(conn) and not conn.udp_server:
                    send_datagram_to(conn, msg, reply_to)
                else:
                    conn.mav.send(msg)
                if self.key is not None:
                    self._last_signing_ts = conn.mav.signing.timestamp
            except Exception as exc:  # pymavlink's writers swallow socket errors; serial ones may not
                self._count_send_error(f"{type(exc).__name__}: {exc}")
                if isinstance(exc, OSError) and reply_to is None:
                    self._drop_locked(exc)
                return False
        with self._counts_lock:
            self._sent[msg.get_type()] += 1
        return True

    def _count_send_error(self, what: str) -> None:
        with self._counts_lock:
            self._send_errors += 1
            self._last_send_error = what

    # ------------------------------------------------------------------ receiving

    def receive(self, timeout_s: float) -> Received | None:
        """Wait up to ``timeout_s`` for data, and return what an admitted peer sent that passed
        every check; None when nothing did (refusals are counted, a dead link is dropped)."""
        conn = self._conn
        if conn is None:
            return None
        datagram = is_datagram(conn)
        try:
            if not conn.select(timeout_s):
                return None
            if datagram:
                data, peer = read_datagram(conn)
            else:
                data, peer = conn.recv(), _stream_peer(conn)
        except Exception as exc:
            if not self._closed:
                with self.lock:
                    if self._conn is conn:
                        self._drop_locked(exc)
            return None
        if not data:
            if isinstance(conn, mavutil.mavtcp) or getattr(conn, "portdead", False):
                with self.lock:  # readable and empty: the stream peer closed
                    if self._conn is conn:
                        self._drop_locked(ConnectionError("peer closed the connection"))
            return None
        source = f"{peer[0]}:{peer[1]}" if peer is not None else None
        if peer is not None and not self.peers.admits(peer):
            self._refusals.note("peer", source)
            if isinstance(conn, mavutil.mavtcpin):
                self._drop_tcp_client(conn)
            return None
        with self.lock:
            if self._conn is not conn:
                return None
            self._source = source
            try:
                if datagram:
                    received, malformed = parse_datagram(conn.mav, data)
                else:
                    received, malformed = conn.mav.parse_buffer(data) or [], False
            finally:
                self._source = None
        if malformed:
            self._refusals.note("malformed", source)
        valid = [m for m in received if m.get_type() != "BAD_DATA"]
        if not valid:
            return None
        if peer is not None:
            self.peers.confirm(peer)
            if datagram:
                self._remember_client(conn, peer)
        return Received(valid, peer, datagram)

    def _note_signing_refusal(self, reason: str) -> None:
        """``SignatureCheck``'s report (called while parsing, under ``lock``)."""
        self._refusals.note(reason, self._source)

    def _remember_client(self, conn, peer: Address) -> None:
        """An admitted peer was heard: a listening link sends to it, a broadcast link switches to it."""
        with self.lock:
            if self._conn is not conn:
                return
            if conn.udp_server:
                conn.clients.add(peer)
                conn.clients_last_alive[peer] = time.time()
                while len(conn.clients) > _MAX_UDP_CLIENTS:
                    oldest = min(conn.clients, key=lambda a: conn.clients_last_alive.get(a, 0.0))
                    conn.clients.discard(oldest)
                    conn.clients_last_alive.pop(oldest, None)
            elif conn.broadcast:
                conn.last_address = peer

    def _drop_tcp_client(self, conn) -> None:
        """Hang up on a tcpin client that is not admitted; the link keeps listening."""
        with self.lock:
            if self._conn is conn and conn.port is not None:
                with contextlib.suppress(OSError):
                    conn.port.close()
                conn.port = None
                conn.fd = conn.listen.fileno()


def _named_peer(url: str) -> Address | None:
    """The peer a URL names (udpout and tcp targets), resolved; None for listening and serial links."""
    scheme, _, rest = url.partition(":")
    if scheme not in ("udpout", "tcp"):
        return None
    host, _, port = rest.rpartition(":")
    return socket.gethostbyname(host), int(port)


def _stream_peer(conn) -> Address | None:
    """The client of a tcpin link (checked against the peers); None for tcp and serial links."""
    if isinstance(conn, mavutil.mavtcpin) and conn.port is not None:
        try:
            return conn.port.getpeername()[:2]
        except OSError:
            return None
    return None
