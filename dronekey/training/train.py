"""``dronekey-train``: train the DroneKey network on rendered crops or on a COCO keypoint folder.

Recipes (``--preset``):

- ``edge`` (default): the shipped model. The edge network (``DroneKeyConfig.edge()``) on 128 px
  crops streamed from ``sim_replay.sampler`` (fresh renders every step, no files), AdamW with a
  warm-up and cosine decay, the pose-adaptive Mahalanobis loss with the paper's exponential scale
  schedule (alpha 5, D 10) plus 4 x L1. Sized to finish on two CPU cores in about two hours.
  Why the L1 term: trained from scratch (no ImageNet weights here), the pose-adaptive loss alone
  leaves the network predicting the mean keypoints for hundreds of steps while S(t) is large (its
  tolerance then spans the whole crop); an over-fitting probe on 128 crops gave a median error of
  29 px after 150 steps with the loss alone at S = 10, 8.7 px with L1 alone and 8.2 px with
  L1 x 4 + the loss. As S(t) shrinks, the Mahalanobis term's gradient grows (1 / sqrt(S)) and
  dominates the refinement, which is where the paper places its benefit. An order-free L1
  (``symmetric_l1``) helps the network find the propellers before it can order them, and fades out
  over the first quarter of the run.
- ``paper``: the paper's settings: ResNet-50, d 1024, N 6, 8 heads, feed-forward 2048, 224 px,
  Adam, learning rate 1e-5, batch 8, 100 epochs, alpha 5, D 10 (a GPU job).
- ``tiny``: a minute-long smoke run for tests.

Data. By default every step draws fresh rendered crops (``sim_replay.sampler``, ``--backgrounds``
mixes photos in). ``--coco PATH`` trains on a COCO keypoint dataset instead (the real 2DroneKey,
or sequences of ours written with ``dronekey-sim --images``): ``dronekey.training.coco_crops`` cuts the same
jittered crops around the annotated boxes, plus drone-free crops and left/right mirrors; a folder's
JSONs named *train* / *val* are the splits.

Presence stage. After the epochs, the best network's presence head is refit alone for
``presence_steps`` steps on the frozen network (``fit_presence_head``), and kept only if its
validation AUC is at least the jointly trained head's. It exists for networks whose head read the
last layer's IR, which with the edge encoder hardly varies between crops (the head collapsed);
the edge preset's head reads the projected-token mean (``DroneKeyConfig.presence_input``) and
trains well jointly, so the refit is a safeguard.

Schedule time. The paper's S(t) = D exp(-0.01 alpha t) runs over t = 0..100 epochs. A recipe with
another number of epochs follows the same curve over its whole run: the loss is evaluated at
``t = 100 * progress`` (progress = step / total steps), so S goes from 10 to 0.067 in every recipe.

Each epoch ends with a validation on a fixed set of rendered crops (or the COCO folder's
validation split): SR90, SR95, AP^kp (presence probability as the score), presence AUC, median
keypoint error and the front/back swap rate; the best checkpoint by AP is kept, training stops
early after ``--patience`` epochs without improvement, ``--resume`` continues the last run, and
plots of the loss and S(t) per epoch (paper Fig. 5) and of the gate weights per layer (Fig. 8)
are rewritten each epoch.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from dronekey.geometry.crop import CropPolicy
from dronekey.perception.keypoint_model import IMAGENET_MEAN, IMAGENET_STD, preprocess_crops
from dronekey.perception.keypoint_order import HEADING_TWIN, SYMMETRIES
from dronekey.training.coco_crops import CocoDataError

log = logging.getLogger("dronekey.training.train")

# Shortest front-to-rear midpoint distance (normalised crop units) for which the nose is learned.
NOSE_MIN_AXIS = 0.03
# Front/back swap of the keypoint order (1 FR <-> 2 RR, 3 RL <-> 4 FL): the hard failure mode.
FRONT_BACK_SWAP = [1, 0, 3, 2]


@dataclass(frozen=True)
class Recipe:
    """Everything that defines a training run besides the data source."""

    model: dict
    epochs: int
    samples_per_epoch: int
    batch_size: int
    lr: float
    optimizer: str = "adamw"
    weight_decay: float = 1e-4
    warmup_steps: int = 300
    cosine: bool = True
    loss: str = "pose"
    schedule: str = "exp"
    alpha: float = 5.0
    D: float = 10.0
    eps: float = 1e-4
    l1_weight: float = 0.0  # + l1_weight x mean |pred - gt| (normalised crop units), see the edge recipe
    symmetric_weight: float = 0.0  # + w x (1 - progress / symmetric_until) x order-free L1, see below
    symmetric_until: float = 0.25
    presence_weight: float = 0.25
    heading_weight: float = (
        1.0  # nose_loss of the front/back head (networks with DroneKeyConfig.heading_head)
    )
    # + w x (L1 to the labelled order - L1 to the aligned one): the pull towards the labelled front,
    # kept below the aligned L1's own weight so that a crop whose front cannot be told is still
    # cheaper at one of the two orders than at their mean (see align_to_twin)
    order_weight: float = 0.0
    # + w x the training-only propeller heatmap loss on the backbone's stride-8/16 maps
    # (dronekey.nn.heatmap_aux: teaches the CNN where the propellers and the front are)
    heatmap_weight: float = 0.0
    # BatchNorm layers kept in eval mode (fixed affine): set when a run starts from an exported
    # model, whose BatchNorm the exporter folded into the convolutions (dronekey.training.onnx_weights)
    frozen_batchnorm: bool = False
    presence_steps: int = 0  # head-only presence steps on the best network after the epochs, see below
    val_samples: int = 1500
    patience: int = 12
    crop: dict = field(default_factory=lambda: asdict(CropPolicy()))


def _recipes() -> dict[str, Recipe]:
    from dronekey.nn.model import DroneKeyConfig

    edge = DroneKeyConfig.edge()
    paper = DroneKeyConfig.paper()
    tiny = replace(edge, d_model=32, num_layers=2, num_heads=2, ff_dim=64, edge_widths=(8, 16, 16, 24, 32))
    return {
        "edge": Recipe(
            model=edge.to_dict(),
            epochs=30,
            samples_per_epoch=16384,
            batch_size=64,
            lr=2e-3,
            warmup_steps=100,
            l1_weight=4.0,
            symmetric_weight=4.0,
            order_weight=2.0,
            heatmap_weight=1.0,
            presence_steps=300,
        ),
        "paper": Recipe(
            model=paper.to_dict(),
            epochs=100,
            samples_per_epoch=7000,
            batch_size=8,
            lr=1e-5,
            optimizer="adam",
            weight_decay=0.0,
            warmup_steps=0,
            cosine=False,
            crop=asdict(CropPolicy(input_size=paper.input_size)),
        ),
        "tiny": Recipe(
            model=tiny.to_dict(),
            epochs=2,
            samples_per_epoch=64,
            batch_size=16,
            lr=2e-3,
            val_samples=64,
            warmup_steps=2,
            heatmap_weight=1.0,  # so the tests exercise the auxiliary heads and their resume
        ),
    }


# ----------------------------------------------------------------------------- data
class _CropSource:
    """Where the crops come from: the renderer (default) or a COCO keypoint dataset (``--coco``).

    Picklable and cheap: each DataLoader worker builds its own sampler from it.
    """

    def __init__(self, crop: CropPolicy, backgrounds: str | None = None, coco_images: list | None = None):
        self.crop, self.backgrounds, self.coco_images = crop, backgrounds, coco_images

    def sampler(self, seed: int):
        """A sampler with ``sample() -> CropSample``, reproducible for ``seed``."""
        if self.coco_images is not None:
            from dronekey.training.coco_crops import CocoCropSampler

            return CocoCropSampler(self.coco_images, self.crop, seed=seed)
        from dronekey.sim_replay.sampler import CropSampler, SamplerConfig

        return CropSampler(SamplerConfig(crop=self.crop), seed=seed, backgrounds=self.backgrounds)


class _StreamDataset:
    """Infinite stream of crops for a torch DataLoader; each worker has its own seed."""

    def __init__(self, seed: int, source: _CropSource) -> None:
        self.seed, self.source = seed, source

    def __iter__(self):
        import torch

        info = torch.utils.data.get_worker_info()
        wid = info.id if info is not None else 0
        sampler = self.source.sampler(self.seed * 1009 + wid)
        S = self.source.crop.input_size
        while True:
            s = sampler.sample()
            x = preprocess_crops(s.image, S, IMAGENET_MEAN, IMAGENET_STD)[0]
            yield x, s.keypoints, bool(s.present), np.float32(s.area)


def _make_loader(seed: int, source: _CropSource, batch: int, workers: int):
    import torch

    class _Iterable(torch.utils.data.IterableDataset):
        def __iter__(self):
            return iter(_StreamDataset(seed, source))

    return torch.utils.data.DataLoader(
        _Iterable(),
        batch_size=batch,
        num_workers=workers,
        persistent_workers=workers > 0,
        prefetch_factor=4 if workers else None,
    )


def _validation_set(path: Path, n: int, seed: int, source: _CropSource) -> dict:
    """A fixed set of crops, cached next to the checkpoints so a resumed run sees the same."""
    if path.is_file():
        data = dict(np.load(path))
        if len(data["image"]) == n and data["image"].shape[1] == source.crop.input_size:
            return data
    from tqdm import tqdm

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


def symmetric_l1(pred, gt):
    """Order-free L1: the smallest mean |pred - gt| over the keypoint rectangle's symmetries.

    Early in training the network cannot yet tell front from back, so the exact-order loss is
    minimised by the mean keypoints (a plateau); this term rewards finding the four propellers
    first. It fades out over ``symmetric_until`` of the run, leaving the exact-order losses.
    """
    import torch

    per = torch.stack([(pred - gt[:, list(perm)]).abs().mean(dim=(1, 2)) for perm in SYMMETRIES], dim=1)
    return per.min(dim=1).values.mean()


def nose_loss(nose, gt):
    """Squared error of the regressed nose direction against the labels' front axis, over the
    crops whose front and rear midpoints lie apart (a drone seen nose-on has no axis to learn)."""
    from dronekey.nn.model import front_axis

    mid = 0.5 * (gt[:, 0] + gt[:, 3]) - 0.5 * (gt[:, 1] + gt[:, 2])
    usable = mid.norm(dim=1) > NOSE_MIN_AXIS
    if not bool(usable.any()):
        return nose.sum() * 0.0
    return ((nose[usable] - front_axis(gt[usable])) ** 2).sum(dim=1).mean()


def align_to_twin(pred, gt):
    """The labels in whichever of the spec's order and its 180-degree twin ``pred`` is closer to.

    Returns (aligned labels (B, K, 2), in_order (B,) bool: the spec's order was the closer one).
    ``in_order`` is the front/back head's target: the head learns to tell when the points came out
    in the twin order, and the points are not pulled onto their mean when the front is unreadable.

    Why the recipe's ``order_weight`` stays below the aligned L1 weight: for a crop whose front
    cannot be told (labels in either order with even odds), a prediction on one of the two orders
    costs ``order_weight * D / 2`` in expectation (D: the L1 distance between them), the mean of the
    two costs ``l1_weight * D / 2``; one of the orders is cheaper, so the points do not collapse, while
    crops whose front can be told are pulled to the labelled order and the head learns how sure that
    is.
    """
    import torch

    twin = gt[:, HEADING_TWIN]
    in_order = (pred - gt).abs().mean(dim=(1, 2)) <= (pred - twin).abs().mean(dim=(1, 2))
    return torch.where(in_order[:, None, None], gt, twin), in_order


# ----------------------------------------------------------------------------- evaluation
def evaluate(net, data: dict, batch: int = 128) -> dict:
    """Keypoint metrics of ``net`` on a set of crops (normalised units; OKS is scale-free).

    Returns sr90, sr95, ap_kp, presence_auc (percent), median_err_px (of the network input),
    swap_rate (share of drones whose front/back order is swapped, percent), and the mean gate weights.
    With a front/back head, keypoints are put in the head's order first, and heading_wrong (percent
    of drones whose order is the 180-degree twin) and heading_confident_wrong (wrong with confidence
    |2p - 1| >= 0.5) are added.
    """
    import torch

    from dronekey.evaluation.metrics import ap_kp, oks_drone, roc_auc, sr

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


# ----------------------------------------------------------------------------- plots
def write_plots(history: list[dict], out_dir: Path) -> None:
    """Loss and S(t) per epoch (paper Fig. 5) and mean gate weight per encoder layer (Fig. 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not history:
        return
    ep = [h["epoch"] for h in history]
    fig, ax1 = plt.subplots(figsize=(6, 3.5))
    ax1.plot(ep, [h["train_loss"] for h in history], "r--", label="loss")
    ax1.set_xlabel("epoch")
    ax1.set_ylabel("training loss", color="r")
    ax2 = ax1.twinx()
    ax2.plot(ep, [h["scale"] for h in history], "b-", label="S(t)")
    ax2.set_ylabel("scale S(t)", color="b")
    fig.tight_layout()
    fig.savefig(out_dir / "loss_scale.png", dpi=120)
    plt.close(fig)

    gate = history[-1]["val"]["gate"]
    fig, ax = plt.subplots(figsize=(5, 3))
    colours = ["tab:pink"] * (len(gate) - 1) + ["tab:orange"]
    ax.bar(range(1, len(gate) + 1), gate, color=colours)
    ax.set_xlabel("encoder layer")
    ax.set_ylabel("mean gate weight")
    ax.set_title(f"gate weights, epoch {history[-1]['epoch']}")
    fig.tight_layout()
    fig.savefig(out_dir / "gate_weights.png", dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 3.5))
    for key in ("ap_kp", "sr90", "sr95"):
        ax.plot(ep, [h["val"][key] for h in history], label=key)
    ax.set_xlabel("epoch")
    ax.set_ylabel("%")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_dir / "validation.png", dpi=120)
    plt.close(fig)


def _crop_sources(args: argparse.Namespace, crop: CropPolicy) -> tuple[_CropSource, _CropSource]:
    """Training and validation crop sources: the renderer (its own validation seed), or ``--coco``.

    With ``--coco`` and no validation JSON, every tenth image is held out for validation (adjacent
    video frames are alike, so such a split flatters the figures: prefer a real validation file).
    """
    if not args.coco:
        source = _CropSource(crop, backgrounds=args.backgrounds)
        return source, source
    from dronekey.training.coco_crops import find_coco_splits, load_coco_images

    train_files, val_files = find_coco_splits(args.coco)
    train_images = load_coco_images(train_files)
    if val_files:
        val_images = load_coco_images(val_files)
    else:
        val_images = train_images[9::10]
        train_images = [im for i, im in enumerate(train_images) if i % 10 != 9]
        log.warning("--coco %s: no validation JSON; holding out every tenth image", args.coco)
    log.info(
        "COCO data: %d training images (%s), %d validation images (%s)",
        len(train_images),
        ", ".join(map(str, train_files)),
        len(val_images),
        ", ".join(map(str, val_files)) or "held out",
    )
    return _CropSource(crop, coco_images=train_images), _CropSource(crop, coco_images=val_images)


# ----------------------------------------------------------------------------- training
def train(args: argparse.Namespace) -> dict:
    import torch

    from dronekey.nn.loss import build_loss
    from dronekey.nn.model import (
        DroneKeyConfig,
        DroneKeyNet,
        count_parameters,
        load_checkpoint,
        save_checkpoint,
    )

    recipe = _recipes()[args.preset]
    overrides = {
        k: v
        for k, v in {
            "epochs": args.epochs,
            "samples_per_epoch": args.samples_per_epoch,
            "batch_size": args.batch,
            "lr": args.lr,
            "loss": args.loss,
            "schedule": args.schedule,
            "alpha": args.alpha,
            "D": args.D,
            "val_samples": args.val_samples,
            "patience": args.patience,
            "presence_steps": args.presence_steps,
            "heading_weight": args.heading_weight,
        }.items()
        if v is not None
    }
    recipe = replace(recipe, **overrides)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(args.seed)
    if args.threads:
        torch.set_num_threads(args.threads)
    crop = CropPolicy(**recipe.crop)
    state_path, last_path, best_path = out / "state.pt", out / "last.pt", out / "best.pt"

    start_epoch, history, best_ap = 0, [], -1.0
    if args.resume and last_path.is_file() and state_path.is_file():
        net, meta = load_checkpoint(last_path)
        state = torch.load(state_path, weights_only=False)
        # Keys a newer version added come from the preset; overrides, e.g. more --epochs, extend a run.
        recipe = replace(Recipe(**{**asdict(recipe), **state["recipe"]}), **overrides)
        start_epoch, history, best_ap = state["epoch"] + 1, state["history"], state["best_ap"]
        log.info("resuming %s at epoch %d (best AP %.2f)", out, start_epoch, best_ap)
    else:
        if args.resume:
            log.info("nothing to resume in %s; starting a new run", out)
        net = DroneKeyNet(DroneKeyConfig.from_dict(recipe.model))
        state = None
        if args.init_from and _warm_start(net, args.init_from):
            recipe = replace(recipe, frozen_batchnorm=True)
    net = net.to(memory_format=torch.channels_last)  # faster convolutions in oneDNN
    use_bf16 = args.precision == "bf16" or (args.precision == "auto" and _cpu_has_bf16())
    log.info("mixed precision: %s", "bfloat16 autocast (fp32 weights)" if use_bf16 else "off (fp32)")
    train_mode(net, recipe)
    params = [p for p in net.parameters() if p.requires_grad]
    aux = None
    if recipe.heatmap_weight and net.config.backbone == "edge":
        from dronekey.nn.heatmap_aux import PropellerHeatmaps, heatmap_loss

        aux = PropellerHeatmaps(net.backbone, net.config.edge_widths, net.config.edge_depths)
        aux = aux.to(memory_format=torch.channels_last).train()
        if state is not None and "heatmaps" in state:
            aux.load_state_dict(state["heatmaps"])
        params += list(aux.parameters())
    if recipe.optimizer == "adam":
        opt = torch.optim.Adam(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
    else:
        opt = torch.optim.AdamW(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
    steps_per_epoch = max(1, recipe.samples_per_epoch // recipe.batch_size)
    total_steps = steps_per_epoch * recipe.epochs

    def lr_at(step: int) -> float:
        if step < recipe.warmup_steps:
            return (step + 1) / recipe.warmup_steps
        if not recipe.cosine:
            return 1.0
        p = (step - recipe.warmup_steps) / max(1, total_steps - recipe.warmup_steps)
        return 0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * min(p, 1.0)))

    sched = torch.optim.lr_scheduler.LambdaLR(opt, lr_at)
    if state is not None:
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
    loss_fn = build_loss(
        recipe.loss, recipe.schedule, recipe.alpha, recipe.D, total_epochs=100, eps=recipe.eps
    )
    bce = torch.nn.BCEWithLogitsLoss()

    train_source, val_source = _crop_sources(args, crop)
    val = _validation_set(
        out / f"val_{'coco_' if args.coco else ''}{recipe.val_samples}_{crop.input_size}.npz",
        recipe.val_samples,
        7919,
        val_source,
    )
    loader = _make_loader(args.seed + 7 * start_epoch, train_source, recipe.batch_size, args.workers)
    batches = iter(loader)
    n_params = count_parameters(net)
    log.info(
        "training %s (%.2f M parameters) for %d epochs x %d steps of %d crops; output in %s",
        args.preset,
        n_params / 1e6,
        recipe.epochs,
        steps_per_epoch,
        recipe.batch_size,
        out,
    )
    from tqdm import tqdm

    stale = 0  # epochs since the best AP
    if history:
        best_epoch = max(history, key=lambda h: h["val"]["ap_kp"])["epoch"]
        stale = history[-1]["epoch"] - best_epoch
    t_start = time.time()
    for epoch in range(start_epoch, recipe.epochs):
        train_mode(net, recipe)
        losses, t0 = [], time.time()
        bar = tqdm(
            range(steps_per_epoch),
            desc=f"epoch {epoch + 1}/{recipe.epochs}",
            unit="step",
            leave=False,
            disable=not sys.stderr.isatty(),  # logs get one line per epoch instead
        )
        for i in bar:
            x, kp, present, _area = next(batches)
            step = epoch * steps_per_epoch + i
            t_sched = 100.0 * step / total_steps
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=use_bf16):
                out_net = net(x.contiguous(memory_format=torch.channels_last))
            pred = out_net.keypoints.float()
            target, in_order = kp, None
            if (
                out_net.heading_logit is not None
            ):  # the head decides front/back; points follow the closer order
                target, in_order = align_to_twin(pred.detach(), kp)
            loss_kp = loss_fn(pred, target, t_sched, present)
            if recipe.l1_weight and bool(present.any()):
                loss_kp = loss_kp + recipe.l1_weight * (pred[present] - target[present]).abs().mean()
            if in_order is not None and recipe.order_weight and bool(present.any()):
                excess = (pred[present] - kp[present]).abs().mean() - (
                    pred[present] - target[present]
                ).abs().mean()
                loss_kp = loss_kp + recipe.order_weight * excess
            w_sym = recipe.symmetric_weight * max(0.0, 1.0 - step / (recipe.symmetric_until * total_steps))
            if w_sym > 0 and bool(present.any()):
                loss_kp = loss_kp + w_sym * symmetric_l1(pred[present], kp[present])
            loss = loss_kp + recipe.presence_weight * bce(out_net.presence_logit.float(), present.float())
            if out_net.nose is not None and bool(present.any()):
                loss = loss + recipe.heading_weight * nose_loss(out_net.nose.float()[present], kp[present])
            if aux is not None:
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=use_bf16):
                    maps = aux()
                loss = loss + recipe.heatmap_weight * heatmap_loss(maps, kp, present, x.shape[-1])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, 2.0)
            opt.step()
            sched.step()
            losses.append(float(loss.item()))
            bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}", S=f"{loss_fn.scale(t_sched):.3f}")
        train_s = time.time() - t0
        metrics = evaluate(net, val)
        t_sched_end = 100.0 * (epoch + 1) * steps_per_epoch / total_steps
        entry = {
            "epoch": epoch + 1,
            "train_loss": float(np.mean(losses)),
            "scale": loss_fn.scale(t_sched_end),
            "lr": float(sched.get_last_lr()[0]),
            "train_s": train_s,
            "samples_per_s": steps_per_epoch * recipe.batch_size / train_s,
            "val": metrics,
        }
        history.append(entry)
        improved = metrics["ap_kp"] > best_ap
        meta = {
            "trained_on": args.data_description,
            "drone_spec": "mini2",  # the daemon's default drone; the renders mix Mini 2 and Air 2S
            "recipe": args.preset,
            "epochs": epoch + 1,
            "figures": {k: round(v, 3) for k, v in metrics.items() if k != "gate"},
            "crop_policy": recipe.crop,
            "train_seconds": float(sum(h["train_s"] for h in history)),
        }
        save_checkpoint(last_path, net, meta)
        if improved:
            best_ap, stale = metrics["ap_kp"], 0
            save_checkpoint(best_path, net, meta)
        else:
            stale += 1
        torch.save(
            {
                "recipe": asdict(recipe),
                "epoch": epoch,
                "history": history,
                "best_ap": best_ap,
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(),
                **({"heatmaps": aux.state_dict()} if aux is not None else {}),
            },
            state_path,
        )
        (out / "history.json").write_text(json.dumps(history, indent=1))
        write_plots(history, out)
        log.info(
            "epoch %d: loss %.4f S %.3f | AP %.2f SR90 %.2f SR95 %.2f AUC %.2f | median %.2f px"
            " (either order %.2f px) p90 %.2f px"
            " swap %.2f%% heading wrong %.2f%% (confident %.2f%%) | %.0f crops/s%s",
            epoch + 1,
            entry["train_loss"],
            entry["scale"],
            metrics["ap_kp"],
            metrics["sr90"],
            metrics["sr95"],
            metrics["presence_auc"],
            metrics["median_err_px"],
            metrics["median_err_either_order_px"],
            metrics["p90_err_px"],
            metrics["swap_rate"],
            metrics.get("heading_wrong", float("nan")),
            metrics.get("heading_confident_wrong", float("nan")),
            entry["samples_per_s"],
            " (best)" if improved else "",
        )
        if stale >= recipe.patience:
            log.info("no AP improvement for %d epochs: stopping early", stale)
            break
    if recipe.presence_steps and best_path.is_file():
        best, meta = load_checkpoint(best_path)
        before = evaluate(best, val)
        fit_presence_head(best, batches, recipe.presence_steps)
        metrics = evaluate(best, val)
        kept = metrics["presence_auc"] >= before["presence_auc"]
        log.info(
            "presence head refit (%d steps): AUC %.3f -> %.3f, AP %.2f -> %.2f: %s",
            recipe.presence_steps,
            before["presence_auc"],
            metrics["presence_auc"],
            before["ap_kp"],
            metrics["ap_kp"],
            "kept" if kept else "discarded (the jointly trained head was better)",
        )
        if kept:
            meta["figures"] = {k: round(v, 3) for k, v in metrics.items() if k != "gate"}
            meta["presence_steps"] = recipe.presence_steps
            save_checkpoint(best_path, best, meta)
            best_ap = metrics["ap_kp"]
    log.info(
        "done in %.1f min; best AP %.2f; checkpoints %s, %s",
        (time.time() - t_start) / 60,
        best_ap,
        best_path,
        last_path,
    )
    return {"best_ap": best_ap, "history": history}


class WarmStartError(ValueError):
    """``--init-from`` names no readable DroneKey checkpoint or model; the message says which and why."""


def train_mode(net, recipe: Recipe) -> None:
    """``net.train()``, with the BatchNorm layers left in eval mode under ``recipe.frozen_batchnorm``."""
    net.train()
    if recipe.frozen_batchnorm:
        from dronekey.training.onnx_weights import frozen_batchnorm

        frozen_batchnorm(net)


def _warm_start(net, path: str) -> bool:
    """Copy into ``net`` the weights of checkpoint or exported model ``path`` whose names and shapes
    match. Returns True when they came from an ONNX export (its BatchNorm folded: keep it frozen)."""
    import torch

    if str(path).endswith(".onnx"):
        from dronekey.training.onnx_weights import OnnxWeightsError, weights_from_onnx

        try:
            weights = weights_from_onnx(path, net)
        except OnnxWeightsError as exc:
            raise WarmStartError(f"--init-from: {exc}") from None
        net.load_state_dict(weights, strict=False)
        log.info("initialised from the exported model %s; BatchNorm frozen (folded in the export)", path)
        return True
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        weights = payload["model"]
    except FileNotFoundError:
        raise WarmStartError(f"--init-from: checkpoint not found: {path}") from None
    except Exception as exc:
        raise WarmStartError(f"--init-from {path}: not a DroneKey checkpoint ({exc})") from None
    own = net.state_dict()
    usable = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape}
    net.load_state_dict(usable, strict=False)
    log.info(
        "initialised %d of %d tensors from %s (fresh: %s)",
        len(usable),
        len(own),
        path,
        ", ".join(sorted({k.split(".")[0] for k in set(own) - set(usable)})) or "none",
    )
    return False


def fit_presence_head(net, batches, steps: int, lr: float = 3e-3) -> None:
    """Refit the presence head alone, on the frozen network, reading the projected tokens.

    Why a separate stage: trained jointly, the presence term is a small share of the loss and, with
    the head on the last IR, sees an input that hardly varies across crops (``DroneKeyConfig``,
    ``presence_input``); the keypoint epochs ended with the presence probability equal to the share
    of drone crops everywhere (AUC < 50 %). The head is a linear map of d features: a few hundred
    steps fit it, and nothing else in the network changes. ``net.config`` is switched to
    ``presence_input="tokens"`` so that the checkpoint and its ONNX export compute what was fitted.
    """
    import torch

    if net.config.presence_input != "tokens":
        log.info(
            "presence head: switching its input from %s to the projected tokens", net.config.presence_input
        )
        net.config = replace(net.config, presence_input="tokens")
    net.eval()  # BatchNorm running statistics, as at inference
    head = net.presence
    torch.nn.init.zeros_(head.weight)
    torch.nn.init.zeros_(head.bias)
    opt = torch.optim.Adam(head.parameters(), lr=lr)
    bce = torch.nn.BCEWithLogitsLoss()
    from tqdm import tqdm

    for _ in tqdm(range(steps), desc="presence head", unit="step", disable=not sys.stderr.isatty()):
        x, _kp, present, _area = next(batches)
        with torch.no_grad():
            features = net.project(x).mean(dim=1)  # (B, d): what forward() gives the head
        loss = bce(head(features).squeeze(-1), present.float())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()


def _cpu_has_bf16() -> bool:
    """Whether oneDNN has native bfloat16 kernels here (AVX512-BF16 / AMX): then autocast pays off."""
    import torch

    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="dronekey-train",
        description="Train the DroneKey keypoint network (see the module docstring for the recipes).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--preset", choices=["edge", "paper", "tiny"], default="edge", help="training recipe")
    p.add_argument("--out", default="runs/edge", help="folder for checkpoints, history and plots")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its last epoch")
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the training stream (validation uses its own)"
    )
    p.add_argument("--backgrounds", default=None, help="folder of background photos mixed into the renders")
    p.add_argument(
        "--coco",
        default=None,
        metavar="PATH",
        help="train on a COCO keypoint dataset instead of renders: a JSON file, or a folder (the "
        "2DroneKey layout) whose JSONs named *train* / *val* are the splits; images beside the JSON "
        "or in an images/ folder next to it",
    )
    p.add_argument("--workers", type=int, default=1, help="rendering processes feeding the trainer")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument(
        "--precision",
        choices=["auto", "bf16", "fp32"],
        default="auto",
        help="bf16: bfloat16 autocast with fp32 weights (about 2x faster on CPUs with AVX512-BF16); "
        "auto: bf16 where the CPU has native support",
    )
    g = p.add_argument_group("recipe overrides (default: the preset's)")
    g.add_argument("--epochs", type=int)
    g.add_argument("--samples-per-epoch", type=int)
    g.add_argument("--batch", type=int)
    g.add_argument("--lr", type=float)
    g.add_argument("--loss", choices=["pose", "gaussian", "mse"])
    g.add_argument("--schedule", choices=["exp", "linear", "fixed"])
    g.add_argument("--alpha", type=float)
    g.add_argument("--D", type=float)
    g.add_argument("--val-samples", type=int)
    g.add_argument("--patience", type=int)
    g.add_argument("--presence-steps", type=int, help="head-only presence steps after the epochs (0: none)")
    g.add_argument("--heading-weight", type=float, help="weight of the front/back head's nose loss")
    p.add_argument(
        "--init-from",
        default=None,
        metavar="CHECKPOINT",
        help="start a new run from the weights of this checkpoint (.pt) or exported model (.onnx, e.g. "
        "the shipped one; its BatchNorm then stays frozen), those whose names and shapes match; heads "
        "it lacks start fresh",
    )
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", stream=sys.stderr)
    for name in ("epochs", "samples_per_epoch", "batch", "val_samples", "patience"):
        v = getattr(args, name)
        if v is not None and v <= 0:
            parser.error(f"--{name.replace('_', '-')} must be positive, got {v}")
    if args.presence_steps is not None and args.presence_steps < 0:
        parser.error(f"--presence-steps must be >= 0, got {args.presence_steps}")
    if args.workers < 0:
        parser.error(f"--workers must be >= 0, got {args.workers}")
    if args.backgrounds is not None and not Path(args.backgrounds).is_dir():
        parser.error(f"--backgrounds folder not found: {args.backgrounds}")
    if args.coco is not None and args.backgrounds is not None:
        parser.error("--backgrounds mixes photos into renders; it does not apply to --coco")
    if args.coco is not None:
        args.data_description = f"COCO keypoint dataset {args.coco}"
    else:
        args.data_description = "dronekey.sim_replay rendered crops" + (
            f" + photos from {args.backgrounds}" if args.backgrounds else ""
        )
    try:
        train(args)
    except (CocoDataError, WarmStartError) as exc:
        print(f"dronekey-train: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("dronekey-train: interrupted; resume with --resume", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
