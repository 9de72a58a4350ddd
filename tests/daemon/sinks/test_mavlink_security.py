"""The MAVLink sink against hostile peers: real pymavlink senders on other UDP ports of
127.0.0.1, a replay across a restart, a forged-timestamp packet, a 2-byte datagram, a flood."""

from __future__ import annotations

import json
import logging
import socket
import time

import psutil
import pytest
from factories import make_track
from pydantic import ValidationError
from test_mavlink_sink import GCS_COMPID, GCS_SYSID, KEY, GroundStation, connect, update

from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.config.loading import config_to_yaml
from dronekey.daemon.sinks.mavlink import MavlinkSink
from dronekey.daemon.sinks.mavlink.verify import StreamTimestamps

SYSID, COMPID = 42, 191
TARGET_RELATIVE = 511


@pytest.fixture
def stations(dialect):
    made = []

    def make(key: bytes | None = None, sysid: int = GCS_SYSID) -> GroundStation:
        station = GroundStation(dialect, key=key, sysid=sysid)
        made.append(station)
        return station

    yield make
    for station in made:
        station.close()


@pytest.fixture
def key_file(tmp_path):
    path = tmp_path / "mavlink.key"
    path.write_bytes(KEY)
    path.chmod(0o600)
    return path


def sink_address(sink: MavlinkSink) -> tuple[str, int]:
    host, port = sink.health()["local"].rsplit(":", 1)
    return host, int(port)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def packer(dialect, sysid=77, compid=1, key: bytes | None = None, link_id=0, timestamp=None):
    """A MAVLink encoder without a connection (``msg.pack(mav)`` gives the bytes)."""
    mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = link_id
        mav.signing.timestamp = (
            timestamp if timestamp is not None else (int(time.time()) - 1420070400) * 100_000
        )
    return mav


def set_interval(dialect, interval_us: int, message_id: int = TARGET_RELATIVE):
    cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
    return dialect.MAVLink_command_long_message(SYSID, COMPID, cmd, 0, message_id, interval_us, 0, 0, 0, 0, 0)


def wait_until(predicate, timeout: float = 3.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def target_relatives_over(sink, station, n: int) -> int:
    station.collect(0.1)
    for i in range(n):
        sink.handle_update(update(make_track(), index=i))
    return sum(m.get_type() == "TARGET_RELATIVE" for m in station.collect(0.4))


# ---------------------------------------------------------------- safe defaults


def test_sockets_bind_to_loopback_and_the_start_line_says_who_may_command(make_sink, stations, caplog):
    gcs = stations()
    with caplog.at_level(logging.INFO, logger="dronekey.daemon.sinks.mavlink.connection"):
        out = make_sink(gcs.url)  # udpout: pymavlink would leave the socket to bind to 0.0.0.0
        port = free_udp_port()
        listening = make_sink(f"udpin:{port}")  # no host given: 127.0.0.1
    connect(out, gcs)  # a send has happened, so an unbound socket would be bound by now
    assert sink_address(out)[0] == "127.0.0.1"
    assert sink_address(listening) == ("127.0.0.1", port)
    assert listening.health()["url"] == f"udpin:127.0.0.1:{port}"
    ours = {sink_address(out)[1], port}
    bound = {c.laddr.port: c.laddr.ip for c in psutil.Process().net_connections(kind="udp")}
    assert ours <= set(bound) and {bound[p] for p in ours} == {"127.0.0.1"}
    starts = [r.getMessage() for r in caplog.records if r.getMessage().startswith("MAVLink on ")]
    assert any(
        f"udpout:127.0.0.1:{gcs.port} (socket 127.0.0.1:" in line
        and f"commands only from 127.0.0.1:{gcs.port} (the link's peer)" in line
        for line in starts
    ), starts
    assert any(
        f"udpin:127.0.0.1:{port} (socket 127.0.0.1:{port})" in line and "first peer heard" in line
        for line in starts
    )


def test_unsigned_command_from_another_port_is_refused(make_sink, stations, dialect):
    gcs = stations()
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    attacker = packer(dialect, sysid=77)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.sendto(bytes(set_interval(dialect, -1).pack(attacker)), sink_address(sink))
        s.settimeout(0.5)
        with pytest.raises(TimeoutError):
            s.recvfrom(65535)  # no ACK, and no track messages either
    assert wait_until(lambda: sink.health()["refusals"]["peer"] == 1)
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 0
    assert target_relatives_over(sink, gcs, 10) == 10  # the ground station still gets every update
    assert sink.fault_counts() == {"refused": 1}


def test_allow_list_admits_hosts_and_ports(make_sink, stations, dialect):
    gcs, a, b = stations(), stations(sysid=200), stations(sysid=201)
    sink = make_sink(gcs.url, allow=[f"127.0.0.1:{a.port}"])
    connect(sink, gcs)
    cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
    for station in (a, b):
        station.conn.clients.add(sink_address(sink))
    b.send(set_interval(dialect, -1))
    assert b.wait_for("COMMAND_ACK", timeout=0.6) is None
    a.send(set_interval(dialect, 200_000))
    assert a.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 200_000
    assert sink.health()["refusals"]["peer"] == 1
    gcs.send(set_interval(dialect, 0))  # the udpout target stays admitted
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED

    anyone = make_sink(gcs.url, allow=["127.0.0.0/8"])  # a network: any host in it, any port
    b.conn.clients = {sink_address(anyone)}
    b.send(set_interval(dialect, -1))
    assert b.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED


def test_listening_link_pins_the_first_peer_heard(make_sink, stations, dialect):
    port = free_udp_port()
    sink = make_sink(f"udpin:127.0.0.1:{port}")
    sink.set_healthy(True)
    first, second = stations(), stations(sysid=201)
    for station in (first, second):
        station.conn.clients.add(("127.0.0.1", port))
    first.send(dialect.MAVLink_ping_message(1, 1, 0, 0))
    assert first.wait_for("PING") is not None
    second.send(dialect.MAVLink_ping_message(2, 2, 0, 0))
    second.send(set_interval(dialect, -1))
    assert second.wait_for("COMMAND_ACK", timeout=0.6) is None
    assert sink.health()["refusals"]["peer"] == 2
    assert f"127.0.0.1:{first.port} (the first peer heard)" in sink.health()["commands_from"]
    sink.handle_update(update(make_track()))
    assert first.wait_for("TARGET_RELATIVE") is not None
    assert second.wait_for("TARGET_RELATIVE", timeout=0.4) is None  # strangers are not sent to either


# ---------------------------------------------------------------- framing


def test_a_two_byte_datagram_does_not_eat_the_next_commands(make_sink, stations, dialect):
    gcs = stations()
    sink = make_sink(gcs.url)
    connect(sink, gcs)
    (address,) = gcs.conn.clients
    gcs.conn.port.sendto(b"\xfd\xff", address)  # a MAVLink 2 start and a payload length of 255
    for interval in (100_000, 200_000, 300_000):
        gcs.send(set_interval(dialect, interval))
    acks = [m for m in gcs.collect(1.0) if m.get_type() == "COMMAND_ACK"]
    assert [a.result for a in acks] == [dialect.MAV_RESULT_ACCEPTED] * 3
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 300_000
    assert sink.health()["refusals"]["malformed"] == 1


# ---------------------------------------------------------------- signing


def test_replay_of_a_captured_command_is_refused_after_a_restart(
    make_sink, stations, dialect, key_file, tmp_path
):
    state = tmp_path / "state"
    state.mkdir()
    gcs = stations(key=KEY)
    cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
    first = make_sink(gcs.url, signing_key_file=key_file, signing_state_dir=state)
    connect(first, gcs)
    captured = bytes(set_interval(dialect, -1).pack(gcs.conn.mav))  # what an eavesdropper records
    gcs.conn.port.sendto(captured, sink_address(first))
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED
    assert first.health()["intervals_us"]["TARGET_RELATIVE"] == -1
    first.close()
    saved = json.loads((state / f"mavlink-signing-{SYSID}-{COMPID}.streams").read_text())
    assert [row[1:3] for row in saved["streams"]] == [[GCS_SYSID, GCS_COMPID]]

    second = make_sink(gcs.url, signing_key_file=key_file, signing_state_dir=state)
    connect(second, gcs)
    gcs.conn.port.sendto(captured, sink_address(second))
    assert gcs.wait_for("COMMAND_ACK", timeout=0.8) is None
    assert second.health()["intervals_us"]["TARGET_RELATIVE"] == 0
    assert second.health()["refusals"]["replay"] == 1
    assert target_relatives_over(second, gcs, 5) == 5
    gcs.conn.clients = {sink_address(second)}
    gcs.send(set_interval(dialect, 500_000))  # the station itself, with a fresh timestamp
    assert gcs.ack(cmd).result == dialect.MAV_RESULT_ACCEPTED


def test_a_wrong_key_packet_with_a_forged_timestamp_does_not_block_the_station(
    make_sink, stations, dialect, key_file, tmp_path
):
    gcs = stations(key=KEY)
    sink = make_sink(gcs.url, signing_key_file=key_file, signing_state_dir=tmp_path)
    connect(sink, gcs)
    link_id = gcs.conn.mav.signing.link_id
    forger = packer(dialect, GCS_SYSID, GCS_COMPID, key=bytes(32), link_id=link_id, timestamp=(1 << 48) - 2)
    (address,) = gcs.conn.clients
    gcs.conn.port.sendto(
        bytes(set_interval(dialect, -1).pack(forger)), address
    )  # from the station's own port
    assert wait_until(lambda: sink.health()["refusals"]["bad_signature"] == 1)
    assert sink.health()["signed_streams"] == 0  # nothing recorded for it
    cmd = dialect.MAV_CMD_SET_MESSAGE_INTERVAL
    gcs.send(set_interval(dialect, 250_000))
    ack = gcs.ack(cmd)
    assert ack is not None and ack.result == dialect.MAV_RESULT_ACCEPTED and ack.get_signed()
    assert sink.health()["intervals_us"]["TARGET_RELATIVE"] == 250_000
    assert sink.health()["signed_streams"] == 1


def test_signed_stream_state_is_capped_oldest_first(make_sink, stations, dialect, key_file, tmp_path):
    gcs = stations(key=KEY)
    sink = make_sink(gcs.url, signing_key_file=key_file, signing_state_dir=tmp_path, max_signed_streams=4)
    connect(sink, gcs)
    (address,) = gcs.conn.clients
    for sysid in range(1, 11):  # ten genuine streams, one after the other
        mav = packer(dialect, sysid=sysid, compid=1, key=KEY, link_id=3)
        gcs.conn.port.sendto(bytes(dialect.MAVLink_ping_message(sysid, 0, 0, 0).pack(mav)), address)
        assert gcs.wait_for("PING", where=lambda m, s=sysid: m.target_system == s) is not None
    assert sink.health()["signed_streams"] == 4
    sink.close()
    saved = json.loads((tmp_path / f"mavlink-signing-{SYSID}-{COMPID}.streams").read_text())
    assert [row[:3] for row in saved["streams"]] == [[3, s, 1] for s in (7, 8, 9, 10)]


def test_a_flood_of_wrong_key_packets_stays_out_of_the_log(
    make_sink, stations, dialect, key_file, tmp_path, caplog
):
    gcs = stations(key=KEY)
    sink = make_sink(gcs.url, signing_key_file=key_file, signing_state_dir=tmp_path)
    connect(sink, gcs)
    (address,) = gcs.conn.clients
    caplog.clear()
    sent = 0
    with caplog.at_level(logging.DEBUG):
        for batch in range(20):  # 2,000 packets, each on a new (link, system, component)
            for i in range(100):
                n = batch * 100 + i
                mav = packer(
                    dialect, sysid=n % 250 + 1, compid=n // 250 + 1, key=bytes(32), timestamp=(1 << 48) - 2
                )
                gcs.conn.port.sendto(
                    bytes(dialect.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav)), address
                )
                sent += 1
            time.sleep(0.02)  # a socket buffer holds a few hundred; a busy machine may still drop some
        assert wait_until(lambda: sink.health()["refusals"]["bad_signature"] >= sent // 2, timeout=5.0)
    records = [r for r in caplog.records if r.levelno >= logging.INFO]
    assert len(records) <= 1, [r.getMessage() for r in records]  # one summary line at most
    assert sink.health()["signed_streams"] == 0
    assert sink.health()["refused_unsigned"] == sink.health()["refusals"]["bad_signature"]


def test_stream_state_file_that_is_corrupt_is_ignored_with_a_warning(tmp_path, caplog):
    path = tmp_path / "s.streams"
    path.write_text('{"streams": [[1, 2, 3, "x"]]}')
    with caplog.at_level(logging.WARNING):
        table = StreamTimestamps(path)
    assert len(table) == 0 and "corrupt" in caplog.text and str(path) in caplog.text
    assert table.accept((1, 2, 3), 100, our_timestamp=0) and not table.accept((1, 2, 3), 100, our_timestamp=0)


# ---------------------------------------------------------------- configuration


def test_config_names_a_bad_allow_entry_and_prints_the_settings():
    with pytest.raises(ValidationError, match=r"mavlink\.allow entry '10\.0\.0\.300'"):
        DaemonConfig.model_validate({"mavlink": {"allow": ["10.0.0.5", "10.0.0.300"]}})
    config = DaemonConfig.model_validate({"mavlink": {"url": "udpin:14550", "allow": ["10.0.0.0/24:14550"]}})
    assert config.mavlink.url == "udpin:127.0.0.1:14550"
    text = config_to_yaml(config)
    assert "url: udpin:127.0.0.1:14550" in text and "10.0.0.0/24:14550" in text
    assert "allow: []" in config_to_yaml(DaemonConfig())
