"""Who may command the sensor over MAVLink: the link's own peer, or an explicit allow-list.

A command changes what the sensor reports (one unsigned ``SET_MESSAGE_INTERVAL(511, -1)`` stops
TARGET_RELATIVE to every ground station), so input is taken only from peers admitted here:

- the peer the link names: the ``udpout:`` target (its address and port) or the ``tcp:`` server;
- every entry of ``mavlink.allow``: ``"HOST"`` (any port) or ``"HOST:PORT"``, HOST an IPv4 address,
  a network (``10.0.0.0/24``; ``0.0.0.0/0`` is anyone) or a host name (resolved when the link opens);
- on links that name no peer (``udpin:``/``udp:``, ``udpbcast:``, ``tcpin:``) and have no
  allow-list: the first peer heard that sent a valid message (correctly signed, with signing on),
  pinned by address and port for the rest of the run.

Serial links have one peer, the wire, and are not checked. This is not authentication (a host on
the same network can forge a UDP source address); signing is. It keeps an unsigned link from
taking orders from anyone who can reach its port, and with signing on it keeps strangers from
costing the signature check.
"""

from __future__ import annotations

import ipaddress
import logging
import re
import socket
import threading
from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["AllowEntry", "PeerPolicy", "parse_allow_entry"]

log = logging.getLogger(__name__)

_ENTRY = re.compile(r"^(?P<host>[A-Za-z0-9_.-]+(?:/\d{1,2})?)(?::(?P<port>\d{1,5}))?$")

Address = tuple[str, int]


@dataclass(frozen=True)
class AllowEntry:
    """One ``mavlink.allow`` entry: a host, address or network, and optionally one port."""

    text: str
    host: str
    port: int | None

    def network(self) -> ipaddress.IPv4Network:
        """The entry's addresses; a host name is resolved now (raises OSError if it cannot be)."""
        try:
            return ipaddress.IPv4Network(self.host, strict=False)
        except ValueError:
            return ipaddress.IPv4Network(socket.gethostbyname(self.host))


def parse_allow_entry(text: str) -> AllowEntry:
    """Check one ``mavlink.allow`` entry; the error names it and says what is accepted."""
    m = _ENTRY.match(text) if isinstance(text, str) else None
    port = int(m["port"]) if m and m["port"] else None
    ok = m is not None and (port is None or 0 < port < 65536)
    if ok and ("/" in m["host"] or m["host"][:1].isdigit()):
        try:
            ipaddress.IPv4Network(m["host"], strict=False)
        except ValueError:
            ok = False
    if not ok:
        raise ValueError(
            f"mavlink.allow entry {text!r} must be HOST or HOST:PORT, HOST an IPv4 address, a network "
            "such as 10.0.0.0/24 (0.0.0.0/0: anyone) or a host name, PORT 1-65535"
        )
    return AllowEntry(text, m["host"], port)


class PeerPolicy:
    """Decides, per sender address, whether its messages are read at all.

    Parameters
    ----------
    allow : ``mavlink.allow`` entries (strings, checked by ``parse_allow_entry``).
    pin_first : admit the first peer that sends a valid message, and only it (links that name no
        peer); ignored when ``allow`` is not empty.
    pin_port : pin the first peer's address and port (UDP), or its address only (a TCP client
        that reconnects comes from a new port).
    """

    def __init__(self, allow: Iterable[str] = (), *, pin_first: bool = False, pin_port: bool = True) -> None:
        self._entries = tuple(parse_allow_entry(a) for a in allow)
        self._pin_first = bool(pin_first) and not self._entries
        self._pin_port = bool(pin_port)
        self._configured: Address | None = None
        self._networks: tuple[tuple[ipaddress.IPv4Network, int | None], ...] = ()
        self._pinned: tuple[str, int | None] | None = None
        self._lock = threading.Lock()

    @classmethod
    def for_url(cls, url: str, allow: Iterable[str] = ()) -> PeerPolicy:
        """The policy of a link: links that name no peer pin the first one heard; ``tcpin`` by host
        only, as a reconnecting client comes from a new port."""
        scheme = url.partition(":")[0]
        pin_first = scheme in ("udpin", "udp", "udpbcast", "tcpin")
        return cls(allow, pin_first=pin_first, pin_port=scheme != "tcpin")

    @property
    def allow(self) -> tuple[str, ...]:
        return tuple(e.text for e in self._entries)

    def resolve(self, configured: Address | None) -> None:
        """Set the link's own peer (resolved address, port) and resolve the allow-list's names.

        Called each time the link opens; raises OSError if a host name cannot be resolved.
        """
        networks = tuple((e.network(), e.port) for e in self._entries)
        with self._lock:
            self._configured = configured
            self._networks = networks

    def admits(self, peer: Address) -> bool:
        """Whether to read what ``peer`` sent (an unpinned link admits anyone until ``confirm``)."""
        with self._lock:
            if self._matches_locked(peer):
                return True
            return self._pin_first and self._pinned in (None, self._pin_key(peer))

    def confirm(self, peer: Address) -> None:
        """``peer`` sent a valid message: on a link that pins the first peer, pin it if none is yet."""
        with self._lock:
            if not self._pin_first or self._pinned is not None or self._matches_locked(peer):
                return
            self._pinned = self._pin_key(peer)
            who = self._pinned_text_locked()
        log.info("MAVLink: commands now only from %s, the first peer heard", who)

    def _pin_key(self, peer: Address) -> Address | tuple[str, None]:
        return (peer[0], peer[1]) if self._pin_port else (peer[0], None)

    def _pinned_text_locked(self) -> str:
        host, port = self._pinned
        return host if port is None else f"{host}:{port}"

    def describe(self) -> str:
        """Who may command, in words, for the start-up log line and the status."""
        with self._lock:
            who = []
            if self._configured is not None:
                who.append(f"{self._configured[0]}:{self._configured[1]} (the link's peer)")
            who += [e.text for e in self._entries]
            if self._pin_first:
                pinned = self._pinned_text_locked() + " (" if self._pinned else ""
                who.append(pinned + "the first peer heard" + (")" if pinned else ""))
        return ", ".join(who) if who else "the serial link"

    def _matches_locked(self, peer: Address) -> bool:
        if self._configured is not None and peer == self._configured:
            return True
        if not self._networks:
            return False
        try:
            address = ipaddress.IPv4Address(peer[0])
        except ValueError:
            return False
        return any(address in net and port in (None, peer[1]) for net, port in self._networks)
