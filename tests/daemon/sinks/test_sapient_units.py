"""The SAPIENT output's parts: the config section and flag, the framing, the error propagation, tasks."""

from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest
from factories import make_track
from pydantic import ValidationError
from sapient_msg.bsi_flex_335_v2_0.registration_ack_pb2 import RegistrationAck
from sapient_msg.bsi_flex_335_v2_0.sapient_message_pb2 import SapientMessage

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.sapient import SapientConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.sapient import geometry
from dronekey.daemon.sinks.sapient.framing import FrameDecoder, FramingError, encode_frame
from dronekey.daemon.sinks.sapient.tasks import Region, reportable

GEO = CameraGeo.parse("51.5,-1.2,100.0,90,5,0")


def test_off_by_default_and_loopback_given_a_port():
    assert DaemonConfig().sapient.connect is None
    assert SapientConfig(connect=5020).connect == "127.0.0.1:5020"
    assert SapientConfig(connect=":5020").address() == ("127.0.0.1", 5020)
    assert SapientConfig(connect="[::1]:5020").address() == ("::1", 5020)
    for bad in ("host:0", "a:b:5020", "host:70000", "", True):
        with pytest.raises(ValidationError, match="HOST:PORT"):
            SapientConfig(connect=bad)
    with pytest.raises(ValidationError, match="UUID"):
        SapientConfig(node_id="not-a-uuid")
    with pytest.raises(ValidationError, match="reconnect_max_s"):
        SapientConfig(reconnect_min_s=5, reconnect_max_s=1)
    node = SapientConfig().resolved_node_id("cam0")
    assert node == SapientConfig().resolved_node_id("cam0") != SapientConfig().resolved_node_id("cam1")


def test_the_flag_one_line_and_exit_2():
    command = [sys.executable, "-m", "dronekey.daemon.cli", "--source", "sim://seq13", "--print-config"]
    good = subprocess.run([*command, "--sapient", "5020"], capture_output=True, text=True, timeout=60)
    assert good.returncode == 0 and "connect: 127.0.0.1:5020" in good.stdout
    bad = subprocess.run([*command, "--sapient", "here:port"], capture_output=True, text=True, timeout=60)
    errors = [line for line in bad.stderr.splitlines() if "sapient.connect" in line]
    assert (
        bad.returncode == 2
        and len(errors) == 1
        and "--sapient" in errors[0]
        and "Traceback" not in bad.stderr
    )


def test_framing_is_a_4_byte_little_endian_length_and_survives_any_split():
    message = SapientMessage(node_id="n", registration_ack=RegistrationAck(acceptance=True))
    frame = encode_frame(message)
    assert struct.unpack("<I", frame[:4])[0] == len(frame) - 4
    decoder = FrameDecoder()
    stream = frame * 3
    received = [m for i in range(len(stream)) for m in decoder.feed(stream[i : i + 1])]
    assert received == [message] * 3
    with pytest.raises(FramingError, match="exceeds"):
        FrameDecoder(max_message_bytes=16).feed(struct.pack("<I", 17))


def test_range_bearing_errors_follow_the_covariance():
    cov = np.array([[0.04, 0.01, 0.0], [0.01, 0.09, 0.02], [0.0, 0.02, 1.0]])
    track = make_track(position_m=(5.0, -3.0, 40.0), position_cov=cov)
    rb = geometry.range_bearing_of(track)
    samples = np.random.default_rng(0).multivariate_normal(track.position_m, cov, 200_000)
    x, y, z = samples.T
    assert rb.range_error_m == pytest.approx(np.linalg.norm(samples, axis=1).std(), rel=0.02)
    assert rb.azimuth_error_deg == pytest.approx(np.degrees(np.arctan2(x, z)).std(), rel=0.02)
    assert rb.elevation_error_deg == pytest.approx(np.degrees(np.arctan2(-y, np.hypot(x, z))).std(), rel=0.02)
    assert geometry.range_bearing_of(make_track(position_m=(np.nan, 0, 1))) is None


def test_geodetic_errors_are_degrees_of_the_ned_spread():
    track = make_track(position_m=(0.0, 0.0, 50.0), position_cov=np.diag([4.0, 4.0, 4.0]))
    g = geometry.geodetic_of(track, GEO)
    metres_per_degree_lat = 111_250  # at 51.5 N
    assert g.lat_error_deg * metres_per_degree_lat == pytest.approx(2.0, rel=0.01)
    assert g.lon_error_deg * metres_per_degree_lat * np.cos(np.radians(51.5)) == pytest.approx(2.0, rel=0.01)
    assert g.alt_error_m == pytest.approx(2.0)


def test_heading_only_once_front_is_told_from_back():
    assert geometry.heading_deg(make_track(heading_confidence=0.49), None) is None
    assert geometry.heading_deg(make_track(heading_confidence=float("nan")), None) is None
    heading, error = geometry.heading_deg(make_track(heading_confidence=0.5), GEO)
    # identity attitude: nose along camera x; the camera looks east (yaw 90), so x points south
    assert heading == pytest.approx(180.0, abs=0.5) and error == pytest.approx(np.degrees(0.03))


def test_regions_include_and_ignore():
    ahead = Region("a", ignore=False, cone=(0.0, 0.0, 0.0, 20.0, 20.0))
    left_ignored = Region("b", ignore=True, cone=(-5.0, 0.0, 0.0, 10.0, 10.0))
    assert reportable(np.array([0.0, 0.0, 10.0]), [ahead], None)
    assert not reportable(np.array([10.0, 0.0, 10.0]), [ahead], None)  # 45 deg right
    assert not reportable(np.array([-0.5, 0.0, 10.0]), [ahead, left_ignored], None)
    east = Region("c", ignore=False, cone=(90.0, 0.0, 100.0, 10.0, 30.0), true_north=True)
    assert reportable(np.array([0.0, 0.0, 50.0]), [east], GEO) and not reportable(
        np.array([0, 0, 150.0]), [east], GEO
    )
    assert not reportable(np.array([0.0, 0.0, 50.0]), [east], None)  # cannot place it: not reported
    lat, lon, _ = GEO.geodetic(np.array([0.0, 0.0, 50.0]))
    square = tuple(
        (lon + dx, lat + dy) for dx, dy in ((-1e-3, -1e-3), (1e-3, -1e-3), (1e-3, 1e-3), (-1e-3, 1e-3))
    )
    field = Region("d", ignore=False, polygon=square)
    assert reportable(np.array([0.0, 0.0, 50.0]), [field], GEO)
    assert not reportable(np.array([0.0, 0.0, 500.0]), [field], GEO)
