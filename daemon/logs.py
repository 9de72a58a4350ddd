"""Logging set-up for the three places the daemon writes to.

- **journal** (stderr is journald's stream): ``<N>`` syslog priority prefixes that journald turns
  into the entry's priority, no timestamps (journald stamps), no colour;
- **terminal** (stderr is a TTY): timestamps, and a live status line kept at the bottom;
- **plain** (a pipe or file): timestamps, no escape codes.
"""

from __future__ import annotations

import logging
import sys
from enum import StrEnum

from dronekey.daemon.status import TerminalStatusLine
from dronekey.daemon.systemd import stderr_is_journal

__all__ = ["LogMode", "detect_log_mode", "setup_logging"]

# sd-daemon(3) priority prefixes.
_SYSLOG_PRIORITY = {
    logging.DEBUG: 7,
    logging.INFO: 6,
    logging.WARNING: 4,
    logging.ERROR: 3,
    logging.CRITICAL: 2,
}


class LogMode(StrEnum):
    JOURNAL = "journal"
    TERMINAL = "terminal"
    PLAIN = "plain"


def detect_log_mode() -> LogMode:
    """Where stderr goes: journald, a terminal, or anything else."""
    if stderr_is_journal():
        return LogMode.JOURNAL
    try:
        if sys.stderr.isatty():
            return LogMode.TERMINAL
    except (AttributeError, ValueError):
        pass
    return LogMode.PLAIN


class _JournalFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{_SYSLOG_PRIORITY.get(record.levelno, 6)}>"
        text = super().format(record)
        return "\n".join(prefix + line for line in text.splitlines())


class _StatusLineHandler(logging.Handler):
    """Writes records above the terminal's live status line."""

    def __init__(self, line: TerminalStatusLine) -> None:
        super().__init__()
        self._line = line

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._line.write_above(self.format(record))
        except Exception:
            self.handleError(record)


def setup_logging(level: str, mode: LogMode) -> TerminalStatusLine | None:
    """Configure the root logger for ``mode``; returns the status line in terminal mode."""
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
    root.setLevel(level)
    status_line = None
    if mode == LogMode.JOURNAL:
        handler: logging.Handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(_JournalFormatter("%(name)s: %(message)s"))
    elif mode == LogMode.TERMINAL:
        status_line = TerminalStatusLine(sys.stderr)
        handler = _StatusLineHandler(status_line)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(message)s", "%H:%M:%S"))
    else:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    return status_line
