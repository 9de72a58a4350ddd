"""What this node does with a SAPIENT Task: the requests, modes and regions it accepts, and why it
refuses the rest.

Accepted (and declared so in the Registration, ``messages.py``):

- ``command.request`` "Start" / "Stop" (detection reports on / off), "Heartbeat" (a StatusReport
  now), "Registration" (register again), "Reset" (reports on, regions cleared); any case.
- ``command.mode_change`` to the one mode, "default".
- ``region`` of type AREA_OF_INTEREST (only tracks inside are reported) or IGNORE (tracks inside
  are not), each either a range-bearing cone (platform datum: the camera frame, as this node
  reports; true datum with ``--camera-geo``) or a lat/lon polygon (needs ``--camera-geo``).
  A cone's extents are full widths centred on its azimuth and elevation; a range of 0 is no limit.
- ``control`` STOP ends the named task (its regions are dropped).

Anything else (another command, UTM coordinates, PAUSE, an empty task id) rejects the whole task,
with every reason, and changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from sapient_msg.bsi_flex_335_v2_0 import location_pb2, range_bearing_pb2
from sapient_msg.bsi_flex_335_v2_0.task_pb2 import Task

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.sapient.geometry import wrap_deg
from dronekey.daemon.sinks.sapient.messages import MODE_NAME, REQUESTS

__all__ = ["Region", "TaskOutcome", "interpret_task", "reportable"]

_RB = range_bearing_pb2
_CONE_UNITS = {  # coordinate system -> (degrees per unit angle, metres per unit range)
    _RB.RANGE_BEARING_COORDINATE_SYSTEM_DEGREES_M: (1.0, 1.0),
    _RB.RANGE_BEARING_COORDINATE_SYSTEM_RADIANS_M: (math.degrees(1.0), 1.0),
    _RB.RANGE_BEARING_COORDINATE_SYSTEM_DEGREES_KM: (1.0, 1000.0),
    _RB.RANGE_BEARING_COORDINATE_SYSTEM_RADIANS_KM: (math.degrees(1.0), 1000.0),
}
_POLYGON_UNITS = {
    location_pb2.LOCATION_COORDINATE_SYSTEM_LAT_LNG_DEG_M: 1.0,
    location_pb2.LOCATION_COORDINATE_SYSTEM_LAT_LNG_RAD_M: math.degrees(1.0),
}


@dataclass(frozen=True, slots=True)
class Region:
    """A region of a Task: a cone (degrees, metres; ``true_north`` or the camera frame) or a polygon of
    (lon, lat) degrees. ``ignore`` regions exclude, the others include."""

    region_id: str
    ignore: bool
    cone: tuple[float, float, float, float, float] | None = None  # azimuth, elevation, range, h, v
    true_north: bool = False
    polygon: tuple[tuple[float, float], ...] = ()

    def contains(self, p_cam: np.ndarray, camera_geo: CameraGeo | None) -> bool:
        """Whether a camera-frame position (m) lies in the region; False when it cannot be placed."""
        if self.cone is not None:
            if self.true_north:
                if camera_geo is None:
                    return False
                north, east, down = camera_geo.ned_from_cam(p_cam)
                forward, right, up = north, east, -down
            else:
                forward, right, up = p_cam[2], p_cam[0], -p_cam[1]
            azimuth, elevation, max_range, width, height = self.cone
            distance = math.sqrt(forward * forward + right * right + up * up)
            if distance == 0.0:
                return False
            az = math.degrees(math.atan2(right, forward))
            el = math.degrees(math.asin(max(-1.0, min(1.0, up / distance))))
            return (
                abs(wrap_deg(az - azimuth)) <= width / 2.0
                and abs(el - elevation) <= height / 2.0
                and (max_range <= 0.0 or distance <= max_range)
            )
        if camera_geo is None:
            return False
        lat, lon, _ = camera_geo.geodetic(p_cam)
        return _inside_polygon(lon, lat, self.polygon)


def _inside_polygon(x: float, y: float, polygon: Sequence[tuple[float, float]]) -> bool:
    """Even-odd rule on a small lat/lon polygon (no antimeridian or pole crossing)."""
    inside = False
    for (x1, y1), (x2, y2) in zip(polygon, [*polygon[1:], polygon[0]], strict=True):
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def reportable(p_cam: np.ndarray, regions: Sequence[Region], camera_geo: CameraGeo | None) -> bool:
    """Whether a track at ``p_cam`` is reported: inside some area of interest (if there are any) and
    in no ignore region."""
    p = np.asarray(p_cam, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(p)):
        return False
    interest = [r for r in regions if not r.ignore]
    if interest and not any(r.contains(p, camera_geo) for r in interest):
        return False
    return not any(r.contains(p, camera_geo) for r in regions if r.ignore)


@dataclass(frozen=True, slots=True)
class TaskOutcome:
    """The TaskAck to send and what changes; ``None`` fields change nothing, an ``active_task_id`` of
    "" means no task, ``end_task`` drops the regions if ``task_id`` is the active task."""

    task_id: str
    accepted: bool
    reasons: tuple[str, ...] = ()
    reporting: bool | None = None
    regions: tuple[Region, ...] | None = None
    active_task_id: str | None = None
    end_task: bool = False
    send_status: bool = False
    register_again: bool = False


def _region(region: Task.Region, index: int, camera_geo: CameraGeo | None) -> Region | str:
    """The region, or why it is refused."""
    name = f"region {index} ({region.region_id or 'no id'})"
    if region.type not in (Task.REGION_TYPE_AREA_OF_INTEREST, Task.REGION_TYPE_IGNORE):
        return f"{name}: type {Task.RegionType.Name(region.type)} not supported (AREA_OF_INTEREST, IGNORE)"
    if region.class_filter or region.behaviour_filter:
        return f"{name}: class and behaviour filters not supported (this node reports one class)"
    ignore = region.type == Task.REGION_TYPE_IGNORE
    area = region.region_area
    kind = area.WhichOneof("fov_oneof")
    if kind == "range_bearing":
        cone = area.range_bearing
        if cone.coordinate_system not in _CONE_UNITS:
            return f"{name}: range-bearing coordinate system unspecified"
        if cone.datum not in (_RB.RANGE_BEARING_DATUM_PLATFORM, _RB.RANGE_BEARING_DATUM_TRUE):
            return f"{name}: datum {_RB.RangeBearingDatum.Name(cone.datum)} not supported (PLATFORM, TRUE)"
        true_north = cone.datum == _RB.RANGE_BEARING_DATUM_TRUE
        if true_north and camera_geo is None:
            return f"{name}: a TRUE datum needs the camera's geodetic pose (--camera-geo)"
        deg, metres = _CONE_UNITS[cone.coordinate_system]
        values = (cone.azimuth * deg, cone.elevation * deg, cone.range * metres)
        extents = (cone.horizontal_extent * deg, cone.vertical_extent * deg)
        if not all(map(math.isfinite, values + extents)) or min(extents) <= 0 or values[2] < 0:
            return f"{name}: cone needs finite values and positive horizontal and vertical extents"
        return Region(region.region_id, ignore, cone=values + extents, true_north=true_north)
    if kind == "location_list":
        points = area.location_list.locations
        if len(points) < 3:
            return f"{name}: a polygon needs at least 3 locations, got {len(points)}"
        systems = {p.coordinate_system for p in points}
        if len(systems) != 1 or next(iter(systems)) not in _POLYGON_UNITS:
            return f"{name}: polygon coordinates must all be LAT_LNG_DEG_M or LAT_LNG_RAD_M"
        if camera_geo is None:
            return f"{name}: a lat/lon polygon needs the camera's geodetic pose (--camera-geo)"
        scale = _POLYGON_UNITS[next(iter(systems))]
        polygon = tuple((p.x * scale, p.y * scale) for p in points)
        if not all(math.isfinite(v) for xy in polygon for v in xy):
            return f"{name}: polygon coordinates must be finite"
        return Region(region.region_id, ignore, polygon=polygon)
    return f"{name}: no region_area"


def _command(task: Task, outcome: dict, reasons: list[str]) -> None:
    command = task.command
    kind = command.WhichOneof("command")
    if kind == "request":
        request = command.request.strip().lower()
        if request not in [r.lower() for r in REQUESTS]:
            reasons.append(f"request {command.request!r} not supported ({', '.join(REQUESTS)})")
        elif request in ("start", "stop"):
            outcome["reporting"] = request == "start"
        elif request == "heartbeat":
            outcome["send_status"] = True
        elif request == "registration":
            outcome["register_again"] = True
        else:  # reset
            outcome.update(reporting=True, regions=(), active_task_id="")
    elif kind == "mode_change":
        if command.mode_change.strip().lower() != MODE_NAME:
            reasons.append(f"mode {command.mode_change!r} not supported (the one mode is {MODE_NAME!r})")
        else:
            outcome["send_status"] = True
    elif kind is not None:
        reasons.append(f"command {kind} not supported (request, mode_change)")


def interpret_task(task: Task, camera_geo: CameraGeo | None) -> TaskOutcome:
    """The outcome of ``task``: accepted with its effects, or rejected with every reason."""
    task_id = task.task_id
    if not task_id:
        return TaskOutcome(task_id, False, ("task_id is empty",))
    if task.control == Task.CONTROL_PAUSE:
        return TaskOutcome(task_id, False, ("control PAUSE not supported (START, STOP)",))
    if task.control == Task.CONTROL_STOP:
        return TaskOutcome(task_id, True, end_task=True)
    reasons: list[str] = []
    outcome: dict = {}
    if task.HasField("command"):
        _command(task, outcome, reasons)
    regions = [_region(region, i, camera_geo) for i, region in enumerate(task.region)]
    reasons += [r for r in regions if isinstance(r, str)]
    if reasons:
        return TaskOutcome(task_id, False, tuple(reasons))
    if regions:
        outcome.update(regions=tuple(regions), active_task_id=task_id)
    if not outcome:
        return TaskOutcome(task_id, False, ("the task has no command and no region: nothing to do",))
    return TaskOutcome(task_id, True, **outcome)
