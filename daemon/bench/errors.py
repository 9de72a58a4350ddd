"""Errors of the daemon's benchmarks: each is one line on stderr and an exit status."""

from __future__ import annotations

__all__ = ["BenchError", "BenchInterruptedError"]


class BenchError(Exception):
    """Bad input (source, calibration, model) or a daemon run that failed; the message says which."""


class BenchInterruptedError(BenchError):
    """SIGINT or SIGTERM stopped the run; ``exit_code`` is 130 or 143 (as for the daemon)."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code
