"""Localiser and pipeline plumbing: candidate search on real rendered frames, boxes, empty frames."""

import itertools
import threading
from dataclasses import replace

import cv2
import numpy as np
import pytest
from daemon_media import write_untrained_model

from dronekey.geometry.camera import CalibrationError
from dronekey.geometry.drone_spec import load_spec
from dronekey.perception.localizer import LocalizerConfig, box_from_keypoints, box_from_pose, keypoint_spread
from dronekey.perception.plausibility import check_detection
from dronekey.pipeline import TrackingPipeline, _timed
from dronekey.sim_replay.backgrounds import landscape, sky, urban
from dronekey.sim_replay.drone_look import DroneStyle
from dronekey.sim_replay.mesh import build_mesh
from dronekey.sim_replay.presets import preset_camera
from dronekey.sim_replay.renderer import Lighting, render_drone
from dronekey.sim_replay.synthetic_sequence import build_sequence
from dronekey.types import Frame, TrackStatus

SPEC = load_spec("mini2")


def _contains(roi, box) -> bool:
    x0, y0, side = roi
    x, y, w, h = box
    return x0 <= x and y0 <= y and x + w <= x0 + side and y + h <= y0 + side


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    model = write_untrained_model(tmp_path_factory.mktemp("m") / "m.onnx")
    return TrackingPipeline(preset_camera(), model, drone=SPEC)


def test_box_from_pose_holds_the_rendered_drone():
    rf = next(iter(build_sequence("seq13", seed=3, frames=1)))
    ann = rf.record.drone
    x, y, w, h = box_from_pose(preset_camera(), SPEC, ann.rotation, ann.translation)
    bx, by, bw, bh = ann.bbox_xywh
    # The projected propeller discs cover the drawn drone (up to the body hanging below).
    assert x <= bx + 0.1 * bw and y <= by + 0.1 * bh
    assert x + w >= bx + 0.9 * bw and y + h >= by + 0.9 * bh
    _, _, kw, kh = box_from_keypoints(ann.keypoints_px, SPEC)
    assert kw > np.ptp(ann.keypoints_px[:, 0]) and kh > np.ptp(ann.keypoints_px[:, 1])


def test_behind_the_camera_has_no_box():
    assert box_from_pose(preset_camera(), SPEC, np.eye(3), np.array([0.0, 0.0, -3.0])) is None


@pytest.mark.parametrize("seed", [11, 12])
def test_acquisition_candidates_include_the_drone(pipeline, seed):
    rf = next(iter(build_sequence("seq11", seed=seed, frames=1)))
    rois = pipeline.localizer.candidate_rois(rf.image)
    assert 1 <= len(rois) <= LocalizerConfig().max_candidates
    centre = np.asarray(rf.record.drone.bbox_xywh[:2]) + np.asarray(rf.record.drone.bbox_xywh[2:]) / 2
    assert any(x0 <= centre[0] <= x0 + s and y0 <= centre[1] <= y0 + s for x0, y0, s in rois)


@pytest.mark.parametrize("background", [sky, landscape])
@pytest.mark.parametrize("size_px", [30, 600])
def test_acquisition_candidates_cover_drones_from_30_to_600_px(pipeline, size_px, background):
    """The ends of the size range the daemon must handle in a 1080p frame: some candidate crop holds
    the whole drone and is at most 3.5 times its size (the network then refines the crop)."""
    camera, rng = preset_camera(), np.random.default_rng(size_px)
    image = background(1080, 1920, rng)
    R = next(iter(build_sequence("seq13", seed=3, frames=1))).record.drone.rotation
    z = camera.fx * SPEC.extent_m / size_px
    t = z * np.array([(800 - camera.cx) / camera.fx, (500 - camera.cy) / camera.fy, 1.0])
    drone = render_drone(image, camera, build_mesh(SPEC), R, t, DroneStyle.random(rng), Lighting.random(rng))
    box = drone.bbox_xywh
    assert 0.8 * size_px <= max(box[2:]) <= 1.05 * size_px
    rois = pipeline.localizer.candidate_rois(image)
    assert any(_contains(roi, box) and roi[2] <= 3.5 * max(box[2:]) for roi in rois), (box, rois)


def test_a_drone_joined_to_wires_and_buildings_is_still_proposed(pipeline):
    """Wires across the frame join every salient thing into one region as big as the frame (a
    rendered seq13 frame did this): that region is searched at its peaks, and a drone seen moving
    (the motion map) is proposed on its own even inside it."""
    camera, rng = preset_camera(), np.random.default_rng(5)
    background = urban(1080, 1920, rng)
    R = next(iter(build_sequence("seq13", seed=3, frames=1))).record.drone.rotation
    z = camera.fx * SPEC.extent_m / 90
    frames, boxes = [], []
    for u in (1000, 1016):  # the drone moves 16 px between two frames
        image = background.copy()
        t = z * np.array([(u - camera.cx) / camera.fx, (650 - camera.cy) / camera.fy, 1.0])
        drone = render_drone(
            image, camera, build_mesh(SPEC), R, t, DroneStyle.random(rng), Lighting.random(rng)
        )
        cv2.line(image, (0, 180), (1919, 170), (20, 20, 20), 3)  # wires through the whole frame
        cv2.line(image, (1130, 200), (1010 + u - 1000, 1079), (20, 20, 20), 4)
        frames.append(image)
        boxes.append(drone.bbox_xywh)
    localizer = pipeline.localizer
    localizer._prev_small = None
    first = localizer.candidate_rois(frames[0])
    assert all(roi[2] <= 1.8 * LocalizerConfig().max_drone_px for roi in first)  # no frame-sized crop
    second = localizer.candidate_rois(frames[1])
    assert any(_contains(roi, boxes[1]) and roi[2] <= 3.5 * max(boxes[1][2:]) for roi in second), second


def test_empty_sky_gives_no_candidate_and_no_track(pipeline):
    sky = np.empty((1080, 1920, 3), np.uint8)
    sky[:] = np.linspace(200, 150, 1080, dtype=np.uint8)[:, None, None]  # a smooth gradient
    rng = np.random.default_rng(0)
    for i in range(3):
        noisy = np.clip(sky + rng.normal(0, 2, sky.shape), 0, 255).astype(np.uint8)
        out = pipeline.process(Frame(i, i * 33_333_333, noisy))
        assert out.detection is None and out.tracks == () and out.mode == "none"


def test_frame_of_the_wrong_size_is_refused(pipeline):
    with pytest.raises(CalibrationError, match="960x540"):
        pipeline.process(Frame(0, 0, np.zeros((540, 960, 3), np.uint8)))


def test_the_search_skips_live_regions_before_its_budget(pipeline):
    """Two drones in the sky; the first is a live track's region: the search's one candidate (its
    budget) goes to the second drone, not to the more salient first one."""
    camera, rng = preset_camera(), np.random.default_rng(8)
    image = sky(1080, 1920, rng)
    R = next(iter(build_sequence("seq13", seed=3, frames=1))).record.drone.rotation
    boxes = []
    for u, size_px in ((600, 160), (1300, 70)):  # the first, bigger drone is the more salient
        z = camera.fx * SPEC.extent_m / size_px
        t = z * np.array([(u - camera.cx) / camera.fx, (540 - camera.cy) / camera.fy, 1.0])
        style, light = DroneStyle.random(rng), Lighting.random(rng)
        drone = render_drone(image, camera, build_mesh(SPEC), R, t, style, light)
        boxes.append(drone.bbox_xywh)
    localizer = pipeline.localizer
    localizer._prev_small = None
    both = localizer.candidate_rois(image)
    assert any(_contains(roi, boxes[0]) for roi in both) and any(_contains(roi, boxes[1]) for roi in both)
    localizer._prev_small = None
    (only,) = localizer.candidate_rois(image, exclude=[boxes[0]], max_candidates=1)
    assert _contains(only, boxes[1]), (only, boxes)
    with pytest.raises(ValueError, match="max_candidates"):
        localizer.candidate_rois(image, max_candidates=0)


def test_a_saliency_pass_run_ahead_gives_the_candidates_the_search_would_find(pipeline):
    """The pipeline runs a periodic search's saliency pass on another thread while the track crops
    run, then selects candidates from it: the same crops as a pass run in place, and the pass
    still moves the motion reference on."""
    rng = np.random.default_rng(3)
    frames = [urban(1080, 1920, rng) for _ in range(2)]
    localizer = pipeline.localizer
    localizer._prev_small = None
    localizer.candidate_rois(frames[0])
    in_place = localizer.candidate_rois(frames[1], max_candidates=4)
    localizer._prev_small = None
    localizer.candidate_rois(frames[0])
    ahead, cpu_s = pipeline._helper.submit(_timed, localizer.saliency, frames[1]).result()
    assert cpu_s > 0.0
    assert localizer.candidate_rois(frames[1], max_candidates=4, saliency=ahead) == in_place
    assert localizer._prev_small is ahead.small
    with pytest.raises(ValueError, match="multiple of element size"):  # the thread's error reaches the caller
        pipeline._helper.submit(_timed, np.frombuffer, b"x", np.float64).result()


def test_every_early_saliency_pass_runs_on_one_long_lived_thread():
    """Shipped model, seq13, a search on every frame: the passes run ahead on one helper thread,
    the same thread every time (a thread per pass leaked OpenCV's per-thread data: +12.5 MiB an hour
    of one camera), never on the pipeline's own."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC, search_more_every=1)
    saliency, threads = pipeline.localizer.saliency, []

    def recorded(image):
        threads.append(threading.get_ident())
        return saliency(image)

    pipeline.localizer.saliency = recorded
    for i, rf in enumerate(build_sequence("seq13", seed=101, frames=12)):
        pipeline.process(Frame(i, i * 33_333_333, rf.image))
    assert len(threads) >= 10
    assert len(set(threads)) == 1 and threads[0] != threading.get_ident()
    assert pipeline.helper_cpu_s > 0.0


@pytest.mark.parametrize("every", [1, 6])
def test_the_search_for_more_drones_runs_every_search_more_every_frames(every):
    """Shipped model, one drone (seq13): once its track is confirmed and measured, the search for
    more drones runs on every ``search_more_every``-th frame only (the full search on every 30th)."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC, search_more_every=every)
    searched, tracked, confirmed = [], 0, set()
    for i, rf in enumerate(build_sequence("seq13", seed=101, frames=40)):
        out = pipeline.process(Frame(i, i * 33_333_333, rf.image))
        if any(m.track_id in confirmed for m in out.measured):  # a confirmed track measured
            tracked += 1
            searched.append(pipeline.frames if "acquire" in out.timings_ms else None)
        confirmed = {t.track_id for t in out.tracks if t.status == TrackStatus.CONFIRMED}
    assert tracked >= 20
    ran = [n for n in searched if n is not None]
    assert all(n % every == 0 for n in ran), ran
    assert len(ran) >= tracked // every - 1, (ran, tracked)


def test_a_measurement_stride_measures_confirmed_drones_every_other_frame_and_publishes_every_frame():
    """Shipped model, one drone (seq13), ``measure_every=2``: until its track is confirmed the drone
    is measured on every frame; from then on every other frame is "predicted" (no detection, no
    network call), yet each frame publishes the confirmed track at that frame's time, near the
    drone, and the search frames (every 6th) are measured."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC, measure_every=2)
    rendered = build_sequence("seq13", seed=101, frames=40)
    confirmed_at, modes, errors = None, [], []
    for i, rf in enumerate(rendered):
        out = pipeline.process(Frame(i, i * 33_333_333, rf.image))
        modes.append(out.mode)
        held = [t for t in out.tracks if t.status == TrackStatus.CONFIRMED]
        if out.mode == "predicted":
            assert out.detection is None and not out.measured and held
            assert all(t.t_ns == i * 33_333_333 and t.keypoints_px is None for t in held)
        if held:
            confirmed_at = i if confirmed_at is None else confirmed_at
            errors.append(min(np.linalg.norm(t.position_m - rf.record.drone.translation) for t in held))
    assert confirmed_at is not None and confirmed_at < 20
    assert "predicted" not in modes[: confirmed_at + 1]
    assert all(modes[i] != "predicted" for i in range(len(modes)) if (i + 1) % 6 == 0)  # searches
    assert modes[confirmed_at + 1 :].count("predicted") >= (len(modes) - confirmed_at) // 3
    assert max(errors) < 0.5, errors


def test_a_frame_taken_late_is_predicted_but_never_two_in_a_row_without_a_stride():
    """Shipped model, one drone (seq13), every frame taken late (``process(late=True)``): before the
    track is confirmed every frame is measured; from then on a late frame is predicted (mode
    "late"), but never two in a row (``measure_every`` 1), nor a search frame (every 6th), and
    every frame publishes the confirmed track near the drone."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC)
    modes, errors = [], []
    for i, rf in enumerate(build_sequence("seq13", seed=101, frames=40)):
        out = pipeline.process(Frame(i, i * 33_333_333, rf.image), late=True)
        modes.append(out.mode)
        held = [t for t in out.tracks if t.status == TrackStatus.CONFIRMED]
        if out.mode == "late":
            assert out.detection is None and not out.measured and held
        if held:
            errors.append(min(np.linalg.norm(t.position_m - rf.record.drone.translation) for t in held))
    first = modes.index("late")
    assert first < 20 and "predicted" not in modes
    assert all(not (a == b == "late") for a, b in itertools.pairwise(modes)), modes
    assert all(modes[i] != "late" for i in range(len(modes)) if (i + 1) % 6 == 0)  # searches
    assert modes[first:].count("late") >= (len(modes) - first) // 3
    assert errors and max(errors) < 0.5, errors


def test_the_verifier_looks_at_tentative_tracks_only():
    """Shipped model and verifier, one drone (seq13): the verdict is confirmation evidence, so a
    tentative track's crop is verified and a confirmed track's is not (``drone_p`` NaN), and the
    track is still confirmed."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC)
    assert pipeline.model.verifier is not None
    verdicts = {"tentative": [], "held": []}
    held: set[int] = set()
    for i, rf in enumerate(build_sequence("seq13", seed=101, frames=20)):
        out = pipeline.process(Frame(i, i * 33_333_333, rf.image))
        for m in out.measured:
            if m.track_id is not None:
                verdicts["held" if m.track_id in held else "tentative"].append(m.detection.drone_p)
        held = {t.track_id for t in out.tracks if t.status in (TrackStatus.CONFIRMED, TrackStatus.COASTING)}
    assert held and verdicts["tentative"] and len(verdicts["held"]) >= 5
    assert all(np.isfinite(verdicts["tentative"])) and all(np.isnan(verdicts["held"]))


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("search_more_every", 0),
        ("search_every", -1),
        ("max_search_candidates", True),
        ("wide_look_every", -1),
        ("measure_every", 0),
    ],
)
def test_bad_search_settings_name_the_argument(name, value):
    with pytest.raises(ValueError, match=f"{name} must be an integer"):
        TrackingPipeline(preset_camera(), drone=SPEC, **{name: value})


def test_of_two_tracks_on_one_drone_the_wider_reading_wins():
    """A track whose crop closed in on its drone reads it small; another track's crop that frames
    the whole drone reads it wider and takes the measurement (more than 10 % wider), else the
    better-ranked track keeps it; a drone elsewhere is untouched."""
    from dronekey.pipeline import _one_reading_per_drone

    narrowed = ("track 2", None, (100.0, 100.0, 30.0, 30.0))  # ranked first (confirmed), read small
    framing = ("track 4", None, (95.0, 95.0, 45.0, 45.0))  # the same drone, read 50 % wider
    elsewhere = ("track 7", None, (900.0, 500.0, 40.0, 40.0))
    kept = _one_reading_per_drone([narrowed, framing, elsewhere])
    assert [k[0] for k in kept] == ["track 4", "track 7"]
    similar = ("track 5", None, (99.0, 99.0, 32.0, 32.0))  # under 10 % wider: the ranking decides
    assert [k[0] for k in _one_reading_per_drone([narrowed, similar])] == ["track 2"]


def _clipped_and_right_boxes(rf, shrink: float):
    """The keypoint box of the rendered drone, and the same box shrunk about its centre."""
    x, y, w, h = box_from_keypoints(rf.record.drone.keypoints_px, SPEC)
    cx, cy = x + w / 2, y + h / 2
    return (cx - shrink * w / 2, cy - shrink * h / 2, shrink * w, shrink * h), (x, y, w, h)


def test_a_wide_look_mends_a_crop_that_clips_its_drone():
    """Shipped model, seq13 (seed 101, the drone 66 px across its hubs): a crop cut from a box 0.4x
    the drone's (a track read 2.5x too far) clips it, and the network crowds its keypoints (under
    half the true spread) and is unsure of the crop (presence below 0.999); the wide look reads the
    drone in a crop twice as large, is taken, and after its recut the spread is the drone's. On the
    right box the network is sure, no wide look is made, and the detection is the plain track's."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC)
    localizer = pipeline.localizer
    rf = next(iter(build_sequence("seq13", seed=101, frames=1)))
    true_spread = keypoint_spread(rf.record.drone.keypoints_px)
    clipped, right = _clipped_and_right_boxes(rf, 0.4)
    narrow = localizer.track_many(rf.image, [clipped])[0]
    assert keypoint_spread(narrow.keypoints_px) < 0.5 * true_spread
    assert narrow.presence < localizer.config.wide_look_presence
    (looked,), (taken,) = localizer.track_looking_wide(rf.image, [clipped], wide=[True])
    assert taken
    assert keypoint_spread(looked.keypoints_px) == pytest.approx(true_spread, rel=0.15)
    assert looked.presence >= localizer.config.presence_threshold
    plain = localizer.track_many(rf.image, [right])[0]
    (looked,), (taken,) = localizer.track_looking_wide(rf.image, [right], wide=[True])
    assert not taken
    np.testing.assert_array_equal(looked.keypoints_px, plain.keypoints_px)
    # No wide look asked: the same as track_many.
    (unasked,), (taken,) = localizer.track_looking_wide(rf.image, [clipped], wide=[False])
    assert not taken
    np.testing.assert_array_equal(unasked.keypoints_px, narrow.keypoints_px)


@pytest.mark.parametrize("every", [1, 3])
def test_wide_looks_are_staggered_over_the_tracks_and_repeated_while_taken(every, pipeline):
    pipeline = TrackingPipeline(preset_camera(), pipeline.model.path, drone=SPEC, wide_look_every=every)
    due = []
    for frame in range(1, 7):
        pipeline.frames = frame
        due.append([pipeline._wide_look_due(track_id) for track_id in (1, 2, 3)])
    assert all(sum(column) == 6 // every for column in zip(*due, strict=True))
    if every > 1:
        assert all(sum(row) == 1 for row in due)  # three tracks, one wide look a frame
        pipeline.frames = 6  # track 2's turn is on frames 1, 4, 7, ...
        assert not pipeline._wide_look_due(2)
        pipeline._widened = {2}  # its wide look was taken last frame: it looks again
        assert pipeline._wide_look_due(2)
    never = TrackingPipeline(preset_camera(), pipeline.model.path, drone=SPEC, wide_look_every=0)
    assert not any(never._wide_look_due(track_id) for track_id in range(5))


@pytest.mark.parametrize(("scale", "ratio"), [(1.0, 2.0), (2.0, 0.9)])
def test_bad_wide_look_settings_name_them(scale, ratio):
    with pytest.raises(ValueError, match="wide_look_scale"):
        LocalizerConfig(wide_look_scale=scale, wide_look_ratio=ratio)


def test_a_bad_acquire_recut_is_named():
    with pytest.raises(ValueError, match=r"acquire_recut must be > 0, got 0\.0"):
        LocalizerConfig(acquire_recut=0.0)


def test_a_search_reading_that_asks_for_another_framing_is_read_again_there():
    """Shipped model, seq13 (seed 101): a sure reading whose crop is 2.5x the one its keypoints ask
    for (as when a search crop sized from a blob is refined from an oversized rough reading) fills
    too little of it for the plausibility gate; it is read again in the crop its keypoints ask for,
    where it passes the gate with the drone's spread. A reading in the crop it asks for is left as it
    is (no second batch), as is one the network is not sure of, and every reading while the recut is
    off (the default)."""
    pipeline = TrackingPipeline(preset_camera(), drone=SPEC, localizer=LocalizerConfig(acquire_recut=0.25))
    localizer = pipeline.localizer
    rf = next(iter(build_sequence("seq13", seed=101, frames=1)))
    size = rf.image.shape[1::-1]
    true_spread = keypoint_spread(rf.record.drone.keypoints_px)
    right = localizer.crop.roi(box_from_keypoints(rf.record.drone.keypoints_px, SPEC))
    (framed,) = localizer.model.detect(rf.image, [right])
    asked = localizer.crop.roi(box_from_keypoints(framed.keypoints_px, SPEC))
    cx, cy = asked[0] + asked[2] / 2, asked[1] + asked[2] / 2
    oversized = (round(cx - 1.25 * asked[2]), round(cy - 1.25 * asked[2]), round(2.5 * asked[2]))
    misframed = replace(framed, roi=oversized)
    assert check_detection(misframed, size) is not None  # too small in its crop
    (again,) = localizer._recut_misframed(rf.image, [misframed])
    assert again.roi == asked
    assert check_detection(again, size) is None
    assert keypoint_spread(again.keypoints_px) == pytest.approx(true_spread, rel=0.15)
    assert localizer._recut_misframed(rf.image, [framed])[0] is framed
    unsure = replace(misframed, presence=0.1)
    assert localizer._recut_misframed(rf.image, [unsure])[0] is unsure
    assert LocalizerConfig().acquire_recut is None
    default = TrackingPipeline(preset_camera(), drone=SPEC).localizer
    assert default._recut_misframed(rf.image, [misframed])[0] is misframed


def test_two_readings_joined_finish_as_one(pipeline):
    """``KeypointReading.joined``: two batches read apart give the detections of one batch."""
    rf = next(iter(build_sequence("seq13", seed=3, frames=1)))
    model = pipeline.model
    rois = [(800, 400, 130), (10, 10, 64), (1700, 900, 300)]
    together = model.finish(model.read(rf.image, rois))
    apart = model.finish(model.read(rf.image, rois[:1]).joined(model.read(rf.image, rois[1:])))
    for a, b in zip(together, apart, strict=True):
        assert a.roi == b.roi
        np.testing.assert_allclose(a.keypoints_px, b.keypoints_px, atol=1e-3)
        assert a.presence == pytest.approx(b.presence, abs=1e-5)
    empty = model.read(rf.image, [])
    assert model.read(rf.image, rois[:1]).joined(empty).rois == rois[:1]
    assert empty.joined(model.read(rf.image, rois[:1])).rois == rois[:1]
