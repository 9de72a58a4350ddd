"""A fused track as its JSON message (schema ``fused_track``, docs/fleet.md)."""

from __future__ import annotations

import numpy as np

from dronekey.daemon.fuse.local_frame import LocalFrame
from dronekey.daemon.messages import jsonable
from dronekey.fusion import FusedTrack

__all__ = ["FUSED_KEY", "FUSER_ID", "fused_track_message"]

FUSER_ID = "fused"
FUSED_KEY = f"dronekey/{FUSER_ID}/tracks"


def fused_track_message(fused: FusedTrack, frame: LocalFrame) -> dict:
    """The message of one fused track update in ``frame``."""
    p = np.asarray(fused.position_m, dtype=np.float64)
    lat = lon = alt = None
    if np.all(np.isfinite(p)):
        lat, lon, alt = frame.geodetic(p)
    heading = fused.heading_confidence
    return jsonable(
        {
            "fuser_id": FUSER_ID,
            "track_id": fused.fused_id,
            "t_ns": fused.t_ns,
            "status": fused.status,
            "method": fused.method,
            "frame": frame.to_message(),
            "position_m": p,
            "velocity_mps": fused.velocity_mps,
            "position_cov": fused.position_cov,
            "quaternion_wxyz": fused.quaternion_wxyz,
            "rotation_std_rad": fused.rotation_std_rad,
            "heading_confidence": min(max(heading, 0.0), 1.0) if np.isfinite(heading) else None,
            "score": fused.score,
            "hits": fused.hits,
            "age_s": fused.age_s,
            "lat": lat,
            "lon": lon,
            "alt_m": alt,
            "cameras": [
                {
                    "camera_id": m.camera_id,
                    "track_id": m.track_id,
                    "t_ns": m.t_ns,
                    "status": m.status,
                    "range_m": m.range_m,
                }
                for m in fused.members
            ],
        }
    )
