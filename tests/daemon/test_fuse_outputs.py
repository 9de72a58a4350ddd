"""The fused tracks on the daemon's SBS-1 and MAVLink outputs: a real TCP client and a real pymavlink
ground station on 127.0.0.1 read the fused drone where the fused Zenoh message puts it."""

from __future__ import annotations

import select
import socket
import time

import numpy as np
import pytest
from pymavlink import mavutil

from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.fuse.cli import FUSER_SYSID
from dronekey.daemon.fuse.fused_message import fused_track_message
from dronekey.daemon.fuse.local_frame import LocalFrame
from dronekey.daemon.fuse.outputs import FusedOutputs, as_camera_track, virtual_camera
from dronekey.daemon.sinks.mavlink import load_dialect, use_dialect
from dronekey.daemon.sinks.target_state import target_geodetic
from dronekey.fusion.fuser import FusedTrack
from dronekey.geometry.rotations import matrix_to_quat_wxyz, quat_wxyz_to_matrix
from dronekey.types import TrackStatus

FRAME = LocalFrame(47.397742, 8.545594, 488.0)


def fused(fused_id: int = 3, position=(120.0, 250.0, 40.0), velocity=(3.0, -1.0, 0.5)) -> FusedTrack:
    yaw = np.radians(30.0)  # body FRD -> site ENU: nose 30 deg east of north, level
    R = np.array([[np.sin(yaw), np.cos(yaw), 0.0], [np.cos(yaw), -np.sin(yaw), 0.0], [0.0, 0.0, -1.0]])
    return FusedTrack(
        fused_id=fused_id,
        t_ns=time.time_ns(),
        status=TrackStatus.CONFIRMED,
        position_m=np.array(position),
        velocity_mps=np.array(velocity),
        position_cov=np.diag([0.25, 1.0, 4.0]),
        quaternion_wxyz=matrix_to_quat_wxyz(R),
        rotation_std_rad=np.full(3, 0.05),
        heading_confidence=0.9,
        score=0.99,
        hits=12,
        age_s=0.4,
        method="triangulated",
        members=(),
    )


def test_a_fused_track_seen_from_the_virtual_camera_is_where_the_fused_message_says():
    track = fused()
    as_camera = as_camera_track(track)
    np.testing.assert_allclose(as_camera.position_m, [120.0, -40.0, 250.0])  # x east, y down, z north
    np.testing.assert_allclose(as_camera.velocity_mps, [3.0, -0.5, -1.0])
    np.testing.assert_allclose(np.diag(as_camera.position_cov), [0.25, 4.0, 1.0])
    geodetic = target_geodetic(as_camera, virtual_camera(FRAME))
    message = fused_track_message(track, FRAME)
    assert geodetic.lat_deg == pytest.approx(message["lat"], abs=1e-9)
    assert geodetic.lon_deg == pytest.approx(message["lon"], abs=1e-9)
    assert geodetic.alt_m == pytest.approx(message["alt_m"], abs=1e-3)
    np.testing.assert_allclose(geodetic.velocity_ned_mps, [-1.0, 3.0, -0.5], atol=1e-9)
    # the body's nose in the site frame is unchanged by the change of frame
    R_cam_body = quat_wxyz_to_matrix(as_camera.quaternion_wxyz)
    R_ned_cam = virtual_camera(FRAME).R_ned_cam
    nose_ned = R_ned_cam @ R_cam_body @ [1.0, 0.0, 0.0]
    np.testing.assert_allclose(nose_ned, [np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0], atol=1e-9)
    assert as_camera.track_id == 3 and as_camera.heading_confidence == pytest.approx(0.9)


def _read_until(client: socket.socket, marker: bytes, timeout_s: float = 5.0) -> str:
    buf, deadline = b"", time.monotonic() + timeout_s
    while marker not in buf and time.monotonic() < deadline:
        ready, _, _ = select.select([client], [], [], 0.1)
        if ready:
            chunk = client.recv(65536)
            assert chunk, "the SBS-1 output closed the connection"
            buf += chunk
    return buf.decode("ascii")


def test_sbs1_and_mavlink_peers_read_the_fused_drone(tmp_path):
    dialect = load_dialect(tmp_path / "dialect")
    station = use_dialect(mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255), dialect)
    port = station.port.getsockname()[1]
    outputs = FusedOutputs(
        FRAME,
        sbs1=Sbs1Config(listen="127.0.0.1:0"),
        mavlink=MavlinkConfig(url=f"udpout:127.0.0.1:{port}", sysid=FUSER_SYSID),
    )
    try:
        client = socket.create_connection(outputs.workers["sbs1"].sink.address[:2], timeout=3.0)
        time.sleep(0.2)  # the server accepts on its own thread
        track = fused()
        expected = fused_track_message(track, FRAME)
        adsb, heartbeat = None, None
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and (adsb is None or heartbeat is None):
            outputs.publish([track], time.time_ns())
            m = station.recv_match(type=["ADSB_VEHICLE", "HEARTBEAT"], blocking=True, timeout=0.2)
            if m is not None and m.get_type() == "ADSB_VEHICLE":
                adsb = m
            elif m is not None:
                heartbeat = m
        assert heartbeat is not None and heartbeat.get_srcSystem() == FUSER_SYSID
        assert adsb is not None and adsb.ICAO_address == 3
        assert adsb.lat / 1e7 == pytest.approx(expected["lat"], abs=2e-7)
        assert adsb.lon / 1e7 == pytest.approx(expected["lon"], abs=2e-7)
        text = _read_until(client, b"MSG,3,")
        position = next(line for line in text.split("\r\n") if line.startswith("MSG,3,"))
        fields = position.split(",")
        assert fields[4] == "000003"  # the fused id's 24-bit address
        assert float(fields[14]) == pytest.approx(expected["lat"], abs=1e-5)
        assert float(fields[15]) == pytest.approx(expected["lon"], abs=1e-5)
        client.close()
    finally:
        outputs.close()
        station.close()
