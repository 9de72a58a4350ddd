"""A scene of one or more drones seen by one or more cameras: what ``dronekey-sim`` renders for the
``swarm`` preset and for ``--cameras N``.

The scene frame is local North-East-Down at the first camera, which stands where a single-camera
sequence's camera does (looking north, pitched up as the preset says). Cameras 1..N-1 stand on a
line to the east of it, ``camera_spacing_m`` apart (0.75 times the drones' mean range, within
5 m and 50 m / (N-1), so any two are 5-50 m apart), each 0.5 m higher than the last and aimed at
the drones' mean position. Every camera sees the same flight on the same time base.

The site file (``io.site``, docs/design.md §5.4) puts the scene in East-North-Up at a geodetic
origin under the first camera, which stands ``CAMERA_HEIGHT_M`` above it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dronekey.geometry.drone_spec import available_specs, load_spec
from dronekey.geometry.rotations import ned_from_camera, rotation_from_euler_deg
from dronekey.sim_replay.flight import CoordinatedFlight
from dronekey.sim_replay.io.site import (
    SITE_FORMAT,
    SITE_FRAME,
    SiteCamera,
    SiteDocument,
    SiteOrigin,
    enu_from_ned,
)
from dronekey.sim_replay.multi_sequence import MultiDroneSequence, SceneDrone, ViewPose
from dronekey.sim_replay.presets import PRESETS, Preset, preset_camera
from dronekey.sim_replay.swarm import DronePlan, swarm_plans
from dronekey.sim_replay.synthetic_sequence import (
    SequenceConditions,
    background_source,
    check_render_size,
    style_seed_for,
)

__all__ = [
    "CAMERA_HEIGHT_M",
    "DEFAULT_DRONES",
    "MAX_CAMERAS",
    "SITE_ORIGIN",
    "Scene",
    "build_scene",
    "camera_spacing_m",
]

SITE_ORIGIN = SiteOrigin(lat=47.397742, lon=8.545594, alt_m=488.0)
CAMERA_HEIGHT_M = 1.5
DEFAULT_DRONES = 3
MAX_CAMERAS = 8
MAX_DRONES = 12
_WGS84_A, _WGS84_F = 6378137.0, 1 / 298.257223563


@dataclass(frozen=True)
class Scene:
    """One rendered view per camera (``views[k]`` is camera ``camk``) and the site file describing them."""

    views: list[MultiDroneSequence]
    site: SiteDocument


def _geodetic(origin: SiteOrigin, enu: np.ndarray) -> tuple[float, float, float]:
    """WGS84 (lat deg, lon deg, alt m) of East-North-Up metres at ``origin`` (exact, via ECEF)."""
    e2 = _WGS84_F * (2 - _WGS84_F)
    lat, lon = math.radians(origin.lat), math.radians(origin.lon)
    sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
    n = _WGS84_A / math.sqrt(1 - e2 * sl**2)
    ecef0 = np.array(
        [(n + origin.alt_m) * cl * co, (n + origin.alt_m) * cl * so, (n * (1 - e2) + origin.alt_m) * sl]
    )
    R_ecef_enu = np.array([[-so, -sl * co, cl * co], [co, -sl * so, cl * so], [0.0, cl, sl]])
    x, y, z = ecef0 + R_ecef_enu @ np.asarray(enu, dtype=np.float64)
    lon_p, r = math.atan2(y, x), math.hypot(x, y)
    lat_p = math.atan2(z, r * (1 - e2))
    for _ in range(8):
        n = _WGS84_A / math.sqrt(1 - e2 * math.sin(lat_p) ** 2)
        alt = r / math.cos(lat_p) - n
        lat_p = math.atan2(z, r * (1 - e2 * n / (n + alt)))
    n = _WGS84_A / math.sqrt(1 - e2 * math.sin(lat_p) ** 2)
    return math.degrees(lat_p), math.degrees(lon_p), r / math.cos(lat_p) - n


def camera_spacing_m(mean_range_m: float, n_cameras: int) -> float:
    """Distance between neighbouring cameras: 0.75 x the mean range, within [5, 50 / (N - 1)] m."""
    return float(np.clip(0.75 * mean_range_m, 5.0, 50.0 / max(n_cameras - 1, 1)))


def _plans(
    preset: Preset, seed: int, n_drones: int, range_scale: float, airframe: str | None
) -> list[DronePlan]:
    if preset.multi_drone:
        return swarm_plans(seed, n_drones, range_scale, airframe)
    offsets = np.random.default_rng(seed).uniform(-1, 1, 8)  # == SyntheticSequence._offsets

    def path(t: float) -> tuple[np.ndarray, tuple[float, float, float]]:
        p, angles = preset.trajectory(t, offsets)
        return np.asarray(p, dtype=np.float64) * range_scale, angles

    return [DronePlan(0, preset.drone, path)]


def _scene_drone(plan: DronePlan, times: np.ndarray, fps: float, c: SequenceConditions) -> SceneDrone:
    def position(t: float) -> np.ndarray:
        return np.asarray(plan.path(t)[0], dtype=np.float64)

    positions = np.array([position(t) for t in times])
    later = np.array([position(t + 0.5 / fps) for t in times])
    if c.flight == "coordinated":
        angles = CoordinatedFlight().attitudes_along(position, times, plan.path(0.0)[1][0])
    else:
        angles = np.array([plan.path(t)[1] for t in times])
    R = np.array([rotation_from_euler_deg(*a) for a in angles]).reshape(-1, 3, 3)
    style_seed = c.style_seed + plan.instance_id
    look = c.draw_look(style_seed)
    return SceneDrone(plan.instance_id, load_spec(plan.drone), look, style_seed, positions, later, R)


def _rig(preset: Preset, drones: list[SceneDrone], n_cameras: int) -> list[ViewPose]:
    views = [ViewPose("cam0", ned_from_camera(0.0, preset.camera_pitch_deg, 0.0).T, np.zeros(3))]
    target = np.concatenate([d.positions_ned for d in drones]).mean(axis=0)
    spacing = camera_spacing_m(float(np.linalg.norm(target)), n_cameras)
    for k in range(1, n_cameras):
        position = np.array([0.0, spacing * k, -0.5 * k])
        d = target - position
        yaw = math.degrees(math.atan2(d[1], d[0]))
        pitch = math.degrees(math.atan2(-d[2], math.hypot(d[0], d[1])))
        views.append(ViewPose(f"cam{k}", ned_from_camera(yaw, pitch, 0.0).T, position))
    return views


def _site_camera(view: ViewPose, origin: SiteOrigin) -> SiteCamera:
    R_site_cam = enu_from_ned @ view.R_cam_ned.T
    t_site = enu_from_ned @ view.position_ned + np.array([0.0, 0.0, CAMERA_HEIGHT_M])
    lat, lon, alt = _geodetic(origin, t_site)
    # Heading, elevation and roll of the optical axis: ned_from_camera's angles, recovered.
    axis_ned = view.R_cam_ned.T @ np.array([0.0, 0.0, 1.0])
    yaw = math.degrees(math.atan2(axis_ned[1], axis_ned[0]))
    pitch = math.degrees(math.asin(float(np.clip(-axis_ned[2], -1.0, 1.0))))
    R_level = ned_from_camera(yaw, pitch, 0.0)
    roll_R = R_level.T @ view.R_cam_ned.T  # rotation about the camera's z axis
    roll = math.degrees(math.atan2(roll_R[1, 0], roll_R[0, 0]))
    geo = (
        ",".join(f"{v:.9f}".rstrip("0").rstrip(".") for v in (lat, lon))
        + ","
        + ",".join(f"{v:.6f}".rstrip("0").rstrip(".") for v in (alt, yaw, pitch, roll))
    )
    return SiteCamera(
        id=view.camera_id,
        folder=view.camera_id,
        geo=geo,
        R_site_cam=R_site_cam.tolist(),
        t_site_cam_m=t_site.tolist(),
    )


def build_scene(
    preset: str,
    *,
    seed: int | None = None,
    frames: int | None = None,
    width: int = 1920,
    height: int = 1080,
    backgrounds: str | None = None,
    style_seed: int | None = None,
    leds: str = "random",
    flight: str = "scripted",
    background: str | None = None,
    range_scale: float = 1.0,
    cue_free: bool = False,
    drones: int | None = None,
    cameras: int = 1,
    airframe: str | None = None,
) -> Scene:
    """Prepare a scene: any preset (its drones; ``drones`` of the swarm) seen by ``cameras`` cameras.

    The keywords are ``synthetic_sequence.build_sequence``'s; ``drones`` (1-12, default 3) and
    ``airframe`` (every drone of the swarm this spec, ``dronekey.geometry.drone_spec``; default the
    swarm's mix) are for multi-drone presets only; drone i's look is drawn from style seed
    ``style_seed + i``.

    Raises
    ------
    ValueError
        Unknown preset, bad sizes, counts or conditions; ``drones`` with a single-drone preset.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; available: {', '.join(PRESETS)}")
    p = PRESETS[preset]
    if drones is not None and not p.multi_drone:
        raise ValueError(f"drones applies to the swarm preset only; {preset!r} flies one drone")
    if airframe is not None:
        if not p.multi_drone:
            raise ValueError(f"airframe applies to the swarm preset only; {preset!r} flies a {p.drone}")
        if airframe not in available_specs():
            raise ValueError(f"airframe must be one of {', '.join(available_specs())}, got {airframe!r}")
    n_drones = DEFAULT_DRONES if drones is None else int(drones)
    if not 1 <= n_drones <= MAX_DRONES:
        raise ValueError(f"drones must be 1-{MAX_DRONES}, got {n_drones}")
    if not 1 <= int(cameras) <= MAX_CAMERAS:
        raise ValueError(f"cameras must be 1-{MAX_CAMERAS}, got {cameras}")
    frames = p.frames if frames is None else int(frames)
    check_render_size(frames, width, height)
    seed = p.default_seed if seed is None else int(seed)
    conditions = SequenceConditions(
        style_seed=style_seed_for(seed) if style_seed is None else style_seed,
        leds=leds,
        flight=flight,
        background="procedural" if background is None else background,
        range_scale=range_scale,
        cue_free=bool(cue_free),
    )
    source = background_source(conditions.background, backgrounds)
    times = np.arange(frames) / p.fps
    plans = _plans(p, seed, n_drones, range_scale, airframe)
    scene_drones = [_scene_drone(plan, times, p.fps, conditions) for plan in plans]
    camera = preset_camera(width, height, p.hfov_deg)
    rig = _rig(p, scene_drones, int(cameras))
    views = [
        MultiDroneSequence(p, seed, camera, v, k, scene_drones, source, conditions) for k, v in enumerate(rig)
    ]
    site = SiteDocument(
        format=SITE_FORMAT,
        origin=SITE_ORIGIN,
        frame=SITE_FRAME,
        cameras=[_site_camera(v, SITE_ORIGIN) for v in rig],
    )
    return Scene(views, site)
