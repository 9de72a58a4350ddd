"""dronekey-calibrate-spread on a real render: the fit, the written model, the command's errors."""

from __future__ import annotations

import pytest

from dronekey.perception.keypoint_model import KeypointModel, default_model_path
from dronekey.sim_replay.io.render_output import write_sequence
from dronekey.sim_replay.synthetic_sequence import build_sequence
from dronekey.training.entry_points import calibrate_spread_main
from dronekey.training.spread_fit import fit_spread_calibration


@pytest.fixture(scope="module")
def seq13(tmp_path_factory):
    folder = tmp_path_factory.mktemp("seq13")
    return write_sequence(build_sequence("seq13", seed=3, frames=20), folder).json_path


def test_the_fit_corrects_the_networks_shortfall(seq13):
    fit = fit_spread_calibration(default_model_path(), [seq13], every=1, crops_per_frame=4, seed=1)
    assert fit.crops >= 50
    assert fit.calibration.intercept == 0.0 and fit.calibration.slope > 1.0  # the network reads drones small
    assert abs(fit.mean_error_fitted) < abs(fit.mean_error_raw)
    assert "of 1 sequences (" in fit.calibration.fitted_on


def test_the_command_writes_a_model_that_applies_it(seq13, tmp_path, capsys):
    out = tmp_path / "calibrated.onnx"
    assert calibrate_spread_main(["--sequences", str(seq13), "--every", "1", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("r = ") and str(out) in printed
    calibration = KeypointModel(out).spread_calibration
    assert calibration.slope > 1.0 and calibration.intercept == 0.0


def test_the_command_fits_the_aspect_term_when_asked(seq13, tmp_path, capsys):
    out = tmp_path / "aspect.onnx"
    argv = ["--sequences", str(seq13), "--every", "1", "--out", str(out), "--aspect-knee", "0.35"]
    assert calibrate_spread_main(argv) == 0
    calibration = KeypointModel(out).spread_calibration
    assert calibration.slope > 1.0 and calibration.aspect_knee in (0.0, 0.35)  # 0: the term added nothing
    if calibration.uses_aspect:
        assert calibration.aspect_slope > 0 and "max(0, 0.35 - aspect)" in capsys.readouterr().out
    with pytest.raises(ValueError, match=r"aspect_knee must be in \(0, 1\), got 1\.2"):
        fit_spread_calibration(default_model_path(), [seq13], aspect_knee=1.2)


def test_the_command_names_a_bad_input_in_one_line(tmp_path, capsys):
    assert (
        calibrate_spread_main(["--sequences", str(tmp_path / "none.json"), "--out", str(tmp_path / "m.onnx")])
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dronekey-calibrate-spread: ") and "none.json" in err[0]


def test_too_few_crops_is_an_error_that_says_so(seq13):
    with pytest.raises(ValueError, match="usable crops"):
        fit_spread_calibration(default_model_path(), [seq13], every=50, crops_per_frame=1)
