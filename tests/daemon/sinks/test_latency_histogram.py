"""The whole run's latency histogram: percentiles as numpy gives them, a window after a snapshot, and a
real sink worker filling it."""

import math
import time

import numpy as np
import pytest

from dronekey.daemon.sinks.base import FrameUpdate, Sink, SinkWorker
from dronekey.daemon.sinks.latency_histogram import LatencyHistogram


def test_percentiles_match_numpy_within_the_bin_width():
    rng = np.random.default_rng(3)
    values = np.concatenate([rng.lognormal(np.log(40.0), 0.5, 20_000), [0.0, 0.004, 2e6, 350.0]])
    hist = LatencyHistogram()
    for v in values:
        hist.add(float(v))
    assert hist.count == values.size
    for q in (50, 90, 99, 99.9):
        exact = float(np.percentile(values, q, method="higher"))
        assert hist.percentile(q) == pytest.approx(exact, rel=2e-3), q


def test_since_leaves_out_what_came_before_the_snapshot():
    hist = LatencyHistogram()
    for _ in range(1000):
        hist.add(500.0)  # a slow warm-up
    start = hist.copy()
    for v in np.linspace(10.0, 20.0, 101):
        hist.add(float(v))
    window = hist.since(start)
    assert window.count == 101
    assert window.percentile(99) == pytest.approx(19.9, rel=2e-3)
    assert hist.percentile(50) == pytest.approx(500.0, rel=2e-3)  # the snapshot did not reset it
    with pytest.raises(ValueError, match="copy of this histogram"):
        start.since(hist)


def test_empty_nan_and_bad_q():
    hist = LatencyHistogram()
    assert math.isnan(hist.percentile(99))
    hist.add(float("nan"))
    assert hist.count == 0
    with pytest.raises(ValueError, match="q must be within 0-100, got 101"):
        hist.percentile(101)


class _Slow(Sink):
    name = "slow"

    def handle_update(self, update: FrameUpdate) -> None:
        time.sleep(0.0002)

    def close(self) -> None:
        pass


def test_a_sink_worker_counts_every_update_past_its_recent_window():
    worker = SinkWorker(_Slow(), max_queue=4096)
    try:
        t0 = time.monotonic_ns()
        for i in range(2100):
            worker.submit_update(FrameUpdate(camera_id="cam0", frame_index=i, t_ns=i, t_arrival_mono_ns=t0))
    finally:
        worker.close(timeout_s=30.0)
    stats = worker.stats
    assert stats.published == 2100
    assert len(stats.latencies_ms) == 2048  # the status messages' recent window
    assert stats.latency_histogram.count == 2100  # every one
    assert stats.latency_histogram.percentile(99) >= float(np.percentile(stats.latencies_ms, 50))
