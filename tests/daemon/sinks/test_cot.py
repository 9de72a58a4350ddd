"""The TAK Cursor-on-Target output with real peers on 127.0.0.1, parsed by takproto and as XML.

Peers: a UDP socket, a multicast group joined on the loopback interface, a TCP listener, a TLS
listener that asks for a client certificate (certificates made with ``cryptography``), and a TCP
peer that accepts and never reads.
"""

from __future__ import annotations

import datetime as dt
import math
import socket
import ssl
import struct
import threading
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import takproto
from factories import make_track
from test_zenoh_security import CertificateAuthority

from dronekey.daemon.config.cot import CotConfig, CotTlsConfig, CotUrl
from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.base import FrameUpdate, SinkWorker
from dronekey.daemon.sinks.cot import CotSink
from dronekey.daemon.sinks.target_state import target_geodetic
from dronekey.types import Track, TrackStatus

GEO = CameraGeo.parse("47.3977,8.5456,488.0,30,5,0")


def update(*tracks: Track) -> FrameUpdate:
    return FrameUpdate("cam0", 0, time.time_ns(), time.monotonic_ns(), tuple(tracks))


def cot_time(text: str) -> dt.datetime:
    return dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=dt.UTC)


def wait_for(condition, timeout_s: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.01)
    return condition()


class Collector:
    """Events received by a peer: the raw bytes of each, in order."""

    def __init__(self) -> None:
        self.events: list[bytes] = []
        self._lock = threading.Lock()

    def add_stream(self, buffer: bytes) -> bytes:
        """Split complete events off a TCP stream buffer; returns the rest."""
        while b"</event>" in buffer:
            head, _, buffer = buffer.partition(b"</event>")
            with self._lock:
                self.events.append((head + b"</event>").strip())
        return buffer

    def add_datagram(self, data: bytes) -> None:
        with self._lock:
            self.events.append(data.strip())

    def of_uid(self, uid: str) -> list[ET.Element]:
        with self._lock:
            events = [ET.fromstring(e) for e in self.events]
        return [e for e in events if e.get("uid") == uid]

    def wait(self, uid: str, count: int = 1) -> list[ET.Element]:
        assert wait_for(lambda: len(self.of_uid(uid)) >= count), f"{uid}: {len(self.of_uid(uid))} events"
        return self.of_uid(uid)


def serve_udp(sock: socket.socket, collector: Collector, stop: threading.Event) -> threading.Thread:
    sock.settimeout(0.1)

    def run() -> None:
        while not stop.is_set():
            try:
                collector.add_datagram(sock.recv(65536))
            except TimeoutError:
                continue
            except OSError:  # closed by the test
                return

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def serve_stream(listener: socket.socket, collector: Collector, stop: threading.Event, wrap=None):
    """Accept connections (``wrap``: TLS) and collect their events until ``stop``."""
    listener.settimeout(0.1)

    def handle(conn: socket.socket) -> None:
        conn.settimeout(0.1)
        buffer = b""
        while not stop.is_set():
            try:
                chunk = conn.recv(65536)
            except TimeoutError:
                continue
            except (OSError, ssl.SSLError):
                return
            if not chunk:
                return
            buffer = collector.add_stream(buffer + chunk)
        conn.close()

    def run() -> None:
        while not stop.is_set():
            try:
                conn, _ = listener.accept()
                if wrap is not None:
                    conn.settimeout(5)
                    conn = wrap(conn)
            except (TimeoutError, ssl.SSLError, OSError):
                continue
            threading.Thread(target=handle, args=(conn,), daemon=True).start()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


@pytest.fixture
def stop():
    event = threading.Event()
    yield event
    event.set()


@pytest.fixture
def udp_peer(stop):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    collector = Collector()
    serve_udp(sock, collector, stop)
    yield sock.getsockname()[1], collector
    stop.set()
    sock.close()


@pytest.fixture
def tcp_peer(stop):
    listener = socket.create_server(("127.0.0.1", 0))
    collector = Collector()
    serve_stream(listener, collector, stop)
    yield listener.getsockname()[1], collector
    stop.set()
    listener.close()


def check_track_event(event: ET.Element, track: Track) -> None:
    """The CoT fields of a track event, against the track's geodetic state."""
    assert event.tag == "event" and event.get("version") == "2.0"
    assert event.get("uid") == f"dronekey-cam0-{track.track_id}"
    assert event.get("type") == "a-u-A-M-H-Q" and event.get("how") == "m-p"
    time_, start, stale = (cot_time(event.get(k)) for k in ("time", "start", "stale"))
    assert time_ == start and stale - time_ == dt.timedelta(seconds=5)
    assert abs((time_ - dt.datetime.fromtimestamp(track.t_ns / 1e9, dt.UTC)).total_seconds()) < 1e-3
    state = target_geodetic(track, GEO)
    point = event.find("point")
    assert float(point.get("lat")) == pytest.approx(state.lat_deg, abs=2e-7)
    assert float(point.get("lon")) == pytest.approx(state.lon_deg, abs=2e-7)
    assert float(point.get("hae")) == pytest.approx(state.alt_m, abs=0.01)
    horizontal = np.linalg.eigvalsh(state.position_cov_ned[:2, :2]).max()
    assert float(point.get("ce")) == pytest.approx(math.sqrt(horizontal), abs=0.01)
    assert float(point.get("le")) == pytest.approx(math.sqrt(state.position_cov_ned[2, 2]), abs=0.01)
    course = event.find("detail/track")
    assert float(course.get("speed")) == pytest.approx(state.ground_speed_mps, abs=0.01)
    assert float(course.get("course")) == pytest.approx(state.course_deg, abs=0.1)
    figures = event.find("detail/dronekey")
    assert float(figures.get("range_m")) == pytest.approx(np.linalg.norm(track.position_m), abs=0.01)
    assert float(figures.get("score")) == pytest.approx(track.score, abs=1e-3)
    assert float(figures.get("heading_confidence")) == pytest.approx(track.heading_confidence, abs=1e-3)
    assert figures.get("bearing_true_deg") is not None
    assert event.find("detail/contact").get("callsign") == f"DK{track.track_id:06d}"


def parse_with_takproto(raw: bytes):
    """takproto's own reading of an XML event (what pytak/TAK gateways convert to TAK protocol 1)."""
    message = takproto.parse_proto(bytearray(raw))
    assert message is not None, raw[:80]
    return message.cotEvent


def test_udp_track_events_parse_with_takproto(udp_peer):
    port, peer = udp_peer
    sink = CotSink(CotConfig(url=f"udp://127.0.0.1:{port}", min_interval_s=0), "cam0", GEO, fov_deg=62.2)
    try:
        track = make_track(score=0.91, heading_confidence=0.8)
        sink.handle_update(update(track))
        (event,) = peer.wait("dronekey-cam0-7")
        check_track_event(event, track)
        raw = next(e for e in peer.events if b'uid="dronekey-cam0-7"' in e)
        cot = parse_with_takproto(raw)
        assert (cot.uid, cot.type, cot.how) == ("dronekey-cam0-7", "a-u-A-M-H-Q", "m-p")
        assert cot.staleTime - cot.sendTime == 5000  # ms
        assert cot.lat == pytest.approx(float(event.find("point").get("lat")))
        assert cot.detail.contact.callsign == "DK000007"
        assert cot.detail.track.speed == pytest.approx(float(event.find("detail/track").get("speed")))
        assert "<dronekey" in cot.detail.xmlDetail  # our detail travels through TAK protocol 1 too
        # the sensor's own point, sent at start
        (sensor,) = peer.wait("dronekey-cam0")
        assert sensor.get("type") == "a-f-G-E-S-E" and sensor.get("how") == "h-e"
        assert float(sensor.find("point").get("lat")) == pytest.approx(GEO.lat_deg)
        cone = sensor.find("detail/sensor")
        assert (float(cone.get("azimuth")), float(cone.get("fov"))) == (30.0, 62.2)
        stale = cot_time(sensor.get("stale")) - cot_time(sensor.get("time"))
        assert stale == dt.timedelta(seconds=30)  # 3 periods of sensor_interval_s
    finally:
        sink.close()


def test_lost_track_is_stale_now_then_deleted(udp_peer):
    port, peer = udp_peer
    sink = CotSink(CotConfig(url=f"udp://127.0.0.1:{port}", min_interval_s=0), "cam0", GEO)
    try:
        sink.handle_update(update(make_track(3), make_track(4, status=TrackStatus.TENTATIVE)))
        peer.wait("dronekey-cam0-3")
        sink.handle_update(
            update(make_track(3, status=TrackStatus.LOST), make_track(4, status=TrackStatus.LOST))
        )
        shown, lost = peer.wait("dronekey-cam0-3", 2)
        assert cot_time(lost.get("stale")) == cot_time(lost.get("time"))  # stale now
        assert cot_time(lost.get("time")) >= cot_time(shown.get("time"))
        assert lost.find("detail/dronekey").get("status") == "lost"
        (delete,) = peer.wait("dronekey-cam0-3-delete")
        assert delete.get("type") == "t-x-d-d"
        link = delete.find("detail/link")
        assert (link.get("uid"), link.get("relation")) == ("dronekey-cam0-3", "none")
        assert delete.find("detail/__forcedelete") is not None
        assert parse_with_takproto(ET.tostring(delete, xml_declaration=True)).type == "t-x-d-d"
        assert peer.of_uid("dronekey-cam0-4") == []  # tentative: never shown, nothing to take down
        assert sink.health()["events"]["lost"] == 1
    finally:
        sink.close()


def test_min_interval_limits_each_track(udp_peer):
    port, peer = udp_peer
    sink = CotSink(CotConfig(url=f"udp://127.0.0.1:{port}", min_interval_s=0.5), "cam0", GEO)
    try:
        for _ in range(20):
            sink.handle_update(update(make_track(1), make_track(2)))
        peer.wait("dronekey-cam0-1")
        peer.wait("dronekey-cam0-2")
        time.sleep(0.2)
        assert len(peer.of_uid("dronekey-cam0-1")) == 1 and len(peer.of_uid("dronekey-cam0-2")) == 1
    finally:
        sink.close()


def test_tcp_peer_gets_track_and_lost_events(stop):
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    peer = Collector()
    serve_stream(listener, peer, stop)
    sink = CotSink(CotConfig(url=f"tcp://127.0.0.1:{port}", min_interval_s=0), "cam0", GEO)
    try:
        track = make_track(5)
        sink.handle_update(update(track))
        (event,) = peer.wait("dronekey-cam0-5")
        check_track_event(event, track)
        assert sink.health()["state"] == "open" and sink.failing() is None
        sink.handle_update(update(make_track(5, status=TrackStatus.LOST)))
        peer.wait("dronekey-cam0-5-delete")
    finally:
        sink.close()
        listener.close()


def test_tcp_peer_absent_then_present(stop):
    probe = socket.create_server(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()  # nobody listens: refused
    config = CotConfig(url=f"tcp://127.0.0.1:{port}", min_interval_s=0)
    sink = CotSink(config, "cam0", GEO)
    try:
        assert wait_for(lambda: sink.failing() is not None)
        assert "ConnectionRefusedError" in sink.failing()
        listener = socket.create_server(("127.0.0.1", port))
        peer = Collector()
        serve_stream(listener, peer, stop)
        assert wait_for(lambda: sink.health()["state"] == "open", timeout_s=5.0)  # backoff 0.5, 1, 2 s
        sink.handle_update(update(make_track(8)))
        peer.wait("dronekey-cam0-8")
        listener.close()
    finally:
        sink.close()


def test_peer_that_never_reads_does_not_stall(stop):
    listener = socket.socket()
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    listener.bind(("127.0.0.1", 0))
    listener.listen()
    accepted = []
    threading.Thread(target=lambda: accepted.append(listener.accept()), daemon=True).start()
    port = listener.getsockname()[1]
    config = CotConfig(url=f"tcp://127.0.0.1:{port}", min_interval_s=0, write_timeout_s=2.0)
    worker = SinkWorker(CotSink(config, "cam0", GEO), max_queue=64)
    sink = worker.sink
    try:
        assert wait_for(lambda: sink.health()["state"] == "open")
        slowest = 0.0
        for i in range(3000):  # about 3 MB of events at the peer's door
            t0 = time.perf_counter()
            worker.submit_update(update(make_track(i % 50 + 1)))
            slowest = max(slowest, time.perf_counter() - t0)
        # The pipeline's side never waits for the socket: a submit that did would take the whole write
        # timeout. (Milliseconds when idle; the bound is the timeout so that load spikes do not count.)
        assert slowest < config.write_timeout_s, f"a submit took {slowest:.3f} s"

        # The transport notices that the peer takes nothing and drops the connection. How much of the
        # burst above reached the socket depends on the machine's load (the queues drop the oldest),
        # so updates keep coming, as from a running pipeline, until the kernel's buffers are full.
        def noticed() -> bool:
            worker.submit_update(update(make_track(1)))
            return "took no data" in (sink.health()["error"] or "")

        assert wait_for(noticed, timeout_s=20.0)
        assert sink.fault_counts()["unsent"] > 0
        assert worker.depth <= 64
    finally:
        t0 = time.monotonic()
        worker.close(timeout_s=3.0)
        assert time.monotonic() - t0 < 4.0
        listener.close()


def test_tls_with_client_certificate(tmp_path, stop):
    ca = CertificateAuthority(tmp_path, "tak-ca")
    server = ca.issue("takserver", server=True)
    client = CotTlsConfig(**ca.issue("dronekey-sensor").model_dump())
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH, cafile=str(ca.pem))
    context.load_cert_chain(server.certificate, server.private_key)
    context.verify_mode = ssl.CERT_REQUIRED  # a TAK Server's TLS input asks for the client's certificate
    peers: list[str] = []

    def wrap(conn: socket.socket) -> ssl.SSLSocket:
        tls = context.wrap_socket(conn, server_side=True)
        peers.append(dict(x[0] for x in tls.getpeercert()["subject"])["commonName"])
        return tls

    listener = socket.create_server(("127.0.0.1", 0))
    peer = Collector()
    serve_stream(listener, peer, stop, wrap=wrap)
    port = listener.getsockname()[1]
    sink = CotSink(CotConfig(url=f"tls://127.0.0.1:{port}", tls=client, min_interval_s=0), "cam0", GEO)
    try:
        track = make_track(11)
        sink.handle_update(update(track))
        (event,) = peer.wait("dronekey-cam0-11")
        check_track_event(event, track)
        assert peers == ["dronekey-sensor"]
    finally:
        sink.close()
        listener.close()


def test_tls_refuses_an_unreadable_key(tmp_path):
    ca = CertificateAuthority(tmp_path, "tak-ca")
    client = CotTlsConfig(**ca.issue("dronekey-sensor").model_dump())
    other = CotTlsConfig(**ca.issue("other").model_dump())
    mixed = CotTlsConfig(
        root_ca=client.root_ca, certificate=client.certificate, private_key=other.private_key
    )
    with pytest.raises(ValueError, match=r"cot\.tls"):
        CotSink(CotConfig(url="tls://127.0.0.1:8089", tls=mixed), "cam0", GEO)


def _loopback_multicast_listener(group: str) -> socket.socket | None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((group, 0))
    try:
        mreq = struct.pack("4s4s", socket.inet_aton(group), socket.inet_aton("127.0.0.1"))
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, mreq)
    except OSError:
        sock.close()
        return None
    return sock


def test_multicast_on_the_loopback_interface(stop):
    group = "239.2.3.1"
    sock = _loopback_multicast_listener(group)
    if sock is None:
        pytest.skip("this machine's loopback interface does not join multicast groups")
    peer = Collector()
    serve_udp(sock, peer, stop)
    port = sock.getsockname()[1]
    # sent on the loopback interface only, with TTL 0: never leaves this machine
    config = CotConfig(
        url=f"udp+multicast://{group}:{port}",
        multicast_interface="127.0.0.1",
        multicast_ttl=0,
        min_interval_s=0,
    )
    sink = CotSink(config, "cam0", GEO)
    try:
        track = make_track(2)
        sink.handle_update(update(track))
        if not wait_for(lambda: peer.of_uid("dronekey-cam0-2"), timeout_s=2.0):
            pytest.skip("multicast on the loopback interface is not delivered on this machine")
        check_track_event(peer.of_uid("dronekey-cam0-2")[0], track)
    finally:
        sink.close()
        sock.close()


def test_refuses_without_camera_geo():
    with pytest.raises(ValueError, match=r"--camera-geo"):
        CotSink(CotConfig(url="udp://127.0.0.1:4242"), "cam0", None)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("udp+multicast://239.2.3.1", ("udp+multicast", "239.2.3.1", 6969)),
        ("udp://10.0.0.5", ("udp", "10.0.0.5", 4242)),
        ("tcp://:8087", ("tcp", "127.0.0.1", 8087)),
        ("tls://tak.example.org", ("tls", "tak.example.org", 8089)),
    ],
)
def test_url_defaults(text, expected):
    assert tuple(CotUrl.parse(text)) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("http://127.0.0.1:80", "must be udp"),
        ("udp+multicast://10.0.0.1:6969", "multicast group"),
        ("tcp://127.0.0.1:99999", "(?i)port"),
        ("udp://[::1]:4242", "IPv6"),
    ],
)
def test_url_errors(text, message):
    with pytest.raises(ValueError, match=message):
        CotConfig(url=text)


def test_cli_flags_and_missing_camera_geo(tmp_path):
    from dronekey.daemon.cli import build_parser, collect_overrides
    from dronekey.daemon.config.errors import ConfigError
    from dronekey.daemon.config.loading import load_config

    args = build_parser().parse_args(["--cot", "udp+multicast://239.2.3.1"])
    with pytest.raises(ConfigError) as err:
        load_config(None, collect_overrides(args))
    (line,) = str(err.value).splitlines()
    assert "cot.url = 'udp+multicast://239.2.3.1:6969' (from --cot)" in line and "--camera-geo" in line
    args = build_parser().parse_args(["--cot", "tls://tak.example.org", "--camera-geo", "47.4,8.5,488"])
    with pytest.raises(ConfigError, match="--cot-cert"):
        load_config(None, collect_overrides(args))
    assert load_config(None).cot.url is None  # off by default
