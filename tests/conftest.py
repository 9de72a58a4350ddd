"""Fixtures shared by test modules (pytest finds them by name)."""

from __future__ import annotations

import pytest

from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.sinks.mavlink import MavlinkSink, load_dialect

# The daemon's MAVLink identity in the MAVLink tests (the config's defaults).
SYSID, COMPID = 42, 191


@pytest.fixture(scope="module")
def dialect(tmp_path_factory):
    """The project's generated MAVLink dialect, built once per module."""
    return load_dialect(tmp_path_factory.mktemp("mavlink-dialect"))


@pytest.fixture
def make_sink(dialect):
    """``make(url, signing_key_file=None, allow=(), **kwargs) -> MavlinkSink`` as our system, every
    sink closed after the test; ``kwargs`` are ``MavlinkSink``'s own."""
    sinks = []

    def make(url: str, signing_key_file=None, allow=(), **kwargs) -> MavlinkSink:
        kwargs.setdefault("dialect_cache_dir", dialect.__file__.rsplit("/", 1)[0])
        config = MavlinkConfig(
            url=url, sysid=SYSID, compid=COMPID, signing_key=signing_key_file, allow=list(allow)
        )
        sink = MavlinkSink(config, **kwargs)
        sinks.append(sink)
        return sink

    yield make
    for sink in sinks:
        sink.close()
