"""Where a paced run's slowest frames spent their time: waiting to be taken, or in the pipeline, and
in which of its stages.

A p99 says how slow the slowest frames were, not why. The thirty-fourth session found a third of one
camera's slowest 2 % to be the replay's own reopen at each loop (docs/performance.md), which the
p99 alone could not show; ``dronekey-bench pipeline`` now prints this breakdown of its paced pass.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

__all__ = ["SLOWEST_SHARE", "FrameTiming", "slowest_frames", "slowest_line"]

SLOWEST_SHARE = 0.02  # the p98 and up: the frames a p99 is made of, and as many again for a sample


class FrameTiming(NamedTuple):
    """One paced frame: ``wait_ms`` from its arrival (its due time) to the pipeline taking it,
    ``pipeline_ms`` in ``TrackingPipeline.process`` (wall clock), its ``mode`` and its stages' wall
    times (``PipelineOutput.timings_ms``; ``acquire`` only where a search ran)."""

    wait_ms: float
    pipeline_ms: float
    mode: str
    stages_ms: dict


def slowest_frames(timings: Sequence[FrameTiming], share: float = SLOWEST_SHARE) -> dict:
    """The slowest ``share`` of ``timings`` by wait + pipeline time (at least one frame), described:
    how many, their mean latency split into waiting and pipeline time, the least of them, how many of
    them searched (an ``acquire`` stage), their modes, and each stage's mean over them (ms, 2
    decimals). Empty timings give ``{"frames": 0}``."""
    if not 0.0 < share <= 1.0:
        raise ValueError(f"share must be in (0, 1], got {share}")
    if not timings:
        return {"frames": 0}
    total = np.array([t.wait_ms + t.pipeline_ms for t in timings])
    n = max(1, math.ceil(share * len(timings)))
    order = np.argsort(-total, kind="stable")[:n]
    slow, latency = [timings[k] for k in order], total[order]
    stages = sorted({name for t in slow for name in t.stages_ms if name != "total"})
    # a stage a frame did not run counts as 0 ms in that stage's mean
    stage_means = {s: round(float(np.mean([t.stages_ms.get(s, 0.0) for t in slow])), 2) for s in stages}
    return {
        "share": share,
        "frames": n,
        "of_frames": len(timings),
        "latency_ms_min": round(float(latency.min()), 2),
        "latency_ms_mean": round(float(latency.mean()), 2),
        "wait_ms_mean": round(float(np.mean([t.wait_ms for t in slow])), 2),
        "pipeline_ms_mean": round(float(np.mean([t.pipeline_ms for t in slow])), 2),
        "searched": sum("acquire" in t.stages_ms for t in slow),
        "modes": dict(Counter(t.mode for t in slow)),
        "stages_ms_mean": stage_means,
    }


def slowest_line(summary: dict) -> str:
    """``slowest_frames``'s summary as one line for the bench's table."""
    if not summary.get("frames"):
        return "slowest frames: none measured"
    return (
        f"slowest {100 * summary['share']:g} % ({summary['frames']} of {summary['of_frames']} paced frames, "
        f"{summary['latency_ms_min']:.1f} ms and more): {summary['latency_ms_mean']:.1f} ms on average = "
        f"{summary['wait_ms_mean']:.1f} waiting + {summary['pipeline_ms_mean']:.1f} in the pipeline; "
        f"{summary['searched']} with a search"
    )
