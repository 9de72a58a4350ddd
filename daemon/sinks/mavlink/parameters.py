"""The sensor's read-only MAVLink parameters and the parameter protocol that serves them.

Ground stations fetch every component's parameters when they see its heartbeat (PARAM_REQUEST_LIST)
and retry until they have ``param_count`` of them; a component that never answers is asked again
for as long as the link lasts. DroneKey answers with a few parameters that describe the sensor:
who it is (MAVLink ids, version, a hash of the camera id and of the model file) and what it sees
(image size, field of view, the mount's attitude from ``--camera-geo``). None of them can be set.

Encoding: values go in PARAM_VALUE's float as C casts (``MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST``,
advertised in AUTOPILOT_VERSION), so integers are kept below 2^24, where a float32 is exact: the
hashes are the first 24 bits of a SHA-256, the version is ``major * 10000 + minor * 100 + patch``.

Answers (all from our ids, to the station that asked):

- PARAM_REQUEST_LIST: one PARAM_VALUE per parameter, ``param_index`` 0..n-1, ``param_count`` n;
- PARAM_REQUEST_READ: that parameter, by ``param_index``, or by ``param_id`` when the index is -1;
  an unknown name or index gets no answer (the protocol has no "not found" in common.xml);
- PARAM_SET: refused (read-only): the PARAM_VALUE of the current value, which the station takes as
  "the set did not happen"; an unknown name gets no answer.
"""

from __future__ import annotations

import hashlib
import logging
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass

from dronekey.daemon.geo import CameraGeo
from dronekey.geometry.camera import CameraModel

__all__ = ["Parameter", "ParameterServer", "encode_version_number", "sensor_parameters"]

log = logging.getLogger(__name__)

_NAME_LEN = 16  # PARAM_VALUE.param_id: char[16], NUL-terminated only when shorter
_FLOAT32_EXACT = 1 << 24


@dataclass(frozen=True)
class Parameter:
    """One read-only parameter: ``name`` (at most 16 characters), its value and whether it is an
    integer (MAV_PARAM_TYPE_INT32, below 2^24) or a float (MAV_PARAM_TYPE_REAL32)."""

    name: str
    value: float
    integer: bool = False

    def __post_init__(self) -> None:
        if not 0 < len(self.name) <= _NAME_LEN or not self.name.isascii():
            raise ValueError(f"parameter name must be 1..16 ASCII characters, got {self.name!r}")
        if self.integer and not (float(self.value).is_integer() and abs(self.value) < _FLOAT32_EXACT):
            raise ValueError(f"integer parameter {self.name} must be below 2^24, got {self.value!r}")


def encode_version_number(version: str) -> int:
    """``major * 10000 + minor * 100 + patch`` of a version string (0.1.0 -> 100); 0 if unreadable."""
    m = re.match(r"^(\d+)\.(\d+)(?:\.(\d+))?", version.strip())
    if not m:
        return 0
    major, minor, patch = (min(int(g or 0), 99) for g in m.groups())
    return major * 10000 + minor * 100 + patch


def _hash24(text: str) -> int:
    """The first 24 bits of the SHA-256 of ``text`` (exact in a float32)."""
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:3], "big")


def sensor_parameters(
    sysid: int,
    compid: int,
    version: str,
    camera_id: str | None = None,
    camera: CameraModel | None = None,
    model_info: Mapping | None = None,
    camera_geo: CameraGeo | None = None,
) -> list[Parameter]:
    """The parameters DroneKey serves, in index order; those whose source is not given are left out.

    DK_SYSID, DK_COMPID : our MAVLink ids. DK_VERSION : ``encode_version_number(version)``.
    DK_CAM_ID_HASH : 24-bit hash of the camera id (``--camera-id``), to tell sensors apart.
    DK_MODEL_HASH : the first 24 bits of the keypoint model file's SHA-256 (``model_info["sha256"]``).
    DK_IMG_WIDTH, DK_IMG_HEIGHT : image size, px. DK_HFOV_DEG, DK_VFOV_DEG : field of view of the
    pinhole intrinsics, degrees. DK_CAM_YAW/PITCH/ROLL : the mount's attitude from ``--camera-geo``, degrees.
    """
    out = [
        Parameter("DK_SYSID", sysid, integer=True),
        Parameter("DK_COMPID", compid, integer=True),
        Parameter("DK_VERSION", encode_version_number(version), integer=True),
    ]
    if camera_id:
        out.append(Parameter("DK_CAM_ID_HASH", _hash24(camera_id), integer=True))
    sha = (model_info or {}).get("sha256")
    if isinstance(sha, str) and re.fullmatch(r"[0-9a-fA-F]{6,}", sha):
        out.append(Parameter("DK_MODEL_HASH", int(sha[:6], 16), integer=True))
    if camera is not None:
        out += [
            Parameter("DK_IMG_WIDTH", camera.width, integer=True),
            Parameter("DK_IMG_HEIGHT", camera.height, integer=True),
            Parameter("DK_HFOV_DEG", camera.horizontal_fov_deg()),
            Parameter("DK_VFOV_DEG", math.degrees(2.0 * math.atan2(camera.height / 2.0, camera.fy))),
        ]
    if camera_geo is not None:
        out += [
            Parameter("DK_CAM_YAW", camera_geo.yaw_deg),
            Parameter("DK_CAM_PITCH", camera_geo.pitch_deg),
            Parameter("DK_CAM_ROLL", camera_geo.roll_deg),
        ]
    return out


class ParameterServer:
    """Answers PARAM_REQUEST_LIST, PARAM_REQUEST_READ and PARAM_SET aimed at our component.

    Parameters
    ----------
    dialect : the generated dialect module.
    sysid, compid : our ids; a request is ours when its target system is ours or 0 and its target
        component ours or 0 (MAV_COMP_ID_ALL).
    parameters : the table, in index order (``sensor_parameters``).
    """

    def __init__(self, dialect, sysid: int, compid: int, parameters: list[Parameter]) -> None:
        names = [p.name for p in parameters]
        if len(set(names)) != len(names):
            raise ValueError(f"parameter names must be unique, got {names}")
        self._d = dialect
        self._sysid, self._compid = sysid, compid
        self._params = list(parameters)
        self._index = {p.name: i for i, p in enumerate(self._params)}

    @property
    def parameters(self) -> list[Parameter]:
        return list(self._params)

    def handle(self, msg) -> list | None:
        """Replies to a parameter request (possibly none), or None when ``msg`` is no parameter request."""
        kind = msg.get_type()
        if kind not in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            return None
        if msg.target_system not in (0, self._sysid) or msg.target_component not in (0, self._compid):
            return []
        if kind == "PARAM_REQUEST_LIST":
            return [self._value(i) for i in range(len(self._params))]
        name = _param_name(msg.param_id)
        if kind == "PARAM_REQUEST_READ":
            index = msg.param_index if msg.param_index >= 0 else self._index.get(name, -1)
            return [self._value(index)] if 0 <= index < len(self._params) else []
        index = self._index.get(name)
        if index is None:
            return []
        log.info(
            "system %d/%d tried to set %s to %s: refused, DroneKey's parameters are read-only",
            msg.get_srcSystem(),
            msg.get_srcComponent(),
            name,
            msg.param_value,
        )
        return [self._value(index)]

    def _value(self, index: int):
        p = self._params[index]
        d = self._d
        kind = d.MAV_PARAM_TYPE_INT32 if p.integer else d.MAV_PARAM_TYPE_REAL32
        return d.MAVLink_param_value_message(
            p.name.encode("ascii"), float(p.value), kind, len(self._params), index
        )


def _param_name(raw) -> str:
    """``param_id`` as text: pymavlink gives str (cut at the first NUL) or bytes."""
    if isinstance(raw, bytes):
        raw = raw.split(b"\0", 1)[0].decode("ascii", "replace")
    return str(raw).split("\0", 1)[0]
