"""A measurement's rotation into a track: which IPPE solution it follows, the rotation gate, resets.

Of a measurement's two solutions (``R`` and ``alternative``), the track is updated with the one
nearer its own orientation, if it passes ``rotation_gate_chi2``. Planar PnP cannot always tell the
two apart in one frame, and the estimator follows the track's prediction when it cannot, so a
track that started on the wrong solution would stay there. Each track therefore keeps the log-odds
that the solution it does *not* follow is the right one (``TrackRecord.branch_evidence``): it
starts at 0 (no preference) and adds, every frame, the log-likelihood ratio
``(SSR_own - SSR_other) / (2 sigma^2)`` (SSR: summed squared reprojection error of the four
keypoints, sigma: the measurement's ``keypoint_sigma_px``). Above ``branch_switch_log_odds`` the
track's orientation is re-initialised on the other solution and the log-odds change sign (the two
swap roles). They are floored at ``-branch_confidence_cap`` so that no amount of agreement makes a
track deaf to later evidence. Frames that cannot tell the solutions apart add nothing.

A rotation that fails the gate with no usable alternative is skipped (the position is still used);
after ``rotation_reset_after`` in a row the orientation is re-initialised from the measurement, and
``update_orientation`` says so (the caller may restart the front/back evidence with it).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from dronekey.tracking.track_record import TrackRecord
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PoseMeasurement

__all__ = ["update_orientation"]

log = logging.getLogger(__name__)


def update_orientation(track: TrackRecord, m: PoseMeasurement, config: TrackerConfig) -> bool:
    """Fold the rotation of ``m`` (already turned to the track's front) into the track's
    orientation, switching IPPE solutions or re-initialising as the evidence says. Returns True
    when the orientation was re-initialised on ``m`` after gated-out rotations (the track then
    follows the measurement's front, not the one its front/back evidence was gathered for)."""
    cfg = config
    rot_cov = m.covariance[3:, 3:]
    branches = [(m.R, m.reprojection_px)]
    if m.alternative is not None:
        branches.append((m.alternative[0], m.alternative[2]))
    d2 = [track.orientation.mahalanobis_sq(R, rot_cov) for R, _ in branches]
    own = int(np.argmin(d2))
    if len(branches) == 2 and math.isfinite(m.keypoint_sigma_px) and m.keypoint_sigma_px > 0:
        other_R, other_px = branches[1 - own]
        log_odds = 2.0 * (branches[own][1] ** 2 - other_px**2) / m.keypoint_sigma_px**2
        track.branch_evidence = max(-cfg.branch_confidence_cap, track.branch_evidence + log_odds)
        if track.branch_evidence > cfg.branch_switch_log_odds:
            evidence = track.branch_evidence
            log.info(
                "track %d: switched to the other IPPE solution (evidence %.1f)",
                track.track_id,
                track.branch_evidence,
            )
            track.reinitialise_orientation(other_R, rot_cov, cfg)
            track.branch_evidence = -evidence  # own and other swap roles
            return False
    if d2[own] <= cfg.rotation_gate_chi2:
        track.orientation.update(branches[own][0], rot_cov)
        track.rotation_misses = 0
        return False
    track.rotation_misses += 1
    log.debug("track %d: rotation gated out (d2 = %.1f)", track.track_id, d2[own])
    if track.rotation_misses >= cfg.rotation_reset_after:
        log.info(
            "track %d: orientation re-initialised after %d gated-out rotations",
            track.track_id,
            track.rotation_misses,
        )
        track.reinitialise_orientation(m.R, rot_cov, cfg)
        return True
    return False
