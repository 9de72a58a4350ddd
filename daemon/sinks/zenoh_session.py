"""The Zenoh session settings of the daemon (docs/design.md §6.1, docs/security.md).

``zenoh_config`` turns the checked ``zenoh`` section into a ``zenoh.Config``; ``describe_exposure``
says in one line what a session with these settings exposes, for the log at start. Secure by
default: a peer listens on 127.0.0.1 only, a client nowhere, and scouting is off.
``CallbackThreads`` lets a session's owner wait for the threads that deliver its callbacks, so the
process can end without aborting.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh

from dronekey.daemon.config.zenoh import ZenohConfig

__all__ = ["CallbackThreads", "describe_exposure", "zenoh_config"]

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


class CallbackThreads:
    """Python callbacks for Zenoh declarations, and a wait for the threads that deliver them.

    zenoh-python delivers each callback on a Python thread of its own, started by the declaring
    thread and so a daemon thread when that one is (the sink opens its session on one). When the
    declaration goes, that thread leaves its wait inside zenoh's Rust code and takes the GIL back; if
    the interpreter is finalizing by then, CPython 3.11 ends the thread with ``pthread_exit``, whose
    unwinding Rust refuses, and the whole process aborts (SIGABRT, "FATAL: exception not rethrown").
    ``wrap`` hands zenoh a ``zenoh.handlers.Callback`` whose drop hook, called on that thread once
    its loop is over, releases a lock (a C call: no Python bytecode, so no thread switch before the
    Rust frames are gone); ``wait``, after the declarations are undeclared and the session closed,
    blocks until every wrapped callback's thread got that far.
    """

    def __init__(self) -> None:
        self._finished: list[threading.Lock] = []

    def wrap(self, callback: Callable[[Any], Any]) -> zenoh.handlers.Callback:
        """``callback`` as a Zenoh handler whose delivery thread ``wait`` can wait for."""
        finished = threading.Lock()
        finished.acquire()
        self._finished.append(finished)
        return zenoh.handlers.Callback(callback, finished.release)

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` (s) in all for the wrapped callbacks' threads to end their
        loops; True if they all did (the declarations must be gone, or they never will)."""
        deadline = time.monotonic() + timeout_s
        while self._finished:
            if not self._finished[-1].acquire(timeout=max(deadline - time.monotonic(), 0.0)):
                return False
            self._finished.pop()
        return True
