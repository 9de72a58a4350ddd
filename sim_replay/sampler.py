"""Streaming training sampler: network-ready crops and labels, rendered on the fly, no files.

Each sample imitates what the daemon's localiser hands the keypoint network: a drone somewhere in a
1080p frame (30 to 600 px across, any attitude, partly outside the frame at times), cropped around
its box with ``dronekey.geometry.crop.CropPolicy``'s scale and jitter, and resized to the network input.
Instead of rendering the whole 1080p frame, the drone is rendered straight into the crop through an
equivalent camera (the full camera's intrinsics shifted and scaled to the crop), at the crop's
native resolution capped at twice the input size; background, blur and noise are applied at that
resolution, then the crop is resized exactly as ``crop_square`` would.

No look decides: every drone gets a random body (``BodyShape.random``) and livery
(``DroneStyle.random``: LEDs absent on 45 % of drones, otherwise any colours either way round,
sometimes in their off phase), some are backlit near-silhouettes against a brightened sky, and
backgrounds mix procedural skies, terrain and cities with the packaged photographs
(``backgrounds.TRAIN_PHOTOS``) and any ``backgrounds`` folder. Clouds, building edges, trees and
wires enter the crops from their edges. A fifth of the samples have no drone (for the presence
score): random crops, crops running far past the frame edge (black padding), and hard negatives:
the crops the localiser's own saliency search (``localizer.propose_rois``) proposes on drone-free
backgrounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.crop import CropPolicy, crop_square, to_normalised
from dronekey.geometry.drone_spec import load_spec
from dronekey.geometry.rotations import ned_from_camera, rotation_from_euler_deg
from dronekey.perception.localizer import LocalizerConfig, propose_rois
from dronekey.sim_replay.annotations import HIDDEN
from dronekey.sim_replay.backgrounds import TRAIN_PHOTOS, BackgroundSource, packaged_photos
from dronekey.sim_replay.drone_look import BodyShape, DroneStyle
from dronekey.sim_replay.effects import (
    camera_response,
    draw_distractors,
    draw_edge_clutter,
    draw_occluder,
    jpeg_roundtrip,
    sensor_noise,
)
from dronekey.sim_replay.mesh import build_mesh
from dronekey.sim_replay.renderer import Lighting, render_drone

__all__ = ["CropSample", "CropSampler", "SamplerConfig", "is_side_on"]

FRAME_W, FRAME_H = 1920, 1080
MESH_POOL, MESH_RENEW = 256, 0.08


def is_side_on(keypoints_px: np.ndarray) -> bool:
    """Whether four hubs (4, 2, image pixels, in the spec's order: front right, rear right, rear left,
    front left) look side-on: their front/back sides (hubs 1-2, 3-4) at least as long in the image as
    their left/right sides (2-3, 4-1), the left/right axis foreshortened. The shipped specs' hubs (Mini 2,
    Air 2S) are wider than long, so in most views the left/right sides look the longer; side-on that
    cue points the wrong way."""
    kp = np.asarray(keypoints_px, dtype=np.float64)
    along = np.linalg.norm(kp[0] - kp[1]) + np.linalg.norm(kp[2] - kp[3])
    across = np.linalg.norm(kp[1] - kp[2]) + np.linalg.norm(kp[3] - kp[0])
    return bool(along >= across)


@dataclass(frozen=True)
class SamplerConfig:
    """What the sampler draws. Sizes are drone extents (propeller discs included) in a 1080p frame."""

    crop: CropPolicy = field(default_factory=CropPolicy)
    size_px: tuple[float, float] = (30.0, 600.0)
    negative_fraction: float = 0.2
    padded_negative_fraction: float = 0.3  # of the negatives: crops running far past the frame edge
    mined_negative_fraction: float = 0.35  # of the negatives: the localiser's proposals on empty frames
    edge_clutter_prob: float = 0.35
    backlit_prob: float = 0.1
    led_off_phase_prob: float = 0.1  # a lit drone caught with its (blinking) LEDs off
    photo_fraction: float = 0.3  # packaged photographs among the backgrounds (0.7 with a folder)
    uniform_rotation_fraction: float = 0.2
    drones: tuple[tuple[str, float], ...] = (("mini2", 0.75), ("air2s", 0.25))
    hfov_deg: tuple[float, float] = (50.0, 90.0)
    truncation_prob: float = 0.08
    occlusion_prob: float = 0.12
    distractor_prob: float = 0.3
    motion_blur_prob: float = 0.3
    defocus_prob: float = 0.2
    jpeg_prob: float = 0.5
    render_cap: float = 2.0  # render at most this times the input size, then area-resize
    # drones drawn with no front/back cue (BodyShape.without_front_cues), besides the few random
    # bodies that have none: the front/back classifier's data, which must teach it to say so
    cue_free_fraction: float = 0.0
    # bodies given obstacle-sensor pods at the front, the rear or both (BodyShape.end_sensors): a
    # dark box at an end, like the nose gimbal's, that marks neither end
    end_sensor_fraction: float = 0.0
    # the share of drone drawings that are not side-on drawn again (``is_side_on``): 0 keeps the
    # attitudes' own mix (about 27 % side-on); 0.5 raises it to about 43 %. Side-on views are where
    # the keypoint network turns its order by a quarter (docs/model.md, "Side-on views")
    side_view_boost: float = 0.0

    def __post_init__(self) -> None:
        lo, hi = self.size_px
        if not 0 < lo <= hi:
            raise ValueError(f"size_px must satisfy 0 < min <= max, got {self.size_px}")
        if not 0 <= self.negative_fraction < 1:
            raise ValueError(f"negative_fraction must be in [0, 1), got {self.negative_fraction}")
        if not 0 <= self.cue_free_fraction <= 1:
            raise ValueError(f"cue_free_fraction must be in [0, 1], got {self.cue_free_fraction}")
        if not 0 <= self.end_sensor_fraction <= 1:
            raise ValueError(f"end_sensor_fraction must be in [0, 1], got {self.end_sensor_fraction}")
        if not 0 <= self.side_view_boost < 1:
            raise ValueError(f"side_view_boost must be in [0, 1), got {self.side_view_boost}")


@dataclass(frozen=True)
class CropSample:
    """One training example.

    image : (S, S, 3) uint8 BGR network input.
    keypoints : (4, 2) float32 normalised crop units (0 = left/top edge, 1 = right/bottom edge).
    visibility : (4,) int, 2 visible / 1 hidden (zeros without a drone).
    present : whether a drone is in the crop.
    area : the drone box's area in normalised crop units^2 (the OKS scale; 0 without a drone).
    front_visible : whether the drone's body shows which end is its front from where the camera
        sees it (``BodyShape.shows_front``; False without a drone).
    """

    image: np.ndarray
    keypoints: np.ndarray
    visibility: np.ndarray
    present: bool
    area: float
    front_visible: bool = False


class CropSampler:
    """Draws ``CropSample`` objects forever; reproducible for a given seed.

    Parameters
    ----------
    config : SamplerConfig
    seed : int
    backgrounds : path, optional
        Folder of photos mixed into the procedural backgrounds.
    pool_size : int
        Number of full 1080p backgrounds kept; one is replaced every ``refresh_every`` samples.
    """

    def __init__(
        self,
        config: SamplerConfig | None = None,
        seed: int = 0,
        backgrounds: str | Path | None = None,
        pool_size: int = 16,
        refresh_every: int = 48,
    ) -> None:
        self.config = config or SamplerConfig()
        self.rng = np.random.default_rng(seed)
        photos = packaged_photos(TRAIN_PHOTOS)
        fraction = 0.7 if backgrounds is not None else self.config.photo_fraction
        self._bg_source = BackgroundSource(backgrounds, photo_fraction=fraction, images=photos)
        self._pool_size = max(1, pool_size)
        self._pool: list[np.ndarray] = []
        self._proposals: list[list[tuple[int, int, int]]] = []  # localiser crops per pool background
        self._localizer_config = LocalizerConfig(use_motion=False)
        self._refresh_every = max(1, refresh_every)
        self._count = 0
        names = [n for n, _ in self.config.drones]
        probs = np.array([p for _, p in self.config.drones], dtype=np.float64)
        self._specs = [load_spec(n) for n in names]
        self._spec_p = probs / probs.sum()
        self._meshes: dict[tuple[str, bool], list] = {}  # (spec, cue-free) -> (mesh, shape); see _mesh

    # ------------------------------------------------------------------ public
    def sample(self) -> CropSample:
        """One sample (a drone with probability 1 - negative_fraction)."""
        self._count += 1
        k = self._background()
        bg = self._pool[k]
        if self.rng.random() < self.config.negative_fraction:
            return self._negative(bg, self._proposals[k])
        for _ in range(20):  # a pose can land fully outside the frame; draw again
            out = self._positive(bg)
            if out is not None:
                return out
        return self._negative(bg, self._proposals[k])

    def batch(self, n: int) -> dict[str, np.ndarray]:
        """``n`` samples stacked: image (n,S,S,3) uint8, keypoints (n,4,2), visibility, present, area."""
        samples = [self.sample() for _ in range(n)]
        return {
            "image": np.stack([s.image for s in samples]),
            "keypoints": np.stack([s.keypoints for s in samples]),
            "visibility": np.stack([s.visibility for s in samples]),
            "present": np.array([s.present for s in samples]),
            "area": np.array([s.area for s in samples], dtype=np.float32),
        }

    # ------------------------------------------------------------------ internals
    def _background(self) -> int:
        """Index of a pool background (1080p BGR), the pool refreshed one at a time."""
        if len(self._pool) < self._pool_size:
            self._pool.append(self._new_background())
            self._proposals.append(self._propose(self._pool[-1]))
            return len(self._pool) - 1
        if self._count % self._refresh_every == 0:
            k = int(self.rng.integers(self._pool_size))
            self._pool[k] = self._new_background()
            self._proposals[k] = self._propose(self._pool[k])
        return int(self.rng.integers(self._pool_size))

    def _new_background(self) -> np.ndarray:
        bg = self._bg_source.draw(FRAME_H, FRAME_W, self.rng)
        if self.rng.random() < 0.5:  # clutter at the frame's edges, where candidates end up
            draw_edge_clutter(bg, self.rng, int(self.rng.integers(1, 3)))
        return bg

    def _propose(self, bg: np.ndarray) -> list[tuple[int, int, int]]:
        rois, _ = propose_rois(bg, self._localizer_config, self.config.crop.min_side)
        return rois

    def _camera(self) -> CameraModel:
        k1 = self.rng.uniform(-0.15, 0.03)
        dist = np.array([k1, -0.2 * k1 * self.rng.uniform(0, 1), 0.0, 0.0, 0.0])
        return CameraModel.from_fov(FRAME_W, FRAME_H, self.rng.uniform(*self.config.hfov_deg), dist=dist)

    def _rotation(self) -> np.ndarray:
        """Body -> camera: mostly flight-like attitudes seen from a camera pitched up, some uniform."""
        rng = self.rng
        if rng.random() < self.config.uniform_rotation_fraction:
            return Rotation.random(rng=rng).as_matrix()
        yaw = rng.uniform(-180, 180)
        pitch, roll = np.clip(rng.normal(0, 18, 2), -60, 60)
        R_ned_body = rotation_from_euler_deg(yaw, pitch, roll)
        R_ned_cam = ned_from_camera(0.0, rng.uniform(-20, 75), rng.normal(0, 4))
        return R_ned_cam.T @ R_ned_body

    def _positive(self, bg: np.ndarray) -> CropSample | None:
        rng, cfg = self.rng, self.config
        S = cfg.crop.input_size
        spec = self._specs[int(rng.choice(len(self._specs), p=self._spec_p))]
        camera = self._camera()
        size = math.exp(rng.uniform(math.log(cfg.size_px[0]), math.log(cfg.size_px[1])))
        z = camera.fx * spec.extent_m / size
        margin = -size / 3 if rng.random() < cfg.truncation_prob else size / 2
        u = rng.uniform(margin, FRAME_W - margin) if 2 * margin < FRAME_W else FRAME_W / 2
        v = rng.uniform(margin, FRAME_H - margin) if 2 * margin < FRAME_H else FRAME_H / 2
        t = z * np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
        R = self._rotation()
        style = DroneStyle.random(rng)
        cue_free = cfg.cue_free_fraction > 0 and rng.random() < cfg.cue_free_fraction
        mesh, shape = self._mesh(spec, cue_free)
        if rng.random() < cfg.led_off_phase_prob:
            style = style.with_leds("off")
        backlit = rng.random() < cfg.backlit_prob
        lighting = Lighting.backlit(rng) if backlit else Lighting.random(rng)
        # The drone's true box in the full frame (every part, clipped to the frame) fixes the crop,
        # exactly as the evaluation crops around the annotated box.
        box = _clip_box(camera.project_body(mesh.vertices, R, t))
        if box is None:
            return None
        kp_full = camera.project_body(spec.keypoints_3d, R, t)
        if cfg.side_view_boost > 0 and not is_side_on(kp_full) and rng.random() < cfg.side_view_boost:
            return None
        roi = cfg.crop.roi(box, rng)
        x0, y0, side = roi
        r = int(min(side, cfg.render_cap * S))
        s = r / side
        K = camera.K.copy()  # the same camera seen through the crop: shift, then scale
        K[0, 0] *= s
        K[1, 1] *= s
        K[0, 2] = (K[0, 2] - x0 + 0.5) * s - 0.5
        K[1, 2] = (K[1, 2] - y0 + 0.5) * s - 0.5
        crop_cam = CameraModel(r, r, K, camera.dist)

        img = _cut(bg, roi, r)
        if backlit:  # a bright sky behind the drone: lift the background towards white
            lift = rng.uniform(0.4, 0.85)
            img[...] = (255 - (255 - img.astype(np.float32)) * (1 - lift)).astype(np.uint8)
        blur = (0.0, 0.0)
        if rng.random() < cfg.motion_blur_prob:
            ang, length = rng.uniform(0, 2 * math.pi), rng.uniform(0, 0.12) * size * s
            blur = (length * math.cos(ang), length * math.sin(ang))
        defocus = rng.uniform(0.3, 0.02 * size * s + 0.5) if rng.random() < cfg.defocus_prob else 0.0
        ann = render_drone(img, crop_cam, mesh, R, t, style, lighting, blur, defocus)
        if ann is None:
            return None
        _blank_outside_frame(img, roi, s)
        vis = ann.visibility.copy()
        outside = (kp_full[:, 0] < -0.5) | (kp_full[:, 0] > FRAME_W - 0.5)
        outside |= (kp_full[:, 1] < -0.5) | (kp_full[:, 1] > FRAME_H - 0.5)
        vis[outside] = HIDDEN
        self._clutter(img, ann.bbox_xywh, ann.keypoints_px, vis, size * s)
        img = _resize(self._camera_effects(img), S)
        kp = to_normalised(kp_full, roi).astype(np.float32)
        area = box[2] * box[3] / side**2
        # seen from above the propeller plane: the body's up axis (-z, z down) points at the camera
        from_above = float(R[:, 2] @ t) > 0
        return CropSample(img, kp, vis, True, float(area), shape.shows_front(from_above))

    def _negative(self, bg: np.ndarray, proposals: list[tuple[int, int, int]]) -> CropSample:
        rng, cfg = self.rng, self.config
        S = cfg.crop.input_size
        kind = rng.random()
        if proposals and kind < cfg.mined_negative_fraction:
            # What the localiser would hand the network on this drone-free frame, jittered a little.
            x0, y0, side = proposals[int(rng.integers(len(proposals)))]
            d = side * rng.uniform(-0.08, 0.08, 2)
            side = max(int(side * rng.uniform(0.85, 1.15)), 8)
            x0, y0 = int(x0 + d[0]), int(y0 + d[1])
        else:
            side = int(
                math.exp(rng.uniform(math.log(cfg.size_px[0] * cfg.crop.scale), math.log(cfg.size_px[1])))
            )
            over = 0.6 if kind > 1.0 - cfg.padded_negative_fraction else 0.25  # past the frame edge
            lo = int(-side * over)
            x0 = int(rng.integers(lo, FRAME_W - side - lo + 1))
            y0 = int(rng.integers(lo, max(FRAME_H - side - lo, lo) + 1))
        roi = (x0, y0, side)
        r = int(min(side, cfg.render_cap * S))
        s = r / side
        img = _cut(bg, roi, r)
        if rng.random() < 0.6:
            draw_distractors(img, rng, int(rng.integers(1, 4)), (0.05 * r, 0.5 * r))
        if rng.random() < 0.5:
            draw_edge_clutter(img, rng)
        _blank_outside_frame(img, roi, s)
        img = _resize(self._camera_effects(img), S)
        return CropSample(img, np.zeros((4, 2), np.float32), np.zeros(4, np.int64), False, 0.0)

    def _mesh(self, spec, cue_free: bool = False) -> tuple:
        """A random body for ``spec`` and its shape (``cue_free``: one without front/back cues): from
        a pool of ``MESH_POOL`` shapes each, one replaced by a new shape in ``MESH_RENEW`` of the
        draws (building a mesh costs as much as rendering it)."""
        pool = self._meshes.setdefault((spec.name, cue_free), [])

        def draw() -> tuple:
            shape = BodyShape.random(self.rng)
            shape = shape.without_front_cues() if cue_free else shape
            shape = shape.with_random_end_sensors(self.rng, self.config.end_sensor_fraction)
            return build_mesh(spec, shape), shape

        if len(pool) < MESH_POOL:
            pool.append(draw())
            return pool[-1]
        k = int(self.rng.integers(MESH_POOL))
        if self.rng.random() < MESH_RENEW:
            pool[k] = draw()
        return pool[k]

    def _clutter(self, img: np.ndarray, box, kp: np.ndarray, vis: np.ndarray, size: float) -> None:
        rng, cfg = self.rng, self.config
        if rng.random() < cfg.distractor_prob:
            draw_distractors(img, rng, int(rng.integers(1, 4)), (0.08 * size, 0.6 * size))
        if rng.random() < cfg.edge_clutter_prob:
            mask = draw_edge_clutter(img, rng)
            _hide_covered(vis, kp, mask)
        if rng.random() < cfg.occlusion_prob:
            mask = draw_occluder(img, rng, box, cover=rng.uniform(0.05, 0.4))
            _hide_covered(vis, kp, mask)

    def _camera_effects(self, img: np.ndarray) -> np.ndarray:
        rng, cfg = self.rng, self.config
        if rng.random() < 0.8:
            img = camera_response(img, rng)
        img = sensor_noise(img, rng)
        if rng.random() < cfg.jpeg_prob:
            img = jpeg_roundtrip(img, int(rng.integers(30, 96)))
        return img


def _hide_covered(vis: np.ndarray, kp: np.ndarray, mask: np.ndarray) -> None:
    """Flag the keypoints (crop pixels) that fall on a covering mask as hidden, in place."""
    h, w = mask.shape
    for i, (u, v) in enumerate(kp):
        iu, iv = int(round(u)), int(round(v))
        if 0 <= iu < w and 0 <= iv < h and mask[iv, iu]:
            vis[i] = HIDDEN


def _clip_box(uv: np.ndarray) -> tuple[float, float, float, float] | None:
    """Box (x, y, w, h) of projected points clipped to the frame, None if (nearly) outside it."""
    x0, y0 = max(uv[:, 0].min(), -0.5), max(uv[:, 1].min(), -0.5)
    x1, y1 = min(uv[:, 0].max(), FRAME_W - 0.5), min(uv[:, 1].max(), FRAME_H - 0.5)
    if x1 - x0 < 2 or y1 - y0 < 2:
        return None
    return float(x0), float(y0), float(x1 - x0), float(y1 - y0)


def _cut(frame: np.ndarray, roi: tuple[int, int, int], r: int) -> np.ndarray:
    """The roi of a full frame at r x r pixels (black outside the frame), as crop_square does."""
    return crop_square(frame, roi, r).copy()


def _blank_outside_frame(img: np.ndarray, roi: tuple[int, int, int], s: float) -> None:
    """Black out crop pixels whose centre falls outside the full frame (truncation at the edge)."""
    x0, y0, _ = roi
    r = img.shape[0]
    c = (np.arange(r) + 0.5) / s - 0.5
    u, v = c + x0, c + y0
    img[:, (u < -0.5) | (u > FRAME_W - 0.5)] = 0
    img[(v < -0.5) | (v > FRAME_H - 0.5), :] = 0


def _resize(img: np.ndarray, S: int) -> np.ndarray:
    r = img.shape[0]
    if r == S:
        return img
    return cv2.resize(img, (S, S), interpolation=cv2.INTER_AREA if r > S else cv2.INTER_LINEAR)
