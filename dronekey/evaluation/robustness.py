"""Robustness of the whole pipeline to the drone's look, the background and the range
(``dronekey-eval robustness``).

The keypoint network once learned the renderer's LEDs instead of the drone. This evaluation renders
a fixed matrix of conditions on scene seeds that training and tuning never used, runs the daemon's
``TrackingPipeline`` (unchanged) over every sequence and reports, per condition, how well the drone
is found and posed and how often the tracker publishes something that is not the drone.

The matrix (defaults; ``run_robustness``'s keywords change it):

- drone sequences: the LED conditions ``LED_CONDITIONS`` (red front / green rear, green front /
  red rear, unlit, the style's own) x the backgrounds ``BACKGROUNDS`` (procedural skies, the
  held-out packaged photographs, procedural cities) x the paper's Tab. I motions ``MOTIONS``
  (seq11, seq12, seq13), ``DEFAULT_FRAMES`` frames each at 1920 x 1080, scripted attitudes. In a
  Latin square, one motion of every (LED, background) cell is rendered ``FAR_RANGE_SCALE`` times as
  far (about 35-60 px across instead of 90-150 px): the one with ``(led + background + motion) % 3
  == 0`` (indices in the lists), so each LED condition, background and motion holds far drones in
  a third of its sequences;
- drone-free sequences (``no_drone``: birds, flying objects, clouds, edge clutter):
  ``DRONE_FREE_SEQUENCES`` of the same length, cycling over the motions' scenes and the
  backgrounds.

Seeds. Training draws crops from the sampler's own streams (``CropSampler`` seeds 0, 1, ... of
``dronekey-train``) and validates on sampler seed 7919; no rendered sequence of the presets is
trained on. The reporting set uses scene seeds ``REPORTING_SEED + i`` for the i-th drone sequence
and ``REPORTING_SEED + DRONE_FREE_SEED_OFFSET + j`` for the j-th drone-free one (7001-7036 and
7501-7520 by default); the tuning set, for choosing thresholds and settings, the same offsets from
``TUNING_SEED`` (6001-6036, 6501-6520). The two sets are kept apart (``check_seeds``) and neither
may hold the validation seed. Each sequence draws its drone from its own style seed, scene seed +
``STYLE_SEED_OFFSET``.

Metrics, per sequence and pooled over the frames of a group (a frame-weighted average):

- the drone's track in a frame: the best published (confirmed or coasting) track within
  ``max(MATCH_GATE_M, MATCH_GATE_FRACTION * range)`` of the true position (camera frame, metres;
  the range is the true distance from the camera), ranked as ``dronekey-eval pose`` ranks its
  estimate (confirmed before coasting, most hits, oldest id);
- detected %: annotated frames with a drone's track, percent of the annotated frames;
- MAE-angle (deg), RMSE (m), MAE-absolute (m): the paper's errors (``eval_pose.pose_errors``)
  of the drone's track over the detected frames;
- AP^kp (percent): COCO keypoint AP of the pipeline's best detection of every annotated frame (its
  presence as the score; a frame without detection is a miss) against the annotated keypoints,
  as ``dronekey-eval pose`` computes it (full-frame pixels, OKS area = annotated box area);
- false-track frames: scored frames holding a published track that is not the drone's (farther
  than the gate from the truth; in a drone-free frame, any published track), also per 1,000
  scored frames, and the number of distinct track ids that were ever such a track;
- confident wrong heading %: annotated frames whose drone's track is more than
  ``WRONG_HEADING_DEG`` from the true attitude (geodesic angle of R_track^T R_true, so a
  front/back flip counts) while its ``heading_confidence`` >= ``CONFIDENT_HEADING``, percent of the
  annotated frames. A model without a front/back head gives NaN confidences, which never count;
  ``wrong_heading_pct`` is the same share at any confidence.

Frames of a drone sequence without an annotation (the drone out of view) are not scored. Rendered
sequences are kept in ``out_dir`` and reused on a rerun when their JSON ``info``, frame count and
image size match what the matrix asks for.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dronekey.evaluation.metrics import ap_kp
from dronekey.evaluation.pose import pose_errors, published_track_rank, rounded, sequence_spec
from dronekey.geometry.rotations import geodesic_angle_deg, quat_wxyz_to_matrix
from dronekey.types import PUBLISHED_STATUSES

__all__ = [
    "BACKGROUNDS",
    "CONFIDENT_HEADING",
    "DEFAULT_FRAMES",
    "DRONE_FREE_SEED_OFFSET",
    "DRONE_FREE_SEQUENCES",
    "FAR_RANGE_SCALE",
    "LED_CONDITIONS",
    "MATCH_GATE_FRACTION",
    "MATCH_GATE_M",
    "MOTIONS",
    "QUICK_BACKGROUNDS",
    "QUICK_DRONE_FREE",
    "QUICK_FRAMES",
    "REPORTING_SEED",
    "STYLE_SEED_OFFSET",
    "TUNING_SEED",
    "VALIDATION_SEED",
    "WRONG_HEADING_DEG",
    "MatrixEntry",
    "RobustnessReport",
    "SequenceScores",
    "check_seeds",
    "match_gate_m",
    "plan_matrix",
    "render_matrix",
    "run_robustness",
    "score_sequence",
    "summarise",
]

log = logging.getLogger(__name__)

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

MATCH_GATE_M = 0.5
MATCH_GATE_FRACTION = 0.25
WRONG_HEADING_DEG = 90.0
CONFIDENT_HEADING = 0.5
_FAR_PERIOD = 3  # one motion in three of each (LED, background) cell is far


def match_gate_m(t_true: np.ndarray) -> float:
    """Largest distance (m) between a track's position and the true one for the track to be the drone.

    Parameters
    ----------
    t_true : (3,) true position of the drone in the camera frame, metres.

    Returns
    -------
    ``max(MATCH_GATE_M, MATCH_GATE_FRACTION * ||t_true||)``, metres.
    """
    return max(MATCH_GATE_M, MATCH_GATE_FRACTION * float(np.linalg.norm(t_true)))


# ----------------------------------------------------------------------------- the matrix
@dataclass(frozen=True)
class MatrixEntry:
    """One sequence of the matrix: what ``sim_replay.synthetic_sequence.build_sequence`` renders.

    preset : motion (``seq11``, ``seq12``, ``seq13``). seed : scene seed. style_seed : drone-look
    seed. leds : LED mode. background : background kind. range_scale : distance factor (1 near,
    ``FAR_RANGE_SCALE`` far). no_drone : a drone-free sequence. frames : frame count. width,
    height : image size, pixels.
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
        return f"s{self.seed}-{self.preset}-{self.leds}-{self.background}{far}"

    def folder(self, out_dir: str | Path) -> Path:
        """Where the sequence is written: ``out_dir/<W>x<H>-<frames>f/<name>/``."""
        return Path(out_dir) / f"{self.width}x{self.height}-{self.frames}f" / self.name

    def build(self):
        """The ``SyntheticSequence`` to render (nothing is rendered yet)."""
        from dronekey.sim_replay.synthetic_sequence import build_sequence

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


def _int_at_least(name: str, value, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


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

    Raises
    ------
    ValueError
        Naming the argument and its value: an unknown LED mode, background or motion, a repeated
        one, an empty axis, non-positive sizes or counts, or more than ``DRONE_FREE_SEED_OFFSET``
        drone sequences.
    """
    from dronekey.sim_replay.drone_look import LED_MODES
    from dronekey.sim_replay.presets import PRESETS
    from dronekey.sim_replay.synthetic_sequence import BACKGROUND_KINDS

    leds = _check_choices("leds", leds, LED_MODES)
    backgrounds = _check_choices("backgrounds", backgrounds, BACKGROUND_KINDS)
    motions = _check_choices("motions", motions, PRESETS)
    frames = _int_at_least("frames", frames)
    drone_free = _int_at_least("drone_free", drone_free, minimum=0)
    width, height = _int_at_least("width", width), _int_at_least("height", height)
    base_seed = _int_at_least("base_seed", base_seed, minimum=0)
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


def _seed_ranges(seeds: Iterable[int]) -> str:
    """``7001-7036, 7501-7520`` for a set of integers."""
    ordered = sorted(set(seeds))
    runs: list[list[int]] = []
    for s in ordered:
        if runs and s == runs[-1][1] + 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs)


def check_seeds(bases: Sequence[int], *, tuning: bool, **matrix) -> dict[int, list[MatrixEntry]]:
    """The matrix of every base seed, after checking that the seed sets are kept apart.

    Parameters
    ----------
    bases : base scene seeds, one matrix each.
    tuning : whether ``bases`` are tuning seeds (else reporting seeds).
    **matrix : ``plan_matrix``'s keywords.

    Returns
    -------
    ``{base: plan_matrix(base, **matrix)}`` in the order of ``bases``.

    Raises
    ------
    ValueError
        A repeated base, two bases whose seeds overlap, a seed of the other set (the default
        tuning set for reporting seeds and the other way round) or the validation seed
        ``VALIDATION_SEED``; the message names the seeds.
    """
    bases = [_int_at_least("seeds", b, minimum=0) for b in bases]
    if not bases:
        raise ValueError("seeds must name at least one base seed, got []")
    if len(set(bases)) != len(bases):
        raise ValueError(f"seeds must not repeat a base seed, got {bases}")
    plans = {b: plan_matrix(b, **matrix) for b in bases}
    used: dict[int, int] = {}
    for base, entries in plans.items():
        for e in entries:
            if e.seed in used:
                raise ValueError(
                    f"seeds {used[e.seed]} and {base} overlap (both render scene seed {e.seed}); "
                    f"space them at least {DRONE_FREE_SEED_OFFSET + sum(x.no_drone for x in entries)} apart"
                )
            used[e.seed] = base
    if VALIDATION_SEED in used:
        raise ValueError(
            f"seeds {used[VALIDATION_SEED]} would render scene seed {VALIDATION_SEED}, the training "
            "validation seed; pick another base"
        )
    other_name, other_base = ("reporting", REPORTING_SEED) if tuning else ("tuning", TUNING_SEED)
    other = {e.seed for e in plan_matrix(other_base, **matrix)}
    clash = sorted(other & set(used))
    if clash:
        this = "tuning" if tuning else "reporting"
        raise ValueError(
            f"{this} seeds {', '.join(str(b) for b in bases)} overlap the {other_name} seeds "
            f"({_seed_ranges(other)}) at {_seed_ranges(clash)}; keep tuning and reporting seeds apart"
        )
    return plans


# ----------------------------------------------------------------------------- rendering
@dataclass(frozen=True)
class Rendered:
    """A matrix entry on disk: its JSON, whether an earlier run's render was reused, render time (s)."""

    entry: MatrixEntry
    json_path: Path
    reused: bool
    render_s: float


def _matches(json_path: Path, entry: MatrixEntry, expected_info: dict) -> bool:
    """Whether ``json_path`` (and its media) is the sequence ``entry`` asks for."""
    from dronekey.sim_replay.io.frames import resolve_source
    from dronekey.sim_replay.io.sequence_reader import load_sequence

    if not json_path.is_file():
        return False
    try:
        seq = load_sequence(json_path)
        resolve_source(seq)
    except (ValueError, OSError, RuntimeError) as exc:  # SequenceFormatError, FrameSourceError
        log.info("%s is not reusable (%s); rendering it again", json_path, exc)
        return False
    size = (entry.width, entry.height)
    if seq.info != expected_info or len(seq.frames) != entry.frames or seq.camera.size != size:
        log.info("%s was rendered with other settings; rendering it again", json_path)
        return False
    return True


def render_matrix(
    entries: Sequence[MatrixEntry], out_dir: str | Path, *, progress: bool = False
) -> list[Rendered]:
    """Render every entry into ``entry.folder(out_dir)``, reusing the ones already there.

    Parameters
    ----------
    entries : the matrix (``plan_matrix``).
    out_dir : root folder (created if missing).
    progress : show a tqdm bar (frames rendered) on stderr.

    Returns
    -------
    One ``Rendered`` per entry, in order.

    Raises
    ------
    ImportError
        ``background="photos"`` without scikit-image and scikit-learn (before anything is rendered).
    OSError
        A file cannot be written.
    """
    from tqdm import tqdm

    from dronekey.sim_replay.io.render_output import write_sequence

    built = [(e, e.build()) for e in entries]  # every entry checked before the first render
    todo = []
    out: dict[int, Rendered] = {}
    for i, (entry, seq) in enumerate(built):
        json_path = entry.folder(out_dir) / f"{seq.name}.json"
        if _matches(json_path, entry, seq.info):
            out[i] = Rendered(entry, json_path, True, 0.0)
        else:
            todo.append((i, entry, seq))
    log.info("%d of %d sequences reused, %d to render", len(out), len(entries), len(todo))
    with tqdm(
        total=sum(e.frames for _, e, _ in todo),
        desc="render",
        unit="frame",
        disable=not progress or not todo,
        file=sys.stderr,
    ) as bar:
        for i, entry, seq in todo:
            folder = entry.folder(out_dir)
            folder.mkdir(parents=True, exist_ok=True)
            bar.set_postfix_str(entry.name)
            written = write_sequence(seq, folder, on_frame=bar.update)
            log.info("rendered %s: %d frames in %.1f s", entry.name, written.n_frames, written.seconds)
            out[i] = Rendered(entry, written.json_path, False, written.seconds)
    return [out[i] for i in range(len(entries))]


# ----------------------------------------------------------------------------- scoring
def _stack(rows: list, shape: tuple[int, ...], dtype=np.float64) -> np.ndarray:
    return np.asarray(rows, dtype=dtype).reshape(len(rows), *shape)


@dataclass
class SequenceScores:
    """Per-frame outcome of one sequence (scored frames only, in frame order).

    no_drone : a drone-free sequence: only ``false_frame`` is filled, the other arrays are empty.
    false_frame : (N,) a published track that is not the drone's in the frame.
    false_ids : distinct track ids that were such a track in at least one frame.
    detected : (N,) the frame has a drone's track (see the module's notes).
    R_track, t_track : (N, 3, 3), (N, 3) the drone's track (body -> camera, camera-frame metres);
        NaN where not detected. R_true, t_true : the ground truth.
    wrong_heading : (N,) the drone's track is more than ``WRONG_HEADING_DEG`` off (geodesic angle).
    confident_wrong_heading : (N,) ``wrong_heading`` while the track's ``heading_confidence`` >=
        ``CONFIDENT_HEADING``.
    kp_pred, kp_true : (N, 4, 2) the pipeline's best detection and the annotated keypoints, pixels.
    area : (N,) annotated box area, pixels^2. score : (N,) presence of the detection (0 without).
    has_pred : (N,) a detection exists.
    fps : frames per second of the pipeline alone (all frames of the sequence).
    """

    no_drone: bool
    false_frame: np.ndarray
    false_ids: int
    detected: np.ndarray
    R_track: np.ndarray
    t_track: np.ndarray
    R_true: np.ndarray
    t_true: np.ndarray
    wrong_heading: np.ndarray
    confident_wrong_heading: np.ndarray
    kp_pred: np.ndarray
    kp_true: np.ndarray
    area: np.ndarray
    score: np.ndarray
    has_pred: np.ndarray
    fps: float = float("nan")

    @property
    def frames(self) -> int:
        """Scored frames: every frame of a drone-free sequence, the annotated ones otherwise."""
        return int(self.false_frame.size)


def score_sequence(
    seq,
    model_path: str | Path | None = None,
    *,
    mirror_average: bool = True,
    on_frame: Callable[[], object] | None = None,
) -> SequenceScores:
    """Run a fresh ``TrackingPipeline`` over a loaded sequence and score every frame.

    Parameters
    ----------
    seq : ``SequenceAnnotations`` (``sim_replay.io.sequence_reader.load_sequence``); ``info.no_drone``
        marks a drone-free sequence.
    model_path : ONNX keypoint model; the shipped one by default.
    mirror_average : passed to the pipeline (the daemon's default).
    on_frame : called after each frame (a progress bar's ``update``).

    Returns
    -------
    SequenceScores
    """
    from dronekey.pipeline import TrackingPipeline
    from dronekey.sim_replay.io.frames import iter_frames

    no_drone = bool(seq.info.get("no_drone", False))
    pipeline = TrackingPipeline(
        seq.camera, model_path, drone=sequence_spec(seq), mirror_average=mirror_average
    )
    rows: dict[str, list] = {
        k: []
        for k in (
            "false",
            "detected",
            "R_track",
            "t_track",
            "R_true",
            "t_true",
            "wrong",
            "confident_wrong",
            "kp_pred",
            "kp_true",
            "area",
            "score",
            "has_pred",
        )
    }
    false_ids: set[int] = set()
    proc_s, n = 0.0, 0
    for sf in iter_frames(seq):
        t0 = time.perf_counter()
        out = pipeline.process(sf.frame)
        proc_s += time.perf_counter() - t0
        n += 1
        if on_frame is not None:
            on_frame()
        published = [tr for tr in out.tracks if tr.status in PUBLISHED_STATUSES]
        ann = sf.record.drone
        if no_drone:
            rows["false"].append(bool(published))
            false_ids.update(tr.track_id for tr in published)
            continue
        if ann is None or not ann.has_pose:
            continue
        gate = match_gate_m(ann.translation)
        is_drone = [float(np.linalg.norm(tr.position_m - ann.translation)) <= gate for tr in published]
        false_ids.update(tr.track_id for tr, ok in zip(published, is_drone, strict=True) if not ok)
        mine = [tr for tr, ok in zip(published, is_drone, strict=True) if ok]
        best = min(mine, key=published_track_rank) if mine else None
        rows["false"].append(not all(is_drone))
        rows["detected"].append(best is not None)
        rows["R_true"].append(ann.rotation)
        rows["t_true"].append(ann.translation)
        if best is not None:
            R = quat_wxyz_to_matrix(best.quaternion_wxyz)
            off = geodesic_angle_deg(R, ann.rotation) > WRONG_HEADING_DEG
            rows["wrong"].append(off)
            rows["confident_wrong"].append(off and bool(best.heading_confidence >= CONFIDENT_HEADING))
            rows["R_track"].append(R)
            rows["t_track"].append(best.position_m)
        else:
            rows["wrong"].append(False)
            rows["confident_wrong"].append(False)
            rows["R_track"].append(np.full((3, 3), np.nan))
            rows["t_track"].append(np.full(3, np.nan))
        det = out.detection
        rows["kp_true"].append(ann.keypoints_px)
        rows["area"].append(ann.area)
        rows["has_pred"].append(det is not None)
        rows["kp_pred"].append(det.keypoints_px if det is not None else np.zeros((4, 2)))
        rows["score"].append(det.presence if det is not None else 0.0)
    return SequenceScores(
        no_drone=no_drone,
        false_frame=_stack(rows["false"], (), bool),
        false_ids=len(false_ids),
        detected=_stack(rows["detected"], (), bool),
        R_track=_stack(rows["R_track"], (3, 3)),
        t_track=_stack(rows["t_track"], (3,)),
        R_true=_stack(rows["R_true"], (3, 3)),
        t_true=_stack(rows["t_true"], (3,)),
        wrong_heading=_stack(rows["wrong"], (), bool),
        confident_wrong_heading=_stack(rows["confident_wrong"], (), bool),
        kp_pred=_stack(rows["kp_pred"], (4, 2)),
        kp_true=_stack(rows["kp_true"], (4, 2)),
        area=_stack(rows["area"], ()),
        score=_stack(rows["score"], ()),
        has_pred=_stack(rows["has_pred"], (), bool),
        fps=n / proc_s if proc_s > 0 else float("nan"),
    )


def _pct(count: int, total: int) -> float:
    return 100.0 * count / total if total else float("nan")


def summarise(scores: Sequence[SequenceScores]) -> dict:
    """The metrics of the module's notes over the pooled frames of ``scores``.

    Returns
    -------
    dict with ``sequences``, ``frames`` (scored), ``detected_frames``, ``detected_pct``,
    ``mae_angle_deg``, ``rmse_m``, ``mae_abs_m``, ``ap_kp`` (percent), ``false_track_frames``,
    ``false_tracks_per_1000_frames``, ``false_track_ids``, ``confident_wrong_heading_frames``,
    ``confident_wrong_heading_pct``, ``wrong_heading_frames`` and ``wrong_heading_pct`` (any
    confidence); figures that need a drone sequence are None without one, and a figure
    with no frame to average is None.
    """
    frames = sum(s.frames for s in scores)
    false_frames = sum(int(s.false_frame.sum()) for s in scores)
    drone = [s for s in scores if not s.no_drone]
    n_ann = sum(s.frames for s in drone)
    out = {
        "sequences": len(scores),
        "frames": frames,
        "detected_frames": None,
        "detected_pct": None,
        "mae_angle_deg": None,
        "rmse_m": None,
        "mae_abs_m": None,
        "ap_kp": None,
        "false_track_frames": false_frames,
        "false_tracks_per_1000_frames": rounded(
            1000.0 * false_frames / frames if frames else float("nan"), 2
        ),
        "false_track_ids": sum(s.false_ids for s in scores),
        "confident_wrong_heading_frames": None,
        "confident_wrong_heading_pct": None,
        "wrong_heading_frames": None,
        "wrong_heading_pct": None,
    }
    if not n_ann:
        return out

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(s, name) for s in drone])

    hit = cat("detected")
    errors = pose_errors(cat("R_track")[hit], cat("t_track")[hit], cat("R_true")[hit], cat("t_true")[hit])
    ap = ap_kp(cat("kp_pred"), cat("kp_true"), cat("area"), cat("score"), has_pred=cat("has_pred"))
    wrong = int(cat("wrong_heading").sum())
    confident_wrong = int(cat("confident_wrong_heading").sum())
    out.update(
        detected_frames=int(hit.sum()),
        detected_pct=rounded(_pct(int(hit.sum()), n_ann), 2),
        mae_angle_deg=rounded(errors.mae_angle_deg),
        rmse_m=rounded(errors.rmse_m),
        mae_abs_m=rounded(errors.mae_abs_m),
        ap_kp=rounded(100.0 * ap, 2),
        confident_wrong_heading_frames=confident_wrong,
        confident_wrong_heading_pct=rounded(_pct(confident_wrong, n_ann), 2),
        wrong_heading_frames=wrong,
        wrong_heading_pct=rounded(_pct(wrong, n_ann), 2),
    )
    return out


# ----------------------------------------------------------------------------- the report
@dataclass(frozen=True)
class EvaluatedSequence:
    """One sequence of the matrix, rendered and scored."""

    rendered: Rendered
    scores: SequenceScores

    def to_dict(self) -> dict:
        return {
            **self.rendered.entry.to_dict(),
            "json": str(self.rendered.json_path),
            "reused": self.rendered.reused,
            "render_s": round(self.rendered.render_s, 2),
            "fps": rounded(self.scores.fps, 1),
            **summarise([self.scores]),
        }


# Table columns: (header, unit, key in summarise's dict, format).
_COLUMNS = (
    ("seqs", "", "sequences", "{:d}"),
    ("frames", "", "frames", "{:d}"),
    ("MAE-ang", "deg", "mae_angle_deg", "{:.2f}"),
    ("RMSE", "m", "rmse_m", "{:.3f}"),
    ("MAE-abs", "m", "mae_abs_m", "{:.3f}"),
    ("detected", "%", "detected_pct", "{:.1f}"),
    ("AP^kp", "%", "ap_kp", "{:.1f}"),
    ("false", "/1k fr", "false_tracks_per_1000_frames", "{:.1f}"),
    ("false", "ids", "false_track_ids", "{:d}"),
    ("conf>90", "%", "confident_wrong_heading_pct", "{:.2f}"),
    ("any>90", "%", "wrong_heading_pct", "{:.2f}"),
)


@dataclass
class RobustnessReport:
    """Everything ``dronekey-eval robustness`` reports: its settings and every sequence."""

    settings: dict
    sequences: list[EvaluatedSequence] = field(default_factory=list)

    def groups(self) -> list[tuple[str, str, list[EvaluatedSequence]]]:
        """``(by, value, sequences)`` of every row of the table, in order: per LED condition, per
        background, per motion, per range (near, far), all drone sequences, drone-free."""
        drone = [s for s in self.sequences if not s.rendered.entry.no_drone]
        free = [s for s in self.sequences if s.rendered.entry.no_drone]
        rows = []
        for by, attr, values in (
            ("leds", "leds", self.settings["leds"]),
            ("background", "background", self.settings["backgrounds"]),
            ("motion", "preset", self.settings["motions"]),
        ):
            rows += [(by, v, [s for s in drone if getattr(s.rendered.entry, attr) == v]) for v in values]
        near = [s for s in drone if not s.rendered.entry.far]
        far = [s for s in drone if s.rendered.entry.far]
        rows.append(("range", "near", near))
        if far:
            rows.append(("range", f"far x{self.settings['far_range_scale']:g}", far))
        rows.append(("all", "drone sequences", drone))
        if free:
            rows.append(("drone-free", "drone-free", free))
        return [r for r in rows if r[2]]

    def to_dict(self) -> dict:
        """The settings, every table row (``groups``) and every sequence, JSON-ready."""
        return {
            "settings": self.settings,
            "groups": [
                {"by": by, "value": value, **summarise([s.scores for s in seqs])}
                for by, value, seqs in self.groups()
            ],
            "sequences": [s.to_dict() for s in self.sequences],
        }

    def table(self) -> str:
        """One text table: a row per group (``groups``), a blank line between kinds of group."""
        st = self.settings
        label_w = 24
        widths = [max(len(h), len(u), 6) for h, u, _, _ in _COLUMNS]
        head = f"{'group':<{label_w}}" + "".join(
            f" {h:>{w}}" for (h, _, _, _), w in zip(_COLUMNS, widths, strict=True)
        )
        units = f"{'':<{label_w}}" + "".join(
            f" {u:>{w}}" for (_, u, _, _), w in zip(_COLUMNS, widths, strict=True)
        )
        lines = [
            f"robustness: {st['seed_set']} seeds {', '.join(map(str, st['seeds']))} "
            f"(scene seeds {st['scene_seeds']}), {st['frames']} frames per sequence at "
            f"{st['size'][0]}x{st['size'][1]}, model {Path(st['model']).name}",
            head,
            units,
            "-" * len(head),
        ]
        if not st.get("model_has_heading_head", True):
            lines.insert(
                1, "(the model has no front/back head: heading_confidence is NaN, conf>90 is 0 by definition)"
            )
        previous = None
        for by, value, seqs in self.groups():
            if previous is not None and by != previous:
                lines.append("")
            previous = by
            summary = summarise([s.scores for s in seqs])
            label = value if by in ("all", "drone-free") else f"{by} {value}"
            cells = []
            for (_, _, key, fmt), w in zip(_COLUMNS, widths, strict=True):
                v = summary[key]
                cells.append(f" {'-' if v is None else fmt.format(v):>{w}}")
            lines.append(f"{label:<{label_w}}" + "".join(cells))
        return "\n".join(lines)


def run_robustness(
    out_dir: str | Path,
    *,
    frames: int = DEFAULT_FRAMES,
    seeds: Sequence[int] | None = None,
    tuning: bool = False,
    model_path: str | Path | None = None,
    leds: Sequence[str] = LED_CONDITIONS,
    backgrounds: Sequence[str] = BACKGROUNDS,
    motions: Sequence[str] = MOTIONS,
    far_range_scale: float | None = FAR_RANGE_SCALE,
    drone_free: int = DRONE_FREE_SEQUENCES,
    width: int = 1920,
    height: int = 1080,
    mirror_average: bool = True,
    progress: bool = False,
) -> RobustnessReport:
    """Render the matrix (reusing what ``out_dir`` holds), run the pipeline and score it.

    Parameters
    ----------
    out_dir : folder for the rendered sequences (created if missing).
    frames : frames per sequence.
    seeds : base scene seeds, one matrix each; default ``[TUNING_SEED]`` with ``tuning``, else
        ``[REPORTING_SEED]``.
    tuning : the seeds are the tuning set (kept apart from the reporting set, ``check_seeds``).
    model_path : ONNX keypoint model; the shipped one by default.
    leds, backgrounds, motions, far_range_scale, drone_free, width, height : the matrix
        (``plan_matrix``).
    mirror_average : passed to the pipeline (the daemon's default).
    progress : tqdm bars on stderr while rendering and evaluating.

    Returns
    -------
    RobustnessReport

    Raises
    ------
    ValueError
        A bad argument (named with its value, see ``plan_matrix`` and ``check_seeds``), a model
        without DroneKey metadata, or ``out_dir`` that is a file.
    FileNotFoundError
        The model file is missing.
    ImportError
        ``backgrounds`` holds ``"photos"`` and neither scikit-image nor scikit-learn is installed.
    """
    from tqdm import tqdm

    from dronekey.perception.keypoint_model import KeypointModel
    from dronekey.sim_replay.io.sequence_reader import load_sequence

    bases = [TUNING_SEED if tuning else REPORTING_SEED] if seeds is None else list(seeds)
    matrix = {
        "frames": frames,
        "leds": leds,
        "backgrounds": backgrounds,
        "motions": motions,
        "far_range_scale": far_range_scale,
        "drone_free": drone_free,
        "width": width,
        "height": height,
    }
    plans = check_seeds(bases, tuning=tuning, **matrix)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out_dir must be a folder, got the file {str(out_dir)!r}")
    model = KeypointModel(model_path)  # a bad model fails now, not after the renders
    entries = [e for plan in plans.values() for e in plan]
    settings = {
        "seed_set": "tuning" if tuning else "reporting",
        "seeds": bases,
        "scene_seeds": _seed_ranges(e.seed for e in entries),
        "frames": int(frames),
        "size": [int(width), int(height)],
        "leds": list(leds),
        "backgrounds": list(backgrounds),
        "motions": list(motions),
        "far_range_scale": far_range_scale,
        "drone_free_sequences": int(drone_free),
        "model": str(model.path),
        "model_has_heading_head": bool(model.has_heading),
        "mirror_average": bool(mirror_average),
        "match_gate": {"min_m": MATCH_GATE_M, "range_fraction": MATCH_GATE_FRACTION},
        "wrong_heading_deg": WRONG_HEADING_DEG,
        "confident_heading": CONFIDENT_HEADING,
        "out_dir": str(out_dir),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rendered = render_matrix(entries, out_dir, progress=progress)
    t1 = time.perf_counter()
    report = RobustnessReport(settings)
    with tqdm(
        total=sum(e.frames for e in entries),
        desc="evaluate",
        unit="frame",
        disable=not progress,
        file=sys.stderr,
    ) as bar:
        for r in rendered:
            bar.set_postfix_str(r.entry.name)
            scores = score_sequence(
                load_sequence(r.json_path),
                settings["model"],
                mirror_average=mirror_average,
                on_frame=bar.update,
            )
            report.sequences.append(EvaluatedSequence(r, scores))
    settings["render_s"] = round(t1 - t0, 1)
    settings["evaluate_s"] = round(time.perf_counter() - t1, 1)
    settings["reused_sequences"] = sum(r.reused for r in rendered)
    return report
