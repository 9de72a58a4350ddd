"""dronekey-calib on rendered boards with known intrinsics: chessboard, ChArUco, fisheye, a video, check.

Boards are rendered by inverse mapping: every output pixel (2x supersampled) is undistorted through
the true K and distortion to a ray, the ray is intersected with the board plane at a known pose,
and the board texture is sampled there; the supersampled frame is area-averaged down, slightly
blurred and given sensor noise. The recovered intrinsics must land within 0.5 % of the truth.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from dronekey.calib.cli import main
from dronekey.geometry.camera import CameraModel

W, H = 640, 480
SUPERSAMPLE = 2
TRUE_K = np.array([[600.0, 0.0, 322.4], [0.0, 603.0, 236.1], [0.0, 0.0, 1.0]])
TRUE_DIST = np.array([-0.18, 0.05, 0.0008, -0.0005, 0.0])
FISHEYE_K = np.array([[260.0, 0.0, 318.2], [0.0, 260.0, 241.7], [0.0, 0.0, 1.0]])
FISHEYE_DIST = np.array([0.05, -0.01, 0.004, -0.001])
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12)


# ---------------------------------------------------------------------------------------------- rendering
class Board:
    """A board texture (grey, pixels) and where the board frame's metres fall on it."""

    def __init__(self, texture: np.ndarray, origin_px: tuple[float, float], px_per_m: float, extent_m):
        self.texture = texture
        self.origin_px = origin_px  # texture pixel edge coordinate of the board-frame origin
        self.px_per_m = px_per_m
        self.extent_m = np.asarray(extent_m, dtype=np.float64)  # (x0, y0, x1, y1) to keep in view


def chessboard(cols: int, rows: int, square: float, px_per_square: int = 60) -> Board:
    """Inner corners cols x rows; board frame origin at the first inner corner."""
    margin = px_per_square
    tex = np.full(
        ((rows + 1) * px_per_square + 2 * margin, (cols + 1) * px_per_square + 2 * margin), 255, np.uint8
    )
    for i in range(rows + 1):
        for j in range(cols + 1):
            if (i + j) % 2 == 0:
                y0, x0 = margin + i * px_per_square, margin + j * px_per_square
                tex[y0 : y0 + px_per_square, x0 : x0 + px_per_square] = 0
    origin = (margin + px_per_square, margin + px_per_square)
    extent = (-1.5 * square, -1.5 * square, (cols + 0.5) * square, (rows + 0.5) * square)
    return Board(tex, origin, px_per_square / square, extent)


def charuco(cols: int, rows: int, square: float, marker: float, px_per_square: int = 60) -> Board:
    """ChArUco board of (cols + 1) x (rows + 1) squares, DICT_5X5_100, as OpenCV draws it."""
    board = cv2.aruco.CharucoBoard(
        (cols + 1, rows + 1), square, marker, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100)
    )
    margin = px_per_square // 2
    size = ((cols + 1) * px_per_square + 2 * margin, (rows + 1) * px_per_square + 2 * margin)
    tex = board.generateImage(size, marginSize=margin)
    extent = (-0.3 * square, -0.3 * square, (cols + 1.3) * square, (rows + 1.3) * square)
    return Board(tex, (margin, margin), px_per_square / square, extent)


def pixel_rays(K: np.ndarray, dist: np.ndarray, fisheye: bool) -> np.ndarray:
    """Normalised ray (x, y) of every supersampled pixel, shape (H*s, W*s, 2)."""
    s = SUPERSAMPLE
    Ks = K.copy()
    Ks[:2, :2] *= s
    Ks[0, 2], Ks[1, 2] = (K[0, 2] + 0.5) * s - 0.5, (K[1, 2] + 0.5) * s - 0.5
    u, v = np.meshgrid(np.arange(W * s, dtype=np.float64), np.arange(H * s, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    if fisheye:
        rays = cv2.fisheye.undistortPoints(pts, Ks, dist, criteria=_CRITERIA)
    else:
        rays = cv2.undistortPoints(pts, Ks, dist, None, None, None, _CRITERIA)
    return rays.reshape(H * s, W * s, 2)


def render(board: Board, rays: np.ndarray, rvec, tvec, rng: np.random.Generator) -> np.ndarray:
    """The board at pose (rvec, tvec) seen through the camera whose rays are given, uint8 (H, W)."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    Hinv = np.linalg.inv(np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, dtype=np.float64)]))
    x, y = rays[..., 0], rays[..., 1]
    wb = Hinv[2, 0] * x + Hinv[2, 1] * y + Hinv[2, 2]
    X = (Hinv[0, 0] * x + Hinv[0, 1] * y + Hinv[0, 2]) / wb
    Y = (Hinv[1, 0] * x + Hinv[1, 1] * y + Hinv[1, 2]) / wb
    map_x = (board.origin_px[0] + X * board.px_per_m - 0.5).astype(np.float32)
    map_y = (board.origin_px[1] + Y * board.px_per_m - 0.5).astype(np.float32)
    map_x[wb <= 0] = -1e6
    big = cv2.remap(
        board.texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=110
    )
    img = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 0.6)
    return np.clip(img + rng.normal(0.0, 1.5, img.shape), 0, 255).astype(np.uint8)


def _project(K, dist, fisheye, pts, rvec, tvec) -> np.ndarray:
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 1, 3)
    if fisheye:
        return cv2.fisheye.projectPoints(pts, rvec.reshape(3, 1), tvec.reshape(3, 1), K, dist)[0].reshape(
            -1, 2
        )
    return cv2.projectPoints(pts, rvec, tvec, K, dist)[0].reshape(-1, 2)


def board_pose(board: Board, K, dist, fisheye, target_uv, tilt_deg, roll_deg, depth) -> tuple | None:
    """A pose putting the board centre on pixel ``target_uv``, or None if the board leaves the image."""
    x0, y0, x1, y1 = board.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    R = (
        cv2.Rodrigues(np.radians([tilt_deg[0], tilt_deg[1], 0.0]))[0]
        @ cv2.Rodrigues(np.radians([0.0, 0.0, roll_deg]))[0]
    )
    if fisheye:
        ray = cv2.fisheye.undistortPoints(np.array([[target_uv]], dtype=np.float64), K, dist).reshape(2)
    else:
        ray = cv2.undistortPoints(np.array([[target_uv]], dtype=np.float64), K, dist).reshape(2)
    direction = np.array([ray[0], ray[1], 1.0])
    tvec = direction / np.linalg.norm(direction) * depth - R @ centre
    rvec = cv2.Rodrigues(R)[0].ravel()
    s = np.linspace(0.0, 1.0, 12)
    border = np.concatenate(
        [
            np.column_stack([x0 + s * (x1 - x0), np.full_like(s, y0)]),
            np.column_stack([x0 + s * (x1 - x0), np.full_like(s, y1)]),
            np.column_stack([np.full_like(s, x0), y0 + s * (y1 - y0)]),
            np.column_stack([np.full_like(s, x1), y0 + s * (y1 - y0)]),
        ]
    )
    border = np.column_stack([border, np.zeros(len(border))])
    # the board must stay in front of the camera and inside the frame (with 4 px to spare); the border
    # is sampled along its edges because a distorted edge bulges past its end points
    if np.any((R @ border.T).T[:, 2] + tvec[2] < 0.05):
        return None
    uv = _project(K, dist, fisheye, border, rvec, tvec)
    if np.any(uv < 4) or np.any(uv[:, 0] > W - 5) or np.any(uv[:, 1] > H - 5):
        return None
    return rvec, tvec


def render_set(board: Board, K, dist, fisheye: bool, count: int, seed: int, depth_range=(0.38, 0.6)):
    """``count`` views spread over the frame (corners, edges, centre), tilted 15-40 deg each way."""
    rng = np.random.default_rng(seed)
    rays = pixel_rays(K, dist, fisheye)
    spots = [(u, v) for v in (0.25, 0.5, 0.75) for u in (0.22, 0.5, 0.78)]
    images, tries = [], 0
    while len(images) < count:
        tries += 1
        assert tries < 400, "could not place the board"
        fu, fv = spots[len(images) % len(spots)]
        pull = max(0.0, 1.0 - 0.25 * (tries // 40))  # a spot the board cannot reach moves toward the centre
        target = (
            W * (0.5 + pull * (fu - 0.5)) + rng.uniform(-30, 30),
            H * (0.5 + pull * (fv - 0.5)) + rng.uniform(-25, 25),
        )
        sign = rng.choice([-1.0, 1.0], size=2)
        tilt = sign * rng.uniform(15, 40, size=2) * np.array([1.0, 1.0] if len(images) % 3 else [1.0, 0.3])
        pose = board_pose(
            board, K, dist, fisheye, target, tilt, rng.uniform(-20, 20), rng.uniform(*depth_range)
        )
        if pose is not None:
            images.append(render(board, rays, *pose, rng))
            tries = 0
    return images


def write_images(folder: Path, images) -> str:
    folder.mkdir(parents=True, exist_ok=True)
    for k, img in enumerate(images):
        cv2.imwrite(str(folder / f"view{k:02d}.png"), img)
    return str(folder / "*.png")


def run_json(capsys, argv) -> dict:
    rc = main([*argv, "--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    return json.loads(out)


def assert_intrinsics_close(result: dict, K: np.ndarray, rel: float = 0.005) -> None:
    for key, true in (("fx", K[0, 0]), ("fy", K[1, 1]), ("cx", K[0, 2]), ("cy", K[1, 2])):
        assert abs(result[key] - true) / true < rel, f"{key} {result[key]:.3f} vs true {true:.3f}"


def distortion_gap_px(K_true, d_true, d_est, fisheye: bool, reach: float = 0.85) -> float:
    """Largest pixel gap between the true and estimated distortion, over the image out to ``reach``.

    Both distortions are applied to the same normalised rays (those of a pixel grid under the true
    camera, out to ``reach`` of the half diagonal, where the boards were seen) and compared in pixels
    of the true focal length; principal point and focal errors are assessed separately.
    """
    u, v = np.meshgrid(np.linspace(0, W - 1, 17), np.linspace(0, H - 1, 13))
    pts = np.stack([u.ravel(), v.ravel()], axis=1)
    radius = np.hypot((pts[:, 0] - W / 2) / (W / 2), (pts[:, 1] - H / 2) / (H / 2)) / math.sqrt(2)
    pts = pts[radius <= reach].reshape(-1, 1, 2)
    if fisheye:
        rays = cv2.fisheye.undistortPoints(pts, K_true, d_true, criteria=_CRITERIA).reshape(-1, 2)
    else:
        rays = cv2.undistortPoints(pts, K_true, d_true, None, None, None, _CRITERIA).reshape(-1, 2)
    xyz = np.column_stack([rays, np.ones(len(rays))])
    zero = np.zeros(3)
    a = _project(np.eye(3), np.asarray(d_true, dtype=np.float64), fisheye, xyz, zero, zero)
    b = _project(np.eye(3), np.asarray(d_est, dtype=np.float64), fisheye, xyz, zero, zero)
    return float(np.linalg.norm(a - b, axis=1).max() * K_true[0, 0])


# ---------------------------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def chess_glob(tmp_path_factory) -> str:
    images = render_set(chessboard(9, 6, 0.025), TRUE_K, TRUE_DIST, False, count=14, seed=3)
    return write_images(tmp_path_factory.mktemp("chess"), images)


CHESS = ["--pattern", "chessboard", "--cols", "9", "--rows", "6", "--square", "0.025"]
CHARUCO = ["--pattern", "charuco", "--cols", "5", "--rows", "4", "--square", "0.03", "--marker", "0.021"]


# ---------------------------------------------------------------------------------------------- tests
def test_chessboard_recovers_known_intrinsics(chess_glob, tmp_path, capsys):
    out = tmp_path / "cam.yaml"
    result = run_json(capsys, ["--images", chess_glob, *CHESS, "--out", str(out)])
    assert result["views_used"] == 14 and result["rejected"] == []
    assert_intrinsics_close(result, TRUE_K)
    assert result["rms_px"] < 0.15
    cam = CameraModel.load(out)
    assert distortion_gap_px(TRUE_K, TRUE_DIST, cam.dist, False) < 0.5
    assert np.allclose(cam.K, [[result["fx"], 0, result["cx"]], [0, result["fy"], result["cy"]], [0, 0, 1]])


def test_charuco_recovers_known_intrinsics(tmp_path, capsys):
    # ChArUco corners are refined in the white gap around the markers: squares of 40-60 px in view
    board = charuco(5, 4, 0.03, 0.021)
    images = render_set(board, TRUE_K, TRUE_DIST, False, count=12, seed=5, depth_range=(0.33, 0.45))
    # a board partly out of view still counts: hide the right 40 % of the board in one view
    columns = np.flatnonzero(np.abs(images[0].astype(int) - 110).max(axis=0) > 40)
    images[0] = images[0].copy()
    images[0][:, int(columns.min() + 0.6 * (columns.max() - columns.min())) :] = 110
    pattern = write_images(tmp_path / "charuco", images)
    result = run_json(capsys, ["--images", pattern, *CHARUCO, "--out", str(tmp_path / "cam.yaml")])
    assert result["views_used"] == 12
    assert_intrinsics_close(result, TRUE_K)
    cam = CameraModel.load(tmp_path / "cam.yaml")
    # this larger board stays further from the frame's corners: judge the distortion where it was seen
    assert distortion_gap_px(TRUE_K, TRUE_DIST, cam.dist, False, reach=0.7) < 0.5


def test_fisheye_recovers_known_intrinsics(tmp_path, capsys):
    images = render_set(
        chessboard(9, 6, 0.025), FISHEYE_K, FISHEYE_DIST, True, count=12, seed=7, depth_range=(0.2, 0.3)
    )
    pattern = write_images(tmp_path / "fish", images)
    out = tmp_path / "fish.yaml"
    result = run_json(capsys, ["--images", pattern, *CHESS, "--fisheye", "--out", str(out)])
    assert len(result["dist"]) == 4
    assert_intrinsics_close(result, FISHEYE_K)
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    assert int(fs.getNode("fisheye_model").real()) == 1
    fs.release()
    assert distortion_gap_px(FISHEYE_K, FISHEYE_DIST, np.array(result["dist"]), True) < 0.5


def test_fixed_flags_hold_their_parameters(chess_glob, tmp_path, capsys):
    result = run_json(
        capsys,
        [
            "--images",
            chess_glob,
            *CHESS,
            "--fix-aspect",
            "--fix-principal-point",
            "--zero-tangent",
            "--fix-k3",
            "--out",
            str(tmp_path / "cam.yaml"),
        ],
    )
    assert result["fx"] == pytest.approx(result["fy"], rel=1e-12)
    assert (result["cx"], result["cy"]) == ((W - 1) / 2, (H - 1) / 2)
    assert result["dist"][2:] == [0.0, 0.0, 0.0]
    # the truth has fx/fy = 600/603: the fixed-aspect fit still lands between them
    assert 598.0 < result["fx"] < 605.0


def test_check_against_true_and_wrong_calibration(chess_glob, tmp_path, capsys):
    truth = tmp_path / "truth.yaml"
    CameraModel(W, H, TRUE_K, TRUE_DIST, 0.1).save_yaml(truth)
    rc = main(["check", "--calib", str(truth), "--images", chess_glob, *CHESS, "--json"])
    good = json.loads(capsys.readouterr().out)
    assert rc == 0 and good["views_used"] == 14 and good["rms_px"] < 0.15

    wrong = tmp_path / "wrong.yaml"
    K = TRUE_K.copy()
    K[0, 0] *= 1.03
    K[1, 1] *= 1.03
    CameraModel(W, H, K, np.zeros(5), 0.1).save_yaml(wrong)
    rc = main(["check", "--calib", str(wrong), "--images", chess_glob, *CHESS, "--max-rms", "0.5"])
    out, err = capsys.readouterr()
    assert rc == 3
    assert "does not fit" in out and "exceeds --max-rms 0.5" in err

    # a calibration at twice the resolution is scaled down to the pictures' size
    double = tmp_path / "double.yaml"
    CameraModel(W, H, TRUE_K, TRUE_DIST, 0.1).scaled_to(2 * W, 2 * H).save_yaml(double)
    assert main(["check", "--calib", str(double), "--images", chess_glob, *CHESS, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["rms_px"] == pytest.approx(good["rms_px"], abs=1e-6)


def test_video_picks_sharp_diverse_views(tmp_path, capsys):
    board = chessboard(9, 6, 0.025)
    rng = np.random.default_rng(11)
    rays = pixel_rays(TRUE_K, TRUE_DIST, False)
    path = tmp_path / "wave.mkv"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (W, H), False)
    assert writer.isOpened()
    frames = 72
    for k in range(frames):
        phase = 2 * math.pi * k / frames
        target = (W / 2 + 0.28 * W * math.cos(phase), H / 2 + 0.25 * H * math.sin(2 * phase))
        tilt = (30 * math.sin(phase), 30 * math.cos(phase))
        pose = None
        for shrink in np.linspace(1.0, 0.0, 6):  # pull toward the centre until the board fits
            t = (W / 2 + shrink * (target[0] - W / 2), H / 2 + shrink * (target[1] - H / 2))
            pose = board_pose(board, TRUE_K, TRUE_DIST, False, t, tilt, 10 * math.sin(3 * phase), 0.5)
            if pose is not None:
                break
        assert pose is not None
        frame = render(board, rays, *pose, rng)
        if k % 6 == 2:  # motion blur: these frames must not be picked
            frame = cv2.filter2D(frame, -1, np.full((1, 15), 1 / 15.0))
        writer.write(frame)
    writer.release()

    out = tmp_path / "cam.yaml"
    result = run_json(
        capsys, ["--video", str(path), *CHESS, "--frames", "36", "--max-views", "14", "--out", str(out)]
    )
    assert 8 <= result["views_used"] <= 14
    assert_intrinsics_close(result, TRUE_K)
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    views = fs.getNode("views")
    names = [views.at(i).string() for i in range(views.size())]
    fs.release()
    indices = [int(n.split("#")[1]) for n in names]
    assert all(n.startswith("wave.mkv#") for n in names)
    assert all(i % 2 == 0 for i in indices), "--frames 36 of 72 examines every second frame"
    assert not any(i % 6 == 2 for i in indices), f"a blurred frame was picked: {indices}"
    assert max(indices) - min(indices) > frames / 2, f"views bunched in time: {indices}"
