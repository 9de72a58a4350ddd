"""SIGTERM / SIGINT / SIGHUP handling with a hard shutdown deadline.

The first signal asks the main loop to stop (it closes the source and every output and finalises
the MCAP); a guard thread woken through ``signal.set_wakeup_fd`` (so it wakes even while the main
thread is inside a long C call) ends the process with the signal's exit code if the orderly
shutdown has not finished by the deadline.

SIGHUP stops the daemon like SIGTERM (exit 129) rather than reloading in place: nearly every
setting (source, model, sockets, keys) needs its part rebuilt, and a half-applied config is worse
than a restart. Under systemd exit 129 is not a success, so ``Restart=on-failure`` starts the
service again with the config file as it is now: SIGHUP is a reload by restart.

Signals that arrive within ``repeat_window_s`` of the first count as that one: GNU ``timeout``
signals the child and then its process group, and a group kill reaches the daemon twice. A signal
after that window exits at once (an operator insisting).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import sys
import threading
import time

from dronekey.daemon.errors import ExitCode

__all__ = ["SignalMonitor", "hard_exit"]

log = logging.getLogger(__name__)

_EXIT_CODES = {
    signal.SIGHUP: ExitCode.SIGHUP,
    signal.SIGINT: ExitCode.SIGINT,
    signal.SIGTERM: ExitCode.SIGTERM,
}


class SignalMonitor:
    """Turns SIGTERM / SIGINT / SIGHUP into a stop request, guarded by a hard deadline.

    Parameters
    ----------
    deadline_s : float
        Seconds after the first signal at which the process exits whatever it is doing.
    repeat_window_s : float
        Signals within this long of the first are the same request; a later one exits at once.
    """

    def __init__(self, deadline_s: float = 5.0, repeat_window_s: float = 1.0) -> None:
        self.deadline_s = deadline_s
        self.repeat_window_s = repeat_window_s
        self.stop = threading.Event()
        self.signum: int | None = None
        self.requested_mono: float | None = None
        self._done = threading.Event()
        self._rsock: socket.socket | None = None
        self._wsock: socket.socket | None = None

    @property
    def exit_code(self) -> ExitCode | None:
        """129, 130 or 143 once a signal arrived, else None."""
        return None if self.signum is None else _EXIT_CODES[self.signum]

    def install(self) -> None:
        """Install the handlers (main thread only) and start the deadline guard."""
        self._rsock, self._wsock = socket.socketpair()
        self._wsock.setblocking(False)
        signal.set_wakeup_fd(self._wsock.fileno(), warn_on_full_buffer=False)
        for signum in _EXIT_CODES:
            signal.signal(signum, self._handle)
        threading.Thread(target=self._guard, name="shutdown-guard", daemon=True).start()

    def finished(self) -> None:
        """The orderly shutdown is over; the deadline no longer applies."""
        self._done.set()

    def _handle(self, signum: int, _frame) -> None:
        name = signal.Signals(signum).name
        if self.signum is not None:
            if time.monotonic() - self.requested_mono < self.repeat_window_s:
                log.info(
                    "%s again within %.0f s of the first signal: already stopping", name, self.repeat_window_s
                )
                return
            log.error("second %s: exiting now", name)
            hard_exit(_EXIT_CODES[signum])
        self.signum = signum
        self.requested_mono = time.monotonic()
        restart = (
            " like SIGTERM, exit 129 (under systemd: a restart, which reads the config again)"
            if signum == signal.SIGHUP
            else ""
        )
        log.info("%s: stopping%s (closing outputs, %.0f s at most)", name, restart, self.deadline_s)
        self.stop.set()

    def _guard(self) -> None:
        """Wakes on the first signal byte, then enforces the deadline."""
        rsock = self._rsock
        while True:
            try:
                data = rsock.recv(16)
            except OSError:
                return
            if not data or self._done.is_set():
                return
            signums = [b for b in data if b in _EXIT_CODES]
            if signums:
                break
        if self._done.wait(self.deadline_s):
            return
        code = self.exit_code or _EXIT_CODES[signums[0]]
        log.error("shutdown did not finish within %.0f s; exiting anyway", self.deadline_s)
        hard_exit(code)


def hard_exit(code: int) -> None:
    for stream in (sys.stderr, sys.stdout):
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(int(code))
