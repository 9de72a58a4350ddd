"""The evaluation's noise floor: a grey level of seeded noise on every frame.

The tracker is a chain of thresholds (presence, recut, confirmation, heading switches), so a change
that moves the network's input by a grey level here and there moves the matrix's figures: a
heading that flips a frame earlier, a clutter candidate that clears the presence floor once more.
Whether a change to the pipeline did better or worse than that is the question every comparison
asks. ``FrameDither`` adds noise that carries no information (each pixel and channel -1, 0 or +1
grey level, with equal odds) to every decoded frame before the pipeline sees it; a matrix scored
with it against one scored without says how far the figures move on noise alone
(``dronekey-eval robustness --dither SEED``, docs/evaluation.md). A compression artefact of the
camera's encoder is of that size.
"""

from __future__ import annotations

import cv2
import numpy as np

from dronekey.types import Frame

__all__ = ["FrameDither", "describe_dither"]

BANK = 4  # noise frames drawn per sequence and used in turn: each frame's noise differs from the last


def describe_dither(seed: int) -> str:
    """How a report names dithered frames (``robustness`` and ``mot`` alike)."""
    return f"frames dithered (seed {seed})"


class FrameDither:
    """Adds -1, 0 or +1 grey level (equal odds, per pixel and channel, saturating at 0 and 255) to
    every frame, reproducibly from ``seed``: frame ``i`` of any sequence of one size gets the same
    noise.

    Parameters
    ----------
    seed : int
        Seed of the noise (``numpy.random.default_rng``), at least 0.
    """

    def __init__(self, seed: int) -> None:
        if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
        self.seed = int(seed)
        self._bank: list[tuple[np.ndarray, np.ndarray]] = []

    def __call__(self, frame: Frame) -> Frame:
        """The frame with noise added (a new ``Frame``, BGR; the input is left as it is)."""
        bgr = frame.bgr
        if not self._bank or self._bank[0][0].shape != bgr.shape:
            self._bank = self._draw(bgr.shape)
        up, down = self._bank[frame.index % len(self._bank)]
        return Frame(frame.index, frame.t_ns, cv2.subtract(cv2.add(bgr, up), down))

    def _draw(self, shape: tuple[int, ...]) -> list[tuple[np.ndarray, np.ndarray]]:
        """``BANK`` pairs of 0/1 masks: +1 where ``up``, -1 where ``down`` (never both)."""
        rng = np.random.default_rng(self.seed)
        bank = []
        for _ in range(BANK):
            step = rng.integers(-1, 2, size=shape, dtype=np.int8)
            bank.append(((step > 0).astype(np.uint8), (step < 0).astype(np.uint8)))
        return bank
