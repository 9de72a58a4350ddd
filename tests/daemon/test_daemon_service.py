"""dronekey-daemon as a service: sd_notify on a real AF_UNIX datagram socket (READY, WATCHDOG,
STATUS, STOPPING), SIGTERM / SIGINT closing every output and finalising the MCAP within 5 s,
journald-style logs, corrupt frames skipped, and the exit codes of docs/daemon.md.

The daemon runs as a real process with the real pipeline and ONNX Runtime; the keypoint model is
an untrained ONNX file with the shipped model's contract (``daemon_media.write_untrained_model``),
so these tests do not depend on training (tracking itself is tested end to end elsewhere).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_media import damage_mjpeg_frames, encode_clip, free_port, write_untrained_model
from mcap.reader import make_reader as make_mcap_reader

from dronekey.daemon.errors import ExitCode
from dronekey.geometry.camera import CameraModel


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("assets")
    encode_clip(folder / "clip.mp4", "libx264", frames=30)
    damage_mjpeg_frames(
        encode_clip(folder / "mjpeg.avi", "mjpeg", frames=30), folder / "damaged.avi", [3, 4, 17]
    )
    CameraModel.from_fov(640, 480, 60).save_yaml(folder / "camera.yaml")  # scaled to 320x240
    write_untrained_model(folder / "untrained.onnx")
    return folder


def daemon_env(**extra: str) -> dict[str, str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID", "JOURNAL_STREAM", "STATE_DIRECTORY")
    }
    env.update(extra)
    return env


def daemon_args(assets: Path, source: str, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "dronekey.daemon.cli", "--source", source,
        "--model", str(assets / "untrained.onnx"), "--calib", str(assets / "camera.yaml"),
        "--no-zenoh", "--no-mavlink", *extra,
    ]  # fmt: skip


class NotifySocket:
    """The systemd side of sd_notify: an AF_UNIX datagram socket collecting the messages."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.messages: list[str] = []

    def wait_for(self, prefix: str, timeout_s: float, containing: str = "") -> str:
        """The first line received that starts with ``prefix`` and contains ``containing``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for message in self.messages:
                for line in message.splitlines():
                    if line.startswith(prefix) and containing in line:
                        return line
            with contextlib.suppress(TimeoutError):
                self.messages.append(self.sock.recv(4096).decode())
        raise AssertionError(f"no {prefix!r} within {timeout_s} s; got {self.messages}")

    def close(self) -> None:
        self.sock.close()


@pytest.mark.parametrize(
    ("signum", "code"), [(signal.SIGTERM, ExitCode.SIGTERM), (signal.SIGINT, ExitCode.SIGINT)]
)
def test_signal_stops_within_5_s_with_sd_notify(tmp_path, assets, signum, code):
    notify = NotifySocket(tmp_path / "notify.sock")
    mcap_dir = tmp_path / "mcap"
    proc = subprocess.Popen(
        daemon_args(assets, str(assets / "clip.mp4"), "--realtime", "--loop", "--mcap-dir", str(mcap_dir)),
        env=daemon_env(NOTIFY_SOCKET=str(notify.path), WATCHDOG_USEC="1000000"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert notify.wait_for("READY=1", 60) == "READY=1"
        assert notify.wait_for("WATCHDOG=1", 10) == "WATCHDOG=1"
        status = notify.wait_for("STATUS=", 10, containing="fps")
        assert "source streaming" in status and "mcap q" in status, status
        time.sleep(1.0)  # a few more frames into the MCAP
        sent = time.monotonic()
        proc.send_signal(signum)
        proc.wait(timeout=10)
        elapsed = time.monotonic() - sent
        stderr = proc.stderr.read()
        assert proc.returncode == code, stderr
        assert elapsed < 5.0, f"took {elapsed:.1f} s"
        assert notify.wait_for("STOPPING=1", 1) == "STOPPING=1"
    finally:
        if proc.poll() is None:
            proc.kill()
        notify.close()
    (recording,) = mcap_dir.glob("*.mcap")
    with open(recording, "rb") as f:  # finalised: the summary (footer) is there
        summary = make_mcap_reader(f).get_summary()
    assert summary is not None and summary.statistics.message_count > 0
    assert "outputs closed" in stderr


def test_journald_logs_and_corrupt_frames_skipped(tmp_path, assets):
    log_path = tmp_path / "journal.txt"
    with open(log_path, "w") as log_file:
        st = os.fstat(log_file.fileno())
        result = subprocess.run(
            daemon_args(assets, str(assets / "damaged.avi"), "--no-mcap"),
            env=daemon_env(JOURNAL_STREAM=f"{st.st_dev}:{st.st_ino}"),
            stderr=log_file,
            stdout=subprocess.PIPE,
            timeout=60,
        )
    text = log_path.read_text()
    assert result.returncode == ExitCode.OK, text
    lines = text.splitlines()
    assert lines and all(re.match(r"^<[2-7]>", line) for line in lines), text  # sd-daemon priorities
    assert not re.search(r"\d\d:\d\d:\d\d", text)  # journald stamps the lines itself
    assert "\x1b[" not in text
    totals = next(line for line in lines if "totals:" in line)
    assert "27 frames processed" in totals and "3 corrupt" in totals


def test_bad_model_file_is_one_line_and_exit_2(tmp_path, assets):
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"this is not an onnx file")
    args = daemon_args(assets, str(assets / "clip.mp4"), "--no-mcap")
    args[args.index("--model") + 1] = str(bad)
    result = subprocess.run(args, env=daemon_env(), capture_output=True, text=True, timeout=60)
    assert result.returncode == ExitCode.USAGE, result.stderr
    errors = [line for line in result.stderr.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and "model:" in errors[0], result.stderr
    assert "Traceback" not in result.stderr


def test_live_source_that_never_comes_is_exit_3(tmp_path, assets):
    config = tmp_path / "config.yaml"
    config.write_text(
        "source:\n  max_reconnects: 1\n  reconnect_initial_s: 0.1\n  network: {open_timeout_s: 1}\n"
    )
    args = daemon_args(assets, f"tcp://127.0.0.1:{free_port()}", "--no-mcap", "--config", str(config))
    result = subprocess.run(args, env=daemon_env(), capture_output=True, text=True, timeout=60)
    assert result.returncode == ExitCode.SOURCE_FAILED, result.stderr
    assert "failed permanently" in result.stderr


def test_outputs_without_peers_never_stop_tracking(tmp_path, assets):
    """No Zenoh router (client mode), no MAVLink peer (TCP refused), an MCAP folder that cannot be
    created: every frame is still processed and the file still ends with exit 0."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the MCAP folder should be")
    args = daemon_args(assets, str(assets / "clip.mp4"))
    args = [a for a in args if a not in ("--no-zenoh", "--no-mavlink")]
    args += [
        "--zenoh-mode", "client", "--zenoh-connect", f"tcp/127.0.0.1:{free_port()}", "--no-zenoh-scouting",
        "--mavlink", f"tcp:127.0.0.1:{free_port()}", "--mcap-dir", str(blocker / "mcap"),
    ]  # fmt: skip
    result = subprocess.run(args, env=daemon_env(), capture_output=True, text=True, timeout=60)
    assert result.returncode == ExitCode.OK, result.stderr
    totals = next(line for line in result.stderr.splitlines() if "totals:" in line)
    assert "30 frames processed" in totals
    warnings = [line.lower() for line in result.stderr.splitlines() if "WARNING" in line]
    assert any("mcap" in line for line in warnings) and any("mavlink" in line for line in warnings)
    assert "Traceback" not in result.stderr
