"""Keypoint losses of the paper (§III-C, equations 7-11, Tab. V): pose-adaptive Mahalanobis, Gaussian
(identity covariance) and MSE, with the Fixed / Linear / Exp scale schedules.

Units. Keypoints are in normalised crop units (0 = the crop's left/top edge, 1 = its right/bottom
edge, see ``dronekey.geometry.crop``); a drone fills about 1/1.3 of its crop, so its keypoints spread over
about +-0.3 and the covariance of eq. 7 has eigenvalues of order 1e-2 (near 0 across the thin
axis of an edge-on drone). ``eps`` (eq. 9) is in the same units squared: the default 1e-4 is a
standard deviation of 0.01 crop, 1.3 px of a 128 px crop, so an edge-on drone's degenerate axis
still has a finite, sensible tolerance.

Normalisation (docs/design.md §7). Eq. 11 is L = E[1 - exp(-d_t / 2) / (2 pi |Sigma_t|^(1/2))]. Its
constant depends on the units: in pixels it is tiny and the loss is ~1 and flat; in these units
it grows as Sigma_t shrinks (S(t) -> 0.067 at epoch 100) and makes L negative and unbounded below
(down to 1 - 1 / (2 pi eps) = -1590). The default, ``normalisation="peak"``, divides the kernel by
its peak instead: L = E[1 - exp(-d_t / 2)], in [0, 1), zero only at a perfect prediction, the
same minimiser and the same shape of the paper's loss at each epoch. ``normalisation="paper"``
keeps eq. 11 verbatim for ablations.

Gradients. As the paper writes, the exponent holds the Mahalanobis distance d_t itself, not its
square: near a perfect prediction L ~ d_t / 2, a cone whose gradient keeps a constant magnitude
(|dL/de| = 1 / (2 sqrt(lambda)) along an eigenvector of Sigma_t with eigenvalue lambda), so
training does not stall close to the target as a squared-error kernel would. At exactly d_t = 0
the gradient is 0 instead of sqrt's NaN.
"""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = [
    "SCHEDULES",
    "KeypointLoss",
    "MSEKeypointLoss",
    "MahalanobisLoss",
    "build_loss",
    "keypoint_covariance",
    "scale_schedule",
]

SCHEDULES = ("fixed", "linear", "exp")
LOSSES = ("pose", "gaussian", "mse")
NORMALISATIONS = ("peak", "paper")


def scale_schedule(
    kind: str, epoch: float, alpha: float = 5.0, D: float = 10.0, total_epochs: int = 100
) -> float:
    """Covariance scale S(t) of eq. 9 and Tab. V at epoch ``t`` (0-based; fractions allowed).

    - ``"exp"``: S(t) = D exp(-0.01 alpha t) (the paper's).
    - ``"fixed"``: S(t) = D.
    - ``"linear"``: from D at t = 0 straight down to the exp schedule's final value
      D exp(-0.01 alpha T) at t = T = ``total_epochs`` (the paper does not say where its linear
      decay ends; same endpoints as exp, so the comparison is about the shape), held after T.
    """
    if kind not in SCHEDULES:
        raise ValueError(f"kind must be one of {SCHEDULES}, got {kind!r}")
    if epoch < 0:
        raise ValueError(f"epoch must be >= 0, got {epoch}")
    if D <= 0:
        raise ValueError(f"D must be > 0, got {D}")
    if kind == "fixed":
        return float(D)
    if kind == "exp":
        return float(D * math.exp(-0.01 * alpha * epoch))
    if total_epochs <= 0:
        raise ValueError(f"total_epochs must be > 0 for the linear schedule, got {total_epochs}")
    end = D * math.exp(-0.01 * alpha * total_epochs)
    return float(D + (end - D) * min(epoch / total_epochs, 1.0))


def keypoint_covariance(gt: torch.Tensor) -> torch.Tensor:
    """Eq. 7: covariance (1/K sum, not 1/(K-1)) of each sample's K ground-truth keypoints.

    gt : (B, K, 2) -> (B, 2, 2).
    """
    centred = gt - gt.mean(dim=1, keepdim=True)
    return centred.transpose(1, 2) @ centred / gt.shape[1]


def _safe_sqrt(x: torch.Tensor) -> torch.Tensor:
    """sqrt(x) for x >= 0 with gradient 0 (instead of NaN) where x == 0."""
    positive = x > 0
    return torch.where(
        positive, torch.sqrt(torch.where(positive, x, torch.ones_like(x))), torch.zeros_like(x)
    )


def _check_inputs(pred: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Validate shapes; return the boolean sample mask (all True when ``mask`` is None)."""
    if pred.dim() != 3 or pred.shape[-1] != 2:
        raise ValueError(f"pred must have shape (B, K, 2), got {tuple(pred.shape)}")
    if gt.shape != pred.shape:
        raise ValueError(f"gt must have the shape of pred {tuple(pred.shape)}, got {tuple(gt.shape)}")
    if mask is None:
        return torch.ones(pred.shape[0], dtype=torch.bool, device=pred.device)
    if mask.shape != (pred.shape[0],):
        raise ValueError(f"mask must have shape ({pred.shape[0]},), got {tuple(mask.shape)}")
    return mask.to(device=pred.device, dtype=torch.bool)


def _masked_mean(per_sample: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over the samples of ``mask``; an all-False mask gives 0 still attached to the graph."""
    if not bool(mask.any()):
        return per_sample.sum() * 0.0
    return per_sample[mask].mean()


class KeypointLoss(nn.Module):
    """Base of the keypoint losses: ``loss(pred, gt, epoch, mask) -> scalar``.

    pred, gt : (B, K, 2) normalised crop units. epoch : training epoch t (float allowed).
    mask : (B,) bool, the samples that hold a drone (others, e.g. drone-free crops trained only for
    presence, do not contribute); None = all.
    """

    def scale(self, epoch: float) -> float:
        """S(t) at ``epoch`` (1 for losses without a schedule); for logs and the paper's Fig. 5."""
        return 1.0

    def forward(
        self, pred: torch.Tensor, gt: torch.Tensor, epoch: float = 0.0, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        raise NotImplementedError


class MahalanobisLoss(KeypointLoss):
    """Pose-adaptive Mahalanobis loss (eqs. 7-11) or, with ``covariance="identity"``, the Gaussian loss.

    Parameters
    ----------
    covariance : {"pose", "identity"}
        Sigma of eq. 9: the ground truth's keypoint covariance (eq. 7) or the identity matrix.
    schedule : {"exp", "fixed", "linear"}
        How S(t) evolves (``scale_schedule``).
    alpha, D : float
        Decay and scale factors of S(t) = D exp(-0.01 alpha t); the paper's 5 and 10.
    total_epochs : int
        Length of training, for the linear schedule.
    eps : float
        Sigma_t = S(t) Sigma + eps I, squared normalised crop units (see the module notes).
    normalisation : {"peak", "paper"}
        "peak": L = 1 - exp(-d_t/2), bounded in [0, 1). "paper": eq. 11 verbatim, with the Gaussian's
        1 / (2 pi |Sigma_t|^(1/2)); unbounded below in these units.
    """

    def __init__(
        self,
        covariance: str = "pose",
        schedule: str = "exp",
        alpha: float = 5.0,
        D: float = 10.0,
        total_epochs: int = 100,
        eps: float = 1e-4,
        normalisation: str = "peak",
    ) -> None:
        super().__init__()
        if covariance not in ("pose", "identity"):
            raise ValueError(f"covariance must be 'pose' or 'identity', got {covariance!r}")
        if normalisation not in NORMALISATIONS:
            raise ValueError(f"normalisation must be one of {NORMALISATIONS}, got {normalisation!r}")
        if eps <= 0:
            raise ValueError(f"eps must be > 0, got {eps}")
        scale_schedule(schedule, 0.0, alpha, D, total_epochs)  # validates the schedule arguments
        self.covariance = covariance
        self.schedule = schedule
        self.alpha = float(alpha)
        self.D = float(D)
        self.total_epochs = int(total_epochs)
        self.eps = float(eps)
        self.normalisation = normalisation

    def scale(self, epoch: float) -> float:
        return scale_schedule(self.schedule, epoch, self.alpha, self.D, self.total_epochs)

    def distance(
        self, pred: torch.Tensor, gt: torch.Tensor, epoch: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Eq. 10: d_t per keypoint (B, K), and Sigma_t (B, 2, 2)."""
        if self.covariance == "pose":
            sigma = keypoint_covariance(gt)
        else:
            sigma = torch.eye(2, dtype=gt.dtype, device=gt.device).expand(gt.shape[0], 2, 2)
        eye = torch.eye(2, dtype=gt.dtype, device=gt.device)
        sigma_t = self.scale(epoch) * sigma + self.eps * eye
        # Closed-form inverse of the symmetric 2x2 matrix [[a, b], [b, c]] (cheaper than linalg.inv).
        a, b, c = sigma_t[:, 0, 0], sigma_t[:, 0, 1], sigma_t[:, 1, 1]
        det = a * c - b * b
        e = gt - pred
        ex, ey = e[..., 0], e[..., 1]
        squared = (c[:, None] * ex * ex - 2.0 * b[:, None] * ex * ey + a[:, None] * ey * ey) / det[:, None]
        return _safe_sqrt(squared), sigma_t

    def forward(
        self, pred: torch.Tensor, gt: torch.Tensor, epoch: float = 0.0, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        mask = _check_inputs(pred, gt, mask)
        d_t, sigma_t = self.distance(pred, gt, epoch)
        kernel = torch.exp(-0.5 * d_t)
        if self.normalisation == "paper":
            kernel = kernel / (2.0 * math.pi * torch.sqrt(torch.linalg.det(sigma_t)))[:, None]
        return _masked_mean((1.0 - kernel).mean(dim=1), mask)


class MSEKeypointLoss(KeypointLoss):
    """Mean squared error over keypoints and coordinates (Tab. V's baseline), normalised crop units."""

    def forward(
        self, pred: torch.Tensor, gt: torch.Tensor, epoch: float = 0.0, mask: torch.Tensor | None = None
    ) -> torch.Tensor:
        mask = _check_inputs(pred, gt, mask)
        return _masked_mean(((pred - gt) ** 2).mean(dim=(1, 2)), mask)


def build_loss(
    name: str = "pose",
    schedule: str = "exp",
    alpha: float = 5.0,
    D: float = 10.0,
    total_epochs: int = 100,
    eps: float = 1e-4,
    normalisation: str = "peak",
) -> KeypointLoss:
    """A loss of Tab. V by name: ``"pose"`` (pose-adaptive Mahalanobis), ``"gaussian"`` or ``"mse"``
    (which ignores the schedule arguments)."""
    if name not in LOSSES:
        raise ValueError(f"name must be one of {LOSSES}, got {name!r}")
    if name == "mse":
        return MSEKeypointLoss()
    return MahalanobisLoss(
        covariance="pose" if name == "pose" else "identity",
        schedule=schedule,
        alpha=alpha,
        D=D,
        total_epochs=total_epochs,
        eps=eps,
        normalisation=normalisation,
    )
