"""``dronekey-bench cameras`` on a tiny clip with the untrained test model: two paced daemon processes
with every output on, their per-camera figures, the totals and the CPU-bound limit. A few seconds of
run time, no speed assertions (the figures come from the command itself, on an idle box)."""

import json
import subprocess
import sys

import pytest
from test_bench import assets as assets  # the same clip, calibration and model (a fixture)
from test_bench import common

CAMERA_KEYS = {
    "camera", "frames", "fps", "clip_fps", "dropped", "latency_ms_p50", "latency_ms_p99",
    "cpu_ms_per_frame", "pipeline_cpu_ms_per_frame", "rss_mb", "rss_mb_settled", "rss_growth_percent",
    "rss_trend_percent", "malloc_arenas", "outputs", "realtime_phase", "modes",
}  # fmt: skip


def cameras(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "dronekey.bench.cli", "cameras", *args],
        capture_output=True,
        text=True,
        timeout=240,
    )


def test_two_cameras_report_each_and_the_cpu_limit(assets):
    result = cameras(*common(assets), "--count", "2", "--seconds", "2", "--phase", "staggered", "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["count"] == 2 and [c["camera"] for c in report["cameras"]] == ["cam0", "cam1"]
    assert report["phase"] == "staggered" and [c["realtime_phase"] for c in report["cameras"]] == [0.0, 0.5]
    assert report["decode_ahead"] is False  # the default: decoded once due, as a camera's stream is
    assert all(c["malloc_arenas"] == 2 for c in report["cameras"])  # as dronekey-daemon caps them
    for cam in report["cameras"]:
        assert set(cam) == CAMERA_KEYS
        assert 0 < cam["frames"] <= 60 and cam["clip_fps"] == pytest.approx(30)  # 2 s at 30 fps at most
        assert cam["frames"] == 60 or cam["dropped"] > 0  # a camera behind its clip stops at 2 s
        # No bound on fps: the 2 s window runs between two publish times, and a camera that fell behind
        # in its warm-up catches up at its start (31.2 FPS seen once in about 15 runs; 35.15 beside a
        # robustness run, on a 30 FPS clip). Pacing is the sources' tests'.
        assert cam["fps"] > 0 and cam["dropped"] >= 0
        assert 0 < cam["latency_ms_p50"] <= cam["latency_ms_p99"]
        assert set(cam["outputs"]) == {"zenoh", "mavlink", "mcap"}  # every output on, each one's own
        assert cam["latency_ms_p99"] == max(o["latency_ms_p99"] for o in cam["outputs"].values())
        assert 0 < cam["pipeline_cpu_ms_per_frame"] < cam["cpu_ms_per_frame"]
    assert report["fps_total"] == pytest.approx(sum(c["fps"] for c in report["cameras"]), abs=0.02)
    per_frame_ms = report["decode_cpu_ms_per_frame"] + report["pipeline_cpu_ms_per_frame"]
    assert report["cpu_limit_fps"] == pytest.approx(report["cores"] * 1000 / per_frame_ms, rel=0.02)
    assert report["rss_mb"] == pytest.approx(sum(c["rss_mb"] for c in report["cameras"]), abs=0.2)
    for cam in report["cameras"]:  # a 2 s run counts its growth from the end of the warm-up
        growth = 100 * (cam["rss_mb"] - cam["rss_mb_settled"]) / cam["rss_mb_settled"]
        # recomputed from the two sizes as printed (0.1 MiB): within 0.05 % at a few hundred MiB
        assert cam["rss_mb_settled"] > 0 and cam["rss_growth_percent"] == pytest.approx(growth, abs=0.05)
    assert report["rss_growth_percent_worst"] == max(c["rss_growth_percent"] for c in report["cameras"])
    trends = [c["rss_trend_percent"] for c in report["cameras"] if c["rss_trend_percent"] is not None]
    assert report["rss_trend_percent_worst"] == max(trends, default=None)  # null (no NaN) when none


def test_table_and_bad_input(assets, tmp_path):
    result = cameras(*common(assets), "--count", "1", "--seconds", "1", "--decode-ahead")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].split()[:3] == ["camera", "fps", "dropped"] and lines[1].startswith("cam0")
    assert any(line.startswith("cpu_limit_fps") for line in lines)
    assert "phase                     aligned" in lines  # the default: every camera at the same instant
    assert "decode_ahead              True" in lines
    bad = cameras("--source", str(tmp_path / "absent.mp4"), "--count", "0")
    assert bad.returncode == 2 and "--count" in bad.stderr
    bad = cameras("--source", str(tmp_path / "absent.mp4"), "--phase", "random")
    assert bad.returncode == 2 and "--phase" in bad.stderr
    missing = cameras("--source", str(tmp_path / "absent.mp4"))
    assert missing.returncode == 1
    expected = f"dronekey-bench cameras: error: --source: no such file: {tmp_path / 'absent.mp4'}"
    assert missing.stderr.strip() == expected


def test_decode_ahead_goes_through_the_bench_setups_overrides(assets):
    from dronekey.daemon.bench.bench_setup import BenchSetup

    setup = BenchSetup(assets / "clip.mp4")
    assert setup.config(10, realtime=True).source.realtime_decode_ahead is False
    ahead = BenchSetup(assets / "clip.mp4", decode_ahead=True).config(10, realtime=True)
    assert ahead.source.realtime_decode_ahead is True


def test_camera_phases_aligned_staggered_and_free():
    from dronekey.daemon.bench import cameras as bench_cameras

    assert bench_cameras.camera_phases("aligned", 3) == [0.0, 0.0, 0.0]
    assert bench_cameras.camera_phases("staggered", 4) == [0.0, 0.25, 0.5, 0.75]
    assert bench_cameras.camera_phases("free", 2) == [None, None]
    with pytest.raises(ValueError, match="phase must be one of aligned, staggered, free, got 'random'"):
        bench_cameras.camera_phases("random", 2)


def test_a_worker_that_logs_more_than_a_pipe_holds_does_not_stall_the_run(assets, monkeypatch):
    """Workers' output goes to files, not pipes nobody reads while they run: a worker that wrote
    more than 64 KiB of log lines used to block until the run's deadline (a 5-minute run)."""
    from pathlib import Path

    from dronekey.daemon.bench import cameras as bench_cameras
    from dronekey.daemon.bench.bench_setup import BenchSetup
    from dronekey.daemon.signals import SignalMonitor

    report = {key: 1.0 for key in CAMERA_KEYS}
    noisy = (
        "import sys, json; sys.stderr.write('a daemon warning line\\n' * 20000); "
        f"print(json.dumps({report!r}))"
    )
    monkeypatch.setattr(bench_cameras, "_worker_command", lambda *args: [sys.executable, "-c", noisy])
    setup = BenchSetup(Path(assets / "clip.mp4"), assets / "camera.yaml", assets / "untrained.onnx")
    result = bench_cameras.run_cameras_bench(setup, count=2, seconds=1.0, signals=SignalMonitor())
    assert [c["fps"] for c in result["cameras"]] == [1.0, 1.0]


def test_a_camera_that_falls_behind_stops_at_the_run_time():
    """The meter ends a camera's window at its seconds when its frames have not all come (a camera
    slower than its clip), and asks the daemon to stop; a camera that keeps up ends on its frames."""
    import threading
    import time
    from types import SimpleNamespace

    from dronekey.daemon.bench.meter import Meter

    class SlowPipeline:
        def process(self, frame, late=False):
            time.sleep(0.01)
            return SimpleNamespace(mode="track")

    stop = threading.Event()
    meter = Meter(1000, 2, "slow", rss=True, settle=2, seconds=0.1, stop=stop)
    meter.pipeline = SlowPipeline()
    while not stop.is_set() and meter.frames < 1000:
        meter.process(None)
    meter.close()
    frames, wall_s, _ = meter.window()
    assert meter.out_of_time and stop.is_set() and 2 < meter.frames < 1000
    assert frames == meter.frames - 2 and 0.1 <= wall_s < 0.5
    quick = Meter(5, 2, "quick", seconds=60.0, stop=threading.Event())
    quick.pipeline = SlowPipeline()
    for _ in range(5):
        quick.process(None)
    quick.close()
    assert quick.window()[0] == 3 and not quick.out_of_time


def test_the_memory_trend_is_the_fitted_line_not_two_samples():
    """``trend_percent`` fits RSS against time: a swing at the last sample moves two-sample growth a
    lot and the fitted rise a little; a steady climb is read in full. The meter keeps the stamps of
    every 100th frame from the settle frame to the end, none after it."""
    import threading
    from types import SimpleNamespace

    from dronekey.daemon.bench.meter import Meter, Stamp, growth_percent, trend_percent

    flat = [Stamp(100 * k, float(k), 0.0, 500.0) for k in range(20)]
    swung = [*flat[:-1], Stamp(1900, 19.0, 0.0, 512.5)]  # +2.5 % at the end only
    climbing = [Stamp(100 * k, float(k), 0.0, 500.0 + k) for k in range(20)]
    assert growth_percent(swung[0].rss_mb, swung[-1].rss_mb) == 2.5
    assert 0 < trend_percent(swung) < 0.8
    assert trend_percent(flat) == 0.0
    assert trend_percent(climbing) == pytest.approx(100 * 19 / 500, abs=0.01)
    assert trend_percent(flat[:2]) != trend_percent(flat[:2])  # NaN: two stamps fit no trend

    class Pipeline:
        def process(self, frame, late=False):
            return SimpleNamespace(mode="track")

    meter = Meter(1000, 50, "trend", rss=True, settle=250, stop=threading.Event())
    meter.pipeline = Pipeline()
    for _ in range(1200):  # the daemon may hand over frames after the end
        meter.process(None)
    meter.close()
    assert [s.frames for s in meter.rss_stamps] == [250, 300, 400, 500, 600, 700, 800, 900, 1000]
