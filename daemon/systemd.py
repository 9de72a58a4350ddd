"""systemd integration with no extra dependency: sd_notify over ``$NOTIFY_SOCKET``, the watchdog
interval, and whether stderr goes to the journal.

The notify protocol is one ``AF_UNIX`` datagram of newline-separated ``KEY=VALUE`` assignments
(``READY=1``, ``STATUS=...``, ``WATCHDOG=1``, ``STOPPING=1``) sent to the socket path in
``$NOTIFY_SOCKET`` (a leading ``@`` names an abstract socket). Outside systemd every call is a
no-op, so the daemon runs the same in a terminal.
"""

from __future__ import annotations

import logging
import os
import socket
import sys

__all__ = ["SystemdNotifier", "stderr_is_journal"]

log = logging.getLogger(__name__)


class SystemdNotifier:
    """Sends sd_notify messages when started by systemd with ``Type=notify``.

    Parameters
    ----------
    environ : mapping, optional
        Where to read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (``os.environ``).
    """

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        self._address = _socket_address(env.get("NOTIFY_SOCKET", ""))
        self._sock: socket.socket | None = None
        if self._address is not None:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self.watchdog_interval_s = _watchdog_interval_s(env)
        self._warned = False

    @property
    def enabled(self) -> bool:
        """True when a notify socket was given."""
        return self._sock is not None

    def notify(self, **fields: str | int) -> bool:
        """Send ``KEY=VALUE`` assignments (keys upper-cased); False when not under systemd or on error."""
        if self._sock is None:
            return False
        text = "\n".join(f"{key.upper()}={_one_line(value)}" for key, value in fields.items())
        try:
            self._sock.sendto(text.encode("utf-8"), self._address)
        except OSError as exc:
            if not self._warned:  # systemd gone or socket full; the daemon itself is fine
                log.warning("sd_notify to %s failed: %s", os.environ.get("NOTIFY_SOCKET"), exc)
                self._warned = True
            return False
        return True

    def ready(self, status: str) -> bool:
        return self.notify(ready=1, status=status)

    def status(self, status: str) -> bool:
        return self.notify(status=status)

    def watchdog(self) -> bool:
        return self.notify(watchdog=1)

    def stopping(self, status: str) -> bool:
        return self.notify(stopping=1, status=status)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _socket_address(path: str) -> str | bytes | None:
    if not path:
        return None
    if path.startswith("@"):
        return b"\0" + path[1:].encode()
    if path.startswith("/"):
        return path
    log.warning("NOTIFY_SOCKET=%r is not a socket path; sd_notify disabled", path)
    return None


def _watchdog_interval_s(env) -> float | None:
    """Half of ``WATCHDOG_USEC`` (systemd's advice), or None when the watchdog is off or not ours."""
    usec = env.get("WATCHDOG_USEC", "")
    pid = env.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if pid and pid != str(os.getpid()):
        return None
    return int(usec) / 2e6


def _one_line(value: str | int) -> str:
    return " ".join(str(value).split())


def stderr_is_journal(environ: dict[str, str] | None = None) -> bool:
    """True when stderr is connected to journald (``JOURNAL_STREAM`` matches stderr's device:inode)."""
    env = os.environ if environ is None else environ
    stream = env.get("JOURNAL_STREAM", "")
    if not stream:
        return False
    try:
        st = os.fstat(sys.stderr.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return stream == f"{st.st_dev}:{st.st_ino}"
