"""Why a network stream did not open: refused, timed out, unknown host, or open but unreadable.

OpenCV's ``VideoCapture`` only answers "not opened"; FFmpeg's reason stays inside it. For the
TCP-based schemes (rtsp, rtsps, rtmp, http, https, tcp) a plain socket connect to the same host and
port, right after the failure, tells the cases apart with the operating system's own error
(``ECONNREFUSED``, a timeout, a DNS failure). Datagram schemes (udp, rtp, srt) have no connection to
refuse: a failure there is a timeout if the open took the whole ``open_timeout_s``.
"""

from __future__ import annotations

import errno
import socket
from urllib.parse import urlsplit

__all__ = ["explain_open_failure"]

_DEFAULT_PORTS = {"rtsp": 554, "rtsps": 322, "rtmp": 1935, "http": 80, "https": 443}
_TCP_SCHEMES = frozenset({"rtsp", "rtsps", "rtmp", "http", "https", "tcp"})
_PROBE_TIMEOUT_S = 3.0
# An open that took at least this share of open_timeout_s ran into the timeout.
_TIMEOUT_SHARE = 0.9


def _errno_text(exc: OSError) -> str:
    name = errno.errorcode.get(exc.errno or 0)
    reason = exc.strerror or str(exc)
    return f"{reason} ({name})" if name else reason


def explain_open_failure(url: str, elapsed_s: float, open_timeout_s: float) -> str:
    """A few words on why OpenCV could not open ``url`` after ``elapsed_s`` seconds.

    Examples: ``connection refused by 127.0.0.1:8554 (Connection refused (ECONNREFUSED))``,
    ``no answer from 10.0.0.9:554 within 3.0 s (connection timed out)``, ``host cam.local not found
    (...)``, ``127.0.0.1:8554 accepts connections, but no video stream came within 10.0 s``.
    """
    timed_out = elapsed_s >= _TIMEOUT_SHARE * open_timeout_s
    try:
        parts = urlsplit(url)
        scheme, host, port = parts.scheme.lower(), parts.hostname, parts.port
    except ValueError:
        return "the URL does not parse"
    port = port or _DEFAULT_PORTS.get(scheme)
    if scheme not in _TCP_SCHEMES or not host or port is None:
        if timed_out:
            return f"no stream arrived within {open_timeout_s:.1f} s (timed out)"
        return "OpenCV's FFmpeg backend could not read a stream from it"
    address = f"{host}:{port}"
    try:
        with socket.create_connection((host, port), timeout=min(_PROBE_TIMEOUT_S, open_timeout_s)):
            pass
    except socket.gaierror as exc:
        return f"host {host} not found ({exc.strerror or exc})"
    except TimeoutError:
        waited = min(_PROBE_TIMEOUT_S, open_timeout_s)
        return f"no answer from {address} within {waited:.1f} s (connection timed out)"
    except ConnectionRefusedError as exc:
        return f"connection refused by {address} ({_errno_text(exc)})"
    except OSError as exc:
        return f"cannot connect to {address} ({_errno_text(exc)})"
    if timed_out:
        return (
            f"{address} accepts connections, but no video stream came within {open_timeout_s:.1f} s "
            "(timed out)"
        )
    return (
        f"{address} accepts connections, but OpenCV's FFmpeg backend could not read a stream from it "
        "(wrong path, codec or credentials?)"
    )
