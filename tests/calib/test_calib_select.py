"""Choosing views from video frames: the pose descriptor, the sharpness measure, the greedy pick."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from dronekey.calib.patterns import BoardPattern
from dronekey.calib.select_views import ViewCandidate, board_sharpness, pose_descriptor, select_diverse
from dronekey.calib.views import BoardView

SIZE = (640, 480)
K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
GRID = BoardPattern("chessboard", 9, 6, 0.025).object_points()


def _view(rvec, tvec) -> BoardView:
    uv, _ = cv2.projectPoints(
        GRID.astype(np.float64), np.asarray(rvec, float), np.asarray(tvec, float), K, None
    )
    return BoardView(uv.reshape(-1, 2).astype(np.float32), GRID)


def _centred_tvec(rvec, depth: float) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.asarray(rvec, float))
    centre = GRID.mean(axis=0).astype(np.float64)
    return np.array([0.0, 0.0, depth]) - R @ centre


def test_descriptor_of_a_frontal_board():
    view = _view([0, 0, 0], _centred_tvec([0, 0, 0], 0.5))
    x, y, size, tilt_x, tilt_y = pose_descriptor(view, SIZE)
    assert x == pytest.approx(0.5, abs=0.01) and y == pytest.approx(0.5, abs=0.01)
    # 8 x 5 squares of 25 mm at 0.5 m and f = 600 px: 240 x 150 px of the 640 x 480 frame
    assert size == pytest.approx(np.sqrt(240 * 150 / (640 * 480)), rel=0.02)
    assert abs(tilt_x) < 1e-6 and abs(tilt_y) < 1e-6


@pytest.mark.parametrize(("axis", "index"), [(1, 3), (0, 4)], ids=["about-y", "about-x"])
def test_descriptor_tilt_follows_the_board(axis, index):
    tilts = []
    for sign in (1.0, -1.0):
        rvec = np.zeros(3)
        rvec[axis] = sign * np.radians(35)
        tilts.append(pose_descriptor(_view(rvec, _centred_tvec(rvec, 0.5)), SIZE))
    assert abs(tilts[0][index]) > 0.3
    assert tilts[0][index] == pytest.approx(-tilts[1][index], rel=0.05)
    assert abs(tilts[0][7 - index]) < 0.05  # the other tilt component stays near 0


def test_sharpness_drops_with_blur():
    rng = np.random.default_rng(0)
    image = (rng.random((480, 640)) > 0.5).astype(np.uint8) * 255
    view = _view([0, 0, 0], _centred_tvec([0, 0, 0], 0.5))
    blurred = cv2.GaussianBlur(image, (0, 0), 2.0)
    assert board_sharpness(blurred, view) < 0.2 * board_sharpness(image, view)


def _candidate(name, descriptor, sharpness=100.0) -> ViewCandidate:
    empty = BoardView(np.zeros((0, 2), np.float32), np.zeros((0, 3), np.float32))
    return ViewCandidate(name, empty, sharpness, np.asarray(descriptor, dtype=float))


def test_select_diverse_skips_duplicates_and_blur():
    candidates = [_candidate(f"dup{k}", [0.5, 0.5, 0.4, 0.0, 0.0 + 0.001 * k]) for k in range(8)]
    candidates += [
        _candidate("left", [0.2, 0.5, 0.4, 0.0, 0.0]),
        _candidate("right-tilted", [0.8, 0.5, 0.4, 0.5, 0.0]),
        _candidate("top", [0.5, 0.2, 0.3, 0.0, -0.4]),
        _candidate("blurred-corner", [0.1, 0.1, 0.3, 0.3, 0.3], sharpness=20.0),
    ]
    picked = {candidates[i].name for i in select_diverse(candidates, max_views=10)}
    assert {"left", "right-tilted", "top"} <= picked
    assert "blurred-corner" not in picked
    assert len([n for n in picked if n.startswith("dup")]) == 1


def test_select_diverse_respects_max_views():
    rng = np.random.default_rng(1)
    candidates = [_candidate(str(k), rng.random(5)) for k in range(50)]
    picked = select_diverse(candidates, max_views=7)
    assert len(picked) == 7 and picked == sorted(set(picked))
    assert select_diverse([], max_views=3) == []
