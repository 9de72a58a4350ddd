"""Several drones at once: Hungarian association on the gated Mahalanobis + keypoint-overlap cost,
stable ids through a crossing and a short occlusion, ``max_tracks``, and ``sim://swarm`` as a
daemon source (the real renderer)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dronekey.daemon.config.source import SimSettings
from dronekey.daemon.sources.sim import SimReader
from dronekey.geometry.camera import CameraModel
from dronekey.tracking.keypoint_overlap import KeypointMotion, box_iou, keypoint_box
from dronekey.tracking.tracker import Tracker
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement, TrackStatus

FPS = 30.0
CAMERA = CameraModel.from_fov(1920, 1080, 70)
HUBS = 0.125 * np.array([[1.0, 1.0, 0.0], [1.0, -1.0, 0.0], [-1.0, -1.0, 0.0], [-1.0, 1.0, 0.0]])


def t_ns(frame: int) -> int:
    return round(frame * 1e9 / FPS)


def measured(t, pos_std: float = 0.05) -> tuple[PoseMeasurement, np.ndarray]:
    """A pose at ``t`` (camera frame, m) and the keypoints (px) of a level drone there."""
    t = np.asarray(t, dtype=float)
    cov = np.diag([pos_std**2] * 3 + [math.radians(1.0) ** 2] * 3)
    m = PoseMeasurement(
        R=np.eye(3), t=t, reprojection_px=0.3, covariance=cov, alternative=None, keypoint_sigma_px=1.0
    )
    return m, CAMERA.project(HUBS + t)


def update(tracker: Tracker, frame: int, positions, rng=None):
    """One frame of the given drones' poses (shuffled: the order must not matter)."""
    pairs = [measured(p) for p in positions]
    if rng is not None:
        rng.shuffle(pairs)
    return tracker.update(t_ns(frame), [m for m, _ in pairs], [0.999] * len(pairs), [k for _, k in pairs])


def nearest_id(tracks, position) -> int:
    held = [tr for tr in tracks if tr.status in (TrackStatus.CONFIRMED, TrackStatus.COASTING)]
    return min(held, key=lambda tr: np.linalg.norm(np.asarray(tr.position_m) - position)).track_id


def crossing(frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Drone A flies left to right at 6 m, drone B right to left at 8 m, one passing in front of the
    other: their images cross at frame 30 (both on the optical axis)."""
    s = (frame - 30) / FPS  # seconds from the crossing
    return np.array([3.0 * s, 0.0, 6.0]), np.array([-4.0 * s, 0.1 * s, 8.0])


def test_two_drones_crossing_keep_two_stable_ids():
    tracker, rng = Tracker(), np.random.default_rng(1)
    ids = {"A": set(), "B": set()}
    for frame in range(61):
        a, b = crossing(frame)
        noisy = [a + rng.normal(0, 0.03, 3), b + rng.normal(0, 0.03, 3)]
        tracks = update(tracker, frame, noisy, rng)
        if frame >= 3:
            ids["A"].add(nearest_id(tracks, a))
            ids["B"].add(nearest_id(tracks, b))
    assert len(ids["A"]) == 1 and len(ids["B"]) == 1 and ids["A"] != ids["B"], ids
    assert len(tracker.track_ids) == 2


def test_hungarian_takes_the_global_optimum_where_greedy_would_swap():
    """Tracks at x = 0 and x = 1 m; measurements at 0.55 and 1.6 m. Greedy nearest-first gives
    track 2 the 0.55 m one (0.45 m is the closest pair) and track 1 the 1.6 m one (1.6 m away);
    the assignment that minimises the total cost keeps 0.55 -> track 1, 1.6 -> track 2."""
    config = TrackerConfig(keypoint_overlap_weight=0.0, confirm_hits=1)
    tracker = Tracker(config)
    first = [measured([0.0, 0.0, 5.0], 0.3)[0], measured([1.0, 0.0, 5.0], 0.3)[0]]
    tracker.update(0, first)
    later = [measured([1.6, 0.0, 5.0], 0.3)[0], measured([0.55, 0.0, 5.0], 0.3)[0]]
    tracks = {tr.track_id: tr for tr in tracker.update(1000, later)}
    assert sorted(tracks) == [1, 2]  # both matched: no third track was started
    assert tracks[1].position_m[0] == pytest.approx(0.55 / 2 + 0.0 / 2, abs=0.1)
    assert tracks[2].position_m[0] == pytest.approx((1.0 + 1.6) / 2, abs=0.1)


def test_keypoint_overlap_settles_two_tracks_that_the_3d_gate_cannot():
    """Two tracks equally far in 3D from both measurements (a wide covariance): the measurement
    whose keypoints overlap a track's expected box goes to that track."""
    tracker = Tracker(TrackerConfig(confirm_hits=1))
    left, right = np.array([-0.4, 0.0, 6.0]), np.array([0.4, 0.0, 6.0])
    for frame in range(3):
        update(tracker, frame, [left, right])
    # Each measurement's position sits between the two tracks, its keypoints on one of them.
    shifted = [measured([0.05, 0.0, 6.0], 2.0), measured([-0.05, 0.0, 6.0], 2.0)]
    m_right = (shifted[0][0], CAMERA.project(HUBS + right))
    m_left = (shifted[1][0], CAMERA.project(HUBS + left))
    pairs = tracker._associate(t_ns(3), [m_right[0], m_left[0]], [m_right[1], m_left[1]])[0]
    assert sorted(pairs) == [(1, 1), (2, 0)]  # track 1 was born on the left drone


def test_a_short_occlusion_keeps_the_id():
    """Drone B disappears behind A for 12 frames (0.4 s) and comes back near its prediction."""
    tracker = Tracker()
    for frame in range(20):
        a, b = crossing(frame)
        tracks = update(tracker, frame, [a, b])
    id_b = nearest_id(tracks, crossing(19)[1])
    for frame in range(20, 32):
        a, _ = crossing(frame)
        tracks = update(tracker, frame, [a])
        assert any(tr.track_id == id_b and tr.status is TrackStatus.COASTING for tr in tracks)
    for frame in range(32, 40):
        tracks = update(tracker, frame, list(crossing(frame)))
    assert nearest_id(tracks, crossing(39)[1]) == id_b
    assert len(tracker.track_ids) == 2


def test_max_tracks_is_respected():
    tracker = Tracker(TrackerConfig(max_tracks=3))
    drones = [np.array([x, 0.0, 7.0]) for x in (-3.0, -1.5, 0.0, 1.5, 3.0)]
    for frame in range(10):
        tracks = update(tracker, frame, drones)
        assert len([tr for tr in tracks if tr.status is not TrackStatus.LOST]) <= 3
    assert len(tracker.track_ids) == 3


def test_keypoint_motion_predicts_the_box():
    motion = KeypointMotion()
    kp = np.array([[100.0, 100.0], [120.0, 100.0], [120.0, 110.0], [100.0, 110.0]])
    motion.observe(0, kp)
    motion.observe(100_000_000, kp + np.array([10.0, 0.0]))  # 100 px/s to the right
    assert motion.predicted_box(200_000_000) == pytest.approx((110.0 + 5.0, 100.0, 130.0 + 5.0, 110.0))
    assert box_iou(keypoint_box(kp), keypoint_box(kp)) == pytest.approx(1.0)
    assert box_iou(None, keypoint_box(kp)) == 0.5
    assert keypoint_box(np.full((4, 2), np.nan)) is None


def test_sim_swarm_is_a_daemon_source():
    reader = SimReader("swarm", SimSettings(frames=2))
    assert reader.bundled_camera()[0].size == (1920, 1080)
    reader.open()
    first, second, end = reader.read(), reader.read(), reader.read()
    assert first.image.shape == (1080, 1920, 3) and second.t_ns > first.t_ns >= 0
    assert end.ended
    reader.close()


def test_a_second_track_on_one_drone_is_merged_into_the_older():
    """A search reading of a drone that a track holds starts a second track on it; when only one
    reading of the drone comes next, the two are merged at once (the older id stays, with the
    reading) instead of the other coasting beside it for a second."""
    tracker = Tracker()
    drone, nudge = np.array([0.5, 0.2, 7.0]), np.array([0.01, 0.0, 0.05])
    for frame in range(5):
        update(tracker, frame, [drone])
    tracks = update(tracker, 5, [drone, drone + nudge])  # the drone read twice
    assert [tr.track_id for tr in tracks] == [1, 2]
    tracks = update(tracker, 6, [drone + nudge])
    assert [(tr.track_id, tr.status) for tr in tracks] == [(1, TrackStatus.CONFIRMED), (2, TrackStatus.LOST)]
    assert tracks[0].hits == 7  # the reading went to the older track


def test_drones_crossing_at_different_ranges_are_not_merged():
    """One drone in front of another on the same line of sight: the far one's track coasts
    through the occlusion (their ranges differ by far more than ``merge_range_ratio``)."""
    tracker = Tracker()
    near, far = np.array([0.0, 0.0, 6.0]), np.array([0.0, 0.0, 8.0])
    for frame in range(5):
        update(tracker, frame, [near, far])
    tracks = update(tracker, 5, [near])
    statuses = [(tr.track_id, tr.status) for tr in tracks]
    assert statuses == [(1, TrackStatus.CONFIRMED), (2, TrackStatus.COASTING)]


def test_merge_settings_are_checked():
    with pytest.raises(ValueError, match="merge_min_iou"):
        TrackerConfig(merge_min_iou=1.5)
    with pytest.raises(ValueError, match="merge_range_ratio"):
        TrackerConfig(merge_range_ratio=0.0)
