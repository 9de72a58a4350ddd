"""Live network sources: an H.264 MPEG-TS stream served over TCP by a helper process (PyAV) is read
through OpenCV's FFmpeg backend; when the server dies and comes back the capture reconnects with
backoff, and when it stops sending the stall watchdog notices and the capture recovers."""

from __future__ import annotations

import os
import signal
import time

import pytest
from daemon_media import free_port, start_server, stop_process

from dronekey.daemon.config.source import NetworkSettings, SourceConfig
from dronekey.daemon.sources import Capture, SourceState, make_reader


def live_capture(port: int, **overrides) -> Capture:
    config = SourceConfig(
        uri=f"tcp://127.0.0.1:{port}",
        stall_timeout_s=overrides.pop("stall_timeout_s", 1.5),
        reconnect_initial_s=0.2,
        reconnect_max_s=1.0,
        network=NetworkSettings(open_timeout_s=3.0),
        **overrides,
    )
    return Capture(make_reader(config), config)


def take_frames(capture: Capture, n: int, timeout_s: float) -> list:
    frames = []
    deadline = time.monotonic() + timeout_s
    while len(frames) < n and time.monotonic() < deadline:
        item = capture.get(0.1)
        if item is not None:
            frames.append(item.frame)
    assert len(frames) == n, f"got {len(frames)} of {n} frames in {timeout_s} s; state {capture.state}"
    return frames


def wait_for(predicate, timeout_s: float, what: str, capture: Capture) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        capture.get(0.05)  # keep consuming like the daemon does
    raise AssertionError(f"{what} did not happen within {timeout_s} s (state {capture.state})")


@pytest.fixture
def port():
    return free_port()


def test_tcp_stream_is_reconnected_after_the_server_restarts(port):
    server = start_server(port)
    capture = live_capture(port)
    try:
        capture.start()
        first = take_frames(capture, 10, timeout_s=20)
        assert capture.state == SourceState.STREAMING
        assert first[0].t_ns > 1_600_000_000 * 10**9  # live frames carry Unix time

        stop_process(server)  # the stream disappears
        wait_for(lambda: capture.state == SourceState.RECONNECTING, 10, "reconnecting", capture)
        time.sleep(1.5)  # a few refused attempts with backoff
        assert capture.state in (SourceState.RECONNECTING, SourceState.CONNECTING)
        assert capture.last_error

        server = start_server(port)  # ... and comes back
        wait_for(lambda: capture.state == SourceState.STREAMING, 20, "streaming again", capture)
        again = take_frames(capture, 10, timeout_s=20)
        assert capture.stats().reconnects == 1
        assert again[0].index > first[-1].index and again[0].t_ns > first[-1].t_ns
    finally:
        capture.stop()
        stop_process(server)


def test_stalled_stream_is_detected_and_recovered(port):
    server = start_server(port)
    capture = live_capture(port, stall_timeout_s=1.0)
    try:
        capture.start()
        take_frames(capture, 5, timeout_s=20)
        os.kill(server.pid, signal.SIGSTOP)  # connected, but no more data: a stall
        wait_for(lambda: capture.state == SourceState.STALLED, 10, "stall detection", capture)
        assert "no frame for" in capture.last_error
        wait_for(
            lambda: capture.state == SourceState.RECONNECTING, 10, "reconnection after the stall", capture
        )
        os.kill(server.pid, signal.SIGCONT)  # the server serves the next connection
        wait_for(lambda: capture.state == SourceState.STREAMING, 20, "streaming again", capture)
        take_frames(capture, 5, timeout_s=20)
        assert capture.stats().reconnects >= 1
    finally:
        capture.stop()
        os.kill(server.pid, signal.SIGCONT)
        stop_process(server)


def test_live_source_gives_up_after_max_reconnects(port):
    capture = live_capture(port, max_reconnects=2)  # nothing listens on the port
    capture.start()
    wait_for(lambda: capture.finished, 15, "giving up", capture)
    assert capture.state == SourceState.FAILED and capture.gave_up
    assert "cannot open stream" in capture.last_error
