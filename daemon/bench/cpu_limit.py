"""The CPU-bound limit: how many frames per second this machine's cores can take a frame through.

A frame costs the decoder ``decode_ms`` of CPU (measured decoding alone) and the pipeline
``pipeline_ms`` (``TrackingPipeline.process`` on its thread, measured in the daemon run). With
``cores`` cores kept busy, at most ``cores * 1000 / (decode_ms + pipeline_ms)`` frames per second go
through, whatever the threading: that is the ceiling a benchmark's end-to-end figure is held
against (``efficiency_vs_cpu_limit``). The outputs' CPU is left out on purpose: it is what the
daemon spends beyond the two, and shows as efficiency below 1.
"""

from __future__ import annotations

import os

__all__ = ["cpu_limit_fps", "usable_cores"]


def usable_cores() -> int:
    """CPUs this process may run on (its affinity mask), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def cpu_limit_fps(decode_ms: float, pipeline_ms: float, cores: int) -> float:
    """Frames per second ``cores`` cores can decode and process, given the CPU ms of each per frame."""
    per_frame_ms = decode_ms + pipeline_ms
    return cores * 1000.0 / per_frame_ms if per_frame_ms > 0 else float("inf")
