"""Coordinated flight: the attitude a multirotor needs to fly a given path.

The presets script the drone's position and, separately, its attitude (``flight="scripted"``), so a
scripted drone may slide sideways or hang level while accelerating. ``CoordinatedFlight`` keeps the
scripted positions and replaces the attitude by the one a real quadcopter would have on that path
(``flight="coordinated"`` in ``synthetic_sequence.build_sequence``, ``--flight coordinated`` in
``dronekey-sim``).

Frames and units: positions ``p`` are local North-East-Down (NED) metres, time in seconds, the body
frame is FRD (x forward, y right, z down) and ``R_ned_body`` maps body vectors to NED. Angles are
the aerospace intrinsic z-y'-x'' Euler angles (yaw, pitch, roll) in degrees, as
``dronekey.geometry.rotations.rotation_from_euler_deg`` takes them: yaw 0 faces north and 90 east, positive
pitch raises the nose, positive roll lowers the right side.

The maths
---------
Velocity and acceleration come from central finite differences of the position with a small step
``h`` (``step_s``)::

    v(t) = (p(t + h) - p(t - h)) / (2 h)
    a(t) = (p(t + h) - 2 p(t) + p(t - h)) / h^2

**Heading.** The nose points along the horizontal velocity: the target heading is
``psi* = atan2(v_E, v_N)`` while the horizontal speed ``|v_NE|`` is at least ``min_speed_mps``
(0.3 m/s); slower, the drone holds its last heading (a hovering drone does not spin to follow
position noise). The heading follows the target through a first-order filter with time constant
``tau`` (``heading_time_constant_s``), always turning the short way round::

    psi_k = psi_{k-1} + wrap(psi* - psi_{k-1}) * (1 - exp(-(t_k - t_{k-1}) / tau))

with ``wrap`` into [-180, 180) deg. The first frame starts from ``psi*`` if the drone moves fast
enough, else from the given initial heading (the preset's scripted yaw).

**Tilt.** A multirotor's thrust acts along its body -z axis. Newton's law ``m a = m g + T`` with
gravity ``g = (0, 0, 9.81)`` m/s^2 in NED gives the specific thrust ``T / m = a - g``, so the body
-z axis points along ``a - g`` and the body z axis along::

    z_b = (g - a) / |g - a|

In hover (``a = 0``) that is straight down: the drone is level. Accelerating north tilts ``z_b``
back (south), which pitches the nose down; the centripetal acceleration of a turn banks it into
the turn. Expressed in the heading frame (``z' = Rz(-psi) z_b``, x along the heading, y to its
right), the ZYX Euler angles that put the body z axis on ``z_b`` while keeping the yaw ``psi`` are::

    roll  phi   = -asin(z'_y)
    pitch theta = atan2(z'_x, z'_z)

because ``Ry(theta) Rx(phi) e_z = (cos(phi) sin(theta), -sin(phi), cos(phi) cos(theta))``. The tilt
(the angle between ``z_b`` and the vertical) is limited to ``max_tilt_deg``; a path asking for
more (or for more than 1 g downwards) is flown at that limit, and one with no horizontal
direction to tilt towards is flown level.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["FLIGHT_MODELS", "GRAVITY_MPS2", "CoordinatedFlight", "finite_differences", "tilt_for_thrust"]

GRAVITY_MPS2 = 9.81
# ``flight`` of synthetic_sequence.build_sequence / --flight of dronekey-sim: the preset's own
# attitude script, or the attitude of coordinated flight along the preset's positions.
FLIGHT_MODELS = ("scripted", "coordinated")

Position = Callable[[float], np.ndarray]


def finite_differences(
    position: Position, times_s: Sequence[float] | np.ndarray, step_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and acceleration of a path by central differences.

    Parameters
    ----------
    position : callable
        ``position(t)`` -> (3,) NED metres at time ``t`` seconds; called at ``t - h``, ``t``, ``t + h``.
    times_s : sequence of float
        Times, seconds.
    step_s : float
        Difference step ``h``, seconds (> 0).

    Returns
    -------
    velocity, acceleration : (N, 3) arrays
        NED, m/s and m/s^2.
    """
    if not step_s > 0:
        raise ValueError(f"step_s must be positive, got {step_s!r}")
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    v = np.zeros((len(times), 3))
    a = np.zeros((len(times), 3))
    for k, t in enumerate(times):
        before = np.asarray(position(t - step_s), dtype=np.float64)
        here = np.asarray(position(t), dtype=np.float64)
        after = np.asarray(position(t + step_s), dtype=np.float64)
        v[k] = (after - before) / (2.0 * step_s)
        a[k] = (after - 2.0 * here + before) / step_s**2
    return v, a


def tilt_for_thrust(
    yaw_deg: float, accel_ned: np.ndarray, gravity_mps2: float = GRAVITY_MPS2, max_tilt_deg: float = 60.0
) -> tuple[float, float]:
    """Pitch and roll (degrees) that align the thrust (body -z) with ``a - g`` at heading ``yaw_deg``.

    Parameters
    ----------
    yaw_deg : float
        Heading of the body x axis, degrees (0 north, 90 east).
    accel_ned : (3,) array
        Acceleration of the drone in NED, m/s^2.
    gravity_mps2 : float
        Gravity, m/s^2 (along +z, down, in NED).
    max_tilt_deg : float
        Largest angle between the body z axis and the vertical, degrees.

    Returns
    -------
    pitch_deg, roll_deg : float
        ZYX Euler angles with ``yaw_deg`` (see the module docstring).
    """
    z_b = np.array([0.0, 0.0, gravity_mps2]) - np.asarray(accel_ned, dtype=np.float64).reshape(3)
    horizontal = float(np.hypot(z_b[0], z_b[1]))
    tilt = math.atan2(horizontal, z_b[2])  # 0 level, pi/2 on its side, > pi/2 upside down
    max_tilt = math.radians(max_tilt_deg)
    if horizontal < 1e-12:  # straight up or down: no direction to tilt towards, fly level
        z_b = np.array([0.0, 0.0, 1.0])
    else:
        tilt = min(tilt, max_tilt)
        direction = z_b[:2] / horizontal
        z_b = np.array([direction[0] * math.sin(tilt), direction[1] * math.sin(tilt), math.cos(tilt)])
    psi = math.radians(yaw_deg)
    c, s = math.cos(psi), math.sin(psi)
    z_heading = np.array([c * z_b[0] + s * z_b[1], -s * z_b[0] + c * z_b[1], z_b[2]])  # Rz(-psi) z_b
    roll = -math.asin(float(np.clip(z_heading[1], -1.0, 1.0)))
    pitch = math.atan2(z_heading[0], z_heading[2])
    return math.degrees(pitch), math.degrees(roll)


def _wrap_deg(angle: float) -> float:
    return (angle + 180.0) % 360.0 - 180.0


@dataclass(frozen=True)
class CoordinatedFlight:
    """The coordinated-flight attitude model (module docstring).

    Parameters
    ----------
    min_speed_mps : float
        Horizontal speed (m/s) below which the heading is held.
    heading_time_constant_s : float
        Time constant of the heading filter, seconds (0: the heading snaps to the velocity).
    max_tilt_deg : float
        Largest tilt from level, degrees, in (0, 90].
    step_s : float
        Finite-difference step, seconds.
    gravity_mps2 : float
        Gravity, m/s^2.
    """

    min_speed_mps: float = 0.3
    heading_time_constant_s: float = 0.2
    max_tilt_deg: float = 60.0
    step_s: float = 0.01
    gravity_mps2: float = GRAVITY_MPS2

    def __post_init__(self) -> None:
        if not self.min_speed_mps >= 0:
            raise ValueError(f"min_speed_mps must be >= 0, got {self.min_speed_mps!r}")
        if not self.heading_time_constant_s >= 0:
            raise ValueError(f"heading_time_constant_s must be >= 0, got {self.heading_time_constant_s!r}")
        if not 0 < self.max_tilt_deg <= 90:
            raise ValueError(f"max_tilt_deg must be in (0, 90], got {self.max_tilt_deg!r}")
        if not self.step_s > 0:
            raise ValueError(f"step_s must be positive, got {self.step_s!r}")
        if not self.gravity_mps2 > 0:
            raise ValueError(f"gravity_mps2 must be positive, got {self.gravity_mps2!r}")

    def attitudes(
        self,
        velocities: np.ndarray,
        accelerations: np.ndarray,
        times_s: Sequence[float] | np.ndarray,
        initial_yaw_deg: float = 0.0,
    ) -> np.ndarray:
        """The coordinated-flight attitude at each sample of a path.

        Parameters
        ----------
        velocities, accelerations : (N, 3) arrays
            NED, m/s and m/s^2.
        times_s : (N,) sequence of float
            Sample times, seconds, not decreasing. The heading filter runs through the samples in
            order, so the first k attitudes do not depend on the samples after them.
        initial_yaw_deg : float
            Heading before the first sample, degrees (held while the drone is slow).

        Returns
        -------
        (N, 3) array
            Yaw, pitch, roll in degrees (ZYX, ``rotation_from_euler_deg`` gives ``R_ned_body``).
        """
        v = np.asarray(velocities, dtype=np.float64).reshape(-1, 3)
        a = np.asarray(accelerations, dtype=np.float64).reshape(-1, 3)
        times = np.asarray(times_s, dtype=np.float64).reshape(-1)
        if not len(v) == len(a) == len(times):
            raise ValueError(
                f"velocities, accelerations and times_s must have one row per sample, got "
                f"{len(v)}, {len(a)} and {len(times)}"
            )
        if np.any(np.diff(times) < 0):
            raise ValueError("times_s must not decrease")
        out = np.zeros((len(times), 3))
        yaw = _wrap_deg(float(initial_yaw_deg))
        for k in range(len(times)):
            speed = float(np.hypot(v[k, 0], v[k, 1]))
            if speed >= self.min_speed_mps and speed > 0:
                target = math.degrees(math.atan2(v[k, 1], v[k, 0]))
                if k == 0 or self.heading_time_constant_s == 0:
                    gain = 1.0
                else:
                    gain = 1.0 - math.exp(-(times[k] - times[k - 1]) / self.heading_time_constant_s)
                yaw = _wrap_deg(yaw + _wrap_deg(target - yaw) * gain)
            pitch, roll = tilt_for_thrust(yaw, a[k], self.gravity_mps2, self.max_tilt_deg)
            out[k] = (yaw, pitch, roll)
        return out

    def attitudes_along(
        self, position: Position, times_s: Sequence[float] | np.ndarray, initial_yaw_deg: float = 0.0
    ) -> np.ndarray:
        """The coordinated-flight attitude along a path given as a function of time.

        Parameters
        ----------
        position : callable
            ``position(t)`` -> (3,) NED metres at ``t`` seconds, differentiated with ``step_s``.
        times_s : (N,) sequence of float
            Sample times, seconds, not decreasing.
        initial_yaw_deg : float
            Heading before the first sample, degrees.

        Returns
        -------
        (N, 3) array
            Yaw, pitch, roll in degrees, as ``attitudes``.
        """
        v, a = finite_differences(position, times_s, self.step_s)
        return self.attitudes(v, a, times_s, initial_yaw_deg)
