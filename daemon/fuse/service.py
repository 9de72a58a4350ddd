"""The fusion service: Zenoh in, ``Fuser``, Zenoh out (docs/fleet.md).

- Subscribes to ``dronekey/*/tracks`` (every daemon) or ``dronekey/<id>/tracks`` per listed camera.
- For each camera it has not placed yet, asks ``dronekey/<id>/info`` for its ``camera_pose`` on a
  background thread (again every ``pose_retry_s`` while it has none); tracks of a camera without a
  pose are counted and left out.
- Puts each camera's clock onto its own (``ClockAlignment``), feeds ``Fuser``, and every
  ``1 / rate_hz`` s, when new tracks came, fuses at the newest track time and publishes one message
  per fused track on ``dronekey/fused/tracks`` (congestion control DROP: a slow subscriber never
  stalls it), with a liveliness token ``dronekey/fused/alive``, and hands them to the SBS-1 /
  MAVLink outputs when it has them (``daemon/fuse/outputs.py``).

The session uses the daemon's settings and secure defaults (``daemon/sinks/zenoh_session.py``): a
peer listens on 127.0.0.1 only, a client through the routers it is given, scouting off.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections import Counter
from collections.abc import Sequence

import zenoh

from dronekey.daemon.config.zenoh import ZenohConfig
from dronekey.daemon.fuse.fused_message import FUSED_KEY, FUSER_ID, fused_track_message
from dronekey.daemon.fuse.local_frame import LocalFrame, camera_ecef_pose, origin_hint
from dronekey.daemon.fuse.outputs import FusedOutputs
from dronekey.daemon.fuse.track_input import parse_track_message
from dronekey.daemon.messages import key_expressions, to_json_bytes
from dronekey.daemon.sinks.zenoh_session import describe_exposure, zenoh_config
from dronekey.fusion import ClockAlignment, Fuser, FusionConfig

__all__ = ["FuseService"]

log = logging.getLogger(__name__)

_ENCODING = zenoh.Encoding.APPLICATION_JSON.with_schema("dronekey.FusedTrack")


class FuseService:
    """Fuses the tracks of several daemons (see the module docstring).

    Parameters
    ----------
    zenoh_settings : the ``zenoh`` section (mode, connect, listen, scouting, TLS).
    cameras : camera ids to fuse; empty: every daemon that publishes tracks.
    origin : the fused frame's origin; None: the first site origin seen, else the first camera.
    fusion : the gates and noise figures.
    clock : ``auto``, ``trust`` or ``arrival`` (``dronekey.fusion.clock``).
    rate_hz : fused updates per second at most.
    pose_retry_s : wait between info queries of a camera that has no pose yet.
    outputs : the fused tracks' SBS-1 / MAVLink outputs (``FusedOutputs``), closed when ``run``
        returns; None: Zenoh only.
    """

    def __init__(
        self,
        zenoh_settings: ZenohConfig,
        cameras: Sequence[str] = (),
        origin: LocalFrame | None = None,
        fusion: FusionConfig | None = None,
        clock: str = "auto",
        rate_hz: float = 30.0,
        pose_retry_s: float = 2.0,
        outputs: FusedOutputs | None = None,
    ) -> None:
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self._zenoh_settings = zenoh_settings
        self._cameras = tuple(cameras)
        self._frame = origin
        self._fuser = Fuser(config=fusion)
        self._clock = ClockAlignment(clock)
        self._period_s = 1.0 / rate_hz
        self._pose_retry_s = pose_retry_s
        self._outputs = outputs
        self._lock = threading.Lock()
        self._fresh = False
        self._warned: set[str] = set()  # cameras whose info had no usable pose, already logged
        self._asked: dict[str, float] = {}  # camera -> monotonic time of the last info query
        self.counts: Counter[str] = Counter()
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask ``run`` to return."""
        self._stop.set()

    # ------------------------------------------------------------------ receiving
    def _on_track(self, sample: zenoh.Sample) -> None:
        try:
            camera_id, track = parse_track_message(sample.payload.to_bytes())
        except ValueError as exc:
            self.counts["bad_messages"] += 1
            log.debug("%s: %s", sample.key_expr, exc)
            return
        if camera_id == FUSER_ID or (self._cameras and camera_id not in self._cameras):
            return
        arrival = time.time_ns()
        with self._lock:
            t_fusion = self._clock.observe(camera_id, track.t_ns, arrival)
            if camera_id not in self._fuser.cameras:
                self.counts["tracks_without_pose"] += 1
                self._want_pose(camera_id)
                return
            self._fuser.update(camera_id, track, t_fusion)
            self._fresh = True
            self.counts["tracks_in"] += 1

    def _want_pose(self, camera_id: str) -> None:
        last = self._asked.get(camera_id)
        if last is not None and time.monotonic() - last < self._pose_retry_s:
            return
        self._asked[camera_id] = time.monotonic()
        threading.Thread(
            target=self._ask_pose, args=(camera_id,), name=f"pose-{camera_id}", daemon=True
        ).start()

    def _ask_pose(self, camera_id: str) -> None:
        key = key_expressions(camera_id)["info"]
        try:
            replies = list(self._session.get(key, timeout=2.0))
        except zenoh.ZError as exc:
            log.warning("info query %s failed: %s", key, exc)
            return
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                info = json.loads(reply.ok.payload.to_bytes())
                position, R = camera_ecef_pose(info)
            except (ValueError, json.JSONDecodeError) as exc:
                if camera_id not in self._warned:
                    log.warning("%s", exc)
                    self._warned.add(camera_id)
                return
            with self._lock:
                if self._frame is None:
                    self._frame = origin_hint(info)
                    log.info("fused frame: ENU at %s", self._frame.to_message()["origin"])
                self._fuser.set_pose(camera_id, self._frame.camera_pose(position, R))
            source = (info.get("camera_pose") or {}).get("source")
            log.info("camera %s placed (from its %s); fusing its tracks", camera_id, source)
            return
        log.info("no answer from %s yet; asking again in %.0f s", key, self._pose_retry_s)

    # ------------------------------------------------------------------ publishing
    def _publish_due(self, publisher: zenoh.Publisher) -> None:
        with self._lock:
            if not self._fresh:
                return
            self._fresh = False
            t_ns = self._fuser.latest_t_ns()
            fused = self._fuser.fuse(t_ns) if t_ns is not None else []
            frame = self._frame
        for track in fused:
            publisher.put(to_json_bytes(fused_track_message(track, frame)))
            self.counts["fused_out"] += 1
        if self._outputs is not None and t_ns is not None:
            self._outputs.publish(fused, t_ns)

    def run(self, opened: threading.Event | None = None) -> None:
        """Open the session, subscribe, publish until ``stop``; close everything on the way out.

        Raises
        ------
        zenoh.ZError
            The session could not be opened (a client with no router reachable).
        """
        log.info("%s", describe_exposure(self._zenoh_settings))
        self._session = zenoh.open(zenoh_config(self._zenoh_settings))
        try:
            keys = [key_expressions(c)["tracks"] for c in self._cameras] or ["dronekey/*/tracks"]
            subscribers = [self._session.declare_subscriber(k, self._on_track) for k in keys]
            publisher = self._session.declare_publisher(
                FUSED_KEY, encoding=_ENCODING, congestion_control=zenoh.CongestionControl.DROP
            )
            token = self._session.liveliness().declare_token(f"dronekey/{FUSER_ID}/alive")
            for camera_id in self._cameras:
                self._want_pose(camera_id)
            log.info("fusing %s, publishing on %s", ", ".join(keys), FUSED_KEY)
            if opened is not None:
                opened.set()
            last_report = last_alive = time.monotonic()
            while not self._stop.wait(self._period_s):
                self._publish_due(publisher)
                if self._outputs is not None and time.monotonic() - last_alive >= 1.0:
                    last_alive = time.monotonic()
                    self._outputs.alive()
                if time.monotonic() - last_report > 10.0:
                    last_report = time.monotonic()
                    log.info("cameras placed: %s; %s", list(self._fuser.cameras), dict(self.counts))
            token.undeclare()
            publisher.undeclare()
            for subscriber in subscribers:
                subscriber.undeclare()
        finally:
            self._session.close()
            if self._outputs is not None:
                self._outputs.close()
        log.info("stopped; %s", dict(self.counts))
