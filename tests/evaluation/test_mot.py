"""dronekey-eval mot: the pipeline over a rendered swarm, scored with motmetrics on 3D distance."""

from __future__ import annotations

import json

import pytest

from dronekey.evaluation.cli import main as eval_main
from dronekey.sim_replay.cli import main as sim_main


@pytest.fixture(scope="module")
def swarm_json(tmp_path_factory):
    out = tmp_path_factory.mktemp("swarm")
    assert (
        sim_main(
            ["--preset", "swarm", "--frames", "12", "--width", "640", "--height", "360", "--out", str(out)]
        )
        == 0
    )
    return out / "swarm.json"


def test_mot_json_reports_clear_mot_identity_and_per_drone(swarm_json, capsys):
    assert eval_main(["mot", "--sequence", str(swarm_json), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames"] == 12 and out["drones"] == 3 and out["gate_m"] == 1.0
    for key in (
        "mota",
        "motp",
        "idf1",
        "id_switches",
        "false_positives",
        "false_negatives",
        "mostly_tracked",
    ):
        assert key in out
    assert out["gt_boxes"] == out["false_negatives"] + sum(d["frames"] for d in out["per_drone"])
    assert [d["instance_id"] for d in out["per_drone"]] == [0, 1, 2]
    assert out["mota"] <= 1.0 and 0.0 <= out["idf1"] <= 1.0


def test_mot_table_and_bad_gate(swarm_json, capsys):
    assert eval_main(["mot", "--sequence", str(swarm_json), "--gate", "0.5"]) == 0
    text = capsys.readouterr().out
    assert "MOTA" in text and "IDF1" in text and "3D gate 0.5 m" in text
    assert eval_main(["mot", "--sequence", str(swarm_json), "--gate", "0"]) == 2
    assert "--gate must be a positive distance" in capsys.readouterr().err


def test_several_sequences_are_scored_each_and_added_up(swarm_json, capsys):
    """Two sequences: each one's figures, then motmetrics' overall row over both, whose counts are
    the sums of theirs (the same file twice: every count doubles, MOTA and IDF1 stay)."""
    assert eval_main(["mot", "--sequence", str(swarm_json), str(swarm_json), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    one, overall = out["sequences"][0], out["overall"]
    assert len(out["sequences"]) == 2 and overall["sequences"] == 2 and overall["frames"] == 24
    for key in ("gt_boxes", "false_positives", "false_negatives", "id_switches"):
        assert overall[key] == sum(s[key] for s in out["sequences"])
    assert overall["mota"] == pytest.approx(one["mota"], abs=1e-3)
    assert overall["idf1"] == pytest.approx(one["idf1"], abs=1e-3)
    assert eval_main(["mot", "--sequence", str(swarm_json), str(swarm_json)]) == 0
    text = capsys.readouterr().out
    assert text.count("3D gate 1 m") == 3 and "all 2 sequences: 24 frames" in text
    assert eval_main(["mot", "--sequence", str(swarm_json), str(swarm_json), "--video", "x.mp4"]) == 2
    assert "--video names one sequence's video" in capsys.readouterr().err


def test_pose_refuses_a_multi_drone_file_in_one_line(swarm_json, capsys):
    assert eval_main(["pose", "--sequence", str(swarm_json)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "has 3 drones" in err and "dronekey-eval mot" in err


def test_pooling_refuses_different_gates_and_results_without_matches():
    import motmetrics as mm

    from dronekey.evaluation.mot import MotResult, pooled_summary

    a = MotResult("a", 1, 1.0, {}, accumulator=mm.MOTAccumulator(auto_id=True))
    b = MotResult("b", 1, 2.0, {}, accumulator=mm.MOTAccumulator(auto_id=True))
    with pytest.raises(ValueError, match=r"different gates: \[1\.0, 2\.0\]"):
        pooled_summary([a, b])
    with pytest.raises(ValueError, match="needs the results of evaluate_mot"):
        pooled_summary([MotResult("c", 1, 1.0, {})])


def test_mot_measures_a_tracker_or_localizer_setting_and_says_so(swarm_json, capsys):
    """``--tracker`` / ``--localizer KEY=VALUE`` reach the pipeline (max_tracks=1: at most one
    track a frame, so at most one drone matched a frame) and the output names what changed."""
    argv = ["mot", "--sequence", str(swarm_json), "--json"]
    assert eval_main([*argv, "--tracker", "max_tracks=1", "--localizer", "max_candidates=3"]) == 0
    out = json.loads(capsys.readouterr().out)
    changed = {
        "localizer_changed": {"max_candidates": 3},
        "tracker_changed": {"max_tracks": 1},
        "dither": None,
    }
    assert out["settings"] == changed
    assert sum(d["frames"] for d in out["per_drone"]) <= out["frames"]
    assert eval_main([*argv]) == 0
    unchanged = {"localizer_changed": {}, "tracker_changed": {}, "dither": None}
    assert json.loads(capsys.readouterr().out)["settings"] == unchanged
    assert eval_main(["mot", "--sequence", str(swarm_json), "--tracker", "max_tracks=1"]) == 0
    assert capsys.readouterr().out.startswith("settings: tracker max_tracks=1\n")
    assert eval_main([*argv, "--tracker", "merge_range_ratio=abc"]) == 2
    err = capsys.readouterr().err
    assert "--tracker merge_range_ratio" in err and "abc" in err and len(err.strip().splitlines()) == 1


def test_mot_dithered_names_its_seed_and_refuses_a_negative_one(swarm_json, capsys):
    """``--dither SEED``: the same frames with a grey level of seeded noise (the swarm figures' noise
    floor); the seed is in the JSON and the table's first line, and a bad one is one line."""
    argv = ["mot", "--sequence", str(swarm_json)]
    assert eval_main([*argv, "--dither", "3", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["settings"]["dither"] == 3
    assert eval_main([*argv, "--dither", "3"]) == 0
    assert capsys.readouterr().out.startswith("settings: frames dithered (seed 3)\n")
    assert eval_main([*argv, "--dither", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--dither must be >= 0, got -1" in err and len(err.strip().splitlines()) == 1
