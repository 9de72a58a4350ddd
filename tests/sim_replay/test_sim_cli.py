"""``dronekey-sim`` end to end with the real presets: the files it writes (decoded with OpenCV and
PyAV), reproducibility, the ground truth in the JSON, bad input, and interruption."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.rotations import geodesic_angle_deg
from dronekey.sim_replay.cli import main
from dronekey.sim_replay.io.frames import iter_frames
from dronekey.sim_replay.io.sequence_reader import load_sequence

SMALL = ["--width", "480", "--height", "270"]


def run_cli(argv: list[str]) -> int:
    """``main`` as the console script runs it: argparse's exits become the return code."""
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def render(out: Path, preset: str = "seq13", frames: int = 8, *extra: str) -> dict:
    assert run_cli(["--preset", preset, "--out", str(out), "--frames", str(frames), *SMALL, *extra]) == 0
    return json.loads((out / f"{preset}.json").read_text())


def poses(doc: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rotations (N, 3, 3), translations (N, 3) and timestamps (N,) s of the annotated frames."""
    t_ns = {img["id"]: img["timestamp_ns"] for img in doc["images"]}
    anns = doc["annotations"]
    return (
        np.array([a["rotation"] for a in anns]),
        np.array([a["translation"] for a in anns]),
        np.array([t_ns[a["image_id"]] for a in anns]) * 1e-9,
    )


@pytest.fixture(scope="module")
def seq13(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("seq13")
    return out, render(out, "seq13", 8)


# ---------------------------------------------------------------------------------- files


def test_writes_video_json_and_camera(seq13, capsys):
    out, doc = seq13
    assert sorted(p.name for p in out.iterdir()) == ["camera.yaml", "seq13.json", "seq13.mp4"]
    camera = CameraModel.load(out / "camera.yaml")
    assert camera.size == (480, 270)
    assert np.allclose(camera.K, doc["camera"]["K"]) and np.allclose(camera.dist, doc["camera"]["dist"])
    assert doc["info"]["sequence"] == "seq13" and doc["info"]["fps"] == 30.0
    assert [img["file_name"] for img in doc["images"]] == [f"seq13.mp4#{i}" for i in range(8)]


def test_decoded_video_has_the_json_frame_count_and_size(seq13):
    out, doc = seq13
    sizes = {(img["width"], img["height"]) for img in doc["images"]}
    assert sizes == {(480, 270)}

    cap = cv2.VideoCapture(str(out / "seq13.mp4"))
    shapes = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        shapes.append(img.shape)
    cap.release()
    assert len(shapes) == len(doc["images"]) and set(shapes) == {(270, 480, 3)}

    with av.open(str(out / "seq13.mp4")) as container:  # a decoder independent of OpenCV
        frames = [f for f in container.decode(video=0)]
    assert len(frames) == len(doc["images"]) and {(f.width, f.height) for f in frames} == {(480, 270)}

    read = list(iter_frames(load_sequence(out / "seq13.json")))
    assert [f.index for f in read] == list(range(8)) and read[0].bgr.shape == (270, 480, 3)


def test_same_seed_gives_the_same_json_bytes(tmp_path):
    for name in ("a", "b", "c"):
        seed = "5" if name != "c" else "6"
        render(tmp_path / name, "2dronekey", 6, "--seed", seed)
    first = (tmp_path / "a" / "2dronekey.json").read_bytes()
    assert first == (tmp_path / "b" / "2dronekey.json").read_bytes()
    assert first != (tmp_path / "c" / "2dronekey.json").read_bytes()
    assert json.loads(first)["info"]["seed"] == 5


def test_keypoints_are_the_projection_of_keypoints_3d_with_distortion(seq13):
    _, doc = seq13
    camera = CameraModel.from_dict(doc["camera"])
    assert np.any(camera.dist != 0), "the presets' camera must exercise distortion"
    kp3d = np.array(doc["drone"]["keypoints_3d"])
    assert doc["annotations"], "seq13 shows the drone"
    for ann in doc["annotations"]:
        uv = np.array(ann["keypoints"]).reshape(4, 3)[:, :2]
        projected = camera.project_body(kp3d, np.array(ann["rotation"]), np.array(ann["translation"]))
        assert np.abs(projected - uv).max() < 0.01


def test_seq11_constant_rotation_and_linear_translation(tmp_path):
    doc = render(tmp_path, "seq11", 10)
    R, t, s = poses(doc)
    assert len(R) >= 8
    assert max(geodesic_angle_deg(R[0], Ri) for Ri in R) < 1e-6
    # t(s) = t0 + v s: a straight line at constant velocity fits to float precision.
    A = np.c_[np.ones_like(s), s]
    coef, *_ = np.linalg.lstsq(A, t, rcond=None)
    assert np.abs(A @ coef - t).max() < 1e-9
    assert np.linalg.norm(coef[1]) > 0.05  # it moves (m/s)


def test_seq13_rotates(tmp_path):
    doc = render(tmp_path, "seq13", 30)
    R, _, _ = poses(doc)
    assert len(R) >= 20
    assert max(geodesic_angle_deg(R[0], Ri) for Ri in R) > 5.0


def test_image_folder_output(tmp_path):
    doc = render(tmp_path, "seq12", 6, "--images")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera.yaml", "seq12", "seq12.json"]
    assert [img["file_name"] for img in doc["images"]] == [f"seq12/{i:06d}.png" for i in range(6)]
    frames = list(iter_frames(load_sequence(tmp_path / "seq12.json")))
    assert len(frames) == 6 and frames[5].bgr.shape == (270, 480, 3)


def test_summary_line_and_verify(seq13, capsys):
    out, _ = seq13
    assert run_cli(["--verify", str(out / "seq13.json")]) == 0
    line = capsys.readouterr().out.strip()
    assert line.endswith(
        "8 frames (8 annotated) of 480x270 read and checked; drone mini2; "
        "keypoints vs projection of keypoints_3d through the pose: max 0.0000 px"
    )

    other = out / "again"
    assert run_cli(["--preset", "seq13", "--out", str(other), "--frames", "3", *SMALL]) == 0
    summary = capsys.readouterr().out.strip()
    assert summary.startswith("wrote 3 frames (3 annotated) of seq13 at 480x270, ")
    assert summary.endswith(f"{other / 'seq13.mp4'}, {other / 'seq13.json'}, {other / 'camera.yaml'}")


def test_verify_a_real_style_coco_file(tmp_path, capsys):
    """Our output rewritten the way a 2DroneKey / 3DronePose release might hold it: no camera, no
    drone, images by base name in another folder, quaternion + millimetres under other keys."""
    render(tmp_path / "ours", "seq13", 5, "--images")
    doc = json.loads((tmp_path / "ours" / "seq13.json").read_text())
    for img in doc["images"]:
        img["file_name"] = Path(img["file_name"]).name
        del img["frame_index"], img["timestamp_ns"]
    for ann in doc["annotations"]:
        x, y, z, w = Rotation.from_matrix(ann.pop("rotation")).as_quat()
        ann["pose"] = {"quat": [w, x, y, z], "location": (np.array(ann.pop("translation")) * 1000).tolist()}
    coco = {k: doc[k] for k in ("images", "annotations", "categories")}
    (tmp_path / "real").mkdir()
    (tmp_path / "real" / "test.json").write_text(json.dumps(coco))
    argv = ["--verify", str(tmp_path / "real" / "test.json"), "--media", str(tmp_path / "ours" / "seq13")]

    assert run_cli(argv) == 2
    assert "no 'camera' object and there is no camera.yaml beside it" in capsys.readouterr().err
    argv += ["--calib", str(tmp_path / "ours" / "camera.yaml"), "--drone", "mini2"]
    assert run_cli(argv) == 0
    line = capsys.readouterr().out
    assert "5 frames (5 annotated) of 480x270 read and checked; drone mini2" in line
    assert float(line.split("max ")[1].split(" px")[0]) < 0.01


def test_list_presets(capsys):
    assert run_cli(["--list-presets"]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert names == ["seq11", "seq12", "seq13", "2dronekey", "far", "swarm"]


# ---------------------------------------------------------------------------------- bad input


def _bad_inputs(tmp: Path) -> list[tuple[list[str], str]]:
    (tmp / "a_file").write_text("x")
    (tmp / "no_images").mkdir()
    (tmp / "no_images" / "notes.txt").write_text("x")
    (tmp / "broken.json").write_text('{"images": [}')
    (tmp / "no_info.json").write_text('{"camera": {}, "drone": {}, "images": []}')
    out = str(tmp / "out")
    render_ = ["--preset", "seq13", "--out", out]
    return [
        (
            ["--preset", "seq99", "--out", out],
            "unknown preset 'seq99'; valid presets: seq11, seq12, seq13, 2dronekey",
        ),
        ([*render_, "--frames", "0"], "argument --frames: must be a positive integer, got '0'"),
        ([*render_, "--frames", "-4"], "argument --frames: must be a positive integer, got '-4'"),
        ([*render_, "--width", "640"], "--width needs its partner"),
        (
            [*render_, "--width", "0", "--height", "9"],
            "argument --width: must be a positive integer, got '0'",
        ),
        (["--preset", "seq13", "--out", str(tmp / "a_file" / "sub")], "is not writable (Not a directory)"),
        (
            ["--preset", "seq13", "--out", str(tmp / "a_file")],
            f"output folder {tmp / 'a_file'} is an existing file",
        ),
        ([*render_, "--backgrounds", str(tmp / "nope")], f"backgrounds folder not found: {tmp / 'nope'}"),
        ([*render_, "--backgrounds", str(tmp / "no_images")], "no images (.jpg"),
        (["--preset", "seq13"], "--out DIR is required with --preset"),
        (["--verify", str(tmp / "broken.json")], "broken.json: line 1 column 13: invalid JSON"),
        (["--verify", str(tmp / "no_info.json")], "no_info.json: top level: missing key 'info'"),
        (["--verify", str(tmp / "missing.json")], "sequence JSON not found"),
        ([], "give exactly one of --preset, --list-presets, --verify"),
    ]


def test_bad_input_is_one_error_line_and_exit_2(tmp_path, capsys):
    for argv, message in _bad_inputs(tmp_path):
        assert run_cli(argv) == 2, argv
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dronekey-sim: error: "), captured.err
        assert message in lines[0], (message, lines[0])
        assert captured.out == ""
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_missing_video_is_one_error_line(seq13, tmp_path, capsys):
    out, _ = seq13
    shutil.copy(out / "seq13.json", tmp_path / "seq13.json")
    assert run_cli(["--verify", str(tmp_path / "seq13.json")]) == 2
    expected = f"video not found: {tmp_path / 'seq13.mp4'} (named by the JSON's file_name entries)"
    assert capsys.readouterr().err.strip() == f"dronekey-sim: error: {expected}"


def _console_script() -> str:
    return shutil.which("dronekey-sim") or str(Path(sys.executable).with_name("dronekey-sim"))


def test_console_script_reports_without_traceback(tmp_path):
    result = subprocess.run(
        [_console_script(), "--preset", "nope", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert result.stderr.strip().startswith("dronekey-sim: error: unknown preset 'nope'")
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


# Started as a background job (`dronekey-sim ... &` in a script) a process inherits SIGINT ignored;
# a SIGINT sent to it must still stop the render cleanly.
_SIGINT_IGNORED = [
    sys.executable,
    "-c",
    "import os, signal, sys; signal.signal(signal.SIGINT, signal.SIG_IGN); "
    "os.execv(sys.argv[1], sys.argv[1:])",
]


@pytest.mark.parametrize(
    ("sig", "code", "launcher"),
    [(signal.SIGINT, 130, []), (signal.SIGTERM, 143, []), (signal.SIGINT, 130, _SIGINT_IGNORED)],
    ids=["SIGINT", "SIGTERM", "SIGINT-after-background-start"],
)
def test_interrupt_leaves_no_files(tmp_path, sig, code, launcher):
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [*launcher, _console_script(), "--preset", "2dronekey", "--out", str(out), *SMALL],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not (out.is_dir() and any(p.name.startswith(".2dronekey.partial") for p in out.iterdir())):
            assert proc.poll() is None and time.monotonic() < deadline, "rendering did not start"
            time.sleep(0.05)
        time.sleep(0.3)  # a few frames in
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err
    assert "Traceback" not in err
    assert list(out.iterdir()) == []
