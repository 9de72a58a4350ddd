"""The tuning and reporting seed sets of ``dronekey-eval robustness``, kept apart.

Training draws crops from the sampler's own streams (``CropSampler`` seeds 0, 1, ... of
``dronekey-train``) and validates on sampler seed ``VALIDATION_SEED`` (7919); no rendered sequence of
the presets is trained on. The reporting set's matrix starts at scene seed ``REPORTING_SEED``, the
tuning set's (for choosing thresholds and settings) at ``TUNING_SEED`` (``matrix``'s notes give the
offsets). ``check_seeds`` refuses base seeds whose sequences would overlap each other, the other
set or the validation seed.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from dronekey.checks import int_at_least
from dronekey.evaluation.robustness.matrix import (
    DRONE_FREE_SEED_OFFSET,
    REPORTING_SEED,
    TUNING_SEED,
    VALIDATION_SEED,
    MatrixEntry,
    plan_matrix,
)

__all__ = ["check_seeds", "seed_ranges"]


def seed_ranges(seeds: Iterable[int]) -> str:
    """``7001-7036, 7501-7520`` for a set of integers."""
    ordered = sorted(set(seeds))
    runs: list[list[int]] = []
    for s in ordered:
        if runs and s == runs[-1][1] + 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs)


def check_seeds(bases: Sequence[int], *, tuning: bool, **matrix) -> dict[int, list[MatrixEntry]]:
    """The matrix of every base seed, after checking that the seed sets are kept apart.

    Parameters
    ----------
    bases : base scene seeds, one matrix each.
    tuning : whether ``bases`` are tuning seeds (else reporting seeds).
    **matrix : ``plan_matrix``'s keywords.

    Returns
    -------
    ``{base: plan_matrix(base, **matrix)}`` in the order of ``bases``.

    Raises
    ------
    ValueError
        A repeated base, two bases whose seeds overlap, a seed of the other set (the default
        tuning set for reporting seeds and the other way round) or the validation seed
        ``VALIDATION_SEED``; the message names the seeds.
    """
    bases = [int_at_least("seeds", b, minimum=0) for b in bases]
    if not bases:
        raise ValueError("seeds must name at least one base seed, got []")
    if len(set(bases)) != len(bases):
        raise ValueError(f"seeds must not repeat a base seed, got {bases}")
    plans = {b: plan_matrix(b, **matrix) for b in bases}
    used: dict[int, int] = {}
    for base, entries in plans.items():
        for e in entries:
            if e.seed in used:
                raise ValueError(
                    f"seeds {used[e.seed]} and {base} overlap (both render scene seed {e.seed}); "
                    f"space them at least {DRONE_FREE_SEED_OFFSET + sum(x.no_drone for x in entries)} apart"
                )
            used[e.seed] = base
    if VALIDATION_SEED in used:
        raise ValueError(
            f"seeds {used[VALIDATION_SEED]} would render scene seed {VALIDATION_SEED}, the training "
            "validation seed; pick another base"
        )
    other_name, other_base = ("reporting", REPORTING_SEED) if tuning else ("tuning", TUNING_SEED)
    other = {e.seed for e in plan_matrix(other_base, **matrix)}
    clash = sorted(other & set(used))
    if clash:
        this = "tuning" if tuning else "reporting"
        raise ValueError(
            f"{this} seeds {', '.join(str(b) for b in bases)} overlap the {other_name} seeds "
            f"({seed_ranges(other)}) at {seed_ranges(clash)}; keep tuning and reporting seeds apart"
        )
    return plans
