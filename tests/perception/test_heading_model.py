"""The front/back classifier at run time: the front-up warp, the shipped model's antisymmetry and
its doubt where the front axis points nowhere, and how KeypointModel hands its answer on."""

from __future__ import annotations

import numpy as np
import pytest

from dronekey.perception.heading_model import (
    PATCH_SIZE,
    HeadingModel,
    canonical_patch,
    default_heading_model_path,
    load_heading_model,
)
from dronekey.perception.keypoint_model import HEADING_TWIN, KeypointModel
from dronekey.perception.spread_calibration import SpreadCalibration
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig

# Spec order 1 FR, 2 RR, 3 RL, 4 FL of a drone seen from above whose nose points right (+x).
KP = np.array([[80.0, 80.0], [40.0, 80.0], [40.0, 40.0], [80.0, 40.0]])


def crop_with_a_nose() -> np.ndarray:
    crop = np.full((128, 128, 3), 60, np.uint8)
    crop[55:65, 90:100] = 250  # a bright mark ahead of the front hubs
    return crop


def test_canonical_patch_turns_the_front_up():
    patch, ratio = canonical_patch(crop_with_a_nose(), KP)
    assert patch.shape == (PATCH_SIZE, PATCH_SIZE, 3)
    assert ratio == pytest.approx(40 / np.hypot(20, 20))
    bright = np.argwhere(patch[..., 0] > 200)
    assert bright[:, 0].max() < PATCH_SIZE / 2 - 5  # the mark is in the top half, centred
    assert abs(bright[:, 1].mean() - PATCH_SIZE / 2) < 3
    twin, _ = canonical_patch(crop_with_a_nose(), KP[HEADING_TWIN])  # the twin order: turned 180 deg
    assert np.argwhere(twin[..., 0] > 200)[:, 0].min() > PATCH_SIZE / 2 + 5


@pytest.mark.parametrize("net", ["gated", "deep"])
def test_shipped_model_answers_the_turned_patch_with_the_complementary_probability(net):
    model = load_heading_model(net)
    assert model.path == default_heading_model_path(net)
    tensor, ratios = model.preprocess(crop_with_a_nose()[None], KP[None] / 128.0)
    logits = model.inference(np.concatenate([tensor, np.ascontiguousarray(tensor[..., ::-1, ::-1])]))
    assert logits[0] == pytest.approx(-logits[1], abs=1e-5)  # antisymmetric by construction
    p = model.postprocess(logits, np.repeat(ratios, 2))
    assert p[0] + p[1] == pytest.approx(1.0, abs=1e-6)
    assert model.metadata["trained_on"]["sampler_seeds"]


def test_no_front_axis_means_a_coin_flip():
    model = HeadingModel()
    nose_on = np.array([[70.0, 64.0], [70.0, 64.0], [58.0, 64.0], [58.0, 64.0]]) / 128.0  # front = rear
    p = model(crop_with_a_nose()[None], nose_on[None])
    assert p[0] == 0.5


def test_errors_name_what_is_wrong(tmp_path):
    with pytest.raises(FileNotFoundError, match="dronekey-train-heading"):
        HeadingModel(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not onnx")
    with pytest.raises(ValueError, match="not an ONNX model"):
        HeadingModel(bad)
    with pytest.raises(ValueError, match="min_axis_ratio"):
        HeadingModel(min_axis_ratio=-1)
    with pytest.raises(TypeError, match="heading_model"):
        load_heading_model(3)
    assert load_heading_model(False) is None
    assert default_heading_model_path().is_file()
    with pytest.raises(ValueError, match="net must be one of gated, deep, got 'huge'"):
        default_heading_model_path("huge")
    assert default_heading_model_path("small") == default_heading_model_path("gated")  # former name


def test_keypoint_model_takes_the_classifiers_order():
    drone = CropSampler(SamplerConfig(negative_fraction=0.0), seed=3).sample()
    frame = np.full((256, 256, 3), 60, np.uint8)
    frame[56:184, 64:192] = drone.image  # a rendered drone crop, placed where the roi cuts it again
    roi = (64, 56, 128)
    plain = KeypointModel(threads=1, mirror_average=True, spread_calibration=SpreadCalibration())
    plain = plain.detect(frame, [roi])[0]
    heading = HeadingModel()
    model = KeypointModel(
        threads=1, mirror_average=True, heading_model=heading, spread_calibration=SpreadCalibration()
    )
    det = model.detect(frame, [roi])[0]
    assert det.presence > 0.5 and 0.5 <= det.heading_p <= 1.0
    # heading_p is the classifier's probability of the order returned: asked on that order it says
    # heading_p, or (when the network's order was the twin and was swapped) asked on the network's
    # order it says 1 - heading_p
    kp_norm = (det.keypoints_px - np.array(roi[:2]) + 0.5) / roi[2]
    crop = frame[roi[1] : roi[1] + 128, roi[0] : roi[0] + 128]
    p = heading(np.stack([crop, crop]), np.stack([kp_norm, kp_norm[HEADING_TWIN]]))
    assert p[0] == pytest.approx(det.heading_p, abs=1e-3) or 1 - p[1] == pytest.approx(
        det.heading_p, abs=1e-3
    )
    np.testing.assert_allclose(
        np.sort(det.keypoints_px, axis=0), np.sort(plain.keypoints_px, axis=0), atol=1e-3
    )  # the same four points, only their order may differ


def test_a_reading_is_classified_only_where_asked_and_as_detect_would():
    """``detect`` is ``finish(read(...))``; ``finish`` on a subset gives those crops' detections, and
    the patch classifiers see only the crops asked for (a crop cut again skips them on its first cut)."""
    drone = CropSampler(SamplerConfig(negative_fraction=0.0), seed=3).sample()
    frame = np.full((256, 320, 3), 60, np.uint8)
    frame[56:184, 64:192] = drone.image
    rois = [(64, 56, 128), (0, 0, 100), (60, 50, 140)]
    heading = HeadingModel()
    model = KeypointModel(threads=1, heading_model=heading, spread_calibration=SpreadCalibration())
    whole = model.detect(frame, rois)
    reading = model.read(frame, rois)
    assert [r.roi for r in model.rough(reading)] == rois and reading.presence.shape == (3,)
    seen = []
    inference = heading.inference
    heading.inference = lambda tensor: seen.append(len(tensor)) or inference(tensor)
    some = model.finish(reading, [2, 0])
    for a, b in zip(some, [whole[2], whole[0]], strict=True):
        assert (a.roi, a.presence, a.heading_p) == (b.roi, b.presence, b.heading_p)
        np.testing.assert_array_equal(a.keypoints_px, b.keypoints_px)
    assert model.finish(reading, []) == []
    assert seen == [sum(d.presence >= 0.3 for d in (whole[2], whole[0]))]  # those two crops at most
    assert model.detect(frame, []) == [] and model.finish(model.read(frame, [])) == []


def test_network_cpu_counts_the_network_and_its_classifiers():
    """``network_cpu_s`` (what ``dronekey-bench pipeline`` reads as the networks' share of a frame)
    grows with every ONNX Runtime call, the keypoint network's and the front/back classifier's."""
    drone = CropSampler(SamplerConfig(negative_fraction=0.0), seed=3).sample()
    heading = HeadingModel()
    model = KeypointModel(threads=1, heading_model=heading, spread_calibration=SpreadCalibration())
    assert model.network_cpu_s == 0.0
    for _ in range(3):
        (detection,) = model.detect(drone.image, [(0, 0, 128)])
    assert detection.presence >= 0.3  # so the classifier ran too
    assert model.inference_cpu_s > 0 and heading.inference_cpu_s > 0
    assert model.network_cpu_s == pytest.approx(model.inference_cpu_s + heading.inference_cpu_s)
