"""The scripted drones of the ``swarm`` preset: several drones of mixed sizes and ranges, crossing.

Positions are local North-East-Down metres relative to the camera (which looks north, pitched up
``SWARM_PITCH_DEG``); attitudes are yaw / pitch / roll in degrees, the nose along the direction of
flight. The first three drones are scripted; more are drawn from the seed:

- drone 0 (DJI Mini 2, about 6 m away) crosses the view left to right;
- drone 1 (DJI Air 2S, about 10 m away) crosses right to left behind it; half-way through the
  sequence both are on the same line of sight, so drone 0 passes in front of drone 1 and hides it
  (or part of it) for a few frames;
- drone 2 (DJI Mini 2, about 4 m away) flies a figure-eight above them, crossing drone 0's image
  path at other times;
- drones 3+ (either model, 5-14 m away) fly straight lines across the view.

The seed moves each path by a little (a few degrees of bearing, a few per cent of range) so another
seed flies another swarm of the same character; the crossing and the occlusion stay.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

__all__ = ["SWARM_DURATION_S", "SWARM_PITCH_DEG", "DronePlan", "swarm_plans"]

SWARM_PITCH_DEG = 15.0
SWARM_DURATION_S = 300 / 30.0
_OFFSETS_STREAM = 0x5A2A

# A path: time (s) -> (p_ned (3,), (yaw, pitch, roll) degrees).
Path = Callable[[float], tuple[np.ndarray, tuple[float, float, float]]]


@dataclass(frozen=True)
class DronePlan:
    """One drone of a scene: instance id, spec name (``dronekey.geometry.drone_spec``) and path."""

    instance_id: int
    drone: str
    path: Path


def _direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit NED vector of a bearing (from north, towards east) and an elevation (up)."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), -math.sin(e)])


def _heading(velocity: np.ndarray) -> float:
    return math.degrees(math.atan2(velocity[1], velocity[0]))


def _straight(through: np.ndarray, velocity: np.ndarray, t_cross: float, wobble: float) -> Path:
    """A straight line through ``through`` at ``t_cross`` (s), nose forward, a little pitch and roll."""

    def path(t: float) -> tuple[np.ndarray, tuple[float, float, float]]:
        p = through + velocity * (t - t_cross)
        return p, (_heading(velocity), -6.0 + 2.0 * math.sin(1.3 * t + wobble), 3.0 * math.sin(0.9 * t))

    return path


def _figure_eight(centre: np.ndarray, size_m: float, period_s: float, phase: float) -> Path:
    """A figure-eight in the plane facing the camera (east and up), nose along the velocity."""
    w = 2 * math.pi / period_s

    def point(t: float) -> np.ndarray:
        return centre + size_m * np.array(
            [0.0, math.sin(w * t + phase), -0.5 * math.sin(2 * (w * t + phase))]
        )

    def path(t: float) -> tuple[np.ndarray, tuple[float, float, float]]:
        velocity = (point(t + 1e-3) - point(t - 1e-3)) / 2e-3
        return point(t), (_heading(velocity), -8.0, 10.0 * math.cos(w * t + phase))

    return path


def swarm_plans(
    seed: int, n_drones: int, range_scale: float = 1.0, airframe: str | None = None
) -> list[DronePlan]:
    """The ``n_drones`` (>= 1) drones of the swarm for scene seed ``seed``.

    ``range_scale`` multiplies every position (the drones keep their bearings, so the crossing and
    the occlusion stay). ``airframe`` (a spec name) makes every drone that airframe, on the same
    paths; by default the swarm mixes Mini 2s and Air 2Ss, which one camera cannot tell apart
    (docs/evaluation.md, "One camera, two airframes").
    """
    if n_drones < 1:
        raise ValueError(f"a swarm needs at least one drone, got {n_drones}")
    rng = np.random.default_rng((int(seed), _OFFSETS_STREAM))
    o = rng.uniform(-1, 1, 8)
    t_cross = SWARM_DURATION_S / 2 + 0.5 * o[0]
    elevation = SWARM_PITCH_DEG + 2.0 * o[1]
    # Drone 1 a little off drone 0's line of sight: a partial or full occlusion of a few frames.
    near = 6.0 * (1 + 0.05 * o[2]) * _direction(2.0 * o[3], elevation)
    far = 10.0 * (1 + 0.05 * o[4]) * _direction(2.0 * o[3] + 0.3 * o[5], elevation + 0.3 * o[6])
    plans = [
        DronePlan(0, "mini2", _straight(near, np.array([0.05, 0.7, -0.02 * o[7]]), t_cross, o[2])),
        DronePlan(1, "air2s", _straight(far, np.array([-0.1, -1.1, 0.03]), t_cross, o[4])),
    ]
    if n_drones > 2:
        centre = 4.0 * _direction(-4.0 + 3.0 * o[5], elevation + 8.0 + 2.0 * o[6])
        plans.append(DronePlan(2, "mini2", _figure_eight(centre, 1.3, 7.0, math.pi * o[7])))
    for i in range(3, n_drones):
        r = float(rng.uniform(5.0, 14.0))
        crossing = r * _direction(float(rng.uniform(-20, 20)), elevation + float(rng.uniform(-8, 8)))
        speed = float(rng.uniform(0.04, 0.08)) * r * float(rng.choice([-1.0, 1.0]))
        velocity = np.array([0.0, speed, float(rng.uniform(-0.2, 0.2))])
        drone = "air2s" if rng.random() < 0.5 else "mini2"
        plans.append(DronePlan(i, drone, _straight(crossing, velocity, float(rng.uniform(3, 7)), r)))
    if range_scale != 1.0:
        plans = [DronePlan(p.instance_id, p.drone, _scaled(p.path, range_scale)) for p in plans]
    if airframe is not None:
        plans = [replace(p, drone=airframe) for p in plans]
    return plans[:n_drones]


def _scaled(path: Path, scale: float) -> Path:
    def scaled(t: float) -> tuple[np.ndarray, tuple[float, float, float]]:
        p, angles = path(t)
        return p * scale, angles

    return scaled
