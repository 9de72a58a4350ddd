"""Front and back: a track's two heading hypotheses (the heading twin) and how measurements move them.

Four propeller hubs fit two poses 180 deg apart about the body's vertical axis equally well; only
the drone's look (the network's front/back head, ``heading_p``) or its flight can tell them apart.
Each track keeps both hypotheses as the log-odds ``L`` that the front it follows is the drone's
front (``TrackRecord.heading_log_odds``): a measurement is first turned to whichever of its pose
and its twin is nearer the track (its ``heading_p`` with it), then adds
``heading_evidence_weight * logit(heading_p)`` (frames are correlated, so each counts for less than
one independent vote), clipped to ``+-heading_confidence_cap``. When ``L`` falls below
``-heading_switch_log_odds`` the track turns to the twin and ``L`` changes sign. The published
``Track.heading_confidence`` is ``tanh(L / 2) = 2 q - 1`` with ``q = sigmoid(L)`` (0: a coin flip,
1: certain), and the orientation covariance gains the two-point mixture's variance
``q (1 - q) pi^2`` about the body's vertical axis, so a coin flip reads as pi / 2 rad of yaw
doubt, never as a confident heading. Measurements without a heading probability (NaN: a model with
no front/back head) leave ``L`` alone and the confidence unknown (NaN).
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from dronekey.tracking.track_record import TrackRecord
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement

__all__ = ["twin_measurement", "twin_of", "update_heading"]

log = logging.getLogger(__name__)

_HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])  # 180 deg about the body's z axis


def twin_of(R: np.ndarray) -> np.ndarray:
    """The body -> camera rotation of the heading twin: the same drone turned 180 deg about its
    vertical (FRD z) axis, which maps the hubs 1 2 3 4 onto 3 4 1 2."""
    return np.asarray(R) @ _HALF_TURN_Z


def twin_measurement(m: PoseMeasurement) -> PoseMeasurement:
    """``m`` with its rotation (and the IPPE alternative's) turned to the heading twin."""
    alt = m.alternative
    if alt is not None:
        alt = (twin_of(alt[0]), alt[1], alt[2])
    return replace(m, R=twin_of(m.R), alternative=alt)


def update_heading(
    track: TrackRecord, m: PoseMeasurement, heading_p: float, config: TrackerConfig
) -> tuple[PoseMeasurement, float]:
    """Turn ``m`` to the track's front (or its twin, whichever is nearer the track), fold its
    front/back evidence, and turn the track around when the evidence says its front is the back.
    Returns the measurement as the track should use it, and its ``heading_p``."""
    cfg = config
    R_track = track.orientation.rotation
    if not math.isfinite(heading_p):  # no front/back head: the order is the network's, as it is
        return m, heading_p
    if _angle(R_track, twin_of(m.R)) < _angle(R_track, m.R):
        m = twin_measurement(m)
        heading_p = 1.0 - heading_p
    track.add_heading_evidence(heading_p, cfg.heading_evidence_weight)
    if cfg.heading_from_motion > 0:
        track.add_heading_evidence(_nose_first_p(R_track, track.position.velocity_mps, cfg), 1.0, look=False)
    if track.heading_log_odds is not None and track.heading_log_odds < -cfg.heading_switch_log_odds:
        log.info("track %d: turned around (front/back log-odds %.1f)", track.track_id, track.heading_log_odds)
        track.reinitialise_orientation(twin_of(R_track), m.covariance[3:, 3:], cfg)
        track.turn_heading_around()
        m = twin_measurement(m)
    return m, heading_p


def _nose_first_p(R: np.ndarray, velocity: np.ndarray, config: TrackerConfig) -> float:
    """Probability that the followed front is right, from the nose-first prior on the velocity."""
    up = R[:, 2]  # body z (down) in the camera frame: the drone's own vertical
    v = np.asarray(velocity, dtype=np.float64)
    v_h = v - (v @ up) * up
    speed = float(np.linalg.norm(v_h))
    if speed < 1e-6:
        return 0.5
    log_odds = config.heading_from_motion * float(R[:, 0] @ v_h / speed) * min(1.0, speed / 2.0)
    return 1.0 / (1.0 + math.exp(-log_odds))


def _angle(A: np.ndarray, B: np.ndarray) -> float:
    """Rotation angle (rad) between two rotation matrices."""
    c = (np.trace(np.asarray(A).T @ np.asarray(B)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))
