"""The fuser's air-picture outputs: fused tracks on the daemon's own SBS-1 and MAVLink outputs.

A ground station that shows one camera's intruders over MAVLink or SBS-1 should show the fused
ones the same way (TARGET_RELATIVE then says where a drone is from the virtual camera). The
daemon's sinks take camera-frame tracks and the camera's geodetic pose; the
fuser gives them a **virtual camera at the fused frame's origin**, level and facing north
(``CameraGeo(lat, lon, alt, 0, 0, 0)``: x east, y down, z north), and its fused tracks turned
from that frame's ENU into this camera's frame. Everything else (latitude and longitude, the
24-bit address and callsign from the fused id, ADSB_VEHICLE / TARGET_ABSOLUTE, the BaseStation
lines, dropping the oldest update when a peer is slow) is the daemon's code, unchanged.

Each output is off unless asked for (``--sbs1-listen``, ``--mavlink``), and both need the fused
frame's origin given (``--origin``): their messages carry latitude and longitude.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping

import numpy as np

from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.fuse.fused_message import FUSER_ID
from dronekey.daemon.fuse.local_frame import LocalFrame
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.outputs import close_outputs
from dronekey.daemon.sinks.base import FrameUpdate, SinkWorker
from dronekey.fusion.fuser import FusedTrack
from dronekey.geometry.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from dronekey.types import Track

__all__ = ["ENU_TO_VIRTUAL_CAMERA", "FusedOutputs", "as_camera_track", "virtual_camera"]

log = logging.getLogger(__name__)

# ENU (east, north, up) -> the virtual camera's frame (x right = east, y down, z forward = north).
ENU_TO_VIRTUAL_CAMERA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def virtual_camera(frame: LocalFrame) -> CameraGeo:
    """A level camera at the fused frame's origin facing north: its geodetic pose."""
    return CameraGeo(frame.lat_deg, frame.lon_deg, frame.alt_m, 0.0, 0.0, 0.0)


def as_camera_track(fused: FusedTrack) -> Track:
    """``fused`` (ENU at the fused frame's origin) as a track of ``virtual_camera``; its id is the
    fused id."""
    M = ENU_TO_VIRTUAL_CAMERA
    R_site_body = quat_wxyz_to_matrix(fused.quaternion_wxyz)
    return Track(
        track_id=int(fused.fused_id),
        t_ns=int(fused.t_ns),
        status=fused.status,
        position_m=M @ np.asarray(fused.position_m, dtype=np.float64),
        velocity_mps=M @ np.asarray(fused.velocity_mps, dtype=np.float64),
        position_cov=M @ np.asarray(fused.position_cov, dtype=np.float64) @ M.T,
        quaternion_wxyz=matrix_to_quat_wxyz(M @ R_site_body),
        rotation_std_rad=np.asarray(fused.rotation_std_rad, dtype=np.float64),
        score=float(fused.score),
        hits=int(fused.hits),
        age_s=float(fused.age_s),
        heading_confidence=float(fused.heading_confidence),
    )


class FusedOutputs:
    """The SBS-1 and MAVLink outputs of the fused tracks, each behind its own ``SinkWorker`` (a slow
    peer never stalls the fusion).

    Parameters
    ----------
    frame : the fused frame (its origin is the virtual camera's position).
    sbs1 : the ``sbs1`` section (``listen`` set), or None for no SBS-1 output.
    mavlink : the ``mavlink`` section, or None for no MAVLink output.
    queue_size : updates each worker holds before it drops the oldest.

    Raises
    ------
    ValueError, OSError
        Naming the output, when one cannot start (an address in use, a bad URL); those already
        started are closed first.
    """

    def __init__(
        self,
        frame: LocalFrame,
        sbs1: Sbs1Config | None = None,
        mavlink: MavlinkConfig | None = None,
        queue_size: int = 8,
    ) -> None:
        geo = virtual_camera(frame)
        self._workers: dict[str, SinkWorker] = {}
        self._frames = 0
        try:
            if sbs1 is not None:
                from dronekey.daemon.sinks.sbs1 import Sbs1Sink

                self._workers["sbs1"] = SinkWorker(Sbs1Sink(sbs1, geo), max_queue=queue_size)
            if mavlink is not None:
                from dronekey.daemon.sinks.mavlink import MavlinkSink

                sink = MavlinkSink(mavlink, geo, camera_id=FUSER_ID)
                self._workers["mavlink"] = SinkWorker(sink, max_queue=queue_size)
        except BaseException:
            self.close()
            raise
        for name in self._workers:
            log.info("fused tracks on the %s output", name)

    @property
    def workers(self) -> Mapping[str, SinkWorker]:
        """The running outputs by name (``sbs1``, ``mavlink``)."""
        return dict(self._workers)

    def publish(self, fused: list[FusedTrack], t_ns: int) -> None:
        """Hand one fusion step's tracks (``lost`` ones included) to every output."""
        if not self._workers:
            return
        update = FrameUpdate(
            FUSER_ID, self._frames, int(t_ns), time.monotonic_ns(), tuple(as_camera_track(f) for f in fused)
        )
        self._frames += 1
        for worker in self._workers.values():
            worker.submit_update(update)

    def alive(self) -> None:
        """The fuser is running (about once a second): MAVLink heartbeats go on while no drone is
        in view, as a daemon's do while its pipeline is healthy."""
        for worker in self._workers.values():
            worker.submit_status({"healthy": True})

    def close(self, timeout_s: float = 3.0) -> None:
        """Drain and close every output."""
        stuck = close_outputs(self._workers, timeout_s)
        if stuck:
            log.warning("outputs still closing after %.0f s: %s", timeout_s, ", ".join(stuck))
        self._workers = {}
