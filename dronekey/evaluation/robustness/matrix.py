"""The matrix of ``dronekey-eval robustness``: its conditions, its scene seeds, one entry per sequence.

Drone sequences: the LED conditions ``LED_CONDITIONS`` (red front / green rear, green front / red
rear, unlit, the style's own) x the backgrounds ``BACKGROUNDS`` (procedural skies, the held-out
packaged photographs, procedural cities) x the paper's Tab. I motions ``MOTIONS`` (seq11, seq12,
seq13), ``DEFAULT_FRAMES`` frames each at 1920 x 1080, scripted attitudes. In a Latin square, one
motion of every (LED, background) cell is rendered ``FAR_RANGE_SCALE`` times as far (about 35-60 px
across instead of 90-150 px): the one with ``(led + background + motion) % 3 == 0`` (indices in the
lists), so each LED condition, background and motion holds far drones in a third of its sequences.

Drone-free sequences (``no_drone``: birds, flying objects, clouds, edge clutter):
``DRONE_FREE_SEQUENCES`` of the same length, cycling over the motions' scenes and the backgrounds.

Seeds: the i-th drone sequence of a seed set renders scene seed ``base + i``, the j-th drone-free
one ``base + DRONE_FREE_SEED_OFFSET + j``, with ``base`` = ``REPORTING_SEED`` (7001-7036 and
7501-7520 by default) or ``TUNING_SEED`` (6001-6036, 6501-6520); ``seed_sets.check_seeds`` keeps
the two apart and off ``VALIDATION_SEED``. Each sequence draws its drone from its own style seed,
scene seed + ``STYLE_SEED_OFFSET``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from dronekey.checks import int_at_least
from dronekey.sim_replay.drone_look import LED_MODES
from dronekey.sim_replay.presets import PRESETS
from dronekey.sim_replay.synthetic_sequence import BACKGROUND_KINDS, SyntheticSequence, build_sequence

__all__ = [
    "BACKGROUNDS",
    "DEFAULT_FRAMES",
    "DRONE_FREE_SEED_OFFSET",
    "DRONE_FREE_SEQUENCES",
    "FAR_RANGE_SCALE",
    "LED_CONDITIONS",
    "MOTIONS",
    "QUICK_BACKGROUNDS",
    "QUICK_DRONE_FREE",
    "QUICK_FRAMES",
    "REPORTING_SEED",
    "STYLE_SEED_OFFSET",
    "TUNING_SEED",
    "VALIDATION_SEED",
    "MatrixEntry",
    "plan_matrix",
]

LED_CONDITIONS = ("red-front", "green-front", "off", "random")
BACKGROUNDS = ("sky", "photos", "urban")
MOTIONS = ("seq11", "seq12", "seq13")
DEFAULT_FRAMES = 150
FAR_RANGE_SCALE = 2.5
DRONE_FREE_SEQUENCES = 20
# --quick: one background, short sequences, fewer drone-free ones (a smoke test, not a figure).
QUICK_FRAMES = 40
QUICK_BACKGROUNDS = ("sky",)
QUICK_DRONE_FREE = 5

REPORTING_SEED = 7001
TUNING_SEED = 6001
VALIDATION_SEED = 7919  # dronekey-train's validation crops (sampler seed)
DRONE_FREE_SEED_OFFSET = 500  # drone-free sequence j: base + 500 + j (so at most 500 drone sequences)
STYLE_SEED_OFFSET = 10_000  # style seed of a sequence: its scene seed + 10,000

_FAR_PERIOD = 3  # one motion in three of each (LED, background) cell is far


@dataclass(frozen=True)
class MatrixEntry:
    """One sequence of the matrix: what ``sim_replay.synthetic_sequence.build_sequence`` renders.

    preset : motion (``seq11``, ``seq12``, ``seq13``). seed : scene seed. style_seed : drone-look
    seed. leds : LED mode. background : background kind. range_scale : distance factor (1 near,
    ``FAR_RANGE_SCALE`` far). no_drone : a drone-free sequence. frames : frame count. width,
    height : image size, pixels. cue_free : the drone's body drawn without front/back cues.
    """

    preset: str
    seed: int
    style_seed: int
    leds: str
    background: str
    range_scale: float
    no_drone: bool
    frames: int
    width: int
    height: int
    cue_free: bool = False

    @property
    def far(self) -> bool:
        """Whether the drone is rendered farther than scripted."""
        return self.range_scale != 1.0

    @property
    def name(self) -> str:
        """Folder name of the sequence inside the size-and-length folder: seed and conditions."""
        if self.no_drone:
            return f"s{self.seed}-{self.preset}-nodrone-{self.background}"
        far = f"-far{self.range_scale:g}" if self.far else ""
        cue_free = "-cuefree" if self.cue_free else ""
        return f"s{self.seed}-{self.preset}-{self.leds}-{self.background}{far}{cue_free}"

    def folder(self, out_dir: str | Path) -> Path:
        """Where the sequence is written: ``out_dir/<W>x<H>-<frames>f/<name>/``."""
        return Path(out_dir) / f"{self.width}x{self.height}-{self.frames}f" / self.name

    def build(self) -> SyntheticSequence:
        """The ``SyntheticSequence`` to render (nothing is rendered yet)."""
        return build_sequence(
            self.preset,
            seed=self.seed,
            frames=self.frames,
            width=self.width,
            height=self.height,
            style_seed=self.style_seed,
            leds=self.leds,
            no_drone=self.no_drone,
            background=self.background,
            range_scale=self.range_scale,
            cue_free=self.cue_free,
        )

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "preset": self.preset,
            "seed": self.seed,
            "style_seed": self.style_seed,
            "leds": None if self.no_drone else self.leds,
            "background": self.background,
            "range_scale": self.range_scale,
            "far": self.far,
            "no_drone": self.no_drone,
            "cue_free": self.cue_free,
            "frames": self.frames,
            "size": [self.width, self.height],
        }


def _check_choices(name: str, values: Sequence[str], allowed: Iterable[str]) -> tuple[str, ...]:
    """``values`` as a tuple, checked: a non-empty list of distinct members of ``allowed``."""
    allowed = tuple(allowed)
    if isinstance(values, str) or not values:
        raise ValueError(f"{name} must be a non-empty list of {', '.join(allowed)}, got {values!r}")
    values = tuple(values)
    bad = [v for v in values if v not in allowed]
    if bad:
        raise ValueError(f"{name}: unknown {bad[0]!r}; choose from {', '.join(allowed)}")
    if len(set(values)) != len(values):
        raise ValueError(f"{name} must not repeat a value, got {values!r}")
    return values


def plan_matrix(
    base_seed: int = REPORTING_SEED,
    *,
    frames: int = DEFAULT_FRAMES,
    leds: Sequence[str] = LED_CONDITIONS,
    backgrounds: Sequence[str] = BACKGROUNDS,
    motions: Sequence[str] = MOTIONS,
    far_range_scale: float | None = FAR_RANGE_SCALE,
    drone_free: int = DRONE_FREE_SEQUENCES,
    width: int = 1920,
    height: int = 1080,
    cue_free: bool = False,
) -> list[MatrixEntry]:
    """The sequences of one seed set: drone sequences (LED x background x motion), then drone-free.

    Parameters
    ----------
    base_seed : scene seed of the first drone sequence (``REPORTING_SEED`` or ``TUNING_SEED``).
    frames : frames per sequence.
    leds, backgrounds, motions : the matrix's axes (LED modes, background kinds, presets).
    far_range_scale : distance factor of the far drones (the Latin square in the module's notes),
        or None for no far drone.
    drone_free : number of drone-free sequences (cycling over motions, then backgrounds).
    width, height : image size, pixels.
    cue_free : draw every drone of the drone sequences without front/back cues (same seeds, same
        liveries and LEDs, a symmetric body): the sequences whose heading no one can know. The
        drone-free sequences are the same either way.

    Raises
    ------
    ValueError
        Naming the argument and its value: an unknown LED mode, background or motion, a repeated
        one, an empty axis, non-positive sizes or counts, or more than ``DRONE_FREE_SEED_OFFSET``
        drone sequences.
    """
    leds = _check_choices("leds", leds, LED_MODES)
    backgrounds = _check_choices("backgrounds", backgrounds, BACKGROUND_KINDS)
    motions = _check_choices("motions", motions, PRESETS)
    frames = int_at_least("frames", frames)
    drone_free = int_at_least("drone_free", drone_free, minimum=0)
    width, height = int_at_least("width", width), int_at_least("height", height)
    base_seed = int_at_least("base_seed", base_seed, minimum=0)
    if far_range_scale is not None and not (
        isinstance(far_range_scale, int | float) and 0 < far_range_scale < math.inf and far_range_scale != 1
    ):
        raise ValueError(
            f"far_range_scale must be a positive number other than 1 or None, got {far_range_scale!r}"
        )
    n_drone = len(leds) * len(backgrounds) * len(motions)
    if n_drone > DRONE_FREE_SEED_OFFSET:
        raise ValueError(
            f"the matrix has {n_drone} drone sequences; at most {DRONE_FREE_SEED_OFFSET} fit a seed set"
        )
    entries = []
    for li, led in enumerate(leds):
        for bi, background in enumerate(backgrounds):
            for mi, motion in enumerate(motions):
                far = far_range_scale is not None and (li + bi + mi) % _FAR_PERIOD == 0
                seed = base_seed + len(entries)
                entries.append(
                    MatrixEntry(
                        motion,
                        seed,
                        seed + STYLE_SEED_OFFSET,
                        led,
                        background,
                        float(far_range_scale) if far else 1.0,
                        False,
                        frames,
                        width,
                        height,
                        bool(cue_free),
                    )
                )
    for j in range(drone_free):
        seed = base_seed + DRONE_FREE_SEED_OFFSET + j
        motion = motions[j % len(motions)]
        background = backgrounds[(j // len(motions)) % len(backgrounds)]
        entries.append(
            MatrixEntry(
                motion, seed, seed + STYLE_SEED_OFFSET, "random", background, 1.0, True, frames, width, height
            )
        )
    return entries
