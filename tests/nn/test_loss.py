"""Keypoint losses against hand-computed values; boundedness; gradients near a perfect prediction."""

import math

import numpy as np
import pytest
import torch

from dronekey.nn.loss import MahalanobisLoss, build_loss, keypoint_covariance, scale_schedule

# A drone seen from above: a square of side 0.4 centred in the crop; covariance diag(0.04, 0.04).
SQUARE = torch.tensor([[[0.3, 0.3], [0.7, 0.3], [0.7, 0.7], [0.3, 0.7]]], dtype=torch.float64)


def _shift_first(gt, dx, dy):
    pred = gt.clone()
    pred[:, 0, 0] += dx
    pred[:, 0, 1] += dy
    return pred


def test_scale_schedules():
    assert scale_schedule("exp", 0) == 10.0
    assert scale_schedule("exp", 100) == pytest.approx(10 * math.exp(-5))
    assert scale_schedule("exp", 20, alpha=10) == pytest.approx(10 * math.exp(-2))
    assert scale_schedule("fixed", 57) == 10.0
    end = 10 * math.exp(-5)
    assert scale_schedule("linear", 50, total_epochs=100) == pytest.approx((10 + end) / 2)
    assert scale_schedule("linear", 150, total_epochs=100) == pytest.approx(end)
    with pytest.raises(ValueError, match="kind"):
        scale_schedule("cosine", 1)


def test_covariance_is_eq_7():
    assert torch.allclose(keypoint_covariance(SQUARE), torch.diag(torch.tensor([0.04, 0.04])).double())


def test_pose_adaptive_loss_hand_value():
    pred = _shift_first(SQUARE, 0.1, 0.0)
    d = 0.1 / math.sqrt(10 * 0.04 + 1e-4)  # Sigma_0 = 10 Sigma + eps I
    expected = (1 - math.exp(-d / 2)) / 4  # the three exact keypoints contribute 0
    assert build_loss("pose")(pred, SQUARE, epoch=0).item() == pytest.approx(expected, rel=1e-12)
    paper = build_loss("pose", normalisation="paper")(pred, SQUARE, epoch=0).item()
    peak = 1 / (2 * math.pi * (10 * 0.04 + 1e-4))  # 1 / (2 pi |Sigma_t|^(1/2))
    assert paper == pytest.approx((3 * (1 - peak) + 1 - peak * math.exp(-d / 2)) / 4, rel=1e-12)


def test_pose_adaptive_loss_matches_numpy_on_a_tilted_drone():
    rng = np.random.default_rng(1)
    gt = torch.from_numpy(rng.uniform(0.2, 0.8, (3, 4, 2)))
    pred = gt + torch.from_numpy(rng.normal(0, 0.05, (3, 4, 2)))
    epoch = 37.5
    s = 10 * math.exp(-0.01 * 5 * epoch)
    expected = []
    for g, p in zip(gt.numpy(), pred.numpy(), strict=True):
        c = g - g.mean(0)
        inv = np.linalg.inv(s * c.T @ c / 4 + 1e-4 * np.eye(2))
        d = np.sqrt(np.einsum("ki,ij,kj->k", g - p, inv, g - p))
        expected.append(np.mean(1 - np.exp(-d / 2)))
    got = build_loss("pose")(pred, gt, epoch=epoch).item()
    assert got == pytest.approx(np.mean(expected), rel=1e-10)


def test_gaussian_and_mse_hand_values():
    pred = _shift_first(SQUARE, 0.1, 0.0)
    d = 0.1 / math.sqrt(10 + 1e-4)
    assert build_loss("gaussian")(pred, SQUARE).item() == pytest.approx((1 - math.exp(-d / 2)) / 4, rel=1e-12)
    assert build_loss("mse")(pred, SQUARE).item() == pytest.approx(0.01 / 8, rel=1e-12)


def test_mask_excludes_samples_without_a_drone():
    gt = SQUARE.repeat(2, 1, 1)
    pred = gt.clone()
    pred[1] += 0.3  # wildly wrong, but masked out
    loss = build_loss("pose")
    assert loss(pred, gt, 0, torch.tensor([True, False])).item() == 0.0
    pred.requires_grad_(True)
    empty = loss(pred, gt, 0, torch.tensor([False, False]))
    empty.backward()
    assert empty.item() == 0.0 and torch.all(pred.grad == 0)


def test_default_loss_is_bounded_and_the_papers_is_not():
    rng = torch.Generator().manual_seed(0)
    gt = torch.rand(64, 4, 2, generator=rng, dtype=torch.float64)
    for epoch in (0, 50, 100):
        for scale in (1e-3, 0.1, 10.0):
            pred = gt + scale * torch.randn(64, 4, 2, generator=rng, dtype=torch.float64)
            assert 0.0 <= build_loss("pose")(pred, gt, epoch).item() < 1.0
    # Eq. 11 verbatim in normalised units: late in training a good prediction scores far below 0.
    assert build_loss("pose", normalisation="paper")(SQUARE + 1e-3, SQUARE, epoch=100).item() < -1.0


@pytest.mark.parametrize("epoch", [0, 100])
def test_gradient_does_not_vanish_near_the_target(epoch):
    gt = SQUARE.clone()
    loss = MahalanobisLoss()
    for error in (1e-3, 1e-5, 1e-7):
        pred = _shift_first(gt, error, 0.0).requires_grad_(True)
        loss(pred, gt, epoch).backward()
        # Cone near 0: |dL/dx| = 1 / (2 sqrt(lambda)) / K for Sigma_t's eigenvalue lambda along x.
        lam = loss.scale(epoch) * 0.04 + 1e-4
        expected = 1 / (2 * math.sqrt(lam)) / 4
        assert pred.grad[0, 0, 0].item() == pytest.approx(expected, rel=0.05)
    perfect = gt.clone().requires_grad_(True)
    loss(perfect, gt, epoch).backward()
    assert torch.all(torch.isfinite(perfect.grad)) and torch.all(perfect.grad == 0)


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="name"):
        build_loss("huber")
    with pytest.raises(ValueError, match="normalisation"):
        build_loss("pose", normalisation="none")
    with pytest.raises(ValueError, match="gt must have the shape"):
        build_loss("pose")(torch.zeros(2, 4, 2), torch.zeros(3, 4, 2))
