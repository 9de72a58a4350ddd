"""``dronekey-eval fusion`` on a small two-camera render, and its usage errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from site_files import render_cameras

from dronekey.evaluation.fusion import _Scores, fused_over_camera_on_its_frames

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


def test_the_ratio_on_a_cameras_own_frames_compares_both_on_the_frames_both_matched():
    camera, fused = _Scores.empty(), _Scores.empty()
    camera.sq_errors = {(0, 0): 49.0, (1, 0): 49.0, (2, 0): 100.0}  # frame 2: the fused tracks had none
    fused.sq_errors = {(0, 0): 16.0, (1, 0): 16.0, (3, 0): 400.0}  # frame 3: only the other camera
    assert fused_over_camera_on_its_frames(camera, fused) == (4.0, round(4.0 / 7.0, 4))
    assert fused_over_camera_on_its_frames(_Scores.empty(), fused) == (None, None)


def test_fusion_eval_names_a_folder_without_a_site_file(tmp_path):
    result = _eval(str(tmp_path))
    assert result.returncode == 2 and "site.json" in result.stderr and "Traceback" not in result.stderr
    result = _eval(str(tmp_path / "absent"))
    assert result.returncode == 2 and "absent" in result.stderr
