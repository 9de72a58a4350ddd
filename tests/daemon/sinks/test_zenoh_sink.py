"""Zenoh sink with real sessions: a subscriber in another process over 127.0.0.1, scouting off.

The subscriber (a small script run with the same Python) receives the track and status messages,
sees the liveliness token appear and disappear, and queries the info queryable. Client mode with no
router must neither raise nor hang, and connects in the background once something listens.
"""

from __future__ import annotations

import json
import queue
import socket
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import zenoh
from factories import make_track
from json_checks import schema_errors, strict_json

from dronekey.daemon import messages
from dronekey.daemon.config.zenoh import ZenohConfig
from dronekey.daemon.sinks.base import FrameUpdate
from dronekey.daemon.sinks.zenoh_session import CallbackThreads
from dronekey.daemon.sinks.zenoh_sink import ZenohSink, zenoh_config
from dronekey.geometry.camera import CameraModel

SUBSCRIBER = textwrap.dedent(
    """
    import json, sys, threading, time
    import zenoh

    port, role, want_tracks, want_status = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    if role == "connect":
        config.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    else:
        config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    session = zenoh.open(config)
    got = {"tracks": [], "status": [], "alive": [], "encodings": set()}
    complete, alive, gone = threading.Event(), threading.Event(), threading.Event()

    def receiver(kind, want):
        def on_sample(sample):
            got[kind].append(sample.payload.to_string())
            got["encodings"].add(str(sample.encoding))
            if len(got["tracks"]) >= want_tracks and len(got["status"]) >= want_status:
                complete.set()
        return on_sample

    def on_alive(sample):
        got["alive"].append([str(sample.key_expr), str(sample.kind)])
        (alive if sample.kind == zenoh.SampleKind.PUT else gone).set()

    subs = [
        session.declare_subscriber("dronekey/cam0/tracks", receiver("tracks", want_tracks)),
        session.declare_subscriber("dronekey/cam0/status", receiver("status", want_status)),
        session.liveliness().declare_subscriber("dronekey/cam0/alive", on_alive, history=True),
    ]
    print("READY", flush=True)
    alive.wait(20)
    info = None
    for reply in session.get("dronekey/cam0/info", timeout=10):
        if reply.ok is not None:
            info = {"payload": reply.ok.payload.to_string(), "encoding": str(reply.ok.encoding)}
    complete.wait(20)
    got["encodings"] = sorted(got["encodings"])
    print(json.dumps({**got, "info": info}), flush=True)
    print("GONE" if gone.wait(20) else "STILL_ALIVE", flush=True)
    session.close()
    """
)


class Subscriber:
    """The subscriber script in its own process, its stdout lines read on a thread."""

    def __init__(self, port: int, role: str, want_tracks: int, want_status: int) -> None:
        args = [sys.executable, "-c", SUBSCRIBER, str(port), role, str(want_tracks), str(want_status)]
        self.process = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
        self._lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.process.stdout:
            self._lines.put(line.strip())

    def line(self, timeout_s: float = 30.0) -> str:
        try:
            return self._lines.get(timeout=timeout_s)
        except queue.Empty:
            pytest.fail(f"the subscriber said nothing for {timeout_s} s (exit code {self.process.poll()})")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait(timeout=10)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.05)


def frame(i: int, n_tracks: int = 2) -> FrameUpdate:
    t_ns = 1_700_000_000_000_000_000 + i * 33_333_333
    tracks = tuple(
        make_track(
            k + 1,
            t_ns=t_ns,
            position_m=(1.0 * k, -2.0, 30.0 + i),
            velocity_mps=(0.0, 0.0, 30.0),
            position_cov=np.eye(3) * 0.05,
            rotation_std_rad=(np.nan, np.nan, np.nan),
            heading_confidence=float("nan"),
            keypoints_px=np.array([[100.0, 100.0], [120.0, 100.0], [120.0, 120.0], [100.0, 120.0]]),
            score=0.9,
            reprojection_px=float("nan"),  # no measurement error known: must arrive as null
        )
        for k in range(n_tracks)
    )
    return FrameUpdate("cam0", i, t_ns, time.monotonic_ns(), tracks)


def status(i: int) -> dict:
    figures = {"healthy": True, "uptime_s": float(i), "fps": 30.0, "source": {"state": "running"}}
    return messages.status_message("cam0", time.time_ns(), figures)


def test_subscriber_in_another_process_gets_tracks_status_liveliness_and_info():
    port = free_port()
    info = messages.info_message("cam0", CameraModel.from_fov(1920, 1080, 70.0), model={"name": "test"})
    sink = ZenohSink(ZenohConfig(listen=[f"tcp/127.0.0.1:{port}"]), "cam0", info=info)
    subscriber = Subscriber(port, "connect", want_tracks=40, want_status=3)
    try:
        assert sink.wait_open(10), sink.health()
        assert subscriber.line() == "READY"
        wait_for(lambda: sink.health().get("subscribers"), 20, "the subscriber to be matched")
        for i in range(20):
            sink.handle_update(frame(i))  # 2 tracks each: 40 messages
        for i in range(3):
            sink.handle_status(status(i))
        result = json.loads(subscriber.line())
        health = sink.health()
        assert health["state"] == "open" and health["peers"] == 1 and health["published"] == 43
        sink.close()
        assert subscriber.line() == "GONE"  # the liveliness token went with the session
    finally:
        sink.close()
        subscriber.stop()

    assert len(result["tracks"]) == 40 and len(result["status"]) == 3
    tracks = [strict_json(p) for p in result["tracks"]]
    for message in tracks:
        assert schema_errors(message, messages.load_schema("track")) == []
    t0 = 1_700_000_000_000_000_000
    assert [(m["t_ns"], m["track_id"]) for m in tracks[:2]] == [(t0, 1), (t0, 2)]  # integer ns, in order
    assert tracks[0]["reprojection_px"] is None
    assert tracks[-1] == messages.track_message(frame(19).tracks[1], "cam0")
    for payload in result["status"]:
        assert schema_errors(strict_json(payload), messages.load_schema("status")) == []
    assert result["encodings"] == ["application/json;dronekey.Status", "application/json;dronekey.Track"]
    assert result["alive"] == [["dronekey/cam0/alive", "SampleKind.PUT"]]  # and DELETE on close: "GONE"
    assert result["info"]["encoding"] == "application/json;dronekey.Info"
    reply = strict_json(result["info"]["payload"])
    assert schema_errors(reply, messages.load_schema("info")) == []
    assert reply["calibration"]["width"] == 1920 and reply["model"]["name"] == "test"


def test_client_mode_without_router_neither_raises_nor_hangs():
    started = time.monotonic()
    sink = ZenohSink(ZenohConfig(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"]), "cam0")
    constructed_s = time.monotonic() - started
    for i in range(5):
        sink.handle_update(frame(i))
        sink.handle_status(status(i))
    health = sink.health()
    assert health["state"] == "connecting" and health["mode"] == "client"
    assert health["not_sent"] == 15 and health["published"] == 0
    wait_for(lambda: sink.health()["error"], 10, "the first failed attempt to be reported")
    assert sink.failing().startswith("session connecting: ")  # the status line and totals say so
    assert sink.fault_counts() == {"unsent": 15}
    started = time.monotonic()
    sink.close()
    closed_s = time.monotonic() - started
    assert sink.health()["state"] == "closed"
    assert sink.failing() is None and sink.fault_counts() == {"unsent": 15}  # closed on purpose
    # Generous bounds on a shared machine; the real figures are milliseconds.
    assert constructed_s < 5 and closed_s < 5


def test_client_connects_in_the_background_once_a_peer_listens():
    port = free_port()
    sink = ZenohSink(
        ZenohConfig(mode="client", connect=[f"tcp/127.0.0.1:{port}"]), "cam0", connect_timeout_s=0.5,
        retry_max_s=1.0,
    )  # fmt: skip
    subscriber = None
    try:
        wait_for(lambda: sink.health()["error"], 10, "a failed attempt")
        subscriber = Subscriber(port, "listen", want_tracks=6, want_status=0)
        assert subscriber.line() == "READY"
        assert sink.wait_open(20), sink.health()
        wait_for(lambda: sink.health().get("subscribers"), 20, "the subscriber to be matched")
        for i in range(3):
            sink.handle_update(frame(i))
        result = json.loads(subscriber.line())
        assert len(result["tracks"]) == 6
        assert sink.health()["state"] == "open" and sink.health()["error"] is None
    finally:
        sink.close()
        if subscriber is not None:
            subscriber.stop()


def test_config_keys_and_argument_errors():
    config = zenoh_config(
        ZenohConfig(mode="client", connect=["tcp/10.0.0.1:7447"], listen=["udp/0.0.0.0:7448"], scouting=False)
    )

    def key(name):
        return json.loads(config.get_json(name))

    assert key("mode") == "client"
    assert key("connect/endpoints") == ["tcp/10.0.0.1:7447"]
    assert key("listen/endpoints") == ["udp/0.0.0.0:7448"]
    assert key("scouting/multicast/enabled") is False
    assert key("connect/exit_on_failure") is False
    assert key("connect/timeout_ms") == 2000
    with pytest.raises(ValueError, match="connect_timeout_s"):
        zenoh_config(ZenohConfig(), connect_timeout_s=0)
    with pytest.raises(ValueError, match="mode"):
        ZenohConfig(mode="router")
    with pytest.raises(ValueError, match="connect"):
        ZenohConfig(connect="tcp/10.0.0.1:7447")
    with pytest.raises(ValueError, match="listen"):
        ZenohConfig(listen=["10.0.0.1:7447"])
    with pytest.raises(ValueError, match="camera_id"):
        ZenohSink(ZenohConfig(), "cam/0")


def test_endpoints_are_protocol_slash_address_as_zenoh_parses_them(tmp_path):
    # Zenoh's link protocols, the hyphenated unixsock-stream among them, all pass the one rule ...
    endpoints = [
        "tcp/127.0.0.1:7447", "udp/0.0.0.0:7448", "tls/router.fleet.lan:7447", "quic/[::1]:7447",
        "ws/127.0.0.1:7447", "unixsock-stream//run/dronekey.sock", "serial//dev/ttyUSB0#baudrate=115200",
        "vsock/VMADDR_CID_LOCAL:7447",
    ]  # fmt: skip
    assert ZenohConfig(connect=endpoints, listen=endpoints).connect == endpoints
    # ... and a session opens on a Unix socket, which the rule once refused.
    config = ZenohConfig(listen=[f"unixsock-stream/{tmp_path / 'z.sock'}"])
    session = zenoh.open(zenoh_config(config))
    session.close()
    for bad in ("127.0.0.1:7447", "TCP/127.0.0.1:7447", "tcp/", "/127.0.0.1:7447", "tcp/a b"):
        with pytest.raises(ValueError, match="PROTOCOL/ADDRESS"):
            ZenohConfig(connect=[bad])


def test_callback_threads_declared_from_a_daemon_thread_end_before_close_returns():
    """The queryables' delivery threads are daemon threads (the session opens on one); one still in
    zenoh's code when the interpreter finalizes aborts the process, so close waits for them."""
    session = zenoh.open(zenoh_config(ZenohConfig()))
    callbacks = CallbackThreads()
    declared: list[zenoh.Queryable] = []
    delivered_on_daemon: list[bool] = []

    def answer(query: zenoh.Query) -> None:
        delivered_on_daemon.append(threading.current_thread().daemon)
        query.reply("dronekey/test/answer", b"42")

    def declare() -> None:
        declared.append(session.declare_queryable("dronekey/test/answer", callbacks.wrap(answer)))

    opener = threading.Thread(target=declare, daemon=True)
    opener.start()
    opener.join()
    try:
        replies = list(session.get("dronekey/test/answer", timeout=5.0))
        assert [r.ok.payload.to_bytes() for r in replies] == [b"42"]
        assert delivered_on_daemon == [True]
        assert callbacks.wait(0.05) is False  # still declared: its thread waits for queries
    finally:
        declared[0].undeclare()
        session.close()
    assert callbacks.wait(2.0) is True
    assert callbacks.wait(0.0) is True  # nothing left to wait for
