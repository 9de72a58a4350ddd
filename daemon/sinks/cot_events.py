"""Cursor-on-Target events for a track, a lost track and the sensor itself (CoT XML, event version 2.0).

Built with pytak's element helpers (``pytak.cot_event``, ``pytak.cot_point``, ``pytak.serialize_cot``),
so the events have the layout TAK clients and pytak-based gateways (DroneCOT, ADSBCOT) send; the
times are set here from the track's clock, since ``pytak.cot_event`` stamps "now" and whole seconds.

- A track is ``dronekey-<camera_id>-<track_id>``, type ``a-u-A-M-H-Q`` by default (atom, unknown
  affiliation, Air, Military, rotary wing, UAV: the type DroneCOT and DragonSync give a drone), how
  ``m-p`` (machine, derived from a sensor's measurement). Its ``point`` is WGS84 latitude and
  longitude, ``hae`` in the datum of ``--camera-geo`` (see ``target_state``), ``ce`` the 1-sigma
  horizontal error (square root of the larger eigenvalue of the north/east covariance, metres) and
  ``le`` the 1-sigma vertical error (metres), as the CoT schema defines them. ``detail`` has
  ``track`` (course, degrees true; speed, m/s), ``contact`` (the callsign MAVLink and SBS-1 use),
  ``link`` to the sensor, ``remarks`` for people and ``dronekey`` for programs (range, bearings,
  score, heading confidence).
- A lost track: the same uid with ``stale`` = ``time`` (every client marks it stale at once), then,
  optionally, a ``t-x-d-d`` delete naming it in ``link`` with ``__forcedelete`` (ATAK, WinTAK and
  iTAK remove the marker; TAK Server forwards it).
- The sensor: ``dronekey-<camera_id>``, type ``a-f-G-E-S-E`` (friendly ground sensor emplacement,
  as DroneCOT's sensor), how ``h-e`` (a configured position), with a ``sensor`` detail that ATAK
  draws as a field-of-view cone (azimuth, elevation, fov, range).
"""

from __future__ import annotations

import datetime as dt
import math
import warnings
import xml.etree.ElementTree as ET

import numpy as np

with warnings.catch_warnings():  # pytak warns at import that its optional aiohttp is missing; unused here
    warnings.simplefilter("ignore")
    import pytak

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.target_state import TargetGeodetic, callsign

__all__ = [
    "UNKNOWN",
    "cot_time",
    "delete_event",
    "sensor_event",
    "sensor_uid",
    "stale_event",
    "track_event",
    "track_uid",
]

UNKNOWN = 9999999.0  # CoT's "unknown" for hae, ce and le
_PRECISION = 7  # decimal places of latitude and longitude: about 1 cm (pytak's default 4 is 11 m)


def track_uid(camera_id: str, track_id: int) -> str:
    """The uid of a track: stable for the camera and the track's life."""
    return f"dronekey-{camera_id}-{int(track_id)}"


def sensor_uid(camera_id: str) -> str:
    """The uid of the sensor's own point."""
    return f"dronekey-{camera_id}"


def cot_time(unix_us: int) -> str:
    """A CoT (W3C XML dateTime, UTC) time from Unix microseconds."""
    when = dt.datetime.fromtimestamp(0, tz=dt.UTC) + dt.timedelta(microseconds=int(unix_us))
    return when.strftime(pytak.W3C_XML_DATETIME)


def _event(
    uid: str, cot_type: str, how: str, unix_us: int, stale_s: float, point: ET.Element, detail: ET.Element
) -> ET.Element:
    event = pytak.cot_event(uid=uid, cot_type=cot_type, how=how, point=point, detail=detail)
    event.set("time", cot_time(unix_us))
    event.set("start", cot_time(unix_us))
    event.set("stale", cot_time(unix_us + round(stale_s * 1e6)))
    return event


def _finite_or_unknown(value: float, digits: int = 2) -> str:
    return f"{value:.{digits}f}" if math.isfinite(value) else str(UNKNOWN)


def _errors_m(cov_ned: np.ndarray) -> tuple[float, float]:
    """(ce, le): 1-sigma horizontal (larger axis of the north/east ellipse) and vertical error, m."""
    cov = np.asarray(cov_ned, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(cov)):
        return UNKNOWN, UNKNOWN
    horizontal = float(np.max(np.linalg.eigvalsh(cov[:2, :2])))
    return math.sqrt(max(horizontal, 0.0)), math.sqrt(max(float(cov[2, 2]), 0.0))


def _fmt(value: float | None, digits: int = 2) -> str | None:
    return None if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def track_event(
    camera_id: str,
    track_id: int,
    state: TargetGeodetic,
    message: dict,
    unix_us: int,
    *,
    cot_type: str,
    sensor_type: str,
    stale_s: float,
) -> ET.Element:
    """The event of one track update.

    state : the track's geodetic state (``target_state.target_geodetic``).
    message : the track's JSON message (``messages.track_message`` with the camera's geo): ``status``,
        ``range_m``, ``bearing``, ``bearing_true``, ``score``, ``heading_confidence``.
    unix_us : the state's time, Unix microseconds (``target_state.unix_time_us``).
    """
    ce, le = _errors_m(state.position_cov_ned)
    point = pytak.cot_point(
        lat=state.lat_deg,
        lon=state.lon_deg,
        hae=_finite_or_unknown(state.alt_m),
        ce=_finite_or_unknown(ce),
        le=_finite_or_unknown(le),
        precision=_PRECISION,
    )
    detail = pytak.cot_detail(flow_tag=False)
    track = ET.SubElement(detail, "track", speed=f"{state.ground_speed_mps:.2f}")
    if state.course_deg is not None:  # below MIN_COURSE_SPEED_MPS the direction is noise
        track.set("course", f"{state.course_deg:.1f}")
    ET.SubElement(detail, "contact", callsign=callsign(track_id))
    ET.SubElement(detail, "link", uid=sensor_uid(camera_id), relation="p-p", type=sensor_type)
    bearing, true = message.get("bearing") or {}, message.get("bearing_true") or {}
    figures = {
        "camera": camera_id,
        "track": str(int(track_id)),
        "status": str(message.get("status")),
        "range_m": _fmt(message.get("range_m")),
        "azimuth_deg": _fmt(bearing.get("azimuth_deg")),
        "elevation_deg": _fmt(bearing.get("elevation_deg")),
        "bearing_true_deg": _fmt(true.get("azimuth_deg")),
        "elevation_true_deg": _fmt(true.get("elevation_deg")),
        "score": _fmt(message.get("score"), 3),
        "heading_confidence": _fmt(message.get("heading_confidence"), 3),
    }
    ET.SubElement(detail, "dronekey", {k: v for k, v in figures.items() if v is not None})
    heading = figures["heading_confidence"] or "unknown"
    ET.SubElement(detail, "remarks").text = (
        f"DroneKey {camera_id} track {track_id} ({figures['status']}): range {figures['range_m']} m, "
        f"bearing {figures['bearing_true_deg']} deg true, score {figures['score']}, "
        f"heading confidence {heading}"
    )
    return _event(track_uid(camera_id, track_id), cot_type, "m-p", unix_us, stale_s, point, detail)


def stale_event(last: ET.Element, unix_us: int) -> ET.Element:
    """The lost track's last event again, stale at ``unix_us`` (its time): clients mark it stale now."""
    event = ET.fromstring(ET.tostring(last))
    for attribute in ("time", "start", "stale"):
        event.set(attribute, cot_time(unix_us))
    remarks = event.find("detail/remarks")
    if remarks is not None:
        remarks.text = f"{remarks.text} - lost"
    dronekey = event.find("detail/dronekey")
    if dronekey is not None:
        dronekey.set("status", "lost")
    return event


def delete_event(uid: str, cot_type: str, unix_us: int) -> ET.Element:
    """A ``t-x-d-d`` event that tells TAK clients to remove the marker ``uid``."""
    point = pytak.cot_point(lat=0.0, lon=0.0, hae=UNKNOWN, ce=UNKNOWN, le=UNKNOWN)
    detail = pytak.cot_detail(flow_tag=False)
    ET.SubElement(detail, "link", uid=uid, relation="none", type=cot_type)
    ET.SubElement(detail, "__forcedelete")
    return _event(f"{uid}-delete", "t-x-d-d", "h-g-i-g-o", unix_us, 20.0, point, detail)


def sensor_event(
    camera_id: str,
    geo: CameraGeo,
    unix_us: int,
    *,
    cot_type: str,
    stale_s: float,
    fov_deg: float | None = None,
    range_m: float | None = None,
) -> ET.Element:
    """The sensor's own point: the camera's configured position, where it looks and how wide."""
    point = pytak.cot_point(
        lat=geo.lat_deg, lon=geo.lon_deg, hae=f"{geo.alt_m:.2f}", ce=UNKNOWN, le=UNKNOWN, precision=_PRECISION
    )
    detail = pytak.cot_detail(flow_tag=False)
    ET.SubElement(detail, "contact", callsign=f"DroneKey {camera_id}")
    sensor = {"azimuth": f"{geo.yaw_deg % 360.0:.1f}", "elevation": f"{geo.pitch_deg:.1f}"}
    sensor["roll"] = f"{geo.roll_deg:.1f}"
    if fov_deg is not None:
        sensor["fov"] = f"{fov_deg:.1f}"
    if range_m is not None:
        sensor["range"] = f"{range_m:.0f}"
    ET.SubElement(detail, "sensor", sensor)
    ET.SubElement(detail, "remarks").text = f"DroneKey drone-tracking camera {camera_id}"
    return _event(sensor_uid(camera_id), cot_type, "h-e", unix_us, stale_s, point, detail)
