"""The published position covariance says how far off the range may be: widened along the line of
sight (``TrackerConfig.range_std_scale`` / ``range_std_floor``), the filter's own left alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dronekey.tracking.track_record import with_range_doubt
from dronekey.tracking.tracker import Tracker
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement


def _los_std(cov: np.ndarray, position: np.ndarray) -> float:
    u = position / np.linalg.norm(position)
    return math.sqrt(float(u @ cov @ u))


def test_a_narrow_range_doubt_is_raised_to_the_floor_along_the_line_of_sight_only():
    position = np.array([3.0, -1.0, 9.0])  # range 9.54 m
    cov = np.diag([0.01, 0.02, 0.03])
    widened = with_range_doubt(cov, position, 1.5, 0.07)
    assert _los_std(widened, position) == pytest.approx(0.07 * np.linalg.norm(position))
    np.testing.assert_allclose(widened, widened.T)
    across = np.cross(position, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    assert across @ widened @ across == pytest.approx(across @ cov @ across)  # unchanged across the ray


def test_a_range_doubt_above_the_floor_is_scaled_and_a_wide_one_kept():
    position = np.array([0.0, 0.0, 5.0])
    cov = np.diag([0.01, 0.01, 0.5**2])  # 0.5 m along the ray: above 0.07 x 5 m
    widened = with_range_doubt(cov, position, 1.5, 0.07)
    assert _los_std(widened, position) == pytest.approx(0.75)
    assert np.isnan(
        with_range_doubt(np.full((3, 3), np.nan), position, 1.5, 0.07)
    ).all()  # unknown stays unknown
    np.testing.assert_array_equal(with_range_doubt(cov, position, 1.0, 0.0), cov)


def test_a_published_track_carries_the_widened_range_doubt_and_the_filter_keeps_its_own():
    config = TrackerConfig(confirm_hits=1, confirm_window=1)
    tracker = Tracker(config)
    t = np.array([0.5, -0.2, 8.0])
    m = PoseMeasurement(
        R=np.eye(3),
        t=t,
        reprojection_px=0.3,
        covariance=np.diag([1e-4] * 3 + [1e-3] * 3),
        keypoint_sigma_px=1.0,
    )
    (track,) = tracker.update(0, [m])
    assert _los_std(track.position_cov, track.position_m) == pytest.approx(
        0.07 * np.linalg.norm(track.position_m)
    )
    state = tracker.state(track.track_id)
    assert _los_std(state.position_velocity_cov[:3, :3], state.position_m) < 0.02  # the filter's own
    plain = Tracker(TrackerConfig(confirm_hits=1, confirm_window=1, range_std_scale=1.0, range_std_floor=0.0))
    (track,) = plain.update(0, [m])
    np.testing.assert_allclose(track.position_cov, plain.state(track.track_id).position_velocity_cov[:3, :3])
