"""Argument types shared by the ``dronekey-bench`` subcommands (``argparse`` ``type=`` callables)."""

from __future__ import annotations

import argparse

__all__ = ["positive_float", "positive_int"]


def positive_int(text: str) -> int:
    """An integer >= 1; else ``argparse.ArgumentTypeError`` naming the value."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def positive_float(text: str) -> float:
    """A number > 0; else ``argparse.ArgumentTypeError`` naming the value."""
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value
