"""``dronekey-bench pipeline`` and ``dronekey-bench soak`` on a tiny clip with the untrained test model:
the commands run the daemon with every output on and report every figure. Short runs, no speed
assertions (the figures come from the commands themselves, see docs/performance.md)."""

import json
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from daemon_media import encode_clip, write_untrained_model

from dronekey.geometry.camera import CameraModel
from dronekey.perception.heading_model import default_heading_model_path

PIPELINE_KEYS = {
    "frames",
    "fps",
    "latency_ms_p50",
    "latency_ms_p99",
    "decode_fps",
    "model_fps",
    "efficiency",
    "cpu_limit_fps",
    "efficiency_vs_cpu_limit",
    "network_limit_fps",
    "cpu_percent",
    "rss_mb",
}


@pytest.fixture(scope="module")
def assets(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("bench")
    encode_clip(folder / "clip.mp4", "libx264", frames=20)
    CameraModel.from_fov(640, 480, 60).save_yaml(folder / "camera.yaml")  # scaled to 320x240
    write_untrained_model(folder / "untrained.onnx")
    return folder


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "dronekey.bench.cli", *args], capture_output=True, text=True, timeout=120
    )


def common(assets: Path) -> list[str]:
    return [
        "--source", str(assets / "clip.mp4"), "--calib", str(assets / "camera.yaml"),
        "--model", str(assets / "untrained.onnx"),
    ]  # fmt: skip


def test_pipeline_reports_every_figure(assets):
    result = bench(
        "pipeline", *common(assets), "--frames", "30", "--latency-frames", "12", "--warmup", "4", "--json"
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert set(report) >= PIPELINE_KEYS
    assert report["frames"] == 26  # measured after the warm-up; the 20-frame clip looped
    for key in PIPELINE_KEYS:
        assert report[key] > 0, key
    assert report["efficiency"] == pytest.approx(
        report["fps"] / min(report["decode_fps"], report["model_fps"]), rel=0.01, abs=0.001
    )  # from the rounded figures
    details = report["details"]
    per_frame_ms = details["decode_cpu_ms_per_frame"] + details["pipeline_cpu_ms_per_frame"]
    assert report["cpu_limit_fps"] == pytest.approx(details["cores"] * 1000 / per_frame_ms, rel=0.02)
    efficiency = report["fps"] / report["cpu_limit_fps"]
    assert report["efficiency_vs_cpu_limit"] == pytest.approx(efficiency, rel=0.01)
    # the networks' CPU is part of the pipeline's, so their limit is the higher
    network_ms = details["network_cpu_ms_per_frame"]
    assert 0 < network_ms <= details["pipeline_cpu_ms_per_frame"]
    per_frame_ms = details["decode_cpu_ms_per_frame"] + network_ms
    assert report["network_limit_fps"] == pytest.approx(details["cores"] * 1000 / per_frame_ms, rel=0.02)
    assert report["network_limit_fps"] >= report["cpu_limit_fps"]
    assert details["resolution"] == [320, 240]
    assert set(details["paced"]["outputs"]) == {"zenoh", "mavlink", "mcap"}
    for output in details["paced"]["outputs"].values():
        assert output["published"] == 12 and output["errors"] == 0
    assert details["model_threads"] == 1 and details["decode_threads"] >= 1
    assert details["front_back"].endswith("dronekey_heading.onnx")  # the shipped classifier, by default
    slowest = details["paced"]["slowest"]  # of the 8 paced frames after the warm-up, the slowest 2 %: one
    assert (slowest["frames"], slowest["of_frames"]) == (1, 8)
    assert slowest["wait_ms_mean"] >= 0 and slowest["pipeline_ms_mean"] > 0
    assert slowest["latency_ms_mean"] == pytest.approx(
        slowest["wait_ms_mean"] + slowest["pipeline_ms_mean"], abs=0.02
    )
    assert sum(slowest["modes"].values()) == 1 and "track_crop" in slowest["stages_ms_mean"]


def test_pipeline_table(assets):
    result = bench("pipeline", *common(assets), "--frames", "10", "--latency-frames", "6", "--warmup", "2")
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert {line.split()[0] for line in lines[:-1]} == PIPELINE_KEYS
    slowest = r"slowest 2 % \(1 of 4 paced frames, [\d.]+ ms and more\): [\d.]+ ms on average = "
    assert re.match(slowest, lines[-1])


def test_pipeline_thread_overrides_reach_the_daemon(assets):
    result = bench(
        "pipeline", *common(assets), "--frames", "10", "--latency-frames", "6", "--warmup", "2",
        "--decode-threads", "2", "--model-threads", "2", "--no-front-back", "--no-mirror-average",
        "--measure-every", "2", "--json",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    details = json.loads(result.stdout)["details"]
    assert details["decode_threads"] == 2 and details["model_threads"] == 2
    assert details["front_back"] is None  # --no-front-back: the classifier's cost can be measured
    assert details["mirror_average"] is False  # and the mirror averaging's
    assert details["measure_every"] == 2  # and the measurement stride's gain


def test_pipeline_runs_another_front_back_classifier(assets):
    deep = default_heading_model_path("deep")
    result = bench(
        "pipeline", *common(assets), "--frames", "10", "--latency-frames", "6", "--warmup", "2",
        "--front-back", str(deep), "--json",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["details"]["front_back"] == str(deep)  # what another one costs


def test_soak_reports_rss_over_time(assets):
    result = bench(
        "soak", *common(assets), "--frames", "40", "--warmup", "10", "--sample-s", "0.2",
        "--max-growth", "1000", "--json",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["frames"] == 40 and report["ok"] is True
    assert report["rss_mb_start"] > 0 and report["rss_mb_end"] > 0
    growth = 100 * (report["rss_mb_end"] - report["rss_mb_start"]) / report["rss_mb_start"]
    assert report["rss_growth_percent"] == pytest.approx(growth, abs=0.05)  # from rounded MiB
    assert report["samples"] and report["samples"][-1]["frames"] == 40
    assert set(report["outputs"]) == {"zenoh", "mavlink", "mcap"}


def test_soak_over_the_growth_limit_exits_1(assets):
    result = bench("soak", *common(assets), "--frames", "12", "--warmup", "2", "--max-growth", "-100")
    assert result.returncode == 1
    assert "RSS grew" in result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--source", "absent.mp4"], "--source: no such file"),
        (["--model", "absent.onnx"], "--model: no such file"),
        (["--front-back", "absent.onnx"], "--front-back: no such file"),
        (["--frames", "5", "--warmup", "10"], "must exceed --warmup"),
    ],
)
def test_bad_input_is_one_line_and_exit_1(assets, args, message):
    result = bench("pipeline", *common(assets), *args)
    assert result.returncode == 1
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("dronekey-bench pipeline: error:")


def test_sigterm_stops_a_soak_with_the_figures_so_far(assets):
    proc = subprocess.Popen(
        [sys.executable, "-m", "dronekey.bench.cli", "soak", *common(assets), "--frames", "1000000",
         "--warmup", "5", "--sample-s", "0.5", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    progress = []  # the soak's progress bar on stderr: "soak: ... 250/1000000 ..."
    reader = threading.Thread(target=lambda: progress.extend(iter(lambda: proc.stderr.read(64), "")))
    reader.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        done = re.findall(r"(\d+)/1000000", "".join(progress))
        if done and int(done[-1]) >= 150:
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGTERM)
    out = proc.stdout.read()
    proc.wait(timeout=60)
    reader.join(10)
    err = "".join(progress)
    assert proc.returncode == 143, err[-2000:]
    report = json.loads(out)
    assert report["stopped_early"].startswith("stopped by SIGTERM") and report["frames"] >= 100
    assert report["exit_code"] == 143 and "figures up to there" in err


def test_sampler_reports_its_rate():
    result = bench("sampler", "--samples", "10", "--json")
    assert result.returncode == 0, result.stderr
    out = json.loads(result.stdout)
    assert out["samples"] == 10 and out["input"] == [128, 128]
    assert out["samples_per_s"] > 0 and out["cpu_ms_per_sample"] > 0 and 0 <= out["with_drone"] <= 1
    assert bench("sampler", "--samples", "0").returncode == 2  # argparse: one line, exit 2


def test_slowest_frames_splits_the_tail_into_waiting_and_pipeline_time():
    from dronekey.daemon.bench.slowest_frames import FrameTiming, slowest_frames, slowest_line

    fast = [FrameTiming(2.0, 10.0, "track", {"track_crop": 9.0, "track": 1.0, "total": 10.0})] * 98
    stages = {"track_crop": 12.0, "acquire": 30.0, "track": 3.0, "total": 45.0}
    search = FrameTiming(5.0, 45.0, "track", stages)
    backlog = FrameTiming(70.0, 12.0, "track", {"track_crop": 11.0, "track": 1.0, "total": 12.0})
    got = slowest_frames([*fast[:40], backlog, *fast[40:], search])
    assert (got["frames"], got["of_frames"], got["share"]) == (2, 100, 0.02)
    assert got["latency_ms_min"] == 50.0 and got["latency_ms_mean"] == 66.0  # (82 + 50) / 2
    assert (got["wait_ms_mean"], got["pipeline_ms_mean"]) == (37.5, 28.5)
    assert got["searched"] == 1 and got["modes"] == {"track": 2}
    assert got["stages_ms_mean"] == {"acquire": 15.0, "track": 2.0, "track_crop": 11.5}  # no search: 0 ms
    assert slowest_line(got).startswith("slowest 2 % (2 of 100 paced frames, 50.0 ms and more): 66.0 ms")
    assert slowest_frames([]) == {"frames": 0}
    assert slowest_line({"frames": 0}) == "slowest frames: none measured"
    assert slowest_frames(fast[:3], share=0.02)["frames"] == 1  # at least one
    with pytest.raises(ValueError, match="share must be in \\(0, 1\\], got 0"):
        slowest_frames(fast, share=0)
