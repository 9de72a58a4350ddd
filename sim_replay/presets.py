"""The scripted sequences (after 3DronePose's Tab. I): each preset's flight path, length, drone and
camera pitch, and the simulated camera.

A sequence is a fixed camera on a tripod, pitched up at the sky, watching one drone fly a scripted
path. Positions are in local North-East-Down metres relative to the camera; attitudes are the
drone's yaw / pitch / roll (degrees, aerospace order). A trajectory takes a few offsets drawn from
the scene seed, so another seed flies a slightly different path of the same character
(``synthetic_sequence.build_sequence`` renders a preset).

Presets (30 fps, 1920x1080, DJI Mini 2 unless noted):

- ``seq11``: 500 frames, linear translation at constant velocity, no rotation.
- ``seq12``: 400 frames, non-linear translation (a Lissajous figure), no rotation.
- ``seq13``: 300 frames, non-linear translation with rotation: a full yaw turn (through +-180 deg)
  with pitch and roll oscillations.
- ``2dronekey``: 1000 frames, rotation-heavy, translation nearly fixed (the paper's keypoint
  training sequences): the drone hovers while tumbling through wide attitudes.
- ``far``: 300 frames, a DJI Air 2S approaching from 145 m to 22 m, weaving, seen through a long
  lens (12 deg horizontal field of view): about 30 px across at the start, 200 px at the end.
- ``swarm``: 300 frames, several drones at once (``sim_replay.swarm``: crossing paths, one drone
  passing in front of another, Mini 2 and Air 2S at 4-14 m); rendered by ``sim_replay.scene``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.sim_replay.swarm import SWARM_PITCH_DEG, swarm_plans

__all__ = ["DISTORTION", "FAR_HFOV_DEG", "HFOV_DEG", "PRESETS", "Preset", "Trajectory", "preset_camera"]

HFOV_DEG = 70.0
FAR_HFOV_DEG = 12.0
DISTORTION = (-0.06, 0.015, 0.0, 0.0, 0.0)

# A trajectory maps (time s, offsets drawn from the seed) to (p_ned (3,), (yaw, pitch, roll) deg).
Trajectory = Callable[[float, np.ndarray], tuple[np.ndarray, tuple[float, float, float]]]


@dataclass(frozen=True)
class Preset:
    """One scripted sequence.

    ``hfov_deg``: the camera's horizontal field of view. ``multi_drone``: the preset flies several
    drones (``sim_replay.swarm``; ``trajectory`` is then its first drone's path for reference and
    ``sim_replay.scene.build_scene`` renders it).
    """

    name: str
    frames: int
    fps: float
    drone: str
    camera_pitch_deg: float
    default_seed: int
    description: str
    trajectory: Trajectory
    hfov_deg: float = HFOV_DEG
    multi_drone: bool = False


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


def _far(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    s = t / (300 / 30.0)  # 0 -> 1 over the sequence
    r = 145.0 + (22.0 - 145.0) * s + 3.0 * o[0]
    azimuth = math.radians(1.2 * math.sin(2 * math.pi * 0.23 * t + o[1]) + 0.5 * o[2])
    elevation = math.radians(6.0 + 0.8 * math.sin(2 * math.pi * 0.17 * t + o[3]) + 0.3 * o[4])
    p = r * np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            -math.sin(elevation),
        ]
    )
    yaw = 180.0 + 25.0 * math.sin(2 * math.pi * 0.23 * t + o[1]) + 20 * o[6]  # coming at the camera
    return p, ((yaw + 180.0) % 360.0 - 180.0, -12.0, 8.0 * math.sin(2 * math.pi * 0.23 * t + o[1]))


def _swarm_reference(t: float, o: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
    """The swarm's first drone at its default seed (``sim_replay.scene`` renders them all)."""
    return swarm_plans(15, 1)[0].path(t)


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset("seq11", 500, 30.0, "mini2", 32.0, 11, "linear translation, no rotation", _seq11),
        Preset("seq12", 400, 30.0, "mini2", 32.0, 12, "non-linear translation, no rotation", _seq12),
        Preset("seq13", 300, 30.0, "mini2", 32.0, 13, "non-linear translation with rotation", _seq13),
        Preset(
            "2dronekey", 1000, 30.0, "mini2", 32.0, 2, "rotation-heavy, translation nearly fixed", _2dronekey
        ),
        Preset(
            "far", 300, 30.0, "air2s", 6.0, 14, "approach from 145 m to 22 m, long lens", _far, FAR_HFOV_DEG
        ),
        Preset(
            "swarm",
            300,
            30.0,
            "mini2",
            SWARM_PITCH_DEG,
            15,
            "several drones crossing, one passing in front of another",
            _swarm_reference,
            multi_drone=True,
        ),
    )
}


def preset_camera(width: int = 1920, height: int = 1080, hfov_deg: float = HFOV_DEG) -> CameraModel:
    """The simulated camera: 70 deg horizontal field of view (a preset's own), mild barrel distortion."""
    return CameraModel.from_fov(width, height, hfov_deg, dist=np.array(DISTORTION))
