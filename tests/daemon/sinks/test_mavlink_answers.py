"""What a ground station asks and the sink answers, through real pymavlink peers on UDP 127.0.0.1:
parameters, MAVLink FTP, commands to component 0, the sensor's own position."""

from __future__ import annotations

import struct

import pytest
from factories import make_track
from test_mavlink_security import packer, sink_address, wait_until
from test_mavlink_sink import GCS_COMPID, GCS_SYSID, GEO, KEY, GroundStation, connect, update

from dronekey.daemon.sinks.mavlink import ftp
from dronekey.daemon.sinks.mavlink.parameters import Parameter, encode_version_number, sensor_parameters
from dronekey.geometry.camera import CameraModel

SYSID, COMPID = 42, 191
CAMERA = CameraModel.from_fov(1920, 1080, 90.0)
MODEL = {"sha256": "c0ffee" + "0" * 58}
# With every source of parameters: ids and version, camera id, model, intrinsics, mount attitude.
PARAM_NAMES = [
    "DK_SYSID",
    "DK_COMPID",
    "DK_VERSION",
    "DK_CAM_ID_HASH",
    "DK_MODEL_HASH",
    "DK_IMG_WIDTH",
    "DK_IMG_HEIGHT",
    "DK_HFOV_DEG",
    "DK_VFOV_DEG",
    "DK_CAM_YAW",
    "DK_CAM_PITCH",
    "DK_CAM_ROLL",
]


@pytest.fixture
def gcs(dialect):
    station = GroundStation(dialect)
    yield station
    station.close()


@pytest.fixture
def described_sink(make_sink, gcs):
    """A sink with the camera geo, id, intrinsics and model, connected to ``gcs``."""
    sink = make_sink(gcs.url, camera_geo=GEO, camera_id="cam0", camera=CAMERA, model_info=MODEL)
    connect(sink, gcs)
    return sink


def param_values(gcs, n: int, timeout: float = 2.0) -> list:
    out = []
    for _ in range(n):
        m = gcs.wait_for("PARAM_VALUE", timeout)
        if m is None:
            break
        out.append(m)
    return out


# ---------------------------------------------------------------- parameters


def test_param_request_list_gets_every_parameter_with_count_and_index(described_sink, gcs, dialect):
    gcs.send(dialect.MAVLink_param_request_list_message(SYSID, 0))  # component 0: every component
    got = param_values(gcs, len(PARAM_NAMES))
    assert [m.param_id for m in got] == PARAM_NAMES
    assert [m.param_index for m in got] == list(range(len(PARAM_NAMES)))
    assert {m.param_count for m in got} == {len(PARAM_NAMES)}
    assert {(m.get_srcSystem(), m.get_srcComponent()) for m in got} == {(SYSID, COMPID)}
    values = {m.param_id: m for m in got}
    assert values["DK_SYSID"].param_value == SYSID and values["DK_COMPID"].param_value == COMPID
    assert values["DK_SYSID"].param_type == dialect.MAV_PARAM_TYPE_INT32
    assert values["DK_MODEL_HASH"].param_value == 0xC0FFEE
    assert values["DK_IMG_WIDTH"].param_value == 1920 and values["DK_IMG_HEIGHT"].param_value == 1080
    assert values["DK_HFOV_DEG"].param_value == pytest.approx(90.0, abs=1e-4)
    assert values["DK_HFOV_DEG"].param_type == dialect.MAV_PARAM_TYPE_REAL32
    assert values["DK_CAM_YAW"].param_value == pytest.approx(30.0)
    assert gcs.wait_for("PARAM_VALUE", 0.3) is None  # no more than param_count


def test_param_read_by_name_and_index_and_set_is_refused(described_sink, gcs, dialect):
    gcs.send(dialect.MAVLink_param_request_read_message(SYSID, COMPID, b"DK_IMG_WIDTH", -1))
    m = gcs.wait_for("PARAM_VALUE")
    assert (m.param_id, m.param_value, m.param_index, m.param_count) == ("DK_IMG_WIDTH", 1920, 5, 12)
    gcs.send(dialect.MAVLink_param_request_read_message(SYSID, COMPID, b"", 1))
    assert gcs.wait_for("PARAM_VALUE").param_id == "DK_COMPID"
    gcs.send(dialect.MAVLink_param_request_read_message(SYSID, COMPID, b"NO_SUCH_PARAM", -1))
    gcs.send(dialect.MAVLink_param_request_read_message(SYSID, COMPID, b"", 99))
    assert gcs.wait_for("PARAM_VALUE", 0.5) is None  # unknown: no answer

    real32 = dialect.MAV_PARAM_TYPE_REAL32
    gcs.send(dialect.MAVLink_param_set_message(SYSID, COMPID, b"DK_HFOV_DEG", 10.0, real32))
    m = gcs.wait_for("PARAM_VALUE")
    assert m.param_id == "DK_HFOV_DEG" and m.param_value == pytest.approx(90.0, abs=1e-4)  # unchanged
    gcs.send(dialect.MAVLink_param_request_read_message(SYSID, COMPID, b"DK_HFOV_DEG", -1))
    assert gcs.wait_for("PARAM_VALUE").param_value == pytest.approx(90.0, abs=1e-4)


def test_param_requests_for_another_component_are_left_alone(described_sink, gcs, dialect):
    gcs.send(dialect.MAVLink_param_request_list_message(SYSID, 1))  # the autopilot's
    gcs.send(dialect.MAVLink_param_request_list_message(7, 0))  # another system's
    assert gcs.wait_for("PARAM_VALUE", 0.6) is None


def test_parameter_table_without_optional_sources():
    names = [p.name for p in sensor_parameters(1, 2, "1.2.3")]
    assert names == ["DK_SYSID", "DK_COMPID", "DK_VERSION"]
    assert sensor_parameters(1, 2, "1.2.3")[2].value == 10203 == encode_version_number("1.2.3.dev4")
    with pytest.raises(ValueError, match="DK_BIG"):
        Parameter("DK_BIG", 1 << 24, integer=True)  # not exact in a float32
    with pytest.raises(ValueError, match=r"1\.\.16"):
        Parameter("A_NAME_LONGER_THAN_16", 1.0)


def test_autopilot_version_says_parameters_are_c_casts_and_no_ftp(described_sink, gcs, dialect):
    gcs.command_long(dialect.MAV_CMD_REQUEST_MESSAGE, dialect.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    caps = gcs.wait_for("AUTOPILOT_VERSION").capabilities
    assert caps & dialect.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    assert not caps & dialect.MAV_PROTOCOL_CAPABILITY_FTP


# ---------------------------------------------------------------- MAVLink FTP


def ftp_request(dialect, opcode: int, seq: int = 7, session: int = 3, data: bytes = b"", target=COMPID):
    header = struct.pack("<HBBBBBBI", seq, session, opcode, len(data), 0, 0, 0, 0)
    payload = (header + data).ljust(251, b"\0")
    return dialect.MAVLink_file_transfer_protocol_message(0, SYSID, target, list(payload))


@pytest.mark.parametrize(
    ("opcode", "reply", "error"),
    [
        (4, ftp.NAK, ftp.ERR_FILE_NOT_FOUND),  # OpenFileRO @PARAM/param.pck (MAVProxy's parameter fetch)
        (3, ftp.NAK, ftp.ERR_FILE_NOT_FOUND),  # ListDirectory
        (6, ftp.NAK, ftp.ERR_FILE_PROTECTED),  # CreateFile
        (15, ftp.NAK, ftp.ERR_INVALID_SESSION),  # BurstReadFile
        (99, ftp.NAK, ftp.ERR_UNKNOWN_COMMAND),
        (2, ftp.ACK, None),  # ResetSessions: nothing to reset
    ],
)
def test_ftp_requests_get_a_nak_with_the_spec_error(described_sink, gcs, dialect, opcode, reply, error):
    gcs.send(ftp_request(dialect, opcode, data=b"@PARAM/param.pck" if opcode == 4 else b""))
    m = gcs.wait_for("FILE_TRANSFER_PROTOCOL")
    assert m is not None, "no FTP reply"
    assert (m.target_system, m.target_component) == (GCS_SYSID, GCS_COMPID)
    seq, session, got_opcode, size, req_opcode, _burst, _offset = ftp.parse_header(m.payload)
    assert (seq, session, got_opcode, req_opcode) == (8, 3, reply, opcode)
    if error is None:
        assert size == 0
    else:
        assert (size, m.payload[12]) == (1, error)


def test_ftp_for_another_component_and_replies_are_not_answered(described_sink, gcs, dialect):
    gcs.send(ftp_request(dialect, 4, target=1))  # the autopilot's
    gcs.send(ftp_request(dialect, ftp.NAK))  # a reply: answering it could ping-pong forever
    assert gcs.wait_for("FILE_TRANSFER_PROTOCOL", 0.6) is None


# ---------------------------------------------------------------- commands to component 0


def test_commands_to_component_zero_get_an_ack(described_sink, gcs, dialect):
    set_mode = dialect.MAV_CMD_DO_SET_MODE
    gcs.command_long(set_mode, 1, 4, target=(SYSID, 0))
    ack = gcs.ack(set_mode)
    assert ack.result == dialect.MAV_RESULT_UNSUPPORTED
    assert (ack.target_system, ack.target_component) == (GCS_SYSID, GCS_COMPID)
    gcs.send(dialect.MAVLink_command_int_message(SYSID, 0, 0, set_mode, 0, 0, 1, 4, 0, 0, 0, 0, 0))
    assert gcs.ack(set_mode).result == dialect.MAV_RESULT_UNSUPPORTED
    gcs.command_long(set_mode, 1, 4, target=(0, 0))  # to everyone: left to the one it is for
    gcs.command_long(set_mode, 1, 4, target=(SYSID, 1))  # to our system's autopilot
    assert gcs.ack(set_mode, timeout=0.6) is None


# ---------------------------------------------------------------- the sensor's own position


def test_own_position_periodic_and_on_request(make_sink, gcs, dialect):
    sink = make_sink(gcs.url, camera_geo=GEO, heartbeat_period_s=0.2)
    connect(sink, gcs)
    got = [m for m in gcs.collect(1.0) if m.get_type() in ("HEARTBEAT", "GLOBAL_POSITION_INT")]
    positions = [m for m in got if m.get_type() == "GLOBAL_POSITION_INT"]
    heartbeats = len(got) - len(positions)
    assert len(positions) >= 3 and abs(len(positions) - heartbeats) <= 1  # one with each heartbeat
    p = positions[-1]
    assert (p.lat, p.lon, p.alt) == (
        round(GEO.lat_deg * 1e7),
        round(GEO.lon_deg * 1e7),
        round(GEO.alt_m * 1000),
    )
    assert (p.relative_alt, p.vx, p.vy, p.vz, p.hdg) == (0, 0, 0, 0, 3000)
    assert positions[0].time_boot_ms <= p.time_boot_ms

    home = dialect.MAV_CMD_GET_HOME_POSITION
    gcs.command_long(home, target=(SYSID, 0))
    assert gcs.ack(home).result == dialect.MAV_RESULT_ACCEPTED
    h = gcs.wait_for("HOME_POSITION")
    assert (h.latitude, h.longitude, h.altitude) == (p.lat, p.lon, p.alt)
    assert list(h.q) == [1, 0, 0, 0]
    request = dialect.MAV_CMD_REQUEST_MESSAGE
    gcs.command_long(request, dialect.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
    assert gcs.ack(request).result == dialect.MAV_RESULT_ACCEPTED
    assert gcs.wait_for("GLOBAL_POSITION_INT") is not None


def test_no_own_position_without_camera_geo(make_sink, gcs, dialect):
    sink = make_sink(gcs.url, heartbeat_period_s=0.2)
    connect(sink, gcs)
    assert not [m for m in gcs.collect(0.6) if m.get_type() == "GLOBAL_POSITION_INT"]
    home = dialect.MAV_CMD_GET_HOME_POSITION
    gcs.command_long(home, target=(SYSID, 0))
    assert gcs.ack(home).result == dialect.MAV_RESULT_DENIED
    sink.handle_update(update(make_track()))  # tracks still flow
    assert gcs.wait_for("TARGET_RELATIVE") is not None


# ---------------------------------------------------------------- the same gatekeeping as commands


def test_answers_only_to_admitted_and_signed_peers(make_sink, dialect, tmp_path):
    key_file = tmp_path / "mavlink.key"
    key_file.write_bytes(KEY)
    key_file.chmod(0o600)
    peer, stranger = GroundStation(dialect, key=KEY), GroundStation(dialect, key=KEY)
    request = dialect.MAVLink_param_request_list_message(SYSID, 0)
    sink = make_sink(peer.url, signing_key_file=key_file, camera_geo=GEO)
    connect(sink, peer)
    sink_at = sink_address(sink)
    unsigned = packer(dialect, sysid=GCS_SYSID, compid=GCS_COMPID)
    peer.conn.port.sendto(request.pack(unsigned), sink_at)
    peer.conn.port.sendto(bytes(ftp_request(dialect, 4).pack(unsigned)), sink_at)
    stranger.conn.port.sendto(request.pack(stranger.conn.mav), sink_at)
    assert wait_until(lambda: sink.health()["refused"] >= 3)
    assert {"PARAM_VALUE", "FILE_TRANSFER_PROTOCOL"}.isdisjoint(sink.health()["sent"])
    assert stranger.wait_for("PARAM_VALUE", 0.3) is None
    refusals = sink.health()["refusals"]
    assert (refusals["unsigned"], refusals["peer"]) == (2, 1)
    peer.send(request)  # signed, from the peer
    assert peer.wait_for("PARAM_VALUE") is not None
    peer.close()
    stranger.close()
