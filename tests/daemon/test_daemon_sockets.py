"""Secure by default: a daemon on its defaults opens no socket beyond this machine.

``dronekey-daemon`` runs as a real process with every output on its default (Zenoh, MAVLink, MCAP)
plus SBS-1 given only a port; ``psutil`` lists its sockets as ``ss -lntup`` would, and every
listening TCP socket and every UDP socket must be bound to 127.0.0.0/8 or ::1.
"""

from __future__ import annotations

import ipaddress
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from daemon_media import daemon_assets
from test_daemon_service import NotifySocket, daemon_env


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    return daemon_assets(tmp_path_factory.mktemp("assets"), 320, 240)


def open_to_the_network(proc: psutil.Process) -> set[str]:
    """The process's listening TCP and bound UDP sockets whose address is not loopback."""
    exposed = set()
    for conn in proc.net_connections(kind="inet"):
        listening = conn.type == socket.SOCK_STREAM and conn.status == psutil.CONN_LISTEN
        if not (listening or conn.type == socket.SOCK_DGRAM) or not conn.laddr:
            continue
        ip = ipaddress.ip_address(conn.laddr.ip.split("%")[0])
        ip = ip.ipv4_mapped or ip if isinstance(ip, ipaddress.IPv6Address) else ip
        if not ip.is_loopback:
            kind = "tcp listen" if listening else "udp"
            exposed.add(f"{kind} {conn.laddr.ip}:{conn.laddr.port}")
    return exposed


def listening_ports(proc: psutil.Process) -> set[int]:
    return {
        c.laddr.port
        for c in proc.net_connections(kind="inet")
        if c.type == socket.SOCK_STREAM and c.status == psutil.CONN_LISTEN
    }


def test_daemon_on_its_defaults_listens_on_loopback_only(tmp_path, assets):
    notify = NotifySocket(tmp_path / "notify.sock")
    args = [
        sys.executable, "-m", "dronekey.daemon.cli", "--source", str(assets / "clip.mp4"),
        "--realtime", "--loop", "--model", str(assets / "untrained.onnx"),
        "--calib", str(assets / "camera.yaml"), "--mcap-dir", str(tmp_path / "mcap"),
        "--camera-geo", "47.3977,8.5456,488.0,30,5,0", "--sbs1-listen", "0",  # a port, no host
    ]  # fmt: skip
    daemon = subprocess.Popen(
        args, env=daemon_env(NOTIFY_SOCKET=str(notify.path)), stderr=subprocess.PIPE, text=True
    )
    try:
        notify.wait_for("READY=1", 60)  # the first frame went through: every output is up
        proc = psutil.Process(daemon.pid)
        exposed, ports = set(), set()
        deadline = time.monotonic() + 3.0  # sockets opened a little later (scouting, first send)
        while time.monotonic() < deadline:
            exposed |= open_to_the_network(proc)
            ports |= listening_ports(proc)
            time.sleep(0.2)
        daemon.send_signal(signal.SIGTERM)
        daemon.wait(timeout=10)
        stderr = daemon.stderr.read()
    finally:
        if daemon.poll() is None:
            daemon.kill()
        notify.close()
    sbs1 = re.search(r"SBS-1 output listening on 127\.0\.0\.1:(\d+) \(this machine only\)", stderr)
    assert sbs1 and int(sbs1[1]) in ports, stderr  # SBS-1 with a port only: there, on loopback
    assert not exposed, f"sockets open to the network: {sorted(exposed)}"
