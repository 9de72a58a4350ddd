"""Zenoh output (docs/design.md §6.1): track updates, live-track keys, status, a liveliness token and
an info queryable, with a history cache for subscribers that join late.

Key expressions, for camera id ``<id>``:

- ``dronekey/<id>/tracks``: the stream, one JSON message per track update (schema ``track``),
- ``dronekey/<id>/tracks/<track_id>``: the latest message of each live track, DELETE when the track
  is lost; a cached (zenoh-ext advanced) publisher per track, and a queryable on
  ``dronekey/<id>/tracks/*`` answering the live tracks, so a ``get`` or a storage holds exactly them,
- ``dronekey/<id>/status``: the status message, about 1 Hz (schema ``status``), cached,
- ``dronekey/<id>/alive``: liveliness token, present while the daemon runs,
- ``dronekey/<id>/info``: queryable answering the info message (camera, calibration, model, version).

Payloads are UTF-8 JSON with encoding ``application/json;dronekey.<Track|Status|Info>``. Every
sample carries the frame index and its key's sequence number as a 16-byte attachment
(``zenoh_publishing``). An advanced subscriber with history that joins late gets the latest status
and the latest message of each live track at once.

The session opens on a background thread and never blocks or fails the daemon: peer mode (the
default) works with no router at all; in client mode a missing router only means the thread retries
with backoff (0.5 s doubling to ``retry_max_s``) while ``health()`` says ``"connecting"``; messages
published meanwhile are counted as ``not_sent`` and dropped (tracks are live data, not a log).
Publishers and the cache's replies use congestion control DROP, so a slow network or a peer that
never reads never stalls the sink thread.

Secure by default (docs/security.md, ``zenoh_session``): a peer listens on ``tcp/127.0.0.1:0`` only
and a client not at all, and scouting is off; one INFO line at start says what the session exposes.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import zenoh

from dronekey.daemon import messages
from dronekey.daemon.config.camera import check_camera_id
from dronekey.daemon.config.zenoh import ZenohConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.zenoh_publishing import LiveTracks, Sequenced, declare_cached_publisher
from dronekey.daemon.sinks.zenoh_session import CallbackThreads, describe_exposure, zenoh_config
from dronekey.types import TrackStatus

__all__ = ["ZenohSink", "describe_exposure", "zenoh_config"]

log = logging.getLogger(__name__)

_TRACK_ENCODING = zenoh.Encoding.APPLICATION_JSON.with_schema("dronekey.Track")
_STATUS_ENCODING = zenoh.Encoding.APPLICATION_JSON.with_schema("dronekey.Status")
_INFO_ENCODING = zenoh.Encoding.APPLICATION_JSON.with_schema("dronekey.Info")


@dataclass(frozen=True)
class _Declared:
    """An open session and what the sink declared on it."""

    session: zenoh.Session
    tracks: Sequenced  # the stream: a plain publisher (its matching status says who listens)
    status: Sequenced  # cached
    live: LiveTracks
    token: zenoh.LivelinessToken
    info: zenoh.Queryable
    live_queryable: zenoh.Queryable
    callbacks: CallbackThreads  # the queryables' delivery threads

    def undeclare_and_close(self, frame_index: int) -> None:
        """Delete the live tracks' keys, undeclare everything, close the session and wait (1 s at
        most) for the queryables' callback threads to end, so the process can exit cleanly."""
        try:
            self.live.close(frame_index)
        except zenoh.ZError as exc:
            log.debug("zenoh live-track deletes failed: %s", exc)
        for entity in (self.token, self.info, self.live_queryable):
            try:
                entity.undeclare()
            except zenoh.ZError as exc:
                log.debug("zenoh undeclare failed: %s", exc)
        self.tracks.undeclare()
        self.status.undeclare()
        self.session.close()
        if not self.callbacks.wait(1.0):
            log.warning("zenoh callback threads still running after the session closed")


class ZenohSink(Sink):
    """Publishes tracks and status on Zenoh (see the module docstring).

    Parameters
    ----------
    config : ZenohConfig
        The ``zenoh`` section: mode (a peer works without a router, a client goes through the
        routers in ``connect``), ``connect`` and ``listen`` endpoints, scouting (off unless asked
        for), the TLS identity for ``tls/`` endpoints (docs/security.md), ``history_depth`` (samples
        each cached key keeps for late joiners) and ``track_expiry_s``.
    camera_id : str
        Key segment of every key expression.
    info : mapping, optional
        The reply of the ``info`` queryable, normally ``messages.info_message(...)``.
    camera_geo : CameraGeo, optional
        Adds WGS84 fields to the track messages.
    connect_timeout_s : float
        Longest wait of one attempt to open the session.
    retry_max_s : float
        Longest wait between attempts while no session could be opened.
    """

    name = "zenoh"

    def __init__(
        self,
        config: ZenohConfig,
        camera_id: str,
        *,
        info: Mapping[str, Any] | None = None,
        camera_geo: CameraGeo | None = None,
        connect_timeout_s: float = 2.0,
        retry_max_s: float = 30.0,
    ) -> None:
        if not retry_max_s > 0:
            raise ValueError(f"retry_max_s must be > 0, got {retry_max_s!r}")
        self._camera_id = check_camera_id(camera_id)
        self._keys = messages.key_expressions(camera_id)
        self._mode = config.mode
        self._history_depth = config.history_depth
        self._track_expiry_s = config.track_expiry_s
        self._session_config = zenoh_config(config, connect_timeout_s)
        log.info("%s", describe_exposure(config))
        info = dict(info) if info is not None else {}
        info.setdefault("camera_id", camera_id)
        info.setdefault("key_expressions", self._keys)
        self._info_bytes = messages.to_json_bytes(info)
        self._camera_geo = camera_geo
        self._retry_max_s = float(retry_max_s)

        self._declared: _Declared | None = None
        self._state = "connecting"
        self._error: str | None = None
        self._published = 0
        self._not_sent = 0
        self._info_replies = 0
        self._frame_index = -1  # the last frame seen: the status messages' attachment
        self._opened = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._open_loop, name=f"zenoh-open-{camera_id}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ Sink interface
    def handle_update(self, update: FrameUpdate) -> None:
        """Publish one message per track on ``dronekey/<id>/tracks`` and on the track's own key
        (deleted when the track is lost); delete the keys of tracks gone quiet."""
        self._frame_index = update.frame_index
        declared = self._declared
        if declared is None:
            self._not_sent += len(update.tracks)
            return
        now = time.monotonic_ns()
        for track in update.tracks:
            payload = messages.to_json_bytes(messages.track_message(track, self._camera_id, self._camera_geo))
            declared.tracks.put(payload, update.frame_index)
            lost = track.status == TrackStatus.LOST
            declared.live.update(track.track_id, lost, payload, update.frame_index, now)
            self._published += 1
        declared.live.expire(now, update.frame_index)

    def handle_status(self, status: dict) -> None:
        """Publish a status message (built by ``messages.status_message``) on ``dronekey/<id>/status``."""
        declared = self._declared
        if declared is None:
            self._not_sent += 1
            return
        declared.status.put(messages.to_json_bytes(status), self._frame_index)
        self._published += 1
        declared.live.expire(time.monotonic_ns(), self._frame_index)  # also while no frame comes

    def failing(self) -> str | None:
        """Why nothing is published (the session is not open yet), or None once it is, and after
        ``close`` (closed on purpose; what went unsent stays in ``fault_counts``)."""
        if self._declared is not None or self._state == "closed":
            return None
        return f"session {self._state}" + (f": {self._error}" if self._error else "")

    def fault_counts(self) -> dict[str, int]:
        """Tracks and status messages dropped while the session was not open."""
        return {"unsent": self._not_sent} if self._not_sent else {}

    def health(self) -> dict:
        """``state`` (connecting, open, closed), ``mode``, connected ``peers``/``routers``, whether the
        tracks have ``subscribers``, message counters, ``live_tracks`` (keys under
        ``tracks/``), ``tracks_expired`` (deleted for want of updates) and the last opening ``error``."""
        out = {
            "state": self._state,
            "mode": self._mode,
            "error": self._error,
            "published": self._published,
            "not_sent": self._not_sent,
            "info_replies": self._info_replies,
        }
        declared = self._declared
        if declared is not None:
            out["live_tracks"] = len(declared.live)
            out["tracks_expired"] = declared.live.expired
            out["track_replies"] = declared.live.replies
            try:
                out["routers"] = len(list(declared.session.info.routers_zid()))
                out["peers"] = len(list(declared.session.info.peers_zid()))
                out["subscribers"] = _matching(declared.tracks.publisher)
            except zenoh.ZError:  # closed meanwhile
                pass
        return out

    def close(self) -> None:
        """Delete the live tracks' keys, undeclare everything (the liveliness token disappears) and
        close the session."""
        self._stop.set()
        declared, self._declared = self._declared, None
        self._state = "closed"
        if declared is not None:
            try:
                declared.undeclare_and_close(self._frame_index)
            except zenoh.ZError as exc:
                log.warning("zenoh session close failed: %s", exc)
        self._thread.join(timeout=0.5)  # an attempt in flight ends by itself and closes its session

    # ------------------------------------------------------------------ extras
    def wait_open(self, timeout_s: float) -> bool:
        """Wait until the session is open and declared; True if it is."""
        return self._opened.wait(timeout_s)

    @property
    def key_expressions(self) -> dict[str, str]:
        return dict(self._keys)

    # ------------------------------------------------------------------ session thread
    def _open_loop(self) -> None:
        delay = 0.5
        while not self._stop.is_set():
            try:
                declared = self._open_and_declare()
            except zenoh.ZError as exc:
                text = str(exc).split(" at ", 1)[0]
                if text != self._error:
                    log.warning(
                        "zenoh %s session not open yet (%s); retrying in the background", self._mode, text
                    )
                self._error = text
                self._stop.wait(delay)
                delay = min(delay * 2.0, self._retry_max_s)
                continue
            if self._stop.is_set():
                declared.undeclare_and_close(self._frame_index)
                return
            self._declared = declared
            self._state, self._error = "open", None
            self._opened.set()
            log.info("zenoh %s session open, publishing on %s", self._mode, self._keys["tracks"])
            return

    def _open_and_declare(self) -> _Declared:
        session = zenoh.open(self._session_config)
        callbacks = CallbackThreads()
        try:
            tracks = session.declare_publisher(
                self._keys["tracks"],
                encoding=_TRACK_ENCODING,
                congestion_control=zenoh.CongestionControl.DROP,
            )
            status = declare_cached_publisher(
                session, self._keys["status"], _STATUS_ENCODING, self._history_depth
            )
            live = LiveTracks(
                session, self._keys["tracks"], _TRACK_ENCODING, self._history_depth, self._track_expiry_s
            )
            live_queryable = session.declare_queryable(
                live.key_pattern, callbacks.wrap(live.answer), complete=True
            )
            token = session.liveliness().declare_token(self._keys["alive"])
            info = session.declare_queryable(self._keys["info"], callbacks.wrap(self._answer_info))
        except BaseException:
            session.close()
            callbacks.wait(1.0)
            raise
        return _Declared(
            session, Sequenced(tracks), Sequenced(status), live, token, info, live_queryable, callbacks
        )

    def _answer_info(self, query: zenoh.Query) -> None:
        try:
            query.reply(self._keys["info"], self._info_bytes, encoding=_INFO_ENCODING)
            self._info_replies += 1
        except zenoh.ZError as exc:
            log.warning("zenoh info reply failed: %s", exc)


def _matching(publisher: zenoh.Publisher) -> bool:
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))
