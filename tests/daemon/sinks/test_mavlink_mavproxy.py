"""A real MAVProxy (the ``test`` extra installs it) against the MAVLink sink on UDP 127.0.0.1.

MAVProxy runs headless (``--non-interactive``) with DroneKey's dialect through ``MDEF``, aimed at
our system and component (the sensor sends no autopilot heartbeat for it to pick them from). It must
print the sink's ADSB_VEHICLE and TARGET_* messages (``watch``), finish its parameter fetch (FTP
first, NAKed, then PARAM_REQUEST_LIST) without asking again, and count the track as a threat
(``adsb status``).
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from factories import make_track
from test_mavlink_answers import CAMERA, MODEL, PARAM_NAMES
from test_mavlink_sink import GEO, update

from dronekey.daemon.sinks.mavlink.dialect import write_message_definitions

SYSID, COMPID = 42, 191
MAVPROXY = Path(sys.executable).with_name("mavproxy.py")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Output:
    """MAVProxy's stdout, read line by line on a thread."""

    def __init__(self, process: subprocess.Popen) -> None:
        self.lines: list[str] = []
        self._thread = threading.Thread(target=self._read, args=(process.stdout,), daemon=True)
        self._thread.start()

    def _read(self, stream) -> None:
        for line in stream:
            self.lines.append(line.rstrip("\n"))

    def has(self, pattern: str) -> bool:
        return any(re.search(pattern, line) for line in list(self.lines))


@pytest.fixture
def mavproxy_dialect(tmp_path):
    """``(MDEF folder, dialect name)``; removes the module pymavlink generates into its own folder."""
    import pymavlink

    name = write_message_definitions(tmp_path / "mdef")
    generated = Path(pymavlink.__file__).parent / "dialects" / "v20" / f"{name}.py"
    existed = generated.exists()
    yield tmp_path / "mdef", name
    if not existed:
        generated.unlink(missing_ok=True)


def test_mavproxy_sees_targets_gets_parameters_and_counts_a_threat(make_sink, mavproxy_dialect, tmp_path):
    assert MAVPROXY.is_file(), f"{MAVPROXY} missing: pip install -e '.[test]' installs MAVProxy"
    mdef, dialect_name = mavproxy_dialect
    port = free_udp_port()
    command = [
        sys.executable,
        str(MAVPROXY),
        f"--master=udpin:127.0.0.1:{port}",
        f"--target-system={SYSID}",
        f"--target-component={COMPID}",
        f"--dialect={dialect_name}",
        "--non-interactive",
        "--no-state",
        "--nowait",
        "--cmd=watch ADSB_VEHICLE TARGET_RELATIVE TARGET_ABSOLUTE; repeat add 1 adsb status",
    ]
    env = dict(os.environ, MDEF=str(mdef), HOME=str(tmp_path), PYTHONUNBUFFERED="1")
    started = time.monotonic()
    process = subprocess.Popen(
        command, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        out = Output(process)
        sink = make_sink(
            f"udpout:127.0.0.1:{port}", camera_geo=GEO, camera_id="cam0", camera=CAMERA, model_info=MODEL
        )
        sink.set_healthy(True)
        wanted = {
            "vehicle": rf"Detected vehicle {SYSID}:{COMPID}",
            "ADSB_VEHICLE": r"^< ADSB_VEHICLE \{ICAO_address : 7, .*callsign : DK000007, emitter_type : 14,",
            "TARGET_RELATIVE": r"^< TARGET_RELATIVE \{timestamp : \d+, id : 7, frame : 1,",
            "TARGET_ABSOLUTE": r"^< TARGET_ABSOLUTE \{timestamp : \d+, id : 7, ",
            "parameters": rf"^Received {len(PARAM_NAMES)} parameters",
            "threat": r"^total threat count: 1 ",
        }
        deadline = time.monotonic() + 30.0
        index = 0
        while time.monotonic() < deadline and not all(out.has(p) for p in wanted.values()):
            sink.handle_update(update(make_track(), index=index))
            index += 1
            time.sleep(0.1)
        missing = [name for name, pattern in wanted.items() if not out.has(pattern)]
        assert not missing, f"MAVProxy did not print {missing}:\n" + "\n".join(out.lines[-40:])

        time.sleep(2.5)  # MAVProxy re-requests missing parameters every second or two
        sent = sink.health()["sent"]
        assert sent["PARAM_VALUE"] == len(PARAM_NAMES), "MAVProxy asked for the parameters again"
        assert sent.get("FILE_TRANSFER_PROTOCOL", 0) >= 1  # its FTP parameter download was NAKed first
        assert sent.get("HOME_POSITION", 0) >= 1  # it asks with MAV_CMD_GET_HOME_POSITION
        assert time.monotonic() - started < 20.0
    finally:
        process.terminate()
        try:
            process.wait(10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
