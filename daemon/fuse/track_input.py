"""A daemon's track message (JSON, schema ``track``, docs/design.md §6.1) back into a ``Track``."""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from dronekey.daemon.config.camera import check_camera_id
from dronekey.types import Track, TrackStatus

__all__ = ["parse_track_message"]


def _array(message: Mapping[str, Any], key: str, shape: tuple[int, ...]) -> np.ndarray:
    value = message.get(key)
    arr = np.array(value, dtype=np.float64)  # null -> nan
    if arr.shape != shape:
        raise ValueError(f"track message field {key} must have shape {shape}, got {value!r}")
    return arr


def parse_track_message(payload: bytes | str) -> tuple[str, Track]:
    """(camera_id, Track) of one track message.

    Raises
    ------
    ValueError
        Not JSON, or a field missing or of the wrong shape (the message names it).
    """
    try:
        message = json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"track message is not JSON: {exc}") from None
    if not isinstance(message, Mapping):
        raise ValueError(f"track message must be a JSON object, got {type(message).__name__}")
    try:
        camera_id = check_camera_id(message["camera_id"])
        track = Track(
            track_id=int(message["track_id"]),
            t_ns=int(message["t_ns"]),
            status=TrackStatus(message["status"]),
            position_m=_array(message, "position_m", (3,)),
            velocity_mps=_array(message, "velocity_mps", (3,)),
            position_cov=_array(message, "position_cov", (3, 3)),
            quaternion_wxyz=_array(message, "quaternion_wxyz", (4,)),
            rotation_std_rad=_array(message, "rotation_std_rad", (3,)),
            score=float(message.get("score") if message.get("score") is not None else np.nan),
            hits=int(message.get("hits") or 0),
            age_s=float(message.get("age_s") or 0.0),
            heading_confidence=float(
                message["heading_confidence"] if message.get("heading_confidence") is not None else np.nan
            ),
        )
    except KeyError as exc:
        raise ValueError(f"track message lacks the field {exc.args[0]}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"track message: {exc}") from None
    return camera_id, track
