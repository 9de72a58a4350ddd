"""Build the configured outputs (Zenoh, MAVLink, MCAP, SBS-1, CoT), each behind its own ``SinkWorker``.

Each sink module is imported only when its output is enabled, so a missing dependency or a broken
output is reported by name (``zenoh output: ...``) instead of taking the others down at import. An
output that is enabled but cannot start stops the daemon with exit code 2 and a line saying how to
fix or disable it; running silently without a configured output would be worse.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.errors import UsageError
from dronekey.daemon.sinks.base import Sink, SinkWorker
from dronekey.geometry.camera import CameraModel

__all__ = ["OutputContext", "build_outputs", "close_outputs"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OutputContext:
    """What the outputs need to know besides the config.

    camera : intrinsics at the source's resolution.
    model_info : ``name``, ``path``, ``sha256`` and more, for Zenoh's info queryable.
    simulated : True for ``sim://`` sources (ADS-B messages get their SIMULATED flag).
    frame_rate : the source's frames per second, None when unknown (the annotated video's rate).
    """

    camera: CameraModel
    model_info: Mapping[str, Any]
    simulated: bool
    frame_rate: float | None = None


def _zenoh(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.messages import info_message
    from dronekey.daemon.sinks.zenoh_sink import ZenohSink

    placement = config.camera.placement()
    geo = placement.geo if placement is not None else None
    return ZenohSink(
        config.zenoh,
        config.camera.id,
        info=info_message(config.camera.id, ctx.camera, ctx.model_info, geo, placement),
        camera_geo=geo,
    )


def _mavlink(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.mavlink import MavlinkSink

    return MavlinkSink(
        config.mavlink,
        config.camera.camera_geo(),
        simulated=ctx.simulated,
        camera_id=config.camera.id,
        camera=ctx.camera,
        model_info=ctx.model_info,
    )


def _mcap(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.mcap.sink import McapSink

    geo = config.camera.camera_geo()
    live = None
    if config.foxglove_ws.listen is not None:
        from dronekey.daemon.sinks.foxglove_ws import FoxgloveLiveServer
        from dronekey.daemon.sinks.mcap.channels import channel_specs

        host, port = config.foxglove_ws.address()
        specs = channel_specs(with_geo=geo is not None)
        live = FoxgloveLiveServer(host, port, specs, message_backlog=config.foxglove_ws.message_backlog)
    try:
        return McapSink(config.mcap, ctx.camera, config.camera.id, camera_geo=geo, live=live)
    except BaseException:
        if live is not None:
            live.close()
        raise


def _sbs1(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.sbs1 import Sbs1Sink

    return Sbs1Sink(config.sbs1, config.camera.camera_geo())


def _cot(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.cot import CotSink

    fov_deg = math.degrees(2.0 * math.atan2(ctx.camera.width / 2.0, float(ctx.camera.K[0, 0])))
    return CotSink(config.cot, config.camera.id, config.camera.camera_geo(), fov_deg=fov_deg)


def _sapient(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.sapient.sink import SapientSink

    return SapientSink(config.sapient, ctx.camera, config.camera.id, config.camera.camera_geo())


def _annotated_video(config: DaemonConfig, ctx: OutputContext) -> Sink:
    from dronekey.daemon.sinks.annotated_video import AnnotatedVideoSink

    return AnnotatedVideoSink(config.annotated_video, ctx.camera, ctx.frame_rate)


# Outputs whose queue holds full frames keep it shorter than sinks.queue_size.
_QUEUE_SIZES: dict[str, Callable[[DaemonConfig], int]] = {
    "annotated_video": lambda c: c.annotated_video.queue_frames,
}

# name -> (enabled?, builder, flag that disables it)
_OUTPUTS: dict[
    str, tuple[Callable[[DaemonConfig], bool], Callable[[DaemonConfig, OutputContext], Sink], str]
] = {
    "zenoh": (lambda c: c.zenoh.enabled, _zenoh, "--no-zenoh"),
    "mavlink": (lambda c: c.mavlink.enabled, _mavlink, "--no-mavlink"),
    # The MCAP sink also feeds the live view: it runs for either (files only with mcap.enabled).
    "mcap": (lambda c: c.mcap.enabled or c.foxglove_ws.listen is not None, _mcap, "--no-mcap"),
    "sbs1": (lambda c: c.sbs1.listen is not None, _sbs1, "no --sbs1-listen"),
    "sapient": (lambda c: c.sapient.connect is not None, _sapient, "no --sapient"),
    "cot": (lambda c: c.cot.url is not None, _cot, "no --cot"),
    "annotated_video": (
        lambda c: c.annotated_video.path is not None,
        _annotated_video,
        "no --annotated-video",
    ),
}


def build_outputs(config: DaemonConfig, ctx: OutputContext) -> dict[str, SinkWorker]:
    """Start every enabled output; on failure close those already started and raise ``UsageError``."""
    workers: dict[str, SinkWorker] = {}
    for name, (enabled, build, disable_hint) in _OUTPUTS.items():
        if not enabled(config):
            continue
        try:
            sink = build(config, ctx)
        except ImportError as exc:
            close_outputs(workers, timeout_s=2.0)
            raise UsageError(
                f"{name} output unavailable ({exc}); install it or run with {disable_hint}"
            ) from None
        except (ValueError, TypeError, OSError) as exc:
            close_outputs(workers, timeout_s=2.0)
            raise UsageError(f"{name} output: {exc}") from None
        except Exception:
            close_outputs(workers, timeout_s=2.0)
            raise
        queue_size = _QUEUE_SIZES[name](config) if name in _QUEUE_SIZES else config.sinks.queue_size
        workers[name] = SinkWorker(sink, max_queue=queue_size)
        log.info("output %s started", name)
    if not workers:
        log.warning("every output is disabled: tracks are shown here and nowhere else")
    return workers


def close_outputs(workers: Mapping[str, SinkWorker], timeout_s: float) -> list[str]:
    """Drain and close every worker in parallel; returns the names still closing after ``timeout_s``."""
    threads = {
        name: threading.Thread(
            target=worker.close,
            kwargs={"timeout_s": max(0.1, timeout_s * 0.5), "grace_s": max(0.05, timeout_s * 0.2)},
            name=f"close-{name}",
            daemon=True,
        )
        for name, worker in workers.items()
    }
    for thread in threads.values():
        thread.start()
    deadline = time.monotonic() + timeout_s
    for thread in threads.values():
        thread.join(max(0.0, deadline - time.monotonic()))
    return [name for name, thread in threads.items() if thread.is_alive()]
