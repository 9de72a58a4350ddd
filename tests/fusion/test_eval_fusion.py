"""``dronekey-eval fusion`` on a small two-camera render, and its usage errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from site_files import render_cameras

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
    assert report["methods"]["fused"]["frames"] > 0
    table = _eval(str(tmp_path), "--frames", "4").stdout
    assert "fused RMSE / better camera's" in table and table.count("|") > 20


def test_fusion_eval_names_a_folder_without_a_site_file(tmp_path):
    result = _eval(str(tmp_path))
    assert result.returncode == 2 and "site.json" in result.stderr and "Traceback" not in result.stderr
    result = _eval(str(tmp_path / "absent"))
    assert result.returncode == 2 and "absent" in result.stderr
