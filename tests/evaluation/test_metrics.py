"""OKS_drone, SR and AP^kp (docs/design.md §4) against hand values and pycocotools' COCOeval."""

import contextlib
import io
import math

import numpy as np
import pytest
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from dronekey.evaluation.metrics import ap_kp, oks_drone, roc_auc, sr

SIGMA = math.sqrt(0.025)  # 0.1581: COCO sigma that makes COCO's OKS equal OKS_drone


def test_oks_hand_value():
    area = 400.0
    d = math.sqrt(0.2 * area * math.log(2))  # exp(-d^2 / (0.2 area)) = 1/2
    gt = np.zeros((1, 4, 2))
    pred = gt.copy()
    pred[0, :2, 0] = d  # two keypoints off by d, two exact
    assert oks_drone(pred, gt, [area])[0] == pytest.approx((0.5 + 0.5 + 1 + 1) / 4, rel=1e-12)
    assert oks_drone(gt, gt, [area])[0] == 1.0


def test_success_rate():
    assert sr([0.95, 0.9, 0.89, 0.2], 0.90) == 0.5
    assert sr([0.95, 0.9, 0.89, 0.2], 0.95) == 0.25


def _cocoeval_ap(pred, gt, area, scores, has_gt, has_pred):
    """AP^kp by pycocotools, on COCO objects built in memory."""
    images, annotations, results = [], [], []
    for i in range(len(gt)):
        images.append({"id": i, "width": 1920, "height": 1080})
        if has_gt[i]:
            x, y = gt[i].min(0)
            w, h = np.ptp(gt[i], axis=0)
            keypoints = np.c_[gt[i], np.full(4, 2)].ravel().tolist()
            # ids from 1: COCOeval stores matched ids in an array it tests for truth.
            annotations.append(
                {
                    "id": len(annotations) + 1,
                    "image_id": i,
                    "category_id": 1,
                    "keypoints": keypoints,
                    "num_keypoints": 4,
                    "bbox": [float(x), float(y), float(w), float(h)],
                    "area": float(area[i]),
                    "iscrowd": 0,
                }
            )
        if has_pred[i]:
            keypoints = np.c_[pred[i], np.ones(4)].ravel().tolist()
            results.append(
                {"image_id": i, "category_id": 1, "keypoints": keypoints, "score": float(scores[i])}
            )
    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO()
        coco.dataset = {
            "images": images,
            "annotations": annotations,
            "categories": [{"id": 1, "name": "drone", "keypoints": ["p1", "p2", "p3", "p4"], "skeleton": []}],
        }
        coco.createIndex()
        detections = coco.loadRes(results)
        evaluator = COCOeval(coco, detections, "keypoints")
        evaluator.params.kpt_oks_sigmas = np.full(4, SIGMA)
        evaluator.evaluate()
        evaluator.accumulate()
        evaluator.summarize()
    return evaluator.stats[0]


@pytest.mark.parametrize("seed", range(6))
def test_ap_kp_equals_pycocotools(seed):
    rng = np.random.default_rng(seed)
    n = 80
    gt = rng.uniform(100, 900, (n, 1, 2)) + rng.uniform(-40, 40, (n, 4, 2))
    area = np.ptp(gt[:, :, 0], axis=1) * np.ptp(gt[:, :, 1], axis=1) + rng.uniform(10, 500, n)
    noise = rng.choice([0.5, 2.0, 5.0, 15.0], size=(n, 1, 1))  # pixels: from perfect to lost
    pred = gt + rng.normal(0, 1, (n, 4, 2)) * noise
    scores = np.round(rng.uniform(0, 1, n), 1)  # rounded: ties between images, as real scores have
    has_gt = rng.uniform(size=n) > 0.15  # some images without a drone ...
    has_pred = rng.uniform(size=n) > 0.1  # ... and some without a prediction
    expected = _cocoeval_ap(pred, gt, area, scores, has_gt, has_pred)
    assert ap_kp(pred, gt, area, scores, has_gt, has_pred) == pytest.approx(expected, abs=1e-6)


def test_ap_kp_perfect_and_empty():
    gt = np.random.default_rng(0).uniform(0, 100, (10, 4, 2))
    assert ap_kp(gt, gt, np.full(10, 900.0), np.ones(10)) == pytest.approx(1.0)
    assert math.isnan(ap_kp(gt, gt, np.full(10, 900.0), np.ones(10), has_gt=np.zeros(10, bool)))


def test_shapes_are_checked():
    with pytest.raises(ValueError, match="pred must have shape"):
        oks_drone(np.zeros((2, 4, 2)), np.zeros((3, 4, 2)), np.ones(3))
    with pytest.raises(ValueError, match="area"):
        oks_drone(np.zeros((3, 4, 2)), np.zeros((3, 4, 2)), np.ones(2))


def test_roc_auc_counts_pairs_and_ties():
    scores = np.array([0.9, 0.8, 0.8, 0.3, 0.1, 0.8])
    labels = np.array([1, 1, 0, 1, 0, 0])
    positive, negative = scores[labels == 1], scores[labels == 0]
    pairs = [(p > q) + 0.5 * (p == q) for p in positive for q in negative]
    assert roc_auc(scores, labels) == pytest.approx(np.mean(pairs))
    assert math.isnan(roc_auc([0.1, 0.2], [1, 1]))
