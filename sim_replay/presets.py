"""3DronePose-style sequence presets (after the paper's Tab. I) and the sequence renderer.

A sequence is a fixed camera on a tripod, pitched up at the sky, watching one drone fly a scripted
path. Positions are in local North-East-Down metres relative to the camera; attitudes are the
drone's yaw / pitch / roll (degrees, aerospace order). The seed draws everything that is not the
script: backgrounds, colours, lighting, noise, and small offsets of the path, so a seed never used
in training gives a fresh sequence with the same character.

Presets (30 fps, 1920x1080, DJI Mini 2 unless noted):

- ``seq11``: 500 frames, linear translation at constant velocity, no rotation.
- ``seq12``: 400 frames, non-linear translation (a Lissajous figure), no rotation.
- ``seq13``: 300 frames, non-linear translation with rotation: a full yaw turn (through +-180 deg)
  with pitch and roll oscillations.
- ``2dronekey``: 1000 frames, rotation-heavy, translation nearly fixed (the paper's keypoint
  training sequences): the drone hovers while tumbling through wide attitudes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dronekey.camera import CameraModel
from dronekey.drone_spec import DroneSpec, load_spec
from dronekey.rotations import ned_from_camera, rotation_from_euler_deg

from .annotations import FrameRecord
from .backgrounds import BackgroundSource
from .effects import sensor_noise
from .mesh import DroneStyle, build_mesh
from .renderer import Lighting, render_drone

__all__ = ["PRESETS", "Preset", "RenderedFrame", "SyntheticSequence", "build_sequence", "preset_camera"]

GENERATOR = "dronekey.sim_replay"
HFOV_DEG = 70.0
DISTORTION = (-0.06, 0.015, 0.0, 0.0, 0.0)

# A trajectory maps (time s, offsets drawn from the seed) to (p_ned (3,), (yaw, pitch, roll) deg).
Trajectory = Callable[[float, np.ndarray], tuple[np.ndarray, tuple[float, float, float]]]


@dataclass(frozen=True)
class Preset:
    """One scripted sequence."""

    name: str
    frames: int
    fps: float
    drone: str
    camera_pitch_deg: float
    default_seed: int
    description: str
    trajectory: Trajectory


def _seq11(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    s = t / (500 / 30.0)  # 0 -> 1 over the sequence
    start = np.array([4.2, -2.0, -2.3]) + o[:3] * 0.3
    end = np.array([3.0, 2.0, -1.7]) + o[3:6] * 0.3
    return start + (end - start) * s, (55.0 + 20 * o[6], -8.0, 4.0)


def _seq12(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    w = 2 * math.pi / (400 / 30.0)
    p = np.array(
        [
            3.6 + 0.8 * math.sin(2 * w * t + o[0]),
            1.8 * math.sin(w * t + o[1]),
            -2.0 - 0.4 * math.sin(3 * w * t),
        ]
    )
    return p, (-35.0 + 20 * o[6], -5.0, -6.0)


def _seq13(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    T = 300 / 30.0
    w = 2 * math.pi / T
    p = np.array(
        [
            3.4 + 0.6 * math.cos(w * t + o[0]),
            1.5 * math.sin(w * t + o[1]),
            -2.0 - 0.3 * math.sin(2 * w * t + o[2]),
        ]
    )
    yaw = -170.0 + 360.0 * t / T + 20 * o[6]  # one full turn: crosses +-180 deg
    yaw = (yaw + 180.0) % 360.0 - 180.0
    return p, (yaw, 12.0 * math.sin(1.7 * w * t), 10.0 * math.sin(2.3 * w * t + 1.0))


def _2dronekey(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    p = np.array([2.6, 0.0, -1.6]) + 0.05 * np.array(
        [math.sin(0.7 * t), math.sin(0.9 * t + 1), math.sin(1.1 * t)]
    )
    yaw = (40.0 * t + 60 * o[6] + 180.0) % 360.0 - 180.0
    pitch = 40.0 * math.sin(0.53 * t + o[0])
    roll = 40.0 * math.sin(0.71 * t + o[1])
    return p, (yaw, pitch, roll)


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("seq11", 500, 30.0, "mini2", 32.0, 11, "linear translation, no rotation", _seq11),
        Preset("seq12", 400, 30.0, "mini2", 32.0, 12, "non-linear translation, no rotation", _seq12),
        Preset("seq13", 300, 30.0, "mini2", 32.0, 13, "non-linear translation with rotation", _seq13),
        Preset(
            "2dronekey", 1000, 30.0, "mini2", 32.0, 2, "rotation-heavy, translation nearly fixed", _2dronekey
        ),
    )
}


def preset_camera(width: int = 1920, height: int = 1080) -> CameraModel:
    """The simulated camera: 70 deg horizontal field of view, mild barrel distortion."""
    return CameraModel.from_fov(width, height, HFOV_DEG, dist=np.array(DISTORTION))


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered image and its ground truth (``record.file_name`` is filled by the writer)."""

    image: np.ndarray
    record: FrameRecord


class SyntheticSequence:
    """A preset rendered with one seed; iterate it for ``RenderedFrame`` objects, deterministically."""

    def __init__(
        self,
        preset: Preset,
        seed: int,
        frames: int,
        camera: CameraModel,
        spec: DroneSpec,
        backgrounds: BackgroundSource,
    ) -> None:
        self.preset = preset
        self.name = preset.name
        self.seed = seed
        self.n_frames = frames
        self.fps = preset.fps
        self.camera = camera
        self.spec = spec
        self._backgrounds = backgrounds

    @property
    def info(self) -> dict:
        """The JSON's ``info`` object (DESIGN.md §5.1)."""
        return {
            "sequence": self.name,
            "generator": GENERATOR,
            "seed": self.seed,
            "fps": self.fps,
            "description": self.preset.description,
        }

    def __len__(self) -> int:
        return self.n_frames

    def __iter__(self) -> Iterator[RenderedFrame]:
        rng = np.random.default_rng(self.seed)
        w, h = self.camera.size
        background = self._backgrounds.draw(h, w, rng)
        style = DroneStyle.random(rng)
        mesh = build_mesh(self.spec)
        lighting = Lighting.random(rng)
        offsets = rng.uniform(-1, 1, 8)
        noise_sigma = float(rng.uniform(1.0, 3.0))
        R_cam_ned = ned_from_camera(0.0, self.preset.camera_pitch_deg, 0.0).T
        exposure_s = 0.5 / self.fps
        for i in range(self.n_frames):
            t_s = i / self.fps
            R, t = self._pose(t_s, offsets, R_cam_ned)
            _, t2 = self._pose(t_s + exposure_s, offsets, R_cam_ned)
            c0, c1 = self.camera.project(np.vstack([t, t2]))
            img = background.copy()
            ann = render_drone(img, self.camera, mesh, R, t, style, lighting, motion_blur_px=tuple(c1 - c0))
            img = sensor_noise(img, rng, sigma=noise_sigma)
            record = FrameRecord(i, round(t_s * 1e9), "", w, h, ann)
            yield RenderedFrame(img, record)

    def _pose(self, t_s: float, offsets: np.ndarray, R_cam_ned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p_ned, (yaw, pitch, roll) = self.preset.trajectory(t_s, offsets)
        return R_cam_ned @ rotation_from_euler_deg(yaw, pitch, roll), R_cam_ned @ p_ned


def build_sequence(
    preset: str,
    *,
    seed: int | None = None,
    frames: int | None = None,
    width: int = 1920,
    height: int = 1080,
    backgrounds: str | Path | None = None,
) -> SyntheticSequence:
    """Prepare a preset for rendering.

    Parameters
    ----------
    preset : str
        One of ``PRESETS``.
    seed : int, optional
        Seed of everything random; defaults to the preset's own (11, 12, 13, 2).
    frames : int, optional
        Number of frames (default: the preset's length); the script is time-based, so fewer frames
        render the beginning of the same flight.
    width, height : int
        Image size; the camera keeps its 70 deg horizontal field of view.
    backgrounds : path, optional
        Folder of background photos to use instead of procedural skies.

    Raises
    ------
    ValueError
        Unknown preset or non-positive sizes / frame count.
    FileNotFoundError
        The backgrounds folder is missing or holds no images.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; available: {', '.join(PRESETS)}")
    p = PRESETS[preset]
    frames = p.frames if frames is None else int(frames)
    if frames <= 0:
        raise ValueError(f"frames must be positive, got {frames}")
    if width <= 0 or height <= 0:
        raise ValueError(f"width and height must be positive, got {width}x{height}")
    seed = p.default_seed if seed is None else int(seed)
    return SyntheticSequence(
        p, seed, frames, preset_camera(width, height), load_spec(p.drone), BackgroundSource(backgrounds)
    )
