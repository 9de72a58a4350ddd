"""The validation of a training run: a fixed set of crops and the network's metrics on it.

Each epoch ends with a validation on a fixed set of rendered crops (or the COCO folder's
validation split), cached next to the checkpoints so that a resumed run sees the same: SR90, SR95,
AP^kp (presence probability as the score), presence AUC, median keypoint error and the front/back
swap rate.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from dronekey.evaluation.metrics import ap_kp, oks_drone, roc_auc, sr
from dronekey.nn.model import DroneKeyNet
from dronekey.perception.keypoint_model import IMAGENET_MEAN, IMAGENET_STD, preprocess_crops
from dronekey.perception.keypoint_order import HEADING_TWIN
from dronekey.training.crop_stream import CropSource

__all__ = ["FRONT_BACK_SWAP", "VALIDATION_SEED", "evaluate", "figures", "validation_set"]

# Front/back swap of the keypoint order (1 FR <-> 2 RR, 3 RL <-> 4 FL): the hard failure mode.
FRONT_BACK_SWAP = [1, 0, 3, 2]
VALIDATION_SEED = 7919  # the validation crops' own sampler seed, apart from the training stream's


def validation_set(path: Path, n: int, seed: int, source: CropSource) -> dict[str, np.ndarray]:
    """``n`` crops from ``source`` (image (n, S, S, 3) uint8 BGR, keypoints (n, K, 2) normalised,
    present (n,), area (n,)), cached at ``path`` (.npz) so a resumed run sees the same."""
    if path.is_file():
        data = dict(np.load(path))
        if len(data["image"]) == n and data["image"].shape[1] == source.crop.input_size:
            return data
    sampler = source.sampler(seed)
    quiet = not sys.stderr.isatty()  # logs get one line per epoch instead of progress bars
    bar = tqdm(range(n), desc="rendering validation crops", unit="crop", leave=False, disable=quiet)
    samples = [sampler.sample() for _ in bar]
    data = {
        "image": np.stack([s.image for s in samples]),
        "keypoints": np.stack([s.keypoints for s in samples]),
        "present": np.array([s.present for s in samples]),
        "area": np.array([s.area for s in samples], dtype=np.float32),
    }
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **data)
    tmp.replace(path)
    return data


def evaluate(net: DroneKeyNet, data: dict[str, np.ndarray], batch: int = 128) -> dict:
    """Keypoint metrics of ``net`` on a set of crops (normalised units; OKS is scale-free).

    Returns sr90, sr95, ap_kp, presence_auc (percent), median_err_px (of the network input),
    swap_rate (share of drones whose front/back order is swapped, percent), and the mean gate weights.
    With a front/back head, keypoints are put in the head's order first, and heading_wrong (percent
    of drones whose order is the 180-degree twin) and heading_confident_wrong (wrong with confidence
    |2p - 1| >= 0.5) are added.
    """
    net.eval()
    S = data["image"].shape[1]
    kps, pres, gates, heads = [], [], [], []
    with torch.no_grad():
        for i in range(0, len(data["image"]), batch):
            x = torch.from_numpy(
                preprocess_crops(data["image"][i : i + batch], S, IMAGENET_MEAN, IMAGENET_STD)
            )
            out = net(x)
            kps.append(out.keypoints.numpy())
            pres.append(torch.sigmoid(out.presence_logit).numpy())
            gates.append(out.gate.numpy())
            if out.heading_logit is not None:
                heads.append(torch.sigmoid(out.heading_logit).numpy())
    kp, p, gate = np.concatenate(kps), np.concatenate(pres), np.concatenate(gates)
    present = data["present"].astype(bool)
    extra = {}
    if heads:
        ph = np.concatenate(heads)
        kp = np.where((ph >= 0.5)[:, None, None], kp, kp[:, HEADING_TWIN])
        gt_all = data["keypoints"]
        e_id = np.abs(kp - gt_all).mean(axis=(1, 2))
        e_tw = np.abs(kp - gt_all[:, HEADING_TWIN]).mean(axis=(1, 2))
        wrong = (e_tw < e_id)[present]
        confident = (np.abs(2 * ph - 1) >= 0.5)[present]
        extra = {
            "heading_wrong": 100 * float(np.mean(wrong)),
            "heading_confident_wrong": 100 * float(np.mean(wrong & confident)),
        }
    gt, area = data["keypoints"][present], data["area"][present]
    oks = oks_drone(kp[present], gt, area)
    err = np.linalg.norm(kp[present] - gt, axis=2) * S
    swapped_err = np.linalg.norm(kp[present][:, FRONT_BACK_SWAP] - gt, axis=2) * S
    ap = ap_kp(kp, data["keypoints"], data["area"], p, has_gt=present)
    return {
        "sr90": 100 * sr(oks, 0.90),
        "sr95": 100 * sr(oks, 0.95),
        "ap_kp": 100 * ap,
        "presence_auc": 100 * roc_auc(p, present),
        "median_err_px": float(np.median(err)),
        # front/back apart: the error against the closer of the labels and their 180-degree twin
        "median_err_either_order_px": float(
            np.median(np.minimum(err, np.linalg.norm(kp[present] - gt[:, HEADING_TWIN], axis=2) * S))
        ),
        "p90_err_px": float(np.percentile(err.mean(axis=1), 90)),
        "swap_rate": 100 * float(np.mean(swapped_err.mean(1) < err.mean(1))),
        **extra,
        "gate": gate[present].mean(axis=0).tolist(),
    }


def figures(metrics: dict) -> dict[str, float]:
    """The metrics a checkpoint's meta records (``figures``): all but the gate weights, rounded."""
    return {k: round(v, 3) for k, v in metrics.items() if k != "gate"}
