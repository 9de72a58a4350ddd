"""Opening a pymavlink connection that speaks our dialect, MAVLink 2, with our own ids.

``mavutil`` keeps one global dialect (set by ``mavutil.set_dialect``, which only finds modules inside
pymavlink's package) and may switch protocol versions on the first byte it reads. Instead, a
connection opened here gets a ``MAVLink`` object of the generated DroneKey dialect, pinned to
MAVLink 2, so other users of ``mavutil`` in the process are unaffected.

Accepted URLs (pymavlink's connection strings): ``udpout:HOST:PORT`` (default; send to a ground
station), ``udpin:HOST:PORT`` (listen; reply to the admitted peers heard, ``peers``),
``udpbcast:ADDR:PORT``, ``udp:HOST:PORT`` (as udpin), ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, and
serial devices ``/dev/ttyX[,BAUD]``.

Sockets bind to loopback unless told otherwise: a listening URL without a host (``udpin::14550`` or
``udpin:14550``) listens on 127.0.0.1, and a ``udpout``/``udpbcast`` socket, which pymavlink leaves
unbound (the kernel then binds it to 0.0.0.0 on the first send, where it receives from any
interface), is bound to the address of the interface that routes to the target
(``source_address``): 127.0.0.1 for a loopback target.
"""

from __future__ import annotations

import errno
import re
import socket

__all__ = [
    "LINK_SCHEMES",
    "is_datagram",
    "local_address",
    "open_link",
    "read_datagram",
    "send_datagram_to",
    "source_address",
    "use_dialect",
    "validate_url",
]

LINK_SCHEMES = ("udpout", "udpin", "udpbcast", "udp", "tcp", "tcpin")
_LISTENING = ("udpin", "udp", "tcpin")
_HOST_PORT = re.compile(r"^(?P<host>[^:\s]+):(?P<port>\d{1,5})$")
_PORT_ONLY = re.compile(r"^:?(?P<port>\d{1,5})$")
_SERIAL = re.compile(r"^(?P<dev>/dev/[^,\s]+)(?:,(?P<baud>\d+))?$")
UDP_MAX_PACKET_LEN = 65535


def validate_url(url: str) -> str:
    """Check a connection string and return it, a listening one without a host given 127.0.0.1.

    The error names the URL and lists what is accepted.
    """
    if not isinstance(url, str):
        raise ValueError(f"mavlink url must be a string, got {url!r}")
    scheme, _, rest = url.partition(":")
    if scheme in LINK_SCHEMES:
        m = _HOST_PORT.match(rest)
        if m and 0 < int(m["port"]) < 65536:
            return url
        m = _PORT_ONLY.match(rest)
        if m and scheme in _LISTENING and 0 < int(m["port"]) < 65536:
            return f"{scheme}:127.0.0.1:{int(m['port'])}"
    elif _SERIAL.match(url):
        return url
    raise ValueError(
        f"mavlink url {url!r} is not one of {', '.join(s + ':HOST:PORT' for s in LINK_SCHEMES)} "
        "(udpin, udp, tcpin: HOST may be left out for 127.0.0.1) or /dev/DEVICE[,BAUD]"
    )


def use_dialect(conn, dialect, sysid: int | None = None, compid: int | None = None):
    """Give a ``mavutil`` connection a MAVLink 2 parser/encoder of ``dialect``; returns ``conn``.

    ``sysid``/``compid`` default to the ids the connection was opened with.
    """
    sysid = conn.source_system if sysid is None else sysid
    compid = conn.source_component if compid is None else compid
    conn.mav = dialect.MAVLink(conn, srcSystem=sysid, srcComponent=compid)
    conn.mav.robust_parsing = True  # bad bytes become BAD_DATA messages, never exceptions
    conn.WIRE_PROTOCOL_VERSION = "2.0"
    conn.first_byte = False  # no automatic protocol switch on the first byte received
    return conn


def open_link(url: str, dialect, sysid: int, compid: int):
    """Open ``url`` with our ids and dialect. Raises OSError (or ValueError) if it cannot be opened."""
    from pymavlink import mavutil

    url = validate_url(url)
    serial = _SERIAL.match(url)
    if serial:
        conn = mavutil.mavlink_connection(
            serial["dev"],
            baud=int(serial["baud"] or 57600),
            source_system=sysid,
            source_component=compid,
        )
    else:
        # retries=0: one attempt for TCP; the sink retries with its own backoff.
        conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=compid, retries=0)
        scheme = url.partition(":")[0]
        if scheme in ("udpout", "udpbcast"):
            try:
                host, port = conn.destination_addr
                conn.port.bind((source_address(host, port, broadcast=scheme == "udpbcast"), 0))
            except OSError:
                conn.close()
                raise
    return use_dialect(conn, dialect, sysid, compid)


def source_address(host: str, port: int, broadcast: bool = False) -> str:
    """The local address the kernel sends from to reach ``host``: connecting a UDP socket sends
    nothing, it only picks the route. Raises OSError (e.g. no route to the host yet)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        if broadcast:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        probe.connect((socket.gethostbyname(host), port))
        return probe.getsockname()[0]


def is_datagram(conn) -> bool:
    """Whether ``conn`` is a UDP link (each datagram is a whole set of messages)."""
    from pymavlink import mavutil

    return isinstance(conn, mavutil.mavudp)


def read_datagram(conn) -> tuple[bytes, tuple[str, int] | None]:
    """One datagram from a UDP link and its sender, or ``(b"", None)`` if none is waiting.

    Read from the socket directly rather than through ``mavudp.recv``, which would add every
    sender to the clients a listening link sends to (and let any sender redirect a ``udpbcast``
    link); the sink decides who is added (``MavlinkSink``, ``peers``).
    """
    try:
        data, sender = conn.port.recvfrom(UDP_MAX_PACKET_LEN)
    except OSError as exc:
        if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK, errno.ECONNREFUSED):
            return b"", None
        raise
    return data, sender[:2]


def send_datagram_to(conn, msg, address: tuple[str, int]) -> None:
    """Encode ``msg`` with the link's encoder (sequence number, signing) and send it to ``address``.

    ``mavudp.write`` of a ``udpout`` link always sends to its target; a reply to another admitted
    station must go to that station. Raises OSError if the send fails.
    """
    mav = conn.mav
    buf = msg.pack(mav)
    conn.port.sendto(buf, address)
    mav.seq = (mav.seq + 1) % 256
    mav.total_packets_sent += 1
    mav.total_bytes_sent += len(buf)


def local_address(conn) -> str | None:
    """Where the link's socket is bound (``"127.0.0.1:53211"``), or None (serial, not bound yet)."""
    sock = getattr(conn, "listen", None) or getattr(conn, "port", None)
    if not isinstance(sock, socket.socket):
        return None
    try:
        host, port = sock.getsockname()[:2]
    except OSError:
        return None
    return f"{host}:{port}"
