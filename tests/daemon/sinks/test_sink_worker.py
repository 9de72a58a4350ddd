"""The sink worker's close: what is queued is published or counted, and nothing reaches a closed sink."""

from __future__ import annotations

import logging
import threading
import time

from dronekey.daemon.sinks.base import FrameUpdate, Sink, SinkWorker


class _RecordingSink(Sink):
    """Takes ``call_s`` per update and records every call and the close, in order."""

    name = "recording"

    def __init__(self, call_s: float) -> None:
        self.call_s = call_s
        self.events: list[str] = []
        self.in_call = False
        self.closed_during_a_call = False
        self._lock = threading.Lock()

    def handle_update(self, update: FrameUpdate) -> None:
        with self._lock:
            self.in_call = True
            self.events.append(f"update {update.frame_index}")
        time.sleep(self.call_s)
        with self._lock:
            self.in_call = False

    def close(self) -> None:
        with self._lock:
            self.closed_during_a_call = self.in_call
            self.events.append("close")


def _submit(worker: SinkWorker, count: int) -> None:
    for i in range(count):
        worker.submit_update(FrameUpdate("cam0", i, i * 33_000_000, time.monotonic_ns()))


def test_a_sink_that_keeps_up_publishes_everything_queued_before_it_closes():
    sink = _RecordingSink(call_s=0.001)
    worker = SinkWorker(sink, max_queue=64)
    _submit(worker, 20)
    worker.close(timeout_s=3.0)
    assert sink.events == [f"update {i}" for i in range(20)] + ["close"]
    assert (worker.stats.published, worker.stats.dropped) == (20, 0)


def test_a_sink_that_cannot_drain_in_time_drops_the_rest_counted_and_is_closed_after_its_call(caplog):
    sink = _RecordingSink(call_s=0.2)
    worker = SinkWorker(sink, max_queue=64)
    _submit(worker, 20)
    with caplog.at_level(logging.WARNING, logger="dronekey.daemon.sinks.base"):
        worker.close(timeout_s=0.3, grace_s=1.0)
    time.sleep(0.5)  # a worker that went on calling the sink would record it by now
    assert sink.events[-1] == "close", sink.events
    assert not sink.closed_during_a_call
    published = sum(event.startswith("update") for event in sink.events)
    assert published == worker.stats.published < 20
    assert worker.stats.published + worker.stats.dropped == 20  # nothing lost silently
    assert f"dropped the {worker.stats.dropped} messages still queued" in caplog.text
    assert not worker._thread.is_alive()
