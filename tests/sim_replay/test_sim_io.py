"""Sequence files: the §5.1 JSON writer and reader (ours and real COCO layouts), the atomic writer,
and reading frames back from real videos and image folders.

A tiny renderer defined here (dots at the projected propellers) feeds the writer, so these tests
do not depend on the full renderer; ``test_sim_cli.py`` covers the real presets end to end.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec, load_spec
from dronekey.geometry.rotations import geodesic_angle_deg, rotation_from_euler_deg
from dronekey.sim_replay.annotations import HIDDEN, VISIBLE, DroneAnnotation, FrameRecord
from dronekey.sim_replay.io.coco_pose import CocoPoseEncoding
from dronekey.sim_replay.io.frames import FrameSourceError, iter_frames
from dronekey.sim_replay.io.render_output import video_fourcc, write_sequence
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.io.sequence_writer import dumps_sequence, save_sequence
from dronekey.sim_replay.io.validation import SequenceFormatError

WIDTH, HEIGHT = 320, 180
DATA = Path(__file__).resolve().parent / "data"


def _camera() -> CameraModel:
    return CameraModel.from_fov(WIDTH, HEIGHT, 70.0, dist=[-0.08, 0.02, 0.0005, -0.0003, 0.0])


@dataclass
class _Rendered:
    image: np.ndarray
    record: FrameRecord


@dataclass
class DotSequence:
    """A minimal renderer with the interface of ``synthetic_sequence.build_sequence``'s result."""

    n_frames: int = 6
    name: str = "dots"
    fps: float = 30.0
    camera: CameraModel = field(default_factory=_camera)
    spec: DroneSpec = field(default_factory=lambda: load_spec("mini2"))
    interrupt_at: int | None = None
    bad_size_at: int | None = None

    @property
    def info(self) -> dict:
        return {"sequence": self.name, "generator": "tests", "seed": 0, "fps": self.fps}

    def pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        R = rotation_from_euler_deg(25.0 * i, -15.0 + 3 * i, 8.0)
        return R, np.array([0.05 * i - 0.1, 0.02 * i, 1.2 + 0.03 * i])

    def __iter__(self):
        rng = np.random.default_rng(0)
        for i in range(self.n_frames):
            if i == self.interrupt_at:
                raise KeyboardInterrupt
            h = HEIGHT + 2 if i == self.bad_size_at else HEIGHT
            img = rng.integers(40, 90, (h, WIDTH, 3), dtype=np.uint8)
            drone = None
            if i != 2:  # frame 2 has no drone
                R, t = self.pose(i)
                kp = self.camera.project_body(self.spec.keypoints_3d, R, t)
                for u, v in kp:
                    cv2.circle(img, (round(u), round(v)), 3, (255, 255, 255), -1)
                lo, hi = kp.min(0) - 4, kp.max(0) + 4
                vis = np.array([VISIBLE, VISIBLE, HIDDEN, VISIBLE])
                drone = DroneAnnotation(kp, vis, (*map(float, lo), *map(float, hi - lo)), R, t)
            yield _Rendered(img, FrameRecord(i, round(i * 1e9 / self.fps), "", WIDTH, HEIGHT, drone))


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---------------------------------------------------------------------------------- writing + reading


def test_written_json_has_the_design_layout_and_reads_back_exactly(tmp_path):
    seq = DotSequence()
    written = write_sequence(seq, tmp_path)
    assert _files(tmp_path) == ["camera.yaml", "dots.json", "dots.mp4"]
    assert (written.n_frames, written.n_annotated) == (6, 5)

    doc = json.loads(written.json_path.read_text())
    assert list(doc) == ["info", "camera", "drone", "categories", "images", "annotations"]
    assert doc["info"] == {"sequence": "dots", "generator": "tests", "seed": 0, "fps": 30.0}
    assert doc["categories"][0]["skeleton"] == [[1, 2], [2, 3], [3, 4], [4, 1]]
    assert doc["images"][3] == {
        "id": 3,
        "file_name": "dots.mp4#3",
        "frame_index": 3,
        "timestamp_ns": 100000000,
        "width": WIDTH,
        "height": HEIGHT,
    }
    ann = doc["annotations"][0]
    assert set(ann) == {
        "id", "image_id", "category_id", "keypoints", "num_keypoints", "bbox", "area", "iscrowd",
        "rotation", "translation",
    }  # fmt: skip
    assert ann["id"] == 1 and ann["keypoints"][8] == HIDDEN and ann["num_keypoints"] == 4
    assert [a["image_id"] for a in doc["annotations"]] == [0, 1, 3, 4, 5]

    loaded = load_sequence(written.json_path)
    assert loaded.name == "dots" and loaded.drone_model == "mini2" and loaded.base_dir == tmp_path
    assert np.array_equal(loaded.camera.K, seq.camera.K) and np.array_equal(
        loaded.camera.dist, seq.camera.dist
    )
    for i, rec in enumerate(loaded.frames):
        assert (rec.index, rec.t_ns, rec.file_name) == (i, round(i * 1e9 / 30), f"dots.mp4#{i}")
        if i == 2:
            assert rec.drone is None
            continue
        R, t = seq.pose(i)  # float64 values survive the text round trip bit for bit
        assert np.array_equal(rec.drone.rotation, R) and np.array_equal(rec.drone.translation, t)
        assert np.array_equal(rec.drone.keypoints_px, seq.camera.project_body(seq.spec.keypoints_3d, R, t))


def test_json_text_is_reproducible_and_pycocotools_reads_it(tmp_path):
    from pycocotools.coco import COCO

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    write_sequence(DotSequence(), a)
    write_sequence(DotSequence(), b)
    assert (a / "dots.json").read_bytes() == (b / "dots.json").read_bytes()
    coco = COCO(str(a / "dots.json"))
    assert len(coco.getImgIds()) == 6 and len(coco.getAnnIds(iscrowd=False)) == 5


def test_save_sequence_round_trip_and_refuses_nan(tmp_path):
    seq = load_sequence(write_sequence(DotSequence(), tmp_path).json_path)
    save_sequence(seq, tmp_path / "copy.json")
    assert (tmp_path / "copy.json").read_text() == (tmp_path / "dots.json").read_text()
    broken = seq.frames[0].drone
    seq.frames[0] = FrameRecord(0, 0, "x", WIDTH, HEIGHT, DroneAnnotation(
        broken.keypoints_px * np.nan, broken.visibility, broken.bbox_xywh, broken.rotation, broken.translation
    ))  # fmt: skip
    with pytest.raises(ValueError, match="Out of range float"):
        dumps_sequence(seq)


# ---------------------------------------------------------------------------------- frames


def test_video_decodes_with_the_json_frame_count_and_size(tmp_path):
    written = write_sequence(DotSequence(n_frames=7), tmp_path)
    assert video_fourcc() in ("avc1", "mp4v")
    cap = cv2.VideoCapture(str(written.media_path))
    decoded = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        decoded.append(img)
    cap.release()
    seq = load_sequence(written.json_path)
    assert len(decoded) == len(seq.frames) == 7
    assert {img.shape for img in decoded} == {(HEIGHT, WIDTH, 3)}

    frames = list(iter_frames(seq))
    assert [f.index for f in frames] == list(range(7))
    assert all(np.array_equal(f.bgr, d) for f, d in zip(frames, decoded, strict=True))
    assert frames[4].frame.t_ns == frames[4].record.t_ns == seq.frames[4].t_ns


def test_image_folder_frames_are_lossless(tmp_path):
    written = write_sequence(DotSequence(), tmp_path, images=True)
    assert _files(tmp_path) == ["camera.yaml", "dots", "dots.json"]
    assert _files(tmp_path / "dots") == [f"{i:06d}.png" for i in range(6)]
    seq = load_sequence(written.json_path)
    assert seq.frames[5].file_name == "dots/000005.png"
    rendered = [r.image for r in DotSequence()]
    frames = list(iter_frames(seq))
    assert all(np.array_equal(f.bgr, img) for f, img in zip(frames, rendered, strict=True))
    # An explicit folder holding just the base names works too.
    assert len(list(iter_frames(seq, tmp_path / "dots"))) == 6


def test_frame_count_and_size_mismatches_are_reported(tmp_path):
    written = write_sequence(DotSequence(), tmp_path)
    short = tmp_path / "short.mp4"
    writer = cv2.VideoWriter(str(short), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (WIDTH, HEIGHT))
    for _ in range(5):
        writer.write(np.zeros((HEIGHT, WIDTH, 3), np.uint8))
    writer.release()
    seq = load_sequence(written.json_path)
    with pytest.raises(FrameSourceError, match=r"short\.mp4 has 5 frames but the JSON describes 6"):
        list(iter_frames(seq, short))

    wrong = tmp_path / "wrong.mp4"
    writer = cv2.VideoWriter(str(wrong), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (WIDTH * 2, HEIGHT * 2))
    for _ in range(6):
        writer.write(np.zeros((HEIGHT * 2, WIDTH * 2, 3), np.uint8))
    writer.release()
    with pytest.raises(FrameSourceError, match=r"frame 0 is 640x360, the JSON says 320x180"):
        list(iter_frames(seq, wrong))

    written.media_path.unlink()
    with pytest.raises(FrameSourceError, match=r"video not found: .*dots\.mp4"):
        iter_frames(seq)


def test_missing_image_is_named(tmp_path):
    written = write_sequence(DotSequence(), tmp_path, images=True)
    (tmp_path / "dots" / "000004.png").unlink()
    with pytest.raises(FrameSourceError, match=r"frame 4: image not found: .*000004.png"):
        list(iter_frames(load_sequence(written.json_path)))


# ---------------------------------------------------------------------------------- atomic writes


@pytest.mark.parametrize("images", [False, True])
def test_interrupted_write_leaves_no_files_and_keeps_old_results(tmp_path, images):
    write_sequence(DotSequence(), tmp_path, images=images)
    before = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*")}
    with pytest.raises(KeyboardInterrupt):
        write_sequence(DotSequence(interrupt_at=3), tmp_path, images=images)
    assert {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*")} == before

    fresh = tmp_path / "fresh"
    fresh.mkdir()
    with pytest.raises(ValueError, match=r"frame 4: image must be \(180, 320, 3\)"):
        write_sequence(DotSequence(bad_size_at=4), fresh, images=images)
    assert _files(fresh) == []


def test_rewriting_replaces_outputs_cleanly(tmp_path):
    write_sequence(DotSequence(n_frames=8), tmp_path, images=True)
    write_sequence(DotSequence(n_frames=3), tmp_path, images=True)
    assert _files(tmp_path) == ["camera.yaml", "dots", "dots.json"]
    assert len(_files(tmp_path / "dots")) == 3


# ---------------------------------------------------------------------------------- malformed JSON


def _mutated(tmp_path: Path, mutate) -> Path:
    path = write_sequence(DotSequence(), tmp_path).json_path
    doc = json.loads(path.read_text())
    mutate(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.pop("images"), "dots.json: top level: missing key 'images'"),
        (lambda d: d["annotations"][1]["keypoints"].pop(), r"annotations\[1\].keypoints: must be 12 numbers"),
        (lambda d: d["annotations"][0]["keypoints"].__setitem__(2, 3), r"flags must be 0, 1 or 2, got \[3"),
        (
            lambda d: d["annotations"][2]["rotation"][0].__setitem__(0, 2.0),
            r"annotations\[2\].rotation: not a rot",
        ),
        (
            lambda d: d["annotations"][0]["translation"].__setitem__(1, "x"),
            r"translation: must be a list of num",
        ),
        (lambda d: d["annotations"][0].__setitem__("image_id", 99), r"image_id: no image has id 99"),
        (lambda d: d["annotations"][1].__setitem__("image_id", 0), r"image 0 already has annotations\[0\]"),
        (
            lambda d: d["camera"].__setitem__("K", [[1, 0], [0, 1]]),
            r"camera.K: must be 3x3 numbers, got shape 2x2",
        ),
        (lambda d: d["images"][4].__setitem__("width", -5), r"images\[4\].width: must be >= 1, got -5"),
        (
            lambda d: d["images"][1].__setitem__("frame_index", True),
            r"frame_index: must be an integer, got bool",
        ),
        (lambda d: d["drone"].pop("keypoints_3d"), r"drone: missing key 'keypoints_3d'"),
        (lambda d: d["info"].__setitem__("fps", 0), r"info\.fps: must be a positive number, got int 0"),
        (lambda d: d["camera"].__setitem__("dist", [1, 2, 3]), r"camera: dist must have 4, 5, 8, 12 or 14"),
        (lambda d: d["categories"][0]["keypoints"].pop(), r"categories\[0\].keypoints: DroneKey needs 4"),
        (lambda d: d.__setitem__("images", "x"), r"dots.json: images: must be a list, got str \"x\""),
        (lambda d: d["images"][2].__setitem__("id", 1), r"images\[2\].id: duplicate image id 1"),
        (lambda d: d["images"][2].__setitem__("frame_index", 1), r"images: frame_index values repeat"),
        (lambda d: d["images"][3].__setitem__("width", 640), r"images\[3\]: image size 640x180 differs"),
        (lambda d: d["annotations"][1].pop("bbox"), r"annotations\[1\]: missing key 'bbox'"),
    ],
)
def test_malformed_json_names_the_key_and_value(tmp_path, mutate, message):
    with pytest.raises(SequenceFormatError, match=message):
        load_sequence(_mutated(tmp_path, mutate))


def test_tolerated_variants_read_as_before(tmp_path):
    """What the reader has always let through: integers written as floats, string image ids, keys it
    does not read (anywhere, and categories after the first naming keypoints), and a file's camera
    object when the caller passes the camera (it is then not read at all)."""

    def variants(d):
        d["info"] = {"z": 1, **d["info"]}  # key order is kept
        d["camera"]["width"], d["images"][3]["frame_index"], d["images"][3]["id"] = 320.0, 3.0, 3.0
        for image in d["images"]:
            image["id"] = f"img{image['id']:g}"
        for ann in d["annotations"]:
            ann["image_id"], ann["extra"] = f"img{ann['image_id']}", {"any": [None]}
        d["categories"].append(5)
        d["unread"] = True

    reference = load_sequence(write_sequence(DotSequence(), tmp_path).json_path)
    seq = load_sequence(_mutated(tmp_path, variants))
    assert list(seq.info) == ["z", "sequence", "generator", "seed", "fps"]
    assert [(r.index, r.t_ns, r.drone is None) for r in seq.frames] == [
        (r.index, r.t_ns, r.drone is None) for r in reference.frames
    ]
    assert np.array_equal(seq.frames[3].drone.rotation, reference.frames[3].drone.rotation)
    broken = _mutated(tmp_path, lambda d: d["camera"].__setitem__("K", "unread"))
    assert load_sequence(broken, camera=_camera()).camera is not None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('{"info": {}, "images": [', r"bad.json: line 1 column 25: invalid JSON"),
        ("[1, 2]", r"bad.json: top level: must be an object, got list"),
        ('{"images": [], "annotations": [], "x": NaN}', r"NaN is not valid JSON"),
    ],
)
def test_syntax_errors_are_reported_with_position(tmp_path, text, message):
    (tmp_path / "bad.json").write_text(text)
    with pytest.raises(SequenceFormatError, match=message):
        load_sequence(tmp_path / "bad.json")


def test_missing_json_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="sequence JSON not found"):
        load_sequence(tmp_path / "nope.json")


# ---------------------------------------------------------------------------------- real COCO files


def _coco_file(folder: Path, name: str, encode_pose, *, with_pose: bool = True, order=(0, 1, 2, 3)) -> Path:
    """A 2DroneKey / 3DronePose-like COCO file of the DotSequence truth, without camera or drone."""
    seq, images, annotations = DotSequence(), [], []
    for i, rendered in enumerate(seq):
        # Shuffled ids and natural-order file names: frame_2 must come before frame_10.
        images.append(
            {"id": 100 + 7 * i, "file_name": f"frame_{i * 4}.jpg", "width": WIDTH, "height": HEIGHT}
        )
        cv2.imwrite(str(folder / f"frame_{i * 4}.jpg"), rendered.image)
        drone = rendered.record.drone
        if drone is None:
            continue
        flat = []
        for k in order:
            flat += [*drone.keypoints_px[k].tolist(), int(drone.visibility[k])]
        ann = {"id": i + 1, "image_id": 100 + 7 * i, "category_id": 1, "keypoints": flat, "num_keypoints": 4,
               "bbox": list(drone.bbox_xywh), "area": drone.area, "iscrowd": 0}  # fmt: skip
        if with_pose:
            ann.update(encode_pose(drone.rotation, drone.translation))
        annotations.append(ann)
    images.reverse()
    doc = {
        "images": images,
        "annotations": annotations,
        "categories": [{"id": 1, "name": "drone", "keypoints": ["p1", "p2", "p3", "p4"], "skeleton": []}],
    }
    path = folder / name
    path.write_text(json.dumps(doc))
    return path


def _euler_zyx_deg_mm(R, t):
    return {
        "rotation": Rotation.from_matrix(R).as_euler("ZYX", degrees=True).tolist(),
        "translation": (t * 1000).tolist(),
    }


def _quat_nested(R, t):
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return {"pose": {"quaternion": [w, x, y, z], "position": t.tolist()}}


def _pose6_translation_first_cm(R, t):
    return {"6dof": [*(t * 100).tolist(), *Rotation.from_matrix(R).as_rotvec().tolist()]}


def _matrix_flat(R, t):
    return {"R": R.ravel().tolist(), "t": t.tolist()}


@pytest.mark.parametrize(
    ("encode", "expected"),
    [
        (_euler_zyx_deg_mm, "rotation euler_ZYX_deg, translation in mm"),
        (_quat_nested, "rotation quat_wxyz, translation in m"),
        (_pose6_translation_first_cm, "rotation rotvec, translation in cm, 6-vector order tr"),
        (_matrix_flat, "rotation matrix, translation in m"),
    ],
)
def test_real_coco_pose_encodings_are_recognised(tmp_path, encode, expected):
    path = _coco_file(tmp_path, "seq13_mini2.json", encode)
    _camera().save_yaml(tmp_path / "camera.yaml")
    seq = load_sequence(path)
    assert seq.info["pose_encoding"] == expected
    assert seq.drone_model == "mini2"  # from the file name
    assert [r.file_name for r in seq.frames] == [f"frame_{i * 4}.jpg" for i in range(6)]
    assert [r.t_ns for r in seq.frames] == [round(i * 1e9 / 30) for i in range(6)]
    truth = DotSequence()
    for i, rec in enumerate(seq.frames):
        if i == 2:
            assert rec.drone is None
            continue
        R, t = truth.pose(i)
        assert geodesic_angle_deg(rec.drone.rotation, R) < 1e-6
        assert np.abs(rec.drone.translation - t).max() < 1e-9
    frames = list(iter_frames(seq))
    assert len(frames) == 6 and frames[0].bgr.shape == (HEIGHT, WIDTH, 3)


def test_real_coco_without_camera_or_drone_says_what_to_pass(tmp_path):
    path = _coco_file(tmp_path, "seq.json", _euler_zyx_deg_mm)
    with pytest.raises(
        SequenceFormatError, match=r"no 'camera' object and there is no camera\.yaml beside it"
    ):
        load_sequence(path)
    _camera().save_yaml(tmp_path / "camera.yaml")
    with pytest.raises(SequenceFormatError, match=r"cannot tell the drone model .* pass it"):
        load_sequence(path)
    assert load_sequence(path, drone="mini2").drone_model == "mini2"
    # A calibration at another resolution of the same aspect ratio is scaled to the images.
    big = CameraModel.from_fov(WIDTH * 4, HEIGHT * 4, 70.0, dist=_camera().dist)
    big.save_yaml(tmp_path / "big.yaml")
    seq = load_sequence(path, drone="mini2", camera=tmp_path / "big.yaml")
    assert seq.camera.size == (WIDTH, HEIGHT) and math.isclose(seq.camera.fx, _camera().fx)


def test_real_coco_with_unmatched_keypoint_order_is_refused(tmp_path):
    path = _coco_file(tmp_path, "mini2.json", _euler_zyx_deg_mm, order=(1, 0, 2, 3))
    _camera().save_yaml(tmp_path / "camera.yaml")
    with pytest.raises(SequenceFormatError, match="cannot tell how the 6DoF is encoded"):
        load_sequence(path)
    # Naming the encoding takes it as given (a warning reports the residual).
    seq = load_sequence(path, pose_encoding=CocoPoseEncoding(rotation="euler_ZYX_deg", translation_unit="mm"))
    assert seq.annotated()[0].drone.has_pose
    with pytest.raises(SequenceFormatError, match=r"a rotation of 3 numbers cannot be read as matrix"):
        load_sequence(path, pose_encoding=CocoPoseEncoding(rotation="matrix"))


def test_2dronekey_keypoints_only_file(tmp_path):
    path = _coco_file(tmp_path, "air2s_seq1.json", None, with_pose=False)
    _camera().save_yaml(tmp_path / "camera.yaml")
    seq = load_sequence(path)
    assert seq.drone_model == "air2s" and len(seq.annotated()) == 5
    assert not any(r.drone.has_pose for r in seq.annotated())
    assert seq.annotated()[0].drone.visibility.tolist() == [2, 2, 1, 2]


# ---------------------------------------------------------------------------------- files written before


def test_a_file_written_by_the_earlier_writer_reads_and_rewrites_byte_for_byte():
    """``data/dots.json``: ``DotSequence(n_frames=4)`` written as images by the writer of commit b0d9921
    (``sim_replay/writer.py`` and ``sequence_io.py``, before the ``sim_replay.io`` package)."""
    path = DATA / "dots.json"
    seq = load_sequence(path)
    assert (seq.name, seq.drone_model, seq.fps, seq.base_dir) == ("dots", "mini2", 30.0, DATA)
    assert seq.info == {"sequence": "dots", "generator": "tests", "seed": 0, "fps": 30.0}
    assert np.array_equal(seq.camera.K, _camera().K) and np.array_equal(seq.camera.dist, _camera().dist)
    truth = DotSequence(n_frames=4)
    for i, rec in enumerate(seq.frames):
        assert (rec.index, rec.t_ns, rec.file_name) == (i, round(i * 1e9 / 30), f"dots/{i:06d}.png")
        if i == 2:
            assert rec.drone is None
            continue
        R, t = truth.pose(i)
        assert np.array_equal(rec.drone.rotation, R) and np.array_equal(rec.drone.translation, t)
        assert rec.drone.visibility.tolist() == [VISIBLE, VISIBLE, HIDDEN, VISIBLE]
    assert dumps_sequence(seq) == path.read_text(encoding="utf-8")
