"""Undo the keypoint network's occasional order flips with the track's prediction.

The four propellers form a near-rectangle, so the network's hard failure is not a misplaced
propeller but a permuted one: front and back exchanged (its most common error), left and right,
or both (docs/design.md §7). A permuted set still fits a pose, about 180 deg away from the true one
(four coplanar points: the mirror image is the same points rotated about an in-plane axis), so
neither the PnP residual nor, for one frame, the tracker's gate can tell. What can is time: while a
track lives, its predicted pose projects where each propeller should be, and the detection's
order that fits that projection is the right one.

Trusting the track blindly would make a track born from a flipped detection keep its flip
forever. So ``KeypointOrder`` keeps a short history of which order fits the prediction best, and
re-orders a detection only while most of the recent detections agreed with the track unpermuted
(the flip is then the detection's, not the track's). When the history says the track is the
one that is flipped, detections pass unchanged and the tracker's gating and lifecycle replace it.
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from dronekey.types import KeypointDetection

__all__ = ["HEADING_TWIN", "SYMMETRIES", "KeypointOrder", "front_axis_turn", "reordered"]

# The keypoint rectangle's symmetries (order 1 FR, 2 RR, 3 RL, 4 FL): identity, front/back,
# left/right, both (a 180 deg turn).
SYMMETRIES = ((0, 1, 2, 3), (1, 0, 3, 2), (3, 2, 1, 0), (2, 3, 0, 1))
# The 180-degree twin (front and back exchanged by a half turn about the body's vertical axis):
# the symmetry no geometry can tell apart, only the drone's look (the front/back head).
HEADING_TWIN = list(SYMMETRIES[3])
_SYMMETRY_INDEX = np.array(SYMMETRIES)  # (4, 4): every symmetry's order, for one fancy index


def front_axis_turn(order) -> int:
    """How a re-ordering (a permutation of the four hubs) turns the front axis (rear hubs' midpoint
    -> front hubs' midpoint, hubs 1 and 4 at the front): +1 kept (left/right), -1 reversed
    (front/back, the half turn: the front/back classifier's ``p`` becomes ``1 - p``), 0 a quarter
    turn or a diagonal reflection (its ``p`` says nothing about the new order's front)."""
    axis = np.array([1, -1, -1, 1])  # the front axis as weights of the hubs, spec order
    weights = np.zeros(4)
    for new_index, old_index in enumerate(order):
        weights[old_index] += axis[new_index]
    return int(round(weights @ axis / 4.0))


def reordered(detection: KeypointDetection, order) -> KeypointDetection:
    """``detection`` with its keypoints in ``order`` (new keypoint i = old ``order[i]``) and the
    front/back classifier's ``heading_p``, which speaks of the order it saw, carried with its
    front: ``1 - p`` where the front axis reverses (the heading twin, a front/back exchange)."""
    heading_p = detection.heading_p
    if front_axis_turn(order) < 0:
        heading_p = 1.0 - heading_p
    return replace(detection, keypoints_px=detection.keypoints_px[list(order)], heading_p=heading_p)


class KeypointOrder:
    """Re-orders detected keypoints to fit a track's predicted keypoints.

    Parameters
    ----------
    window : int
        Detections remembered (the last ``window`` verdicts of which order fits the prediction).
    min_history : int
        Verdicts needed before any detection is re-ordered (a young track has not earned trust).
    clear_ratio : float
        A permutation counts only when its mean distance to the prediction is below this fraction
        of the unpermuted order's (and vice versa for "agrees")...
    min_gain_px : float
        ...and differs from it by more than this many pixels (mean over the keypoints). Ambiguous
        frames (a drone seen head-on or edge-on, where two orders nearly coincide) do not vote
        and are not changed.
    """

    def __init__(
        self, window: int = 15, min_history: int = 5, clear_ratio: float = 0.5, min_gain_px: float = 3.0
    ) -> None:
        if window < 1 or not 1 <= min_history <= window:
            raise ValueError(f"need 1 <= min_history <= window, got {min_history} and {window}")
        if not 0 < clear_ratio < 1:
            raise ValueError(f"clear_ratio must be in (0, 1), got {clear_ratio}")
        self.min_history, self.clear_ratio, self.min_gain_px = min_history, clear_ratio, min_gain_px
        self._verdicts: deque[int] = deque(maxlen=window)
        self.reordered = 0  # detections re-ordered since construction, for logs and tests

    def reset(self) -> None:
        """Forget the history (no track any more, or another track)."""
        self._verdicts.clear()

    def apply(self, keypoints_px: np.ndarray, predicted_px: np.ndarray) -> tuple[np.ndarray, int]:
        """The detection's keypoints in the order that fits the prediction, and the symmetry used.

        Parameters
        ----------
        keypoints_px : (4, 2) detected keypoints, full-frame pixels, in the network's order.
        predicted_px : (4, 2) the track's predicted keypoints, same frame and units.

        Returns
        -------
        keypoints : (4, 2), re-ordered when the history trusts the track, else unchanged.
        symmetry : index into ``SYMMETRIES`` applied (0: none).
        """
        kp = np.asarray(keypoints_px, dtype=np.float64)
        pred = np.asarray(predicted_px, dtype=np.float64)
        if not (np.all(np.isfinite(kp)) and np.all(np.isfinite(pred))):
            return kp, 0
        dist = np.linalg.norm(kp[_SYMMETRY_INDEX] - pred, axis=2).mean(axis=1)  # (4,): per symmetry
        best = int(np.argmin(dist))
        runner_up = float(np.min(np.delete(dist, best)))
        if dist[best] >= self.clear_ratio * runner_up or runner_up - dist[best] <= self.min_gain_px:
            return kp, 0  # ambiguous: no vote, no change
        if best == 0:
            self._verdicts.append(0)
            return kp, 0
        history = len(self._verdicts)
        trusted = history >= self.min_history and 2 * self._verdicts.count(0) > history
        self._verdicts.append(best)
        if not trusted:
            return kp, 0
        self.reordered += 1
        return kp[list(SYMMETRIES[best])], best
