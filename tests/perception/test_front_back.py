"""Front and back: the network's front/back head through the runtime (mirror averaging, the head's
decision), the tracker's two heading hypotheses, and the honest doubt it publishes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dronekey.geometry.apparent_size import keypoint_spread
from dronekey.geometry.rotations import geodesic_angle_deg, quat_wxyz_to_matrix
from dronekey.perception.keypoint_model import (
    HEADING_TWIN,
    RawOutputs,
    in_heading_order,
    mirror_averaged,
    mirrored_back,
)
from dronekey.tracking.heading import twin_measurement, twin_of
from dronekey.tracking.track_record import SURE_LOG_ODDS, size_bound_log_odds
from dronekey.tracking.tracker import Tracker
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import TrackStatus
from tests.tracking.test_tracker import measurement, seen_from_below, t_ns

KP = np.array([[0.7, 0.4], [0.35, 0.35], [0.3, 0.65], [0.65, 0.7]], dtype=np.float32)


def mirrored_input(kp: np.ndarray) -> np.ndarray:
    """What the network answers on the mirrored crop for keypoints ``kp`` of the direct crop."""
    return mirrored_back(kp[None])[0]  # the mirror map is its own inverse


def test_mirror_average_aligns_a_twin_ordered_mirror_answer():
    direct = KP[None]
    mirror_twin = mirrored_input(KP[HEADING_TWIN])[None]  # mirrored answer came out in the twin order
    raw = RawOutputs(
        np.concatenate([direct, mirror_twin]),
        np.array([0.9, 0.8], np.float32),
        np.zeros((2, 4), np.float32),
        np.array([0.8, 0.3], np.float32),  # the mirrored crop's head says "twin": 1 - 0.3 agrees
    )
    avg = mirror_averaged(raw, 1)
    np.testing.assert_allclose(avg.keypoints[0], KP, atol=1e-6)  # no collapse onto the mean
    assert math.isclose(float(avg.heading[0]), 0.75, abs_tol=1e-6)
    assert math.isclose(float(avg.presence[0]), 0.85, abs_tol=1e-6)


def test_head_decision_swaps_to_the_twin_and_reports_its_own_probability():
    raw = RawOutputs(
        np.stack([KP, KP]),
        np.ones(2, np.float32),
        np.zeros((2, 4), np.float32),
        np.array([0.9, 0.2], np.float32),
    )
    out = in_heading_order(raw)
    np.testing.assert_allclose(out.keypoints[0], KP)
    np.testing.assert_allclose(out.keypoints[1], KP[HEADING_TWIN])
    np.testing.assert_allclose(out.heading, [0.9, 0.8], atol=1e-6)
    assert in_heading_order(RawOutputs(KP[None], np.ones(1), np.zeros((1, 4)), None)).heading is None


def test_twin_is_a_half_turn_about_the_body_vertical():
    R = seen_from_below(30.0, 5.0, -3.0)
    T = twin_of(R)
    assert math.isclose(geodesic_angle_deg(R, T), 180.0, abs_tol=1e-6)
    np.testing.assert_allclose(T[:, 2], R[:, 2], atol=1e-12)  # same vertical axis: same tilt
    np.testing.assert_allclose(twin_of(T), R, atol=1e-12)


def run(tracker: Tracker, R, frames: int, heading_p: float, start: int = 0):
    tracks = []
    for k in range(start, start + frames):
        tracks = tracker.update(t_ns(k), [measurement(R, [0.2, -0.5, 5.0])], [0.99], None, [heading_p])
    return tracks


def test_a_coin_flip_heading_is_published_as_doubt_not_as_a_heading():
    tracker = Tracker()
    (track,) = run(tracker, seen_from_below(40.0), 20, 0.5)
    assert track.status is TrackStatus.CONFIRMED
    assert abs(track.heading_confidence) < 0.05
    # The orientation doubt about the body's vertical axis is about pi / 2 (a two-point mixture).
    R = quat_wxyz_to_matrix(track.quaternion_wxyz)
    axis = R[:, 2]
    yaw_var = float(axis @ np.diag(track.rotation_std_rad**2) @ axis)
    assert yaw_var > (0.8 * math.pi / 2) ** 2 / 3


def test_confident_evidence_builds_up_and_a_flipped_track_turns_around():
    tracker = Tracker()
    R_true = seen_from_below(-60.0)
    # Born on the twin (the first detection's head got it wrong, weakly), then confident and right.
    tracker.update(t_ns(0), [twin_measurement(measurement(R_true, [0.2, -0.5, 5.0]))], [0.99], None, [0.55])
    tracks = run(tracker, R_true, 30, 0.95, start=1)
    (track,) = tracks
    assert geodesic_angle_deg(quat_wxyz_to_matrix(track.quaternion_wxyz), R_true) < 3.0
    assert track.heading_confidence > 0.6  # the look's mean is still catching up with 0.95
    (track,) = run(tracker, R_true, 60, 0.95, start=31)
    assert track.heading_confidence > 0.85  # tanh(logit(0.95) / 2) = 0.9 at most


def test_without_a_front_back_head_the_confidence_is_unknown_and_the_order_is_kept():
    tracker = Tracker()
    R = seen_from_below(10.0)
    (track,) = run(tracker, R, 10, float("nan"))
    assert math.isnan(track.heading_confidence)
    assert geodesic_angle_deg(quat_wxyz_to_matrix(track.quaternion_wxyz), R) < 2.0


def test_inconsistent_ranges_never_confirm_and_do_not_block_the_consistent_hypothesis():
    """Two hypotheses per frame: a drone at 5 m, and a cloud whose range jumps 8 <-> 20 m (each
    jump inside the association gate of a far, uncertain measurement). Only the drone confirms."""
    tracker = Tracker(TrackerConfig(position_gate_chi2=1e6))
    R = seen_from_below(0.0)
    statuses = {}
    for k in range(8):
        far = [3.0, -4.0, 8.0 if k % 2 == 0 else 20.0]
        ms = [measurement(R, [0.2, -0.5, 5.0]), measurement(R, far, pos_std=5.0)]
        for tr in tracker.update(t_ns(k), ms, [0.99, 0.99], None, [0.9, 0.9]):
            statuses.setdefault(tr.track_id, set()).add(tr.status)
    confirmed = [i for i, s in statuses.items() if TrackStatus.CONFIRMED in s]
    assert len(confirmed) == 1
    assert len(statuses) >= 2


def test_nose_first_motion_tells_the_front_when_asked_and_only_then():
    """A symmetric drone (heading_p 0.5 every frame) flying nose-first along +x of the camera:
    with heading_from_motion the track learns which way it faces; without, it stays in doubt."""
    R = seen_from_below(0.0)  # nose along the camera's +z (away), level
    nose = R[:, 0]
    for weight, expect_sure in ((0.0, False), (0.5, True)):
        tracker = Tracker(TrackerConfig(heading_from_motion=weight))
        # Born facing backwards: the motion must turn it around.
        tracker.update(t_ns(0), [twin_measurement(measurement(R, [0.0, 0.0, 8.0]))], [0.99], None, [0.5])
        for k in range(1, 60):
            p = np.array([0.0, 0.0, 8.0]) + nose * 3.0 * k / 30  # 3 m/s forward
            (track,) = tracker.update(t_ns(k), [measurement(R, p)], [0.99], None, [0.5])
        angle = geodesic_angle_deg(quat_wxyz_to_matrix(track.quaternion_wxyz), R)
        if expect_sure:
            assert track.heading_confidence > 0.8 and angle < 5.0
        else:
            assert abs(track.heading_confidence) < 0.1


def test_a_front_more_likely_wrong_than_right_has_no_confidence_never_a_negative_one():
    tracker = Tracker()
    R = seen_from_below(25.0)
    # evidence against the track's front, too weak to turn it around (the switch hysteresis)
    (track,) = run(tracker, R, 3, 0.4)  # log-odds 3 x 0.3 x log(0.4 / 0.6) = -0.36: tanh would be -0.18
    assert track.heading_confidence == 0.0


def test_a_long_run_of_weak_answers_is_not_published_as_a_sure_front():
    """One drone seen from one side answers alike on every frame, right or wrong: 150 frames of
    p = 0.7 pile up log-odds, but the published confidence stays what one frame of 0.7 says."""
    R = seen_from_below(15.0)
    one_frame = math.tanh(math.log(0.7 / 0.3) / 2)  # 0.4
    piled, averaged = (run(Tracker(TrackerConfig(heading_look_frames=n)), R, 150, 0.7)[0] for n in (0, 30))
    assert piled.heading_confidence > 0.95  # the accumulated log-odds alone
    assert averaged.heading_confidence == pytest.approx(one_frame, abs=1e-6)
    assert geodesic_angle_deg(quat_wxyz_to_matrix(averaged.quaternion_wxyz), R) < 2.0  # same front followed
    # Strong, steady answers still make a sure track.
    (sure,) = run(Tracker(TrackerConfig(heading_look_frames=30)), R, 60, 0.97)
    assert sure.heading_confidence > 0.9


def test_turning_around_turns_the_looks_mean_too():
    tracker = Tracker(TrackerConfig(heading_look_frames=30))
    R_true = seen_from_below(-60.0)
    # Born on the twin with a strong wrong answer, then steadily right: it turns, and ends sure.
    tracker.update(t_ns(0), [twin_measurement(measurement(R_true, [0.2, -0.5, 5.0]))], [0.99], None, [0.9])
    (track,) = run(tracker, R_true, 120, 0.97, start=1)
    assert geodesic_angle_deg(quat_wxyz_to_matrix(track.quaternion_wxyz), R_true) < 3.0
    assert track.heading_confidence > 0.9


def hubs_apart(spread_px: float) -> np.ndarray:
    """Four hubs on a square whose diagonal (the longest hub distance) is ``spread_px``."""
    half = spread_px / (2 * math.sqrt(2))
    return np.array(
        [
            [960 + half, 540 - half],
            [960 - half, 540 - half],
            [960 - half, 540 + half],
            [960 + half, 540 + half],
        ]
    )


def run_sized(tracker: Tracker, R, frames: int, heading_p: float, spread_px: float):
    tracks = []
    for k in range(frames):
        tracks = tracker.update(
            t_ns(k), [measurement(R, [0.2, -0.5, 5.0])], [0.99], [hubs_apart(spread_px)], [heading_p]
        )
    return tracks


def test_the_size_bound_is_none_at_half_the_full_spread_and_sure_at_it():
    assert keypoint_spread(hubs_apart(30.0)) == pytest.approx(30.0)
    assert size_bound_log_odds(20.0, 43.5) == 0.0
    assert size_bound_log_odds(43.5 / 2, 43.5) == 0.0
    assert math.tanh(size_bound_log_odds(43.5, 43.5) / 2) == pytest.approx(0.5)  # "sure" from here on
    assert size_bound_log_odds(87.0, 43.5) == pytest.approx(3 * SURE_LOG_ODDS)


def test_a_far_drone_is_never_published_sure_of_its_front_and_follows_the_same_one():
    """Steady, strong answers on a drone whose hubs are 25 px apart: sure without the bound, at most
    what its size allows with it, through a missed frame too; the front followed is the same."""
    R = seen_from_below(15.0)
    free, bounded = (
        run_sized(Tracker(TrackerConfig(heading_full_spread_px=s)), R, 60, 0.97, 25.0)[0] for s in (0.0, 43.5)
    )
    assert free.heading_confidence > 0.9
    assert bounded.heading_confidence <= math.tanh(size_bound_log_odds(25.0, 43.5) / 2) + 1e-12
    assert bounded.heading_confidence < 0.1
    assert np.allclose(free.quaternion_wxyz, bounded.quaternion_wxyz)  # only what the outputs are told
    tracker = Tracker(TrackerConfig(heading_full_spread_px=43.5))
    run_sized(tracker, R, 60, 0.97, 25.0)
    (coasting,) = tracker.update(t_ns(60), [])
    assert coasting.heading_confidence < 0.1  # the last size holds through a miss
    # A near drone (hubs 120 px apart) is as sure as its look says.
    (near,) = run_sized(Tracker(TrackerConfig(heading_full_spread_px=43.5)), R, 60, 0.97, 120.0)
    assert near.heading_confidence == pytest.approx(free.heading_confidence)
