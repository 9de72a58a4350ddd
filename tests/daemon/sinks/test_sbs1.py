"""The SBS-1 (BaseStation) TCP output with real clients on 127.0.0.1."""

from __future__ import annotations

import datetime as dt
import socket
import time

import pytest
from factories import make_track

from dronekey.daemon.config.sbs1 import Sbs1Config
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate
from dronekey.daemon.sinks.sbs1 import Sbs1Sink, sbs1_lines
from dronekey.daemon.sinks.target_state import target_geodetic
from dronekey.types import Track, TrackStatus

GEO = CameraGeo.parse("47.3977,8.5456,488.0,30,5,0")
ANY_PORT = Sbs1Config(listen="127.0.0.1:0")  # a free port of this machine


def update(*tracks: Track) -> FrameUpdate:
    return FrameUpdate("cam0", 0, time.time_ns(), time.monotonic_ns(), tuple(tracks))


@pytest.fixture
def sink():
    s = Sbs1Sink(ANY_PORT, GEO)
    yield s
    s.close()


def connect(sink: Sbs1Sink, rcvbuf: int | None = None) -> socket.socket:
    """A client connected and accepted by the sink."""
    before = sink.health()["clients_total"]
    client = socket.socket()
    if rcvbuf:
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    client.connect(sink.address[:2])
    client.settimeout(3.0)
    deadline = time.monotonic() + 3
    while sink.health()["clients_total"] == before and time.monotonic() < deadline:
        time.sleep(0.01)
    return client


def read_lines(client: socket.socket, count: int) -> list[str]:
    buf = b""
    while buf.count(b"\r\n") < count:
        chunk = client.recv(65536)
        assert chunk, "server closed the connection"
        buf += chunk
    return buf.decode("ascii").split("\r\n")[:count]


def test_clients_receive_position_lines(sink):
    a, b = connect(sink), connect(sink)
    track = make_track()
    sink.handle_update(update(track, make_track(track_id=9, status=TrackStatus.TENTATIVE)))
    lat, lon, alt = GEO.geodetic(track.position_m)
    for client in (a, b):
        lines = read_lines(client, 3)
        assert [line[:6] for line in lines] == ["MSG,1,", "MSG,3,", "MSG,4,"]  # tentative track 9 left out
        fields = [line.split(",") for line in lines]
        assert all(len(f) == 22 for f in fields)
        ident, position, velocity = fields
        assert ident[4] == "000007" and ident[10] == "DK000007"
        assert position[4] == "000007"
        assert float(position[14]) == pytest.approx(lat, abs=1e-6)
        assert float(position[15]) == pytest.approx(lon, abs=1e-6)
        assert int(position[11]) == round(alt / 0.3048)  # feet, an integer as QGroundControl parses it
        assert position[19] == "0"  # alert flag
        assert 0 <= float(velocity[13]) < 360 and float(velocity[12]) > 0
        dt.datetime.strptime(position[6] + " " + position[7], "%Y/%m/%d %H:%M:%S.%f")
        client.close()


def test_callsign_repeats_only_now_and_then(sink):
    client = connect(sink)
    for _ in range(3):
        sink.handle_update(update(make_track()))
    kinds = [line[:5] for line in read_lines(client, 7)]
    assert kinds == ["MSG,1", "MSG,3", "MSG,4", "MSG,3", "MSG,4", "MSG,3", "MSG,4"]
    client.close()


def test_slow_client_is_dropped_and_others_keep_receiving():
    sink = Sbs1Sink(ANY_PORT, GEO, max_pending_bytes=16384)
    try:
        slow = connect(sink, rcvbuf=4096)  # never reads
        fast = connect(sink)
        fast.settimeout(0)
        tracks = [make_track(i, position_m=(i, 0.0, 50.0)) for i in range(5)]
        updates = 0
        while not sink.health()["clients_dropped_slow"] and updates < 20000:
            sink.handle_update(update(*tracks))
            updates += 1
            time.sleep(0.0005)  # the pace of a fast camera, so the fast client keeps up
            try:
                while fast.recv(1 << 20):
                    pass
            except BlockingIOError:
                pass
        assert sink.health()["clients_dropped_slow"] == 1, updates
        deadline = time.monotonic() + 3
        while sink.health()["clients"] != 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sink.health()["clients"] == 1  # the fast one
        fast.settimeout(3.0)
        sink.handle_update(update(make_track()))
        assert b"MSG,3" in fast.recv(1 << 20)
        slow.close()
        fast.close()
    finally:
        sink.close()


def test_disconnected_client_is_forgotten(sink):
    client = connect(sink)
    client.close()
    deadline = time.monotonic() + 3
    while sink.health()["clients"] and time.monotonic() < deadline:
        sink.handle_update(update(make_track()))
        time.sleep(0.02)
    assert sink.health()["clients"] == 0


def test_refuses_without_camera_geo_or_with_bad_address():
    with pytest.raises(ValueError, match="--camera-geo"):
        Sbs1Sink(ANY_PORT, None)
    for bad in ("host:", "host:99999", "99999", "::30003", "x"):
        with pytest.raises(ValueError, match="HOST:PORT"):
            Sbs1Config(listen=bad)
    assert Sbs1Config(listen="[::1]:30003").address() == ("::1", 30003)
    with pytest.raises(ValueError, match=r"sbs1\.listen is not set"):
        Sbs1Sink(Sbs1Config(), GEO)
    first = Sbs1Sink(ANY_PORT, GEO)
    try:
        port = first.address[1]
        with pytest.raises(OSError, match=f"127.0.0.1:{port}"):
            Sbs1Sink(Sbs1Config(listen=f"127.0.0.1:{port}"), GEO)
    finally:
        first.close()


def test_listen_without_a_host_is_loopback_only():
    port_only, colon_port = Sbs1Config(listen="30003"), Sbs1Config(listen=":30003")
    assert port_only.address() == colon_port.address() == ("127.0.0.1", 30003)
    assert Sbs1Config(listen="30003").listen == Sbs1Config(listen=30003).listen == "127.0.0.1:30003"
    assert Sbs1Config(listen=":0").listen == "127.0.0.1:0"
    assert Sbs1Config(listen="0.0.0.0:30003").listen == "0.0.0.0:30003"  # the network: explicit
    with pytest.raises(ValueError, match="PORT"):
        Sbs1Config(listen="host:")
    for listen in ("0", ":0"):
        sink = Sbs1Sink(Sbs1Config(listen=listen), GEO)
        try:
            assert sink.address[0] == "127.0.0.1"
            client = connect(sink)
            sink.handle_update(update(make_track()))
            assert read_lines(client, 1)[0].startswith("MSG,1")
            client.close()
        finally:
            sink.close()


def publish_for(sink: Sbs1Sink, seconds: float, until=lambda: False, readers=()) -> None:
    """Publish 20 tracks up to 200 times a second (some 800 kB/s) while ``readers`` read: a client
    that does not read fills its kernel buffers within a fraction of a second."""
    tracks = [make_track(i, position_m=(i, 0.0, 50.0)) for i in range(20)]
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not until():
        sink.handle_update(update(*tracks))
        time.sleep(0.005)
        for reader in readers:
            try:
                while reader.recv(1 << 20):
                    pass
            except BlockingIOError:
                pass


def test_client_that_reads_nothing_times_out():
    sink = Sbs1Sink(Sbs1Config(listen="127.0.0.1:0", idle_timeout_s=1.0), GEO, max_pending_bytes=8 << 20)
    try:
        idle = connect(sink, rcvbuf=4096)  # connects and never reads
        reader = connect(sink)
        reader.settimeout(0)
        publish_for(sink, 30.0, until=lambda: sink.health()["clients_dropped_idle"], readers=[reader])
        health = sink.health()
        assert health["clients_dropped_idle"] == 1, health
        assert health["clients_dropped_slow"] == 0  # the time limit, not the size limit (8 MB)
        idle.settimeout(3.0)
        with pytest.raises(ConnectionResetError):
            while idle.recv(1 << 20):
                pass
            raise ConnectionResetError  # closed cleanly: also gone
        publish_for(sink, 0.5, readers=[reader])  # the reader kept up and is still served
        assert sink.health()["clients"] == 1
        reader.close()
    finally:
        sink.close()


def test_full_house_a_newcomer_replaces_a_client_that_reads_nothing():
    sink = Sbs1Sink(
        Sbs1Config(listen="127.0.0.1:0", idle_timeout_s=60.0), GEO, max_clients=2, max_pending_bytes=8 << 20
    )
    try:
        squatters = [connect(sink, rcvbuf=4096) for _ in range(2)]
        early = socket.create_connection(sink.address[:2])  # no data yet: readers and squatters look alike
        deadline = time.monotonic() + 3
        while not sink.health()["clients_refused"] and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sink.health()["clients_refused"] == 1
        # the squatters' buffers fill (however slowly a loaded machine sends), then they accept
        # nothing for more than the 1 s after which a newcomer may take a stalled client's slot
        publish_for(sink, 30.0, until=lambda: sink.health()["clients_stalled"] == 2)
        assert sink.health()["clients_stalled"] == 2
        publish_for(sink, 1.5)
        newcomer = connect(sink)
        newcomer.settimeout(0)
        publish_for(sink, 0.5, readers=[newcomer])
        health = sink.health()
        assert health["clients_refused"] == 1 and health["clients_dropped_idle"] == 1, health
        assert health["clients"] == 2 and health["clients_total"] == 3
        newcomer.settimeout(3.0)
        sink.handle_update(update(make_track()))
        assert b"MSG,3" in newcomer.recv(1 << 20)
        for s in (*squatters, early, newcomer):
            s.close()
    finally:
        sink.close()


def test_line_format_without_course():
    hover = make_track(velocity_mps=(0.0, 0.0, 0.0))
    when = dt.datetime(2025, 1, 2, 3, 4, 5, 678000, tzinfo=dt.UTC)
    lines = sbs1_lines(7, target_geodetic(hover, GEO), when, 0xF00000, with_callsign=False)
    assert [line[:5] for line in lines] == ["MSG,3", "MSG,4"]
    velocity = lines[1].rstrip("\r\n").split(",")
    assert velocity[13] == "" and velocity[6:8] == ["2025/01/02", "03:04:05.678"]
