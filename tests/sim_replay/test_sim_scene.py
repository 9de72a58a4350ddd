"""Several drones and several cameras: the swarm and far presets, the instance ids in the §5.1 JSON,
and the site file of a multi-camera render (positions agree across cameras in the site frame)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dronekey.sim_replay.cli import main as run_cli
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.io.site import SITE_FORMAT, load_site
from dronekey.sim_replay.io.validation import SequenceFormatError
from dronekey.sim_replay.scene import build_scene

SIZE = ["--width", "320", "--height", "180"]


def test_two_cameras_map_each_drone_to_one_site_point(tmp_path):
    assert (
        run_cli(["--preset", "swarm", "--frames", "3", *SIZE, "--cameras", "2", "--out", str(tmp_path)]) == 0
    )
    site = load_site(tmp_path / "site.json")
    assert site.format == SITE_FORMAT and [c.id for c in site.cameras] == ["cam0", "cam1"]
    baseline = np.linalg.norm(site.cameras[1].t_site_cam_m - site.cameras[0].t_site_cam_m)
    assert 5.0 <= baseline <= 50.0
    seqs = [load_sequence(tmp_path / c.folder / "swarm.json") for c in site.cameras]
    assert all((tmp_path / c.folder / "camera.yaml").is_file() for c in site.cameras)
    compared = 0
    for f0, f1 in zip(seqs[0].frames, seqs[1].frames, strict=True):
        assert f0.t_ns == f1.t_ns  # one time base
        in_1 = {d.instance_id: d for d in f1.drones}
        for d0 in f0.drones:
            if d0.instance_id in in_1:
                p0 = site.cameras[0].site_from_cam(d0.translation)
                p1 = site.cameras[1].site_from_cam(in_1[d0.instance_id].translation)
                np.testing.assert_allclose(p0, p1, atol=1e-6)
                # Orientation agrees too: R_site_body from either camera.
                R0 = site.cameras[0].R_site_cam @ d0.rotation
                R1 = site.cameras[1].R_site_cam @ in_1[d0.instance_id].rotation
                np.testing.assert_allclose(R0, R1, atol=1e-9)
                compared += 1
    assert compared >= 3
    # geo is the daemon's --camera-geo: LAT,LON,ALT,YAW,PITCH,ROLL; cam0 looks north at the preset pitch
    lat, lon, alt, yaw, pitch, roll = (float(v) for v in site.cameras[0].geo.split(","))
    assert (lat, lon, yaw, pitch, roll) == (47.397742, 8.545594, 0.0, 15.0, 0.0) and alt == pytest.approx(
        489.5
    )


def test_swarm_has_several_instances_with_their_models(tmp_path):
    assert (
        run_cli(["--preset", "swarm", "--frames", "2", *SIZE, "--drones", "4", "--out", str(tmp_path)]) == 0
    )
    doc = json.loads((tmp_path / "swarm.json").read_text())
    assert [i["instance_id"] for i in doc["instances"]] == [0, 1, 2, 3]
    assert {i["model"] for i in doc["instances"]} >= {"mini2", "air2s"}
    assert all("instance_id" in a for a in doc["annotations"])
    seq = load_sequence(tmp_path / "swarm.json")
    assert seq.is_multi_drone and seq.instance(1).model == "air2s"
    assert len(seq.frames[0].drones) >= 3
    with pytest.raises(ValueError, match="has 4 drones"):
        seq.require_single_drone("pose")
    # Each drone has its own look (style seed + instance id).
    assert len({d["style_seed"] for d in doc["info"]["drones"]}) == 4


def test_one_airframe_swarm_flies_the_mixed_swarms_paths(tmp_path):
    """``--airframe`` changes the drones' spec, not their paths: the same positions, every instance the
    one model, its hubs that model's."""
    mixed, single = tmp_path / "mixed", tmp_path / "mini2"
    common = ["--preset", "swarm", "--frames", "2", *SIZE, "--seed", "15"]
    assert run_cli([*common, "--out", str(mixed)]) == 0
    assert run_cli([*common, "--airframe", "mini2", "--out", str(single)]) == 0
    a, b = load_sequence(mixed / "swarm.json"), load_sequence(single / "swarm.json")
    assert {a.instance(i).model for i in a.instance_ids()} == {"mini2", "air2s"}
    assert {b.instance(i).model for i in b.instance_ids()} == {"mini2"}
    for fa, fb in zip(a.frames, b.frames, strict=True):
        for da, db in zip(fa.drones, fb.drones, strict=True):
            assert da.instance_id == db.instance_id
            np.testing.assert_allclose(da.translation, db.translation)
    air = next(i for i in a.instance_ids() if a.instance(i).model == "air2s")
    first = (a.frames[0], b.frames[0])
    spread = [np.ptp(next(d for d in f.drones if d.instance_id == air).keypoints_px[:, 0]) for f in first]
    assert spread[1] < 0.8 * spread[0]  # a Mini 2 on the Air 2S's path: 213 against 302 mm


def test_duplicate_instance_in_one_image_is_refused(tmp_path):
    assert run_cli(["--preset", "swarm", "--frames", "1", *SIZE, "--out", str(tmp_path)]) == 0
    path = tmp_path / "swarm.json"
    doc = json.loads(path.read_text())
    doc["annotations"][1]["instance_id"] = doc["annotations"][0]["instance_id"]
    path.write_text(json.dumps(doc))
    with pytest.raises(SequenceFormatError, match=r"annotations\[1\]\.image_id.*at most once per image"):
        load_sequence(path)
    doc["annotations"][1]["instance_id"] = 9
    path.write_text(json.dumps(doc))
    with pytest.raises(SequenceFormatError, match="instance_id 9 is not listed"):
        load_sequence(path)


def test_single_drone_files_stay_as_they_were(tmp_path):
    assert run_cli(["--preset", "seq13", "--frames", "2", *SIZE, "--out", str(tmp_path)]) == 0
    text = (tmp_path / "seq13.json").read_text()
    assert "instance_id" not in text and '"instances"' not in text
    seq = load_sequence(tmp_path / "seq13.json")
    assert not seq.is_multi_drone and seq.frames[0].drone.instance_id == 0 and seq.instance_ids() == [0]


def test_far_preset_sizes_and_scene_determinism():
    scene = build_scene("far", frames=300, width=1920, height=1080)
    view = scene.views[0]
    ranges = [float(np.linalg.norm(view.ground_truth_cam(i)[0][2])) for i in (0, 299)]
    assert 140 <= ranges[0] <= 150 and 20 <= ranges[1] <= 25
    assert view.camera.K[0, 0] > 8000  # long lens
    a = build_scene("swarm", frames=5, width=320, height=180, cameras=2)
    b = build_scene("swarm", frames=5, width=320, height=180, cameras=2)
    for va, vb in zip(a.views, b.views, strict=True):
        for fa, fb in zip(va, vb, strict=True):
            assert np.array_equal(fa.image, fb.image)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--preset", "seq13", "--drones", "2"], "--drones applies to the swarm preset only"),
        (["--preset", "swarm", "--drones", "13"], "--drones must be 1-12"),
        (["--preset", "seq13", "--cameras", "9"], "--cameras must be 1-8"),
        (["--preset", "swarm", "--no-drone"], "--no-drone"),
        (["--preset", "seq13", "--airframe", "air2s"], "--airframe applies to the swarm preset only"),
        (["--preset", "swarm", "--airframe", "mavic"], "--airframe must be one of air2s, mini2"),
    ],
)
def test_bad_scene_arguments_are_one_line(tmp_path, capsys, argv, message):
    assert run_cli([*argv, *SIZE, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_site_file_errors_name_the_key(tmp_path):
    path = Path(tmp_path) / "site.json"
    path.write_text(json.dumps({"format": "dronekey-site/0", "origin": {"lat": 0, "lon": 0, "alt_m": 0}}))
    with pytest.raises(SequenceFormatError, match="format"):
        load_site(path)
