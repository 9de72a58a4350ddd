"""3DronePose-style sequence presets (after the paper's Tab. I) and the sequence renderer.

A sequence is a fixed camera on a tripod, pitched up at the sky, watching one drone fly a scripted
path. Positions are in local North-East-Down metres relative to the camera; attitudes are the
drone's yaw / pitch / roll (degrees, aerospace order). Three seeds draw everything that is not the
script, so a seed never used in training gives a fresh sequence with the same character:

- the scene seed (``seed``): small offsets of the path, the background, lighting and noise, and the
  clutter of drone-free sequences;
- the drone-style seed (``style_seed``, derived from ``seed`` when not given): the drone's look,
  drawn as the training sampler draws it: a random body (``mesh.BodyShape.random``), a random
  livery (``mesh.DroneStyle.random``; LEDs absent on 45 % of drones), and whether lit LEDs blink.
  The same scene with another style seed flies the same path (the same keypoints and pose) with
  another drone.

Conditions for evaluation (``build_sequence``'s keywords, ``dronekey-sim``'s options): the LEDs
(``leds``: red front / green rear, the other way round, unlit, or the style's own), drone-free
sequences with moving birds, flying objects and clouds (``no_drone``), the attitude of coordinated
flight along the scripted positions (``flight``, see ``sim_replay.flight``), the background kind
(``background``: the procedural mix, skies only, cities only, or the held-out packaged photos
``backgrounds.HELD_OUT_PHOTOS`` that training never sees) and the distance (``range_scale``).

Presets (30 fps, 1920x1080, DJI Mini 2 unless noted):

- ``seq11``: 500 frames, linear translation at constant velocity, no rotation.
- ``seq12``: 400 frames, non-linear translation (a Lissajous figure), no rotation.
- ``seq13``: 300 frames, non-linear translation with rotation: a full yaw turn (through +-180 deg)
  with pitch and roll oscillations.
- ``2dronekey``: 1000 frames, rotation-heavy, translation nearly fixed (the paper's keypoint
  training sequences): the drone hovers while tumbling through wide attitudes.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.geometry.drone_spec import DroneSpec, load_spec
from dronekey.geometry.rotations import ned_from_camera, rotation_from_euler_deg

from .annotations import FrameRecord
from .backgrounds import HELD_OUT_PHOTOS, BackgroundSource, packaged_photos
from .effects import draw_edge_clutter, sensor_noise
from .flight import FLIGHT_MODELS, CoordinatedFlight
from .mesh import LED_MODES, BodyShape, DroneStyle, build_mesh
from .renderer import Lighting, render_drone

__all__ = [
    "BACKGROUND_KINDS",
    "FLIGHT_MODELS",
    "LED_MODES",
    "PRESETS",
    "DroneLook",
    "FlightPath",
    "Preset",
    "RenderedFrame",
    "SequenceConditions",
    "SyntheticSequence",
    "build_sequence",
    "preset_camera",
    "style_seed_for",
]

log = logging.getLogger(__name__)

GENERATOR = "dronekey.sim_replay"
HFOV_DEG = 70.0
DISTORTION = (-0.06, 0.015, 0.0, 0.0, 0.0)
# ``background`` of build_sequence / --background of dronekey-sim: the procedural mix (skies,
# terrain, cities), procedural skies only, procedural cities only, or the held-out packaged photos.
BACKGROUND_KINDS = ("procedural", "sky", "urban", "photos")
# Lit LEDs blink in this share of the drones, at a rate drawn in BLINK_HZ (half the period on).
BLINK_PROB = 0.25
BLINK_HZ = (1.0, 2.0)
# Streams of the scene seed besides the main one: the drone-style seed it implies, the clutter.
_STYLE_STREAM, _CLUTTER_STREAM = 0x5717, 0xC1077

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


def style_seed_for(seed: int) -> int:
    """The drone-style seed that the scene seed ``seed`` implies when no style seed is given."""
    return int(np.random.SeedSequence((int(seed), _STYLE_STREAM)).generate_state(1)[0])


# ----------------------------------------------------------------------------- the drone's look
@dataclass(frozen=True)
class DroneLook:
    """The drone of one sequence: its body, its livery and its LEDs' blinking.

    shape : the body around the fixed keypoints (``mesh.BodyShape``).
    style : colours, propeller look and LED colours when they are on (``mesh.DroneStyle``).
    blink_hz : blinking rate of lit LEDs, Hz, or None for steady LEDs (or none lit).
    blink_phase : where in its period the blinking starts at t = 0, as a fraction of the period.
    """

    shape: BodyShape
    style: DroneStyle
    blink_hz: float | None = None
    blink_phase: float = 0.0

    @classmethod
    def draw(cls, style_seed: int, leds: str = "random") -> DroneLook:
        """The look drawn from ``style_seed`` (a non-negative integer) with the LEDs of ``leds``.

        ``leds`` is one of ``LED_MODES``: ``"random"`` keeps the style's own LEDs (absent on 45 % of
        drones, any colours otherwise); ``"red-front"`` / ``"green-front"`` light red at the front and
        green at the rear or the other way round, ``"off"`` leaves them dark; those three give the
        body LED housings at both ends. The body, the livery and the blinking are drawn the same
        way whatever ``leds`` is, so one style seed gives the same drone in every LED mode.
        """
        if leds not in LED_MODES:
            raise ValueError(f"leds must be one of {', '.join(LED_MODES)}, got {leds!r}")
        rng = np.random.default_rng(style_seed)
        shape = BodyShape.random(rng, leds=True)
        style = DroneStyle.random(rng)
        blinks = bool(rng.random() < BLINK_PROB)
        hz = float(rng.uniform(*BLINK_HZ))
        phase = float(rng.uniform(0.0, 1.0))
        if leds != "random":
            shape = dataclasses.replace(shape, led_front=True, led_rear=True)
            style = style.with_leds(leds)
        look = cls(shape, style, hz if blinks else None, phase)
        return look if look.leds_lit else dataclasses.replace(look, blink_hz=None)

    @property
    def leds_lit(self) -> bool:
        """Whether the drone shows at least one lit LED (when not in a blink's off phase)."""
        return (self.shape.led_front and self.style.front_led is not None) or (
            self.shape.led_rear and self.style.rear_led is not None
        )

    def leds_on(self, t_s: float) -> bool:
        """Whether the lit LEDs are on at time ``t_s`` (seconds from the start of the sequence)."""
        if not self.leds_lit:
            return False
        if self.blink_hz is None:
            return True
        return (t_s * self.blink_hz + self.blink_phase) % 1.0 < 0.5

    def style_at(self, t_s: float) -> DroneStyle:
        """The style to render at time ``t_s``: the LEDs unlit in a blink's off phase."""
        if self.blink_hz is None or self.leds_on(t_s):
            return self.style
        return self.style.with_leds("off")


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
    """

    style_seed: int
    leds: str = "random"
    no_drone: bool = False
    flight: str = "scripted"
    background: str = "procedural"
    range_scale: float = 1.0

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


# ----------------------------------------------------------------------------- moving clutter
@dataclass(frozen=True)
class _Flyer:
    """A bird, a flying object or a cloud crossing the frame in a straight line (pixels, seconds).

    Positions wrap round a frame grown by ``margin`` on every side: one that leaves comes back in
    from the opposite edge, so long sequences keep their clutter.
    """

    kind: str  # "bird", "blob" or "cloud"
    start: tuple[float, float]
    velocity: tuple[float, float]  # px/s
    size: float  # px: wing span, blob diameter, cloud width
    colour: tuple[float, float, float]  # BGR 0-255
    margin: float
    bank: float = 0.0  # rad
    flap_hz: float = 0.0
    phase: float = 0.0
    outline: np.ndarray | None = None  # blob: (M + 1, 2) outline, then its string's end (0, 0: none), x size
    alpha: np.ndarray | None = None  # cloud: (h, w) float32 opacity patch

    def centre(self, t_s: float, w: int, h: int) -> tuple[float, float]:
        m = self.margin
        x = (self.start[0] + self.velocity[0] * t_s + m) % (w + 2 * m) - m
        y = (self.start[1] + self.velocity[1] * t_s + m) % (h + 2 * m) - m
        return x, y

    def draw(self, img: np.ndarray, t_s: float) -> None:
        """Draw at time ``t_s`` into ``img`` (BGR uint8, in place)."""
        h, w = img.shape[:2]
        cx, cy = self.centre(t_s, w, h)
        if self.kind == "cloud":
            _blend_patch(img, self.alpha, self.colour, cx, cy)
        elif self.kind == "bird":
            span = self.size / 2
            flap = 0.6 * span * math.sin(2 * math.pi * (self.flap_hz * t_s + self.phase))
            pts = np.array(
                [[-span, -flap], [-0.3 * span, -0.2 * flap], [0, 0], [0.3 * span, -0.2 * flap], [span, -flap]]
            )
            c, s = math.cos(self.bank), math.sin(self.bank)
            pts = pts @ np.array([[c, s], [-s, c]]) + [cx, cy]
            thick = max(1, round(self.size / 12))
            cv2.polylines(
                img, [np.round(pts * 16).astype(np.int32)], False, self.colour, thick, cv2.LINE_AA, 4
            )
            body = (max(1, thick), max(1, thick // 2))
            cv2.ellipse(img, (round(cx), round(cy)), body, 0, 0, 360, self.colour, -1, cv2.LINE_AA)
        else:
            outline = self.outline[:-1] * self.size + [cx, cy]
            cv2.fillPoly(img, [np.round(outline * 16).astype(np.int32)], self.colour, cv2.LINE_AA, 4)
            tail = self.outline[-1]
            if np.any(tail):  # a kite string, an antenna, a wing
                end = (round(cx + tail[0] * self.size), round(cy + tail[1] * self.size))
                width = max(1, round(self.size / 15))
                cv2.line(img, (round(cx), round(cy)), end, self.colour, width, cv2.LINE_AA)


def _blend_patch(img: np.ndarray, alpha: np.ndarray, colour: tuple, cx: float, cy: float) -> None:
    """Blend ``colour`` over ``img`` with the opacity patch ``alpha`` centred at (cx, cy), in place."""
    h, w = img.shape[:2]
    ph, pw = alpha.shape
    x0, y0 = round(cx - pw / 2), round(cy - ph / 2)
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + pw, w), min(y0 + ph, h)
    if xb <= xa or yb <= ya:
        return
    a = alpha[ya - y0 : yb - y0, xa - x0 : xb - x0, None]
    region = img[ya:yb, xa:xb].astype(np.float32)
    img[ya:yb, xa:xb] = (region * (1 - a) + np.asarray(colour, np.float32) * a + 0.5).astype(np.uint8)


def _cloud_alpha(rng: np.random.Generator, width: float) -> np.ndarray:
    """A soft cloud's opacity (float32 in [0, 1]) about ``width`` x ``width / 2`` pixels."""
    pw, ph = max(8, int(width)), max(6, int(width / 2))
    mask = np.zeros((ph, pw), np.uint8)
    for _ in range(int(rng.integers(4, 10))):
        cx, cy = rng.uniform(0.25, 0.75) * pw, rng.uniform(0.4, 0.6) * ph
        axes = (max(1, int(pw * rng.uniform(0.1, 0.22))), max(1, int(ph * rng.uniform(0.15, 0.3))))
        cv2.ellipse(mask, (int(cx), int(cy)), axes, 0, 0, 360, 255, -1)
    soft = cv2.GaussianBlur(mask, (0, 0), max(1.0, width * 0.05)).astype(np.float32) / 255.0
    return soft * float(rng.uniform(0.45, 0.9))


def _flyers(rng: np.random.Generator, w: int, h: int) -> list[_Flyer]:
    """Clouds, then flying objects, then birds (drawn in that order), sized for a (w, h) frame."""
    k = w / 1920.0  # the sizes and speeds below are for a 1080p frame
    out: list[_Flyer] = []
    for _ in range(int(rng.integers(1, 4))):
        width = float(rng.uniform(0.1, 0.35)) * w
        speed = float(rng.uniform(3.0, 20.0)) * k * rng.choice([-1.0, 1.0])
        alpha = _cloud_alpha(rng, width)
        colour = tuple(float(v) for v in np.full(3, rng.uniform(200, 255)) * rng.uniform(0.9, 1.0, 3))
        start = (float(rng.uniform(0, w)), float(rng.uniform(0, 0.7 * h)))
        out.append(_Flyer("cloud", start, (speed, 0.0), width, colour, margin=width, alpha=alpha))
    for _ in range(int(rng.integers(0, 3))):
        size = float(np.exp(rng.uniform(np.log(8), np.log(60)))) * k
        speed, heading = float(rng.uniform(10, 150)) * k, float(rng.uniform(0, 2 * np.pi))
        n = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = 0.5 * rng.uniform(0.4, 1.0, n)
        outline = np.c_[rad * np.cos(ang), rad * np.sin(ang) * rng.uniform(0.3, 1.0)]
        tail = rng.normal(0, 1.0, 2) if rng.random() < 0.5 else np.zeros(2)
        out.append(
            _Flyer(
                "blob",
                (float(rng.uniform(0, w)), float(rng.uniform(0, h))),
                (speed * math.cos(heading), speed * math.sin(heading)),
                size,
                tuple(float(v) for v in rng.uniform(0, 255, 3)),
                margin=2 * size,
                outline=np.vstack([outline, tail]),
            )
        )
    for _ in range(int(rng.integers(2, 7))):
        size = float(np.exp(rng.uniform(np.log(6), np.log(40)))) * k
        speed = float(rng.uniform(40, 250)) * k
        heading = float(rng.normal(0, 0.3)) + (math.pi if rng.random() < 0.5 else 0.0)
        out.append(
            _Flyer(
                "bird",
                (float(rng.uniform(0, w)), float(rng.uniform(0, 0.8 * h))),
                (speed * math.cos(heading), speed * math.sin(heading)),
                size,
                tuple(float(v) for v in np.full(3, rng.uniform(10, 70))),
                margin=size,
                bank=float(rng.uniform(-0.5, 0.5)),
                flap_hz=float(rng.uniform(2.0, 6.0)),
                phase=float(rng.uniform(0, 1)),
            )
        )
    return out


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
        self.look = look or DroneLook.draw(self.conditions.style_seed, self.conditions.leds)
        self._backgrounds = backgrounds

    @property
    def info(self) -> dict:
        """The JSON's ``info`` object (docs/design.md §5.1) with the conditions it was rendered under."""
        c = self.conditions
        return {
            "sequence": self.name,
            "generator": GENERATOR,
            "seed": self.seed,
            "fps": self.fps,
            "description": self.preset.description,
            "style_seed": c.style_seed,
            "leds": c.leds,
            "leds_lit": False if c.no_drone else bool(self.look.leds_lit),
            "led_blink_hz": None if c.no_drone else self.look.blink_hz,
            "no_drone": c.no_drone,
            "flight": c.flight,
            "background": c.background,
            "range_scale": float(c.range_scale),
        }

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
        flyers = _flyers(clutter_rng, w, h)
        for i in range(self.n_frames):
            t_s = i / self.fps
            img = background.copy()
            for flyer in flyers:
                flyer.draw(img, t_s)
            img = sensor_noise(img, rng, sigma=noise_sigma)
            yield RenderedFrame(img, FrameRecord(i, round(t_s * 1e9), "", w, h, None))


def _background_source(kind: str, folder: str | Path | None) -> BackgroundSource:
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
    frames = p.frames if frames is None else int(frames)
    if frames <= 0:
        raise ValueError(f"frames must be positive, got {frames}")
    if width <= 0 or height <= 0:
        raise ValueError(f"width and height must be positive, got {width}x{height}")
    seed = p.default_seed if seed is None else int(seed)
    conditions = SequenceConditions(
        style_seed=style_seed_for(seed) if style_seed is None else style_seed,
        leds=leds,
        no_drone=bool(no_drone),
        flight=flight,
        background="procedural" if background is None else background,
        range_scale=range_scale,
    )
    source = _background_source(conditions.background, backgrounds)
    return SyntheticSequence(
        p, seed, frames, preset_camera(width, height), load_spec(p.drone), source, conditions
    )
