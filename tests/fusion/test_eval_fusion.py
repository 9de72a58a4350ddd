"""``dronekey-eval fusion`` on a small two-camera render, and its usage errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from site_files import render_cameras

from dronekey.evaluation.fusion import FUSED, FusionResult

BIN = Path(sys.executable).parent


def _eval(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [BIN / "dronekey-eval", "fusion", *args], capture_output=True, text=True, timeout=300
    )


def test_fusion_eval_reports_each_camera_and_the_fused_tracks(tmp_path):
    render_cameras(tmp_path, 12)
    result = _eval(str(tmp_path), "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert set(report["methods"]) == {"cam0", "cam1", "fused"} and report["frames"] == 12
    for method in report["methods"].values():
        assert method["truths"] == 12
        assert {"rmse_m", "mae_abs_m", "mae_angle_deg", "mota", "idf1", "id_switches"} <= set(method)
    fused = report["methods"]["fused"]
    assert fused["frames"] > 0 and fused["fused_rmse_on_its_frames_m"] == fused["rmse_m"]
    for camera in ("cam0", "cam1"):  # the fused tracks over the frames this camera matched
        there = report["methods"][camera]["fused_rmse_on_its_frames_m"]
        assert there is None if report["methods"][camera]["frames"] == 0 else there >= 0
    assert "fused_rmse_over_better_camera_on_its_frames" in report
    table = _eval(str(tmp_path), "--frames", "4").stdout
    assert "fused RMSE / better camera's" in table and "on that camera's own frames" in table
    assert "fused there" in table and table.count("|") > 20


def test_the_ratio_on_the_better_cameras_own_frames_divides_the_fused_rmse_there_by_its_own():
    def method(rmse, there):
        return {"rmse_m": rmse, "fused_rmse_on_its_frames_m": there}

    # camera b is the better one (7 m); the fused tracks cover a's worse frames too (15 m overall)
    methods = {"a": method(21.0, 16.0), "b": method(7.0, 5.6), FUSED: method(15.0, 15.0)}
    result = FusionResult("dir", "far", 90, 2.0, methods, 0.36)
    assert result.fused_over_better == round(15.0 / 7.0, 4)
    assert result.fused_over_better_on_its_frames == 0.8
    assert (
        FusionResult(
            "dir", "far", 90, 2.0, {"a": method(None, None), FUSED: method(None, None)}, None
        ).fused_over_better_on_its_frames
        is None
    )


def test_fusion_eval_names_a_folder_without_a_site_file(tmp_path):
    result = _eval(str(tmp_path))
    assert result.returncode == 2 and "site.json" in result.stderr and "Traceback" not in result.stderr
    result = _eval(str(tmp_path / "absent"))
    assert result.returncode == 2 and "absent" in result.stderr
