"""dronekey-eval robustness: the matrix and its seeds, rendering reused on a rerun, drone-free frames
counted, the JSON's keys and one-line errors. Behaviour only: the shipped model was trained on the
old renders, so no accuracy is asserted."""

import json
import os

import numpy as np
import pytest
from factories import make_track

from dronekey.evaluation.cli import main
from dronekey.evaluation.robustness import matrix as matrix
from dronekey.evaluation.robustness.run import run_robustness
from dronekey.evaluation.robustness.scoring import (
    WRONG_HEADING_DEG,
    SequenceScores,
    axis_exchanged,
    front_back_verdict,
    keypoint_error_px,
    match_gate_m,
    miss_reason,
    on_line_of_sight,
    position_m2,
    range_z,
)
from dronekey.evaluation.robustness.seed_sets import check_seeds
from dronekey.evaluation.robustness.summary import summarise
from dronekey.geometry.rotations import rotation_from_euler_deg
from dronekey.perception.keypoint_order import HEADING_TWIN
from dronekey.sim_replay.provenance import renderer_fingerprint
from dronekey.types import KeypointDetection, TrackStatus

# A tiny matrix: two LED modes on the held-out photos, one motion (the first sequence is far), two
# drone-free sequences; 6 frames at 320 x 180.
TINY = {
    "frames": 6,
    "leds": ("red-front", "off"),
    "backgrounds": ("photos",),
    "motions": ("seq13",),
    "drone_free": 2,
    "width": 320,
    "height": 180,
}
METRICS = {
    "sequences",
    "frames",
    "detected_frames",
    "detected_pct",
    "mae_angle_deg",
    "rmse_m",
    "mae_abs_m",
    "mae_angle_up_to_twin_deg",
    "ap_kp",
    "false_track_frames",
    "false_tracks_per_1000_frames",
    "false_track_ids",
    "off_sight_track_frames",
    "off_sight_tracks_per_1000_frames",
    "off_sight_track_ids",
    "confident_wrong_heading_frames",
    "confident_wrong_heading_pct",
    "wrong_heading_frames",
    "wrong_heading_pct",
    "confident_right_heading_frames",
    "confident_right_heading_pct",
    "missed_wrong_range_pct",
    "missed_unconfirmed_pct",
    "missed_unseen_pct",
    "front_back_frames",
    "front_back_right_pct",
    "axis_frames",
    "axis_exchanged_pct",
    "kp_err_px_median",
    "range_doubt_frames",
    "range_within_1sd_pct",
    "range_within_2sd_pct",
    "position_within_2sd_measured_pct",
    "coasting_frames",
    "position_within_2sd_coasting_pct",
    "front_away_pct",
    "confident_wrong_heading_front_away_pct",
    "confident_wrong_heading_front_toward_pct",
    "front_shown_pct",
    "mae_angle_front_shown_deg",
}

ENTRY_KEYS = {"name", "seed", "style_seed", "leds", "background", "range_scale", "far", "no_drone", "reused"}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("robustness")
    return out, run_robustness(out, **TINY)


def test_default_matrix_and_seeds():
    entries = matrix.plan_matrix()
    drone = [e for e in entries if not e.no_drone]
    free = [e for e in entries if e.no_drone]
    assert len(drone) == 4 * 3 * 3 and sum(e.frames for e in drone) == 5400
    assert len(free) == 20 and sum(e.frames for e in free) >= 3000
    assert {e.background for e in free} == set(matrix.BACKGROUNDS)
    assert {e.preset for e in free} == set(matrix.MOTIONS)
    # Latin square: one far motion per (LED, background) cell, a third of every LED, background, motion.
    for led in matrix.LED_CONDITIONS:
        for bg in matrix.BACKGROUNDS:
            assert sum(e.far for e in drone if (e.leds, e.background) == (led, bg)) == 1
    axes = (("leds", matrix.LED_CONDITIONS), ("background", matrix.BACKGROUNDS), ("preset", matrix.MOTIONS))
    for attr, values in axes:
        for v in values:
            group = [e for e in drone if getattr(e, attr) == v]
            assert 3 * sum(e.far for e in group) == len(group)
    seeds = [e.seed for e in entries]
    styles = [e.style_seed for e in entries]
    assert len(set(seeds)) == len(seeds) and len(set(styles)) == len(styles)
    assert min(seeds) == matrix.REPORTING_SEED and matrix.VALIDATION_SEED not in seeds
    tuning = {e.seed for e in matrix.plan_matrix(matrix.TUNING_SEED)}
    assert not tuning & set(seeds)
    assert len({e.name for e in entries}) == len(entries)


def test_cue_free_matrix_is_the_same_scenes_with_symmetric_drones():
    plain, symmetric = matrix.plan_matrix(), matrix.plan_matrix(cue_free=True)
    for a, b in zip(plain, symmetric, strict=True):
        assert (a.seed, a.style_seed, a.leds, a.background, a.far) == (
            b.seed,
            b.style_seed,
            b.leds,
            b.background,
            b.far,
        )
        if a.no_drone:  # nothing to draw: the same sequence, rendered once for both
            assert b == a
            continue
        assert b.cue_free and b.name == a.name + "-cuefree" and b.build().info["cue_free"] is True
        assert not a.cue_free and a.build().info["cue_free"] is False


def test_seed_sets_are_kept_apart():
    with pytest.raises(ValueError, match="overlap the tuning seeds"):
        check_seeds([matrix.TUNING_SEED], tuning=False)
    with pytest.raises(ValueError, match="overlap the reporting seeds"):
        check_seeds([matrix.REPORTING_SEED + 3], tuning=True)
    with pytest.raises(ValueError, match="7919"):
        check_seeds([matrix.VALIDATION_SEED - matrix.DRONE_FREE_SEED_OFFSET], tuning=False)
    with pytest.raises(ValueError, match="overlap"):
        check_seeds([8001, 8002], tuning=False)
    plans = check_seeds([8001, 9001], tuning=False)
    assert [p[0].seed for p in plans.values()] == [8001, 9001]


@pytest.mark.parametrize(
    "kwargs,message",
    [
        ({"leds": ("blue",)}, "leds: unknown 'blue'"),
        ({"backgrounds": ()}, "backgrounds must be a non-empty list"),
        ({"motions": ("seq13", "seq13")}, "motions must not repeat"),
        ({"frames": 0}, "frames must be an integer >= 1, got 0"),
        ({"drone_free": -1}, "drone_free must be an integer >= 0, got -1"),
        ({"far_range_scale": 0}, "far_range_scale must be a positive number"),
    ],
)
def test_plan_errors_name_the_argument(kwargs, message):
    with pytest.raises(ValueError, match=message):
        matrix.plan_matrix(**kwargs)


def test_match_gate():
    assert match_gate_m(np.array([0.0, 0.0, 1.0])) == 0.5
    assert match_gate_m(np.array([0.0, 6.0, 8.0])) == pytest.approx(2.5)


def _scores(
    false, detected=(), wrong=(), confident=(), dt=(), sure_right=None, off_sight=None, miss=None, fb=None
):
    n = len(detected)
    miss = miss or [None] * n
    R = np.repeat(np.eye(3)[None], n, axis=0)
    t_true = np.tile([0.0, 0.0, 4.0], (n, 1))
    t_track = t_true + np.asarray(dt, dtype=float).reshape(n, 3) if n else t_true
    return SequenceScores(
        no_drone=n == 0,
        false_frame=np.asarray(false, bool),
        false_ids=int(any(false)),
        off_sight_frame=np.asarray(false if off_sight is None else off_sight, bool),
        off_sight_ids=int(any(false if off_sight is None else off_sight)),
        detected=np.asarray(detected, bool),
        R_track=R,
        t_track=t_track,
        R_true=R,
        t_true=t_true,
        wrong_heading=np.asarray(wrong, bool).reshape(n),
        sure_heading=np.asarray(confident, bool).reshape(n) | np.asarray(sure_right or [False] * n, bool),
        kp_pred=np.zeros((n, 4, 2)),
        kp_true=np.zeros((n, 4, 2)),
        area=np.ones(n),
        score=np.ones(n),
        has_pred=np.ones(n, bool),
        missed_wrong_range=np.array([m == "wrong_range" for m in miss], bool),
        missed_unconfirmed=np.array([m == "unconfirmed" for m in miss], bool),
        missed_unseen=np.array([m == "unseen" for m in miss], bool),
        front_back_right=np.asarray(fb if fb is not None else [np.nan] * n, float),
        axis_exchanged=np.full(n, np.nan),
        range_z=np.full(n, np.nan),
        position_m2=np.full(n, np.nan),
        coasting=np.zeros(n, bool),
    )


def test_summarise_pools_frames():
    dt_a = [[0.3, 0, 0], [0, 0, 0]]
    a = _scores(
        [False, True],
        [True, False],
        [True, False],
        [False, False],
        dt_a,
        off_sight=[0, 0],
        miss=[None, "wrong_range"],
        fb=[0.0, np.nan],
    )
    dt = [[0, 0.1, 0], [0, 0.1, 0]]
    b = _scores(
        [False, False], [True, True], [False, False], [False, False], dt, sure_right=[True, False], fb=[1, 1]
    )
    free = _scores([True, False, False, True])
    s = summarise([a, b, free])
    assert s["sequences"] == 3 and s["frames"] == 8
    assert s["detected_frames"] == 3 and s["detected_pct"] == 75.0
    # RMSE over the 3 detected frames (not the mean of per-sequence RMSEs).
    assert s["rmse_m"] == pytest.approx(np.sqrt((0.09 + 0.01 + 0.01) / 3), abs=1e-4)
    assert s["false_track_frames"] == 3 and s["false_tracks_per_1000_frames"] == 375.0
    assert s["false_track_ids"] == 2
    # a's false frame is the drone at a wrong range, on its line of sight: only the drone-free
    # frames count.
    assert s["off_sight_track_frames"] == 2 and s["off_sight_tracks_per_1000_frames"] == 250.0
    assert s["off_sight_track_ids"] == 1
    assert s["wrong_heading_frames"] == 1 and s["wrong_heading_pct"] == 25.0
    assert s["confident_wrong_heading_frames"] == 0
    assert s["confident_right_heading_frames"] == 1 and s["confident_right_heading_pct"] == 25.0
    # The one missed frame was the drone at a wrong range; the classifier was asked on 3 frames.
    assert (s["missed_wrong_range_pct"], s["missed_unconfirmed_pct"], s["missed_unseen_pct"]) == (
        25.0,
        0.0,
        0.0,
    )
    assert s["front_back_frames"] == 3 and s["front_back_right_pct"] == pytest.approx(66.67)
    # every drone square across the view (identity rotation): none points its front away
    assert s["front_away_pct"] == 0.0 and s["confident_wrong_heading_front_away_pct"] is None
    assert s["confident_wrong_heading_front_toward_pct"] == 0.0
    only_free = summarise([free])
    assert only_free["false_tracks_per_1000_frames"] == 500.0 and only_free["mae_angle_deg"] is None
    assert set(only_free) == METRICS


def test_summarise_splits_confident_wrong_headings_by_where_the_front_points():
    # four detected frames; the first three point the front away from the camera (body x along
    # the camera's +z), the last towards it; all but the third are wrong and sure
    wrong = [True, True, False, True]
    s = _scores([False] * 4, [True] * 4, wrong, wrong, [[0, 0, 0]] * 4)
    turn = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # x -> +z
    s.R_true[:3] = turn
    s.R_true[3] = turn.T  # x -> -z: front towards the camera
    out = summarise([s])
    assert out["front_away_pct"] == 75.0
    assert out["confident_wrong_heading_front_away_pct"] == pytest.approx(66.67)
    assert out["confident_wrong_heading_front_toward_pct"] == 100.0
    assert out["confident_wrong_heading_pct"] == 75.0


def test_summarise_gives_the_angle_over_the_frames_that_show_the_front():
    # three detected frames: right, read the wrong way round (180 deg of yaw), right; the second's
    # body shows no front to the camera, so a reader is not answerable for it
    s = _scores([False] * 3, [True] * 3, [False, True, False], [False] * 3, [[0, 0, 0]] * 3)
    s.R_track = s.R_true.copy()
    s.R_track[1] = np.diag([-1.0, -1.0, 1.0])
    s.front_shown = np.array([True, False, True])
    out = summarise([s])
    assert out["mae_angle_deg"] == pytest.approx(60.0)  # the bar's figure counts every frame
    assert out["mae_angle_front_shown_deg"] == 0.0 and out["front_shown_pct"] == pytest.approx(66.67)
    s.front_shown = None  # a sequence that does not name its look: nothing to tell
    out = summarise([s])
    assert out["mae_angle_front_shown_deg"] is None and out["front_shown_pct"] is None


def test_front_shown_follows_the_body_and_the_view():
    from dronekey.evaluation.robustness.front_cues import camera_above, front_shown
    from dronekey.sim_replay.drone_look import DroneLook

    up = np.eye(3)  # body z (down) along the camera's +z: the drone seen from above its props
    down = np.diag([1.0, -1.0, -1.0])  # body z towards the camera: seen from below
    R, t = np.stack([up, down]), np.tile([0.0, 0.0, 5.0], (2, 1))
    assert camera_above(R, t).tolist() == [True, False]
    top_only = next(
        seed
        for seed in range(17000, 17200)
        if DroneLook.draw(seed).shape.shows_front(True) and not DroneLook.draw(seed).shape.shows_front(False)
    )
    info = {"style_seed": top_only, "leds": "red-front", "no_drone": False, "cue_free": False}
    assert front_shown(info, R, t).tolist() == [True, False]  # its cue is on the top shell
    assert front_shown({**info, "cue_free": True}, R, t).tolist() == [False, False]
    assert front_shown({**info, "no_drone": True}, R, t) is None
    assert front_shown({"leds": "off"}, R, t) is None  # no style seed: a file from elsewhere


def test_line_of_sight_tells_the_drone_at_a_wrong_range_from_elsewhere():
    # A Mini 2 (hubs 0.106 m + half a 0.119 m propeller) at 5 m subtends 1.9 deg of radius.
    t_true, radius = np.array([0.0, 0.0, 5.0]), 0.166
    assert on_line_of_sight(np.array([0.0, 0.0, 3.0]), t_true, radius)  # read 40 % short
    assert on_line_of_sight(np.array([0.1, 0.0, 8.0]), t_true, radius)  # far, 0.7 deg off
    assert not on_line_of_sight(np.array([1.0, 0.0, 5.0]), t_true, radius)  # 11 deg off: elsewhere
    assert not on_line_of_sight(np.zeros(3), t_true, radius)


def test_a_missed_frame_says_whether_the_drone_was_read_at_a_wrong_range_held_or_not_held():
    t_true, radius = np.array([0.0, 0.0, 5.0]), 0.166
    far_on_sight = make_track(1, position_m=(0.0, 0.0, 9.0))
    tentative = make_track(2, status=TrackStatus.TENTATIVE, position_m=(0.0, 0.0, 5.2))
    elsewhere = make_track(3, position_m=(2.0, 0.0, 5.0))
    lost = make_track(4, status=TrackStatus.LOST, position_m=(0.0, 0.0, 9.0))
    assert miss_reason([tentative, far_on_sight], t_true, radius) == "wrong_range"
    assert miss_reason([tentative, elsewhere], t_true, radius) == "unconfirmed"
    assert miss_reason([elsewhere, lost], t_true, radius) == "unseen"
    assert miss_reason([], t_true, radius) == "unseen"


def test_front_back_verdict_is_the_classifiers_word_for_the_true_order():
    truth = np.array([[110.0, 90.0], [90.0, 90.0], [90.0, 110.0], [110.0, 110.0]])

    def det(kp, p):
        return KeypointDetection(np.asarray(kp, float), 1.0, (0, 0, 200), heading_p=p)

    assert front_back_verdict(det(truth + 0.5, 0.8), truth) == 1.0
    assert front_back_verdict(det(truth[HEADING_TWIN], 0.8), truth) == 0.0  # sure of the twin
    assert front_back_verdict(det(truth[HEADING_TWIN], 0.3), truth) == 1.0  # turned, p with it
    assert np.isnan(front_back_verdict(det(truth, 0.5), truth))  # no answer
    assert np.isnan(front_back_verdict(det(truth, float("nan")), truth))  # no classifier
    assert np.isnan(front_back_verdict(det(truth + 50.0, 0.9), truth))  # another object
    collapsed = np.tile(truth.mean(axis=0), (4, 1))  # both orders equally far: undecided
    assert np.isnan(front_back_verdict(det(collapsed, 0.9), truth))
    assert np.isnan(front_back_verdict(None, truth))


def test_axis_exchanged_tells_a_quarter_turned_order_from_one_that_keeps_the_axes():
    # a Mini 2 from above: 131 mm along the body (image x), 168 mm across (image y), 1 px per mm
    truth = np.array([[65.5, 84.0], [-65.5, 84.0], [-65.5, -84.0], [65.5, -84.0]]) + 200.0
    for kept in ((0, 1, 2, 3), (2, 3, 0, 1), (3, 2, 1, 0), (1, 0, 3, 2)):  # twin and mirrors keep it
        assert axis_exchanged(truth[list(kept)] + 1.0, truth) == 0.0
    for turned in ((1, 2, 3, 0), (3, 0, 1, 2), (0, 3, 2, 1), (2, 1, 0, 3)):
        assert axis_exchanged(truth[list(turned)], truth) == 1.0
    assert np.isnan(axis_exchanged(truth + 300.0, truth))  # another object
    assert np.isnan(axis_exchanged(np.tile(truth.mean(axis=0), (4, 1)), truth))  # collapsed: undecided
    assert np.isnan(axis_exchanged(np.full((4, 2), np.nan), truth))


def test_summary_counts_detections_whose_order_exchanges_the_axes():
    s = _scores([False] * 4, [True] * 4, [False] * 4, [False] * 4, [[0, 0, 0]] * 4)
    square = np.array([[60.0, 80.0], [-60.0, 80.0], [-60.0, -80.0], [60.0, -80.0]])
    s.kp_true[:] = square
    s.kp_pred[:] = square
    s.kp_pred[1] = square[[1, 2, 3, 0]]  # a quarter turn
    s.has_pred[3] = False  # no detection: not counted
    s.axis_exchanged = np.array(  # as score_sequence records it, frame by frame
        [
            axis_exchanged(p, t) if has else np.nan
            for p, t, has in zip(s.kp_pred, s.kp_true, s.has_pred, strict=True)
        ]
    )
    out = summarise([s])
    assert out["axis_frames"] == 3 and out["axis_exchanged_pct"] == pytest.approx(33.33)


def test_keypoint_error_forgives_the_front_back_twin_but_not_a_quarter_turn():
    truth = np.array([[65.5, 84.0], [-65.5, 84.0], [-65.5, -84.0], [65.5, -84.0]]) + 200.0
    shifted = truth + np.array([3.0, 4.0])
    detections = np.stack([shifted, shifted[list(HEADING_TWIN)], truth[[1, 2, 3, 0]]])
    err = keypoint_error_px(detections, truth[None])
    np.testing.assert_allclose(err[:2], 5.0)  # in order and its twin: 5 px each
    assert err[2].min() > 100  # turned a quarter: each keypoint on a neighbour's hub
    assert np.isnan(keypoint_error_px(truth + 300.0, truth)).all()  # another object
    assert np.isnan(keypoint_error_px(np.full((4, 2), np.nan), truth)).all()


def test_oracle_keypoints_measure_the_pose_stage_alone(tiny):
    out, _ = tiny
    # The same renders, no network: the true keypoints go through PnP and the tracker.
    exact = run_robustness(out, **TINY, oracle_noise_px=0.0)
    assert exact.settings["oracle_noise_px"] == 0.0 and exact.settings["reused_sequences"] == 4
    rows = {(by, value): summary for by, value, summary in exact.group_summaries()}
    drone = rows[("all", "drone sequences")]
    # the filter's constant-velocity lag over its first hits: centimetres
    assert drone["rmse_m"] < 0.05 and drone["mae_angle_deg"] < 1.0 and drone["kp_err_px_median"] == 0.0
    assert drone["detected_pct"] == pytest.approx(100 * 8 / 12, abs=0.01)  # confirmed from the 3rd hit on
    assert rows[("drone-free", "drone-free")]["false_track_frames"] == 0  # nothing to track
    assert "ORACLE: no network, the true keypoints with 0 px of noise" in exact.table().splitlines()[0]
    # Half a pixel on drones a few pixels across (320 x 180): the pose stage's error rises.
    noisy = run_robustness(out, **TINY, oracle_noise_px=0.5)
    drone = {(by, v): s for by, v, s in noisy.group_summaries()}[("all", "drone sequences")]
    assert 0.45 < drone["kp_err_px_median"] < 0.75  # 1.18 sigma: the median of a 2-D Gaussian's radius
    assert drone["rmse_m"] > rows[("all", "drone sequences")]["rmse_m"]
    again = {(by, v): s for by, v, s in run_robustness(out, **TINY, oracle_noise_px=0.5).group_summaries()}
    assert again[("all", "drone sequences")] == drone  # seeded by the scene seeds


def test_wrong_heading_is_a_geodesic_angle_over_90_deg():
    # The front/back twin (180 deg of yaw) is the case the metric is for.
    from dronekey.geometry.rotations import geodesic_angle_deg

    R = rotation_from_euler_deg(30.0, 5.0, -3.0)
    twin = rotation_from_euler_deg(210.0, -5.0, 3.0)
    assert geodesic_angle_deg(R, twin) > WRONG_HEADING_DEG


def test_report_json_keys_and_drone_free_frames(tiny):
    _, report = tiny
    d = json.loads(json.dumps(report.to_dict()))
    assert set(d) == {"settings", "groups", "sequences"}
    assert d["settings"]["seed_set"] == "reporting" and d["settings"]["seeds"] == [matrix.REPORTING_SEED]
    assert d["settings"]["reused_sequences"] == 0
    assert len(d["sequences"]) == 4
    for seq in d["sequences"]:
        assert set(seq) >= METRICS
        assert set(seq) >= ENTRY_KEYS
        assert seq["frames"] == 6 and not seq["reused"]
    assert [s["far"] for s in d["sequences"][:2]] == [True, False]
    rows = {(g["by"], g["value"]): g for g in d["groups"]}
    assert set(rows) == {
        ("leds", "red-front"),
        ("leds", "off"),
        ("background", "photos"),
        ("motion", "seq13"),
        ("range", "near"),
        ("range", "far x2.5"),
        ("all", "drone sequences"),
        ("drone-free", "drone-free"),
    }
    for g in d["groups"]:
        assert set(g) >= METRICS
    # Every drone-free frame is scored, with or without an annotation.
    free = rows[("drone-free", "drone-free")]
    assert free["sequences"] == 2 and free["frames"] == 12
    assert 0 <= free["false_track_frames"] <= 12
    assert free["false_tracks_per_1000_frames"] == pytest.approx(
        1000 * free["false_track_frames"] / 12, abs=0.01
    )
    assert free["ap_kp"] is None and free["detected_pct"] is None
    drone = rows[("all", "drone sequences")]
    assert drone["frames"] == 12 and 0 <= drone["detected_pct"] <= 100
    assert drone["detected_pct"] + drone["missed_wrong_range_pct"] + drone["missed_unconfirmed_pct"] + drone[
        "missed_unseen_pct"
    ] == pytest.approx(100.0, abs=0.05)
    table = report.table()
    assert "leds red-front" in table and "drone-free" in table and "far x2.5" in table
    # The second table (missed frames, front/back per detection) has no drone-free row.
    second = table[table.index("frames without the drone's track") :]
    assert "leds red-front" in second and "unconf" in second and "drone-free" not in second
    assert "ang fr" in second and 0 <= drone["front_shown_pct"] <= 100  # the rendered looks are named


def test_rerun_reuses_the_renders(tiny):
    out, first = tiny
    paths = [s.rendered.json_path for s in first.sequences]
    stamps = [os.stat(p).st_mtime_ns for p in paths]
    again = run_robustness(out, **{**TINY, "leds": ("red-front",), "drone_free": 1})
    assert again.settings["reused_sequences"] == 2
    assert all(s.rendered.reused for s in again.sequences)
    assert [os.stat(p).st_mtime_ns for p in paths] == stamps
    # Other settings are another sequence: rendered, the earlier one left alone.
    longer = run_robustness(out, **{**TINY, "leds": ("red-front",), "drone_free": 0, "frames": 7})
    assert longer.settings["reused_sequences"] == 0
    assert longer.sequences[0].rendered.json_path != paths[0]
    assert os.stat(paths[0]).st_mtime_ns == stamps[0]


def test_a_render_from_another_renderer_is_rendered_again(tmp_path):
    one = {**TINY, "leds": ("off",), "drone_free": 0}
    first = run_robustness(tmp_path, **one).sequences[0].rendered.json_path
    doc = json.loads(first.read_text())
    assert doc["info"]["renderer"] == renderer_fingerprint()
    doc["info"]["renderer"] = "source 000000000000; av 0.0"  # as an older simulator or encoder wrote it
    first.write_text(json.dumps(doc))
    again = run_robustness(tmp_path, **one)
    assert again.settings["reused_sequences"] == 0
    assert json.loads(first.read_text())["info"]["renderer"] == renderer_fingerprint()
    assert run_robustness(tmp_path, **one).settings["reused_sequences"] == 1


def test_select_scores_only_the_matching_sequences_with_their_matrix_seeds(tiny):
    out, first = tiny
    free = [s for s in first.sequences if s.rendered.entry.no_drone]
    only = run_robustness(out, **TINY, select=["*nodrone*"])
    assert [s.rendered.entry for s in only.sequences] == [s.rendered.entry for s in free]
    assert only.settings["reused_sequences"] == len(free)  # same seeds, so the same renders
    assert only.settings["select"] == ["*nodrone*"]


def test_cli_json_then_table(tmp_path, capsys):
    argv = ["robustness", "--out", str(tmp_path), "--quick", "--frames", "3", "--size", "320x180"]
    assert main([*argv, "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["settings"]["backgrounds"] == list(matrix.QUICK_BACKGROUNDS)
    assert len(d["sequences"]) == 4 * 3 + matrix.QUICK_DRONE_FREE
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("robustness: reporting seeds 7001")
    assert any(line.startswith("drone-free") for line in lines)


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--frames", "0"], "--frames must be positive, got 0"),
        (["--seeds", "-3"], "--seeds must be >= 0, got -3"),
        (["--size", "12"], "--size must be WIDTHxHEIGHT"),
        (["--size", "0x10"], "--size must be positive"),
        (["--model", "/nonexistent.onnx"], "--model not found"),
        (["--seeds", "6001"], "overlap the tuning seeds"),
        (["--tuning", "--seeds", "7001"], "overlap the reporting seeds"),
        (["--drone-free", "-1"], "--drone-free must be >= 0, got -1"),
        (["--select", "s99*"], "select ['s99*'] matches no sequence"),
        (["--front-back", "/nonexistent.onnx"], "--front-back not found"),
        (["--front-back", "deep", "--select", "s99*"], "matches no sequence"),  # a shipped name is no file
        (["--tracker", "confirm_hitz=3"], "--tracker: TrackerConfig has no setting 'confirm_hitz'; known: "),
        (["--tracker", "confirm_hits"], "--tracker takes KEY=VALUE, got 'confirm_hits'"),
        (["--tracker", "confirm_hits=0"], "--tracker: TrackerConfig.confirm_hits must be an integer >= 1"),
        (["--localizer", "use_motion=maybe"], "--localizer use_motion must be true or false, got 'maybe'"),
        (["--localizer", "max_candidates=2.5"], "--localizer max_candidates must be an integer, got '2.5'"),
        (["--oracle-noise", "1", "--model", "m.onnx"], "--oracle-noise runs no network, so --model would do"),
        (["--oracle-noise", "0", "--measure-every", "2"], "so --measure-every would do nothing"),
        (["--oracle-noise", "nan"], "--oracle-noise must be a finite number >= 0 px, got nan"),
    ],
)
def test_bad_arguments_are_one_line(extra, message, tmp_path, capsys):
    assert main(["robustness", "--out", str(tmp_path / "out"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("dronekey-eval: error:") and message in err[0]
    assert not (tmp_path / "out").exists()  # nothing rendered


def test_out_must_be_a_folder(tmp_path, capsys):
    path = tmp_path / "file"
    path.write_text("x")
    assert main(["robustness", "--out", str(path)]) == 2
    assert "--out must be a folder" in capsys.readouterr().err


def test_dither_adds_at_most_one_grey_level_reproducibly():
    """Each pixel and channel moves by -1, 0 or +1 (about a third each), saturating at 0 and 255;
    the same seed gives the same noise, another seed other noise, and the input is left alone."""
    from dronekey.evaluation.robustness.dither import FrameDither
    from dronekey.types import Frame

    image = np.full((60, 80, 3), 128, np.uint8)
    image[0] = 0
    image[1] = 255
    frame = Frame(3, 100, image)
    a, b, other = FrameDither(5)(frame).bgr, FrameDither(5)(frame).bgr, FrameDither(6)(frame).bgr
    step = a.astype(int) - image
    assert set(np.unique(step[2:])) == {-1, 0, 1}
    assert all(0.3 < np.mean(step[2:] == v) < 0.37 for v in (-1, 0, 1))
    assert a[0].min() == 0 and a[0].max() <= 1 and a[1].max() == 255 and a[1].min() >= 254
    assert np.array_equal(a, b) and not np.array_equal(a, other)
    assert np.array_equal(frame.bgr, image)
    nxt = FrameDither(5)(Frame(4, 133, image)).bgr
    assert not np.array_equal(nxt, a)  # the next frame's noise is drawn apart
    with pytest.raises(ValueError, match="seed must be an integer >= 0, got -1"):
        FrameDither(-1)


def test_cli_dither_is_recorded_and_named_in_the_table(tmp_path, capsys):
    argv = ["robustness", "--out", str(tmp_path), "--quick", "--frames", "2", "--size", "320x180"]
    argv += ["--drone-free", "1", "--select", "*nodrone*", "--dither", "9"]
    assert main([*argv, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["settings"]["dither"] == 9
    assert main(argv) == 0
    assert "frames dithered (seed 9)" in capsys.readouterr().out.splitlines()[0]
    assert main(["robustness", "--out", str(tmp_path), "--dither", "-2"]) == 2
    assert "--dither must be >= 0, got -2" in capsys.readouterr().err


# (flag, value, settings key, recorded value, words in the table's first line, a bad value, its error)
SETTINGS_UNDER_MEASURE = [
    ("--confirm-max-outliers", "1", "confirm_max_outliers", 1, "confirmation leaving out 1 outlying hit(s)",
     "-1", "--confirm-max-outliers must be >= 0, got -1"),
    ("--acquire-recut", "0.25", "acquire_recut", 0.25, "search recut 0.25",
     "0", "--acquire-recut must be > 0, got 0.0"),
    ("--heading-full-spread", "43.5", "heading_full_spread_px", 43.5, "sure from hubs 43.5 px",
     "-1", "--heading-full-spread must be a finite number >= 0, got -1.0"),
    ("--measure-every", "2", "measure_every", 2, "confirmed drones measured every 2 frames",
     "0", "--measure-every must be >= 1, got 0"),
    ("--oracle-noise", "1", "oracle_noise_px", 1.0, "ORACLE: no network, the true keypoints with 1 px",
     "-1", "--oracle-noise must be a finite number >= 0 px, got -1.0"),
]  # fmt: skip


def test_cli_pipeline_settings_under_measure_are_recorded_and_named_in_the_table(tmp_path, capsys):
    argv = ["robustness", "--out", str(tmp_path), "--quick", "--frames", "2", "--size", "320x180"]
    argv += ["--drone-free", "1", "--select", "*nodrone*"]
    assert main([*argv, "--json"]) == 0
    settings = json.loads(capsys.readouterr().out)["settings"]
    assert settings["acquire_recut"] is None and settings["confirm_max_outliers"] == 0  # as shipped
    assert settings["heading_full_spread_px"] == 0.0 and settings["measure_every"] == 1
    assert settings["oracle_noise_px"] is None
    for flag, value, key, recorded, words, bad, error in SETTINGS_UNDER_MEASURE:
        assert main([*argv, flag, value, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["settings"][key] == recorded
        assert main([*argv, flag, value]) == 0
        assert words in capsys.readouterr().out.splitlines()[0]
        assert main(["robustness", "--out", str(tmp_path), flag, bad]) == 2
        assert error in capsys.readouterr().err


def test_range_z_is_the_range_error_over_the_stated_doubt_along_the_line_of_sight():
    track = make_track(position_m=(0.0, 3.0, 4.0), position_cov=np.diag([9.0, 0.16, 0.09]))  # range 5 m
    u = np.array([0.0, 0.6, 0.8])
    sd = float(np.sqrt(u @ np.diag([9.0, 0.16, 0.09]) @ u))  # the 9 m^2 across the ray does not count
    assert range_z(track, np.array([0.0, 0.0, 4.5])) == pytest.approx(0.5 / sd)
    assert range_z(track, np.array([0.0, 6.0, 8.0])) == pytest.approx(-5.0 / sd)
    assert np.isnan(range_z(make_track(position_m=(0.0, 3.0, 4.0), position_cov=np.zeros((3, 3))), [0, 0, 5]))


def test_summary_counts_frames_whose_range_lies_within_one_and_two_stated_deviations():
    s = _scores([False] * 5, [True] * 5, [False] * 5, [False] * 5, [[0, 0, 0]] * 5)
    s.range_z = np.array([0.2, -0.9, 1.5, -3.0, np.nan])  # the last: no track on the drone
    out = summarise([s])
    assert out["range_doubt_frames"] == 4
    assert out["range_within_1sd_pct"] == pytest.approx(50.0)
    assert out["range_within_2sd_pct"] == pytest.approx(75.0)


def test_position_m2_is_the_true_positions_squared_mahalanobis_distance_under_the_published_cov():
    track = make_track(position_m=(0.0, 3.0, 4.0), position_cov=np.diag([4.0, 0.25, 1.0]))
    assert position_m2(track, np.array([2.0, 3.5, 3.0])) == pytest.approx(1.0 + 1.0 + 1.0)
    assert np.isnan(position_m2(make_track(position_m=(0, 3, 4), position_cov=np.zeros((3, 3))), [0, 0, 5]))


def test_summary_counts_positions_within_two_deviations_measured_and_coasting_apart():
    s = _scores([False] * 6, [True] * 6, [False] * 6, [False] * 6, [[0, 0, 0]] * 6)
    s.position_m2 = np.array([1.0, 9.0, 2.0, 20.0, 3.0, np.nan])  # the last: no track on the drone
    s.coasting = np.array([False, False, False, True, True, False])
    out = summarise([s])
    assert out["position_within_2sd_measured_pct"] == 66.67  # 1 and 2 of 1, 9, 2 (rounded to 2 places)
    assert out["coasting_frames"] == 2
    assert out["position_within_2sd_coasting_pct"] == pytest.approx(50.0)  # 3 of 20 and 3


def test_cli_any_tracker_or_localizer_setting_is_measured_recorded_and_named(tmp_path, capsys):
    """``--tracker`` / ``--localizer KEY=VALUE`` set any field of the two configs for the run; the
    report's settings list the fields that differ from the shipped ones, and the table names them."""
    argv = ["robustness", "--out", str(tmp_path), "--quick", "--frames", "2", "--size", "320x180"]
    argv += ["--drone-free", "1", "--select", "*nodrone*"]
    assert main([*argv, "--json"]) == 0
    settings = json.loads(capsys.readouterr().out)["settings"]
    assert settings["tracker_changed"] == {} and settings["localizer_changed"] == {}  # as shipped
    extra = ["--tracker", "confirm_min_presence=0.9", "--tracker", "max_tracks=2"]
    extra += ["--localizer", "max_candidates=4", "--localizer", "acquire_recut=null"]
    extra += ["--confirm-max-outliers", "1"]
    assert main([*argv, *extra, "--json"]) == 0
    settings = json.loads(capsys.readouterr().out)["settings"]
    changed = {"max_tracks": 2, "confirm_max_outliers": 1, "confirm_min_presence": 0.9}
    assert settings["tracker_changed"] == changed
    assert settings["localizer_changed"] == {"max_candidates": 4}  # null is the shipped value
    assert main([*argv, *extra]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "localizer max_candidates=4" in first and "tracker max_tracks=2, confirm_max_outliers=1" in first


def test_overrides_are_read_as_the_fields_types():
    from dronekey.evaluation.config_overrides import (
        OverrideError,
        changed_settings,
        config_with_overrides,
        parse_overrides,
    )
    from dronekey.perception.localizer import LocalizerConfig
    from dronekey.tracking.tracker_config import TrackerConfig

    pairs = ["use_motion=off", "acquire_recut=0.25", "max_candidates= 3 ", "presence_threshold=0.6"]
    got = parse_overrides(pairs, LocalizerConfig, "-L")
    assert got == {"use_motion": False, "acquire_recut": 0.25, "max_candidates": 3, "presence_threshold": 0.6}
    assert type(got["max_candidates"]) is int and type(got["presence_threshold"]) is float
    assert parse_overrides(["acquire_recut=None"], LocalizerConfig, "-L") == {"acquire_recut": None}
    with pytest.raises(OverrideError, match="-L: max_candidates given twice"):
        parse_overrides(["max_candidates=3", "max_candidates=4"], LocalizerConfig, "-L")
    with pytest.raises(OverrideError, match="-L presence_threshold must be a number, got 'nan'"):
        parse_overrides(["presence_threshold=nan"], LocalizerConfig, "-L")
    with pytest.raises(OverrideError, match="-L max_candidates must be an integer, got 'null'"):
        parse_overrides(["max_candidates=null"], LocalizerConfig, "-L")  # not a field that may be None
    config = config_with_overrides(TrackerConfig, {"max_tracks": 2}, "-T", max_tracks=3, confirm_hits=4)
    assert (config.max_tracks, config.confirm_hits) == (2, 4)  # the overrides win over the base
    with pytest.raises(OverrideError, match=r"^-T: .*presence_threshold"):
        config_with_overrides(LocalizerConfig, {"presence_threshold": 1.5}, "-T")
    assert changed_settings(config, TrackerConfig) == {"confirm_hits": 4, "max_tracks": 2}
    assert changed_settings(None, TrackerConfig) == {}
