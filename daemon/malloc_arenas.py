"""glibc's malloc arenas, capped for the daemon's process.

glibc gives each thread that allocates its own arena, up to eight per core, and every arena keeps
the memory its thread freed for that thread's next allocation. The daemon runs about twenty threads (the
decoder, one per output, ONNX Runtime's, the search's saliency pass): one camera's daemon held
510.6 MiB with glibc's default and 403.3 MiB with two arenas, at the same CPU per frame (19.05
against 19.12 ms; docs/performance.md, twenty-ninth session), a hundred MiB a camera on a box
with several. The cap is what ``MALLOC_ARENA_MAX=2`` in the environment
would set; an operator's own ``MALLOC_ARENA_MAX`` is left to stand.
"""

from __future__ import annotations

import ctypes
import logging
import os

__all__ = ["DAEMON_MALLOC_ARENAS", "limit_malloc_arenas"]

log = logging.getLogger(__name__)

DAEMON_MALLOC_ARENAS = 2
_M_ARENA_MAX = -8  # mallopt's parameter number (glibc malloc.h)


def limit_malloc_arenas(arenas: int = DAEMON_MALLOC_ARENAS) -> int | None:
    """Cap this process's malloc arenas at ``arenas`` (call it first thing in a process's entry
    point: the cap holds for arenas created after it). Returns the cap in force: ``arenas``, the
    environment's ``MALLOC_ARENA_MAX`` when set (glibc read it at start), or None where the C
    library is not glibc (musl, macOS) and nothing was changed."""
    if isinstance(arenas, bool) or not isinstance(arenas, int) or arenas < 1:
        raise ValueError(f"arenas must be an integer >= 1, got {arenas!r}")
    from_env = os.environ.get("MALLOC_ARENA_MAX", "").strip()
    if from_env:
        return int(from_env) if from_env.isdigit() else None
    try:
        libc = ctypes.CDLL(None)
    except (OSError, TypeError):  # no process-wide C library handle (Windows)
        return None
    if not hasattr(libc, "gnu_get_libc_version") or not hasattr(libc, "mallopt"):
        return None
    if libc.mallopt(_M_ARENA_MAX, arenas) != 1:
        log.debug("mallopt(M_ARENA_MAX, %d) refused; glibc's default arenas stay", arenas)
        return None
    return arenas
