"""The filters' shared motion model, built once per step, and the orientation kept per state."""

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise

from dronekey.tracking.motion_model import transition, white_noise_acceleration
from dronekey.tracking.orientation_filter import OrientationFilter, rotation_exp


def test_white_noise_is_filterpys_and_shared_read_only():
    Q = white_noise_acceleration(1 / 30, 4.0)
    assert np.array_equal(Q, Q_discrete_white_noise(2, dt=1 / 30, var=4.0, block_size=3, order_by_dim=False))
    assert white_noise_acceleration(1 / 30, 4.0) is Q
    with pytest.raises(ValueError, match="read-only"):
        Q[0, 0] = 1.0


def test_transition_moves_values_by_their_rates():
    F = transition(0.1)
    assert np.array_equal(F @ np.array([1.0, 2.0, 3.0, 10.0, 0.0, -10.0]), [2.0, 2.0, 2.0, 10.0, 0.0, -10.0])
    assert not F.flags.writeable and transition(0.1) is F
    decaying = transition(0.1, tau=0.5)
    a = np.exp(-0.1 / 0.5)
    assert decaying[3, 3] == pytest.approx(a) and decaying[0, 3] == pytest.approx(0.5 * (1 - a))


def test_orientation_rotation_follows_every_change_and_is_the_callers_own():
    start = rotation_exp(np.array([0.1, -0.2, 0.3]))
    f = OrientationFilter(start, 0.01 * np.eye(3), 1.0, 2.0)
    R = f.rotation
    R[:] = 0.0  # the caller's copy: the filter's rotation is unchanged
    assert np.array_equal(f.rotation, start @ rotation_exp(np.zeros(3)))
    target = rotation_exp(np.array([0.1, -0.2, 0.6]))
    f.predict(0.1)  # correlates the angle with its rate, so that the update gives a rate
    f.update(target, 1e-4 * np.eye(3))
    after_update = f.rotation
    assert np.degrees(np.arccos((np.trace(after_update.T @ target) - 1) / 2)) < 1.0
    f.predict(0.5)  # the update left an angular velocity: the rotation turns on
    assert not np.array_equal(f.rotation, after_update)
