"""Training on a COCO keypoint dataset (the 2DroneKey layout): split discovery, crops that carry the
annotated keypoints, bad data as one-line errors, and a tiny dronekey-train run on rendered images."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from dronekey.geometry.crop import CropPolicy
from dronekey.training.checkpoints import load_checkpoint
from dronekey.training.coco_crops import (
    MIRROR,
    CocoCropSampler,
    CocoDataError,
    find_coco_splits,
    load_coco_images,
)
from dronekey.training.train_cli import main


@pytest.fixture(scope="module")
def coco_folder(tmp_path_factory):
    """A 2DroneKey-style folder made from a real render: annotations/{train,val}.json + images/."""
    render = tmp_path_factory.mktemp("render")
    sim = [sys.executable, "-m", "dronekey.sim_replay.cli", "--preset", "2dronekey", "--frames", "6"]
    subprocess.run(
        [*sim, "--seed", "3", "--width", "480", "--height", "270", "--images", "--out", str(render)],
        check=True,
        capture_output=True,
    )
    doc = json.loads((render / "2dronekey.json").read_text())
    root = tmp_path_factory.mktemp("coco")
    (root / "annotations").mkdir()
    (root / "images").mkdir()
    for image in doc["images"]:
        name = image["file_name"].split("/")[-1]
        shutil.copy(render / image["file_name"], root / "images" / name)
        image["file_name"] = name
    for split, ids in (("train", {0, 1, 2, 3}), ("val", {4, 5})):
        part = dict(doc)
        part["images"] = [im for im in doc["images"] if im["id"] in ids]
        part["annotations"] = [a for a in doc["annotations"] if a["image_id"] in ids]
        (root / "annotations" / f"{split}.json").write_text(json.dumps(part))
    return root


def test_splits_are_found_by_name(coco_folder):
    train, val = find_coco_splits(coco_folder)
    assert [p.name for p in train] == ["train.json"] and [p.name for p in val] == ["val.json"]
    assert find_coco_splits(train[0]) == ([train[0]], [])
    with pytest.raises(CocoDataError, match="no JSON file with 'train'"):
        find_coco_splits(coco_folder / "images")
    with pytest.raises(CocoDataError, match="no such file or folder"):
        find_coco_splits(coco_folder / "missing")


def test_crops_carry_the_annotated_keypoints_and_mirror_exchanges_sides(coco_folder):
    images = load_coco_images([coco_folder / "annotations" / "train.json"])
    assert len(images) == 4 and all(im.path.is_file() for im in images)
    policy = CropPolicy()
    sampler = CocoCropSampler(images, policy, seed=1, negative_fraction=0.25)
    gt = [(im.keypoints[0], im.boxes[0]) for im in images if len(im.boxes)]
    plain = mirrored = negatives = 0
    for _ in range(200):
        s = sampler.sample()
        assert s.image.shape == (128, 128, 3) and s.image.dtype == np.uint8
        if not s.present:
            negatives += 1
            assert s.area == 0 and not s.keypoints.any()
            continue
        # The keypoints are some annotation's, seen through a square crop around its box: their
        # shape in the crop equals the annotation's up to a scale and shift (or its mirror image).
        matched = None
        for kp_px, box in gt:
            side = np.sqrt(box[2] * box[3] / s.area)  # area = box area / crop side^2
            for mirror in (False, True):
                kp = s.keypoints.astype(np.float64)
                if mirror:
                    kp = kp[MIRROR].copy()
                    kp[:, 0] = 1.0 - kp[:, 0]
                rel = (kp - kp.mean(axis=0)) * side
                if np.allclose(rel, kp_px - kp_px.mean(axis=0), atol=0.05):
                    matched = mirror
        assert matched is not None
        mirrored += matched
        plain += not matched
    assert negatives > 20 and plain > 20 and mirrored > 20


def test_negative_crops_touch_no_drone(coco_folder):
    images = load_coco_images([coco_folder / "annotations" / "train.json"])
    sampler = CocoCropSampler(images, CropPolicy(), seed=2)
    found = 0
    for k, image in enumerate(images):
        for _ in range(50):
            roi = sampler._negative_roi(k, (image.height, image.width))
            if roi is None:
                continue
            found += 1
            x0, y0, side = roi
            assert x0 >= 0 and y0 >= 0 and x0 + side <= image.width and y0 + side <= image.height
            for bx, by, bw, bh in image.boxes:
                assert bx + bw <= x0 or x0 + side <= bx or by + bh <= y0 or y0 + side <= by
    assert found > 100


def test_bad_data_is_a_one_line_error(coco_folder, tmp_path, capsys):
    bad = tmp_path / "bad"
    (bad / "annotations").mkdir(parents=True)
    doc = json.loads((coco_folder / "annotations" / "train.json").read_text())
    (bad / "annotations" / "train.json").write_text(json.dumps(doc))  # images are not beside it
    assert main(["--preset", "tiny", "--coco", str(bad), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("dronekey-train: ") and "images not found" in err[-1]
    doc["annotations"][0]["keypoints"] = [1, 2, 2]
    (bad / "annotations" / "train.json").write_text(json.dumps(doc))
    with pytest.raises(CocoDataError, match=r"annotations\[0\]: needs 'image_id' and 'keypoints'"):
        load_coco_images([bad / "annotations" / "train.json"])


def test_tiny_training_run_on_a_coco_folder(coco_folder, tmp_path):
    out = tmp_path / "run"
    args = ["--preset", "tiny", "--coco", str(coco_folder), "--out", str(out), "--epochs", "1"]
    assert main([*args, "--workers", "0", "--threads", "1"]) == 0
    _, meta = load_checkpoint(out / "best.pt")
    assert meta["trained_on"] == f"COCO keypoint dataset {coco_folder}"
    assert (out / "val_coco_64_128.npz").is_file()
    val = np.load(out / "val_coco_64_128.npz")
    assert val["present"].any() and (~val["present"]).any()
