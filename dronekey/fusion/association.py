"""Whether two cameras' observations are the same drone: the gate and the cost.

Two tests, both scaled by the observations' covariances (``FusionConfig``):

- the positions' squared Mahalanobis distance with the two covariances summed: each camera's
  depth is uncertain along its own ray, so two estimates of one drone may differ by metres in depth
  and still match, but not across the rays;
- the viewing rays' closest approach: the rays from the two camera centres through the two
  estimates meet, up to the covariance across both rays. (Where they cross is left to the first
  test: nearly parallel rays of a far drone may cross behind the cameras on noise alone.)

The cost of a match is the Mahalanobis term; a pair that fails either test costs ``math.inf``.
"""

from __future__ import annotations

import math

import numpy as np

from dronekey.fusion.config import FusionConfig
from dronekey.fusion.observation import Observation

__all__ = ["pair_cost", "ray_closest_approach"]

_PARALLEL = 1e-9  # |u_a x u_b| below which two rays are parallel (no meeting point to test)


def ray_closest_approach(a: Observation, b: Observation) -> tuple[float, np.ndarray]:
    """(distance, unit common normal) of the rays ``c + s u`` of ``a`` and ``b``: their
    closest-approach distance (m) and the direction it is measured along; (nan, zeros) for
    parallel rays."""
    n = np.cross(a.ray_direction, b.ray_direction)
    nn = float(np.linalg.norm(n))
    if nn < _PARALLEL:
        return math.nan, np.zeros(3)
    n = n / nn
    return abs(float((a.camera_centre_m - b.camera_centre_m) @ n)), n


def pair_cost(a: Observation, b: Observation, config: FusionConfig, scale: float = 1.0) -> float:
    """Squared Mahalanobis distance of ``a`` and ``b`` if they pass both gates (times ``scale``),
    else ``math.inf``; observations of one camera never match."""
    if a.camera_id == b.camera_id:
        return math.inf
    cov = a.position_cov + b.position_cov
    d = a.position_m - b.position_m
    try:
        m2 = float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        return math.inf
    if not m2 <= config.gate_mahalanobis2 * scale:
        return math.inf
    distance, normal = ray_closest_approach(a, b)
    if math.isfinite(distance):
        var_across = float(normal @ cov @ normal)
        if not distance**2 <= config.gate_ray2 * scale * var_across:
            return math.inf
    return m2
