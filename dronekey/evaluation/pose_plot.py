"""The paper's Fig. 10 for one sequence of ``dronekey-eval pose --plot``: ground truth against the
estimate (matplotlib, the ``plot`` extra; imported when drawing)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dronekey.evaluation.pose import SequenceResult
from dronekey.geometry.rotations import geodesic_angle_deg

__all__ = ["plot_sequence"]


def plot_sequence(result: SequenceResult, path: str | Path) -> None:
    """Ground truth against the estimate: trajectory, viewing axis, per-frame errors (paper Fig. 10)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result.series
    t = s["t"]
    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    ax[0, 0].plot(s["t_gt"][:, 0], s["t_gt"][:, 2], "g-", label="ground truth")
    ax[0, 0].plot(s["t_f"][:, 0], s["t_f"][:, 2], "m.", ms=2, label="filtered")
    ax[0, 0].plot(s["t_raw"][:, 0], s["t_raw"][:, 2], "k.", ms=1, alpha=0.4, label="raw PnP")
    ax[0, 0].set_xlabel("camera x (m, right)")
    ax[0, 0].set_ylabel("camera z (m, forward)")
    ax[0, 0].set_title(f"{result.sequence}: trajectory seen from above")
    ax[0, 0].axis("equal")
    ax[0, 0].legend()
    # Viewing axis: the drone's forward (body x) direction in the camera frame, as azimuth/elevation.
    for key, style, lab in (("R_gt", "g-", "ground truth"), ("R_f", "m.", "filtered")):
        fwd = s[key][:, :, 0]
        az = np.degrees(np.arctan2(fwd[:, 0], fwd[:, 2]))
        el = np.degrees(np.arcsin(np.clip(-fwd[:, 1], -1, 1)))
        ax[0, 1].plot(t, az, style, ms=2, label=f"azimuth {lab}")
        ax[0, 1].plot(t, el, style, ms=2, alpha=0.5, label=f"elevation {lab}")
    ax[0, 1].set_xlabel("time (s)")
    ax[0, 1].set_ylabel("deg")
    ax[0, 1].set_title("viewing axis (drone forward) in the camera frame")
    ax[0, 1].legend(fontsize=7)
    for key, style, lab in (("R_f", "m-", "filtered"), ("R_raw", "k.", "raw PnP")):
        err = [
            geodesic_angle_deg(a, b) if np.all(np.isfinite(a)) else np.nan
            for a, b in zip(s[key], s["R_gt"], strict=True)
        ]
        ax[1, 0].plot(t, err, style, ms=2, label=lab)
    ax[1, 0].set_xlabel("time (s)")
    ax[1, 0].set_ylabel("rotation error (deg)")
    ax[1, 0].legend()
    for key, style, lab in (("t_f", "m-", "filtered"), ("t_raw", "k.", "raw PnP")):
        ax[1, 1].plot(t, np.linalg.norm(s[key] - s["t_gt"], axis=1), style, ms=2, label=lab)
    ax[1, 1].set_xlabel("time (s)")
    ax[1, 1].set_ylabel("position error (m)")
    ax[1, 1].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
