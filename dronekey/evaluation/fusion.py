"""Fusion evaluation on a multi-camera render (``dronekey-sim --cameras N``): single cameras
against the fused tracks, in the site frame.

Each camera's pipeline (``TrackingPipeline``, unchanged) runs over its video; its tracks go into
``dronekey.fusion.Fuser`` with the cameras' poses from ``site.json`` (the files share one
timeline, so their clocks are trusted). On every frame, for each method (each camera alone, and
the fused tracks) the published estimates (confirmed and coasting) are put into the site frame and
matched to the ground-truth drones:

- pose errors (docs/design.md §4, in the site frame): the Hungarian assignment on 3D distance,
  ungated (with one drone: the estimate nearest to it), then RMSE, MAE-absolute and MAE-angle of
  the matches; ``frames`` counts the drone-frames that had an estimate;
- MOT metrics (``motmetrics``): CLEAR-MOT and identity metrics matched on 3D distance within
  ``gate_m``;
- for each camera, the fused RMSE over the drone-frames that camera matched (and the fused tracks
  too; ``fused_rmse_on_its_frames_m``), and for the better camera the ratio of the two RMSEs over
  those frames: the fused tracks also cover frames where only the other camera sees the drone, so
  the fused RMSE over all its frames mixes accuracy with coverage; this ratio is the accuracy alone.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import motmetrics as mm
import numpy as np
from scipy.optimize import linear_sum_assignment

from dronekey.evaluation.pose import PoseErrors, pose_errors, rounded, sequence_spec
from dronekey.fusion import CameraPose, Fuser
from dronekey.geometry.rotations import quat_wxyz_to_matrix
from dronekey.pipeline import TrackingPipeline
from dronekey.sim_replay.io.frames import iter_frames
from dronekey.sim_replay.io.sequence_reader import load_sequence
from dronekey.sim_replay.io.site import SITE_FILE, load_site
from dronekey.types import PUBLISHED_STATUSES, Frame

__all__ = ["FUSED", "FusionResult", "evaluate_fusion", "fusion_table"]

log = logging.getLogger(__name__)

FUSED = "fused"
_MOT_METRICS = {"mota": "mota", "idf1": "idf1", "num_switches": "id_switches"}


@dataclass
class _Scores:
    """One method's matches and MOT accumulator."""

    R: list
    t: list
    R_gt: list
    t_gt: list
    truths: int
    acc: mm.MOTAccumulator
    sq_errors: dict  # (frame, truth instance id) -> squared position error of its match, m^2

    @classmethod
    def empty(cls) -> _Scores:
        return cls([], [], [], [], 0, mm.MOTAccumulator(auto_id=True), {})

    def add(self, frame: int, estimates, truths, gate_m: float) -> None:
        """estimates: [(id, p_site, R_site_body)]; truths: [(instance_id, p_site, R_site_body)]."""
        self.truths += len(truths)
        if not truths:
            self.acc.update([], [e[0] for e in estimates], np.empty((0, len(estimates))))
            return
        d = np.array([[np.linalg.norm(e[1] - g[1]) for e in estimates] for g in truths]).reshape(
            len(truths), len(estimates)
        )
        if estimates:
            for r, c in zip(*linear_sum_assignment(d), strict=True):
                self.R.append(estimates[c][2])
                self.t.append(estimates[c][1])
                self.R_gt.append(truths[r][2])
                self.t_gt.append(truths[r][1])
                self.sq_errors[(frame, truths[r][0])] = float(d[r, c]) ** 2
        self.acc.update([g[0] for g in truths], [e[0] for e in estimates], np.where(d <= gate_m, d, np.nan))

    def summary(self, name: str) -> dict:
        errors: PoseErrors = pose_errors(self.R, self.t, self.R_gt, self.t_gt)
        df = mm.metrics.create().compute(self.acc, metrics=list(_MOT_METRICS), name=name)
        mot = {
            v: (int(df[k].iloc[0]) if k.startswith("num_") else rounded(float(df[k].iloc[0])))
            for k, v in _MOT_METRICS.items()
        }
        return {"frames": errors.frames, "truths": self.truths, **errors.to_dict(), **mot}

    def rmse_on(self, keys) -> float | None:
        """RMSE (m) over the given (frame, truth) matches of this method, None when there are none."""
        values = [self.sq_errors[k] for k in keys if k in self.sq_errors]
        return float(np.sqrt(np.mean(values))) if values else None


def better_camera(methods: dict) -> str | None:
    """The camera (a key of ``methods`` other than ``FUSED``) with the lowest RMSE; None if none has one."""
    seen = [k for k, m in methods.items() if k != FUSED and m["rmse_m"] is not None]
    return min(seen, key=lambda k: methods[k]["rmse_m"], default=None)


def fused_over_camera_on_its_frames(camera: _Scores, fused: _Scores) -> tuple[float | None, float | None]:
    """(fused RMSE, fused RMSE / the camera's RMSE), both over the drone-frames the camera and the
    fused tracks matched; (None, None) where there are none."""
    common = camera.sq_errors.keys() & fused.sq_errors.keys()
    there, own = fused.rmse_on(common), camera.rmse_on(common)
    if there is None or own is None:
        return None, None
    return rounded(there), (rounded(there / own) if own > 0 else None)


@dataclass(frozen=True)
class FusionResult:
    """What ``dronekey-eval fusion`` reports: per method (camera ids and ``fused``) the pose errors
    and MOT metrics, the share of fused estimates that were triangulated, and fused RMSE over the
    better camera's."""

    folder: str
    sequence: str
    frames: int
    gate_m: float
    methods: dict
    triangulated_share: float | None
    fused_over_better_on_its_frames: float | None = None  # see ``fused_over_camera_on_its_frames``

    @property
    def fused_over_better(self) -> float | None:
        better = better_camera(self.methods)
        fused = self.methods[FUSED]["rmse_m"]
        return None if better is None or fused is None else rounded(fused / self.methods[better]["rmse_m"])

    def to_dict(self) -> dict:
        return {
            "folder": self.folder,
            "sequence": self.sequence,
            "frames": self.frames,
            "gate_m": self.gate_m,
            "methods": self.methods,
            "triangulated_share": self.triangulated_share,
            "fused_rmse_over_better_camera": self.fused_over_better,
            "fused_rmse_over_better_camera_on_its_frames": self.fused_over_better_on_its_frames,
        }


def _sequence_json(folder: Path) -> Path:
    found = sorted(p for p in folder.glob("*.json"))
    if len(found) != 1:
        raise ValueError(f"{folder} must hold exactly one sequence JSON, found {[p.name for p in found]}")
    return found[0]


def evaluate_fusion(folder: str | Path, model_path=None, gate_m: float = 2.0, max_frames: int | None = None):
    """Run each camera's pipeline and the fuser over the render in ``folder`` (``site.json`` and
    one sub-folder per camera); returns a ``FusionResult``.

    Raises
    ------
    ValueError
        Naming the file: no site file, a camera folder without one sequence JSON, cameras whose
        frame counts differ.
    """
    if not gate_m > 0:
        raise ValueError(f"gate must be a positive distance in metres, got {gate_m}")
    folder = Path(folder)
    site_path = folder / SITE_FILE
    if not site_path.is_file():
        raise ValueError(f"{site_path} not found: give the folder dronekey-sim --cameras N wrote")
    site = load_site(site_path)
    cameras = {c.id: c for c in site.cameras}
    poses = {cid: CameraPose(c.R_site_cam, c.t_site_cam_m) for cid, c in cameras.items()}
    sequences = {cid: load_sequence(_sequence_json(folder / c.folder)) for cid, c in cameras.items()}
    counts = {cid: len(s.frames) for cid, s in sequences.items()}
    if len(set(counts.values())) != 1:
        raise ValueError(f"the cameras' sequences differ in length: {counts}")
    pipelines = {
        cid: TrackingPipeline(s.camera, model_path, drone=sequence_spec(s)) for cid, s in sequences.items()
    }
    fuser = Fuser(poses)
    scores = {cid: _Scores.empty() for cid in [*cameras, FUSED]}
    reference = next(iter(cameras))
    fused_total = triangulated = frames = 0
    streams = {cid: iter_frames(s) for cid, s in sequences.items()}
    for per_camera in zip(*streams.values(), strict=True):
        if max_frames is not None and frames >= max_frames:
            break
        frames += 1
        t_ns = per_camera[0].t_ns
        truths = _truths(per_camera[0], poses[reference])
        for cid, sf in zip(streams, per_camera, strict=True):
            out = pipelines[cid].process(Frame(sf.index, sf.t_ns, sf.bgr))
            pose = poses[cid]
            estimates = []
            for track in out.tracks:
                fuser.update(cid, track)
                if track.status in PUBLISHED_STATUSES:
                    R_body = pose.R_site_cam @ quat_wxyz_to_matrix(track.quaternion_wxyz)
                    estimates.append((track.track_id, pose.point_to_site(track.position_m), R_body))
            scores[cid].add(frames, estimates, truths, gate_m)
        fused = [f for f in fuser.fuse(t_ns) if f.status in PUBLISHED_STATUSES]
        fused_total += len(fused)
        triangulated += sum(f.method == "triangulated" for f in fused)
        estimates = [(f.fused_id, f.position_m, quat_wxyz_to_matrix(f.quaternion_wxyz)) for f in fused]
        scores[FUSED].add(frames, estimates, truths, gate_m)
    methods = {name: s.summary(name) for name, s in scores.items()}
    ratios = {}
    for cid in cameras:
        methods[cid]["fused_rmse_on_its_frames_m"], ratios[cid] = fused_over_camera_on_its_frames(
            scores[cid], scores[FUSED]
        )
    methods[FUSED]["fused_rmse_on_its_frames_m"] = methods[FUSED]["rmse_m"]
    better = better_camera(methods)
    share = rounded(triangulated / fused_total) if fused_total else None
    name = next(iter(sequences.values())).name
    return FusionResult(
        str(folder), name, frames, float(gate_m), methods, share, ratios.get(better) if better else None
    )


def _truths(sf, pose: CameraPose) -> list:
    """The ground-truth drones of one frame in the site frame: [(instance_id, p_site, R_site_body)]."""
    return [
        (d.instance_id, pose.point_to_site(d.translation), pose.R_site_cam @ np.asarray(d.rotation))
        for d in sf.record.drones
        if d.has_pose
    ]


def fusion_table(result: FusionResult) -> str:
    """Single cameras against the fused tracks, one line each."""
    lines = [
        f"{result.sequence} in {result.folder}: {result.frames} frames, {len(result.methods) - 1} cameras "
        f"(MOT matched within {result.gate_m:g} m)",
        f"{'method':<8} | {'frames':>11} | {'RMSE (m)':>8} | {'fused there':>11} | {'MAE-abs (m)':>11} | "
        f"{'MAE-angle':>9} | {'MOTA':>6} | {'IDF1':>6} | {'ID sw':>5}",
    ]

    def fmt(value, spec):
        return format(value, spec) if value is not None else f"{'-':>{spec.split('.')[0]}}"

    for name, m in result.methods.items():
        lines.append(
            f"{name:<8} | {m['frames']:>5}/{m['truths']:<5} | {fmt(m['rmse_m'], '8.3f')} | "
            f"{fmt(m['fused_rmse_on_its_frames_m'], '11.3f')} | "
            f"{fmt(m['mae_abs_m'], '11.3f')} | {fmt(m['mae_angle_deg'], '9.2f')} | "
            f"{fmt(m['mota'], '6.3f')} | {fmt(m['idf1'], '6.3f')} | {m['id_switches']:>5}"
        )
    share = "-" if result.triangulated_share is None else f"{100 * result.triangulated_share:.0f} %"
    ratio = "-" if result.fused_over_better is None else f"{result.fused_over_better:.2f}"
    there = result.fused_over_better_on_its_frames
    there = "-" if there is None else f"{there:.2f}"
    lines.append(
        f"fused RMSE / better camera's: {ratio} (on that camera's own frames: {there}); "
        f"fused estimates triangulated: {share}"
    )
    lines.append("fused there: the fused RMSE over the drone-frames that camera matched (its own frames)")
    return "\n".join(lines)
