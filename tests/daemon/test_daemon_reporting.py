"""dronekey-daemon says when an output fails: a real daemon whose MCAP cannot be written (a disk
that refuses every write) keeps tracking, its status lines and its totals name the failure and
count the frames not recorded, and it leaves no empty .mcap file behind.

The full disk is RLIMIT_FSIZE 0 with SIGXFSZ ignored: every write to a file fails (EFBIG), for this
process only; ``mcap.min_free_mb: 0`` so the free-space check does not stop the attempts first.
"""

from __future__ import annotations

import resource
import signal
import subprocess
from pathlib import Path

import pytest
from daemon_media import daemon_assets
from test_daemon_service import daemon_args, daemon_env

from dronekey.daemon.errors import ExitCode


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    return daemon_assets(tmp_path_factory.mktemp("assets"))


def _full_disk() -> None:
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # inherited through exec: writes fail instead
    resource.setrlimit(resource.RLIMIT_FSIZE, (0, resource.RLIM_INFINITY))


def test_a_failing_mcap_is_named_in_the_status_and_the_totals(tmp_path, assets):
    config = tmp_path / "config.yaml"
    config.write_text(
        "source: {max_frames: 45}\nmcap: {min_free_mb: 0}\nlog: {journal_status_interval_s: 0.3}\n"
    )
    mcap_dir = tmp_path / "mcap"
    args = daemon_args(
        assets,
        str(assets / "clip.mp4"),
        "--realtime",
        "--loop",
        "--mcap-dir",
        str(mcap_dir),
        "--config",
        str(config),
    )
    result = subprocess.run(
        args, env=daemon_env(), capture_output=True, text=True, timeout=60, preexec_fn=_full_disk
    )
    assert result.returncode == ExitCode.OK, result.stderr
    lines = result.stderr.splitlines()
    totals = next(line for line in lines if "totals:" in line)
    assert "45 frames processed" in totals
    assert "mcap 45 published 0 dropped" in totals and "45 not recorded" in totals, totals
    assert "FAILING: not recording: " in totals and "File too large" in totals, totals
    statuses = [line for line in lines if "status:" in line]  # the journal's status lines
    failing = [line for line in statuses if "not recorded, FAILING: not recording: File too large" in line]
    assert failing and failing[-1] == statuses[-1], statuses  # from the first attempt on
    assert list(mcap_dir.iterdir()) == []  # no 0-byte file from the attempt
