"""``run_robustness``: render the matrix, run the pipeline over every sequence, score and report it.

What the matrix holds and how its seeds are chosen: ``matrix`` and ``seed_sets``; how a frame is
scored: ``scoring``; the pooled figures: ``summary``; the table and JSON: ``report``.
"""

from __future__ import annotations

import fnmatch
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from dronekey.evaluation.config_overrides import pipeline_changes
from dronekey.evaluation.robustness.dither import FrameDither
from dronekey.evaluation.robustness.matrix import (
    BACKGROUNDS,
    DEFAULT_FRAMES,
    DRONE_FREE_SEQUENCES,
    FAR_RANGE_SCALE,
    LED_CONDITIONS,
    MOTIONS,
    REPORTING_SEED,
    TUNING_SEED,
)
from dronekey.evaluation.robustness.render import render_matrix
from dronekey.evaluation.robustness.report import EvaluatedSequence, RobustnessReport
from dronekey.evaluation.robustness.scoring import (
    CONFIDENT_HEADING,
    MATCH_GATE_FRACTION,
    MATCH_GATE_M,
    WRONG_HEADING_DEG,
    score_sequence,
)
from dronekey.evaluation.robustness.seed_sets import check_seeds, seed_ranges
from dronekey.perception.drone_verifier import load_verifier
from dronekey.perception.heading_model import load_heading_model
from dronekey.perception.keypoint_model import KeypointModel
from dronekey.perception.localizer import LocalizerConfig
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.tracking.tracker_config import TrackerConfig

__all__ = ["run_robustness"]


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
    front_back: bool | str | Path = True,
    verifier: bool | str | Path = True,
    progress: bool = False,
    select: Sequence[str] | None = None,
    dither: int | None = None,
    cue_free: bool = False,
    localizer: LocalizerConfig | None = None,
    tracker: TrackerConfig | None = None,
    measure_every: int = 1,
    oracle_noise_px: float | None = None,
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
    leds, backgrounds, motions, far_range_scale, drone_free, width, height, cue_free : the matrix
        (``plan_matrix``; ``cue_free``: every drone front/back symmetric).
    mirror_average : passed to the pipeline (the daemon's default).
    front_back, verifier : the pipeline's front/back classifier and drone verifier: True the
        shipped ones, a path another, False none.
    progress : tqdm bars on stderr while rendering and evaluating.
    select : glob patterns on the sequence names (``s6501-seq11-nodrone-sky``, ...); only the
        sequences matching one of them are rendered and scored, each with the seeds it has in the
        whole matrix (e.g. ``["*nodrone*"]``: the drone-free part alone). None: every sequence.
    dither : a seed: every frame gets a grey level of seeded noise before the pipeline
        (``dronekey.evaluation.robustness.dither``); the figures' change against a run without
        says how far they move on noise alone. None: the frames as decoded.
    localizer, tracker : the pipeline's configs, for a setting measured before it is shipped (the
        report's settings name the two that are off as shipped: ``acquire_recut``,
        ``confirm_max_outliers``); None: the defaults, as shipped.
    oracle_noise_px : None (the pipeline), or the network replaced by every drone's true keypoints
        with this much Gaussian noise (px; ``dronekey.evaluation.oracle``, seeded by each
        sequence's scene seed): the RMSE and MAE-angle the pose stage alone reaches at that
        precision.

    Returns
    -------
    RobustnessReport

    Raises
    ------
    ValueError
        A bad argument (named with its value, see ``plan_matrix`` and ``check_seeds``), ``select``
        matching no sequence, a model
        without DroneKey metadata, or ``out_dir`` that is a file.
    FileNotFoundError
        The model file is missing.
    ImportError
        ``backgrounds`` holds ``"photos"`` and neither scikit-image nor scikit-learn is installed.
    """
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
        "cue_free": bool(cue_free),
    }
    plans = check_seeds(bases, tuning=tuning, **matrix)
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out_dir must be a folder, got the file {str(out_dir)!r}")
    noise = None if dither is None else FrameDither(dither)  # a bad seed fails before the renders
    model = KeypointModel(model_path)  # bad models fail now, not after the renders
    heading, drone_verifier = load_heading_model(front_back), load_verifier(verifier)
    entries = [e for plan in plans.values() for e in plan]
    if select is not None:
        patterns = list(select)
        entries = [e for e in entries if any(fnmatch.fnmatchcase(e.name, p) for p in patterns)]
        if not entries:
            raise ValueError(f"select {patterns} matches no sequence of the matrix")
    settings = {
        "seed_set": "tuning" if tuning else "reporting",
        "seeds": bases,
        "scene_seeds": seed_ranges(e.seed for e in entries),
        "frames": int(frames),
        "size": [int(width), int(height)],
        "leds": list(leds),
        "backgrounds": list(backgrounds),
        "motions": list(motions),
        "far_range_scale": far_range_scale,
        "drone_free_sequences": int(drone_free),
        "cue_free": bool(cue_free),
        "select": None if select is None else list(select),
        "model": str(model.path),
        "model_has_heading_head": bool(model.has_heading),
        "front_back": str(heading.path) if heading else None,
        "verifier": str(drone_verifier.path) if drone_verifier else None,
        "mirror_average": bool(mirror_average),
        "dither": None if noise is None else noise.seed,
        "acquire_recut": (localizer or LocalizerConfig()).acquire_recut,
        "confirm_max_outliers": (tracker or TrackerConfig()).confirm_max_outliers,
        "heading_full_spread_px": (tracker or TrackerConfig()).heading_full_spread_px,
        **pipeline_changes(localizer, tracker),
        "measure_every": int(measure_every),
        "oracle_noise_px": None if oracle_noise_px is None else float(oracle_noise_px),
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
                front_back=settings["front_back"] or False,
                verifier=settings["verifier"] or False,
                on_frame=bar.update,
                dither=noise,
                localizer=localizer,
                tracker=tracker,
                measure_every=measure_every,
                oracle_noise_px=oracle_noise_px,
                oracle_seed=r.entry.seed,
            )
            report.sequences.append(EvaluatedSequence(r, scores))
    settings["render_s"] = round(t1 - t0, 1)
    settings["evaluate_s"] = round(time.perf_counter() - t1, 1)
    settings["reused_sequences"] = sum(r.reused for r in rendered)
    return report
