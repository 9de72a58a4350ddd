"""6DoF evaluation on 3DronePose-style sequences (paper Tab. VI, Fig. 10).

Runs the daemon's pipeline (``TrackingPipeline``, unchanged) over a sequence and compares, on every
annotated frame, the filtered track and the raw PnP pose with the ground truth (docs/design.md §4):

- MAE-angle: mean geodesic angle of R_pred^T R_gt, degrees;
- MAE-angle up to the twin (not the paper's): the same against the nearer of R_gt and its heading
  twin (R_gt turned 180 deg about the body's vertical axis), degrees: the attitude error with
  front and back set aside, which four coplanar hubs alone cannot tell apart
  (``dronekey.tracking.heading``);
- RMSE: sqrt(mean ||t_pred - t_gt||^2), metres;
- MAE-absolute: mean over frames and axes of |t_pred - t_gt|, metres;
- confidently wrong (not the paper's; filtered only): the share of the frames with an estimate
  whose attitude is more than ``WRONG_HEADING_DEG`` off while its track's ``heading_confidence``
  is at least ``CONFIDENT_HEADING``, percent: the pipeline sure of a front it has wrong, which the
  brief forbids. A drone read the wrong way round with its doubt said does not count.

Errors are averaged over the annotated frames that have an estimate; ``detected_frames`` says how
many that is. The filtered estimate is the best confirmed or coasting track, the tracks the
daemon's MAVLink output sends (a tentative track can be a single wrong detection); the raw PnP
estimate is every frame's measurement. With ``oracle_noise_px`` the network is replaced by the
ground-truth keypoints plus Gaussian noise, which measures PnP and the filter alone.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dronekey.evaluation.metrics import ap_kp, oks_drone, sr
from dronekey.evaluation.oracle import frame_runner
from dronekey.geometry.drone_spec import DroneSpec, load_spec
from dronekey.geometry.rotations import geodesic_angle_deg, quat_wxyz_to_matrix
from dronekey.perception.localizer import LocalizerConfig
from dronekey.tracking.heading import twin_of
from dronekey.tracking.tracker_config import TrackerConfig
from dronekey.types import PUBLISHED_STATUSES, Frame, TrackStatus

__all__ = [
    "CONFIDENT_HEADING",
    "WRONG_HEADING_DEG",
    "PoseErrors",
    "SequenceResult",
    "evaluate_sequence",
    "pose_errors",
    "published_track_rank",
    "rounded",
    "sequence_spec",
    "table_vi",
    "weighted_average",
]

log = logging.getLogger(__name__)

WRONG_HEADING_DEG = 90.0
CONFIDENT_HEADING = 0.5


@dataclass(frozen=True)
class PoseErrors:
    """Pose errors over a set of frames (NaN when the set is empty); the module's notes define them."""

    frames: int
    mae_angle_deg: float
    rmse_m: float
    mae_abs_m: float
    mae_angle_up_to_twin_deg: float = float("nan")
    confident_wrong_pct: float = float("nan")

    def to_dict(self) -> dict:
        return {
            "frames": self.frames,
            "mae_angle_deg": rounded(self.mae_angle_deg),
            "rmse_m": rounded(self.rmse_m),
            "mae_abs_m": rounded(self.mae_abs_m),
            "mae_angle_up_to_twin_deg": rounded(self.mae_angle_up_to_twin_deg),
            "confident_wrong_pct": rounded(self.confident_wrong_pct),
        }


def pose_errors(R_pred, t_pred, R_gt, t_gt, heading_confidence=None) -> PoseErrors:
    """The paper's three pose errors between lists of predicted and true poses (same length), and,
    given each estimate's ``heading_confidence`` (NaN never counts as sure), the confidently wrong
    share; NaN without them."""
    n = len(R_pred)
    if n == 0:
        return PoseErrors(0, float("nan"), float("nan"), float("nan"))
    ang = np.array([geodesic_angle_deg(a, b) for a, b in zip(R_pred, R_gt, strict=True)])
    ang_twin = np.array([geodesic_angle_deg(a, twin_of(b)) for a, b in zip(R_pred, R_gt, strict=True)])
    dt = np.asarray(t_pred, dtype=np.float64) - np.asarray(t_gt, dtype=np.float64)
    confident_wrong = float("nan")
    if heading_confidence is not None:
        sure = np.asarray(heading_confidence, dtype=np.float64) >= CONFIDENT_HEADING  # NaN: False
        confident_wrong = 100.0 * float(np.mean(sure & (ang > WRONG_HEADING_DEG)))
    return PoseErrors(
        n,
        float(ang.mean()),
        float(np.sqrt(np.mean(np.sum(dt**2, axis=1)))),
        float(np.mean(np.abs(dt))),
        float(np.minimum(ang, ang_twin).mean()),
        confident_wrong,
    )


def published_track_rank(track) -> tuple:
    """Which published track is the pipeline's estimate: confirmed (measured this frame) before
    coasting, then the most hits, then the oldest id."""
    return (track.status != TrackStatus.CONFIRMED, -track.hits, track.track_id)


@dataclass
class SequenceResult:
    """Everything ``dronekey-eval pose`` reports for one sequence, plus per-frame series for plots."""

    sequence: str
    frames: int
    detected_frames: int
    filtered: PoseErrors
    raw: PoseErrors
    ap_kp: float
    sr90: float
    sr95: float
    fps: float
    series: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        out = {
            "sequence": self.sequence,
            "frames": self.frames,
            "detected_frames": self.detected_frames,
            "mae_angle_deg": rounded(self.filtered.mae_angle_deg),
            "rmse_m": rounded(self.filtered.rmse_m),
            "mae_abs_m": rounded(self.filtered.mae_abs_m),
            "mae_angle_up_to_twin_deg": rounded(self.filtered.mae_angle_up_to_twin_deg),
            "confident_wrong_pct": rounded(self.filtered.confident_wrong_pct),
            "ap_kp": rounded(self.ap_kp),
            "sr90": rounded(self.sr90),
            "sr95": rounded(self.sr95),
            "fps": rounded(self.fps),
            "raw_pnp": self.raw.to_dict(),
        }
        return out


def rounded(v: float, nd: int = 4) -> float | None:
    return None if v is None or not np.isfinite(v) else round(float(v), nd)


def sequence_spec(seq) -> DroneSpec:
    """The drone of a loaded sequence: the shipped spec of its model, with the file's 3D keypoints."""
    try:
        spec = load_spec(seq.drone_model)
    except ValueError:
        spec = load_spec("mini2")
    kp = np.asarray(seq.keypoints_3d, dtype=np.float64)
    if kp.shape == (4, 3) and not np.allclose(kp, spec.keypoints_3d):
        spec = replace(spec, name=str(seq.drone_model), keypoints_3d=kp)
    return spec


def evaluate_sequence(
    seq,
    frames,
    model_path: str | Path | None = None,
    oracle_noise_px: float | None = None,
    seed: int = 0,
    progress: bool = False,
    mirror_average: bool = True,
    tracker: TrackerConfig | None = None,
    localizer: LocalizerConfig | None = None,
) -> SequenceResult:
    """Run the pipeline over ``frames`` (an iterable of ``SequenceFrame``) of the loaded ``seq``.
    ``tracker`` / ``localizer``: settings to measure instead of the shipped ones (None: shipped)."""
    spec = sequence_spec(seq)
    run = frame_runner(
        seq.camera,
        spec,
        model_path,
        oracle_noise_px=oracle_noise_px,
        oracle_seed=seed,
        tracker=tracker,
        mirror_average=mirror_average,
        localizer=localizer,
    )

    s = {k: [] for k in ("t", "R_gt", "t_gt", "R_f", "t_f", "conf_f", "R_raw", "t_raw", "has_f", "has_raw")}
    kp_pred, kp_gt, areas, has_pred, scores = [], [], [], [], []
    proc_s, n_frames = 0.0, 0
    iterator = frames
    if progress:
        iterator = tqdm(frames, total=len(seq.frames), desc=seq.name, unit="frame", leave=False)
    for sf in iterator:
        frame = Frame(sf.index, sf.t_ns, sf.bgr)
        ann = sf.record.drone
        t0 = time.perf_counter()
        out = run(frame, ann)
        tracks, det, meas = out.tracks, out.detection, out.measurement
        proc_s += time.perf_counter() - t0
        n_frames += 1
        if ann is None or not getattr(ann, "has_pose", True):
            continue
        live = sorted((tr for tr in tracks if tr.status in PUBLISHED_STATUSES), key=published_track_rank)
        s["t"].append(sf.t_ns / 1e9)
        s["R_gt"].append(ann.rotation)
        s["t_gt"].append(ann.translation)
        s["has_f"].append(bool(live))
        s["R_f"].append(quat_wxyz_to_matrix(live[0].quaternion_wxyz) if live else np.full((3, 3), np.nan))
        s["t_f"].append(live[0].position_m if live else np.full(3, np.nan))
        s["conf_f"].append(live[0].heading_confidence if live else np.nan)
        s["has_raw"].append(meas is not None)
        s["R_raw"].append(meas.R if meas is not None else np.full((3, 3), np.nan))
        s["t_raw"].append(meas.t if meas is not None else np.full(3, np.nan))
        kp_gt.append(ann.keypoints_px)
        areas.append(ann.area)
        has_pred.append(det is not None)
        kp_pred.append(det.keypoints_px if det is not None else np.zeros((4, 2)))
        scores.append(det.presence if det is not None else 0.0)

    series = {k: np.asarray(v) for k, v in s.items()}
    f, r = series.get("has_f", np.zeros(0, bool)), series.get("has_raw", np.zeros(0, bool))
    n_ann = len(kp_gt)
    filtered = (
        pose_errors(
            series["R_f"][f], series["t_f"][f], series["R_gt"][f], series["t_gt"][f], series["conf_f"][f]
        )
        if n_ann
        else pose_errors([], [], [], [])
    )
    raw = (
        pose_errors(series["R_raw"][r], series["t_raw"][r], series["R_gt"][r], series["t_gt"][r])
        if n_ann
        else pose_errors([], [], [], [])
    )
    if n_ann:
        kp_pred_a, kp_gt_a = np.asarray(kp_pred), np.asarray(kp_gt)
        hp = np.asarray(has_pred)
        oks = np.zeros(n_ann)
        if hp.any():
            oks[hp] = oks_drone(kp_pred_a[hp], kp_gt_a[hp], np.asarray(areas)[hp])
        ap = 100 * ap_kp(kp_pred_a, kp_gt_a, np.asarray(areas), np.asarray(scores), has_pred=hp)
        sr90, sr95 = 100 * sr(oks, 0.90), 100 * sr(oks, 0.95)
        series["oks"] = oks
    else:
        ap = sr90 = sr95 = float("nan")
    return SequenceResult(
        sequence=seq.name,
        frames=n_ann,
        detected_frames=int(f.sum()) if n_ann else 0,
        filtered=filtered,
        raw=raw,
        ap_kp=ap,
        sr90=sr90,
        sr95=sr95,
        fps=n_frames / proc_s if proc_s > 0 else float("nan"),
        series=series,
    )


def table_vi(results: list[SequenceResult]) -> str:
    """The paper's Tab. VI layout (filtered, then raw PnP), with the frame-weighted average."""
    lines = []
    for label, get in (("filtered", lambda res: res.filtered), ("raw PnP", lambda res: res.raw)):
        names = [res.sequence for res in results]
        header = f"{label:<10} | {'metric':<17} | " + " | ".join(f"{n:>8}" for n in names) + f" | {'Avg':>8}"
        lines += [header, "-" * len(header)]
        for metric, attr, fmt in (
            ("MAE-angle (deg)", "mae_angle_deg", "{:8.2f}"),
            ("RMSE (m)", "rmse_m", "{:8.3f}"),
            ("MAE-absolute (m)", "mae_abs_m", "{:8.3f}"),
            ("MAE-ang mod twin", "mae_angle_up_to_twin_deg", "{:8.2f}"),
            ("conf>90 (%)", "confident_wrong_pct", "{:8.2f}"),
        ):
            if label == "raw PnP" and attr == "confident_wrong_pct":
                continue  # a measurement carries no heading confidence
            vals = [getattr(get(res), attr) for res in results]
            weights = [get(res).frames for res in results]
            avg = weighted_average(vals, weights, rms=attr == "rmse_m")
            cells = " | ".join(fmt.format(v) for v in vals)
            lines.append(f"{'':<10} | {metric:<17} | {cells} | {fmt.format(avg)}")
        det = " | ".join(f"{get(res).frames:>4}/{res.frames:<3}" for res in results)
        lines.append(f"{'':<10} | {'frames w/ estimate':<17} | {det} |")
        lines.append("")
    return "\n".join(lines)


def weighted_average(values, weights, rms: bool = False) -> float:
    """Frame-weighted average; RMSE values are combined as the RMSE over all frames."""
    v, w = np.asarray(values, dtype=np.float64), np.asarray(weights, dtype=np.float64)
    ok = np.isfinite(v) & (w > 0)
    if not ok.any():
        return float("nan")
    if rms:
        return float(np.sqrt(np.sum(w[ok] * v[ok] ** 2) / np.sum(w[ok])))
    return float(np.sum(w[ok] * v[ok]) / np.sum(w[ok]))
