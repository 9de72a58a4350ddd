"""dronekey-calib on 25 real images of an asymmetric circle grid, against OpenCV's own reference result.

tests/data/calib-real/reference_right.xml is the result of OpenCV's C++ calibration sample on these
images with fixed aspect ratio, principal point fixed at (320, 256), zero tangential distortion and
k4 = k5 = 0: RMS 0.1083 px. With the same flags the tool must land within 0.01 px RMS and 0.5 % fx.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import paths
import pytest

from dronekey.calib.calibrate import CalibrationOptions, calibrate
from dronekey.calib.cli import main
from dronekey.calib.patterns import BoardDetector, BoardPattern
from dronekey.calib.sources import read_gray
from dronekey.calib.views import BoardView
from dronekey.geometry.camera import CameraModel

DATA = paths.DATA / "calib-real"
GLOB = str(DATA / "right*.jpg")
BOARD = ["--pattern", "acircles", "--cols", "4", "--rows", "11", "--square", "0.02"]
REFERENCE_FLAGS = ["--fix-aspect", "--fix-principal-point", "--zero-tangent", "--fix-k4", "--fix-k5"]
REFERENCE_OPTIONS = CalibrationOptions(
    fix_aspect=True,
    fix_principal_point=True,
    principal_point=(320.0, 256.0),
    zero_tangent=True,
    fix_k4=True,
    fix_k5=True,
)


@pytest.fixture(scope="module")
def reference() -> dict:
    fs = cv2.FileStorage(str(DATA / "reference_right.xml"), cv2.FILE_STORAGE_READ)
    try:
        ref = {
            "K": fs.getNode("camera_matrix_right").mat(),
            "dist": fs.getNode("distortion_coefficients_right").mat().ravel(),
            "rms": fs.getNode("avg_reprojection_error_right").real(),
            "per_view": fs.getNode("per_view_reprojection_errors_right").mat().ravel(),
            "points": fs.getNode("image_points_right").mat().reshape(25, 44, 2),
            "flags": int(fs.getNode("flags").real()),
        }
    finally:
        fs.release()
    return ref


def _run(capsys, argv: list[str]) -> tuple[int, str, str]:
    rc = main(argv)
    out, err = capsys.readouterr()
    return rc, out, err


@pytest.mark.parametrize(
    ("principal_point", "rms_tol"),
    [(["--principal-point", "320", "256"], 0.001), ([], 0.01)],
    ids=["reference-principal-point", "image-centre"],
)
def test_reference_flags_match_opencv_reference(reference, tmp_path, capsys, principal_point, rms_tol):
    out = tmp_path / "camera.yaml"
    rc, stdout, err = _run(
        capsys, ["--images", GLOB, *BOARD, *REFERENCE_FLAGS, *principal_point, "--out", str(out), "--json"]
    )
    assert rc == 0, err
    result = json.loads(stdout)
    assert set(result) == {"views_used", "rms_px", "fx", "fy", "cx", "cy", "dist", "per_view_rms", "rejected"}
    assert result["views_used"] == 25 and result["rejected"] == []
    ref_fx = reference["K"][0, 0]
    assert abs(result["rms_px"] - reference["rms"]) < rms_tol
    assert abs(result["fx"] - ref_fx) / ref_fx < 0.005
    assert result["fy"] == result["fx"]
    expected_pp = (320.0, 256.0) if principal_point else (319.5, 255.5)
    assert (result["cx"], result["cy"]) == expected_pp
    assert result["dist"][2:4] == [0.0, 0.0]
    assert len(result["per_view_rms"]) == 25
    # the file the daemon reads
    camera = CameraModel.load(out)
    assert camera.size == (640, 512)
    assert camera.fx == pytest.approx(result["fx"]) and camera.rms_px == pytest.approx(result["rms_px"])
    np.testing.assert_allclose(camera.dist, result["dist"])
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("flags").real()) & reference["flags"] == reference["flags"]
    assert int(fs.getNode("fisheye_model").real()) == 0
    assert fs.getNode("per_view_reprojection_errors").mat().shape == (25, 1)
    assert fs.getNode("views").at(0).string() == "right01.jpg"
    fs.release()
    coverage = cv2.imread(str(tmp_path / "camera.coverage.png"))
    assert coverage is not None and coverage.shape[1] == 960


def test_detected_circles_match_reference_points(reference):
    detector = BoardDetector(BoardPattern("acircles", 4, 11, 0.02))
    gaps = []
    for k in range(25):
        view = detector.detect(read_gray(DATA / f"right{k + 1:02d}.jpg"))
        assert view is not None, f"right{k + 1:02d}.jpg"
        gaps.append(np.linalg.norm(view.image_points - reference["points"][k], axis=1))
    gaps = np.concatenate(gaps)
    assert np.median(gaps) < 0.05 and gaps.max() < 0.3


def test_calibration_of_reference_points_reproduces_reference(reference):
    """The calibration itself, fed OpenCV's own detected points, gives OpenCV's own result."""
    grid = BoardPattern("acircles", 4, 11, 0.02).object_points() * 1000.0  # the reference is in mm
    views = [BoardView(reference["points"][k].astype(np.float32), grid) for k in range(25)]
    result = calibrate(views, [f"view{k}" for k in range(25)], (640, 512), REFERENCE_OPTIONS)
    np.testing.assert_allclose(result.camera.K, reference["K"], rtol=1e-7)
    np.testing.assert_allclose(result.camera.dist, reference["dist"], atol=1e-6)
    assert result.rms == pytest.approx(reference["rms"], abs=1e-7)
    np.testing.assert_allclose(result.per_view_rms, reference["per_view"], atol=1e-5)  # stored as float32


def test_summary_gives_figures_files_and_advice(tmp_path, capsys):
    out = tmp_path / "cam.yaml"
    rc, stdout, err = _run(capsys, ["--images", GLOB, *BOARD, *REFERENCE_FLAGS, "--out", str(out)])
    assert rc == 0, err
    assert "25 views" in stdout and "RMS reprojection error" in stdout
    assert f"wrote {out}" in stdout and f"wrote {tmp_path / 'cam.coverage.png'}" in stdout
    # the real set keeps the board in the middle of the sensor: the advice says so
    assert "hold the board near the edges and corners" in stdout
    assert "never near the right edge" in stdout


def test_check_real_images_against_the_calibration(tmp_path, capsys):
    out = tmp_path / "cam.yaml"
    assert _run(capsys, ["--images", GLOB, *BOARD, *REFERENCE_FLAGS, "--out", str(out), "--json"])[0] == 0
    rc, stdout, err = _run(
        capsys, ["check", "--calib", str(out), "--images", str(DATA / "right1*.jpg"), *BOARD, "--json"]
    )
    assert rc == 0, err
    result = json.loads(stdout)
    assert result["views_used"] == 10
    # six pose parameters per view fitted instead of all of them: about the calibration's own error
    assert result["rms_px"] < 2 * result["calibration_rms_px"]
    # the reference file itself (a stereo rig's right camera, keys suffixed _right) loads and fits too
    rc, stdout, err = _run(
        capsys, ["check", "--calib", str(DATA / "reference_right.xml"), "--images", GLOB, *BOARD, "--json"]
    )
    assert rc == 0, err
    assert json.loads(stdout)["rms_px"] < 0.15


def test_outlier_view_is_left_out_and_named(tmp_path, capsys):
    """A view of a bent board (here: an image warped by a 4 px ripple) is left out and named."""
    for path in sorted(DATA.glob("right*.jpg"))[:12]:
        (tmp_path / path.name).write_bytes(path.read_bytes())
    image = cv2.imread(str(tmp_path / "right05.jpg"), cv2.IMREAD_GRAYSCALE)
    ys, xs = np.mgrid[0 : image.shape[0], 0 : image.shape[1]].astype(np.float32)
    rippled = cv2.remap(image, xs + 4.0 * np.sin(2 * np.pi * ys / 200.0), ys, cv2.INTER_LINEAR)
    cv2.imwrite(str(tmp_path / "right05.png"), rippled)
    (tmp_path / "right05.jpg").unlink()
    rc, stdout, err = _run(
        capsys, ["--images", str(tmp_path / "right*"), *BOARD, "--out", str(tmp_path / "c.yaml"), "--json"]
    )
    assert rc == 0, err
    result = json.loads(stdout)
    assert result["views_used"] == 11
    assert [r["view"] for r in result["rejected"]] == ["right05.png"]
    assert result["rejected"][0]["reason"].startswith("outlier")
    assert result["rms_px"] < 0.2
