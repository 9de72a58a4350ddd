"""``dronekey-calibrate-spread``: fit a model's spread calibration on tuning renders and store it.

The keypoint network reads a drone's size partly from its crop, and on average too small
(``dronekey.perception.spread_calibration`` says how, and why it matters for tracking). This fits
one factor, the least-squares slope through the origin of the true normalised keypoint spread ``r``
on the network's ``q`` (``r = slope * q``), on crops of rendered sequences cut as the tracker cuts
them (the training framing around the true keypoints, scaled by 0.75-1.35 and shifted by up to 8 %
of the side, seeded), and writes a copy of the ONNX model with it in its metadata
(``spread_calibration``), which ``KeypointModel`` then applies.

Why one factor: three fits were compared on the full tuning matrix (36 drone + 12 drone-free
sequences, ``dronekey-eval robustness --tuning --drone-free 12``), each fitted on its 36 drone
sequences (7,118 crops): the factor (1.0749), the least-squares line of ``r`` on ``q`` (0.124 +
0.805 q) and the inverse of the network's mean answer (-0.666 + 2.555 q, which de-compresses sizes
but multiplies the per-crop noise by 2.6). Detected / RMSE / out-of-gate frames per 1,000 (ids) /
drone-free false frames per 1,000 (ids): none 63.9 % / 0.871 m / 342.8 (48) / 33.3 (1); factor
84.7 % / 0.787 m / 137.8 (30) / 46.7 (1); line 85.6 % / 0.770 m / 171.1 (29) / 64.4 (2); inverse
80.2 % / 0.813 m / 194.4 (35) / 22.8 (1). The factor is as good as the line on the drones, keeps
the drone-free clips at one false object, and cannot extrapolate.

``--aspect-knee K`` fits a second term, the slope's growth below the keypoints' aspect ``K``
(``r = q (slope + aspect_slope max(0, K - a))``, least squares through the origin, the growth kept
>= 0): edge-on drones, whose keypoints are read with a short pair, are read smaller still.

Fit on tuning sequences only (``dronekey-eval robustness --tuning`` renders them), never on the
sequences the figures are reported on.
"""

from __future__ import annotations

import argparse
import logging
import shutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dronekey.evaluation.pose import sequence_spec
from dronekey.geometry.crop import CropPolicy, roi_around_box
from dronekey.perception.keypoint_model import KeypointModel
from dronekey.perception.localizer import box_from_keypoints
from dronekey.perception.spread_calibration import (
    METADATA_KEY,
    SpreadCalibration,
    below_knee,
    keypoint_aspect,
    normalised_spread,
)
from dronekey.sim_replay.annotations import UNLABELLED
from dronekey.sim_replay.io.frames import iter_frames
from dronekey.sim_replay.io.sequence_reader import load_sequence

__all__ = ["SpreadFit", "fit_spread_calibration", "main", "write_calibrated_model"]

log = logging.getLogger(__name__)

SCALE_RANGE = (0.75, 1.35)  # crop side over the training framing's: the tracker's crops and beyond
SHIFT_FRAC = 0.08  # centre shift, of the side: CropPolicy's jitter
MIN_SPREAD = 0.25  # answers below this (collapsed keypoints) say nothing about size


@dataclass(frozen=True)
class SpreadFit:
    """A fitted calibration and how well it does on the crops it was fitted on.

    crops : crops used. mean_error_raw / _fitted : mean of estimate - truth, crop-side units (the
    bias). median_abs_error_raw / _fitted : median |estimate / truth - 1| (the per-crop error).
    """

    calibration: SpreadCalibration
    crops: int
    mean_error_raw: float
    mean_error_fitted: float
    median_abs_error_raw: float
    median_abs_error_fitted: float


def fit_spread_calibration(
    model_path: str | Path,
    sequences: Sequence[str | Path],
    every: int = 3,
    crops_per_frame: int = 4,
    seed: int = 0,
    progress: bool = False,
    aspect_knee: float | None = None,
) -> SpreadFit:
    """Fit ``r = slope * q`` on crops of ``sequences`` (sequence JSON files); with ``aspect_knee``
    (in (0, 1)) also the slope's growth below that keypoint aspect (``SpreadCalibration``).

    Raises ValueError when the sequences give fewer than 50 usable crops (no drone in them, or a
    model that finds none).
    """
    if every < 1 or crops_per_frame < 1:
        raise ValueError(f"every and crops_per_frame must be >= 1, got {every} and {crops_per_frame}")
    if aspect_knee is not None and not 0.0 < aspect_knee < 1.0:
        raise ValueError(f"aspect_knee must be in (0, 1), got {aspect_knee}")
    model = KeypointModel(model_path, threads=1, mirror_average=True, spread_calibration=SpreadCalibration())
    crop = CropPolicy(**{**model.metadata.get("crop_policy", {}), "input_size": model.input_size})
    rng = np.random.default_rng(seed)
    q_all, r_all, a_all = [], [], []
    for path in sequences:
        seq = load_sequence(path)
        spec = sequence_spec(seq)
        frames = iter_frames(seq)
        if progress:
            frames = tqdm(frames, total=len(seq.frames), desc=Path(path).name, unit="frame", leave=False)
        for i, sf in enumerate(frames):
            ann = sf.record.drone
            if i % every or ann is None or np.any(ann.visibility == UNLABELLED):
                continue
            x0, y0, side = crop.roi(box_from_keypoints(ann.keypoints_px, spec))
            cx, cy = x0 + side / 2 - 0.5, y0 + side / 2 - 0.5
            true_spread = float(normalised_spread(ann.keypoints_px[None])[0])
            rois = []
            for _ in range(crops_per_frame):
                scale = float(np.exp(rng.uniform(*np.log(SCALE_RANGE))))
                dx, dy = rng.uniform(-SHIFT_FRAC, SHIFT_FRAC, 2) * side
                rois.append(roi_around_box(cx + dx, cy + dy, side * scale))
            for roi, det in zip(rois, model.detect(sf.bgr, rois), strict=True):
                if det.presence >= 0.5:
                    q_all.append(float(normalised_spread(det.keypoints_px[None])[0]) / roi[2])
                    r_all.append(true_spread / roi[2])
                    a_all.append(float(keypoint_aspect(det.keypoints_px[None])[0]))
    q, r = np.asarray(q_all), np.asarray(r_all)
    keep = q >= MIN_SPREAD
    if keep.sum() < 50:
        raise ValueError(
            f"only {int(keep.sum())} usable crops in {len(sequences)} sequence(s) (need 50): "
            "render tuning sequences with a drone in view"
        )
    q, r, a = q[keep], r[keep], np.asarray(a_all)[keep]
    names = [Path(p).parent.name or Path(p).name for p in sequences]
    span = names[0] if len(names) == 1 else f"{names[0]} .. {names[-1]}"
    fitted_on = f"{len(q)} crops of {len(sequences)} sequences ({span})"
    calibration = SpreadCalibration(0.0, round(_slope(q, r), 5), fitted_on)
    if aspect_knee is not None:
        (slope, growth), *_ = np.linalg.lstsq(np.c_[q, q * below_knee(a, aspect_knee)], r, rcond=None)
        if growth > 0:  # else the aspect adds nothing: the single factor stays
            calibration = SpreadCalibration(
                0.0, round(float(slope), 5), fitted_on, aspect_knee, round(float(growth), 5)
            )
    grown = calibration.aspect_slope * below_knee(a, calibration.aspect_knee)
    fitted = calibration.intercept + (calibration.slope + grown) * q
    return SpreadFit(
        calibration,
        int(len(q)),
        float(np.mean(q - r)),
        float(np.mean(fitted - r)),
        float(np.median(np.abs(q / r - 1))),
        float(np.median(np.abs(fitted / r - 1))),
    )


def _slope(q: np.ndarray, r: np.ndarray) -> float:
    """Least squares through the origin: ``r = slope q``."""
    return float(np.sum(q * r) / np.sum(q * q))


def write_calibrated_model(model_path: str | Path, out: str | Path, calibration: SpreadCalibration) -> Path:
    """Copy ``model_path`` to ``out`` with ``calibration`` in its metadata (other entries kept)."""
    # onnx is the train extra (training.export.write_metadata would bring torch too, and drops the
    # other entries); the runtime reads the metadata through onnxruntime.
    import onnx

    model_path, out = Path(model_path), Path(out)
    model = onnx.load(str(model_path))
    entries = {p.key: p.value for p in model.metadata_props}
    entries[METADATA_KEY] = calibration.to_metadata()
    del model.metadata_props[:]
    for key, value in entries.items():
        model.metadata_props.add(key=key, value=value)
    tmp = out.with_name(out.name + ".tmp")
    onnx.save(model, str(tmp))
    shutil.move(tmp, out)
    return out


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dronekey-calibrate-spread",
        description="Fit how the keypoint model's spread answers the true one, on rendered tuning "
        "sequences, and write a copy of the model that applies the fit (docs/model.md).",
    )
    parser.add_argument("--model", type=Path, help="ONNX model (default: the shipped one)")
    parser.add_argument(
        "--sequences", type=Path, nargs="+", required=True, metavar="JSON", help="tuning sequence files"
    )
    parser.add_argument("--out", type=Path, required=True, help="ONNX file to write (may be --model)")
    parser.add_argument("--every", type=int, default=3, help="use every N-th frame (default 3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the crop scales and shifts (default 0)")
    parser.add_argument(
        "--aspect-knee",
        type=float,
        metavar="K",
        help="also fit the slope's growth for keypoints whose shortest pair is under K of their longest "
        "(edge-on drones, read small), K in (0, 1); default: one factor",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    """``dronekey-calibrate-spread``; bad input is one line on stderr and exit status 2."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    from dronekey.perception.keypoint_model import default_model_path

    model = args.model or default_model_path()
    try:
        fit = fit_spread_calibration(
            model,
            args.sequences,
            every=args.every,
            seed=args.seed,
            progress=True,
            aspect_knee=args.aspect_knee,
        )
        write_calibrated_model(model, args.out, fit.calibration)
    except (FileNotFoundError, ValueError, OSError) as exc:
        print(f"dronekey-calibrate-spread: {exc}", file=sys.stderr)
        return 2
    c = fit.calibration
    aspect = f" (+ {c.aspect_slope:.4f} max(0, {c.aspect_knee:g} - aspect))" if c.uses_aspect else ""
    print(
        f"r = {c.intercept:.4f} + {c.slope:.4f}{aspect} q on {fit.crops} crops; mean spread error "
        f"{fit.mean_error_raw:+.4f} -> {fit.mean_error_fitted:+.4f} of the crop side, median per-crop "
        f"error {fit.median_abs_error_raw:.3f} -> {fit.median_abs_error_fitted:.3f}; wrote {args.out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
