"""Exit codes of ``dronekey-daemon`` and the exceptions that map onto them.

The table is the contract with systemd (``SuccessExitStatus=``), scripts and operators; it is
repeated in ``docs/daemon.md`` and in ``dronekey-daemon --help``.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["EXIT_CODE_HELP", "DaemonError", "ExitCode", "UsageError"]


class ExitCode(IntEnum):
    """Process exit status."""

    OK = 0  # a finite source (file, image folder, sim) reached its end; --validate-config passed
    RUNTIME_FAILURE = 1  # an unexpected error while running (a bug, the pipeline failing on every frame)
    USAGE = 2  # bad usage, config, calibration, model or video: fix the command line or the files
    SOURCE_FAILED = 3  # a live source could not be (re)opened within source.max_reconnects
    SIGHUP = 129  # stopped by SIGHUP (a closed terminal, `systemctl kill -s HUP`), sinks closed
    SIGINT = 130  # stopped by SIGINT (Ctrl-C), sinks closed
    SIGTERM = 143  # stopped by SIGTERM (systemctl stop), sinks closed


EXIT_CODE_HELP = """exit codes:
  0    the source ended (file, image folder, sim://) or --validate-config passed
  1    runtime failure (unexpected error; see the log)
  2    bad usage, config, calibration, model or video (one line on stderr says which)
  3    a live source failed permanently (source.max_reconnects exhausted)
  129  stopped by SIGHUP, 130 by SIGINT, 143 by SIGTERM (sinks closed, MCAP finalised);
       under systemd 129 is restarted, so SIGHUP re-reads the config file"""


class DaemonError(Exception):
    """An error that ends the daemon with ``exit_code`` and a one-line message (no traceback)."""

    exit_code: ExitCode = ExitCode.RUNTIME_FAILURE


class UsageError(DaemonError):
    """Bad command line, config, calibration, model or video: the message says what and how to fix it."""

    exit_code = ExitCode.USAGE
