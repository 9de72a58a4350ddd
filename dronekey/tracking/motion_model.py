"""The two filters' shared motion model: a state of three values and their rates, one step of
``dt`` seconds (position and velocity in m, m/s; an orientation error and its angular velocity in
rad, rad/s).

Both matrices depend only on the step and the noise level, which a camera repeats every frame, so
they are built once per value and shared, read-only: filterpy's ``predict`` only reads them.
"""

from __future__ import annotations

import functools

import numpy as np
from filterpy.common import Q_discrete_white_noise

__all__ = ["transition", "white_noise_acceleration"]

_CACHED_STEPS = 64  # a file's frame times repeat a few steps; a live clock's rarely repeat


@functools.lru_cache(maxsize=_CACHED_STEPS)
def transition(dt: float, tau: float = 0.0) -> np.ndarray:
    """(6, 6) state transition over ``dt`` seconds, read-only. ``tau`` (s): the rates' time
    constant, a first-order Gauss-Markov decay ``rate <- a rate``, ``a = exp(-dt / tau)``, the value
    moving by ``tau (1 - a) rate``; 0 keeps the rates constant (the value moves by ``dt rate``)."""
    F = np.eye(6)
    if tau > 0.0:
        a = float(np.exp(-dt / tau))
        F[:3, 3:] = tau * (1.0 - a) * np.eye(3)
        F[3:, 3:] = a * np.eye(3)
    else:
        F[:3, 3:] = dt * np.eye(3)
    F.flags.writeable = False
    return F


@functools.lru_cache(maxsize=_CACHED_STEPS)
def white_noise_acceleration(dt: float, var: float) -> np.ndarray:
    """(6, 6) process noise over ``dt`` seconds of a white acceleration of variance ``var`` per
    axis, constant over the step (filterpy's discrete model, values first, rates after), read-only:
    ``var [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` per axis."""
    Q = Q_discrete_white_noise(2, dt=dt, var=var, block_size=3, order_by_dim=False)
    Q.flags.writeable = False
    return Q
