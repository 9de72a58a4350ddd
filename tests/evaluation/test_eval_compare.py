"""dronekey-eval compare: two real robustness runs on the same tiny renders, side by side."""

from __future__ import annotations

import contextlib
import copy
import json

import pytest

from dronekey.evaluation.cli import main
from dronekey.evaluation.robustness.compare import compare_reports, load_report

TINY = ["--quick", "--frames", "4", "--size", "320x180", "--select", "s70??-seq13-*", "*nodrone*"]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The shipped pipeline and the deep front/back classifier on the same renders, as JSON files."""
    root = tmp_path_factory.mktemp("compare")
    paths = {}
    for name, extra in (("base", []), ("deep", ["--front-back", "deep"])):
        paths[name] = root / f"{name}.json"
        with paths[name].open("w") as out, contextlib.redirect_stdout(out):
            assert main(["robustness", "--out", str(root / "renders"), *TINY, *extra, "--json"]) == 0
    return paths


def _rows(d: dict) -> dict:
    return {(r["by"], r["value"]): r for r in d["rows"]}


def test_a_run_against_itself_moves_nothing(runs, capsys):
    assert main(["compare", "--base", str(runs["base"]), "--candidate", str(runs["base"]), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    report = load_report(runs["base"])
    drone = [s for s in report["sequences"] if not s["no_drone"]]
    assert d["sets"] == 1 and d["sequences"] == len(drone) > 0
    assert d["moved"] == [] and d["moved_better"] == d["moved_worse"] == 0
    rows = _rows(d)
    assert ("all", "drone sequences") in rows and ("drone-free", "drone-free") in rows
    for row in d["rows"]:
        for key, pair in row.items():
            if key not in ("by", "value"):
                assert pair["base"] == pair["candidate"], (row["by"], row["value"], key)


def test_one_set_pools_to_its_own_rows(runs, capsys):
    assert main(["compare", "--base", str(runs["base"]), "--candidate", str(runs["deep"]), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    own = {(g["by"], g["value"]): g for g in load_report(runs["deep"])["groups"]}
    for row, figs in _rows(d).items():
        for key in ("mae_angle_deg", "rmse_m", "detected_pct", "ap_kp", "false_track_frames"):
            want = own[row][key]
            got = figs[key]["candidate"]
            assert got == pytest.approx(want, abs=0.006) if want is not None else got is None, (row, key)


def test_sets_pool_frame_weighted(runs):
    base, deep = load_report(runs["base"]), load_report(runs["deep"])
    pooled = compare_reports([base, base], [base, deep])
    a = {(g["by"], g["value"]): g for g in base["groups"]}[("all", "drone sequences")]
    b = {(g["by"], g["value"]): g for g in deep["groups"]}[("all", "drone sequences")]
    figs = pooled.rows[("all", "drone sequences")]
    n_a, n_b = a["detected_frames"], b["detected_frames"]
    assert figs["mae_angle_deg"][1] == pytest.approx(
        (a["mae_angle_deg"] * n_a + b["mae_angle_deg"] * n_b) / (n_a + n_b)
    )
    assert figs["rmse_m"][1] == pytest.approx(
        ((a["rmse_m"] ** 2 * n_a + b["rmse_m"] ** 2 * n_b) / (n_a + n_b)) ** 0.5
    )
    assert figs["ap_kp"][1] == pytest.approx((a["ap_kp"] + b["ap_kp"]) / 2)
    assert figs["false_track_frames"][1] == a["false_track_frames"] + b["false_track_frames"]
    wrong = a["confident_wrong_heading_frames"] + b["confident_wrong_heading_frames"]
    assert figs["confident_wrong_heading_frames"] == (2 * a["confident_wrong_heading_frames"], wrong)
    assert pooled.rows[("drone-free", "drone-free")]["confident_wrong_heading_frames"] == (None, None)
    base_wrong = 2 * a["confident_wrong_heading_frames"]
    line = f"confidently wrong frames over the drone sequences: {base_wrong} -> {wrong}"
    assert line in pooled.table()
    assert pooled.sequences == 2 * sum(not s["no_drone"] for s in base["sequences"])


def test_sequences_that_moved_are_counted_and_named(runs, tmp_path, capsys):
    base = load_report(runs["base"])
    drone = [s for s in base["sequences"] if not s["no_drone"] and s["mae_angle_deg"] is not None]
    assert len(drone) >= 2
    turned = copy.deepcopy(base)
    by_name = {s["name"]: s for s in turned["sequences"]}
    by_name[drone[0]["name"]]["mae_angle_deg"] = drone[0]["mae_angle_deg"] + 150.0  # read backwards
    by_name[drone[1]["name"]]["mae_angle_deg"] = drone[1]["mae_angle_deg"] + 5.0  # within the threshold
    path = tmp_path / "turned.json"
    path.write_text(json.dumps(turned))
    assert main(["compare", "--base", str(runs["base"]), "--candidate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "moved by more than 10 deg: 0 better, 1 worse" in out
    assert f"worse   {drone[0]['name']}" in out and drone[1]["name"] not in out.split("deg:")[-1]
    assert main(["compare", "--base", str(path), "--candidate", str(runs["base"]), "--moved", "4"]) == 0
    assert "moved by more than 4 deg: 2 better, 0 worse" in capsys.readouterr().out


@pytest.mark.parametrize(
    "case,message",
    [
        ("count", "give as many --candidate files as --base files"),
        ("missing", "report not found"),
        ("not_json", "is not JSON"),
        ("not_report", "is not the output of 'dronekey-eval robustness --json'"),
        ("other_sequences", "does not hold the baseline's sequences"),
        ("moved", "--moved must be a finite number of degrees >= 0, got -1.0"),
    ],
)
def test_bad_input_is_one_line(case, message, runs, tmp_path, capsys):
    base = str(runs["base"])
    bad = tmp_path / "bad.json"
    candidate = [str(bad)]
    extra = []
    if case == "count":
        candidate = [base, base]
    elif case == "not_json":
        bad.write_text("{")
    elif case == "not_report":
        bad.write_text(json.dumps({"sets": 1}))
    elif case == "other_sequences":
        d = load_report(runs["base"])
        d["sequences"] = d["sequences"][1:]
        bad.write_text(json.dumps(d))
    elif case == "moved":
        candidate, extra = [base], ["--moved", "-1"]
    assert main(["compare", "--base", base, "--candidate", *candidate, *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dronekey-eval: error:") and message in err[0]
