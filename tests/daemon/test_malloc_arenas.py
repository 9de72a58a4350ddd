"""The daemon's cap on glibc's malloc arenas, seen in glibc's own count of them (``malloc_stats``)
in a fresh process where eight threads allocate at once."""

import os
import subprocess
import sys

import pytest

from dronekey.daemon.malloc_arenas import limit_malloc_arenas

_PROBE = """
import ctypes, sys, threading
from dronekey.daemon.malloc_arenas import limit_malloc_arenas
if sys.argv[1] == "cap":
    print(limit_malloc_arenas(), flush=True)
barrier = threading.Barrier(8)
def work():
    keep = [bytearray(64 * 1024) for _ in range(4)]  # under the mmap threshold: from an arena
    barrier.wait()
threads = [threading.Thread(target=work) for _ in range(8)]
for t in threads:
    t.start()
for t in threads:
    t.join()
ctypes.CDLL(None).malloc_stats()  # one "Arena N:" block per arena, on stderr
"""

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")


def _arenas(mode: str, **env: str) -> tuple[str, int]:
    environ = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"} | env
    done = subprocess.run(
        [sys.executable, "-c", _PROBE, mode],
        capture_output=True,
        text=True,
        env=environ,
        timeout=60,
        check=True,
    )
    return done.stdout.strip(), sum(line.startswith("Arena ") for line in done.stderr.splitlines())


def test_eight_threads_share_two_arenas_once_capped():
    assert _arenas("cap") == ("2", 2)
    _, uncapped = _arenas("none")
    assert uncapped >= 8  # glibc's default: an arena per thread, up to eight per core


def test_the_operators_malloc_arena_max_stands():
    assert _arenas("cap", MALLOC_ARENA_MAX="3") == ("3", 3)


@pytest.mark.parametrize("bad", [0, -1, True, 2.0])
def test_a_bad_cap_names_the_argument(bad):
    with pytest.raises(ValueError, match="arenas must be an integer >= 1"):
        limit_malloc_arenas(bad)
