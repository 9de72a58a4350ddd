"""A fleet deployed as docs/fleet.md says: a Zenoh router, two ``dronekey-daemon`` cameras on two
rendered videos of one flight, and ``dronekey-fuse``, all clients of the router over 127.0.0.1.
The fused tracks arrive, both cameras contribute, and they are where the drone was."""

from __future__ import annotations

import json
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from daemon_media import free_port
from json_checks import schema_errors
from site_files import render_cameras

from dronekey.daemon import messages
from dronekey.daemon.errors import ExitCode

BIN = Path(sys.executable).parent
FRAMES = 24  # 0.8 s of flight, looped by the daemons


@pytest.fixture(scope="module")
def two_cameras(tmp_path_factory) -> Path:
    """``dronekey-sim --cameras 2 --preset seq13``: cam0/, cam1/ and site.json."""
    return render_cameras(tmp_path_factory.mktemp("fleet"), FRAMES)


def _router(port: int) -> zenoh.Session:
    """A router-mode session on 127.0.0.1 only (what zenohd is in production)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    return zenoh.open(config)


@pytest.mark.slow
def test_two_daemons_and_the_fuser_through_a_router(two_cameras):
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = _router(port)
    fused: list[dict] = []
    subscriber = router.declare_subscriber(
        "dronekey/fused/tracks", lambda sample: fused.append(json.loads(sample.payload.to_bytes()))
    )
    client = ["--zenoh-mode", "client", "--zenoh-connect", endpoint]
    sbs1_port = free_port()
    processes = [
        subprocess.Popen(
            [
                BIN / "dronekey-fuse",
                *client,
                "--cameras",
                "cam0,cam1",
                "--clock",
                "trust",
                "--max-age-s",
                "2",
                "--origin",
                "47.397742,8.545594,488",
                "--sbs1-listen",
                str(sbs1_port),
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
    ]
    for camera_id in ("cam0", "cam1"):
        source = str(two_cameras / camera_id / "seq13.mp4")
        site = str(two_cameras / "site.json")
        command = [BIN / "dronekey-daemon", "--source", source, "--camera-id", camera_id]
        command += ["--camera-extrinsics", site, *client, "--realtime", "--loop", "--no-mavlink", "--no-mcap"]
        processes.append(
            subprocess.Popen(
                command,
                stderr=subprocess.DEVNULL,
            )
        )
    sbs1_lines = ""
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any(len(m["cameras"]) == 2 for m in fused):
            time.sleep(0.1)
            assert all(p.poll() is None for p in processes), "a process of the fleet exited early"
        with socket.create_connection(("127.0.0.1", sbs1_port), timeout=5.0) as air_picture:
            while "MSG,3," not in sbs1_lines and time.monotonic() < deadline + 10:
                sbs1_lines += air_picture.recv(65536).decode("ascii")
    finally:
        for p in processes:
            p.send_signal(signal.SIGTERM)
        codes = [p.wait(timeout=15) for p in processes]
        _, fuser_log = processes[0].communicate()
        subscriber.undeclare()
        router.close()
    both = [m for m in fused if len(m["cameras"]) == 2]
    assert both, f"no fused track with both cameras in {len(fused)} messages; fuser log:\n{fuser_log}"
    assert codes[0] == ExitCode.SIGTERM, fuser_log
    schema = messages.load_schema("fused_track")
    for message in fused:
        assert schema_errors(message, schema) == []
    last = both[-1]
    assert last["method"] == "triangulated" and {c["camera_id"] for c in last["cameras"]} == {"cam0", "cam1"}
    assert last["frame"]["origin"] == {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0}
    # near the site: the drone flies some metres from the cameras (accuracy: dronekey-eval fusion)
    assert np.linalg.norm(last["position_m"]) < 30.0
    assert abs(last["lat"] - 47.397742) < 3e-4 and abs(last["lon"] - 8.545594) < 4e-4
    assert "camera cam0 placed (from its extrinsics)" in fuser_log
    # the same fused drone on the fuser's SBS-1 output (lat, lon: fields 15 and 16 of MSG,3)
    position = next(line for line in sbs1_lines.split("\r\n") if line.startswith("MSG,3,")).split(",")
    assert abs(float(position[14]) - 47.397742) < 3e-4 and abs(float(position[15]) - 8.545594) < 4e-4


def test_fuse_usage_errors_are_one_line():
    result = subprocess.run(
        [BIN / "dronekey-fuse", "--zenoh-mode", "client"], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == ExitCode.USAGE and "--zenoh-connect" in result.stderr
    assert "Traceback" not in result.stderr
    result = subprocess.run(
        [BIN / "dronekey-fuse", "--origin", "95,0,0"], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == ExitCode.USAGE and "--origin '95,0,0'" in result.stderr
    result = subprocess.run(
        [BIN / "dronekey-fuse", "--zenoh-connect", "localhost:7447"],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert result.returncode == ExitCode.USAGE and "--zenoh-connect" in result.stderr
    result = subprocess.run(
        [BIN / "dronekey-fuse", "--sbs1-listen", "30004"], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == ExitCode.USAGE and "--origin LAT,LON,ALT_M" in result.stderr


def test_fuse_client_without_a_router_says_so():
    result = subprocess.run(
        [BIN / "dronekey-fuse", "--zenoh-mode", "client", "--zenoh-connect", f"tcp/127.0.0.1:{free_port()}"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 3 and "zenoh session could not be opened" in result.stderr
