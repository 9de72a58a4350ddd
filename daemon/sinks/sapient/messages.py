"""The SAPIENT (BSI Flex 335 v2.0) messages this sensor node sends, built from tracks and status.

Each builder returns a complete ``SapientMessage`` wrapper (send time, this node's UUID, one
content). Ids are ULIDs, as the ICD asks for report, object, alert and task ids. The detection
classes, the mode and the tasks this node accepts are declared once here and used both in the
Registration and where detections and tasks are handled, so what is declared is what is done.

The protobuf classes come from ``sapient-proto`` (Apache-2.0; Dstl's published v2.0 protos,
Crown copyright, Apache-2.0): of the three bindings on PyPI it is the one generated for the
protobuf 7 runtime the project already runs (onnx and onnxruntime bring it); ``sapient-msg``
pins protobuf < 7 and ``sapient-py`` protobuf < 6. All three carry the same wire schema.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from google.protobuf.timestamp_pb2 import Timestamp
from sapient_msg.bsi_flex_335_v2_0 import (
    alert_pb2,
    location_pb2,
    range_bearing_pb2,
    registration_pb2,
    status_report_pb2,
    task_ack_pb2,
    velocity_pb2,
)
from sapient_msg.bsi_flex_335_v2_0.detection_report_pb2 import DetectionReport
from sapient_msg.bsi_flex_335_v2_0.sapient_message_pb2 import SapientMessage
from ulid import ULID

import dronekey
from dronekey.daemon.sinks.sapient.geometry import Geodetic, RangeBearing

__all__ = [
    "CLASS_NAME",
    "ICD_VERSION",
    "MODE_NAME",
    "REQUESTS",
    "SUBCLASS_NAME",
    "TrackReport",
    "alert_message",
    "detection_message",
    "new_ulid",
    "registration_message",
    "status_message",
    "task_ack_message",
]

ICD_VERSION = "BSI Flex 335 v2.0"
CLASS_NAME = "Air Vehicle"  # taxonomy level 0
SUBCLASS_NAME = "UAV Rotary Wing"  # level 1: what the keypoint model finds (four propellers)
MODE_NAME = "default"
REQUESTS = ("Start", "Stop", "Heartbeat", "Registration", "Reset")

_Reg = registration_pb2.Registration
_DEG_M = range_bearing_pb2.RANGE_BEARING_COORDINATE_SYSTEM_DEGREES_M
_PLATFORM = range_bearing_pb2.RANGE_BEARING_DATUM_PLATFORM
_LAT_LNG_DEG_M = location_pb2.LOCATION_COORDINATE_SYSTEM_LAT_LNG_DEG_M
_WGS84_E = location_pb2.LOCATION_DATUM_WGS84_E


def new_ulid() -> str:
    """A fresh ULID (26 characters, time-ordered)."""
    return str(ULID())


def _wrap(node_id: str, **content) -> SapientMessage:
    stamp = Timestamp()
    stamp.FromNanoseconds(time.time_ns())
    return SapientMessage(timestamp=stamp, node_id=node_id, **content)


def _seconds(value: float) -> _Reg.Duration:
    return _Reg.Duration(units=_Reg.TIME_UNITS_SECONDS, value=float(value))


# --------------------------------------------------------------------------- registration
def _location_type(geodetic: bool) -> _Reg.LocationType:
    if geodetic:
        return _Reg.LocationType(location_units=_LAT_LNG_DEG_M, location_datum=_WGS84_E)
    return _Reg.LocationType(range_bearing_units=_DEG_M, range_bearing_datum=_PLATFORM)


def _detection_definition(geodetic: bool) -> _Reg.DetectionDefinition:
    velocity_units = velocity_pb2.ENUVelocityUnits(
        east_north_rate_units=velocity_pb2.SPEED_UNITS_MS, up_rate_units=velocity_pb2.SPEED_UNITS_MS
    )
    velocity = (
        _Reg.VelocityType(enu_velocity_units=velocity_units, location_datum=_WGS84_E)
        if geodetic
        else _Reg.VelocityType(enu_velocity_units=velocity_units, range_bearing_datum=_PLATFORM)
    )
    classes = _Reg.DetectionClassDefinition(
        confidence_definition=_Reg.CONFIDENCE_DEFINITION_SINGLE_CLASS,
        class_definition=[
            _Reg.ClassDefinition(
                type=CLASS_NAME,
                units="probability",
                sub_class=[_Reg.SubClass(type=SUBCLASS_NAME, units="probability", level=1)],
            )
        ],
    )
    heading_units = "degrees from true north" if geodetic else "degrees right of the optical axis"
    return _Reg.DetectionDefinition(
        location_type=_location_type(geodetic),
        detection_class_definition=[classes],
        velocity_type=velocity,
        detection_report=[
            _Reg.DetectionReport(
                category=_Reg.DETECTION_REPORT_CATEGORY_TRACK, type="heading", units=heading_units
            ),
            _Reg.DetectionReport(
                category=_Reg.DETECTION_REPORT_CATEGORY_TRACK, type="track_id", units="integer"
            ),
        ],
    )


def registration_message(
    node_id: str, camera_id: str, *, geodetic: bool, fov_deg: tuple[float, float], status_interval_s: float
) -> SapientMessage:
    """The Registration: a fixed EO camera node that tracks rotary-wing UAVs, one mode, the tasks it takes.

    ``geodetic`` declares lat/lon locations (``--camera-geo`` set) instead of platform range-bearing;
    ``fov_deg`` is the (horizontal, vertical) field of view.
    """
    task = _Reg.TaskDefinition(
        concurrent_tasks=1,
        region_definition=_Reg.RegionDefinition(
            region_type=[_Reg.REGION_TYPE_AREA_OF_INTEREST, _Reg.REGION_TYPE_IGNORE],
            region_area=[_location_type(False)] + ([_location_type(True)] if geodetic else []),
        ),
        command=[
            _Reg.Command(type=_Reg.COMMAND_TYPE_REQUEST, units=", ".join(REQUESTS)),
            _Reg.Command(type=_Reg.COMMAND_TYPE_MODE_CHANGE, units=MODE_NAME),
        ],
    )
    mode = _Reg.ModeDefinition(
        mode_name=MODE_NAME,
        mode_type=_Reg.MODE_TYPE_DEFAULT,
        mode_description="track rotary-wing UAVs by their four propellers; 6DoF pose by PnP",
        settle_time=_seconds(0.0),
        maximum_latency=_seconds(1.0),
        scan_type=_Reg.SCAN_TYPE_FIXED,
        tracking_type=_Reg.TRACKING_TYPE_TRACK,
        detection_definition=[_detection_definition(geodetic)],
        task=task,
    )
    status = _Reg.StatusDefinition(
        status_interval=_seconds(status_interval_s),
        location_definition=_location_type(True) if geodetic else None,
        field_of_view_definition=_location_type(False),
        status_report=[
            _Reg.StatusReport(
                category=_Reg.STATUS_REPORT_CATEGORY_STATUS, type="Not Detecting", on_change=True
            )
        ],
    )
    registration = _Reg(
        node_definition=[_Reg.NodeDefinition(node_type=_Reg.NODE_TYPE_CAMERA, node_sub_type=["EO"])],
        icd_version=ICD_VERSION,
        name=f"DroneKey {camera_id}",
        short_name=f"dronekey-{camera_id}"[:32],
        capabilities=[
            _Reg.Capability(category="Detection", type="Class", value=SUBCLASS_NAME),
            _Reg.Capability(
                category="Field of view", type="Horizontal", value=f"{fov_deg[0]:.1f}", units="degrees"
            ),
            _Reg.Capability(
                category="Field of view", type="Vertical", value=f"{fov_deg[1]:.1f}", units="degrees"
            ),
        ],
        status_definition=status,
        mode_definition=[mode],
        config_data=[
            _Reg.ConfigurationData(
                manufacturer="dronekey", model="dronekey-daemon", software_version=dronekey.__version__
            )
        ],
    )
    return _wrap(node_id, registration=registration)


# --------------------------------------------------------------------------- status
def status_message(
    node_id: str,
    *,
    healthy: bool,
    problem: str | None,
    new: bool,
    active_task_id: str | None,
    fov_deg: tuple[float, float],
    camera_location: tuple[float, float, float] | None,
    goodbye: bool = False,
) -> SapientMessage:
    """A StatusReport: OK or WARNING (with ``problem`` as a "not detecting" status), the mode, the
    camera's field of view (platform frame) and, with a camera geo, its location; GOODBYE on close."""
    Report = status_report_pb2.StatusReport
    system = Report.SYSTEM_GOODBYE if goodbye else (Report.SYSTEM_OK if healthy else Report.SYSTEM_WARNING)
    report = Report(
        report_id=new_ulid(),
        system=system,
        info=Report.INFO_NEW if new else Report.INFO_UNCHANGED,
        mode=MODE_NAME,
        field_of_view=range_bearing_pb2.LocationOrRangeBearing(
            range_bearing=range_bearing_pb2.RangeBearingCone(
                azimuth=0.0,
                elevation=0.0,
                horizontal_extent=fov_deg[0],
                vertical_extent=fov_deg[1],
                coordinate_system=_DEG_M,
                datum=_PLATFORM,
            )
        ),
    )
    if active_task_id:
        report.active_task_id = active_task_id
    if camera_location is not None:
        lat, lon, alt = camera_location
        report.node_location.CopyFrom(
            location_pb2.Location(x=lon, y=lat, z=alt, coordinate_system=_LAT_LNG_DEG_M, datum=_WGS84_E)
        )
    if problem and not healthy:
        report.status.append(
            Report.Status(
                status_level=Report.STATUS_LEVEL_WARNING_STATUS,
                status_type=Report.STATUS_TYPE_NOT_DETECTING,
                status_value=problem,
            )
        )
    return _wrap(node_id, status_report=report)


# --------------------------------------------------------------------------- detections
@dataclass(frozen=True, slots=True)
class TrackReport:
    """What a DetectionReport or Alert says about one track update (sink.py fills it)."""

    object_id: str
    track_id: int
    confidence: float
    range_bearing: RangeBearing | None
    geodetic: Geodetic | None
    velocity_enu: tuple[float, float, float] | None
    heading: tuple[float, float] | None
    lost: bool = False


def _finite(value: float) -> bool:
    return value is not None and math.isfinite(value)


def _set_position(target, report: TrackReport) -> None:
    """Location when geodetic, else platform range-bearing; errors only where finite."""
    if report.geodetic is not None:
        g = report.geodetic
        loc = location_pb2.Location(
            x=g.lon_deg, y=g.lat_deg, z=g.alt_m, coordinate_system=_LAT_LNG_DEG_M, datum=_WGS84_E
        )
        for field, value in (
            ("x_error", g.lon_error_deg),
            ("y_error", g.lat_error_deg),
            ("z_error", g.alt_error_m),
        ):
            if _finite(value):
                setattr(loc, field, value)
        target.location.CopyFrom(loc)
    elif report.range_bearing is not None:
        rb = report.range_bearing
        msg = range_bearing_pb2.RangeBearing(
            range=rb.range_m,
            azimuth=rb.azimuth_deg,
            elevation=rb.elevation_deg,
            coordinate_system=_DEG_M,
            datum=_PLATFORM,
        )
        for field, value in (
            ("range_error", rb.range_error_m),
            ("azimuth_error", rb.azimuth_error_deg),
            ("elevation_error", rb.elevation_error_deg),
        ):
            if _finite(value):
                setattr(msg, field, value)
        target.range_bearing.CopyFrom(msg)


def detection_message(node_id: str, report: TrackReport, task_id: str | None) -> SapientMessage:
    """A DetectionReport of one track update (docs/sapient.md has the field mapping)."""
    confidence = min(max(float(report.confidence), 0.0), 1.0) if _finite(report.confidence) else 0.0
    detection = DetectionReport(
        report_id=new_ulid(),
        object_id=report.object_id,
        detection_confidence=confidence,
        classification=[
            DetectionReport.DetectionReportClassification(
                type=CLASS_NAME,
                confidence=confidence,
                sub_class=[DetectionReport.SubClass(type=SUBCLASS_NAME, confidence=confidence, level=1)],
            )
        ],
        track_info=[DetectionReport.TrackObjectInfo(type="track_id", value=str(report.track_id))],
        id=str(report.track_id),
    )
    _set_position(detection, report)
    if task_id:
        detection.task_id = task_id
    if report.lost:
        detection.state = "lost"
    if report.velocity_enu is not None:
        east, north, up = report.velocity_enu
        detection.enu_velocity.CopyFrom(
            velocity_pb2.ENUVelocity(east_rate=east, north_rate=north, up_rate=up)
        )
    if report.heading is not None:
        heading, error = report.heading
        info = DetectionReport.TrackObjectInfo(type="heading", value=f"{heading:.1f}")
        if _finite(error):
            info.error = error
        detection.track_info.append(info)
    return _wrap(node_id, detection_report=detection)


def alert_message(node_id: str, alert_id: str, report: TrackReport, *, clear: bool = False) -> SapientMessage:
    """An Alert that a rotary-wing UAV track is confirmed (ACTIVE), or that it is gone (CLEAR)."""
    Alert = alert_pb2.Alert
    verb = "lost" if clear else "confirmed"
    alert = Alert(
        alert_id=alert_id,
        alert_type=Alert.ALERT_TYPE_WARNING,
        status=Alert.ALERT_STATUS_CLEAR if clear else Alert.ALERT_STATUS_ACTIVE,
        description=f"{SUBCLASS_NAME} track {report.track_id} {verb}",
        priority=Alert.DISCRETE_PRIORITY_HIGH,
    )
    if _finite(report.confidence):
        alert.confidence = min(max(float(report.confidence), 0.0), 1.0)
    _set_position(alert, report)
    alert.associated_detection.add(node_id=node_id, object_id=report.object_id)
    return _wrap(node_id, alert=alert)


def task_ack_message(node_id: str, task_id: str, accepted: bool, reasons: list[str]) -> SapientMessage:
    """A TaskAck: ACCEPTED, or REJECTED with the reasons."""
    Ack = task_ack_pb2.TaskAck
    status = Ack.TASK_STATUS_ACCEPTED if accepted else Ack.TASK_STATUS_REJECTED
    return _wrap(node_id, task_ack=Ack(task_id=task_id, task_status=status, reason=reasons))
