"""The JSON messages the daemon publishes: track updates, status and the info reply.

One builder per message, shared by every output that speaks JSON (Zenoh and MCAP), so the same
bytes reach both. The JSON schemas (draft 2020-12) ship in ``dronekey.daemon/schemas/`` and are the
contract (docs/design.md §6.1); ``load_schema`` reads them.

Frames and units follow docs/design.md §4: camera frame x right, y down, z forward (metres); quaternions
(w, x, y, z) body -> camera; pixels of the full source frame. Non-finite numbers (NaN, inf) are
sent as ``null`` and ``to_json_bytes`` refuses to emit anything that is not strict JSON. The camera
id is checked by ``config.camera.check_camera_id``, the one rule for it.

Kept whole (some 400 lines): one job, the JSON contract, whose three builders share their helpers.
"""

from __future__ import annotations

import enum
import functools
import json
import math
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import PurePath
from typing import TYPE_CHECKING, Any

import numpy as np

import dronekey
from dronekey.daemon.config.camera import check_camera_id
from dronekey.types import Track, TrackStatus

if TYPE_CHECKING:
    from dronekey.daemon.camera_pose import CameraPlacement
    from dronekey.daemon.geo import CameraGeo
    from dronekey.daemon.sinks.base import SinkWorker
    from dronekey.geometry.camera import CameraModel

__all__ = [
    "SCHEMA_NAMES",
    "check_heading_confidence",
    "info_message",
    "jsonable",
    "key_expressions",
    "load_schema",
    "sink_entry",
    "status_message",
    "to_json_bytes",
    "track_message",
]

SCHEMA_NAMES = ("track", "status", "info", "fused_track")

_STATUS_REQUIRED = ("healthy", "uptime_s", "fps", "source")
_STATUS_OPTIONAL = ("latency_ms", "frames", "model", "tracks_active", "sinks")
_SOURCE_KEYS = ("state", "uri", "reconnects", "error")
_MODEL_KEYS = ("name", "path", "sha256")
# Float rounding a tracker may leave outside [0, 1]; clipped, not refused.
_HEADING_TOLERANCE = 1e-6


# --------------------------------------------------------------------------- schemas and names
@functools.cache
def _schema_text(name: str) -> str:
    if name not in SCHEMA_NAMES:
        raise ValueError(f"schema name must be one of {SCHEMA_NAMES}, got {name!r}")
    path = resources.files("dronekey.daemon").joinpath("schemas", f"{name}.schema.json")
    return path.read_text(encoding="utf-8")


def load_schema(name: str) -> dict:
    """The JSON schema (draft 2020-12) of the ``track``, ``status``, ``info`` or ``fused_track`` message
    (a fresh copy)."""
    return json.loads(_schema_text(name))


def key_expressions(camera_id: str) -> dict[str, str]:
    """The Zenoh key expressions of one camera (docs/design.md §6.1); ``live_tracks`` selects the
    per-track keys ``dronekey/<camera_id>/tracks/<track_id>``."""
    base = f"dronekey/{check_camera_id(camera_id)}"
    keys = {name: f"{base}/{name}" for name in ("tracks", "status", "alive", "info")}
    return {**keys, "live_tracks": f"{base}/tracks/*"}


# --------------------------------------------------------------------------- JSON helpers
def _number(value: Any) -> float | None:
    """A finite float, or None for NaN, inf and None."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _numbers(values: Any, shape: tuple[int, ...], field: str) -> list:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != shape and arr.size == math.prod(shape):
        arr = arr.reshape(shape)
    if arr.shape != shape:
        raise ValueError(f"{field} must have shape {shape}, got {arr.shape}")
    return jsonable(arr)


def jsonable(value: Any) -> Any:
    """``value`` as plain JSON types: numpy scalars and arrays to Python numbers and lists, non-finite
    floats to None, enums to their value, paths to strings, tuples to lists."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, enum.Enum):
        return jsonable(value.value)
    if isinstance(value, (int, np.integer)) and not isinstance(value, np.bool_):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return _number(value)
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.ndarray):
        return [jsonable(v) for v in value.tolist()]
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, PurePath):
        return str(value)
    raise TypeError(f"cannot put a {type(value).__name__} into a JSON message: {value!r}")


def to_json_bytes(message: Mapping[str, Any]) -> bytes:
    """Compact UTF-8 JSON of a message; NaN and inf become null, never the invalid ``NaN`` token."""
    return json.dumps(jsonable(message), allow_nan=False, separators=(",", ":")).encode("utf-8")


# --------------------------------------------------------------------------- track
def _bearing_deg(forward: float, right: float, up: float) -> dict[str, float | None]:
    if not all(math.isfinite(v) for v in (forward, right, up)) or (forward == right == up == 0.0):
        return {"azimuth_deg": None, "elevation_deg": None}
    return {
        "azimuth_deg": math.degrees(math.atan2(right, forward)),
        "elevation_deg": math.degrees(math.atan2(up, math.hypot(forward, right))),
    }


def check_heading_confidence(value: Any) -> float:
    """A track's ``heading_confidence`` checked: a float in [0, 1], or NaN when unknown.

    Parameters
    ----------
    value : float or None
        How sure the tracker is that the drone's front is its front and not its back (the
        180-degree twin about the body's vertical axis): 0 a coin flip, 1 certain. None and
        non-finite values mean "unknown" (a model without a front/back head).

    Returns
    -------
    float
        ``value`` in [0, 1] (rounding excess up to 1e-6 clipped), or NaN.

    Raises
    ------
    ValueError
        Naming ``heading_confidence`` and the value, if it is finite and outside [0, 1].
    """
    allowed = "a number in [0, 1], or NaN / None (unknown)"
    try:
        number = _number(value)
    except (TypeError, ValueError):
        raise ValueError(f"heading_confidence must be {allowed}, got {value!r}") from None
    if number is None:
        return math.nan
    if not -_HEADING_TOLERANCE <= number <= 1.0 + _HEADING_TOLERANCE:
        raise ValueError(f"heading_confidence must be {allowed}, got {value!r}")
    return min(max(number, 0.0), 1.0)


def track_message(track: Track, camera_id: str, camera_geo: CameraGeo | None = None) -> dict:
    """The JSON message of one track update (schema ``track``).

    Parameters
    ----------
    track : dronekey.types.Track
        The track state at ``track.t_ns``.
    camera_id : str
        The daemon's camera id.
    camera_geo : CameraGeo, optional
        The camera's geodetic pose; adds ``lat``, ``lon``, ``alt_m`` (WGS84), ``bearing_true``
        (azimuth from true north, elevation above the horizon) and ``velocity_ned_mps``.

    Returns
    -------
    dict of plain JSON values; ``range_m`` and ``bearing`` (azimuth right of and elevation above the
    optical axis, degrees) are derived from ``position_m``; ``heading_confidence`` is in [0, 1]
    (0: the front may as well be the back, 1: certain), None when unknown.

    Raises
    ------
    ValueError
        Naming the field whose shape or value is wrong (``position_m``, ``heading_confidence``, ...).
    """
    p = np.asarray(track.position_m, dtype=np.float64).reshape(-1)
    if p.shape != (3,):
        raise ValueError(f"track.position_m must have 3 values, got shape {p.shape}")
    status = track.status.value if isinstance(track.status, TrackStatus) else TrackStatus(track.status).value
    keypoints = None if track.keypoints_px is None else _numbers(track.keypoints_px, (4, 2), "keypoints_px")
    message = {
        "camera_id": check_camera_id(camera_id),
        "track_id": int(track.track_id),
        "t_ns": int(track.t_ns),
        "status": status,
        "position_m": _numbers(p, (3,), "position_m"),
        "quaternion_wxyz": _numbers(track.quaternion_wxyz, (4,), "quaternion_wxyz"),
        "velocity_mps": _numbers(track.velocity_mps, (3,), "velocity_mps"),
        "position_cov": _numbers(track.position_cov, (3, 3), "position_cov"),
        "rotation_std_rad": _numbers(track.rotation_std_rad, (3,), "rotation_std_rad"),
        "keypoints_px": keypoints,
        "score": _number(track.score),
        "reprojection_px": _number(track.reprojection_px),
        "heading_confidence": _number(check_heading_confidence(track.heading_confidence)),
        "hits": int(track.hits),
        "age_s": _number(track.age_s),
        "range_m": _number(np.linalg.norm(p)),
        "bearing": _bearing_deg(forward=p[2], right=p[0], up=-p[1]),
    }
    if camera_geo is not None:
        message.update(_geodetic_fields(camera_geo, p, np.asarray(track.velocity_mps, dtype=np.float64)))
    return message


def _geodetic_fields(camera_geo: CameraGeo, p_cam: np.ndarray, v_cam: np.ndarray) -> dict:
    if np.all(np.isfinite(p_cam)):
        lat, lon, alt = camera_geo.geodetic(p_cam)
        north, east, down = camera_geo.ned_from_cam(p_cam)
        bearing = _bearing_deg(forward=north, right=east, up=-down)
        if bearing["azimuth_deg"] is not None:
            bearing["azimuth_deg"] %= 360.0
    else:
        lat = lon = alt = None
        bearing = {"azimuth_deg": None, "elevation_deg": None}
    velocity_ned = camera_geo.ned_from_cam(v_cam.reshape(3))
    return {
        "lat": _number(lat),
        "lon": _number(lon),
        "alt_m": _number(alt),
        "bearing_true": bearing,
        "velocity_ned_mps": jsonable(velocity_ned),
    }


# --------------------------------------------------------------------------- status
def _p50_p99(value: Any, field: str) -> dict[str, float | None]:
    if value is None:
        return {"p50": None, "p99": None}
    if isinstance(value, Mapping):
        unknown = set(value) - {"p50", "p99"}
        if unknown:
            raise ValueError(f"{field} takes the keys p50 and p99, got also {sorted(unknown)}")
        return {"p50": _number(value.get("p50")), "p99": _number(value.get("p99"))}
    if isinstance(value, Sequence) and len(value) == 2:
        return {"p50": _number(value[0]), "p99": _number(value[1])}
    raise ValueError(f"{field} must be {{'p50': ms, 'p99': ms}} or (p50, p99), got {value!r}")


def _sub_object(value: Any, keys: tuple[str, ...], field: str, *, extra_ok: bool = False) -> dict:
    if value is None:
        value = {}
    if not isinstance(value, Mapping):
        raise ValueError(f"{field} must be a mapping, got {type(value).__name__}: {value!r}")
    unknown = set(value) - set(keys)
    if unknown and not extra_ok:
        raise ValueError(f"{field} takes the keys {list(keys)}, got unknown {sorted(unknown)}")
    out = {k: jsonable(value.get(k)) for k in keys}
    out.update({str(k): jsonable(v) for k, v in value.items() if k not in keys})
    return out


def sink_entry(name: str, worker: SinkWorker) -> dict:
    """The ``sinks`` entry of the status message for one output, read from its worker."""
    p50, p99 = worker.stats.latency_percentiles()
    try:
        health = dict(worker.sink.health())
    except Exception as exc:  # a broken health() must not break the status message
        health = {"error": f"health() failed: {type(exc).__name__}: {exc}"}
    try:
        failing = worker.sink.failing()
        faults = {str(k): int(v) for k, v in worker.sink.fault_counts().items()}
    except Exception as exc:
        failing, faults = f"failing() or fault_counts() failed: {type(exc).__name__}: {exc}", {}
    return {
        "name": name,
        "queue_depth": int(worker.depth),
        "published": int(worker.stats.published),
        "dropped": int(worker.stats.dropped),
        "errors": int(worker.stats.errors),
        "last_error": worker.stats.last_error,
        "latency_ms": {"p50": p50, "p99": p99},
        "health": health,
        "failing": failing,
        "faults": faults,
    }


def _sink_entries(sinks: Any) -> list[dict]:
    if sinks is None:
        return []
    items = sinks.items() if isinstance(sinks, Mapping) else ((None, s) for s in sinks)
    entries = []
    for name, entry in items:
        if not isinstance(entry, Mapping):
            raise ValueError(f"each sinks entry must be a mapping, got {entry!r}")
        entry = dict(entry)
        if name is not None:
            entry.setdefault("name", name)
        if "name" not in entry:
            raise ValueError(f"a sinks entry lacks its 'name': {entry!r}")
        entries.append(
            {
                "name": str(entry["name"]),
                "queue_depth": int(entry.get("queue_depth", 0)),
                "published": int(entry.get("published", 0)),
                "dropped": int(entry.get("dropped", 0)),
                "errors": int(entry.get("errors", 0)),
                "last_error": entry.get("last_error"),
                "latency_ms": _p50_p99(entry.get("latency_ms"), f"sinks[{entry['name']}].latency_ms"),
                "health": jsonable(dict(entry.get("health") or {})),
                "failing": None if entry.get("failing") is None else str(entry["failing"]),
                "faults": {str(k): int(v) for k, v in dict(entry.get("faults") or {}).items()},
            }
        )
    return entries


def status_message(camera_id: str, t_ns: int, figures: Mapping[str, Any]) -> dict:
    """The JSON status message (schema ``status``) from the daemon's figures.

    Parameters
    ----------
    camera_id : str
    t_ns : int
        Wall-clock time of the status, Unix epoch ns.
    figures : mapping
        Required: ``healthy`` (bool), ``uptime_s`` (s), ``fps`` (frames/s, None if unknown),
        ``source`` ({``state``, ``uri``, ``reconnects``, ``error``}; only ``state`` required).
        Optional: ``latency_ms`` ({``p50``, ``p99``} or a (p50, p99) pair, ms), ``frames``
        ({``processed``, ``dropped``}), ``model`` ({``name``, ``path``, ``sha256``, ...}),
        ``tracks_active`` (int), ``sinks`` (a list of ``sink_entry`` dicts, or a mapping name -> entry).

    Raises
    ------
    ValueError
        Naming the missing or unknown figure, or the malformed value.
    """
    missing = [k for k in _STATUS_REQUIRED if k not in figures]
    if missing:
        raise ValueError(f"status figures lack {missing} (required: {list(_STATUS_REQUIRED)})")
    unknown = set(figures) - set(_STATUS_REQUIRED) - set(_STATUS_OPTIONAL)
    if unknown:
        raise ValueError(
            f"unknown status figures {sorted(unknown)}; allowed: {list(_STATUS_REQUIRED + _STATUS_OPTIONAL)}"
        )
    source = _sub_object(figures["source"], _SOURCE_KEYS, "source")
    if not isinstance(source["state"], str) or not source["state"]:
        raise ValueError(f"source.state must be a non-empty string, got {source['state']!r}")
    source["reconnects"] = int(source["reconnects"] or 0)
    frames = _sub_object(figures.get("frames"), ("processed", "dropped"), "frames")
    uptime_s = _number(figures["uptime_s"])
    if uptime_s is None or uptime_s < 0:
        raise ValueError(f"uptime_s must be a finite number >= 0, got {figures['uptime_s']!r}")
    return {
        "camera_id": check_camera_id(camera_id),
        "t_ns": int(t_ns),
        "healthy": bool(figures["healthy"]),
        "uptime_s": uptime_s,
        "fps": _number(figures["fps"]),
        "latency_ms": _p50_p99(figures.get("latency_ms"), "latency_ms"),
        "frames": {k: int(frames[k] or 0) for k in ("processed", "dropped")},
        "source": source,
        "model": _sub_object(figures.get("model"), _MODEL_KEYS, "model", extra_ok=True),
        "tracks_active": int(figures.get("tracks_active") or 0),
        "sinks": _sink_entries(figures.get("sinks")),
    }


# --------------------------------------------------------------------------- info
def info_message(
    camera_id: str,
    camera: CameraModel,
    model: Mapping[str, Any] | None = None,
    camera_geo: CameraGeo | None = None,
    placement: CameraPlacement | None = None,
) -> dict:
    """The reply of the ``dronekey/<camera_id>/info`` queryable (schema ``info``).

    Parameters
    ----------
    camera_id : str
    camera : CameraModel
        Intrinsics at the source resolution.
    model : mapping, optional
        The keypoint model: ``name``, ``path``, ``sha256`` and anything else worth telling.
    camera_geo : CameraGeo, optional
        The camera's geodetic pose.
    placement : CameraPlacement, optional
        The camera's pose as configured (``camera.geo`` or ``camera.extrinsics``): ``camera_pose``
        gives it in ECEF and, from extrinsics, in the site frame (what ``dronekey-fuse`` reads).
    """
    geo = None
    if camera_geo is not None:
        geo = {
            k: float(getattr(camera_geo, k))
            for k in ("lat_deg", "lon_deg", "alt_m", "yaw_deg", "pitch_deg", "roll_deg")
        }
    return {
        "camera_id": check_camera_id(camera_id),
        "version": dronekey.__version__,
        "key_expressions": key_expressions(camera_id),
        "calibration": {
            "width": camera.width,
            "height": camera.height,
            "K": jsonable(camera.K),
            "dist": jsonable(camera.dist),
            "rms_px": _number(camera.rms_px),
        },
        "camera_geo": geo,
        "camera_pose": placement.to_message() if placement is not None else None,
        "model": _sub_object(model, _MODEL_KEYS, "model", extra_ok=True),
        "schemas": {"track": load_schema("track"), "status": load_schema("status")},
    }
