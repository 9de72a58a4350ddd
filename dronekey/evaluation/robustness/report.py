"""The report of ``dronekey-eval robustness``: its settings and every sequence, as a table or JSON.

Rows (``RobustnessReport.groups``): per LED condition, per background, per motion, per range (near,
far), all drone sequences, drone-free; each row pools its sequences' frames (``summary``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from dronekey.evaluation.config_overrides import describe_pipeline_changes
from dronekey.evaluation.pose import rounded
from dronekey.evaluation.robustness.dither import describe_dither
from dronekey.evaluation.robustness.render import Rendered
from dronekey.evaluation.robustness.scoring import SequenceScores
from dronekey.evaluation.robustness.summary import summarise

__all__ = ["EvaluatedSequence", "RobustnessReport"]


@dataclass(frozen=True)
class EvaluatedSequence:
    """One sequence of the matrix, rendered and scored."""

    rendered: Rendered
    scores: SequenceScores

    def to_dict(self) -> dict:
        return {
            **self.rendered.entry.to_dict(),
            "json": str(self.rendered.json_path),
            "reused": self.rendered.reused,
            "render_s": round(self.rendered.render_s, 2),
            "fps": rounded(self.scores.fps, 1),
            **summarise([self.scores]),
        }


# Table columns: (header, unit, key in summarise's dict, format).
_COLUMNS = (
    ("seqs", "", "sequences", "{:d}"),
    ("frames", "", "frames", "{:d}"),
    ("MAE-ang", "deg", "mae_angle_deg", "{:.2f}"),
    ("RMSE", "m", "rmse_m", "{:.3f}"),
    ("MAE-abs", "m", "mae_abs_m", "{:.3f}"),
    ("modtwin", "deg", "mae_angle_up_to_twin_deg", "{:.2f}"),
    ("detected", "%", "detected_pct", "{:.1f}"),
    ("AP^kp", "%", "ap_kp", "{:.1f}"),
    ("false", "/1k fr", "false_tracks_per_1000_frames", "{:.1f}"),
    ("false", "ids", "false_track_ids", "{:d}"),
    ("off-sight", "/1k fr", "off_sight_tracks_per_1000_frames", "{:.1f}"),
    ("conf>90", "%", "confident_wrong_heading_pct", "{:.2f}"),
    ("any>90", "%", "wrong_heading_pct", "{:.2f}"),
    ("sure ok", "%", "confident_right_heading_pct", "{:.1f}"),
)

# The second table: where the frames without the drone's track went, the front/back classifier per
# detection, the detections whose order exchanges the body's axes, and how often the true range lies
# within one and two published standard deviations, the true position within two of the whole
# covariance on measured and on coasting frames, the drone's keypoints' median error, and the frames
# whose drone shows its front with the MAE-angle over them (``summary``'s notes).
_MISS_COLUMNS = (
    ("detected", "%", "detected_pct", "{:.1f}"),
    ("range", "%", "missed_wrong_range_pct", "{:.1f}"),
    ("unconf", "%", "missed_unconfirmed_pct", "{:.1f}"),
    ("unseen", "%", "missed_unseen_pct", "{:.1f}"),
    ("f/b dets", "", "front_back_frames", "{:d}"),
    ("f/b ok", "%", "front_back_right_pct", "{:.1f}"),
    ("axis x", "%", "axis_exchanged_pct", "{:.1f}"),
    ("kp err", "px", "kp_err_px_median", "{:.2f}"),
    ("rng<1sd", "%", "range_within_1sd_pct", "{:.1f}"),
    ("rng<2sd", "%", "range_within_2sd_pct", "{:.1f}"),
    ("pos<2sd", "%", "position_within_2sd_measured_pct", "{:.1f}"),
    ("coast<2sd", "%", "position_within_2sd_coasting_pct", "{:.1f}"),
    ("front", "%", "front_shown_pct", "{:.1f}"),
    ("ang fr", "deg", "mae_angle_front_shown_deg", "{:.2f}"),
)


@dataclass
class RobustnessReport:
    """Everything ``dronekey-eval robustness`` reports: its settings and every sequence."""

    settings: dict
    sequences: list[EvaluatedSequence] = field(default_factory=list)

    def groups(self) -> list[tuple[str, str, list[EvaluatedSequence]]]:
        """``(by, value, sequences)`` of every row of the table, in order: per LED condition, per
        background, per motion, per range (near, far), all drone sequences, drone-free."""
        drone = [s for s in self.sequences if not s.rendered.entry.no_drone]
        free = [s for s in self.sequences if s.rendered.entry.no_drone]
        rows = []
        for by, attr, values in (
            ("leds", "leds", self.settings["leds"]),
            ("background", "background", self.settings["backgrounds"]),
            ("motion", "preset", self.settings["motions"]),
        ):
            rows += [(by, v, [s for s in drone if getattr(s.rendered.entry, attr) == v]) for v in values]
        near = [s for s in drone if not s.rendered.entry.far]
        far = [s for s in drone if s.rendered.entry.far]
        rows.append(("range", "near", near))
        if far:
            rows.append(("range", f"far x{self.settings['far_range_scale']:g}", far))
        rows.append(("all", "drone sequences", drone))
        if free:
            rows.append(("drone-free", "drone-free", free))
        return [r for r in rows if r[2]]

    def group_summaries(self) -> list[tuple[str, str, dict]]:
        """``(by, value, summary)`` of every row (``groups``), ``summary`` from ``summarise``: what
        both the table and the JSON report."""
        return [(by, value, summarise([s.scores for s in seqs])) for by, value, seqs in self.groups()]

    def to_dict(self) -> dict:
        """The settings, every table row (``group_summaries``) and every sequence, JSON-ready."""
        return {
            "settings": self.settings,
            "groups": [{"by": by, "value": v, **summary} for by, v, summary in self.group_summaries()],
            "sequences": [s.to_dict() for s in self.sequences],
        }

    def table(self) -> str:
        """Two text tables of a row per group (``groups``), a blank line between kinds of group: the
        figures, then where the missed frames went and the front/back classifier per detection."""
        st = self.settings
        lines = [
            f"robustness: {st['seed_set']} seeds {', '.join(map(str, st['seeds']))} "
            f"(scene seeds {st['scene_seeds']}), {st['frames']} frames per sequence at "
            f"{st['size'][0]}x{st['size'][1]}, model {Path(st['model']).name}"
            + (f", front/back {Path(st['front_back']).name}" if st.get("front_back") else "")
            + (f", verifier {Path(st['verifier']).name}" if st.get("verifier") else "")
            + (f", {describe_dither(st['dither'])}" if st.get("dither") is not None else "")
            + (f", search recut {st['acquire_recut']}" if st.get("acquire_recut") is not None else "")
            + (
                f", confirmation leaving out {st['confirm_max_outliers']} outlying hit(s)"
                if st.get("confirm_max_outliers")
                else ""
            )
            + (
                f", heading confidence bounded by size (sure from hubs {st['heading_full_spread_px']:g} px)"
                if st.get("heading_full_spread_px")
                else ""
            )
            + (
                f", confirmed drones measured every {st['measure_every']} frames (AP^kp on those)"
                if st.get("measure_every", 1) > 1
                else ""
            )
            + (", every drone cue-free (no front/back cue)" if st.get("cue_free") else "")
            + (
                f", ORACLE: no network, the true keypoints with {st['oracle_noise_px']:g} px of noise"
                " (the pose stage alone; detection and false tracks not measured)"
                if st.get("oracle_noise_px") is not None
                else ""
            )
            + "".join(f", {change}" for change in describe_pipeline_changes(st)),
        ]
        if not st.get("model_has_heading_head", True):
            lines.append(
                "(the model has no front/back head: heading_confidence is NaN, conf>90 is 0 by definition)"
            )
        rows = self.group_summaries()
        lines += _table_lines(_COLUMNS, rows)
        lines += [
            "",
            "frames without the drone's track: read at a wrong range, held but not confirmed, not held;"
            " the front/back classifier per detection of the drone; the frames whose drone shows its"
            " front, and the MAE-angle over them",
            *_table_lines(_MISS_COLUMNS, [r for r in rows if r[0] != "drone-free"]),
        ]
        return "\n".join(lines)


def _table_lines(columns: tuple, rows: list[tuple[str, str, dict]]) -> list[str]:
    """Header, units, rule and a line per ``(by, value, summary)`` row of one table of ``columns``;
    the groups are summarised once for both tables."""
    label_w = 24
    widths = [max(len(h), len(u), 6) for h, u, _, _ in columns]
    head = f"{'group':<{label_w}}" + "".join(
        f" {h:>{w}}" for (h, _, _, _), w in zip(columns, widths, strict=True)
    )
    units = f"{'':<{label_w}}" + "".join(
        f" {u:>{w}}" for (_, u, _, _), w in zip(columns, widths, strict=True)
    )
    lines = [head, units, "-" * len(head)]
    previous = None
    for by, value, summary in rows:
        if previous is not None and by != previous:
            lines.append("")
        previous = by
        label = value if by in ("all", "drone-free") else f"{by} {value}"
        cells = []
        for (_, _, key, fmt), w in zip(columns, widths, strict=True):
            v = summary[key]
            cells.append(f" {'-' if v is None else fmt.format(v):>{w}}")
        lines.append(f"{label:<{label_w}}" + "".join(cells))
    return lines
