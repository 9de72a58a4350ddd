"""Opening a pymavlink connection that speaks our dialect, MAVLink 2, with our own ids.

``mavutil`` keeps one global dialect (set by ``mavutil.set_dialect``, which only finds modules inside
pymavlink's package) and may switch protocol versions on the first byte it reads. Instead, a
connection opened here gets a ``MAVLink`` object of the generated DroneKey dialect, pinned to
MAVLink 2, so other users of ``mavutil`` in the process are unaffected.

Accepted URLs (pymavlink's connection strings): ``udpout:HOST:PORT`` (default; send to a ground
station), ``udpin:HOST:PORT`` (listen; reply to whoever sent last), ``udpbcast:ADDR:PORT``,
``udp:HOST:PORT``, ``tcp:HOST:PORT``, ``tcpin:HOST:PORT``, and serial devices ``/dev/ttyX[,BAUD]``.
"""

from __future__ import annotations

import re

__all__ = ["LINK_SCHEMES", "open_link", "use_dialect", "validate_url"]

LINK_SCHEMES = ("udpout", "udpin", "udpbcast", "udp", "tcp", "tcpin")
_HOST_PORT = re.compile(r"^(?P<host>[^:\s]+):(?P<port>\d{1,5})$")
_SERIAL = re.compile(r"^(?P<dev>/dev/[^,\s]+)(?:,(?P<baud>\d+))?$")


def validate_url(url: str) -> str:
    """Check a connection string and return it; the error names it and lists what is accepted."""
    if not isinstance(url, str):
        raise ValueError(f"mavlink url must be a string, got {url!r}")
    scheme, _, rest = url.partition(":")
    if scheme in LINK_SCHEMES:
        m = _HOST_PORT.match(rest)
        if m and 0 < int(m["port"]) < 65536:
            return url
    elif _SERIAL.match(url):
        return url
    raise ValueError(
        f"mavlink url {url!r} is not one of {', '.join(s + ':HOST:PORT' for s in LINK_SCHEMES)} "
        "or /dev/DEVICE[,BAUD]"
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

    validate_url(url)
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
    return use_dialect(conn, dialect, sysid, compid)
