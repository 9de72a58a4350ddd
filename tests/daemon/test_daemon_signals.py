"""dronekey-daemon and the signals that stop it: SIGHUP stops it cleanly like SIGTERM (exit 129),
and a SIGTERM repeated at once (GNU ``timeout``: the child, then its process group) is the same
request, so the outputs are closed and the MCAP finalised either way.

The daemon runs as a real process on a generated clip with the untrained model of
``daemon_media.write_untrained_model``; the MCAP is read back with the ``mcap`` reader.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from daemon_media import daemon_assets
from mcap.reader import make_reader as make_mcap_reader
from test_daemon_service import NotifySocket, daemon_args, daemon_env

from dronekey.daemon.errors import ExitCode


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    return daemon_assets(tmp_path_factory.mktemp("assets"))


def _hangup(proc: subprocess.Popen) -> None:
    proc.send_signal(signal.SIGHUP)


def _terminate_like_gnu_timeout(proc: subprocess.Popen) -> None:
    """The child, then its process group (the daemon leads its own here), and a few more on top:
    some reach the daemon while its first handler has run and the shutdown is under way."""
    proc.send_signal(signal.SIGTERM)
    for _ in range(4):
        with contextlib.suppress(ProcessLookupError):  # it may be gone already
            os.killpg(proc.pid, signal.SIGTERM)
        time.sleep(0.002)


@pytest.mark.parametrize(
    ("send", "code", "said"),
    [
        (_hangup, ExitCode.SIGHUP, "SIGHUP: stopping like SIGTERM, exit 129"),
        (_terminate_like_gnu_timeout, ExitCode.SIGTERM, "SIGTERM: stopping"),
    ],
    ids=["sighup", "sigterm-twice"],
)
def test_signal_closes_the_outputs_and_finalises_the_mcap(tmp_path, assets, send, code, said):
    notify = NotifySocket(tmp_path / "notify.sock")
    mcap_dir = tmp_path / "mcap"
    proc = subprocess.Popen(
        daemon_args(assets, str(assets / "clip.mp4"), "--realtime", "--loop", "--mcap-dir", str(mcap_dir)),
        env=daemon_env(NOTIFY_SOCKET=str(notify.path)),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        notify.wait_for("READY=1", 60)
        time.sleep(1.0)  # frames going into the MCAP
        send(proc)
        _, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
        notify.close()
    assert proc.returncode == code, stderr
    assert said in stderr and "outputs closed" in stderr, stderr
    assert "exiting now" not in stderr and "exiting anyway" not in stderr, stderr
    assert stderr.count(": stopping") == 1, stderr  # one request, however many signals
    (recording,) = mcap_dir.glob("*.mcap")
    with open(recording, "rb") as f:
        reader = make_mcap_reader(f)
        summary = reader.get_summary()  # finalised: summary and footer are there
        topics = [channel.topic for _schema, channel, _message in reader.iter_messages()]
    assert summary is not None and summary.statistics.message_count == len(topics) > 0
    assert "/dronekey/annotations" in topics and "/dronekey/status" in topics
