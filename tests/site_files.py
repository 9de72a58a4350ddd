"""Site files (docs/design.md §5.4) for tests: ``from site_files import write_site``, and
``render_cameras``: a real ``dronekey-sim --cameras N`` render with its site file.

Cameras are given as (id, yaw_deg, pitch_deg, t_site_cam_m): a camera whose optical axis has that
heading (clockwise from north) and elevation, no roll, in the site's ENU frame.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from dronekey.geometry.rotations import ned_from_camera
from dronekey.sim_replay.io.site import SITE_FORMAT, SiteDocument, enu_from_ned, save_site

ORIGIN = {"lat": 47.397742, "lon": 8.545594, "alt_m": 488.0}


def R_site_cam(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """Camera -> site ENU rotation of a camera looking along (yaw, pitch), no roll."""
    return enu_from_ned @ ned_from_camera(yaw_deg, pitch_deg, 0.0)


def write_site(path: Path, cameras, origin=None) -> Path:
    """Write a site file with ``cameras`` [(id, yaw_deg, pitch_deg, (x, y, z))] and return its path;
    each camera's ``geo`` string is its pose at the origin's latitude and longitude (approximate:
    what matters in the tests is R_site_cam and t_site_cam_m)."""
    origin = dict(origin or ORIGIN)
    entries = []
    for camera_id, yaw, pitch, t in cameras:
        geo = f"{origin['lat']},{origin['lon']},{origin['alt_m'] + t[2]},{yaw},{pitch},0"
        entries.append(
            {
                "id": camera_id,
                "folder": camera_id,
                "geo": geo,
                "R_site_cam": R_site_cam(yaw, pitch).tolist(),
                "t_site_cam_m": list(map(float, t)),
            }
        )
    doc = SiteDocument.model_validate({"format": SITE_FORMAT, "origin": origin, "cameras": entries})
    save_site(doc, path)
    return path


def render_cameras(out: Path, frames: int, cameras: int = 2, preset: str = "seq13") -> Path:
    """``dronekey-sim --cameras N --preset P --frames F --out OUT``: cam0/ .. and site.json in ``out``."""
    sim = Path(sys.executable).parent / "dronekey-sim"
    command = [sim, "--cameras", str(cameras), "--preset", preset, "--frames", str(frames), "--out", str(out)]
    subprocess.run(command, check=True, capture_output=True, timeout=120)
    return out
