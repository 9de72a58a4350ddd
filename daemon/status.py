"""The daemon's counters and its status: the ~1 Hz status figures for the outputs (built into the
status message by ``messages.status_message``), the one-line summary for systemd's ``STATUS=`` and
the journal, and the live status line shown when stderr is a terminal.
"""

from __future__ import annotations

import collections
import math
import shutil
import sys
import threading
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.messages import sink_entry
from dronekey.daemon.sinks.base import SinkWorker
from dronekey.daemon.sources import CaptureStats
from dronekey.types import Track, TrackStatus

__all__ = [
    "PipelineCounters",
    "RateMeter",
    "TerminalStatusLine",
    "format_track",
    "sink_faults",
    "status_figures",
    "status_summary",
]


class RateMeter:
    """Events per second over the last ``window_s`` seconds."""

    def __init__(self, window_s: float = 2.0) -> None:
        self._window_s = window_s
        self._samples: collections.deque[tuple[float, int]] = collections.deque()

    def rate(self, count: int, now: float | None = None) -> float | None:
        """Record the running ``count`` and return the rate over the window (None after one sample)."""
        now = time.monotonic() if now is None else now
        self._samples.append((now, count))
        while len(self._samples) > 2 and now - self._samples[1][0] >= self._window_s:
            self._samples.popleft()
        t0, c0 = self._samples[0]
        return (count - c0) / (now - t0) if now > t0 else None


@dataclass
class PipelineCounters:
    """What the main loop counts; read by the status builder on the same thread."""

    frames: int = 0
    errors: int = 0
    consecutive_errors: int = 0
    last_error: str | None = None
    tracks: tuple[Track, ...] = ()
    latencies_ms: collections.deque = field(default_factory=lambda: collections.deque(maxlen=2048))

    def processed(self, tracks: tuple[Track, ...], latency_ms: float) -> None:
        self.frames += 1
        self.consecutive_errors = 0
        self.tracks = tuple(t for t in tracks if t.status != TrackStatus.LOST)
        self.latencies_ms.append(latency_ms)

    def failed(self, message: str) -> None:
        self.errors += 1
        self.consecutive_errors += 1
        self.last_error = message


def _percentiles(values: Iterable[float]) -> dict[str, float | None]:
    arr = np.fromiter(values, dtype=np.float64)
    if arr.size == 0:
        return {"p50": None, "p99": None}
    return {"p50": round(float(np.percentile(arr, 50)), 2), "p99": round(float(np.percentile(arr, 99)), 2)}


def _worst_latency(sinks: Mapping[str, Mapping]) -> dict[str, float | None]:
    worst: dict[str, float | None] = {}
    for key in ("p50", "p99"):
        values = [
            float(s["latency_ms"][key])
            for s in sinks.values()
            if s["latency_ms"][key] is not None and math.isfinite(s["latency_ms"][key])
        ]
        worst[key] = round(max(values), 2) if values else None
    return worst


def status_figures(
    *,
    healthy: bool,
    started_mono: float,
    pipeline_fps: float | None,
    capture: CaptureStats,
    source_uri: str,
    counters: PipelineCounters,
    model_info: Mapping,
    workers: Mapping[str, SinkWorker],
) -> dict:
    """The figures ``messages.status_message`` turns into the status message (schema ``status``).

    ``latency_ms`` is frame-decoded-to-published of the slowest output (the pipeline's own
    decoded-to-processed latency when no output runs).
    """
    sinks = {name: sink_entry(name, worker) for name, worker in workers.items()}
    latency = _worst_latency(sinks) if sinks else _percentiles(counters.latencies_ms)
    return {
        "healthy": bool(healthy),
        "uptime_s": round(time.monotonic() - started_mono, 3),
        "fps": None if pipeline_fps is None else round(pipeline_fps, 2),
        "latency_ms": latency,
        "frames": {"processed": counters.frames, "dropped": capture.dropped},
        "source": {
            "state": str(capture.state),
            "uri": source_uri,
            "reconnects": capture.reconnects,
            "error": capture.last_error,
        },
        "model": dict(model_info),
        "tracks_active": len(counters.tracks),
        "sinks": sinks,
    }


def format_track(track: Track, geo: CameraGeo | None = None) -> str:
    """``#3 42.1 m az +12.3° el +5.0°`` (relative to the optical axis) or ``brg 123°`` with a geo pose."""
    x, y, z = (float(v) for v in np.asarray(track.position_m, dtype=np.float64).reshape(3))
    rng = math.sqrt(x * x + y * y + z * z)
    elevation = math.degrees(math.atan2(-y, math.hypot(x, z)))
    if geo is not None:
        north, east, _down = geo.ned_from_cam(np.array([x, y, z]))
        bearing = math.degrees(math.atan2(east, north)) % 360.0
        direction = f"brg {bearing:05.1f}°"
    else:
        direction = f"az {math.degrees(math.atan2(x, z)):+.1f}°"
    status = "" if track.status == TrackStatus.CONFIRMED else f" {track.status}"
    return f"#{track.track_id} {rng:.1f} m {direction} el {elevation:+.1f}°{status}"


def status_summary(
    figures: Mapping, capture: CaptureStats, tracks: tuple[Track, ...], geo: CameraGeo | None = None
) -> str:
    """One line for the terminal, ``STATUS=`` and the journal: fps, source state, outputs, tracks.

    The tracks come last: a terminal line cut to its width loses the end of the track list, never
    the outputs' queue figures.
    """
    fps = figures["fps"]
    parts = [
        f"{fps:.1f} fps" if fps is not None else "- fps",
        f"source {capture.state}",
        f"frame {figures['frames']['processed']}",
    ]
    if capture.dropped or capture.corrupt:
        parts.append(f"dropped {capture.dropped} corrupt {capture.corrupt}")
    for name, sink in figures["sinks"].items():
        faults = sink_faults(sink)
        parts.append(f"{name} q{sink['queue_depth']}" + (f" {faults}" if faults else ""))
    p99 = figures["latency_ms"]["p99"]
    if p99 is not None and math.isfinite(p99):
        parts.append(f"p99 {p99:.0f} ms")
    parts.append(" ; ".join(format_track(t, geo) for t in tracks) if tracks else "no track")
    return " | ".join(parts)


def sink_faults(sink: Mapping, reason_chars: int = 60) -> str:
    """``err 2, 451 not recorded, FAILING: not recording: ...`` for a ``sink_entry``; "" when fine.

    The part of the status line and the totals that says an output is failing, so a sink that takes
    every update and delivers none is never shown as just ``published``.
    """
    notes = [f"err {sink['errors']}"] if sink.get("errors") else []
    notes += [f"{count} {what}" for what, count in (sink.get("faults") or {}).items() if count]
    failing = sink.get("failing")
    if failing:
        text = str(failing)
        notes.append("FAILING: " + (text if len(text) <= reason_chars else text[: reason_chars - 1] + "…"))
    return ", ".join(notes)


class TerminalStatusLine:
    """The live status line at the bottom of a terminal; log records are written above it.

    Use ``write_above`` for anything else sent to the same stream so the line is redrawn after it.
    """

    def __init__(self, stream=None) -> None:
        self._stream = stream if stream is not None else sys.stderr
        self._lock = threading.Lock()
        self._text = ""

    def show(self, text: str) -> None:
        width = max(20, shutil.get_terminal_size((120, 24)).columns - 1)
        with self._lock:
            self._text = text if len(text) <= width else text[: width - 1] + "…"
            self._stream.write("\r\x1b[2K" + self._text)
            self._stream.flush()

    def write_above(self, text: str) -> None:
        with self._lock:
            prefix = "\r\x1b[2K" if self._text else ""
            self._stream.write(prefix + text + ("\n" if not text.endswith("\n") else ""))
            if self._text:
                self._stream.write(self._text)
            self._stream.flush()

    def clear(self) -> None:
        with self._lock:
            if self._text:
                self._stream.write("\r\x1b[2K")
                self._stream.flush()
            self._text = ""
