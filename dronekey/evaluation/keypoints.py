"""Keypoint evaluation on freshly rendered frames (AP^kp / SR90 / SR95 / presence AUC).

Renders N frames of a preset with a seed, crops around each ground-truth drone box with the crop
policy the model was trained with (the same jitter of centre and scale that stands in for the
localiser's error), runs the ONNX model, maps the keypoints back to full-frame pixels and scores
them against the annotation (OKS area = the annotated box's area, docs/design.md §4). For the presence
score, each frame also contributes one crop of the same size away from the drone.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dronekey.evaluation.metrics import ap_kp, oks_drone, roc_auc, sr
from dronekey.geometry.crop import CropPolicy, roi_around_box
from dronekey.perception.keypoint_model import KeypointModel
from dronekey.sim_replay.synthetic_sequence import build_sequence

__all__ = ["evaluate_keypoints"]

# Front/back swap of the keypoint order (1 FR <-> 2 RR, 3 RL <-> 4 FL).
_FRONT_BACK = [1, 0, 3, 2]


def _negative_roi(box, side: int, w: int, h: int, rng: np.random.Generator):
    """A crop of ``side`` px inside the frame that does not overlap ``box``, or None."""
    x, y, bw, bh = box
    for _ in range(20):
        cx, cy = (
            rng.uniform(side / 2, max(w - side / 2, side / 2 + 1)),
            rng.uniform(side / 2, max(h - side / 2, side / 2 + 1)),
        )
        if abs(cx - (x + bw / 2)) > (side + bw) / 2 or abs(cy - (y + bh / 2)) > (side + bh) / 2:
            return roi_around_box(cx, cy, side)
    return None


def evaluate_keypoints(
    preset: str = "2dronekey",
    frames: int = 200,
    seed: int = 1234,
    model_path: str | Path | None = None,
    progress: bool = False,
    mirror_average: bool = True,
) -> dict:
    """Render, crop, detect and score; returns the figures of ``dronekey-eval keypoints``.

    ``mirror_average`` as the daemon's pipeline runs the model by default (``KeypointModel``)."""
    model = KeypointModel(model_path, mirror_average=mirror_average)
    policy = CropPolicy(**{**model.metadata.get("crop_policy", {}), "input_size": model.input_size})
    seq = build_sequence(preset, seed=seed, frames=frames)
    rng = np.random.default_rng(seed + 1)
    w, h = seq.camera.size
    pred, gt, area, presence, neg_presence = [], [], [], [], []
    infer_s = 0.0
    iterator = iter(seq)
    if progress:
        iterator = tqdm(iterator, total=len(seq), desc=f"{preset} seed {seed}", unit="frame", leave=False)
    for rf in iterator:
        ann = rf.record.drone
        if ann is None:
            continue
        roi = policy.roi(ann.bbox_xywh, rng)
        rois = [roi]
        neg = _negative_roi(ann.bbox_xywh, roi[2], w, h, rng)
        if neg is not None:
            rois.append(neg)
        t0 = time.perf_counter()
        dets = model.detect(rf.image, rois)
        infer_s += time.perf_counter() - t0
        pred.append(dets[0].keypoints_px)
        presence.append(dets[0].presence)
        gt.append(ann.keypoints_px)
        area.append(ann.area)
        if len(dets) > 1:
            neg_presence.append(dets[1].presence)
    if not gt:
        raise ValueError(f"preset {preset!r} rendered no annotated frame in {frames} frames")
    pred_a, gt_a, area_a = np.asarray(pred), np.asarray(gt), np.asarray(area)
    oks = oks_drone(pred_a, gt_a, area_a)
    err = np.linalg.norm(pred_a - gt_a, axis=2)
    swap_err = np.linalg.norm(pred_a[:, _FRONT_BACK] - gt_a, axis=2)
    scores = np.asarray(presence)
    labels = np.r_[np.ones(len(scores)), np.zeros(len(neg_presence))]
    auc = roc_auc(np.r_[scores, np.asarray(neg_presence)], labels) if neg_presence else math.nan
    return {
        "frames": len(gt),
        "ap_kp": round(100 * ap_kp(pred_a, gt_a, area_a, scores), 3),
        "sr90": round(100 * sr(oks, 0.90), 3),
        "sr95": round(100 * sr(oks, 0.95), 3),
        "presence_auc": round(100 * auc, 3) if np.isfinite(auc) else None,
        "median_err_px": round(float(np.median(err)), 3),
        "swap_rate": round(100 * float(np.mean(swap_err.mean(1) < err.mean(1))), 3),
        "model": str(model.path),
        "preset": preset,
        "seed": seed,
        "inference_ms_per_frame": round(1e3 * infer_s / len(gt), 3),
    }
