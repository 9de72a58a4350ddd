"""The runner: capture thread -> pipeline (main thread) -> one ``SinkWorker`` per output.

``DaemonApp.run`` opens the source, resolves the calibration, builds the pipeline and the outputs
as soon as the source's resolution is known (at once for files, image folders and sim; at the
first frame for live sources), then loops: take a frame, run the pipeline, hand the
``FrameUpdate`` to every output without waiting for it, and about once a second publish the status
(outputs, terminal or journal, systemd ``STATUS=``). systemd hears ``READY=1`` after the first frame
went through the pipeline and ``WATCHDOG=1`` while the loop runs and no source call hangs.

It returns the exit code (``errors.ExitCode``) after logging why it stopped; ``UsageError`` (bad
calibration, model or video) propagates, with exit code 2, after every output was closed.

One job, kept whole (about 400 lines): the run loop and its start, health and shutdown read best
together; the parts it drives (sources, pipeline, outputs, status) live in their own modules.
"""

from __future__ import annotations

import hashlib
import logging
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

from dronekey.daemon.calibration import camera_at_resolution, resolve_calibration
from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.errors import ExitCode, UsageError
from dronekey.daemon.messages import sink_entry, status_message
from dronekey.daemon.outputs import OutputContext, build_outputs, close_outputs
from dronekey.daemon.signals import SignalMonitor
from dronekey.daemon.sinks.base import FrameUpdate, SinkWorker
from dronekey.daemon.sources import Capture, CapturedFrame, SourceOpenError, SourceState, make_reader
from dronekey.daemon.status import (
    PipelineCounters,
    RateMeter,
    TerminalStatusLine,
    format_track,
    sink_faults,
    status_figures,
    status_summary,
)
from dronekey.daemon.systemd import SystemdNotifier
from dronekey.geometry.camera import CameraModel
from dronekey.types import Frame, TrackStatus

__all__ = ["DaemonApp", "PipelineFactory", "default_pipeline_factory"]

log = logging.getLogger(__name__)

_GET_TIMEOUT_S = 0.1
_MAX_CONSECUTIVE_PIPELINE_ERRORS = 100  # then the pipeline is broken, not one frame
_PIPELINE_ERROR_LOG_EVERY = 100
_SHUTDOWN_BUDGET_S = 4.5  # of the 5 s that SIGTERM allows; the signal guard enforces the rest


class Pipeline(Protocol):
    """What the runner needs of ``dronekey.pipeline.TrackingPipeline``."""

    def process(self, frame: Frame, late: bool = False) -> Any: ...

    def info(self) -> dict: ...


PipelineFactory = Callable[[CameraModel, DaemonConfig], Pipeline]


def default_pipeline_factory(camera: CameraModel, config: DaemonConfig) -> Pipeline:
    """The tracking pipeline with the configured model, drone, inference threads and search."""
    from dronekey.pipeline import TrackingPipeline
    from dronekey.tracking.tracker_config import TrackerConfig

    m, t = config.model, config.tracking
    return TrackingPipeline(
        camera,
        model_path=m.path,
        drone=m.drone,
        drone_alternatives=tuple(m.drone_alternatives),
        threads=m.threads,
        mirror_average=m.mirror_average,
        heading_model=(m.front_back_path or m.front_back_net) if m.front_back else False,
        verifier=(m.verifier_path or True) if m.verifier else False,
        tracker=TrackerConfig(
            max_tracks=t.max_tracks,
            confirm_min_change=t.confirm_min_change,
            confirm_drone_p=t.confirm_drone_p,
            heading_full_spread_px=t.heading_full_spread_px,
        ),
        search_every=t.search_every,
        search_more_every=t.search_more_every,
        wide_look_every=t.wide_look_every,
        measure_every=t.measure_every,
        max_search_candidates=t.max_search_candidates,
    )


def build_pipeline(
    camera: CameraModel, config: DaemonConfig, factory: PipelineFactory = default_pipeline_factory
) -> Pipeline:
    """``factory(camera, config)``; a bad model, drone spec or calibration is a ``UsageError``."""
    try:
        return factory(camera, config)
    except Exception as exc:
        if _is_model_error(exc):
            raise UsageError(f"model: {exc}") from None
        raise


def _is_model_error(exc: BaseException) -> bool:
    """Errors a bad model, drone spec or calibration raises while the pipeline is built."""
    if isinstance(exc, (FileNotFoundError, ValueError, OSError)):
        return True
    return type(exc).__module__.startswith("onnxruntime") or (
        isinstance(exc, RuntimeError) and "onnxruntime" in str(exc).lower()
    )


def _file_sha256(path: Path) -> str | None:
    try:
        digest = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        return digest.hexdigest()
    except OSError:
        return None


class DaemonApp:
    """One run of the daemon (see the module docstring).

    Parameters
    ----------
    config : DaemonConfig
    signals : SignalMonitor
        Installed by the caller; its ``stop`` event ends the loop.
    notifier : SystemdNotifier
    status_line : TerminalStatusLine, optional
        The live line in terminal mode.
    pipeline_factory : callable, optional
        ``(camera, config) -> pipeline``; default ``default_pipeline_factory``.
    """

    def __init__(
        self,
        config: DaemonConfig,
        *,
        signals: SignalMonitor,
        notifier: SystemdNotifier,
        status_line: TerminalStatusLine | None = None,
        pipeline_factory: PipelineFactory | None = None,
    ) -> None:
        self.config = config
        self.signals = signals
        self.notifier = notifier
        self.status_line = status_line
        self._pipeline_factory = pipeline_factory or default_pipeline_factory
        self._geo = config.camera.camera_geo()
        self._started_mono = time.monotonic()
        self._capture: Capture | None = None
        self._base_camera: CameraModel | None = None
        self._pipeline: Pipeline | None = None
        self._resolution: tuple[int, int] | None = None
        self._model_info: dict = {}
        self._workers: dict[str, SinkWorker] = {}
        self._counters = PipelineCounters()
        self._capture_rate = RateMeter()
        self._pipeline_rate = RateMeter()
        self._last_processed_mono: float | None = None
        self._ready = False
        self.frame_arrival_mono_ns: int | None = None  # the frame in the pipeline now: when it arrived
        self._stopping = False
        self._confirmed: set[int] = set()
        self._last_watchdog_mono = 0.0
        self._hang_reported = False
        self._next_journal_status = time.monotonic() + config.log.journal_status_interval_s

    @property
    def outputs(self) -> Mapping[str, SinkWorker]:
        """The running outputs by name (their ``stats`` hold published, dropped and latency figures)."""
        return dict(self._workers)

    # ------------------------------------------------------------------------------ run
    def run(self) -> ExitCode:
        """Run until the source ends, a signal arrives or something fails; returns the exit code."""
        cfg = self.config
        reader = make_reader(cfg.source)
        self._capture = Capture(reader, cfg.source)
        try:
            try:
                self._capture.open()
            except SourceOpenError as exc:
                raise UsageError(f"source: {exc}") from None
            self._base_camera, origin = resolve_calibration(cfg.camera.calibration, reader)
            cam = self._base_camera
            log.info("calibration: %s (%dx%d, fx %.1f)", origin, cam.width, cam.height, cam.fx)
            if reader.resolution is not None:  # known now for files, folders and sim; later for live
                self._prepare(*reader.resolution)
            self._capture.start()
            code = self._loop()
            self._stopping = True
            self._publish_status()  # the outputs record how it ended (unhealthy: no more heartbeats)
            return code
        finally:
            self._shutdown()

    def _loop(self) -> ExitCode:
        capture = self._capture
        interval = self.config.log.status_interval_s
        next_status = time.monotonic()
        max_frames = self.config.source.max_frames
        while True:
            if self.signals.stop.is_set():
                return self.signals.exit_code or ExitCode.SIGTERM
            item = capture.get(_GET_TIMEOUT_S)
            if item is not None:
                self._handle_frame(item)
                if max_frames is not None and self._counters.frames >= max_frames:
                    log.info("processed %d frames (--max-frames): stopping", max_frames)
                    return ExitCode.OK
            elif capture.finished:
                return self._end_code()
            if self._counters.consecutive_errors >= _MAX_CONSECUTIVE_PIPELINE_ERRORS:
                log.error(
                    "the pipeline failed on %d frames in a row; last error: %s",
                    self._counters.consecutive_errors,
                    self._counters.last_error,
                )
                return ExitCode.RUNTIME_FAILURE
            now = time.monotonic()
            if now >= next_status:
                self._publish_status()
                next_status = now + interval
            self._pet_watchdog(now)

    def _end_code(self) -> ExitCode:
        capture = self._capture
        if capture.state == SourceState.ENDED:
            log.info("source ended after %d frames", self._counters.frames)
            return ExitCode.OK
        if capture.crashed:
            log.error("the capture thread failed: %s", capture.last_error)
            return ExitCode.RUNTIME_FAILURE
        log.error("source %s failed permanently: %s", capture.reader.description, capture.last_error)
        return ExitCode.SOURCE_FAILED

    # ------------------------------------------------------------------------------ frames
    def _prepare(self, width: int, height: int) -> None:
        """Build the pipeline and the outputs for frames of ``width`` x ``height``."""
        camera = camera_at_resolution(self._base_camera, width, height)
        if self._resolution is not None:
            log.warning(
                "source resolution changed from %dx%d to %dx%d: restarting pipeline and outputs",
                *self._resolution,
                width,
                height,
            )
            close_outputs(self._workers, timeout_s=2.0)
            self._workers = {}
        elif (width, height) != self._base_camera.size:
            log.info(
                "intrinsics scaled from %dx%d to the source's %dx%d", *self._base_camera.size, width, height
            )
        self._pipeline = build_pipeline(camera, self.config, self._pipeline_factory)
        self._model_info = self._describe_model(self._pipeline)
        self._resolution = (width, height)
        reader = self._capture.reader
        ctx = OutputContext(
            camera, self._model_info, simulated=reader.kind == "sim", frame_rate=reader.frame_rate
        )
        self._workers = build_outputs(self.config, ctx)

    def _describe_model(self, pipeline: Pipeline) -> dict:
        """The status message's ``model``: name, path, sha256, providers, input size, the drone and the other
        airframes it may be (``drone_alternatives``, with the range doubt they set: ``range_std_floor``)."""
        info = pipeline.info()
        model = dict(info.get("model") or {})
        path = model.get("path")
        drone = info.get("drone")
        described = {
            "name": Path(path).stem if path else None,
            "path": str(path) if path else None,
            "sha256": _file_sha256(Path(path)) if path else None,
            **{k: v for k, v in model.items() if k != "path"},
            "drone": drone.get("name") if isinstance(drone, Mapping) else drone,
            "drone_alternatives": list(info.get("drone_alternatives") or []),
            "range_std_floor": info.get("range_std_floor"),
        }
        front_back = described.get("front_back")
        log.info(
            "model %s (%s, sha256 %s...) on %s; front/back classifier %s",
            described["name"],
            described["path"],
            (described["sha256"] or "?")[:12],
            ", ".join(described.get("providers") or ["?"]),
            Path(front_back).name if front_back else "none (the network's own head)",
        )
        return described

    def _handle_frame(self, item: CapturedFrame) -> None:
        frame = item.frame
        width, height = frame.size
        if (width, height) != self._resolution:
            self._prepare(width, height)
        late_ms = self.config.tracking.late_after_ms
        self.frame_arrival_mono_ns = item.t_arrival_mono_ns  # read by a metering pipeline (bench)
        late = late_ms is not None and time.monotonic_ns() - item.t_arrival_mono_ns > late_ms * 1e6
        try:
            output = self._pipeline.process(frame, late=late)
        except Exception as exc:  # one bad frame must not end a service that runs for months
            self._counters.failed(f"{type(exc).__name__}: {exc}")
            if self._counters.errors % _PIPELINE_ERROR_LOG_EVERY == 1:
                log.exception(
                    "pipeline failed on frame %d (%d failures so far)", frame.index, self._counters.errors
                )
            return
        tracks = tuple(output.tracks)
        update = FrameUpdate(
            camera_id=self.config.camera.id,
            frame_index=frame.index,
            t_ns=frame.t_ns,
            t_arrival_mono_ns=item.t_arrival_mono_ns,
            tracks=tracks,
            detection=output.detection,
            image=frame.image,  # read-only: shared with the outputs
        )
        for worker in self._workers.values():
            worker.submit_update(update)
        self._counters.processed(tracks, (time.monotonic_ns() - item.t_arrival_mono_ns) / 1e6)
        self._last_processed_mono = time.monotonic()
        self._log_track_events(tracks)
        if not self._ready:
            self._ready = True
            log.info("first frame processed (%dx%d); running", width, height)
            self.notifier.ready(f"running: {self._capture.reader.description}")

    def _log_track_events(self, tracks) -> None:
        for track in tracks:
            if track.status == TrackStatus.CONFIRMED and track.track_id not in self._confirmed:
                self._confirmed.add(track.track_id)
                log.info("track confirmed: %s", format_track(track, self._geo))
            elif track.status == TrackStatus.LOST and track.track_id in self._confirmed:
                self._confirmed.discard(track.track_id)
                log.info("track lost: #%d after %.1f s", track.track_id, track.age_s)

    # ------------------------------------------------------------------------------ status
    def _healthy(self) -> bool:
        """Frames are flowing through a working pipeline (MAVLink heartbeats follow this)."""
        last = self._last_processed_mono
        return (
            not self._stopping
            and self._pipeline is not None
            and self._capture.state == SourceState.STREAMING
            and self._counters.consecutive_errors == 0
            and last is not None
            and time.monotonic() - last <= self.config.source.stall_timeout_s
        )

    def _publish_status(self) -> None:
        capture_stats = self._capture.stats()
        capture_fps = self._capture_rate.rate(capture_stats.frames)
        pipeline_fps = self._pipeline_rate.rate(self._counters.frames)
        figures = status_figures(
            healthy=self._healthy(),
            started_mono=self._started_mono,
            pipeline_fps=pipeline_fps,
            capture=capture_stats,
            source_uri=self._capture.reader.description,
            counters=self._counters,
            model_info=self._model_info,
            workers=self._workers,
        )
        if self._workers:
            message = status_message(self.config.camera.id, time.time_ns(), figures)
            for worker in self._workers.values():
                worker.submit_status(message)
        summary = status_summary(figures, capture_stats, self._counters.tracks, self._geo)
        self.notifier.status(summary)
        if self.status_line is not None:
            self.status_line.show(summary)
        elif time.monotonic() >= self._next_journal_status:
            self._next_journal_status = time.monotonic() + self.config.log.journal_status_interval_s
            source_fps = "-" if capture_fps is None else f"{capture_fps:.1f}"
            log.info("status: %s (source %s fps)", summary, source_fps)

    def _pet_watchdog(self, now: float) -> None:
        """WATCHDOG=1 while the loop runs and no source call hangs (then systemd restarts us)."""
        interval = self.notifier.watchdog_interval_s
        if interval is None or now - self._last_watchdog_mono < interval:
            return
        busy = self._capture.busy_for_s()
        src = self.config.source
        hang_limit = max(30.0, 3 * src.stall_timeout_s, 2 * src.network.open_timeout_s)
        if busy > hang_limit:
            if not self._hang_reported:
                log.error("source call hangs for %.0f s: no more watchdog pings, systemd will restart", busy)
                self._hang_reported = True
            return
        self.notifier.watchdog()
        self._last_watchdog_mono = now

    # ------------------------------------------------------------------------------ shutdown
    def _shutdown(self) -> None:
        """Stop the source and close every output within the signal's deadline."""
        started = self.signals.requested_mono or time.monotonic()
        deadline = started + _SHUTDOWN_BUDGET_S
        self.notifier.stopping("stopping: closing outputs")
        if self.status_line is not None:
            self.status_line.clear()
        if self._capture is not None:
            self._capture.stop(timeout_s=min(1.0, max(0.1, deadline - time.monotonic())))
        stuck = close_outputs(self._workers, timeout_s=max(0.5, deadline - time.monotonic()))
        if stuck:
            log.error("outputs still closing at the deadline: %s", ", ".join(stuck))
        else:
            log.info("outputs closed in %.2f s", time.monotonic() - started)
        self._log_totals()

    def _log_totals(self) -> None:
        if self._capture is None:
            return
        cs = self._capture.stats()
        parts = [
            f"{self._counters.frames} frames processed",
            f"{cs.dropped} dropped",
            f"{cs.corrupt} corrupt",
            f"{self._counters.errors} pipeline errors",
        ]
        if self._capture.reader.live:  # failed attempts count: "0 reconnects" alone hid them
            parts.insert(
                3, f"source opened {cs.opened} of {cs.open_attempts} attempts, {cs.reconnects} reconnects"
            )
        for name, worker in self._workers.items():
            p50, p99 = worker.stats.latency_percentiles()
            lat = f", p50 {p50:.1f} / p99 {p99:.1f} ms" if math.isfinite(p99) else ""
            faults = sink_faults(sink_entry(name, worker), reason_chars=200)  # what did not get through
            faults = f", {faults}" if faults else ""
            parts.append(
                f"{name} {worker.stats.published} published {worker.stats.dropped} dropped{lat}{faults}"
            )
        log.info("totals: %s", "; ".join(parts))
