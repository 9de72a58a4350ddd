"""Two runs of ``dronekey-eval robustness --json`` side by side: ``dronekey-eval compare``.

A candidate (another model, classifier or setting) is judged against a baseline on the same
renders. Two things are printed:

- every row of the matrix pooled over one or more seed sets, baseline -> candidate: MAE-angle and
  RMSE over the detected frames (frame-weighted), detected %, confidently wrong and sure-and-right
  shares of the frames, false-track frames, and AP^kp as the mean of the sets (an AP cannot be
  pooled from its sets' figures);
- the sequences whose MAE-angle moved by more than ``moved_deg``, better and worse.

The second is there because which way round a hard drone is read is decided per sequence: two
front/back classifiers of the same held-out skill read about one sequence in five the other way
round (forty-sixth session, docs/evaluation.md), so a pooled mean can move by several degrees
while as many sequences turn wrong as right.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from dronekey.evaluation.pose import weighted_average

__all__ = ["MovedSequence", "ReportComparison", "compare_reports", "load_report"]


def load_report(path: str | Path) -> dict:
    """A ``dronekey-eval robustness --json`` output; ValueError naming the file when it is not one."""
    path = Path(path)
    try:
        report = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(report, dict) or not {"settings", "groups", "sequences"} <= set(report):
        raise ValueError(f"{path} is not the output of 'dronekey-eval robustness --json'")
    return report


@dataclass(frozen=True)
class MovedSequence:
    """One sequence whose MAE-angle (deg) differs between the runs by more than the threshold."""

    name: str
    base_deg: float
    candidate_deg: float

    @property
    def better(self) -> bool:
        return self.candidate_deg < self.base_deg


@dataclass(frozen=True)
class ReportComparison:
    """Rows pooled over the sets (``rows``: (by, value) -> {figure: (base, candidate)}), and the
    sequences that moved (``moved``), out of ``sequences`` compared."""

    sets: int
    rows: dict[tuple[str, str], dict[str, tuple[float | None, float | None]]]
    moved: list[MovedSequence]
    sequences: int
    moved_deg: float

    @property
    def better(self) -> int:
        return sum(m.better for m in self.moved)

    @property
    def worse(self) -> int:
        return len(self.moved) - self.better

    def to_dict(self) -> dict:
        return {
            "sets": self.sets,
            "moved_deg": self.moved_deg,
            "sequences": self.sequences,
            "rows": [
                {"by": by, "value": value, **{k: {"base": b, "candidate": c} for k, (b, c) in figs.items()}}
                for (by, value), figs in self.rows.items()
            ],
            "moved_better": self.better,
            "moved_worse": self.worse,
            "moved": [
                {"name": m.name, "base_deg": m.base_deg, "candidate_deg": m.candidate_deg, "better": m.better}
                for m in self.moved
            ],
        }

    def table(self) -> str:
        head = f"rows pooled over {self.sets} seed set{'s' if self.sets != 1 else ''}, baseline -> candidate"
        lines = [head, "  ".join(f"{h:>{w}}" for h, w in _HEADER)]
        for (by, value), figs in self.rows.items():
            cells = [f"{by} {value}" if by != value else value]
            cells += [_pair(figs[key], fmt) for key, fmt in _FIGURES]
            lines.append("  ".join(f"{c:>{w}}" for c, (_, w) in zip(cells, _HEADER, strict=True)))
        wrong = self.rows.get(("all", "drone sequences"), {}).get("confident_wrong_heading_frames")
        if wrong is not None:  # the rows give it as a share; rules are often written in frames
            lines.append(f"confidently wrong frames over the drone sequences: {_pair(wrong, '{:d}')}")
        lines.append(
            f"sequences whose MAE-angle moved by more than {self.moved_deg:g} deg: {self.better} better, "
            f"{self.worse} worse (of {self.sequences})"
        )
        for m in sorted(self.moved, key=lambda m: (not m.better, m.name)):
            verdict = "better" if m.better else "worse"
            lines.append(f"  {verdict:6s}  {m.name}  {m.base_deg:.1f} -> {m.candidate_deg:.1f}")
        return "\n".join(lines)


# (key, format) of each pooled figure, in the table's order.
_FIGURES = (
    ("mae_angle_deg", "{:.2f}"),
    ("rmse_m", "{:.4f}"),
    ("detected_pct", "{:.2f}"),
    ("ap_kp", "{:.2f}"),
    ("confident_wrong_heading_pct", "{:.2f}"),
    ("confident_right_heading_pct", "{:.1f}"),
    ("false_track_frames", "{:d}"),
)
_HEADER = (
    ("row", 24),
    ("MAE-ang deg", 16),
    ("RMSE m", 18),
    ("detected %", 16),
    ("AP^kp (mean)", 16),
    ("conf>90 %", 14),
    ("sure ok %", 14),
    ("false frames", 14),
)


def _pair(pair: tuple, fmt: str) -> str:
    return " -> ".join("-" if v is None else fmt.format(v) for v in pair)


def _pooled(groups: list[dict]) -> dict[str, float | None]:
    """One row's figures over several sets' rows of it."""
    frames = sum(g["frames"] for g in groups)
    aps = [g["ap_kp"] for g in groups if g.get("ap_kp") is not None]
    return {
        "mae_angle_deg": _weighted(groups, "mae_angle_deg"),
        "rmse_m": _weighted(groups, "rmse_m", rms=True),
        "detected_pct": _share(groups, "detected_frames", frames),
        "ap_kp": sum(aps) / len(aps) if aps else None,
        "confident_wrong_heading_pct": _share(groups, "confident_wrong_heading_frames", frames),
        "confident_right_heading_pct": _share(groups, "confident_right_heading_frames", frames),
        "false_track_frames": sum(g.get("false_track_frames") or 0 for g in groups),
        "confident_wrong_heading_frames": _count(groups, "confident_wrong_heading_frames"),
    }


def _weighted(groups: list[dict], key: str, rms: bool = False) -> float | None:
    """``key`` over the rows that have it, weighted by their detected frames (the frames the figure
    is over; ``pose.weighted_average``, ``rms`` for an RMSE); None where no row has it."""
    values = [math.nan if g.get(key) is None else g[key] for g in groups]
    pooled = weighted_average(values, [g.get("detected_frames") or 0 for g in groups], rms=rms)
    return None if math.isnan(pooled) else pooled


def _count(groups: list[dict], key: str) -> int | None:
    """``key``'s frames summed over the rows; None where no row has it (drone-free rows)."""
    if all(g.get(key) is None for g in groups):
        return None
    return sum(g.get(key) or 0 for g in groups)


def _share(groups: list[dict], key: str, frames: int) -> float | None:
    """``_count`` of ``key`` as a percentage of ``frames``; None where either is missing."""
    count = _count(groups, key)
    return None if not frames or count is None else 100 * count / frames


def compare_reports(
    base: list[dict], candidate: list[dict], moved_deg: float = 10.0, names: list[str] | None = None
) -> ReportComparison:
    """Compare robustness reports pairwise (``base[i]`` with ``candidate[i]``: the same seed set).

    Parameters
    ----------
    base, candidate : list of dict
        ``load_report`` outputs, as many of each; a pair must hold the same sequences.
    moved_deg : float
        A sequence counts as moved when its MAE-angle differs by more than this (deg).
    names : list of str, optional
        The candidate files' names, for errors.
    """
    if len(base) != len(candidate) or not base:
        raise ValueError(
            f"give as many candidate reports as baseline ones, got {len(base)} and {len(candidate)}"
        )
    if not (math.isfinite(moved_deg) and moved_deg >= 0):
        raise ValueError(f"moved_deg must be a finite number >= 0, got {moved_deg}")
    names = names or [f"candidate {i + 1}" for i in range(len(candidate))]
    per_row: dict[tuple[str, str], list[tuple[dict, dict]]] = {}
    moved: list[MovedSequence] = []
    sequences = 0
    for b, c, name in zip(base, candidate, names, strict=True):
        b_seq = {s["name"]: s for s in b["sequences"]}
        c_seq = {s["name"]: s for s in c["sequences"]}
        if set(b_seq) != set(c_seq):
            only = sorted(set(b_seq) ^ set(c_seq))
            raise ValueError(
                f"{name} does not hold the baseline's sequences "
                f"(differs in {only[0]} and {len(only) - 1} more)"
            )
        for key, seq in b_seq.items():
            other = c_seq[key]
            if seq["frames"] != other["frames"]:
                raise ValueError(f"{name}: {key} has {other['frames']} frames, the baseline {seq['frames']}")
            sequences += not seq.get("no_drone", False)
            a, z = seq.get("mae_angle_deg"), other.get("mae_angle_deg")
            if a is not None and z is not None and abs(z - a) > moved_deg:
                moved.append(MovedSequence(key, float(a), float(z)))
        c_rows = {(g["by"], g["value"]): g for g in c["groups"]}
        for g in b["groups"]:
            row = (g["by"], g["value"])
            if row in c_rows:
                per_row.setdefault(row, []).append((g, c_rows[row]))
    rows = {}
    for row, pairs in per_row.items():
        if len(pairs) != len(base):  # a row some sets lack is left out rather than pooled over fewer
            continue
        b_fig, c_fig = _pooled([p[0] for p in pairs]), _pooled([p[1] for p in pairs])
        rows[row] = {k: (b_fig[k], c_fig[k]) for k in b_fig}
    return ReportComparison(len(base), rows, moved, sequences, float(moved_deg))
