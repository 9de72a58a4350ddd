"""Geometry core: camera model, rotations, drone specs, crops."""

import cv2
import numpy as np
import paths
import pytest
from scipy.spatial.transform import Rotation

from dronekey.geometry.apparent_size import keypoint_spread
from dronekey.geometry.camera import CalibrationError, CameraModel
from dronekey.geometry.crop import CropPolicy, crop_square, from_normalised, to_normalised
from dronekey.geometry.drone_spec import DroneSpecError, load_spec
from dronekey.geometry.rotations import (
    canonical_quat,
    geodesic_angle_deg,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
    rotation_from_euler_deg,
)

SHARED_CALIB = paths.DATA / "calib-real" / "reference_right.xml"


def test_project_and_undistort_roundtrip():
    cam = CameraModel.from_fov(1920, 1080, 70.0, dist=[-0.12, 0.05, 0.001, -0.0005, 0.0])
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-1.5, 1.5, (50, 2)), rng.uniform(3, 8, 50)]
    uv = cam.project(pts)
    ideal = cam.undistort_points(uv)
    expected = (cam.K @ (pts / pts[:, 2:]).T).T[:, :2]
    assert np.abs(ideal - expected).max() < 1e-6


def test_scale_intrinsics_roundtrip_and_pixel_centres():
    cam = CameraModel.from_fov(1920, 1080, 70.0, dist=[-0.1, 0.02, 0, 0, 0])
    half = cam.scaled_to(960, 540)
    back = half.scaled_to(1920, 1080)
    assert np.allclose(back.K, cam.K, atol=1e-9)
    # The same 3D point lands on the same spot of the picture at both resolutions.
    p = np.array([[0.3, -0.2, 4.0]])
    u_full, u_half = cam.project(p)[0], half.project(p)[0]
    assert np.allclose((u_full + 0.5) / 2 - 0.5, u_half, atol=1e-9)


def test_scale_refuses_other_aspect_ratio():
    cam = CameraModel.from_fov(1920, 1080, 70.0)
    with pytest.raises(CalibrationError, match="aspect ratio"):
        cam.scaled_to(640, 480)


def test_camera_yaml_roundtrip(tmp_path):
    cam = CameraModel.from_fov(1280, 720, 60.0, dist=[-0.1, 0.01, 0.0, 0.0, 0.002])
    cam.save_yaml(tmp_path / "camera.yaml")
    text = (tmp_path / "camera.yaml").read_text()
    assert text.startswith("%YAML") and "camera_matrix" in text
    loaded = CameraModel.load(tmp_path / "camera.yaml")
    assert loaded.size == (1280, 720)
    assert np.allclose(loaded.K, cam.K) and np.allclose(loaded.dist, cam.dist)


def test_load_reference_xml_with_suffixed_keys():
    cam = CameraModel.load(SHARED_CALIB)
    assert cam.size == (640, 512)
    assert cam.fx == pytest.approx(512.17068744744154)
    assert cam.rms_px == pytest.approx(0.10834546667739016)


def test_load_bad_calibration(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        CameraModel.load(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("%YAML:1.0\n---\nfoo: 1\n")
    with pytest.raises(CalibrationError, match="camera_matrix"):
        CameraModel.load(bad)


def test_quaternion_roundtrip_and_sign():
    rng = np.random.default_rng(1)
    for _ in range(100):
        R = rotation_from_euler_deg(*rng.uniform(-180, 180, 3))
        q = matrix_to_quat_wxyz(R)
        assert q[0] >= 0 and np.isclose(np.linalg.norm(q), 1)
        assert np.allclose(quat_wxyz_to_matrix(q), R, atol=1e-12)
        assert np.allclose(quat_wxyz_to_matrix(-q), R, atol=1e-12)


def test_quaternion_same_bits_as_scipys_checked_conversion():
    """``matrix_to_quat_wxyz`` skips scipy's rotation check where a stricter one passes: the
    quaternion must be the checked conversion's to the bit, for clean rotations and for ones a
    long filter run has pushed off orthogonality (those get scipy's repair)."""
    rng = np.random.default_rng(2)
    for k in range(300):
        R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        if k % 2:
            R = R + rng.normal(0.0, 10.0 ** rng.uniform(-15, -8), (3, 3))
        xyzw = Rotation.from_matrix(R).as_quat()
        checked = canonical_quat(np.array([xyzw[3], *xyzw[:3]]))
        assert np.array_equal(matrix_to_quat_wxyz(R), checked)
    with pytest.raises(ValueError, match="determinant"):
        matrix_to_quat_wxyz(-np.eye(3))


def test_keypoint_spread_is_the_longest_pair_to_the_bit():
    rng = np.random.default_rng(3)
    for _ in range(500):
        kp = rng.uniform(-50.0, 2000.0, (4, 2)) * rng.uniform(1e-3, 1.0)
        longest = max(np.linalg.norm(kp[i] - kp[j]) for i in range(4) for j in range(i + 1, 4))
        assert keypoint_spread(kp) == float(longest)
    assert keypoint_spread(np.zeros((4, 2))) == 0.0


def test_extent_points_ring_each_disc_and_are_shared_read_only():
    spec = load_spec("mini2")
    points = spec.extent_points_m
    assert points.shape == (36, 3) and not points.flags.writeable
    assert spec.extent_points_m is points  # computed once per spec
    radius = spec.prop_diameter_m / 2
    for k, hub in enumerate(spec.keypoints_3d):
        assert np.allclose(np.linalg.norm(points[8 * k : 8 * k + 8] - hub, axis=1), radius)
    assert np.all(points[32:, 2] > 0)  # the body's box hangs below the hubs (z down)


def test_geodesic_angle():
    R = rotation_from_euler_deg(30, 0, 0)
    assert geodesic_angle_deg(np.eye(3), R) == pytest.approx(30.0)
    assert geodesic_angle_deg(R, R) == pytest.approx(0.0, abs=1e-6)
    assert geodesic_angle_deg(np.eye(3), rotation_from_euler_deg(180, 0, 0)) == pytest.approx(180.0)


@pytest.mark.parametrize("name,diagonal", [("mini2", 0.213), ("air2s", 0.302)])
def test_shipped_specs(name, diagonal):
    spec = load_spec(name)
    kp = spec.keypoints_3d
    assert spec.diagonal_m == pytest.approx(diagonal, abs=1e-4)
    assert np.allclose(kp.mean(axis=0), 0)
    # 1 front-right, 2 rear-right, 3 rear-left, 4 front-left in FRD.
    assert kp[0, 0] > 0 and kp[0, 1] > 0 and kp[1, 0] < 0 and kp[1, 1] > 0
    assert kp[2, 0] < 0 and kp[2, 1] < 0 and kp[3, 0] > 0 and kp[3, 1] < 0
    # Clockwise seen from above (looking along +z, down): signed area in (x, y) is negative
    # for x forward/y right when walking 1 -> 2 -> 3 -> 4.
    x, y = kp[:, 0], kp[:, 1]
    signed_area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    assert signed_area > 0  # positive in the right-handed (x fwd, y right) plane = clockwise from above
    assert "diagonal_wheelbase" in spec.sources


def test_spec_errors(tmp_path):
    with pytest.raises(DroneSpecError, match="unknown drone spec"):
        load_spec("phantom9")
    bad = tmp_path / "x.yaml"
    bad.write_text("name: x\nkeypoints_3d: [[0, 0, 0]]\n")
    with pytest.raises(DroneSpecError, match="4 x 3"):
        load_spec(bad)


def test_crop_mapping_is_exact():
    img = np.zeros((300, 400, 3), np.uint8)
    img[150, 220] = 255  # a single bright pixel at u=220, v=150
    policy = CropPolicy(input_size=64)
    roi = policy.roi((200, 130, 40, 40))
    crop = crop_square(img, roi, 128)  # upsampled x ~2.5
    n = to_normalised(np.array([[220.0, 150.0]]), roi)
    peak = np.unravel_index(np.argmax(crop[..., 0]), crop.shape[:2])
    assert abs((peak[1] + 0.5) / 128 - n[0, 0]) < 1.0 / 128
    assert abs((peak[0] + 0.5) / 128 - n[0, 1]) < 1.0 / 128
    assert np.allclose(from_normalised(n, roi), [[220.0, 150.0]])


def test_crop_outside_frame_is_black():
    img = np.full((100, 100, 3), 200, np.uint8)
    crop = crop_square(img, (-50, -50, 100), 50)
    assert crop[:20, :20].max() == 0 and crop[-10:, -10:].min() == 200


def test_load_refuses_fisheye_unless_allowed(tmp_path):
    path = tmp_path / "fish.yaml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 640)
    fs.write("image_height", 480)
    fs.write("fisheye_model", 1)
    fs.write("camera_matrix", np.array([[300.0, 0, 320], [0, 300, 240], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array([[0.1, 0.01, 0.0, 0.0]]))
    fs.release()
    with pytest.raises(CalibrationError, match="fisheye"):
        CameraModel.load(path)
    assert CameraModel.load(path, allow_fisheye=True).dist.size == 4
