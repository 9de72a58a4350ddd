"""One daemon run for a benchmark: local output endpoints, the daemon's signal handling, its runner."""

from __future__ import annotations

import contextlib
import socket
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from dronekey.daemon.app import DaemonApp
from dronekey.daemon.bench.errors import BenchError, BenchInterruptedError
from dronekey.daemon.bench.meter import Meter
from dronekey.daemon.config.daemon_config import DaemonConfig
from dronekey.daemon.errors import DaemonError, ExitCode
from dronekey.daemon.signals import SignalMonitor
from dronekey.daemon.systemd import SystemdNotifier

__all__ = ["check_signals", "local_endpoints", "run_daemon", "signal_monitor"]


class _UdpDrain:
    """A UDP socket on 127.0.0.1 standing in for a ground station: reads and discards datagrams."""

    def __init__(self) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.settimeout(0.2)
        self.port = self._sock.getsockname()[1]
        self.datagrams = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-udp-drain", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._sock.recv(65536)
                self.datagrams += 1
            except TimeoutError:
                continue
            except OSError:
                return

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self._sock.close()


@contextlib.contextmanager
def local_endpoints() -> Iterator[tuple[Path, int]]:
    """A temporary MCAP folder and a drained local UDP port, for one daemon run."""
    drain = _UdpDrain()
    try:
        with tempfile.TemporaryDirectory(prefix="dronekey-bench-mcap-") as tmp:
            yield Path(tmp), drain.port
    finally:
        drain.close()


def signal_monitor(install: bool = False) -> SignalMonitor:
    """The daemon's SIGINT / SIGTERM handling for a whole command (installed from the main thread)."""
    signals = SignalMonitor(deadline_s=30.0)
    if install:
        signals.install()
    return signals


def check_signals(signals: SignalMonitor, frames: int) -> None:
    """Raise ``BenchInterruptedError`` once ``signals`` saw SIGINT or SIGTERM (``frames`` done so far)."""
    if signals.exit_code is not None:
        name = signals.exit_code.name
        raise BenchInterruptedError(f"stopped by {name} after {frames} frames", int(signals.exit_code))


def run_daemon(config: DaemonConfig, meter: Meter, signals: SignalMonitor) -> DaemonApp:
    """Run ``DaemonApp`` to its end with ``meter`` as the pipeline; returns the app (for its outputs).

    A signal seen by ``signals`` (``SignalMonitor``) stops it the daemon's way (outputs closed) and
    raises ``BenchInterruptedError``; a meter whose time ran out (``Meter.out_of_time``) stops it the
    same way, without a signal, and that is a normal end.
    """
    app = DaemonApp(
        config, signals=signals, notifier=SystemdNotifier(environ={}), pipeline_factory=meter.factory
    )
    meter.app = app
    try:
        code = app.run()
    except DaemonError as exc:
        raise BenchError(str(exc)) from None
    finally:
        meter.close()
    check_signals(signals, meter.frames)
    if code != ExitCode.OK and not meter.out_of_time:  # a timed run stops through the stop event
        raise BenchError(
            f"the daemon stopped with exit code {int(code)} ({code.name}) after {meter.frames} frames"
        )
    return app
