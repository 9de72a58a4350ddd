"""The MAVLink sink against real pymavlink peers on UDP 127.0.0.1: a ground station listens for what
the sink sends and sends it commands, signed and unsigned."""

from __future__ import annotations

import math
import select
import socket
import time

import pytest
from factories import make_track
from pymavlink import mavutil

from dronekey.daemon.config.mavlink import MavlinkConfig
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, SinkWorker
from dronekey.daemon.sinks.mavlink import MavlinkSink, SigningKeyError, use_dialect
from dronekey.types import Track, TrackStatus

SYSID, COMPID = 42, 191
GCS_SYSID, GCS_COMPID = 255, 190
KEY = bytes(range(100, 132))
GEO = CameraGeo.parse("47.3977,8.5456,488.0,30,5,0")


class GroundStation:
    """A pymavlink peer on a random UDP port of 127.0.0.1, speaking DroneKey's dialect."""

    def __init__(self, dialect, key: bytes | None = None, sysid: int = GCS_SYSID, compid: int = GCS_COMPID):
        conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=sysid, source_component=compid)
        self.conn = use_dialect(conn, dialect)
        self.d = dialect
        if key is not None:
            self.conn.setup_signing(key, sign_outgoing=True)
        self.port = self.conn.port.getsockname()[1]
        self.url = f"udpout:127.0.0.1:{self.port}"

    def poll(self, timeout: float = 0.05) -> list:
        """Every message (BAD_DATA included) that arrives within ``timeout``."""
        ready, _, _ = select.select([self.conn.port], [], [], timeout)
        if not ready:
            return []
        data, addr = self.conn.port.recvfrom(65535)
        self.conn.clients.add(addr)  # replies go to whoever sent to us, as mavutil's udpin does
        self.conn.clients_last_alive[addr] = time.time()
        return self.conn.mav.parse_buffer(data) or []

    def wait_for(self, kind: str, timeout: float = 3.0, where=lambda m: True):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for m in self.poll(0.05):
                if m.get_type() == kind and where(m):
                    return m
        return None

    def collect(self, duration: float) -> list:
        out, deadline = [], time.monotonic() + duration
        while time.monotonic() < deadline:
            out += self.poll(0.05)
        return out

    def send(self, msg) -> None:
        self.conn.mav.send(msg)

    def command_long(self, command: int, p1=0.0, p2=0.0, target=(SYSID, COMPID), p7=0.0) -> None:
        self.send(self.d.MAVLink_command_long_message(*target, command, 0, p1, p2, 0, 0, 0, 0, p7))

    def ack(self, command: int, timeout: float = 2.0):
        return self.wait_for("COMMAND_ACK", timeout, lambda m: m.command == command)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def gcs(dialect):
    station = GroundStation(dialect)
    yield station
    station.close()


def update(*tracks: Track, index: int = 0) -> FrameUpdate:
    return FrameUpdate("cam0", index, time.time_ns(), time.monotonic_ns(), tuple(tracks))


def connect(sink: MavlinkSink, gcs: GroundStation):
    """Make the sink healthy and wait for its heartbeat, so the station knows where to reply."""
    sink.set_healthy(True)
    hb = gcs.wait_for("HEARTBEAT")
    assert hb is not None, "no heartbeat from the sink"
    return hb


# ---------------------------------------------------------------- what the sink sends


def test_heartbeat_and_target_relative(make_sink, gcs, dialect):
    sink = make_sink(gcs.url)
    hb = connect(sink, gcs)
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (SYSID, COMPID)
    assert hb.autopilot == dialect.MAV_AUTOPILOT_INVALID
    assert hb.type == dialect.MAV_TYPE_ONBOARD_CONTROLLER
    assert hb.get_header().incompat_flags == 0 and hb.get_msgbuf()[0] == 0xFD  # MAVLink 2, unsigned

    tentative = make_track(track_id=8, status=TrackStatus.TENTATIVE)
    sink.handle_update(update(make_track(), tentative))
    got = gcs.collect(0.5)
    targets = [m for m in got if m.get_type() == "TARGET_RELATIVE"]
    assert [m.id for m in targets] == [7]  # tentative tracks are not published
    m = targets[0]
    assert (m.get_srcSystem(), m.get_srcComponent()) == (SYSID, COMPID)
    assert m.frame == dialect.TARGET_OBS_FRAME_BODY_FRD
    assert (m.x, m.y, m.z) == pytest.approx((30.0, 1.0, -2.0))
    assert list(m.pos_std) == pytest.approx([0.5, 0.1, 0.2])
    assert m.yaw_std == pytest.approx(0.02)
    assert list(m.q_sensor) == [0, 0, 0, 0]  # no camera geo: sensor attitude unknown
    assert abs(m.timestamp - time.time_ns() // 1000) < 10_000_000
    assert not [x for x in got if x.get_type() in ("TARGET_ABSOLUTE", "ADSB_VEHICLE")]  # need camera geo


def test_yaw_std_reaches_the_ground_station_with_the_front_back_doubt(make_sink, gcs):
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    tracks = (
        make_track(track_id=1, heading_confidence=1.0),
        make_track(track_id=2, heading_confidence=0.82),
        make_track(track_id=3, heading_confidence=0.0),
        make_track(track_id=4, heading_confidence=float("nan")),  # a model without a front/back head
    )
    sink.handle_update(update(*tracks))
    got = {m.id: m for m in gcs.collect(0.5) if m.get_type() == "TARGET_RELATIVE"}
    assert sorted(got) == [1, 2, 3, 4]
    assert got[1].yaw_std == pytest.approx(0.02)
    assert got[2].yaw_std == pytest.approx(math.pi * math.sqrt(0.91 * 0.09), rel=1e-6)
    assert got[3].yaw_std == pytest.approx(math.pi / 2, rel=1e-6)
    assert got[4].yaw_std == pytest.approx(math.pi / 2, rel=1e-6)
    assert len({tuple(m.q_target) for m in got.values()}) == 1  # same attitude; only the doubt differs


def test_geodetic_messages_with_camera_geo(make_sink, gcs):
    sink = make_sink(gcs.url, camera_geo=GEO)
    connect(sink, gcs)
    track = make_track()
    sink.handle_update(update(track))
    absolute = gcs.wait_for("TARGET_ABSOLUTE")
    adsb = gcs.wait_for("ADSB_VEHICLE")
    lat, lon, alt = GEO.geodetic(track.position_m)
    assert (absolute.lat, absolute.lon) == (round(lat * 1e7), round(lon * 1e7))
    assert absolute.alt == pytest.approx(alt, abs=1e-3)
    assert (adsb.lat, adsb.lon, adsb.altitude) == (round(lat * 1e7), round(lon * 1e7), round(alt * 1000))
    assert adsb.emitter_type == 14 and adsb.callsign == "DK000007" and adsb.ICAO_address == 0x000007


def test_heartbeat_only_while_healthy(make_sink, gcs):
    sink = make_sink(gcs.url, heartbeat_period_s=0.2)
    assert gcs.wait_for("HEARTBEAT", timeout=0.6) is None  # no sign of life from the pipeline yet
    connect(sink, gcs)
    sink.handle_status({"healthy": False})
    gcs.collect(0.3)  # a heartbeat already on its way
    assert gcs.wait_for("HEARTBEAT", timeout=1.0) is None
    sink.handle_update(update())  # frames flow again, but the daemon still says unhealthy
    assert gcs.wait_for("HEARTBEAT", timeout=0.6) is None
    sink.handle_status({"healthy": True})
    assert gcs.wait_for("HEARTBEAT", timeout=2.0) is not None


def test_no_listener_breaks_nothing(make_sink, dialect):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sink = make_sink(f"udpout:127.0.0.1:{port}", camera_geo=GEO)
    worker = SinkWorker(sink)
    sink.set_healthy(True)
    for i in range(300):
        worker.submit_update(update(make_track(), index=i))
    t0 = time.monotonic()
    worker.close()
    assert time.monotonic() - t0 < 3.0
    assert worker.stats.errors == 0 and worker.stats.published + worker.stats.dropped == 300
    assert sink.health()["sent"]["TARGET_RELATIVE"] == worker.stats.published


def test_absent_tcp_peer_is_retried_in_background(make_sink):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: connections are refused
    sink = make_sink(f"tcp:127.0.0.1:{port}")
    sink.handle_update(update(make_track()))
    health = sink.health()
    assert not health["link_open"] and "Connection" in health["last_link_error"]
    assert health["send_errors"] >= 1


def test_bad_arguments_are_named(dialect, tmp_path):
    for kwargs, word in (
        ({"url": "udpout:nohostport"}, "mavlink url"),
        ({"url": "udpout:1.2.3.4:5", "sysid": 255}, "sysid"),
        ({"url": "udpout:1.2.3.4:5", "compid": 0}, "compid"),
    ):
        with pytest.raises(ValueError, match=word):
            MavlinkConfig(**kwargs)
    (tmp_path / "bad.key").write_bytes(b"x" * 31)
    with pytest.raises(SigningKeyError, match=r"bad\.key"):
        MavlinkSink(MavlinkConfig(signing_key=tmp_path / "bad.key"))


# ---------------------------------------------------------------- two-way


def test_ping_and_request_message(make_sink, gcs, dialect):
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    gcs.send(dialect.MAVLink_ping_message(123456, 77, 0, 0))
    pong = gcs.wait_for("PING")
    assert (pong.time_usec, pong.seq) == (123456, 77)
    assert (pong.target_system, pong.target_component) == (GCS_SYSID, GCS_COMPID)
    assert (pong.get_srcSystem(), pong.get_srcComponent()) == (SYSID, COMPID)

    cmd = dialect.MAV_CMD_REQUEST_MESSAGE
    gcs.command_long(cmd, dialect.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    ack = gcs.ack(cmd)
    assert ack.result == dialect.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (GCS_SYSID, GCS_COMPID)
    version = gcs.wait_for("AUTOPILOT_VERSION")
    assert version.capabilities & dialect.MAV_PROTOCOL_CAPABILITY_MAVLINK2

    gcs.command_long(cmd, 300)  # PROTOCOL_VERSION: deprecated upstream, not in this pymavlink's common.xml
    expected = "PROTOCOL_VERSION" if hasattr(dialect, "MAVLink_protocol_version_message") else None
    ack = gcs.ack(cmd)
    assert ack.result == (dialect.MAV_RESULT_ACCEPTED if expected else dialect.MAV_RESULT_DENIED)
    gcs.command_long(cmd, dialect.MAVLINK_MSG_ID_TARGET_RELATIVE)  # no track yet
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_TEMPORARILY_REJECTED
    sink.handle_update(update(make_track()))
    gcs.command_long(cmd, dialect.MAVLINK_MSG_ID_TARGET_RELATIVE)
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert gcs.wait_for("TARGET_RELATIVE").id == 7
    gcs.command_long(12345)  # a command we do not know, addressed to us
    assert gcs.ack(12345).result == dialect.MAV_RESULT_UNSUPPORTED


def test_set_message_interval(make_sink, gcs, dialect):
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    set_cmd, req_cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL, dialect.MAV_CMD_REQUEST_MESSAGE
    target_relative = dialect.MAVLINK_MSG_ID_TARGET_RELATIVE

    def sent_over(n: int) -> int:
        gcs.collect(0.1)
        for i in range(n):
            sink.handle_update(update(make_track(), index=i))
        return sum(m.get_type() == "TARGET_RELATIVE" for m in gcs.collect(0.4))

    assert sent_over(10) == 10  # default: every track update

    gcs.command_long(set_cmd, target_relative, 10_000_000)  # one per 10 s
    assert gcs.ack(set_cmd).result == dialect.MAV_RESULT_ACCEPTED
    gcs.command_long(req_cmd, 244, target_relative)  # MESSAGE_INTERVAL of TARGET_RELATIVE
    assert gcs.ack(req_cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert gcs.wait_for("MESSAGE_INTERVAL").interval_us == 10_000_000
    assert sent_over(10) == 1

    # COMMAND_INT works as well; -1 stops the stream
    gcs.send(
        dialect.MAVLink_command_int_message(
            SYSID, COMPID, 0, set_cmd, 0, 0, target_relative, -1, 0, 0, 0, 0, 0
        )
    )
    assert gcs.ack(set_cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert sent_over(10) == 0

    gcs.command_long(set_cmd, target_relative, 0)  # back to the default
    assert gcs.ack(set_cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert sent_over(10) == 10
    assert sink.health()["intervals_us"] == {"TARGET_RELATIVE": 0}

    gcs.command_long(set_cmd, dialect.MAVLINK_MSG_ID_HEARTBEAT, 100_000)  # not a stream we rate
    assert gcs.ack(set_cmd).result == dialect.MAV_RESULT_DENIED


def test_commands_for_other_ids_are_ignored(make_sink, gcs, dialect):
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
    target_relative = dialect.MAVLINK_MSG_ID_TARGET_RELATIVE
    gcs.command_long(cmd, target_relative, -1, target=(SYSID + 1, COMPID))
    gcs.command_long(cmd, target_relative, -1, target=(SYSID, 1))
    gcs.send(dialect.MAVLink_ping_message(1, 1, SYSID, COMPID))  # a ping reply, not a request
    assert gcs.wait_for("COMMAND_ACK", timeout=0.8) is None
    assert gcs.wait_for("PING", timeout=0.2) is None
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 0
    gcs.command_long(cmd, target_relative, 500_000, target=(0, 0))  # broadcast is for us too
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 500_000


# ---------------------------------------------------------------- signing


@pytest.fixture
def key_file(tmp_path):
    path = tmp_path / "mavlink.key"
    path.write_bytes(KEY)
    path.chmod(0o600)
    return path


def _signature_timestamp(msg) -> int:
    buf = msg.get_msgbuf()
    return int.from_bytes(buf[-12:-6], "little")


def test_signed_messages_verify_and_forgeries_are_rejected(make_sink, key_file, dialect):
    station = GroundStation(dialect, key=KEY)
    stranger = GroundStation(dialect, key=bytes(32))  # a listener with another key
    try:
        sink = make_sink(station.url, signing_key_file=key_file)
        connect(sink, station)
        sink.handle_update(update(make_track()))
        m = station.wait_for("TARGET_RELATIVE")
        assert m is not None and m.get_signed()
        assert station.conn.mav.signing.goodsig_count >= 2 and station.conn.mav.signing.badsig_count == 0

        # A forger without the key signs a fresh message from our ids; then the genuine one is replayed.
        forger = dialect.MAVLink(None, srcSystem=SYSID, srcComponent=COMPID)
        forger.signing.secret_key = bytes(32)
        forger.signing.sign_outgoing = True
        forger.signing.link_id = 1
        forger.signing.timestamp = _signature_timestamp(m) + 100_000
        forged = dialect.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3).pack(forger)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.sendto(bytes(forged), ("127.0.0.1", station.port))
            rejected = [x for x in station.collect(0.3) if x.get_type() == "BAD_DATA"]
            assert rejected and "signature" in rejected[0].reason.lower()
            assert station.conn.mav.signing.badsig_count == 1
            s.sendto(bytes(m.get_msgbuf()), ("127.0.0.1", station.port))  # replay
            assert [x.get_type() for x in station.collect(0.3) if x.get_type() != "HEARTBEAT"] == ["BAD_DATA"]

        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a genuine message, wrong key
            s.sendto(bytes(m.get_msgbuf()), ("127.0.0.1", stranger.port))
        got = stranger.collect(0.3)
        assert got and all(x.get_type() == "BAD_DATA" for x in got)
    finally:
        station.close()
        stranger.close()


def test_unsigned_and_wrongly_signed_commands_are_refused(make_sink, key_file, dialect):
    signed = GroundStation(dialect, key=KEY)
    unsigned = GroundStation(dialect)
    wrong = GroundStation(dialect, key=bytes(32))
    try:
        # Any port of 127.0.0.1 may command, so signing is what refuses the other two.
        sink = make_sink(signed.url, signing_key_file=key_file, allow=["127.0.0.1"])
        connect(sink, signed)
        cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
        (sink_address,) = signed.conn.clients  # where the sink sends from
        for station in (unsigned, wrong):
            station.conn.clients.add(sink_address)
            station.command_long(cmd, dialect.MAVLINK_MSG_ID_TARGET_RELATIVE, -1)
            station.send(dialect.MAVLink_ping_message(5, 5, 0, 0))
            assert station.wait_for("COMMAND_ACK", timeout=0.8) is None
            assert station.wait_for("PING", timeout=0.2) is None
        assert sink.health()["refused_unsigned"] >= 4
        assert sink.health()["refusals"]["unsigned"] >= 2 and sink.health()["refusals"]["bad_signature"] >= 2
        assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 0  # unchanged

        signed.command_long(cmd, dialect.MAVLINK_MSG_ID_TARGET_RELATIVE, -1)
        ack = signed.ack(cmd)
        assert ack.result == dialect.MAV_RESULT_ACCEPTED and ack.get_signed()
        assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == -1
    finally:
        for station in (signed, unsigned, wrong):
            station.close()


def test_signing_timestamp_survives_restart(make_sink, key_file, dialect, tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    future = (int(time.time()) - 1420070400 + 3600) * 100_000  # saved while the clock was 1 h ahead
    (state / f"mavlink-signing-{SYSID}-{COMPID}.timestamp").write_text(f"{future}\n")
    station = GroundStation(dialect, key=KEY)
    try:
        sink = make_sink(station.url, signing_key_file=key_file, signing_state_dir=state)
        hb = connect(sink, station)
        assert _signature_timestamp(hb) > future  # continues after the saved value, not from the clock
        sink.close()
        saved = int((state / f"mavlink-signing-{SYSID}-{COMPID}.timestamp").read_text())
        assert saved >= _signature_timestamp(hb)
    finally:
        station.close()
