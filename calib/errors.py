"""The one exception the calibration tool raises for input an operator can fix."""

from __future__ import annotations

__all__ = ["CalibInputError"]


class CalibInputError(ValueError):
    """Bad input (files, board description, flags, too few views); the message is one line for the CLI."""
