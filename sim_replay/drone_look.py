"""The drone's look, drawn at random: its body around the fixed keypoints (``BodyShape``), its livery
and LEDs (``DroneStyle``), and for a rendered sequence whether its lit LEDs blink (``DroneLook``).

The propeller hubs are the labels and never move; everything else is a look that real drones do not
share, so it is drawn at random: body length, width and height, nose taper, a battery bulge at the
rear, the gimbal (under the nose, on top, or none), arm thickness, rear arms that leave the body
lower (folding-arm drones), propeller guards, landing legs, the light stripe (anywhere or absent)
and the LEDs (absent on many drones; any colours; under the motors, under the arms or on the body;
front/back convention either way). ``mesh.build_mesh`` turns a shape into parts; the renderer
paints them in a style.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = [
    "BLINK_HZ",
    "BLINK_PROB",
    "GIMBAL_PLACES",
    "LED_MODES",
    "LED_PLACES",
    "PROP_LOOKS",
    "BodyShape",
    "DroneLook",
    "DroneStyle",
]

GIMBAL_PLACES = ("nose", "top", "none")
LED_PLACES = ("motor", "arm", "body")
PROP_LOOKS = ("disc", "blades", "stopped")
# Obstacle-sensor pods (a dark plate with two lenses) on the shell's end faces. Real drones carry
# them at the front, the rear, both or neither; drawn either way round they are no front/back cue.
END_SENSOR_PLACES = ("none", "front", "rear", "both")
# --leds of dronekey-sim: red at the front and green at the rear (the usual DJI convention), the
# other way round, none, or drawn at random like the training sampler does.
LED_MODES = ("red-front", "green-front", "off", "random")
# Lit LEDs blink in this share of the drones, at a rate drawn in BLINK_HZ (half the period on).
BLINK_PROB = 0.25
BLINK_HZ = (1.0, 2.0)

_RED, _GREEN = (0.15, 0.15, 1.0), (0.3, 1.0, 0.35)  # BGR


@dataclass(frozen=True)
class BodyShape:
    """The drone's shape around the fixed keypoints; lengths are fractions of the hub diagonal.

    ``None`` for a dimension means the spec's own (``DroneSpec.body``) or its wheelbase default.
    """

    length: float | None = None
    width: float | None = None
    height: float | None = None
    nose_taper: float = 1.0  # front-face size over the rear-face size of the shell (1: a box)
    nose_length: float = 0.0  # extra tapered nose ahead of the shell
    battery: float = 0.0  # battery bulge on the rear top, as a fraction of the body length (0: none)
    gimbal: str = "nose"
    gimbal_size: float = 1.0  # times the default (half the body height)
    arm_scale: float = 1.0
    rear_arm_drop: float = 0.0  # rear arms leave the body this fraction of its height lower (folding arms)
    guards: bool = False
    legs: bool = False
    stripe: str = "front"  # "front", "rear", "full" or "none"
    led_place: str = "motor"
    led_front: bool = True  # LEDs under the front rotors (place "motor"/"arm") or on the nose ("body")
    led_rear: bool = True
    end_sensors: str = "none"  # obstacle-sensor pods on the end faces: one of END_SENSOR_PLACES

    def __post_init__(self) -> None:
        if self.gimbal not in GIMBAL_PLACES:
            raise ValueError(f"gimbal must be one of {GIMBAL_PLACES}, got {self.gimbal!r}")
        if self.led_place not in LED_PLACES:
            raise ValueError(f"led_place must be one of {LED_PLACES}, got {self.led_place!r}")
        if self.stripe not in ("front", "rear", "full", "none"):
            raise ValueError(f"stripe must be front, rear, full or none, got {self.stripe!r}")
        if self.end_sensors not in END_SENSOR_PLACES:
            raise ValueError(f"end_sensors must be one of {END_SENSOR_PLACES}, got {self.end_sensors!r}")

    @classmethod
    def random(cls, rng: np.random.Generator, leds: bool = True) -> BodyShape:
        """A consumer-to-prosumer quadcopter; ``leds`` False gives a shape with no LED parts."""
        # Camera drones, the kind a counter-drone sensor meets, carry their camera at the front: it is
        # the one front cue real drones share, so most shapes have one (the rest must stay doubtful).
        gimbal = str(rng.choice(GIMBAL_PLACES, p=[0.75, 0.15, 0.1]))
        return cls(
            length=float(rng.uniform(0.45, 0.8)),
            width=float(rng.uniform(0.2, 0.38)),
            height=float(rng.uniform(0.14, 0.3)),
            nose_taper=float(rng.uniform(0.55, 1.0)) if rng.random() < 0.6 else 1.0,
            nose_length=float(rng.uniform(0.03, 0.12)) if rng.random() < 0.5 else 0.0,
            battery=float(rng.uniform(0.2, 0.4)) if rng.random() < 0.55 else 0.0,
            gimbal=gimbal,
            gimbal_size=float(rng.uniform(1.0, 1.8)),
            arm_scale=float(rng.uniform(0.6, 1.8)),
            rear_arm_drop=float(rng.uniform(0.2, 0.7)) if rng.random() < 0.4 else 0.0,
            guards=bool(rng.random() < 0.15),
            legs=bool(rng.random() < 0.3),
            stripe=str(rng.choice(["front", "rear", "full", "none"], p=[0.2, 0.2, 0.15, 0.45])),
            led_place=str(rng.choice(LED_PLACES, p=[0.4, 0.35, 0.25])),
            led_front=leds and bool(rng.random() < 0.9),
            led_rear=leds and bool(rng.random() < 0.9),
        )

    def shows_front(self, from_above: bool) -> bool:
        """Whether a viewer can tell this body's front from its back, from above the propeller plane
        (``from_above``) or from below it.

        The cues: a gimbal under the nose, a tapered shell or a nose cone, rear arms dropped lower
        (seen from anywhere); a battery bulge, a front or rear stripe, a gimbal on top (on the top
        shell: seen from above only). LEDs are no cue, since drones light them either way round. A
        body with none is front/back symmetric, and whoever reads its heading must say it cannot.
        """
        anywhere = self.gimbal == "nose" or self.nose_taper < 1.0 or self.nose_length > 0
        anywhere = anywhere or self.rear_arm_drop > 0
        on_top = self.battery > 0 or self.stripe in ("front", "rear") or self.gimbal == "top"
        return anywhere or (from_above and on_top)

    def without_front_cues(self) -> BodyShape:
        """This body with every front/back cue removed (``shows_front`` is False from anywhere):
        no gimbal, a box shell, no nose cone, no battery bulge, level arms, no half stripe. Size,
        arms, guards, legs, LEDs and end sensors stay."""
        return replace(
            self,
            gimbal="none",
            nose_taper=1.0,
            nose_length=0.0,
            battery=0.0,
            rear_arm_drop=0.0,
            stripe="none" if self.stripe in ("front", "rear") else self.stripe,
        )

    def with_random_end_sensors(self, rng: np.random.Generator, fraction: float) -> BodyShape:
        """This body with obstacle-sensor pods drawn from ``rng``: on ``fraction`` of bodies, at the
        front, the rear or both ends with equal chance (so a dark box at an end says nothing about
        which end it is); the others keep theirs. ``fraction`` 0 draws nothing from ``rng``, so
        every other stream of it stays as it was."""
        if fraction <= 0 or not rng.random() < fraction:
            return self
        return replace(self, end_sensors=str(rng.choice(END_SENSOR_PLACES[1:])))

    def key(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))


@dataclass(frozen=True)
class DroneStyle:
    """Colours and propeller look of one rendered drone (randomised per sequence or sample).

    ``front_led`` / ``rear_led`` are BGR colours, or None for an unlit (dark) LED housing.
    ``camo`` is a palette of BGR colours painted face by face over the body, or empty.
    ``gloss`` scales the light's specular highlight (0 matt, 1 the light's own, >1 glossy).
    """

    body: tuple[float, float, float] = (0.55, 0.56, 0.58)
    underside: tuple[float, float, float] = (0.18, 0.18, 0.2)
    arms: tuple[float, float, float] = (0.45, 0.46, 0.48)
    stripe: tuple[float, float, float] = (0.92, 0.92, 0.9)
    motor: tuple[float, float, float] = (0.12, 0.12, 0.13)
    prop: tuple[float, float, float] = (0.1, 0.1, 0.1)
    front_led: tuple[float, float, float] | None = _RED
    rear_led: tuple[float, float, float] | None = _GREEN
    prop_opacity: float = 0.35
    blade_opacity: float = 0.5
    blade_angle_deg: float = 0.0
    blade_smear_deg: float = 40.0
    gimbal: tuple[float, float, float] = (0.2, 0.2, 0.22)
    lens: tuple[float, float, float] = (0.05, 0.04, 0.04)
    gloss: float = 1.0
    camo: tuple[tuple[float, float, float], ...] = ()
    led_housing: tuple[float, float, float] = (0.12, 0.12, 0.13)

    def colour_of(self, role: str) -> np.ndarray:
        """BGR colour in [0, 1] of a part role (an unlit LED is its dark housing)."""
        value = getattr(self, role)
        if value is None:
            value = self.led_housing
        return np.asarray(value, dtype=np.float64)

    def with_leds(self, mode: str, rng: np.random.Generator | None = None) -> DroneStyle:
        """This style with the LEDs of ``mode`` (one of ``LED_MODES``)."""
        if mode not in LED_MODES:
            raise ValueError(f"leds must be one of {', '.join(LED_MODES)}, got {mode!r}")
        if mode == "red-front":
            return replace(self, front_led=_RED, rear_led=_GREEN)
        if mode == "green-front":
            return replace(self, front_led=_GREEN, rear_led=_RED)
        if mode == "off":
            return replace(self, front_led=None, rear_led=None)
        front, rear = _random_leds(rng if rng is not None else np.random.default_rng())
        return replace(self, front_led=front, rear_led=rear)

    @classmethod
    def random(cls, rng: np.random.Generator) -> DroneStyle:
        """Any livery from white to black (matt, glossy or camouflage), any LEDs, any propeller look."""
        family = int(rng.choice(5, p=[0.25, 0.22, 0.25, 0.13, 0.15]))
        if family == 4:  # coloured shell (red, yellow, orange, blue racing and survey drones)
            body = np.clip(rng.uniform(0.05, 0.95, 3), 0.03, 0.97)
        else:
            base = {0: 0.55, 1: 0.86, 2: 0.16, 3: 0.06}[family] + rng.uniform(-0.08, 0.08)
            body = np.clip(base + rng.normal(0, 0.02, 3), 0.02, 0.97)
        camo: tuple = ()
        if rng.random() < 0.12:
            greens = np.array([[0.2, 0.35, 0.3], [0.15, 0.25, 0.35], [0.35, 0.45, 0.5], [0.1, 0.12, 0.12]])
            camo = tuple(
                tuple(np.clip(c + rng.normal(0, 0.04, 3), 0, 1)) for c in greens[rng.permutation(4)[:3]]
            )
            body = np.asarray(camo[0])
        arms = (
            np.clip(body * rng.uniform(0.6, 1.05), 0, 1) if rng.random() < 0.7 else rng.uniform(0.03, 0.9, 3)
        )
        front, rear = _random_leds(rng)
        look = str(rng.choice(PROP_LOOKS, p=[0.55, 0.3, 0.15]))
        if look == "disc":
            prop_op, blade_op, smear = rng.uniform(0.1, 0.45), rng.uniform(0.1, 0.6), rng.uniform(60, 160)
        elif look == "blades":
            prop_op, blade_op, smear = rng.uniform(0.05, 0.25), rng.uniform(0.4, 0.8), rng.uniform(8, 40)
        else:
            prop_op, blade_op, smear = 0.0, rng.uniform(0.85, 1.0), rng.uniform(3, 8)
        # gimbals are mostly black or dark grey, whatever the shell
        gimbal_grey = rng.uniform(0.03, 0.25) if rng.random() < 0.75 else rng.uniform(0.05, 0.8)
        under = body * rng.uniform(0.3, 1.0) if rng.random() < 0.7 else rng.uniform(0.05, 0.5) * np.ones(3)
        return cls(
            body=tuple(body),
            underside=tuple(np.clip(under, 0, 1)),
            arms=tuple(arms),
            stripe=tuple(np.clip(rng.uniform(0, 1, 3) if rng.random() < 0.5 else 1.2 - body, 0.03, 1)),
            motor=tuple(np.full(3, rng.uniform(0.05, 0.6))),
            prop=tuple(np.full(3, rng.uniform(0.03, 0.7))),
            prop_opacity=float(prop_op),
            blade_opacity=float(blade_op),
            blade_angle_deg=float(rng.uniform(0, 360)),
            blade_smear_deg=float(smear),
            gimbal=tuple(np.full(3, gimbal_grey)),
            gloss=float(rng.choice([0.0, rng.uniform(0.2, 1.0), rng.uniform(1.5, 4.0)], p=[0.3, 0.45, 0.25])),
            camo=camo,
            front_led=front,
            rear_led=rear,
        )


def _random_leds(rng: np.random.Generator) -> tuple[tuple | None, tuple | None]:
    """Absent on 45 % of drones; otherwise red/green either way round, or any two colours."""
    if rng.random() < 0.45:
        return None, None
    r = rng.random()
    if r < 0.3:
        pair = (_RED, _GREEN)
    elif r < 0.6:
        pair = (_GREEN, _RED)
    else:
        palette = np.array([_RED, _GREEN, (1.0, 0.4, 0.1), (1.0, 1.0, 1.0), (0.2, 0.8, 1.0), (1.0, 0.2, 0.9)])
        pair = tuple(tuple(palette[i]) for i in rng.choice(len(palette), 2))
    jitter = [tuple(np.clip(np.asarray(c) + rng.normal(0, 0.05, 3), 0, 1)) for c in pair]
    if rng.random() < 0.15:  # one end only
        jitter[int(rng.integers(2))] = None
    return jitter[0], jitter[1]


@dataclass(frozen=True)
class DroneLook:
    """The drone of one sequence: its body, its livery and its LEDs' blinking.

    shape : the body around the fixed keypoints (``BodyShape``).
    style : colours, propeller look and LED colours when they are on (``DroneStyle``).
    blink_hz : blinking rate of lit LEDs, Hz, or None for steady LEDs (or none lit).
    blink_phase : where in its period the blinking starts at t = 0, as a fraction of the period.
    """

    shape: BodyShape
    style: DroneStyle
    blink_hz: float | None = None
    blink_phase: float = 0.0

    @classmethod
    def draw(cls, style_seed: int, leds: str = "random", cue_free: bool = False) -> DroneLook:
        """The look drawn from ``style_seed`` (a non-negative integer) with the LEDs of ``leds``;
        ``cue_free``: the same body with its front/back cues removed (``BodyShape.without_front_cues``).

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
            shape = replace(shape, led_front=True, led_rear=True)
            style = style.with_leds(leds)
        if cue_free:
            shape = shape.without_front_cues()
        look = cls(shape, style, hz if blinks else None, phase)
        return look if look.leds_lit else replace(look, blink_hz=None)

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
