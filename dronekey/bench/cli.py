"""``dronekey-bench``: speed measurements of the product, one subcommand each.

- ``dronekey-bench model [--json]``: ONNX Runtime latency of the keypoint network, batch 1, for the
  paper configuration (random weights, exported to a temporary folder) and the shipped edge model
  (a randomly initialised one until it exists; the output says which), fp32 and int8
  (``dronekey.bench.model``).
- ``dronekey-bench pipeline --source FILE [--json]``: the daemon end to end with every output on,
  against its decode and model ceilings (``dronekey.daemon.bench``).
- ``dronekey-bench soak --source FILE --frames N [--json]``: the daemon looping over a video;
  resident memory at the start and the end (``dronekey.daemon.bench``).
- ``dronekey-bench sampler [--json]``: training crops rendered per second (``dronekey.bench.sampler``).

Each subcommand lives with the package it measures and registers through the ``dronekey.bench``
entry-point group of ``pyproject.toml`` (so this package never imports the daemon). Adding one:
write ``add_<name>_command(subparsers)`` that creates its parser and sets ``handler=`` to a function
``(args) -> exit status``, list it under ``[project.entry-points."dronekey.bench"]`` and reinstall
(``pip install -e .``). Progress goes to stderr; results (a table, or JSON with ``--json``) to stdout.
"""

from __future__ import annotations

import argparse
import logging
import sys
from importlib.metadata import entry_points

__all__ = ["ENTRY_POINT_GROUP", "build_parser", "main"]

ENTRY_POINT_GROUP = "dronekey.bench"


def build_parser() -> argparse.ArgumentParser:
    """The ``dronekey-bench`` parser with every subcommand of the ``dronekey.bench`` entry points,
    in the order of their names.

    Raises
    ------
    RuntimeError
        No subcommand is registered: the package's metadata is missing (not installed).
    """
    parser = argparse.ArgumentParser(prog="dronekey-bench", description="Speed measurements of DroneKey.")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    registered = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda entry_point: entry_point.name)
    if not registered:
        raise RuntimeError(
            f"no {ENTRY_POINT_GROUP!r} entry points in the package metadata Python found: reinstall "
            "(pip install -e .); a dronekey.egg-info left in the current folder by an older build "
            "shadows the installed metadata"
        )
    for entry_point in registered:
        entry_point.load()(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``dronekey-bench``; returns the exit status."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s", stream=sys.stderr
    )
    return int(args.handler(args))


if __name__ == "__main__":
    sys.exit(main())
