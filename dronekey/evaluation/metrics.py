"""Keypoint metrics of the paper (§V-A) as docs/design.md §4 defines them: OKS_drone, SR90 / SR95, AP^kp,
plus the presence head's ROC AUC. numpy only (the evaluation runs without torch).

OKS_drone = mean_k exp(-d_k^2 / (0.2 * area)) (paper eq. 15 with beta^2 = area, gamma = 1) is COCO's
OKS with every keypoint sigma = sqrt(0.025) = 0.1581; ``ap_kp`` follows pycocotools' COCOeval
(iouType "keypoints", area range "all") step by step, so both agree to rounding (tested).

All coordinates are pixels (any consistent unit works: OKS only uses d^2 / area). Scores and
rates are fractions in [0, 1]; reports multiply by 100.
"""

from __future__ import annotations

import numpy as np

__all__ = ["OKS_THRESHOLDS", "ap_kp", "oks_drone", "roc_auc", "sr"]

# COCOeval's iouThrs: 0.50:0.05:0.95 built exactly as pycocotools does (same floating-point values).
OKS_THRESHOLDS = np.linspace(0.5, 0.95, int(np.round((0.95 - 0.5) / 0.05)) + 1, endpoint=True)
_RECALL_THRESHOLDS = np.linspace(0.0, 1.00, int(np.round((1.00 - 0.0) / 0.01)) + 1, endpoint=True)
_OKS_DENOMINATOR = 0.2  # 2 * (2 sigma)^2 with sigma^2 = 0.025 (COCO: e = d^2 / vars / (area + eps) / 2)


def _keypoints(name: str, value, n: int | None = None) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 3 or arr.shape[2] != 2 or (n is not None and arr.shape[0] != n):
        want = f"({n}, K, 2)" if n is not None else "(N, K, 2)"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    return arr


def _vector(name: str, value, n: int, dtype=np.float64) -> np.ndarray:
    arr = np.asarray(value, dtype=dtype)
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    return arr


def oks_drone(pred, gt, area) -> np.ndarray:
    """OKS_drone per instance.

    Parameters
    ----------
    pred, gt : (N, K, 2) keypoints, pixels.
    area : (N,) instance area (the drone's box area), pixels^2; the OKS scale beta^2.

    Returns
    -------
    (N,) OKS in [0, 1].
    """
    gt = _keypoints("gt", gt)
    pred = _keypoints("pred", pred, gt.shape[0])
    if pred.shape != gt.shape:
        raise ValueError(f"pred must have the shape of gt {gt.shape}, got {pred.shape}")
    area = _vector("area", area, gt.shape[0])
    if np.any(area < 0) or not np.all(np.isfinite(area)):
        raise ValueError("area must be finite and >= 0")
    squared = ((pred - gt) ** 2).sum(axis=2)
    # + np.spacing(1) as COCOeval does: the same numbers, and no division by zero for a zero area.
    return np.exp(-squared / (_OKS_DENOMINATOR * (area[:, None] + np.spacing(1)))).mean(axis=1)


def sr(oks, threshold: float) -> float:
    """Success rate: the share of instances with OKS >= ``threshold`` (SR90: 0.90, SR95: 0.95)."""
    oks = np.asarray(oks, dtype=np.float64)
    if oks.ndim != 1 or oks.size == 0:
        raise ValueError(f"oks must be a non-empty 1-D array, got shape {oks.shape}")
    return float(np.mean(oks >= threshold))


def ap_kp(pred, gt, area, scores, has_gt=None, has_pred=None) -> float:
    """COCO keypoint AP (AP^kp) over OKS thresholds 0.50:0.05:0.95, one drone per image at most.

    Image i holds the ground truth ``gt[i]`` when ``has_gt[i]`` and the prediction ``pred[i]`` with
    confidence ``scores[i]`` when ``has_pred[i]`` (both default to all True). A prediction on an
    image without ground truth is a false positive; an image without prediction is a miss. Same
    computation as COCOeval's ``stats[0]`` (area "all", 101 recall points, interpolated precision,
    ties in score broken by image order).

    Parameters
    ----------
    pred, gt : (N, K, 2) keypoints, pixels (rows without gt / prediction are ignored).
    area : (N,) ground-truth area, pixels^2.
    scores : (N,) prediction confidence (e.g. the presence probability).
    has_gt, has_pred : (N,) bool or None.

    Returns
    -------
    AP in [0, 1]; NaN when no image holds ground truth (COCOeval's -1).
    """
    gt = _keypoints("gt", gt)
    n = gt.shape[0]
    pred = _keypoints("pred", pred, n)
    area = _vector("area", area, n)
    scores = _vector("scores", scores, n)
    has_gt = np.ones(n, bool) if has_gt is None else _vector("has_gt", has_gt, n, bool)
    has_pred = np.ones(n, bool) if has_pred is None else _vector("has_pred", has_pred, n, bool)
    num_gt = int(has_gt.sum())
    if num_gt == 0:
        return float("nan")
    oks = np.zeros(n)
    both = has_gt & has_pred
    if both.any():
        oks[both] = oks_drone(pred[both], gt[both], area[both])
    # Detections in COCOeval's accumulate order: stable sort by descending score over images in order.
    det_index = np.flatnonzero(has_pred)
    order = np.argsort(-scores[det_index], kind="mergesort")
    det_index = det_index[order]
    precisions = []
    for threshold in OKS_THRESHOLDS:
        # COCOeval matches when oks >= min(threshold, 1 - 1e-10).
        matched = has_gt[det_index] & (oks[det_index] >= min(threshold, 1 - 1e-10))
        tp = np.cumsum(matched).astype(float)
        fp = np.cumsum(~matched).astype(float)
        recall = tp / num_gt
        precision = tp / (fp + tp + np.spacing(1))
        precision = np.maximum.accumulate(precision[::-1])[::-1] if precision.size else precision
        at = np.searchsorted(recall, _RECALL_THRESHOLDS, side="left")
        q = np.zeros(_RECALL_THRESHOLDS.size)
        valid = at < precision.size
        q[valid] = precision[at[valid]]
        precisions.append(q.mean())
    return float(np.mean(precisions))


def roc_auc(scores, labels) -> float:
    """Area under the ROC curve of ``scores`` for binary ``labels`` (presence AUC), ties counted half.

    Computed as the Mann-Whitney U statistic with average ranks. NaN when only one class is present.
    """
    scores = np.asarray(scores, dtype=np.float64)
    labels = np.asarray(labels).astype(bool)
    if scores.ndim != 1 or labels.shape != scores.shape:
        raise ValueError(
            f"scores and labels must be 1-D of one length, got {scores.shape} and {labels.shape}"
        )
    positives = int(labels.sum())
    negatives = labels.size - positives
    if positives == 0 or negatives == 0:
        return float("nan")
    order = np.argsort(scores, kind="mergesort")
    sorted_scores = scores[order]
    ranks = np.empty(scores.size)
    # Average rank (1-based) over each run of equal scores.
    starts = np.flatnonzero(np.r_[True, sorted_scores[1:] != sorted_scores[:-1]])
    ends = np.r_[starts[1:], scores.size]
    for start, end in zip(starts, ends, strict=True):
        ranks[order[start:end]] = (start + 1 + end) / 2.0
    u = ranks[labels].sum() - positives * (positives + 1) / 2.0
    return float(u / (positives * negatives))
