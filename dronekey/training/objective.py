"""The training loss of one batch: the recipe's terms on the network's outputs, added up.

Terms (weights from ``Recipe``): the keypoint loss (``dronekey.nn.loss``, read at the schedule time
t), an L1 term, the pull towards the labelled front/back order, the fading order-free L1, the
presence BCE, the front/back head's nose loss and the propeller heatmap loss
(``dronekey.nn.heatmap_aux``). Keypoints are in normalised crop units (0 = the crop's left/top
edge, 1 = its right/bottom edge).
"""

from __future__ import annotations

import torch

from dronekey.nn.heatmap_aux import heatmap_loss
from dronekey.nn.model import DroneKeyOutput, front_axis
from dronekey.perception.keypoint_order import HEADING_TWIN, SYMMETRIES
from dronekey.training.recipe import Recipe, schedule_time

__all__ = ["NOSE_MIN_AXIS", "align_to_twin", "batch_loss", "nose_loss", "symmetric_l1"]

# Shortest front-to-rear midpoint distance (normalised crop units) for which the nose is learned.
NOSE_MIN_AXIS = 0.03


def symmetric_l1(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Order-free L1: the smallest mean |pred - gt| over the keypoint rectangle's symmetries.

    Early in training the network cannot yet tell front from back, so the exact-order loss is
    minimised by the mean keypoints (a plateau); this term rewards finding the four propellers
    first. It fades out over ``symmetric_until`` of the run, leaving the exact-order losses.
    """
    per = torch.stack([(pred - gt[:, list(perm)]).abs().mean(dim=(1, 2)) for perm in SYMMETRIES], dim=1)
    return per.min(dim=1).values.mean()


def nose_loss(nose: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Squared error of the regressed nose direction against the labels' front axis, over the
    crops whose front and rear midpoints lie apart (a drone seen nose-on has no axis to learn)."""
    mid = 0.5 * (gt[:, 0] + gt[:, 3]) - 0.5 * (gt[:, 1] + gt[:, 2])
    usable = mid.norm(dim=1) > NOSE_MIN_AXIS
    if not bool(usable.any()):
        return nose.sum() * 0.0
    return ((nose[usable] - front_axis(gt[usable])) ** 2).sum(dim=1).mean()


def align_to_twin(pred: torch.Tensor, gt: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
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
    twin = gt[:, HEADING_TWIN]
    in_order = (pred - gt).abs().mean(dim=(1, 2)) <= (pred - twin).abs().mean(dim=(1, 2))
    return torch.where(in_order[:, None, None], gt, twin), in_order


def batch_loss(
    recipe: Recipe,
    keypoint_loss: torch.nn.Module,
    out: DroneKeyOutput,
    keypoints: torch.Tensor,
    present: torch.Tensor,
    heatmaps: dict[int, torch.Tensor] | None,
    input_size: int,
    step: int,
    total_steps: int,
) -> torch.Tensor:
    """The scalar loss of a batch at ``step`` of ``total_steps``.

    Parameters
    ----------
    recipe : the run's recipe (term weights, order-free L1 fade).
    keypoint_loss : ``dronekey.nn.loss.build_loss(...)``, called at ``schedule_time(step, total_steps)``.
    out : the network's outputs on the batch.
    keypoints : (B, K, 2) labels in normalised crop units; present : (B,) bool.
    heatmaps : the propeller heatmap heads' logits on the batch, or None without them.
    input_size : the crops' side in pixels (the heatmap targets' blob size is in pixels).
    """
    pred = out.keypoints.float()
    target, in_order = keypoints, None
    if out.heading_logit is not None:  # the head decides front/back; points follow the closer order
        target, in_order = align_to_twin(pred.detach(), keypoints)
    loss_kp = keypoint_loss(pred, target, schedule_time(step, total_steps), present)
    if recipe.l1_weight and bool(present.any()):
        loss_kp = loss_kp + recipe.l1_weight * (pred[present] - target[present]).abs().mean()
    if in_order is not None and recipe.order_weight and bool(present.any()):
        excess = (pred[present] - keypoints[present]).abs().mean() - (
            pred[present] - target[present]
        ).abs().mean()
        loss_kp = loss_kp + recipe.order_weight * excess
    w_sym = recipe.symmetric_weight * max(0.0, 1.0 - step / (recipe.symmetric_until * total_steps))
    if w_sym > 0 and bool(present.any()):
        loss_kp = loss_kp + w_sym * symmetric_l1(pred[present], keypoints[present])
    presence = torch.nn.functional.binary_cross_entropy_with_logits(
        out.presence_logit.float(), present.float()
    )
    loss = loss_kp + recipe.presence_weight * presence
    if out.nose is not None and bool(present.any()):
        loss = loss + recipe.heading_weight * nose_loss(out.nose.float()[present], keypoints[present])
    if heatmaps is not None:
        loss = loss + recipe.heatmap_weight * heatmap_loss(heatmaps, keypoints, present, input_size)
    return loss
