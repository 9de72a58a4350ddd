"""Keypoint-order flips undone with the track's prediction, and never forced onto a flipped track."""

import numpy as np
import pytest

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import load_spec
from dronekey.geometry.rotations import geodesic_angle_deg, rotation_from_euler_deg
from dronekey.perception.keypoint_order import HEADING_TWIN, SYMMETRIES, KeypointOrder, front_axis_turn
from dronekey.pipeline import PoseTracker
from dronekey.types import KeypointDetection

SPEC = load_spec("mini2")
CAMERA = CameraModel.from_fov(1920, 1080, 70)
E = np.radians(40)  # seen from 40 deg below; level FRD facing away: x->z, y->x, z->y
MOUNT = np.array([[1, 0, 0], [0, np.cos(E), np.sin(E)], [0, -np.sin(E), np.cos(E)]]) @ np.array(
    [[0, 1, 0], [0, 0, 1], [1, 0, 0]]
)
FRONT_BACK, LEFT_RIGHT = 1, 2


def truth(s: float):
    t = np.array([0.3 * np.sin(0.5 * s), 0.1 * np.sin(0.7 * s), 4.0])
    return MOUNT @ rotation_from_euler_deg(30 * s, 10 * np.sin(0.8 * s), 5 * np.sin(1.1 * s)), t


def keypoints(s: float) -> np.ndarray:
    return CAMERA.project_body(SPEC.keypoints_3d, *truth(s))


def flipped(kp: np.ndarray, symmetry: int) -> np.ndarray:
    return kp[list(SYMMETRIES[symmetry])]


def test_a_flip_is_undone_once_the_track_has_history():
    order = KeypointOrder(window=15, min_history=5)
    pred = keypoints(0.0)
    for _ in range(5):
        kp, sym = order.apply(pred + 0.5, pred)
        assert sym == 0 and np.allclose(kp, pred + 0.5)
    for symmetry in (FRONT_BACK, LEFT_RIGHT, 3):
        kp, sym = order.apply(flipped(pred, symmetry), pred)
        assert sym == symmetry and np.allclose(kp, pred)
    assert order.reordered == 3


def test_a_young_track_does_not_impose_its_order():
    order = KeypointOrder(min_history=5)
    pred = keypoints(0.0)
    for _ in range(4):
        order.apply(pred, pred)
    kp, sym = order.apply(flipped(pred, FRONT_BACK), pred)
    assert sym == 0 and np.allclose(kp, flipped(pred, FRONT_BACK))


def test_a_flipped_track_loses_the_vote():
    """A track that itself has the wrong order: once most detections disagree, they pass unchanged."""
    order = KeypointOrder(window=9, min_history=5)
    pred = keypoints(0.0)
    for _ in range(5):
        order.apply(pred, pred)
    results = [order.apply(flipped(pred, FRONT_BACK), pred)[1] for _ in range(12)]
    assert results[0] == FRONT_BACK  # the first disagreements are taken for the detector's flips
    assert results[-1] == 0 and results.count(0) >= 6  # then the detections win


def test_ambiguous_and_invalid_input_change_nothing():
    order = KeypointOrder(min_history=1)
    pred = keypoints(0.0)
    order.apply(pred, pred)
    head_on = np.array([[0.0, 0.0], [0.0, 1.0], [30.0, 1.0], [30.0, 0.0]])  # front and back 1 px apart
    kp, sym = order.apply(flipped(head_on, FRONT_BACK), head_on)
    assert sym == 0 and np.allclose(kp, flipped(head_on, FRONT_BACK))
    kp, sym = order.apply(np.full((4, 2), np.nan), pred)
    assert sym == 0 and np.isnan(kp).all()
    with pytest.raises(ValueError, match="min_history"):
        KeypointOrder(window=3, min_history=5)
    with pytest.raises(ValueError, match="clear_ratio"):
        KeypointOrder(clear_ratio=1.5)


def test_pose_tracker_measures_through_a_front_back_flip():
    """Ground-truth keypoints with a front/back flip every 7th frame: with the order fixed against
    the prior, every measurement stays within a few degrees of the truth (a flip alone would be
    off by about 180 deg)."""
    poses = PoseTracker(CAMERA, SPEC, keypoint_sigma_px=0.5)
    errors, flips = [], 0
    for k in range(60):
        s, t_ns = k / 30, round(k * 1e9 / 30)
        kp = keypoints(s)
        if k > 10 and k % 7 == 0:
            kp, flips = flipped(kp, FRONT_BACK), flips + 1
        prior = poses.prior(t_ns)
        det = poses.order_keypoints(KeypointDetection(kp, 0.99, (0, 0, 1)), prior)
        meas, _ = poses.measure(det, prior)
        poses.track(t_ns, meas, det)
        if k > 10:
            assert meas is not None
            errors.append(geodesic_angle_deg(meas.R, truth(s)[0]))
    assert flips >= 6 and poses.order().reordered == flips
    assert max(errors) < 2.0
    track = poses.tracker.predict(round(60 * 1e9 / 30))[0]
    assert geodesic_angle_deg(track.R, truth(2.0)[0]) < 3.0


@pytest.mark.parametrize(
    ("order", "turn"),
    [
        (SYMMETRIES[0], 1),  # as it is
        (SYMMETRIES[FRONT_BACK], -1),  # front and back exchanged: the axis reversed
        (SYMMETRIES[LEFT_RIGHT], 1),  # left and right exchanged: the front stays the front
        (tuple(HEADING_TWIN), -1),  # the half turn
        ((1, 2, 3, 0), 0),  # a quarter turn: the old front axis is now across
        ((0, 3, 2, 1), 0),  # a reflection about a diagonal
    ],
)
def test_front_axis_turn(order, turn):
    assert front_axis_turn(order) == turn


def test_an_undone_front_back_flip_carries_the_classifiers_word_with_it():
    """The front/back classifier's p is for the order it saw. When a front/back flip is undone
    against the track, the front it spoke of is now the back: p becomes 1 - p (a left/right flip
    keeps p)."""
    poses = PoseTracker(CAMERA, SPEC, keypoint_sigma_px=0.5)
    seen = {}
    for k in range(30):
        s, t_ns = k / 30, round(k * 1e9 / 30)
        kp = keypoints(s)
        symmetry = FRONT_BACK if k == 20 else LEFT_RIGHT if k == 25 else 0
        prior = poses.prior(t_ns)
        detection = KeypointDetection(flipped(kp, symmetry), 0.99, (0, 0, 1), heading_p=0.8)
        det = poses.order_keypoints(detection, prior)
        np.testing.assert_allclose(det.keypoints_px, kp)
        seen[k] = det.heading_p
        meas, _ = poses.measure(det, prior)
        poses.track(t_ns, meas, det)
    assert poses.order().reordered == 2
    assert (
        seen[20] == pytest.approx(0.2) and seen[25] == pytest.approx(0.8) and seen[19] == pytest.approx(0.8)
    )
