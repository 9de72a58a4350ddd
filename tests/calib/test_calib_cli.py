"""dronekey-calib on bad input: one clear line on stderr and a non-zero exit, never a traceback."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import paths
import pytest

from dronekey.calib.cli import main

DATA = paths.DATA / "calib-real"
BOARD = ["--pattern", "acircles", "--cols", "4", "--rows", "11", "--square", "0.02"]
CHARUCO_5X4 = ["--pattern", "charuco", "--cols", "5", "--rows", "4", "--square", "0.03"]


def _fails(capsys, argv: list[str], expected_rc: int = 1) -> str:
    """Run the CLI expecting failure; return its single stderr line."""
    rc = main(argv)
    out, err = capsys.readouterr()
    assert rc == expected_rc, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("dronekey-calib") and "error" in lines[0]
    assert "Traceback" not in err and out == ""
    return lines[0]


def _copy_real(folder: Path, count: int) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for path in sorted(DATA.glob("right*.jpg"))[:count]:
        (folder / path.name).write_bytes(path.read_bytes())


def _frontal_chessboard(cols: int, rows: int, square_px: int = 40) -> np.ndarray:
    """A fronto-parallel chessboard of cols x rows inner corners on a white page."""
    page = np.full(((rows + 3) * square_px, (cols + 3) * square_px), 255, np.uint8)
    for i in range(rows + 1):
        for j in range(cols + 1):
            if (i + j) % 2 == 0:
                y, x = (i + 1) * square_px, (j + 1) * square_px
                page[y : y + square_px, x : x + square_px] = 0
    return cv2.GaussianBlur(page, (0, 0), 0.8)


def test_no_file_matches(capsys, tmp_path):
    line = _fails(capsys, ["--images", str(tmp_path / "*.png"), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "no files match --images" in line


def test_unreadable_file_is_named(capsys, tmp_path):
    _copy_real(tmp_path, 6)
    (tmp_path / "right99.jpg").write_bytes(b"not a jpeg at all")
    line = _fails(capsys, ["--images", str(tmp_path / "*.jpg"), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "cannot read" in line and "right99.jpg" in line


def test_no_board_in_any_image(capsys, tmp_path):
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"empty{k}.png"), rng.integers(100, 140, (240, 320), dtype=np.uint8))
    line = _fails(capsys, ["--images", str(tmp_path / "*.png"), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "no acircles 4x11, 20 mm board found in any of the 3 images" in line


def test_wrong_circle_grid_size_is_diagnosed(capsys, tmp_path):
    _copy_real(tmp_path, 3)
    argv = ["--images", str(tmp_path / "*.jpg"), "--pattern", "acircles", "--cols", "5", "--rows", "11"]
    line = _fails(capsys, [*argv, "--square", "0.02", "--out", str(tmp_path / "c.yaml")])
    assert "no acircles 5x11" in line and "try --cols 4 --rows 11" in line


def test_chessboard_squares_counted_instead_of_corners(capsys, tmp_path):
    cv2.imwrite(str(tmp_path / "board.png"), _frontal_chessboard(9, 6))
    argv = ["--images", str(tmp_path / "board.png"), "--pattern", "chessboard", "--cols", "10", "--rows", "7"]
    line = _fails(capsys, [*argv, "--square", "0.025", "--out", str(tmp_path / "c.yaml")])
    assert "not squares" in line and "try --cols 9 --rows 6" in line


def test_charuco_wrong_dictionary_is_diagnosed(capsys, tmp_path):
    board = cv2.aruco.CharucoBoard(
        (6, 5), 0.03, 0.021, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    )
    cv2.imwrite(str(tmp_path / "charuco.png"), board.generateImage((480, 400), marginSize=40))
    argv = ["--images", str(tmp_path / "charuco.png"), "--pattern", "charuco", "--cols", "5", "--rows", "4"]
    line = _fails(capsys, [*argv, "--square", "0.03", "--marker", "0.021", "--out", str(tmp_path / "c.yaml")])
    assert "no DICT_5X5_100 markers were seen" in line and "--dictionary DICT_4X4" in line


def test_too_few_views(capsys, tmp_path):
    _copy_real(tmp_path, 3)
    line = _fails(capsys, ["--images", str(tmp_path / "*.jpg"), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "too few views: board found in 3 of 3 images" in line and "at least 5" in line
    assert not (tmp_path / "c.yaml").exists()


def test_pictures_of_different_sizes(capsys, tmp_path):
    _copy_real(tmp_path, 5)
    small = cv2.resize(cv2.imread(str(tmp_path / "right05.jpg")), (320, 256))
    cv2.imwrite(str(tmp_path / "right05.jpg"), small)
    line = _fails(capsys, ["--images", str(tmp_path / "*.jpg"), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "differ in size" in line and "640x512" in line and "320x256" in line


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (CHARUCO_5X4, "--marker"),
        ([*BOARD, "--fisheye", "--fix-aspect"], "--fix-aspect does not apply to --fisheye"),
        ([*BOARD, "--principal-point", "320", "256"], "--principal-point needs --fix-principal-point"),
        (["--pattern", "acircles", "--cols", "4", "--rows", "11", "--square", "20"], "metres"),
        (["--pattern", "chessboard", "--cols", "1", "--rows", "6", "--square", "0.02"], "--cols must be"),
        (
            [*CHARUCO_5X4, "--marker", "0.02", "--dictionary", "DICT_9X9_1"],
            "not an OpenCV ArUco dictionary",
        ),
    ],
    ids=[
        "charuco-no-marker",
        "fisheye-aspect",
        "pp-without-fix",
        "square-in-mm",
        "cols-too-small",
        "dictionary",
    ],
)
def test_bad_board_or_flags(capsys, tmp_path, extra, message):
    _copy_real(tmp_path, 1)
    line = _fails(capsys, ["--images", str(tmp_path / "*.jpg"), *extra, "--out", str(tmp_path / "c.yaml")])
    assert message in line


def test_out_must_be_yaml(capsys, tmp_path):
    line = _fails(capsys, ["--images", str(DATA / "*.jpg"), *BOARD, "--out", str(tmp_path / "camera.json")])
    assert "must end in .yaml" in line


def test_missing_square_is_a_command_line_error(capsys, tmp_path):
    argv = ["--images", str(DATA / "*.jpg"), "--pattern", "acircles", "--cols", "4", "--rows", "11"]
    line = _fails(capsys, [*argv, "--out", str(tmp_path / "c.yaml")], expected_rc=2)
    assert "--square" in line


def test_video_that_is_not_a_video(capsys, tmp_path):
    fake = tmp_path / "clip.mp4"
    fake.write_bytes(b"\x00" * 1000)
    line = _fails(capsys, ["--video", str(fake), *BOARD, "--out", str(tmp_path / "c.yaml")])
    assert "clip.mp4" in line
    line = _fails(
        capsys, ["--video", str(tmp_path / "absent.mp4"), *BOARD, "--out", str(tmp_path / "c.yaml")]
    )
    assert "video not found" in line


def test_check_with_missing_calibration(capsys, tmp_path):
    line = _fails(
        capsys, ["check", "--calib", str(tmp_path / "none.yaml"), "--images", str(DATA / "*.jpg"), *BOARD]
    )
    assert "calibration file not found" in line


def test_installed_console_script(tmp_path):
    """The entry point a fresh install puts on PATH: help works, bad input exits 1 with one line."""
    exe = shutil.which("dronekey-calib") or str(Path(sys.executable).with_name("dronekey-calib"))
    assert Path(exe).exists(), "dronekey-calib is not installed (pip install -e .)"
    helped = subprocess.run([exe, "--help"], capture_output=True, text=True, timeout=60)
    assert helped.returncode == 0 and "--fix-principal-point" in helped.stdout
    argv = [exe, "--images", str(tmp_path / "*.png"), *BOARD, "--out", str(tmp_path / "c.yaml")]
    failed = subprocess.run(argv, capture_output=True, text=True, timeout=60)
    assert failed.returncode == 1
    assert failed.stderr.strip().splitlines() == [
        f"dronekey-calib: error: no files match --images '{tmp_path}/*.png'"
    ]
