"""The Zenoh session settings of the daemon (docs/design.md §6.1, docs/security.md).

``zenoh_config`` turns the checked ``zenoh`` section into a ``zenoh.Config``; ``describe_exposure``
says in one line what a session with these settings exposes, for the log at start. Secure by
default: a peer listens on 127.0.0.1 only, a client nowhere, and scouting is off.
"""

from __future__ import annotations

import json
import re

import zenoh

from dronekey.daemon.config.zenoh import ZenohConfig

__all__ = ["describe_exposure", "zenoh_config"]

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
