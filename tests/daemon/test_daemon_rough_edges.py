"""What a newcomer trips over first, each pinned: the shipped example config validates after its one
documented edit, no heartbeat "stops" before there was one, honest reconnect counts in the totals,
why a stream did not open, queue figures kept on a long status line, one list of sim presets."""

from __future__ import annotations

import io
import logging
import socket
import subprocess
import sys
import time

import paths
import pytest
from daemon_media import daemon_assets, free_port
from factories import make_track

from dronekey.daemon.config.source import NetworkSettings
from dronekey.daemon.errors import ExitCode
from dronekey.daemon.sinks.base import FrameUpdate, Sink, SinkWorker
from dronekey.daemon.sources import SIM_SOURCES, CaptureStats, SourceOpenError, SourceState
from dronekey.daemon.sources.opencv_readers import NetworkStreamReader
from dronekey.daemon.sources.stream_errors import explain_open_failure
from dronekey.daemon.status import PipelineCounters, TerminalStatusLine, status_figures, status_summary
from dronekey.geometry.camera import CameraModel
from dronekey.sim_replay.presets import PRESETS

EXAMPLE = paths.ROOT / "daemon" / "config.example.yaml"
# The edit docs/daemon.md's service recipe makes: point camera.calibration at the camera's file.
DOCUMENTED_EDIT = ("  calibration: null ", "  calibration: /etc/dronekey/camera.yaml ")


def run_daemon(*args: str, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "dronekey.daemon.cli", *args], capture_output=True, text=True, timeout=timeout
    )


# ------------------------------------------------------------------------------ example config
def test_shipped_example_config_names_the_one_edit_it_needs(tmp_path):
    shipped = tmp_path / "config.yaml"
    shipped.write_text(EXAMPLE.read_text())
    result = run_daemon("--config", str(shipped), "--validate-config")
    assert result.returncode == ExitCode.USAGE, result.stderr
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "camera.calibration" in errors[0], result.stderr
    assert "Traceback" not in result.stderr


def test_example_config_validates_after_the_documented_edit(tmp_path):
    assert DOCUMENTED_EDIT[0] in EXAMPLE.read_text()
    recipe = (paths.ROOT / "docs" / "daemon.md").read_text()
    assert "s|calibration: null|calibration: /etc/dronekey/camera.yaml|" in recipe, "docs name the edit"
    calibration = tmp_path / "camera.yaml"
    CameraModel.from_fov(1920, 1080, 70).save_yaml(calibration)
    edited = EXAMPLE.read_text().replace(DOCUMENTED_EDIT[0], f"  calibration: {calibration} ")
    config = tmp_path / "config.yaml"
    config.write_text(edited)
    result = run_daemon("--config", str(config), "--validate-config")
    assert result.returncode == ExitCode.OK, result.stderr
    assert "config OK" in result.stderr


# ------------------------------------------------------------------------------ MAVLink heartbeat
def test_heartbeat_is_not_said_to_stop_before_it_ever_went_out(make_sink, caplog):
    caplog.set_level(logging.INFO, logger="dronekey.daemon.sinks.mavlink")
    sink = make_sink(f"udpout:127.0.0.1:{free_port()}")
    sink.handle_status({"healthy": False})  # the status before the first frame
    assert not [r for r in caplog.records if "heartbeat" in r.getMessage()]
    sink.handle_update(FrameUpdate("cam0", 0, 0, time.monotonic_ns()))
    sink.handle_status({"healthy": True})
    sink.handle_status({"healthy": False})
    sink.handle_status({"healthy": True})
    said = [r.getMessage() for r in caplog.records if "heartbeat" in r.getMessage()]
    assert said == [
        "MAVLink heartbeat starts",
        "MAVLink heartbeat stops (unhealthy)",
        "MAVLink heartbeat resumes (pipeline healthy)",
    ]


# ------------------------------------------------------------------------------ reconnects
def test_totals_count_failed_reconnect_attempts(tmp_path_factory, tmp_path):
    assets = daemon_assets(tmp_path_factory.mktemp("assets"))
    config = tmp_path / "config.yaml"
    config.write_text(
        "source:\n  max_reconnects: 2\n  reconnect_initial_s: 0.1\n  network: {open_timeout_s: 1}\n"
    )
    result = run_daemon(
        "--source", f"tcp://127.0.0.1:{free_port()}", "--model", str(assets / "untrained.onnx"),
        "--calib", str(assets / "camera.yaml"), "--no-zenoh", "--no-mavlink", "--no-mcap",
        "--config", str(config),
    )  # fmt: skip
    assert result.returncode == ExitCode.SOURCE_FAILED, result.stderr
    totals = next(line for line in result.stderr.splitlines() if "totals:" in line)
    assert "source opened 0 of 3 attempts, 0 reconnects" in totals, totals
    assert "refused" in result.stderr.lower()


# ------------------------------------------------------------------------------ why a stream did not open
def open_error(port: int, open_timeout_s: float) -> str:
    """What OpenCV's stream reader says when tcp://127.0.0.1:PORT does not open."""
    reader = NetworkStreamReader(
        f"tcp://127.0.0.1:{port}", NetworkSettings(open_timeout_s=open_timeout_s), 1.0
    )
    with pytest.raises(SourceOpenError) as failure:
        reader.open()
    return str(failure.value)


def test_refused_port_is_named_refused():
    port = free_port()  # nothing listens there
    message = open_error(port, open_timeout_s=2.0)
    assert f"cannot open stream tcp://127.0.0.1:{port}: connection refused by 127.0.0.1:{port}" in message
    assert "ECONNREFUSED" in message


def test_silent_server_is_named_a_timeout():
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(4)  # accepts (the kernel does), never sends a byte
        port = server.getsockname()[1]
        started = time.monotonic()
        message = open_error(port, open_timeout_s=1.0)
    assert time.monotonic() - started < 10
    assert "accepts connections, but no video stream came within 1.0 s (timed out)" in message, message


def test_explanations_for_hosts_and_datagram_schemes():
    assert "timed out" in explain_open_failure("udp://127.0.0.1:5000", elapsed_s=3.0, open_timeout_s=3.0)
    assert "not found" in explain_open_failure("rtsp://no-such-host.invalid/stream", 0.1, 3.0)


# ------------------------------------------------------------------------------ status line
class _Quiet(Sink):
    name = "quiet"

    def handle_update(self, update: FrameUpdate) -> None:
        pass

    def close(self) -> None:
        pass


def test_status_line_keeps_queue_figures_with_two_tracks(monkeypatch):
    monkeypatch.setenv("COLUMNS", "120")
    workers = {name: SinkWorker(_Quiet()) for name in ("zenoh", "mavlink", "mcap")}
    try:
        capture = CaptureStats(SourceState.STREAMING, 300, 0, 0, 0, None, 0.03)
        tracks = (make_track(1, position_m=(3.0, -1.0, 40.0)), make_track(2, position_m=(-5.0, -2.0, 35.0)))
        figures = status_figures(
            healthy=True, started_mono=time.monotonic(), pipeline_fps=29.8, capture=capture,
            source_uri="seq13.mp4", counters=PipelineCounters(tracks=tracks),
            model_info={"name": None, "path": None, "sha256": None}, workers=workers,
        )  # fmt: skip
        summary = status_summary(figures, capture, tracks)
        stream = io.StringIO()
        TerminalStatusLine(stream).show(summary)
    finally:
        for worker in workers.values():
            worker.close()
    shown = stream.getvalue()
    assert len(shown.split("\x1b[2K")[-1]) <= 120
    for figure in ("zenoh q0", "mavlink q0", "mcap q0", "#1 "):
        assert figure in shown, shown
    assert "#1 " in summary and "#2 " in summary  # systemd's STATUS= and the journal get them all


# ------------------------------------------------------------------------------ sim presets
def test_help_and_the_bad_preset_error_offer_the_same_presets():
    assert "sim://" + "|".join(PRESETS) == SIM_SOURCES
    help_text = run_daemon("--help").stdout
    assert SIM_SOURCES in help_text
    result = run_daemon("--source", "sim://seq99", "--validate-config")
    assert result.returncode == ExitCode.USAGE
    offered = result.stderr.split("available:")[-1]
    assert [p.strip() for p in offered.strip().split(",")] == list(PRESETS), result.stderr
