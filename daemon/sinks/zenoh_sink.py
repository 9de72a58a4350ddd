"""Zenoh output (docs/design.md §6.1): track updates, status, a liveliness token and an info queryable.

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

Secure by default (docs/security.md): a peer listens on ``tcp/127.0.0.1:0`` only and a client not at
all, and scouting (multicast on the LAN, gossip through connected nodes) is off, so nothing off this
machine can find or reach the session unless the config says so; one INFO line at start says what
the session exposes. The section's ``tls`` identity adds TLS with mutual authentication: the router
of a fleet then knows each sensor by its certificate's common name and its access control decides
who publishes. The settings are checked once, by ``ZenohConfig``; this module only applies them.
"""

from __future__ import annotations

import json
import logging
import re
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import zenoh

from dronekey.daemon import messages
from dronekey.daemon.config.camera import check_camera_id
from dronekey.daemon.config.zenoh import ZenohConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink

__all__ = ["ZenohSink", "describe_exposure", "zenoh_config"]

log = logging.getLogger(__name__)

# The host of an endpoint's address: [IPv6] or everything up to the port, metadata or config.
_HOST = re.compile(r"^(?:\[(?P<v6>[^\]]*)\]|(?P<host>[^:#?]*))")


def zenoh_config(config: ZenohConfig, connect_timeout_s: float = 2.0) -> zenoh.Config:
    """The Zenoh session configuration of the daemon, from its ``zenoh`` section.

    Keys set: ``mode``; ``connect/endpoints`` when given; ``listen/endpoints`` always (the section
    resolves a missing ``listen``: a peer listens on ``LOOPBACK_LISTEN``, a client nowhere; Zenoh's
    own default would be every interface); ``scouting/multicast/enabled`` and
    ``scouting/gossip/enabled`` (both follow ``scouting``); ``connect/timeout_ms`` (bounds one
    opening attempt) and ``connect/exit_on_failure = false`` (a peer opens even when its connect
    endpoints are down and Zenoh keeps trying them; a client still needs one router to open, hence
    the retry thread). With ``tls``: ``transport/link/tls`` with the CA, the certificate and key for
    both connecting and listening, ``enable_mtls`` and ``close_link_on_expiration``.

    Raises
    ------
    ValueError
        Naming ``connect_timeout_s`` if it is not > 0.
    """
    if not connect_timeout_s > 0:
        raise ValueError(f"connect_timeout_s must be > 0, got {connect_timeout_s!r}")
    session_config = zenoh.Config()
    session_config.insert_json5("mode", json.dumps(config.mode))
    if config.connect:
        session_config.insert_json5("connect/endpoints", json.dumps(config.connect))
    session_config.insert_json5("listen/endpoints", json.dumps(config.listen))
    session_config.insert_json5("scouting/multicast/enabled", json.dumps(config.scouting))
    session_config.insert_json5("scouting/gossip/enabled", json.dumps(config.scouting))
    session_config.insert_json5("connect/timeout_ms", json.dumps(int(connect_timeout_s * 1000)))
    session_config.insert_json5("connect/exit_on_failure", "false")
    tls = config.tls
    if tls is not None:
        files = {
            "root_ca_certificate": str(tls.root_ca),
            "connect_certificate": str(tls.certificate),
            "connect_private_key": str(tls.private_key),
            "listen_certificate": str(tls.certificate),
            "listen_private_key": str(tls.private_key),
        }
        for key, value in files.items():
            session_config.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
        session_config.insert_json5("transport/link/tls/enable_mtls", "true")  # both ends show a certificate
        session_config.insert_json5("transport/link/tls/close_link_on_expiration", "true")
        session_config.insert_json5(
            "transport/link/tls/verify_name_on_connect", json.dumps(bool(tls.verify_name_on_connect))
        )
    return session_config


def _is_loopback(endpoint: str) -> bool:
    protocol, _, address = endpoint.partition("/")
    if protocol.startswith("unixsock-"):  # a Unix socket: this machine only
        return True
    match = _HOST.match(address)
    host = (match["v6"] if match["v6"] is not None else match["host"]).lower()
    return host == "localhost" or host == "::1" or host.startswith("127.")


def describe_exposure(config: ZenohConfig) -> str:
    """One line saying what a session with these settings exposes, for the log at start.

    E.g. ``zenoh peer session: listens on tcp/127.0.0.1:0 (this machine only), connects to
    nothing, scouting off, no TLS``; a listener beyond loopback or scouting on is called out as
    reachable from the network.
    """
    listen, connect, tls = config.listen, config.connect, config.tls
    exposed = [ep for ep in listen if not _is_loopback(ep)]
    if not listen:
        listening = "listens nowhere"
    elif exposed:
        listening = f"listens on {', '.join(listen)} (REACHABLE FROM THE NETWORK: {', '.join(exposed)})"
    else:
        listening = f"listens on {', '.join(listen)} (this machine only)"
    connecting = f"connects to {', '.join(connect)}" if connect else "connects to nothing"
    scouting_text = (
        "scouting ON (multicast and gossip: discoverable on the network)"
        if config.scouting
        else "scouting off"
    )
    tls_text = f"TLS with mutual authentication as {tls.certificate}" if tls is not None else "no TLS"
    return f"zenoh {config.mode} session: {listening}, {connecting}, {scouting_text}, {tls_text}"


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
    config : ZenohConfig
        The ``zenoh`` section: mode (a peer works without a router, a client goes through the
        routers in ``connect``), ``connect`` and ``listen`` endpoints, scouting (off unless asked
        for) and the TLS identity for ``tls/`` endpoints (docs/security.md).
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
        session = zenoh.open(self._session_config)
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
