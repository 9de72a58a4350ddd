"""The spread calibration: the keypoints' size de-compressed about their centroid, carried by the model."""

from __future__ import annotations

import numpy as np
import pytest

from dronekey.perception.keypoint_model import KeypointModel, ModelFormatError, default_model_path
from dronekey.perception.plausibility import check_detection
from dronekey.perception.spread_calibration import SpreadCalibration, keypoint_aspect, normalised_spread
from dronekey.types import KeypointDetection

SQUARE = np.array([[[0.3, 0.3], [0.3, 0.7], [0.7, 0.7], [0.7, 0.3]]], np.float32)  # spread 0.566


def test_apply_scales_about_the_centroid_to_the_calibrated_spread():
    calibration = SpreadCalibration(intercept=-0.5, slope=2.5)
    out, scale = calibration.apply(SQUARE)
    q = float(normalised_spread(SQUARE)[0])
    assert normalised_spread(out)[0] == pytest.approx(-0.5 + 2.5 * q, rel=1e-5)
    assert scale[0] == pytest.approx((-0.5 + 2.5 * q) / q, rel=1e-5)
    np.testing.assert_allclose(out.mean(axis=1), SQUARE.mean(axis=1), atol=1e-6)  # where it sits is kept
    same, ones = SpreadCalibration().apply(SQUARE)
    assert np.array_equal(same, SQUARE) and np.array_equal(ones, [1.0])
    collapsed = np.full((1, 4, 2), 0.5, np.float32)
    assert np.array_equal(calibration.apply(collapsed)[0], collapsed)  # nothing to scale


def test_an_edge_on_drone_is_grown_more_than_a_square_one_below_the_aspect_knee():
    # An edge-on drone: two hubs nearly in line, its shortest pair 0.18 of the longest.
    edge_on = np.array([[[0.2, 0.5], [0.45, 0.52], [0.8, 0.5], [0.55, 0.48]]], np.float32)
    a = float(keypoint_aspect(edge_on)[0])
    assert a == pytest.approx(0.1795, abs=1e-3) and keypoint_aspect(SQUARE)[0] == pytest.approx(0.7071, 1e-4)
    calibration = SpreadCalibration(0.0, 1.04, "", aspect_knee=0.35, aspect_slope=0.6)
    (_, square_scale), (_, edge_scale) = calibration.apply(SQUARE), calibration.apply(edge_on)
    assert square_scale[0] == pytest.approx(1.04)  # above the knee: the factor alone
    assert edge_scale[0] == pytest.approx(1.04 + 0.6 * (0.35 - a), rel=1e-4)
    assert not calibration.is_identity and calibration.uses_aspect
    kept = SpreadCalibration.from_metadata({"spread_calibration": calibration.to_metadata()})
    assert kept == calibration
    # A calibration written before the aspect term reads as a factor alone, and writes as before.
    old = SpreadCalibration.from_metadata({"spread_calibration": '{"intercept": 0.0, "slope": 1.04}'})
    assert old == SpreadCalibration(0.0, 1.04) and "aspect" not in old.to_metadata()
    assert np.isnan(keypoint_aspect(np.full((1, 4, 2), 0.5))[0])  # collapsed: no aspect


def test_bad_calibrations_name_what_is_wrong():
    with pytest.raises(ValueError, match=r"aspect_knee in \[0, 1\)"):
        SpreadCalibration(0.0, 1.0, "", aspect_knee=1.5, aspect_slope=0.1)
    with pytest.raises(ValueError, match="aspect_slope >= 0"):
        SpreadCalibration(0.0, 1.0, "", aspect_knee=0.3, aspect_slope=-0.1)
    with pytest.raises(ValueError, match="slope > 0"):
        SpreadCalibration(0.0, 0.0)
    with pytest.raises(ValueError, match="'spread_calibration' must hold intercept and slope"):
        SpreadCalibration.from_metadata({"spread_calibration": {"slope": 1.0}})
    with pytest.raises(ValueError, match="not JSON"):
        SpreadCalibration.from_metadata({"spread_calibration": "{"})
    assert SpreadCalibration.from_metadata({}).is_identity


def test_the_model_applies_its_own_calibration_and_says_by_how_much(tmp_path):
    from dronekey.training.spread_fit import write_calibrated_model

    frame = np.random.default_rng(0).integers(0, 255, (480, 640, 3), dtype=np.uint8)
    rois = [(100, 100, 128), (300, 200, 200)]
    plain = KeypointModel(spread_calibration=SpreadCalibration())
    path = write_calibrated_model(default_model_path(), tmp_path / "m.onnx", SpreadCalibration(0.05, 0.8))
    model = KeypointModel(path)
    assert model.spread_calibration == SpreadCalibration(0.05, 0.8)
    for a, b, roi in zip(plain.detect(frame, rois), model.detect(frame, rois), rois, strict=True):
        q = normalised_spread(a.keypoints_px[None])[0] / roi[2]
        assert b.spread_scale == pytest.approx((0.05 + 0.8 * q) / q, rel=1e-4)
        assert normalised_spread(b.keypoints_px[None])[0] == pytest.approx(
            b.spread_scale * q * roi[2], rel=1e-4
        )
        assert b.presence == a.presence and b.heading_p == a.heading_p


def test_a_malformed_calibration_in_the_model_is_a_format_error(tmp_path):
    import onnx

    model = onnx.load(str(default_model_path()))
    model.metadata_props.add(key="spread_calibration", value='{"intercept": 0.1}')
    onnx.save(model, str(tmp_path / "bad.onnx"))
    with pytest.raises(ModelFormatError, match=r"bad\.onnx: metadata 'spread_calibration' must hold"):
        KeypointModel(tmp_path / "bad.onnx")


def test_the_gate_reads_the_networks_own_spread_not_the_calibrated_one():
    side = 200
    kp = np.array([[60.0, 60.0], [60.0, 140.0], [140.0, 140.0], [140.0, 60.0]])  # spread 0.566 of the side
    plausible = KeypointDetection(kp, 0.99, (0, 0, side), 0.5, spread_scale=1.0)
    assert check_detection(plausible, (1920, 1080)) is None
    # The same keypoints, which the calibration grew 1.6x: the network itself said 0.35 of the side,
    # below the gate's floor (clutter re-cut on itself reads smaller).
    grown = KeypointDetection(kp, 0.99, (0, 0, side), 0.5, spread_scale=1.6)
    assert "keypoint spread 0.35 of the crop side" in check_detection(grown, (1920, 1080))
