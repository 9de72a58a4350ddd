"""MAVLink output of the daemon (docs/design.md §6.2): DroneKey's dialect and the MAVLink sink.

``MavlinkSink`` is the sink; ``load_dialect`` gives the generated pymavlink module of
``dronekey.xml`` (common.xml + TARGET_ABSOLUTE / TARGET_RELATIVE); ``use_dialect`` gives any
``mavutil`` connection that dialect (tools and tests listening to the daemon use it).

Names are imported on first use, so importing one submodule (e.g. ``link`` or ``peers`` for the
config's checks, or ``dialect``) does not pull in pymavlink's ``mavutil`` and the sink.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "MavlinkSink": "sink",
    "DialectError": "dialect",
    "load_dialect": "dialect",
    "use_dialect": "link",
    "SigningKeyError": "signing",
    "read_signing_key": "signing",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
