"""The renderer and the training sampler: geometry, visibility, determinism, crop framing."""

import numpy as np
import pytest

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.crop import CropPolicy, from_normalised
from dronekey.geometry.drone_spec import load_spec
from dronekey.geometry.rotations import rotation_from_euler_deg
from dronekey.sim_replay.annotations import HIDDEN, VISIBLE
from dronekey.sim_replay.drone_look import BodyShape, DroneStyle
from dronekey.sim_replay.mesh import build_mesh, segment_hits
from dronekey.sim_replay.renderer import Lighting, render_drone
from dronekey.sim_replay.sampler import CropSampler, SamplerConfig, is_side_on

SPEC = load_spec("mini2")


def _look_at(camera_pos_body: np.ndarray, target_body: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pose (R body->camera, t) of a camera at ``camera_pos_body`` looking at ``target_body``."""
    z = target_body - camera_pos_body
    z /= np.linalg.norm(z)
    up = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])  # rows: camera axes in body coordinates
    return R, -R @ camera_pos_body


def _render(R, t, size=(640, 480)):
    cam = CameraModel.from_fov(*size, 60.0, dist=[-0.05, 0.01, 0, 0, 0])
    img = np.full((size[1], size[0], 3), 180, np.uint8)
    ann = render_drone(img, cam, build_mesh(SPEC), R, t, DroneStyle(), Lighting())
    return cam, img, ann


def test_keypoints_are_the_projection_and_the_drone_is_drawn():
    R = rotation_from_euler_deg(30, 20, -10) @ np.eye(3)
    R = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0.0]]) @ R  # body FRD -> camera looking north
    t = np.array([0.05, -0.1, 1.2])
    cam, img, ann = _render(R, t)
    assert ann is not None
    expected = cam.project_body(SPEC.keypoints_3d, R, t)
    assert np.abs(ann.keypoints_px - expected).max() < 1e-9
    x, y, w, h = ann.bbox_xywh
    inside = img[int(y) : int(y + h), int(x) : int(x + w)]
    assert (inside != 180).any(axis=2).mean() > 0.2  # pixels of the drone changed
    assert (img[:5, :5] == 180).all()  # far from it, nothing changed


def test_body_hides_a_hub_seen_through_it():
    hub = SPEC.keypoints_3d[0]
    body_centre = np.array([0.0, 0.0, 0.04])
    cam_pos = hub + 12.0 * (body_centre - hub)  # below the body, on the far side from hub 1
    R, t = _look_at(cam_pos, body_centre)
    _, _, ann = _render(R, t)
    assert ann.visibility[0] == HIDDEN
    mesh = build_mesh(SPEC)
    assert any(
        segment_hits(p, cam_pos, hub) for p in mesh.parts if p.name == "shell" or p.name == "underside"
    )


def test_all_hubs_visible_from_above():
    R, t = _look_at(np.array([0.0, 0.0, -1.0]), np.zeros(3))
    _, _, ann = _render(R, t)
    assert (ann.visibility == VISIBLE).all()


def test_drone_behind_camera_is_not_drawn():
    R, t = _look_at(np.array([0.0, 0.0, -1.0]), np.zeros(3))
    _, img, ann = _render(R, -t)
    assert ann is None and (img == 180).all()


def test_sampler_is_deterministic_and_labels_match_the_crop():
    cfg = SamplerConfig(crop=CropPolicy(input_size=64))
    a, b = CropSampler(cfg, seed=5, pool_size=2), CropSampler(cfg, seed=5, pool_size=2)
    batch_a, batch_b = a.batch(24), b.batch(24)
    for key in batch_a:
        assert np.array_equal(batch_a[key], batch_b[key]), key
    assert batch_a["image"].shape == (24, 64, 64, 3) and batch_a["image"].dtype == np.uint8
    present = batch_a["present"]
    assert 0 < present.sum() < 24 or present.all()
    kp = batch_a["keypoints"][present]
    # Keypoints of a drone framed by the crop policy lie in (or just around) the crop.
    assert (kp > -0.3).all() and (kp < 1.3).all()
    assert (batch_a["area"][present] > 0).all() and (batch_a["area"][~present] == 0).all()


def test_normalised_keypoints_map_back_to_full_frame_pixels():
    """The sampler's labels are exactly what crop.from_normalised inverts (same convention)."""
    roi = (100, 50, 256)
    n = np.array([[0.5, 0.5], [0.0, 0.0], [1.0, 1.0]])
    px = from_normalised(n, roi)
    assert np.allclose(px, [[227.5, 177.5], [99.5, 49.5], [355.5, 305.5]])


@pytest.mark.parametrize("bad", [(0.0, 10.0), (50.0, 10.0)])
def test_sampler_config_rejects_bad_sizes(bad):
    with pytest.raises(ValueError, match="size_px"):
        SamplerConfig(size_px=bad)


def test_end_sensors_are_drawn_at_either_end_and_are_no_front_cue():
    ends = {}
    for end in ("front", "rear", "both"):
        parts = [p.name for p in build_mesh(SPEC, BodyShape(end_sensors=end)).parts]
        ends[end] = {n.split("_")[-1] for n in parts if n.startswith("sensor_")}
    assert ends == {"front": {"front"}, "rear": {"rear"}, "both": {"front", "rear"}}
    # the front pod sits on the body's frontmost face: a nose cone's tip, not hidden inside the cone
    for nose_length in (0.0, 0.1):
        mesh = build_mesh(SPEC, BodyShape(end_sensors="front", nose_length=nose_length))
        front = "nose" if nose_length else "shell"
        face = max(p.vertices[:, 0].max() for p in mesh.parts if p.name == front)
        pod = min(p.vertices[:, 0].min() for p in mesh.parts if p.name.startswith("sensor_lens"))
        assert pod > face - 1e-9
    symmetric = BodyShape(end_sensors="front").without_front_cues()
    assert symmetric.end_sensors == "front" and not symmetric.shows_front(from_above=True)
    with pytest.raises(ValueError, match="end_sensors must be one of"):
        BodyShape(end_sensors="left")
    rng = np.random.default_rng(0)
    drawn = [BodyShape().with_random_end_sensors(rng, 1.0).end_sensors for _ in range(300)]
    counts = [drawn.count(end) for end in ("front", "rear", "both")]
    assert sum(counts) == 300 and min(counts) > 70  # either end alike: no cue
    assert BodyShape().with_random_end_sensors(rng, 0.0) == BodyShape()


def test_sampler_gives_end_sensors_on_request_and_leaves_other_streams_alone():
    plain = CropSampler(SamplerConfig(negative_fraction=0.0), seed=4).sample()
    same = CropSampler(SamplerConfig(negative_fraction=0.0, end_sensor_fraction=0.0), seed=4).sample()
    pods = CropSampler(SamplerConfig(negative_fraction=0.0, end_sensor_fraction=1.0), seed=4).sample()
    assert np.array_equal(plain.image, same.image)
    assert not np.array_equal(plain.image, pods.image)
    with pytest.raises(ValueError, match="end_sensor_fraction must be in"):
        SamplerConfig(end_sensor_fraction=-0.1)


def test_side_on_is_the_front_back_sides_looking_longer():
    # hubs in the spec's order (front right, rear right, rear left, front left), image pixels
    head_on = np.array([[60, 40], [60, 60], [20, 60], [20, 40]], dtype=float)  # left/right sides 40 px
    side_on = np.array([[40, 20], [40, 80], [20, 80], [20, 20]], dtype=float)  # front/back sides 60 px
    assert not is_side_on(head_on)
    assert is_side_on(side_on)


def test_side_view_boost_raises_the_side_on_share_and_leaves_other_streams_alone():
    def side_on_share(boost: float) -> float:
        sampler = CropSampler(SamplerConfig(negative_fraction=0.0, side_view_boost=boost), seed=11)
        return float(np.mean([is_side_on(sampler.sample().keypoints) for _ in range(80)]))

    plain, boosted = side_on_share(0.0), side_on_share(0.8)
    assert boosted > plain + 0.15
    first = CropSampler(SamplerConfig(negative_fraction=0.0), seed=4).sample()
    again = CropSampler(SamplerConfig(negative_fraction=0.0, side_view_boost=0.0), seed=4).sample()
    np.testing.assert_array_equal(first.image, again.image)
    with pytest.raises(ValueError, match="side_view_boost"):
        SamplerConfig(side_view_boost=1.0)
