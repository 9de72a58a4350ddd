"""Argument checks shared by every layer: one rule, one error wording that names the argument."""

from __future__ import annotations

import numpy as np

__all__ = ["int_at_least"]


def int_at_least(name: str, value, minimum: int = 1) -> int:
    """``value`` as an int, checked: an integer (not a bool) >= ``minimum``, else ValueError naming
    ``name`` and the value."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)
