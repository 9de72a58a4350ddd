"""The fusion core on constructed tracks: two cameras at known poses, noise from a PnP-like
covariance (long along the ray), drones where we put them."""

from __future__ import annotations

import numpy as np
import pytest
from fusion_scene import camera_track, heading, looking_at

from dronekey.fusion import CameraPose, ClockAlignment, Fuser, FusionConfig
from dronekey.geometry.rotations import geodesic_angle_deg, quat_wxyz_to_matrix
from dronekey.types import TrackStatus

DRONE = np.array([5.0, 60.0, 15.0])  # site ENU, m
CAM_A = looking_at((0.0, 0.0, 2.0), DRONE)
CAM_B = looking_at((25.0, 5.0, 2.0), DRONE)


def _fuser(**config) -> Fuser:
    return Fuser({"camA": CAM_A, "camB": CAM_B}, FusionConfig(**config))


def _rmse(errors) -> float:
    return float(np.sqrt(np.mean(np.sum(np.asarray(errors) ** 2, axis=1))))


def test_two_cameras_fused_error_is_below_the_better_camera():
    rng = np.random.default_rng(1)
    err_a, err_b, err_fused = [], [], []
    fuser = _fuser()  # one pair of tracks over 300 frames: the binding holds with hysteresis
    for i in range(300):
        t_ns = i * 33_000_000
        a = camera_track(CAM_A, DRONE, t_ns=t_ns, rng=rng)
        b = camera_track(CAM_B, DRONE, t_ns=t_ns, rng=rng)
        fuser.update("camA", a)
        fuser.update("camB", b)
        (fused,) = fuser.fuse(t_ns)
        assert fused.method == "triangulated"
        assert {m.camera_id for m in fused.members} == {"camA", "camB"}
        err_a.append(CAM_A.point_to_site(a.position_m) - DRONE)
        err_b.append(CAM_B.point_to_site(b.position_m) - DRONE)
        err_fused.append(fused.position_m - DRONE)
    better = min(_rmse(err_a), _rmse(err_b))
    assert _rmse(err_fused) < 0.25 * better, (_rmse(err_fused), better)


def test_one_camera_falls_back_to_its_own_position():
    fuser = _fuser()
    a = camera_track(CAM_A, DRONE, t_ns=0)
    fuser.update("camA", a)
    (fused,) = fuser.fuse(0)
    assert fused.method == "single"
    np.testing.assert_allclose(fused.position_m, CAM_A.point_to_site(a.position_m), atol=1e-9)


def test_association_rejects_a_mismatched_pair():
    # camA sees one drone, camB another 6 m above it: their rays miss by metres. (Two drones at one
    # height seen by two cameras at one height give rays that cross: a ghost no two-camera geometry
    # can reject; a third camera or the drones' tracks over time can.)
    other = DRONE + np.array([0.0, 0.0, 6.0])
    fuser = _fuser()
    fuser.update("camA", camera_track(CAM_A, DRONE, t_ns=0))
    fuser.update("camB", camera_track(CAM_B, other, t_ns=0))
    fused = fuser.fuse(0)
    assert sorted(f.method for f in fused) == ["single", "single"]
    assert len({f.fused_id for f in fused}) == 2


def test_two_drones_two_cameras_pair_correctly():
    rng = np.random.default_rng(2)
    other = DRONE + np.array([-8.0, 10.0, 3.0])
    fuser = _fuser()
    for t in range(5):
        t_ns = t * 33_000_000
        fuser.update("camA", camera_track(CAM_A, DRONE, track_id=1, t_ns=t_ns, rng=rng))
        fuser.update("camA", camera_track(CAM_A, other, track_id=2, t_ns=t_ns, rng=rng))
        fuser.update("camB", camera_track(CAM_B, other, track_id=7, t_ns=t_ns, rng=rng))
        fuser.update("camB", camera_track(CAM_B, DRONE, track_id=8, t_ns=t_ns, rng=rng))
        fused = fuser.fuse(t_ns)
        assert len(fused) == 2 and all(f.method == "triangulated" for f in fused)
        pairs = {tuple(sorted((m.camera_id, m.track_id) for m in f.members)) for f in fused}
        assert pairs == {(("camA", 1), ("camB", 8)), (("camA", 2), ("camB", 7))}
        near = {
            f.fused_id: min(np.linalg.norm(f.position_m - DRONE), np.linalg.norm(f.position_m - other))
            for f in fused
        }
        assert max(near.values()) < 1.5  # the depth std alone is 5 m
        if t == 0:
            ids = {f.fused_id for f in fused}
        assert {f.fused_id for f in fused} == ids  # stable ids


def test_clock_offset_and_frame_rates_tolerated():
    """camB's clock is 1000 s off and runs at 25 fps against camA's 30; the drone flies at 10 m/s.
    The offsets are estimated from arrival times, the tracks predicted to one time."""
    rng = np.random.default_rng(3)
    velocity = np.array([10.0, 0.0, 0.0])
    offset_b = 1_000_000_000_000
    clock = ClockAlignment("arrival")
    fuser = _fuser()
    latency_ns = 40_000_000
    errors, better = [], []
    events = [(i * 1e9 / 30, "camA") for i in range(60)] + [(i * 1e9 / 25, "camB") for i in range(50)]
    for t_true, camera in sorted(events):
        pose = CAM_A if camera == "camA" else CAM_B
        p_true = DRONE + velocity * t_true * 1e-9
        own_t = int(t_true) + (offset_b if camera == "camB" else 0)
        track = camera_track(pose, p_true, t_ns=own_t, rng=rng, v_site=velocity)
        arrival = int(t_true) + latency_ns + int(rng.integers(0, 5_000_000))
        fuser.update(camera, track, clock.observe(camera, own_t, arrival))
        if t_true < 0.5e9:
            continue
        t_fuse = fuser.latest_t_ns()
        fused = [f for f in fuser.fuse(t_fuse) if f.status != TrackStatus.LOST]
        assert len(fused) == 1 and fused[0].method == "triangulated"
        p_at = DRONE + velocity * (t_fuse - latency_ns) * 1e-9
        errors.append(fused[0].position_m - p_at)
        better.append(pose.point_to_site(track.position_m) - p_true)
    assert _rmse(errors) < 0.5 * _rmse(better), (_rmse(errors), _rmse(better))


def test_orientation_takes_the_confident_heading_and_flips_the_twin():
    true = heading(30.0)
    twin = true @ np.diag([-1.0, -1.0, 1.0])
    fuser = _fuser()
    fuser.update("camA", camera_track(CAM_A, DRONE, R_site_body=true, heading_confidence=0.9))
    fuser.update("camB", camera_track(CAM_B, DRONE, R_site_body=twin, heading_confidence=0.1))
    (fused,) = fuser.fuse(0)
    assert geodesic_angle_deg(quat_wxyz_to_matrix(fused.quaternion_wxyz), true) < 1e-6
    assert fused.heading_confidence == pytest.approx(0.9)


def test_lost_tracks_end_the_fused_track_once():
    fuser = _fuser()
    a = camera_track(CAM_A, DRONE, t_ns=0)
    b = camera_track(CAM_B, DRONE, t_ns=0)
    fuser.update("camA", a)
    fuser.update("camB", b)
    (first,) = fuser.fuse(0)
    a.status = TrackStatus.LOST
    fuser.update("camA", a)
    (still,) = fuser.fuse(0)
    assert still.fused_id == first.fused_id and still.method == "single"
    b.status = TrackStatus.LOST
    fuser.update("camB", b)
    (lost,) = fuser.fuse(0)
    assert lost.status == TrackStatus.LOST and lost.fused_id == first.fused_id and lost.members == ()
    assert fuser.fuse(0) == []


def test_a_late_second_camera_joins_the_existing_fused_id():
    fuser = _fuser()
    fuser.update("camA", camera_track(CAM_A, DRONE, t_ns=0))
    (alone,) = fuser.fuse(0)
    fuser.update("camB", camera_track(CAM_B, DRONE, t_ns=0))
    (both,) = fuser.fuse(0)
    assert both.fused_id == alone.fused_id and both.method == "triangulated"


def test_stale_and_tentative_tracks_are_left_out():
    fuser = _fuser(max_age_s=0.2)
    fuser.update("camA", camera_track(CAM_A, DRONE, t_ns=0))
    fuser.update("camB", camera_track(CAM_B, DRONE, t_ns=0, status=TrackStatus.TENTATIVE))
    (fused,) = fuser.fuse(100_000_000)
    assert [m.camera_id for m in fused.members] == ["camA"]
    assert fuser.fuse(300_000_000) == []  # camA too old now (still bound: no lost message yet)


@pytest.mark.parametrize(
    ("R", "t", "field"),
    [
        (np.eye(3) * 2, (0, 0, 0), "R_site_cam"),
        (np.diag([1.0, 1.0, -1.0]), (0, 0, 0), "R_site_cam"),
        (np.eye(3), (0, np.nan, 0), "t_site_cam_m"),
        (np.eye(3), (0, 0), "t_site_cam_m"),
    ],
)
def test_camera_pose_names_the_bad_field(R, t, field):
    with pytest.raises(ValueError, match=field):
        CameraPose(R, t)


def test_clock_alignment_trusts_synchronised_epoch_clocks():
    clock = ClockAlignment("auto")
    now = 1_700_000_000_000_000_000
    assert clock.observe("a", now - 30_000_000, now) == now - 30_000_000
    assert clock.observe("b", 5_000_000_000, now) == now  # a file's PTS: aligned to arrival
    with pytest.raises(ValueError, match="clock mode"):
        ClockAlignment("ntp")


def test_one_camera_keeps_the_depth_of_the_last_triangulation_for_depth_memory_s():
    """When the second camera loses the drone, the fused track takes the bearing from the camera
    left and the depth from where the two last put it, predicted with its velocity; after
    ``depth_memory_s`` the camera's own (biased) depth comes back."""
    velocity = np.array([1.0, 0.0, 0.0])
    ray = (DRONE - CAM_A.t_site_cam_m) / np.linalg.norm(DRONE - CAM_A.t_site_cam_m)

    def at(t_s: float) -> np.ndarray:
        return DRONE + velocity * t_s

    fuser = _fuser(depth_memory_s=2.0)
    for k in range(3):  # both cameras: triangulated
        t = int(k * 1e8)
        fuser.update("camA", camera_track(CAM_A, at(k * 0.1), t_ns=t, v_site=velocity))
        fuser.update("camB", camera_track(CAM_B, at(k * 0.1), t_ns=t, v_site=velocity))
        (both,) = fuser.fuse(t)
    assert both.method == "triangulated"
    fuser.update("camB", camera_track(CAM_B, at(0.2), t_ns=int(2e8), status=TrackStatus.LOST))

    def alone(t_s: float) -> np.ndarray:
        biased = at(t_s) + 8.0 * ray  # camera A reads the drone 8 m too far along its ray
        fuser.update("camA", camera_track(CAM_A, biased, t_ns=int(t_s * 1e9), v_site=velocity))
        (fused,) = fuser.fuse(int(t_s * 1e9))
        assert fused.method == "single" and fused.fused_id == both.fused_id
        return fused.position_m

    assert np.linalg.norm(alone(1.0) - at(1.0)) < 1.0
    assert np.linalg.norm(alone(3.0) - at(3.0)) == pytest.approx(8.0, abs=0.1)
