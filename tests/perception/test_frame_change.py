"""The frame-change evidence on real pixel arrays: a moving object out-changes its surroundings,
a still one does not even when the whole frame flickers (a key frame's re-quantisation)."""

from __future__ import annotations

import math

import cv2
import numpy as np

from dronekey.perception.frame_change import frame_change, largest_channel_change, percentile_95_of_levels

KEYPOINTS = np.array([[980.0, 520.0], [980.0, 560.0], [940.0, 560.0], [940.0, 520.0]])


def textured(rng: np.random.Generator) -> np.ndarray:
    small = rng.integers(60, 200, (68, 120, 3), dtype=np.uint8)
    return cv2.resize(small, (1920, 1080), interpolation=cv2.INTER_LINEAR)


def test_a_moving_object_changes_more_than_its_ring():
    rng = np.random.default_rng(0)
    background = textured(rng)
    before, after = background.copy(), background.copy()
    cv2.circle(before, (957, 540), 18, (20, 20, 20), -1)
    cv2.circle(after, (963, 540), 18, (20, 20, 20), -1)  # 6 px to the right
    assert frame_change(after, before, KEYPOINTS) > 30.0


def test_a_still_object_under_whole_frame_flicker_does_not():
    rng = np.random.default_rng(1)
    frame = textured(rng)
    cv2.circle(frame, (960, 540), 18, (20, 20, 20), -1)
    flicker = np.clip(frame.astype(np.int16) + rng.integers(-12, 13, frame.shape), 0, 255).astype(np.uint8)
    assert abs(frame_change(flicker, frame, KEYPOINTS)) < 4.0


def test_no_previous_frame_or_no_box_is_unknown():
    frame = np.zeros((1080, 1920, 3), np.uint8)
    assert math.isnan(frame_change(frame, None, KEYPOINTS))
    assert math.isnan(frame_change(frame, np.zeros((540, 960, 3), np.uint8), KEYPOINTS))
    assert math.isnan(frame_change(frame, frame, KEYPOINTS + 5000.0))
    assert math.isnan(frame_change(frame, frame, np.full((4, 2), np.nan)))


def test_a_near_drone_with_spinning_propellers_is_strided_not_skipped():
    """A drone 500 px across: the region is sampled with a stride, and its four propeller discs
    (their blades at another angle each frame) out-change the still background."""
    rng = np.random.default_rng(2)
    background = textured(rng)
    hubs = np.array([[1210.0, 290.0], [1210.0, 790.0], [710.0, 790.0], [710.0, 290.0]])
    frames = []
    for angle in (0.0, 40.0):
        frame = background.copy()
        for x, y in hubs.astype(int):
            for blade in (angle, angle + 180.0):
                end = (int(x + 90 * np.cos(np.radians(blade))), int(y + 90 * np.sin(np.radians(blade))))
                cv2.line(frame, (x, y), end, (15, 15, 15), 14)
        frames.append(frame)
    assert frame_change(frames[1], frames[0], hubs) > 30.0


def test_largest_channel_change_is_the_int16_reduction_to_the_value():
    rng = np.random.default_rng(5)
    a = rng.integers(0, 256, (90, 130, 3), dtype=np.uint8)
    b = rng.integers(0, 256, (90, 130, 3), dtype=np.uint8)
    for cur, prev in ((a, b), (a[::3, ::2], b[::3, ::2]), (a[:1, :1], b[:1, :1])):  # strided views too
        expected = np.abs(cur.astype(np.int16) - prev.astype(np.int16)).max(axis=2)
        got = largest_channel_change(cur, prev)
        assert got.dtype == np.uint8 and np.array_equal(got, expected)


def test_percentile_95_of_levels_is_numpys_to_the_bit():
    rng = np.random.default_rng(11)
    for _ in range(3000):
        n = int(rng.integers(1, 5000))
        values = rng.integers(0, int(rng.integers(1, 257)), n).astype(np.uint8)
        assert percentile_95_of_levels(values) == np.percentile(values, 95)
    assert percentile_95_of_levels(np.full((3, 4), 7, np.uint8)) == 7.0  # any shape, one value
