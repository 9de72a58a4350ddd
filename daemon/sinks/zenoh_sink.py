"""Zenoh output (DESIGN.md §6.1): track updates, status, a liveliness token and an info queryable.

Key expressions, for camera id ``<id>``:

- ``dronekey/<id>/tracks``: one JSON message per track update (schema ``track``),
- ``dronekey/<id>/status``: the status message, about 1 Hz (schema ``status``),
- ``dronekey/<id>/alive``: liveliness token, present while the daemon runs,
- ``dronekey/<id>/info``: queryable answering the info message (camera, calibration, model, version).

Payloads are UTF-8 JSON with encoding ``application/json;dronekey.<Track|Status|Info>``.

The session opens on a background thread and never blocks or fails the daemon: peer mode (the
default) works with no router at all; in client mode a missing router only means the thread retries
with backoff (0.5 s doubling to ``retry_max_s``) while ``health()`` says ``"connecting"``; messages
published meanwhile are counted as ``not_sent`` and dropped (tracks are live data, not a log).
Publishers use congestion control DROP, so a slow network never stalls the sink thread.
"""

from __future__ import annotations

import json
import logging
import re
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import zenoh

from dronekey.daemon import messages
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink

__all__ = ["ZenohSink", "zenoh_config"]

log = logging.getLogger(__name__)

_MODES = ("peer", "client")
_ENDPOINT = re.compile(r"^[a-z0-9\-]+/\S+$")


def _check_endpoints(endpoints: Sequence[str], name: str) -> list[str]:
    if isinstance(endpoints, str):
        raise ValueError(f"{name} must be a list of endpoints, got the string {endpoints!r}")
    out = []
    for endpoint in endpoints:
        if not isinstance(endpoint, str) or not _ENDPOINT.match(endpoint):
            raise ValueError(f"{name} endpoint must look like 'tcp/127.0.0.1:7447', got {endpoint!r}")
        out.append(endpoint)
    return out


def zenoh_config(
    mode: str = "peer",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    scouting: bool = True,
    connect_timeout_s: float = 2.0,
) -> zenoh.Config:
    """The Zenoh session configuration of the daemon.

    Keys set: ``mode``; ``connect/endpoints`` and ``listen/endpoints`` when given;
    ``scouting/multicast/enabled``; ``connect/timeout_ms`` (bounds one opening attempt) and
    ``connect/exit_on_failure = false`` (a peer opens even when its connect endpoints are down and
    Zenoh keeps trying them; a client still needs one router to open, hence the retry thread).

    Raises
    ------
    ValueError
        Naming a bad mode, endpoint or timeout.
    """
    if mode not in _MODES:
        raise ValueError(f"zenoh mode must be one of {_MODES}, got {mode!r}")
    if not connect_timeout_s > 0:
        raise ValueError(f"connect_timeout_s must be > 0, got {connect_timeout_s!r}")
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    connect = _check_endpoints(connect, "connect")
    listen = _check_endpoints(listen, "listen")
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", json.dumps(bool(scouting)))
    config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    config.insert_json5("connect/exit_on_failure", "false")
    return config


@dataclass(frozen=True)
class _Declared:
    """An open session and what the sink declared on it."""

    session: zenoh.Session
    tracks: zenoh.Publisher
    status: zenoh.Publisher
    token: zenoh.LivelinessToken
    info: zenoh.Queryable

    def undeclare_and_close(self) -> None:
        for entity in (self.token, self.info, self.tracks, self.status):
            try:
                entity.undeclare()
            except zenoh.ZError as exc:
                log.debug("zenoh undeclare failed: %s", exc)
        self.session.close()


class ZenohSink(Sink):
    """Publishes tracks and status on Zenoh (see the module docstring).

    Parameters
    ----------
    camera_id : str
        Key segment of every key expression.
    mode : {"peer", "client"}
        Peer (default) works without a router; client goes through the routers in ``connect``.
    connect, listen : sequence of str
        Zenoh endpoints, e.g. ``"tcp/192.168.1.10:7447"``.
    scouting : bool
        Multicast scouting (discovery on the LAN); turn off where multicast is not wanted.
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
        camera_id: str,
        *,
        mode: str = "peer",
        connect: Sequence[str] = (),
        listen: Sequence[str] = (),
        scouting: bool = True,
        info: Mapping[str, Any] | None = None,
        camera_geo: CameraGeo | None = None,
        connect_timeout_s: float = 2.0,
        retry_max_s: float = 30.0,
    ) -> None:
        if not retry_max_s > 0:
            raise ValueError(f"retry_max_s must be > 0, got {retry_max_s!r}")
        self._camera_id = messages.check_camera_id(camera_id)
        self._keys = messages.key_expressions(camera_id)
        self._mode = mode
        self._config = zenoh_config(mode, connect, listen, scouting, connect_timeout_s)
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
        self._opened = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._open_loop, name=f"zenoh-open-{camera_id}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ Sink interface
    def handle_update(self, update: FrameUpdate) -> None:
        """Publish one message per track on ``dronekey/<id>/tracks``."""
        declared = self._declared
        if declared is None:
            self._not_sent += len(update.tracks)
            return
        for track in update.tracks:
            payload = messages.to_json_bytes(messages.track_message(track, self._camera_id, self._camera_geo))
            declared.tracks.put(payload)
            self._published += 1

    def handle_status(self, status: dict) -> None:
        """Publish a status message (built by ``messages.status_message``) on ``dronekey/<id>/status``."""
        declared = self._declared
        if declared is None:
            self._not_sent += 1
            return
        declared.status.put(messages.to_json_bytes(status))
        self._published += 1

    def health(self) -> dict:
        """``state`` (connecting, open, closed), ``mode``, connected ``peers``/``routers``, whether the
        tracks have ``subscribers``, message counters and the last opening ``error``."""
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
            try:
                out["routers"] = len(list(declared.session.info.routers_zid()))
                out["peers"] = len(list(declared.session.info.peers_zid()))
                out["subscribers"] = _matching(declared.tracks)
            except zenoh.ZError:  # closed meanwhile
                pass
        return out

    def close(self) -> None:
        """Undeclare everything (the liveliness token disappears) and close the session."""
        self._stop.set()
        declared, self._declared = self._declared, None
        self._state = "closed"
        if declared is not None:
            try:
                declared.undeclare_and_close()
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
                declared.undeclare_and_close()
                return
            self._declared = declared
            self._state, self._error = "open", None
            self._opened.set()
            log.info("zenoh %s session open, publishing on %s", self._mode, self._keys["tracks"])
            return

    def _open_and_declare(self) -> _Declared:
        session = zenoh.open(self._config)
        try:
            json_enc = zenoh.Encoding.APPLICATION_JSON
            tracks = session.declare_publisher(
                self._keys["tracks"],
                encoding=json_enc.with_schema("dronekey.Track"),
                congestion_control=zenoh.CongestionControl.DROP,
            )
            status = session.declare_publisher(
                self._keys["status"],
                encoding=json_enc.with_schema("dronekey.Status"),
                congestion_control=zenoh.CongestionControl.DROP,
            )
            token = session.liveliness().declare_token(self._keys["alive"])
            info = session.declare_queryable(self._keys["info"], self._answer_info)
        except BaseException:
            session.close()
            raise
        return _Declared(session, tracks, status, token, info)

    def _answer_info(self, query: zenoh.Query) -> None:
        try:
            query.reply(
                self._keys["info"],
                self._info_bytes,
                encoding=zenoh.Encoding.APPLICATION_JSON.with_schema("dronekey.Info"),
            )
            self._info_replies += 1
        except zenoh.ZError as exc:
            log.warning("zenoh info reply failed: %s", exc)


def _matching(publisher: zenoh.Publisher) -> bool:
    status = publisher.matching_status
    return bool(getattr(status, "matching", status))
