"""Console entry points of ``dronekey-train``, ``dronekey-train-heading``, ``dronekey-train-verifier``
and ``dronekey-export``.

They need torch, which the runtime install (``pip install dronekey``) leaves out. This module
imports nothing of torch, so a runtime install answers with one line naming the extra to install
(exit status 2) instead of a ``ModuleNotFoundError`` traceback; the command's own module, and torch
with it, is imported only once torch is known to be there.
"""

from __future__ import annotations

import importlib.util
import sys

__all__ = [
    "calibrate_spread_main",
    "export_main",
    "train_heading_main",
    "train_main",
    "train_verifier_main",
]

TRAIN_EXTRA_HINT = "pip install 'dronekey[train]' (torch==2.13.0, the CPU wheel)"


def torch_missing_message(command: str) -> str | None:
    """The one-line error for ``command`` where torch is not installed, else None."""
    if importlib.util.find_spec("torch") is not None:
        return None
    return f"{command}: needs torch, which the runtime install leaves out: {TRAIN_EXTRA_HINT}"


def train_main(argv: list[str] | None = None) -> int:
    """``dronekey-train``."""
    if message := torch_missing_message("dronekey-train"):
        print(message, file=sys.stderr)
        return 2
    from dronekey.training.train_cli import main  # torch from here on

    return main(argv)


def train_heading_main(argv: list[str] | None = None) -> int:
    """``dronekey-train-heading``."""
    if message := torch_missing_message("dronekey-train-heading"):
        print(message, file=sys.stderr)
        return 2
    from dronekey.training.heading_cli import main  # torch from here on

    return main(argv)


def train_verifier_main(argv: list[str] | None = None) -> int:
    """``dronekey-train-verifier``."""
    if message := torch_missing_message("dronekey-train-verifier"):
        print(message, file=sys.stderr)
        return 2
    from dronekey.training.verifier_cli import main  # torch from here on

    return main(argv)


def export_main(argv: list[str] | None = None) -> int:
    """``dronekey-export``."""
    if message := torch_missing_message("dronekey-export"):
        print(message, file=sys.stderr)
        return 2
    from dronekey.training.export_cli import main  # torch from here on

    return main(argv)


def calibrate_spread_main(argv: list[str] | None = None) -> int:
    """``dronekey-calibrate-spread`` (needs the ``onnx`` package of the train extra, not torch)."""
    if importlib.util.find_spec("onnx") is None:
        hint = f"needs onnx, which the runtime install leaves out: {TRAIN_EXTRA_HINT}"
        print(f"dronekey-calibrate-spread: {hint}", file=sys.stderr)
        return 2
    from dronekey.training.spread_fit import main

    return main(argv)
