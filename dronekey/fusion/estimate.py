"""The fused state of several cameras' observations of one drone.

Position: information-form least squares, ``x = (sum C_i^-1)^-1 sum C_i^-1 p_i`` with covariance
``(sum C_i^-1)^-1``. Each camera's covariance is long along its ray and narrow across it, so two
cameras at an angle pin the drone where their rays cross: the depth of one comes from the
bearing of the other. With one camera this is that camera's position (the fallback), unless an
earlier estimate is given as a prior (the fuser's depth memory): then the camera's bearing and the
prior's depth.

Velocity: the same weights. Orientation: body -> site rotations of the cameras, weighted by the
inverse of their rotation variance, averaged as quaternions (Markley's eigenvector mean). A drone
looks nearly the same from the front and the back, so each camera's rotation is first replaced by
its twin (a half turn about the body's vertical axis) when the twin is closer to the rotation of
the camera most sure of the heading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dronekey.fusion.observation import Observation
from dronekey.geometry.rotations import geodesic_angle_deg, matrix_to_quat_wxyz, quat_wxyz_to_matrix

__all__ = ["FusedState", "fuse_observations"]

_TWIN = np.diag([-1.0, -1.0, 1.0])  # half turn about body z (FRD: down), the front/back twin


@dataclass(frozen=True)
class FusedState:
    """The fused estimate at one time, site frame (see the module docstring)."""

    position_m: np.ndarray
    velocity_mps: np.ndarray
    position_cov: np.ndarray
    quaternion_wxyz: np.ndarray  # body (FRD) -> site
    rotation_std_rad: np.ndarray
    heading_confidence: float


def _position(
    observations: Sequence[Observation], prior: tuple[np.ndarray, np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    infos = [np.linalg.inv(o.position_cov) for o in observations]
    info = sum(infos)
    weighted = sum(i @ o.position_m for i, o in zip(infos, observations, strict=True))
    cov = np.linalg.inv(info)
    velocity = cov @ sum(i @ o.velocity_mps for i, o in zip(infos, observations, strict=True))
    if prior is not None:  # the prior weighs in on position only
        prior_info = np.linalg.inv(prior[1])
        weighted = weighted + prior_info @ prior[0]
        cov = np.linalg.inv(info + prior_info)
    cov = 0.5 * (cov + cov.T)
    return cov @ weighted, velocity, cov


def _orientation(observations: Sequence[Observation]) -> tuple[np.ndarray, np.ndarray, float]:
    reference = max(observations, key=lambda o: (o.heading_confidence, -o.rotation_var_rad2))
    R_ref = reference.R_site_body
    M = np.zeros((4, 4))
    total = 0.0
    for o in observations:
        R = o.R_site_body
        twin = R @ _TWIN
        if geodesic_angle_deg(R_ref, twin) < geodesic_angle_deg(R_ref, R):
            R = twin
        q = matrix_to_quat_wxyz(R)
        weight = 1.0 / o.rotation_var_rad2
        M += weight * np.outer(q, q)
        total += weight
    _, vectors = np.linalg.eigh(M)
    q = vectors[:, -1]
    q = q / np.linalg.norm(q)
    q = -q if q[0] < 0 else q
    std = np.full(3, float(np.sqrt(1.0 / total)))
    heading = max(o.heading_confidence for o in observations)
    return q, std, heading


def fuse_observations(
    observations: Sequence[Observation], prior: tuple[np.ndarray, np.ndarray] | None = None
) -> FusedState:
    """The fused state of observations of one drone at one time (at least one).

    ``prior``: (position, covariance), site frame, m: an earlier estimate of this drone predicted to
    this time, weighed in as one more position (not velocity) observation.
    """
    if not observations:
        raise ValueError("fuse_observations needs at least one observation, got none")
    position, velocity, cov = _position(observations, prior)
    q, std, heading = _orientation(observations)
    # normalise through a matrix round trip: the eigenvector may carry rounding off the unit sphere
    q = matrix_to_quat_wxyz(quat_wxyz_to_matrix(q))
    return FusedState(position, velocity, cov, q, std, heading)
