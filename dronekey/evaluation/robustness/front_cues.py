"""Which scored frames show the drone's front to the camera: what any heading reader can know.

The simulator draws each drone's body from its style seed (``sim_replay.drone_look``). Some bodies
show their front only from above the propeller plane (a gimbal on top, a battery bulge, a half
stripe: cues on the top shell), some from nowhere (``cue_free``, or none of the cues drawn), and
LEDs are no cue (``BodyShape.shows_front``). In a frame whose body shows no front to the camera,
front and back are a coin flip for any reader: an honest one says so, and its heading is still
half the time the twin, 90 deg of MAE-angle on average whatever it does. So the robustness table
also gives the angle over the frames that do show the front, where a heading read the wrong way
round is the reader's failure and not the view's.
"""

from __future__ import annotations

import numpy as np

from dronekey.sim_replay.drone_look import DroneLook

__all__ = ["camera_above", "front_shown"]


def camera_above(R_true: np.ndarray, t_true: np.ndarray) -> np.ndarray:
    """(N,) True where the camera is above the drone's propeller plane.

    ``R_true`` (N, 3, 3) body (FRD) -> camera and ``t_true`` (N, 3) the body origin in the camera
    frame (m), as the sequence JSON gives them. The camera sits at the origin, so it is above the
    plane when the vector to it, ``-t``, points against the body's z axis (down), ``R[:, :, 2]``.
    """
    R = np.asarray(R_true, dtype=np.float64).reshape(-1, 3, 3)
    t = np.asarray(t_true, dtype=np.float64).reshape(-1, 3)
    return np.einsum("ni,ni->n", t, R[:, :, 2]) > 0.0


def front_shown(info: dict, R_true: np.ndarray, t_true: np.ndarray) -> np.ndarray | None:
    """(N,) True where the drone's body shows its front to the camera, per scored frame.

    ``info`` is the sequence JSON's ``info`` (docs/design.md §5.1): the body is drawn again from its
    ``style_seed`` and ``cue_free``, as the simulator drew it for a one-drone sequence (the LED mode
    changes only the LEDs, which are no cue).
    None where ``info`` names no look (a drone-free sequence, or a file the simulator did not write
    or wrote before looks had seeds): there is nothing to tell.
    """
    style_seed = info.get("style_seed")
    if info.get("no_drone") or not isinstance(style_seed, int) or isinstance(style_seed, bool):
        return None
    look = DroneLook.draw(style_seed, "random", bool(info.get("cue_free", False)))
    above = camera_above(R_true, t_true)
    from_above, from_below = look.shape.shows_front(True), look.shape.shows_front(False)
    return np.where(above, from_above, from_below)
