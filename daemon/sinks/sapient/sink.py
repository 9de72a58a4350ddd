"""SAPIENT output (``--sapient HOST:PORT``): the daemon as a BSI Flex 335 v2.0 sensor node.

Per track update, once the decision node has accepted the Registration, a DetectionReport of each
confirmed or coasting track that the node's tasks let through (reporting on, inside the regions of
interest, outside the ignore regions); the track's last update (lost) closes it with
``state: "lost"``. The first report of a confirmed track on a connection comes with an ACTIVE Alert,
its loss with a CLEAR one. Tentative tracks are not reported (docs/design.md: no false alarms).
The field mapping is in docs/sapient.md; the connection, tasks and timings in ``session``.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Iterable

import numpy as np

from dronekey.daemon.config.sapient import SapientConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, Sink
from dronekey.daemon.sinks.sapient import geometry
from dronekey.daemon.sinks.sapient.messages import (
    TrackReport,
    alert_message,
    detection_message,
    new_ulid,
    registration_message,
    status_message,
)
from dronekey.daemon.sinks.sapient.session import SapientSession
from dronekey.daemon.sinks.sapient.tasks import reportable
from dronekey.daemon.sinks.target_state import validate_statuses
from dronekey.geometry.camera import CameraModel
from dronekey.types import PUBLISHED_STATUSES, Track, TrackStatus

__all__ = ["SapientSink"]


def _fov_deg(camera: CameraModel) -> tuple[float, float]:
    """(horizontal, vertical) field of view of the pinhole model, degrees."""
    return camera.horizontal_fov_deg(), math.degrees(2.0 * math.atan2(camera.height / 2.0, camera.fy))


class SapientSink(Sink):
    """Report tracks to a SAPIENT decision node over TCP (module docstring).

    Parameters
    ----------
    config : the ``sapient`` section (``connect`` must be set).
    camera : intrinsics at the source's resolution (the field of view in Registration and status).
    camera_id : the daemon's camera id (node name; default node UUID).
    camera_geo : the camera's geodetic pose: locations in lat/lon instead of camera range-bearing.
    statuses : track statuses that are reported (default confirmed and coasting).
    """

    name = "sapient"

    def __init__(
        self,
        config: SapientConfig,
        camera: CameraModel,
        camera_id: str,
        camera_geo: CameraGeo | None = None,
        *,
        statuses: Iterable[TrackStatus | str] = PUBLISHED_STATUSES,
    ) -> None:
        if camera_geo is not None and not isinstance(camera_geo, CameraGeo):
            raise TypeError(f"camera_geo must be a CameraGeo, got {type(camera_geo).__name__}")
        self._geo = camera_geo
        self._statuses = validate_statuses(statuses)
        self._fov = _fov_deg(camera)
        self.node_id = config.resolved_node_id(camera_id)
        self._health: tuple[bool, str | None] = (True, None)
        self._object_ids: dict[int, str] = {}
        self._alert_ids: dict[int, str] = {}
        self._alert_generation = -1
        self.counts: collections.Counter[str] = collections.Counter()
        camera_location = (
            None if camera_geo is None else (camera_geo.lat_deg, camera_geo.lon_deg, camera_geo.alt_m)
        )

        def registration():
            return registration_message(
                self.node_id,
                camera_id,
                geodetic=camera_geo is not None,
                fov_deg=self._fov,
                status_interval_s=config.status_interval_s,
            )

        def status(new: bool, active_task_id: str | None, goodbye: bool):
            healthy, problem = self._health
            return status_message(
                self.node_id,
                healthy=healthy,
                problem=problem,
                new=new,
                active_task_id=active_task_id,
                fov_deg=self._fov,
                camera_location=camera_location,
                goodbye=goodbye,
            )

        self.session = SapientSession(config, self.node_id, registration, status, camera_geo)

    def _report(self, track: Track, object_id: str, lost: bool = False) -> TrackReport | None:
        range_bearing = geometry.range_bearing_of(track)
        geodetic = None if self._geo is None else geometry.geodetic_of(track, self._geo)
        if range_bearing is None and geodetic is None:
            return None
        return TrackReport(
            object_id=object_id,
            track_id=int(track.track_id),
            confidence=float(track.score),
            range_bearing=range_bearing,
            geodetic=geodetic,
            velocity_enu=geometry.velocity_enu(track, self._geo),
            heading=geometry.heading_deg(track, self._geo),
            lost=lost,
        )

    def handle_update(self, update: FrameUpdate) -> None:
        """Queue the reports (and alerts) of one frame's tracks; never blocks."""
        state = self.session.state
        if state.generation != self._alert_generation:  # a new connection: alert its node afresh
            self._alert_ids.clear()
            self._alert_generation = state.generation
        for track in update.tracks:
            track_id = int(track.track_id)
            if track.status == TrackStatus.LOST:
                object_id = self._object_ids.pop(track_id, None)
                alert_id = self._alert_ids.pop(track_id, None)
                if object_id is not None and self.session.accepting():
                    report = self._report(track, object_id, lost=True)
                    if report is not None:
                        self.session.send_report(
                            detection_message(self.node_id, report, state.active_task_id), state.generation
                        )
                        if alert_id is not None:
                            self.session.send_report(
                                alert_message(self.node_id, alert_id, report, clear=True), state.generation
                            )
                continue
            if track.status not in self._statuses:
                continue
            if not state.registered:
                self.counts["unsent"] += 1
                continue
            if not state.reporting:
                self.counts["stopped by task"] += 1
                continue
            if not reportable(np.asarray(track.position_m, dtype=np.float64), state.regions, self._geo):
                self.counts["outside regions"] += 1
                continue
            object_id = self._object_ids.setdefault(track_id, new_ulid())
            report = self._report(track, object_id)
            if report is None:
                continue
            self.session.send_report(
                detection_message(self.node_id, report, state.active_task_id), state.generation
            )
            self.counts["reports"] += 1
            if track.status == TrackStatus.CONFIRMED and track_id not in self._alert_ids:
                self._alert_ids[track_id] = new_ulid()
                self.session.send_report(
                    alert_message(self.node_id, self._alert_ids[track_id], report), state.generation
                )
                self.counts["alerts"] += 1

    def handle_status(self, status: dict) -> None:
        """Keep the daemon's health for the next StatusReport (OK, or WARNING naming the source state)."""
        healthy = bool(status.get("healthy", True))
        source = status.get("source") or {}
        problem = (
            None
            if healthy
            else f"source {source.get('state', 'unknown')}: {source.get('error') or 'not healthy'}"
        )
        self._health = (healthy, problem)

    def health(self) -> dict:
        state = self.session.state
        return {
            "peer": self.session.peer,
            "node_id": self.node_id,
            "registered": state.registered,
            "reporting": state.reporting,
            "regions": len(state.regions),
            "active_task_id": state.active_task_id,
            "counts": dict(self.counts) | dict(self.session.counts),
        }

    def failing(self) -> str | None:
        return None if self.session.state.registered else self.session.problem

    def fault_counts(self) -> dict[str, int]:
        return {"dropped": self.session.counts["dropped"], "unsent": self.counts["unsent"]}

    def close(self) -> None:
        self.session.close()
