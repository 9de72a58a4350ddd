"""Render a preset into a sequence of frames with their ground truth, deterministically per seed.

Three seeds draw everything that is not the script, so a seed never used in training gives a fresh
sequence with the same character:

- the scene seed (``seed``): small offsets of the path, the background, lighting and noise, and the
  clutter of drone-free sequences;
- the drone-style seed (``style_seed``, derived from ``seed`` when not given): the drone's look,
  drawn as the training sampler draws it: a random body (``drone_look.BodyShape.random``), a random
  livery (``drone_look.DroneStyle.random``; LEDs absent on 45 % of drones), and whether lit LEDs
  blink. The same scene with another style seed flies the same path (the same keypoints and pose)
  with another drone.

Conditions for evaluation (``build_sequence``'s keywords, ``dronekey-sim``'s options): the LEDs
(``leds``: red front / green rear, the other way round, unlit, or the style's own), drone-free
sequences with moving birds, flying objects and clouds (``no_drone``), the attitude of coordinated
flight along the scripted positions (``flight``, see ``sim_replay.flight``), the background kind
(``background``: the procedural mix, skies only, cities only, or the held-out packaged photos
``backgrounds.HELD_OUT_PHOTOS`` that training never sees) and the distance (``range_scale``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec, load_spec
from dronekey.geometry.rotations import ned_from_camera, rotation_from_euler_deg
from dronekey.sim_replay.annotations import FrameRecord
from dronekey.sim_replay.backgrounds import HELD_OUT_PHOTOS, BackgroundSource, packaged_photos
from dronekey.sim_replay.drone_look import LED_MODES, DroneLook
from dronekey.sim_replay.effects import draw_edge_clutter, sensor_noise
from dronekey.sim_replay.flight import FLIGHT_MODELS, CoordinatedFlight
from dronekey.sim_replay.flyers import random_flyers
from dronekey.sim_replay.mesh import build_mesh
from dronekey.sim_replay.presets import PRESETS, Preset, preset_camera
from dronekey.sim_replay.provenance import renderer_fingerprint
from dronekey.sim_replay.renderer import Lighting, render_drone

__all__ = [
    "BACKGROUND_KINDS",
    "GENERATOR",
    "FlightPath",
    "RenderedFrame",
    "SequenceConditions",
    "SyntheticSequence",
    "background_source",
    "build_sequence",
    "check_render_size",
    "sequence_info",
    "style_seed_for",
]

log = logging.getLogger(__name__)

GENERATOR = "dronekey.sim_replay"
# ``background`` of build_sequence / --background of dronekey-sim: the procedural mix (skies,
# terrain, cities), procedural skies only, procedural cities only, or the held-out packaged photos.
BACKGROUND_KINDS = ("procedural", "sky", "urban", "photos")
# Streams of the scene seed besides the main one: the drone-style seed it implies, the clutter.
_STYLE_STREAM, _CLUTTER_STREAM = 0x5717, 0xC1077


def style_seed_for(seed: int) -> int:
    """The drone-style seed that the scene seed ``seed`` implies when no style seed is given."""
    return int(np.random.SeedSequence((int(seed), _STYLE_STREAM)).generate_state(1)[0])


# ----------------------------------------------------------------------------- conditions
@dataclass(frozen=True)
class SequenceConditions:
    """The knobs of a rendered sequence beyond the preset and the scene seed (``build_sequence``).

    style_seed : seed of the drone's look (``DroneLook.draw``), a non-negative integer.
    leds : one of ``LED_MODES``.
    no_drone : render the scene without the drone (and with moving birds, flying objects, clouds).
    flight : one of ``FLIGHT_MODELS``: the preset's attitude script, or coordinated flight.
    background : one of ``BACKGROUND_KINDS``.
    range_scale : factor on the drone's position relative to the camera (> 0; 2 is twice as far).
    cue_free : draw the drone's body with no front/back cue (``BodyShape.without_front_cues``): a
        drone whose front nobody can tell, whose heading the pipeline must report as unknown.
    """

    style_seed: int
    leds: str = "random"
    no_drone: bool = False
    flight: str = "scripted"
    background: str = "procedural"
    range_scale: float = 1.0
    cue_free: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.style_seed, bool) or not isinstance(self.style_seed, int | np.integer):
            raise ValueError(f"style_seed must be a non-negative integer, got {self.style_seed!r}")
        if self.style_seed < 0:
            raise ValueError(f"style_seed must be a non-negative integer, got {self.style_seed!r}")
        if self.leds not in LED_MODES:
            raise ValueError(f"leds must be one of {', '.join(LED_MODES)}, got {self.leds!r}")
        if self.flight not in FLIGHT_MODELS:
            raise ValueError(f"flight must be one of {', '.join(FLIGHT_MODELS)}, got {self.flight!r}")
        if self.background not in BACKGROUND_KINDS:
            raise ValueError(
                f"background must be one of {', '.join(BACKGROUND_KINDS)}, got {self.background!r}"
            )
        scale = self.range_scale
        if isinstance(scale, bool) or not isinstance(scale, int | float) or not (0 < scale < math.inf):
            raise ValueError(f"range_scale must be a positive number, got {scale!r}")

    def draw_look(self, style_seed: int) -> DroneLook:
        """The drone look these conditions give style seed ``style_seed`` (its LEDs, and its body made
        front/back symmetric with ``cue_free``): one rule for single- and multi-drone scenes."""
        return DroneLook.draw(style_seed, self.leds, self.cue_free)


def sequence_info(
    name: str, seed: int, preset: Preset, conditions: SequenceConditions, look: DroneLook | None
) -> dict:
    """The fields every sequence JSON's ``info`` (docs/design.md §5.1) starts with: the sequence, the
    renderer (``provenance.renderer_fingerprint``), the preset and the conditions it was rendered
    under; ``look`` is the (first) drone's, None without a drone."""
    c = conditions
    return {
        "sequence": name,
        "generator": GENERATOR,
        "renderer": renderer_fingerprint(),
        "seed": seed,
        "fps": preset.fps,
        "description": preset.description,
        "style_seed": c.style_seed,
        "leds": c.leds,
        "leds_lit": False if look is None else bool(look.leds_lit),
        "led_blink_hz": None if look is None else look.blink_hz,
        "no_drone": c.no_drone,
        "flight": c.flight,
        "background": c.background,
        "range_scale": float(c.range_scale),
        "cue_free": bool(c.cue_free),
    }


def check_render_size(frames: int, width: int, height: int) -> None:
    """Raise ``ValueError`` naming the argument when the frame count or the image size is not positive."""
    if frames <= 0:
        raise ValueError(f"frames must be positive, got {frames}")
    if width <= 0 or height <= 0:
        raise ValueError(f"width and height must be positive, got {width}x{height}")


@dataclass(frozen=True)
class FlightPath:
    """Where the drone is in every frame, before rendering.

    times_s : (N,) frame times, seconds. positions_ned : (N, 3) metres relative to the camera.
    R_ned_body : (N, 3, 3) body (FRD) -> NED. R_cam_ned : (3, 3) NED -> camera (OpenCV).
    """

    times_s: np.ndarray
    positions_ned: np.ndarray
    R_ned_body: np.ndarray
    R_cam_ned: np.ndarray

    def camera_pose(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` of frame ``i``: ``p_cam = R @ p_body + t``, metres."""
        return self.R_cam_ned @ self.R_ned_body[i], self.R_cam_ned @ self.positions_ned[i]


# ----------------------------------------------------------------------------- the sequence
@dataclass(frozen=True)
class RenderedFrame:
    """One rendered image and its ground truth (``record.file_name`` is filled by the writer)."""

    image: np.ndarray
    record: FrameRecord


class SyntheticSequence:
    """A preset rendered with one seed; iterate it for ``RenderedFrame`` objects, deterministically.

    ``conditions`` default to the preset as it is (the style seed derived from ``seed``); ``look``
    defaults to the one ``conditions`` draw.
    """

    def __init__(
        self,
        preset: Preset,
        seed: int,
        frames: int,
        camera: CameraModel,
        spec: DroneSpec,
        backgrounds: BackgroundSource,
        conditions: SequenceConditions | None = None,
        look: DroneLook | None = None,
    ) -> None:
        self.preset = preset
        self.name = preset.name
        self.seed = seed
        self.n_frames = frames
        self.fps = preset.fps
        self.camera = camera
        self.spec = spec
        self.conditions = conditions or SequenceConditions(style_seed=style_seed_for(seed))
        self.look = look or self.conditions.draw_look(self.conditions.style_seed)
        self._backgrounds = backgrounds

    @property
    def info(self) -> dict:
        """The JSON's ``info`` object (docs/design.md §5.1) with the conditions it was rendered under."""
        look = None if self.conditions.no_drone else self.look
        return sequence_info(self.name, self.seed, self.preset, self.conditions, look)

    def __len__(self) -> int:
        return self.n_frames

    def _offsets(self) -> np.ndarray:
        """The path's offsets: the first draws of the scene seed's main stream."""
        return np.random.default_rng(self.seed).uniform(-1, 1, 8)

    def _position(self, t_s: float, offsets: np.ndarray) -> np.ndarray:
        return (
            np.asarray(self.preset.trajectory(t_s, offsets)[0], dtype=np.float64)
            * self.conditions.range_scale
        )

    def flight_path(self) -> FlightPath:
        """The drone's position and attitude in every frame (no rendering; cheap)."""
        offsets = self._offsets()
        times = np.arange(self.n_frames) / self.fps
        positions = np.array([self._position(t, offsets) for t in times])
        if self.conditions.flight == "coordinated":
            initial_yaw = self.preset.trajectory(0.0, offsets)[1][0]
            angles = CoordinatedFlight().attitudes_along(
                lambda t: self._position(t, offsets), times, initial_yaw
            )
        else:
            angles = np.array([self.preset.trajectory(t, offsets)[1] for t in times])
        R_ned_body = np.array([rotation_from_euler_deg(*a) for a in angles]).reshape(-1, 3, 3)
        R_cam_ned = ned_from_camera(0.0, self.preset.camera_pitch_deg, 0.0).T
        return FlightPath(times, positions, R_ned_body, R_cam_ned)

    def __iter__(self) -> Iterator[RenderedFrame]:
        rng = np.random.default_rng(self.seed)
        offsets = rng.uniform(-1, 1, 8)  # == self._offsets()
        w, h = self.camera.size
        background = self._backgrounds.draw(h, w, rng)
        lighting = Lighting.random(rng)
        noise_sigma = float(rng.uniform(1.0, 3.0))
        if self.conditions.no_drone:
            yield from self._drone_free(background, rng, noise_sigma)
            return
        path = self.flight_path()
        mesh = build_mesh(self.spec, self.look.shape)
        exposure_s = 0.5 / self.fps
        for i in range(self.n_frames):
            t_s = float(path.times_s[i])
            R, t = path.camera_pose(i)
            t2 = path.R_cam_ned @ self._position(t_s + exposure_s, offsets)
            c0, c1 = self.camera.project(np.vstack([t, t2]))
            img = background.copy()
            style = self.look.style_at(t_s)
            ann = render_drone(img, self.camera, mesh, R, t, style, lighting, motion_blur_px=tuple(c1 - c0))
            img = sensor_noise(img, rng, sigma=noise_sigma)
            yield RenderedFrame(img, FrameRecord(i, round(t_s * 1e9), "", w, h, ann))

    def _drone_free(
        self, background: np.ndarray, rng: np.random.Generator, noise_sigma: float
    ) -> Iterator[RenderedFrame]:
        """The scene without the drone: edge clutter on the background, birds and clouds moving."""
        w, h = self.camera.size
        clutter_rng = np.random.default_rng((self.seed, _CLUTTER_STREAM))
        draw_edge_clutter(background, clutter_rng, int(clutter_rng.integers(1, 4)))
        flyers = random_flyers(clutter_rng, w, h)
        for i in range(self.n_frames):
            t_s = i / self.fps
            img = background.copy()
            for flyer in flyers:
                flyer.draw(img, t_s)
            img = sensor_noise(img, rng, sigma=noise_sigma)
            yield RenderedFrame(img, FrameRecord(i, round(t_s * 1e9), "", w, h, None))


def background_source(kind: str, folder: str | Path | None) -> BackgroundSource:
    if kind == "photos":
        if folder is not None:
            raise ValueError(
                f"background 'photos' draws only the held-out packaged photos; it cannot be combined "
                f"with a backgrounds folder (got {str(folder)!r})"
            )
        photos = packaged_photos(HELD_OUT_PHOTOS)
        if not photos:
            raise ImportError(
                f"background 'photos' needs the held-out packaged photos ({', '.join(HELD_OUT_PHOTOS)}) "
                "from scikit-image or scikit-learn, and neither is installed (pip install scikit-image "
                "scikit-learn)"
            )
        if len(photos) < len(HELD_OUT_PHOTOS):
            log.warning(
                "background 'photos': %d of the %d held-out photos are installed (scikit-image and "
                "scikit-learn ship them)",
                len(photos),
                len(HELD_OUT_PHOTOS),
            )
        return BackgroundSource(images=photos, photo_fraction=1.0)
    kinds = {"procedural": ("sky", "landscape", "urban"), "sky": ("sky",), "urban": ("urban",)}[kind]
    return BackgroundSource(folder, kinds=kinds)


def build_sequence(
    preset: str,
    *,
    seed: int | None = None,
    frames: int | None = None,
    width: int = 1920,
    height: int = 1080,
    backgrounds: str | Path | None = None,
    style_seed: int | None = None,
    leds: str = "random",
    no_drone: bool = False,
    flight: str = "scripted",
    background: str | None = None,
    range_scale: float = 1.0,
    cue_free: bool = False,
) -> SyntheticSequence:
    """Prepare a preset for rendering.

    Parameters
    ----------
    preset : str
        One of ``PRESETS``.
    seed : int, optional
        Seed of the scene (path offsets, background, lighting, noise, clutter); defaults to the
        preset's own (11, 12, 13, 2).
    frames : int, optional
        Number of frames (default: the preset's length); the script is time-based, so fewer frames
        render the beginning of the same flight.
    width, height : int
        Image size, pixels; the camera keeps its 70 deg horizontal field of view.
    backgrounds : path, optional
        Folder of background photos, drawn for 70 % of the sequences instead of procedural ones
        (not with ``background="photos"``).
    style_seed : int, optional
        Seed of the drone's look (body, livery, LEDs, blinking; ``DroneLook.draw``), a non-negative
        integer; defaults to ``style_seed_for(seed)``. It changes the drone, never its path.
    leds : str
        One of ``LED_MODES``: ``"random"`` (the style's own LEDs), ``"red-front"``,
        ``"green-front"`` or ``"off"``.
    no_drone : bool
        Render the scene without the drone: no annotation in any frame; clouds, buildings, trees or
        wires enter from the edges, and birds, flying objects and clouds cross the frame.
    flight : str
        One of ``FLIGHT_MODELS``: ``"scripted"`` (the preset's attitudes) or ``"coordinated"``
        (the attitude of coordinated flight along the scripted positions, ``sim_replay.flight``).
    background : str, optional
        One of ``BACKGROUND_KINDS``: ``"procedural"`` (default: skies, terrain and cities),
        ``"sky"``, ``"urban"``, or ``"photos"`` (only the held-out packaged photos,
        ``backgrounds.HELD_OUT_PHOTOS``, never used in training).
    range_scale : float
        Factor (> 0) on the drone's scripted position relative to the camera: 2.5 puts it 2.5 times
        as far and draws it 2.5 times smaller (about 30-60 px across at 1080p).
    cue_free : bool
        Draw the drone's body without any front/back cue (no gimbal, nose, taper, battery bulge,
        dropped rear arms or half stripe): the same style seed's drone, made front/back symmetric.

    Raises
    ------
    ValueError
        Unknown preset, LED mode, flight model or background kind; non-positive sizes, frame count
        or range scale; a negative style seed; ``background="photos"`` with a backgrounds folder.
    FileNotFoundError
        The backgrounds folder is missing or holds no images.
    ImportError
        ``background="photos"`` without scikit-image and scikit-learn (no packaged photo).
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; available: {', '.join(PRESETS)}")
    p = PRESETS[preset]
    if p.multi_drone:
        raise ValueError(
            f"preset {preset!r} flies several drones; render it with sim_replay.scene.build_scene "
            "(dronekey-sim does)"
        )
    frames = p.frames if frames is None else int(frames)
    check_render_size(frames, width, height)
    seed = p.default_seed if seed is None else int(seed)
    conditions = SequenceConditions(
        style_seed=style_seed_for(seed) if style_seed is None else style_seed,
        leds=leds,
        no_drone=bool(no_drone),
        flight=flight,
        background="procedural" if background is None else background,
        range_scale=range_scale,
        cue_free=bool(cue_free),
    )
    source = background_source(conditions.background, backgrounds)
    return SyntheticSequence(
        p, seed, frames, preset_camera(width, height, p.hfov_deg), load_spec(p.drone), source, conditions
    )
