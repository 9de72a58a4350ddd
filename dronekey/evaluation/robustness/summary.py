"""The figures of ``dronekey-eval robustness``, pooled over the frames of a group of sequences.

Per sequence and per group (a frame-weighted average over the scored frames, ``scoring``):

- detected %: annotated frames with a drone's track, percent of the annotated frames;
- MAE-angle (deg), RMSE (m), MAE-absolute (m): the paper's errors (``evaluation.pose.pose_errors``)
  of the drone's track over the detected frames, and MAE-angle up to the heading twin (front and
  back set aside);
- AP^kp (percent): COCO keypoint AP of the pipeline's best detection of every annotated frame (its
  presence as the score; a frame without detection is a miss) against the annotated keypoints,
  as ``dronekey-eval pose`` computes it (full-frame pixels, OKS area = annotated box area);
- false-track frames: scored frames holding a false track, also per 1,000 scored frames, and the
  number of distinct track ids that were ever such a track; and the same for the false tracks
  off the drone's line of sight alone (clutter, or a drone's track that coasted away; the rest are
  the drone read at a wrong range);
- confident wrong heading %: annotated frames whose drone's track has a wrong heading with
  confidence, percent of the annotated frames; ``wrong_heading_pct`` is the same share at any
  confidence; ``confident_right_heading_pct`` the share whose track is right and says so (what the
  pipeline's doubt costs: never being sure would make the confident-wrong share 0);
- the view: ``front_away_pct``, the annotated frames whose drone points its front away from the
  camera (its forward axis has a positive component along the optical axis), and the confident
  wrong heading % among those frames and among the others (front towards the camera, or square
  across the view). A heading reader that follows the end nearer the camera is wrong with the
  front away and right with it towards; one misled by the look (livery, light) is wrong whichever
  way the front points. Without the split, a matrix whose drones mostly point their front away
  makes the second look like the first;
- why frames were missed, percent of the annotated frames (with detected % they add up to 100):
  the drone read at a wrong range by a published track, held by a tentative track that was not
  confirmed, or not held at all;
- front/back per detection: of the frames whose best detection is the drone's with a decided
  keypoint order and an answer from the front/back classifier, the percent where it favoured the
  true order. The tracker adds these answers up, so this says whether a wrong heading is the
  classifier's or the tracker's;
- axis exchanged per detection: of the frames whose best detection is the drone's with a clearly
  decided kind of order (``scoring.axis_exchanged``), the percent whose order exchanges the body's
  front/back and left/right axes (a quarter turn): such a detection reads the drone at a wrong
  range, whatever the front/back classifier says;
- keypoint error: the median distance (px) of the drone's detections' keypoints from their hubs,
  the order taken up to the front/back twin (``scoring.keypoint_error_px``): the pixel precision
  to set beside ``--oracle-noise`` (noise of sigma px per coordinate is 1.18 sigma px here);
- range doubt: of the frames with a published track on the drone (``scoring.range_z``), the
  percent whose true range lies within one and within two of the standard deviations the track's
  ``position_cov`` states along its line of sight (an honest Gaussian doubt: 68 and 95); and the
  percent whose true position lies within two standard deviations of the whole covariance
  (``scoring.position_m2`` <= 8.02, 95.4 for an honest Gaussian in 3 dof), the measured frames
  (``position_within_2sd_measured_pct``) and the coasting ones (``position_within_2sd_coasting_pct``,
  over ``coasting_frames``) apart: a track that coasts must widen its doubt as fast as its error grows;
- the front shown: ``front_shown_pct``, the annotated frames whose drone's body shows its front to
  the camera (``front_cues``), and ``mae_angle_front_shown_deg``, MAE-angle over the detected frames
  among them. Where the body shows no front, front and back are a coin flip for any reader (90 deg
  on average, however honest its doubt), so this is the angle a reader is answerable for; the
  table's MAE-angle, which the accuracy bar reads, counts every detected frame. None where a
  sequence does not name its look.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dronekey.evaluation.metrics import ap_kp
from dronekey.evaluation.pose import pose_errors, rounded
from dronekey.evaluation.robustness.scoring import SequenceScores, keypoint_error_px

__all__ = ["summarise"]

_CHI2_3DOF_2SD = 8.02  # chi-square, 3 degrees of freedom, at the 95.4 % of two standard deviations


def _pct(count: int, total: int) -> float:
    return 100.0 * count / total if total else float("nan")


def summarise(scores: Sequence[SequenceScores]) -> dict:
    """The metrics of the module's notes over the pooled frames of ``scores``.

    Returns
    -------
    dict with ``sequences``, ``frames`` (scored), ``detected_frames``, ``detected_pct``,
    ``mae_angle_deg``, ``rmse_m``, ``mae_abs_m``, ``mae_angle_up_to_twin_deg``, ``ap_kp``
    (percent), ``false_track_frames``, ``false_tracks_per_1000_frames``, ``false_track_ids``,
    ``off_sight_track_frames``, ``off_sight_tracks_per_1000_frames``, ``off_sight_track_ids`` (the false
    tracks off the drone's line of sight),
    ``confident_wrong_heading_frames``, ``confident_wrong_heading_pct``, ``wrong_heading_frames``,
    ``wrong_heading_pct`` (any confidence), ``confident_right_heading_frames``,
    ``confident_right_heading_pct``, ``missed_wrong_range_pct``, ``missed_unconfirmed_pct``,
    ``missed_unseen_pct``, ``front_back_frames``, ``front_back_right_pct``, ``axis_frames``,
    ``axis_exchanged_pct``, ``kp_err_px_median``, ``range_doubt_frames``, ``range_within_1sd_pct``,
    ``range_within_2sd_pct``, ``position_within_2sd_measured_pct``, ``coasting_frames``,
    ``position_within_2sd_coasting_pct``, ``front_away_pct``,
    ``confident_wrong_heading_front_away_pct``, ``confident_wrong_heading_front_toward_pct``,
    ``front_shown_pct`` and ``mae_angle_front_shown_deg``; figures that need a drone sequence are
    None without one, and a figure with no frame to average is None.
    """
    frames = sum(s.frames for s in scores)
    false_frames = sum(int(s.false_frame.sum()) for s in scores)
    off_sight_frames = sum(int(s.off_sight_frame.sum()) for s in scores)
    drone = [s for s in scores if not s.no_drone]
    n_ann = sum(s.frames for s in drone)
    out = {
        "sequences": len(scores),
        "frames": frames,
        "detected_frames": None,
        "detected_pct": None,
        "mae_angle_deg": None,
        "rmse_m": None,
        "mae_abs_m": None,
        "mae_angle_up_to_twin_deg": None,
        "ap_kp": None,
        "false_track_frames": false_frames,
        "false_tracks_per_1000_frames": rounded(
            1000.0 * false_frames / frames if frames else float("nan"), 2
        ),
        "false_track_ids": sum(s.false_ids for s in scores),
        "off_sight_track_frames": off_sight_frames,
        "off_sight_tracks_per_1000_frames": rounded(
            1000.0 * off_sight_frames / frames if frames else float("nan"), 2
        ),
        "off_sight_track_ids": sum(s.off_sight_ids for s in scores),
        "confident_wrong_heading_frames": None,
        "confident_wrong_heading_pct": None,
        "wrong_heading_frames": None,
        "wrong_heading_pct": None,
        "confident_right_heading_frames": None,
        "confident_right_heading_pct": None,
        "missed_wrong_range_pct": None,
        "missed_unconfirmed_pct": None,
        "missed_unseen_pct": None,
        "front_back_frames": None,
        "front_back_right_pct": None,
        "axis_frames": None,
        "axis_exchanged_pct": None,
        "kp_err_px_median": None,
        "range_doubt_frames": None,
        "range_within_1sd_pct": None,
        "range_within_2sd_pct": None,
        "position_within_2sd_measured_pct": None,
        "coasting_frames": None,
        "position_within_2sd_coasting_pct": None,
        "front_away_pct": None,
        "confident_wrong_heading_front_away_pct": None,
        "confident_wrong_heading_front_toward_pct": None,
        "front_shown_pct": None,
        "mae_angle_front_shown_deg": None,
    }
    if not n_ann:
        return out

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(s, name) for s in drone])

    hit = cat("detected")
    poses = [cat(k) for k in ("R_track", "t_track", "R_true", "t_true")]  # track's, then the truth
    R_true = poses[2]
    errors = pose_errors(*(a[hit] for a in poses))
    kp_pred, kp_true, has_pred = cat("kp_pred"), cat("kp_true"), cat("has_pred")
    ap = ap_kp(kp_pred, kp_true, cat("area"), cat("score"), has_pred=has_pred)
    wrong = int(cat("wrong_heading").sum())
    confident_wrong_frames = cat("confident_wrong_heading")
    confident_wrong = int(confident_wrong_frames.sum())
    away = R_true[:, 2, 0] > 0  # the body's forward (x) axis along the camera's optical axis
    confident_right = int(cat("confident_right_heading").sum())
    front_back = cat("front_back_right")
    asked = np.isfinite(front_back)
    exchanged = cat("axis_exchanged")
    decided = np.isfinite(exchanged)
    kp_err = keypoint_error_px(kp_pred[has_pred], kp_true[has_pred])
    kp_err = kp_err[np.isfinite(kp_err)]
    z = np.abs(cat("range_z"))
    z = z[np.isfinite(z)]
    m2, coasting = cat("position_m2"), cat("coasting")
    known = np.isfinite(m2)
    within = m2 <= _CHI2_3DOF_2SD
    measured, coasted = known & ~coasting, known & coasting
    if all(s.front_shown is not None for s in drone):
        shown = cat("front_shown")
        angle_shown = pose_errors(*(a[hit & shown] for a in poses))
        out.update(
            front_shown_pct=rounded(_pct(int(shown.sum()), n_ann), 2),
            mae_angle_front_shown_deg=rounded(angle_shown.mae_angle_deg),
        )
    out.update(
        detected_frames=int(hit.sum()),
        detected_pct=rounded(_pct(int(hit.sum()), n_ann), 2),
        mae_angle_deg=rounded(errors.mae_angle_deg),
        rmse_m=rounded(errors.rmse_m),
        mae_abs_m=rounded(errors.mae_abs_m),
        mae_angle_up_to_twin_deg=rounded(errors.mae_angle_up_to_twin_deg),
        ap_kp=rounded(100.0 * ap, 2),
        confident_wrong_heading_frames=confident_wrong,
        confident_wrong_heading_pct=rounded(_pct(confident_wrong, n_ann), 2),
        wrong_heading_frames=wrong,
        wrong_heading_pct=rounded(_pct(wrong, n_ann), 2),
        confident_right_heading_frames=confident_right,
        confident_right_heading_pct=rounded(_pct(confident_right, n_ann), 2),
        missed_wrong_range_pct=rounded(_pct(int(cat("missed_wrong_range").sum()), n_ann), 2),
        missed_unconfirmed_pct=rounded(_pct(int(cat("missed_unconfirmed").sum()), n_ann), 2),
        missed_unseen_pct=rounded(_pct(int(cat("missed_unseen").sum()), n_ann), 2),
        front_back_frames=int(asked.sum()),
        front_back_right_pct=rounded(_pct(int(front_back[asked].sum()), int(asked.sum())), 2),
        axis_frames=int(decided.sum()),
        axis_exchanged_pct=rounded(_pct(int(exchanged[decided].sum()), int(decided.sum())), 2),
        kp_err_px_median=rounded(float(np.median(kp_err)), 2) if kp_err.size else None,
        range_doubt_frames=int(len(z)),
        range_within_1sd_pct=rounded(_pct(int((z <= 1.0).sum()), len(z)), 2),
        range_within_2sd_pct=rounded(_pct(int((z <= 2.0).sum()), len(z)), 2),
        position_within_2sd_measured_pct=rounded(_pct(int(within[measured].sum()), int(measured.sum())), 2),
        coasting_frames=int(coasted.sum()),
        position_within_2sd_coasting_pct=rounded(_pct(int(within[coasted].sum()), int(coasted.sum())), 2),
        front_away_pct=rounded(_pct(int(away.sum()), n_ann), 2),
        confident_wrong_heading_front_away_pct=rounded(
            _pct(int(confident_wrong_frames[away].sum()), int(away.sum())), 2
        ),
        confident_wrong_heading_front_toward_pct=rounded(
            _pct(int(confident_wrong_frames[~away].sum()), int((~away).sum())), 2
        ),
    )
    return out
