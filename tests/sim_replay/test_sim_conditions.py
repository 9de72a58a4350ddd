"""Rendering conditions of the simulator's sequences: the drone-style seed, LED modes and blinking,
drone-free sequences, coordinated flight, background kinds, range scale, and their CLI options."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dronekey.geometry.rotations import rotation_from_euler_deg
from dronekey.sim_replay import synthetic_sequence
from dronekey.sim_replay.backgrounds import HELD_OUT_PHOTOS, packaged_photos
from dronekey.sim_replay.cli import main
from dronekey.sim_replay.drone_look import BodyShape, DroneLook
from dronekey.sim_replay.flight import CoordinatedFlight, finite_differences, tilt_for_thrust
from dronekey.sim_replay.io.frames import iter_frames
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.synthetic_sequence import build_sequence, style_seed_for

W, H = 480, 270
SMALL = ["--width", str(W), "--height", str(H)]


def run_cli(argv: list[str]) -> int:
    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)


def frames_of(seq) -> list:
    return list(seq)


def outside(box_list, shape, pad: int = 3) -> np.ndarray:
    """Mask of the pixels outside every (dilated) box (x, y, w, h)."""
    mask = np.ones(shape[:2], bool)
    for x, y, w, h in box_list:
        x0, y0 = max(int(x) - pad, 0), max(int(y) - pad, 0)
        mask[y0 : int(math.ceil(y + h)) + pad + 1, x0 : int(math.ceil(x + w)) + pad + 1] = False
    return mask


def yaw_deg(R_ned_body: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(R_ned_body).as_euler("ZYX", degrees=True)[..., 0]


def wrap(angle):
    return (np.asarray(angle) + 180.0) % 360.0 - 180.0


# ---------------------------------------------------------------------------------- flight model


def test_accelerating_north_pitches_the_nose_down():
    a = 2.0  # m/s^2 north
    times = np.arange(0, 60) / 30.0
    att = CoordinatedFlight().attitudes_along(lambda t: np.array([0.5 * a * t * t, 0.0, -2.0]), times, 0.0)
    for yaw, pitch, roll in att[15:]:
        assert abs(yaw) < 1e-6 and abs(roll) < 1e-6
        assert pitch == pytest.approx(-math.degrees(math.atan2(a, 9.81)), abs=1e-3)
        x_body = rotation_from_euler_deg(yaw, pitch, roll)[:, 0]  # the nose in NED
        assert x_body[0] > 0.95 and x_body[2] > 0.1  # towards north, below the horizon
        thrust = -rotation_from_euler_deg(yaw, pitch, roll)[:, 2]
        assert np.allclose(thrust, np.array([a, 0, -9.81]) / math.hypot(a, 9.81))


def test_yaw_follows_a_turning_path_and_banks_into_the_turn():
    r, w = 5.0, 0.5  # a right turn (north, then east, south...) at 2.5 m/s, 15 s: 1.2 turns
    times = np.arange(0, 450) / 30.0

    def position(t):
        return np.array([r * math.sin(w * t), r * (1 - math.cos(w * t)), -3.0])

    att = CoordinatedFlight().attitudes_along(position, times, initial_yaw_deg=120.0)
    v, _ = finite_differences(position, times, 0.01)
    heading = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    assert att[0, 0] == pytest.approx(0.0, abs=1e-6)  # moving: starts along the velocity
    lag = np.abs(wrap(att[30:, 0] - heading[30:]))
    assert lag.max() < 10.0  # the smoothed heading trails the velocity by rate x time constant
    assert np.ptp(np.unwrap(np.radians(att[:, 0]))) > 2 * math.pi  # a full turn, through +-180
    bank = math.degrees(math.atan2(r * w * w, 9.81))
    assert np.allclose(att[30:, 2], bank, atol=0.2)
    assert np.all(np.abs(att[30:, 1]) < 1.0)  # the heading's lag turns a little of the bank into pitch


def test_slow_or_hovering_drone_holds_its_heading_and_stays_level():
    times = np.arange(0, 30) / 30.0
    att = CoordinatedFlight().attitudes_along(lambda t: np.array([3.0, 0.1 * t, -2.0]), times, 30.0)
    assert np.allclose(att, [30.0, 0.0, 0.0], atol=1e-6)


def test_tilt_is_limited_and_bad_parameters_are_named():
    pitch, roll = tilt_for_thrust(0.0, np.array([100.0, 0.0, 0.0]), max_tilt_deg=45.0)
    assert pitch == pytest.approx(-45.0) and roll == pytest.approx(0.0, abs=1e-9)
    assert tilt_for_thrust(10.0, np.array([0.0, 0.0, 20.0])) == (0.0, 0.0)  # >1 g down: level
    with pytest.raises(ValueError, match="max_tilt_deg must be in"):
        CoordinatedFlight(max_tilt_deg=0)
    with pytest.raises(ValueError, match="min_speed_mps must be >= 0, got -1"):
        CoordinatedFlight(min_speed_mps=-1)
    with pytest.raises(ValueError, match="times_s must not decrease"):
        CoordinatedFlight().attitudes(np.zeros((2, 3)), np.zeros((2, 3)), [1.0, 0.0])


def test_coordinated_sequence_yaw_follows_velocity():
    seq = build_sequence("seq13", frames=90, flight="coordinated", width=W, height=H)
    path = seq.flight_path()
    v = np.gradient(path.positions_ned, path.times_s, axis=0)
    heading = np.degrees(np.arctan2(v[:, 1], v[:, 0]))
    assert np.all(np.hypot(v[:, 0], v[:, 1]) > 0.3)
    assert np.abs(wrap(yaw_deg(path.R_ned_body) - heading))[5:-1].max() < 25.0
    scripted = build_sequence("seq13", frames=90, width=W, height=H).flight_path()
    assert np.allclose(scripted.positions_ned, path.positions_ned)  # the same path, other attitude
    assert np.abs(wrap(yaw_deg(scripted.R_ned_body) - heading)).max() > 45.0
    # The rendered annotations carry that attitude.
    for i, frame in enumerate(
        frames_of(build_sequence("seq13", frames=3, flight="coordinated", width=W, height=H))
    ):
        R, t = path.camera_pose(i)
        assert np.allclose(frame.record.drone.rotation, R) and np.allclose(frame.record.drone.translation, t)
    assert seq.info["flight"] == "coordinated"


# ---------------------------------------------------------------------------------- the drone's look


def test_style_seed_changes_the_look_but_not_the_annotation():
    a = frames_of(build_sequence("seq13", frames=3, style_seed=1, width=W, height=H))
    b = frames_of(build_sequence("seq13", frames=3, style_seed=2, width=W, height=H))
    for fa, fb in zip(a, b, strict=True):
        da, db = fa.record.drone, fb.record.drone
        assert np.array_equal(da.keypoints_px, db.keypoints_px)
        assert np.array_equal(da.rotation, db.rotation) and np.array_equal(da.translation, db.translation)
        away = outside([da.bbox_xywh, db.bbox_xywh], fa.image.shape)
        assert np.array_equal(fa.image[away], fb.image[away])  # the same scene around the drone
        assert np.abs(fa.image.astype(int) - fb.image.astype(int))[~away].max() > 40  # another drone
    assert DroneLook.draw(1) != DroneLook.draw(2)


def test_default_style_seed_is_derived_from_the_seed_and_recorded():
    seq = build_sequence("seq12", seed=8, frames=2, width=W, height=H)
    assert seq.info["style_seed"] == style_seed_for(8) != style_seed_for(9)
    explicit = build_sequence("seq12", seed=8, frames=2, width=W, height=H, style_seed=style_seed_for(8))
    for fa, fb in zip(frames_of(seq), frames_of(explicit), strict=True):
        assert np.array_equal(fa.image, fb.image)


def test_cue_free_draws_the_same_drone_with_no_front_back_cue():
    nose_gimbal = next(s for s in range(100) if DroneLook.draw(s).shape.gimbal == "nose")
    look, symmetric = DroneLook.draw(nose_gimbal), DroneLook.draw(nose_gimbal, cue_free=True)
    assert look.shape.shows_front(from_above=False) and look.shape.shows_front(from_above=True)
    assert not symmetric.shape.shows_front(from_above=True)
    assert not symmetric.shape.shows_front(from_above=False)
    assert symmetric.style == look.style and symmetric.shape.length == look.shape.length
    # cues on the top shell are seen from above only
    battery_only = BodyShape(battery=0.3, gimbal="none", stripe="none")
    assert battery_only.shows_front(from_above=True) and not battery_only.shows_front(from_above=False)
    a = frames_of(build_sequence("seq13", frames=2, style_seed=nose_gimbal, width=W, height=H))
    b = frames_of(build_sequence("seq13", frames=2, style_seed=nose_gimbal, width=W, height=H, cue_free=True))
    assert np.array_equal(a[0].record.drone.keypoints_px, b[0].record.drone.keypoints_px)
    assert not np.array_equal(a[0].image, b[0].image)  # the nose gimbal is gone


def _steady_motor_led_seed() -> int:
    """A style seed whose forced LEDs sit under the motors and do not blink."""
    for s in range(200):
        look = DroneLook.draw(s, "red-front")
        if look.blink_hz is None and look.shape.led_place == "motor":
            return s
    raise AssertionError("no style seed with steady motor LEDs")


def test_led_modes_change_only_the_led_pixels_red_at_the_front():
    s = _steady_motor_led_seed()
    kw = dict(frames=1, style_seed=s, width=960, height=540)
    looks = {mode: DroneLook.draw(s, mode) for mode in ("red-front", "green-front", "off")}
    assert looks["off"].shape == looks["red-front"].shape  # one drone in every mode
    assert looks["off"].style.body == looks["red-front"].style.body
    assert looks["off"].style.front_led is None and looks["off"].style.rear_led is None
    off = next(iter(build_sequence("seq13", leds="off", **kw)))
    kp = off.record.drone.keypoints_px
    front, rear = kp[[0, 3]].mean(axis=0), kp[[1, 2]].mean(axis=0)  # keypoints 1 FR, 4 FL / 2 RR, 3 RL
    for mode, (near_front, near_rear) in {"red-front": (2, 1), "green-front": (1, 2)}.items():
        lit = next(iter(build_sequence("seq13", leds=mode, **kw)))
        assert np.array_equal(lit.record.drone.keypoints_px, kp)
        changed = np.abs(lit.image.astype(int) - off.image.astype(int)).max(axis=2) > 25
        assert changed.sum() >= 4, mode
        assert not np.any(changed & outside([off.record.drone.bbox_xywh], off.image.shape)), mode
        ys, xs = np.nonzero(changed)
        pts = np.c_[xs, ys].astype(float)
        at_front = np.linalg.norm(pts - front, axis=1) < np.linalg.norm(pts - rear, axis=1)
        colours = lit.image[ys, xs].astype(float)  # BGR
        for where, channel in ((at_front, near_front), (~at_front, near_rear)):
            assert where.sum() >= 2, mode
            other = 3 - channel  # red (2) against green (1)
            assert colours[where, channel].mean() > colours[where, other].mean() + 30, (mode, where.sum())


def test_blinking_leds_go_dark_in_their_off_phase():
    s = next(s for s in range(200) if DroneLook.draw(s, "red-front").blink_hz is not None)
    look = DroneLook.draw(s, "red-front")
    period = 1.0 / look.blink_hz
    assert 1.0 <= look.blink_hz <= 2.0
    t_on = next(t for t in np.arange(0, 1, 0.01) if look.leds_on(t))
    t_off = next(t for t in np.arange(0, 1, 0.01) if not look.leds_on(t))
    assert look.style_at(t_on).front_led is not None and look.style_at(t_off).front_led is None
    assert look.leds_on(t_on + period) and not look.leds_on(t_off + 3 * period)
    steady = DroneLook.draw(s, "off")  # nothing lit, nothing blinks
    assert steady.blink_hz is None and not steady.leds_on(t_on)
    # Rendered: the off-phase frames are those of the same drone with its LEDs off, the others not.
    kw = dict(frames=30, style_seed=s, width=W, height=H)
    blinking = frames_of(build_sequence("seq13", leds="red-front", **kw))
    dark = frames_of(build_sequence("seq13", leds="off", **kw))
    on = [look.leds_on(i / 30.0) for i in range(30)]
    assert any(on) and not all(on)
    for lit, b, d in zip(on, blinking, dark, strict=True):
        assert np.array_equal(b.image, d.image) != lit


# ---------------------------------------------------------------------------------- conditions


def test_range_scale_shrinks_the_drone():
    near = next(iter(build_sequence("seq11", frames=1, width=960, height=540))).record.drone
    far = next(iter(build_sequence("seq11", frames=1, width=960, height=540, range_scale=2.5))).record.drone
    assert np.allclose(far.translation, 2.5 * near.translation)
    assert np.array_equal(far.rotation, near.rotation)
    ratio = max(far.bbox_xywh[2:]) / max(near.bbox_xywh[2:])
    assert 0.8 / 2.5 < ratio < 1.2 / 2.5
    assert 15 <= max(far.bbox_xywh[2:]) <= 30  # 30-60 px at 1920x1080


def test_no_drone_sequence_has_moving_clutter_and_no_annotation():
    seq = build_sequence("seq11", no_drone=True, frames=30, width=W, height=H)
    assert build_sequence("2dronekey", no_drone=True).n_frames == 1000  # the preset's length
    frames = frames_of(seq)
    assert all(f.record.drone is None for f in frames)
    moved = np.abs(frames[0].image.astype(int) - frames[-1].image.astype(int)).max(axis=2) > 60
    assert moved.sum() > 20  # birds, objects and clouds crossed the frame in a second
    with_drone = next(iter(build_sequence("seq11", frames=1, width=W, height=H)))
    assert not np.array_equal(with_drone.image, frames[0].image)
    assert seq.info["no_drone"] is True and seq.info["leds_lit"] is False


def test_no_drone_files_read_back(tmp_path, capsys):
    assert run_cli(["--preset", "seq12", "--out", str(tmp_path), "--frames", "6", "--no-drone", *SMALL]) == 0
    assert "wrote 6 frames (0 annotated) of seq12" in capsys.readouterr().out
    doc = json.loads((tmp_path / "seq12.json").read_text())
    assert doc["annotations"] == [] and len(doc["images"]) == 6 and doc["info"]["no_drone"] is True
    seq = load_sequence(tmp_path / "seq12.json")
    assert len(seq.frames) == 6 and seq.annotated() == []
    read = list(iter_frames(seq))
    assert [f.index for f in read] == list(range(6)) and read[0].bgr.shape == (H, W, 3)
    assert run_cli(["--verify", str(tmp_path / "seq12.json")]) == 0
    assert "6 frames (0 annotated)" in capsys.readouterr().out


@pytest.mark.parametrize("kind", ["sky", "urban"])
def test_procedural_background_kinds(kind):
    seq = build_sequence("seq12", frames=1, background=kind, width=W, height=H)
    assert seq._backgrounds._kinds and len(seq._backgrounds._kinds) == 1
    assert next(iter(seq)).record.drone is not None and seq.info["background"] == kind


def test_held_out_photo_backgrounds():
    if not packaged_photos(HELD_OUT_PHOTOS):
        pytest.skip("neither scikit-image nor scikit-learn is installed")
    seq = build_sequence("seq12", frames=2, background="photos", width=W, height=H)
    frames = frames_of(seq)
    assert all(f.record.drone is not None for f in frames) and seq.info["background"] == "photos"
    procedural = next(iter(build_sequence("seq12", frames=1, width=W, height=H)))
    assert not np.array_equal(procedural.image, frames[0].image)


def test_photos_without_the_packages_is_a_clear_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(synthetic_sequence, "packaged_photos", lambda names: [])
    with pytest.raises(ImportError, match=r"needs the held-out packaged photos .*\(pip install scikit-image"):
        build_sequence("seq12", background="photos")
    assert run_cli(["--preset", "seq12", "--out", str(tmp_path), "--background", "photos"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("dronekey-sim: error: --background photos needs") and "\n" not in err


def test_info_records_the_conditions(tmp_path):
    argv = ["--preset", "seq13", "--out", str(tmp_path), "--frames", "2", *SMALL, "--style-seed", "5"]
    argv += [
        "--leds",
        "green-front",
        "--flight",
        "coordinated",
        "--background",
        "sky",
        "--range-scale",
        "1.5",
        "--cue-free",
    ]
    assert run_cli(argv) == 0
    info = json.loads((tmp_path / "seq13.json").read_text())["info"]
    keys = ("style_seed", "leds", "no_drone", "flight", "background", "range_scale", "cue_free")
    assert {k: info[k] for k in keys} == {
        "style_seed": 5,
        "leds": "green-front",
        "no_drone": False,
        "flight": "coordinated",
        "background": "sky",
        "range_scale": 1.5,
        "cue_free": True,
    }
    assert info["leds_lit"] is True and "led_blink_hz" in info
    assert load_sequence(tmp_path / "seq13.json").info["style_seed"] == 5


def test_bad_values_name_the_argument(tmp_path, capsys):
    cases = [
        (dict(leds="blue"), "leds must be one of red-front, green-front, off, random, got 'blue'"),
        (dict(flight="loop"), "flight must be one of scripted, coordinated, got 'loop'"),
        (dict(background="moon"), "background must be one of procedural, sky, urban, photos, got 'moon'"),
        (dict(range_scale=0), "range_scale must be a positive number, got 0"),
        (dict(range_scale=float("nan")), "range_scale must be a positive number, got nan"),
        (dict(style_seed=-3), "style_seed must be a non-negative integer, got -3"),
        (dict(background="photos", backgrounds=tmp_path), "cannot be combined with a backgrounds folder"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError) as info:
            build_sequence("seq13", **kwargs)
        assert message in str(info.value), (kwargs, str(info.value))

    out = ["--preset", "seq13", "--out", str(tmp_path / "out")]
    cli_cases = [
        (["--leds", "blue"], "argument --leds: invalid choice: 'blue'"),
        (["--flight", "loop"], "argument --flight: invalid choice: 'loop'"),
        (["--background", "moon"], "argument --background: invalid choice: 'moon'"),
        (["--range-scale", "0"], "argument --range-scale: must be a positive number, got '0'"),
        (["--range-scale", "far"], "argument --range-scale: must be a positive number, got 'far'"),
        (["--style-seed", "-1"], "argument --style-seed: must be a non-negative integer, got '-1'"),
        (
            ["--background", "photos", "--backgrounds", str(tmp_path)],
            "--background photos draws only the held-out packaged photos; it cannot be combined with "
            "--backgrounds",
        ),
    ]
    for extra, message in cli_cases:
        assert run_cli([*out, *extra]) == 2, extra
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("dronekey-sim: error: "), captured.err
        assert message in lines[0], (message, lines[0])
    assert not Path(tmp_path / "out").exists()
