"""Multi-object tracking scores of the pipeline on a sequence with one or more drones.

Runs the daemon's pipeline (``TrackingPipeline``) over the sequence's video and matches, frame by
frame, its published tracks (confirmed and coasting, as the outputs send them) with the
ground-truth drones on 3D distance: the Euclidean distance between a track's position and a drone's
translation, both in the camera frame (metres); pairs farther apart than ``gate_m`` never match.
``motmetrics`` accumulates the matches (CLEAR-MOT and identity metrics):

- MOTA = 1 - (FN + FP + ID switches) / ground-truth objects; MOTP = mean distance of the matches, m;
- IDF1, ID switches, FP, FN; mostly tracked / mostly lost drones (>= 80 % / <= 20 % of their frames).

Per ground-truth drone, the paper's Tab. VI figures over the frames where a track matched it:
MAE-angle (deg), RMSE (m), MAE-absolute (m).

``pooled_summary`` adds several sequences' matches up (motmetrics' overall row): one swarm of 300
frames decides few track births, so its IDF1 moves by several hundredths on any perturbation
(docs/evaluation.md, twenty-sixth session), and a figure over several seeds is the steadier one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import motmetrics as mm
import numpy as np
from tqdm import tqdm

from dronekey.evaluation.pose import PoseErrors, pose_errors, rounded, sequence_spec
from dronekey.evaluation.robustness.dither import FrameDither
from dronekey.geometry.rotations import quat_wxyz_to_matrix
from dronekey.perception.localizer import LocalizerConfig
from dronekey.pipeline import TrackingPipeline
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PUBLISHED_STATUSES, Frame

__all__ = [
    "DEFAULT_GATE_M",
    "MotResult",
    "evaluate_mot",
    "mot_table",
    "pooled_summary",
    "pooled_table",
    "pooled_to_dict",
]

log = logging.getLogger(__name__)

DEFAULT_GATE_M = 1.0
_SUMMARY = {
    "mota": "mota",
    "motp": "motp",
    "idf1": "idf1",
    "num_switches": "id_switches",
    "num_false_positives": "false_positives",
    "num_misses": "false_negatives",
    "mostly_tracked": "mostly_tracked",
    "mostly_lost": "mostly_lost",
    "num_unique_objects": "drones",
    "num_objects": "gt_boxes",
}


@dataclass
class MotResult:
    """What ``dronekey-eval mot`` reports for one sequence."""

    sequence: str
    frames: int
    gate_m: float
    summary: dict
    per_drone: dict[int, PoseErrors] = field(default_factory=dict)
    per_drone_frames: dict[int, int] = field(default_factory=dict)
    accumulator: mm.MOTAccumulator | None = field(default=None, repr=False, compare=False)

    def to_dict(self) -> dict:
        return {
            "sequence": self.sequence,
            "frames": self.frames,
            "gate_m": self.gate_m,
            **_rounded_figures(self.summary),
            "per_drone": [
                {"instance_id": i, "gt_frames": self.per_drone_frames[i], **self.per_drone[i].to_dict()}
                for i in sorted(self.per_drone)
            ],
        }


def _distances(gt_t: np.ndarray, hyp_t: np.ndarray, gate_m: float) -> np.ndarray:
    """(G, H) Euclidean distances, NaN beyond the gate (motmetrics' "cannot match")."""
    if len(gt_t) == 0 or len(hyp_t) == 0:
        return np.empty((len(gt_t), len(hyp_t)))
    d = np.linalg.norm(gt_t[:, None, :] - hyp_t[None, :, :], axis=2)
    d[d > gate_m] = np.nan
    return d


def evaluate_mot(
    seq,
    frames,
    model_path=None,
    gate_m: float = DEFAULT_GATE_M,
    progress: bool = False,
    mirror_average=True,
    tracker: TrackerConfig | None = None,
    localizer: LocalizerConfig | None = None,
    dither: FrameDither | None = None,
) -> MotResult:
    """Run the pipeline over ``frames`` (``SequenceFrame`` iterable) of the loaded ``seq`` and score it.

    ``tracker`` / ``localizer``: settings to measure instead of the shipped ones (None: shipped).
    ``dither``: seeded noise added to every frame first (the figures' noise floor), or None."""
    if not gate_m > 0:
        raise ValueError(f"gate must be a positive distance in metres, got {gate_m}")
    pipeline = TrackingPipeline(
        seq.camera,
        model_path,
        drone=sequence_spec(seq),
        mirror_average=mirror_average,
        tracker=tracker,
        localizer=localizer,
    )
    acc = mm.MOTAccumulator(auto_id=True)
    matched: dict[int, dict[str, list]] = {
        i: {"R": [], "t": [], "R_gt": [], "t_gt": []} for i in seq.instance_ids()
    }
    gt_frames = dict.fromkeys(seq.instance_ids(), 0)
    iterator = (
        tqdm(frames, total=len(seq.frames), desc=seq.name, unit="frame", leave=False) if progress else frames
    )
    n = 0
    for sf in iterator:
        frame = Frame(sf.index, sf.t_ns, sf.bgr)
        out = pipeline.process(frame if dither is None else dither(frame))
        n += 1
        truth = [d for d in sf.record.drones if d.has_pose]
        tracks = [tr for tr in out.tracks if tr.status in PUBLISHED_STATUSES]
        gt_t = np.array([d.translation for d in truth]).reshape(-1, 3)
        hyp_t = np.array([tr.position_m for tr in tracks], dtype=np.float64).reshape(-1, 3)
        frame_id = acc.update(
            [d.instance_id for d in truth], [tr.track_id for tr in tracks], _distances(gt_t, hyp_t, gate_m)
        )
        for d in truth:
            gt_frames[d.instance_id] += 1
        events = acc.mot_events.loc[frame_id]
        by_track = {tr.track_id: tr for tr in tracks}
        by_drone = {d.instance_id: d for d in truth}
        for _, ev in events[events.Type.isin(["MATCH", "SWITCH"])].iterrows():
            d, tr = by_drone[int(ev.OId)], by_track[int(ev.HId)]
            m = matched[d.instance_id]
            m["R"].append(quat_wxyz_to_matrix(tr.quaternion_wxyz))
            m["t"].append(tr.position_m)
            m["R_gt"].append(d.rotation)
            m["t_gt"].append(d.translation)
    df = mm.metrics.create().compute(acc, metrics=list(_SUMMARY), name=seq.name)
    per_drone = {i: pose_errors(m["R"], m["t"], m["R_gt"], m["t_gt"]) for i, m in matched.items()}
    return MotResult(seq.name, n, float(gate_m), _summary_row(df.iloc[0]), per_drone, gt_frames, acc)


def _summary_row(row) -> dict:
    """motmetrics' row -> our names (counts as int)."""
    return {
        name: int(row[key]) if key.startswith(("num_", "mostly_")) else float(row[key])
        for key, name in _SUMMARY.items()
    }


def pooled_summary(results: list[MotResult]) -> dict:
    """The CLEAR-MOT and identity figures of several sequences' matches added up (motmetrics'
    overall row: MOTA, IDF1 and the counts over every frame of every sequence), plus ``frames``,
    ``sequences`` and ``gate_m``. Raises ValueError when the results were matched with different
    gates or hold no matches to add."""
    if not results or any(r.accumulator is None for r in results):
        raise ValueError("pooling needs the results of evaluate_mot (with their matches)")
    gates = {r.gate_m for r in results}
    if len(gates) > 1:
        raise ValueError(f"cannot pool results matched with different gates: {sorted(gates)}")
    df = mm.metrics.create().compute_many(
        [r.accumulator for r in results],
        metrics=list(_SUMMARY),
        names=[f"{k}:{r.sequence}" for k, r in enumerate(results)],
        generate_overall=True,
    )
    summary = _summary_row(df.loc["OVERALL"])
    return {
        "sequences": len(results),
        "frames": sum(r.frames for r in results),
        "gate_m": gates.pop(),
        **summary,
    }


def pooled_to_dict(results: list[MotResult]) -> dict:
    """``--json`` of several sequences: each one's ``to_dict`` and the pooled figures."""
    return {"sequences": [r.to_dict() for r in results], "overall": _rounded_figures(pooled_summary(results))}


def _rounded_figures(summary: dict) -> dict:
    """A summary for JSON: its floats rounded as every evaluation rounds them, counts as they are."""
    return {k: (rounded(v) if isinstance(v, float) else v) for k, v in summary.items()}


def pooled_table(results: list[MotResult]) -> str:
    """Each sequence's ``mot_table``, then the pooled CLEAR-MOT / identity line."""
    s = pooled_summary(results)
    tables = "\n\n".join(mot_table(r) for r in results)
    head = f"all {s['sequences']} sequences: {s['frames']} frames, 3D gate {s['gate_m']:g} m"
    return f"{tables}\n\n{head}\n{_figures_line(s)}"


def _figures_line(s: dict) -> str:
    """The CLEAR-MOT / identity figures of a summary on one line."""
    return (
        f"MOTA {s['mota']:.3f}  MOTP {s['motp']:.3f} m  IDF1 {s['idf1']:.3f}  "
        f"ID switches {s['id_switches']}  FP {s['false_positives']}  FN {s['false_negatives']}  "
        f"mostly tracked {s['mostly_tracked']}  mostly lost {s['mostly_lost']}"
    )


def mot_table(result: MotResult) -> str:
    """The CLEAR-MOT / identity line and the per-drone Tab. VI rows as text."""
    s = result.summary
    lines = [
        f"{result.sequence}: {result.frames} frames, {s['drones']} drones, 3D gate {result.gate_m:g} m",
        _figures_line(s),
        "",
        f"{'drone':>5} | {'matched':>11} | {'MAE-angle (deg)':>15} | {'RMSE (m)':>8} | {'MAE-abs (m)':>11}",
    ]
    for i in sorted(result.per_drone):
        e = result.per_drone[i]
        lines.append(
            f"{i:>5} | {e.frames:>5}/{result.per_drone_frames[i]:<5} | {e.mae_angle_deg:>15.2f} | "
            f"{e.rmse_m:>8.3f} | {e.mae_abs_m:>11.3f}"
        )
    return "\n".join(lines)
