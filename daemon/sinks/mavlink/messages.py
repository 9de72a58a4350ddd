"""Tracks to MAVLink messages: TARGET_RELATIVE, TARGET_ABSOLUTE, ADSB_VEHICLE, and our identity.

Frames (docs/design.md §4): a track's position and velocity are in the OpenCV camera frame (x right,
y down, z forward); its quaternion rotates the drone body (FRD) into that camera frame.

TARGET_RELATIVE uses ``TARGET_OBS_FRAME_BODY_FRD``: the "vehicle" is the sensor itself, whose body
frame is the camera mount with forward along the optical axis. The axes map as
``x_frd = z_cam`` (forward), ``y_frd = x_cam`` (right), ``z_frd = y_cam`` (down), i.e.
``p_frd = FRD_FROM_CAM @ p_cam``. ``q_sensor`` rotates that FRD frame into local NED when the camera's
geodetic pose is configured (the mount's yaw, pitch, roll), and is (0, 0, 0, 0), "ignored", otherwise.

Front and back. A symmetric drone's front cannot always be told from its back: ``Track.heading_confidence``
(0 a coin flip, 1 certain, NaN unknown) says how sure the track is. Of the messages sent here only
TARGET_RELATIVE carries an attitude uncertainty, ``yaw_std``, which never claims more than the
front/back doubt allows (``target_relative``, ``heading_flip_yaw_std``). TARGET_ABSOLUTE has no
attitude uncertainty field: its ``q_target`` and body-frame ``vel`` are the published heading as it
is (read TARGET_RELATIVE's ``yaw_std`` of the same track). ADSB_VEHICLE's heading is the course over
ground, from the velocity, and does not depend on the drone's front.

Every function takes the generated dialect module (``dialect``, see ``dialect.load_dialect``) and
returns a message object ready for ``MAVLink.send``; none of them sends.
"""

from __future__ import annotations

import math
import re

import numpy as np

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.messages import check_heading_confidence
from dronekey.daemon.sinks.target_state import TargetGeodetic, callsign, icao_address, target_geodetic
from dronekey.geometry.rotations import matrix_to_quat_wxyz, ned_from_camera, quat_wxyz_to_matrix
from dronekey.types import Track

__all__ = [
    "FRD_FROM_CAM",
    "TRACK_MESSAGE_NAMES",
    "adsb_vehicle",
    "autopilot_version",
    "encode_version",
    "heading_flip_yaw_std",
    "heartbeat",
    "sensor_quaternion",
    "target_absolute",
    "target_relative",
    "track_messages",
]

# Camera frame (x right, y down, z forward) -> sensor body FRD (x forward, y right, z down): the
# mount's FRD frame is the NED frame of a level, north-looking mount (one definition, in rotations).
FRD_FROM_CAM = ned_from_camera(0.0, 0.0, 0.0)

# The per-track messages by id, in the order ``track_messages`` gives them.
TARGET_RELATIVE, TARGET_ABSOLUTE, ADSB_VEHICLE = 511, 510, 246
TRACK_MESSAGE_NAMES = {511: "TARGET_RELATIVE", 510: "TARGET_ABSOLUTE", 246: "ADSB_VEHICLE"}

_NO_QUATERNION = (0.0, 0.0, 0.0, 0.0)
_UNKNOWN3 = (math.nan, math.nan, math.nan)


def _finite(a: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(a)))


def _body_to_cam(track: Track) -> np.ndarray | None:
    q = np.asarray(track.quaternion_wxyz, dtype=np.float64).ravel()
    if q.shape != (4,) or not _finite(q) or np.linalg.norm(q) < 1e-9:
        return None
    return quat_wxyz_to_matrix(q)


def _quat_tuple(R: np.ndarray | None) -> tuple[float, float, float, float]:
    return _NO_QUATERNION if R is None else tuple(float(v) for v in matrix_to_quat_wxyz(R))


def sensor_quaternion(geo: CameraGeo | None) -> tuple[float, float, float, float]:
    """TARGET_RELATIVE's ``q_sensor``: sensor FRD -> local NED (w, x, y, z), or zeros without a geo pose."""
    if geo is None:
        return _NO_QUATERNION
    return _quat_tuple(geo.R_ned_cam @ FRD_FROM_CAM.T)


def heading_flip_yaw_std(heading_confidence: float) -> float:
    """Standard deviation of the target's yaw that the front/back doubt alone implies, rad.

    With ``q = (1 + heading_confidence) / 2`` the probability that the published front is the
    drone's front, the yaw is a two-point mixture: the published yaw with probability ``q``, and
    the yaw of the 180-degree twin about the body's vertical axis (yaw + pi: the body's x and y
    axes change sign, so the twin's yaw differs by exactly pi in any frame, whatever the tilt) with
    probability ``1 - q``. The mixture's variance about its mean is ``q (1 - q) pi^2``.

    Parameters
    ----------
    heading_confidence : float
        ``Track.heading_confidence`` in [0, 1]; NaN (a model without a front/back head) is taken as
        0, the conservative reading.

    Returns
    -------
    float
        ``pi * sqrt(q (1 - q))``: pi / 2 at a coin flip (or unknown), 0 when certain.

    Raises
    ------
    ValueError
        Naming ``heading_confidence`` and its value, if it is outside [0, 1].
    """
    confidence = check_heading_confidence(heading_confidence)
    if math.isnan(confidence):
        confidence = 0.0
    q = 0.5 * (1.0 + confidence)
    return math.pi * math.sqrt(q * (1.0 - q))


def target_relative(dialect, track: Track, q_sensor: tuple[float, ...], timestamp_us: int):
    """TARGET_RELATIVE (511) of one track, in the sensor's FRD frame (module docstring).

    Parameters
    ----------
    dialect : module
        The generated dialect (``dialect.load_dialect``).
    track : dronekey.types.Track
        The track; position and covariance in the camera frame, m and m^2.
    q_sensor : (4,) floats
        Sensor FRD -> local NED (w, x, y, z), or zeros (``sensor_quaternion``).
    timestamp_us : int
        Unix time of the state, µs (``target_state.unix_time_us``).

    Returns
    -------
    MAVLink_target_relative_message, with:

    pos_std : square roots of the FRD covariance's diagonal, m.
    yaw_std : standard deviation of the target's yaw about the sensor's FRD z (down) axis, rad:
        ``max(rotation_std_rad[1], heading_flip_yaw_std(heading_confidence))``, NaN when the
        track's rotation std is not finite (unknown). ``rotation_std_rad[1]`` is the track's
        rotation std about the camera y axis (= FRD z), the small-angle reading of a
        rotation-vector standard deviation. The tracker already folds the front/back doubt into
        ``rotation_std_rad`` (its variance gains ``q (1 - q) pi^2``, see ``heading_flip_yaw_std``),
        so it is not added again here; the floor only guarantees that ``yaw_std`` never claims a
        heading surer than ``heading_confidence`` allows (pi / 2 at a coin flip or when the
        confidence is unknown), whatever the camera's tilt spreads over the other components.
    q_target : drone body (FRD) -> sensor FRD, (w, x, y, z); zeros when the track has no attitude.
        While ``heading_confidence`` is low it may point the drone's back forward.
    id : track id modulo 256 (the field is uint8).

    Raises
    ------
    ValueError
        Naming ``heading_confidence`` if it is outside [0, 1].
    """
    p_frd = FRD_FROM_CAM @ np.asarray(track.position_m, dtype=np.float64).reshape(3)
    cov = np.asarray(track.position_cov, dtype=np.float64).reshape(3, 3)
    pos_std = np.sqrt(np.clip(np.diag(FRD_FROM_CAM @ cov @ FRD_FROM_CAM.T), 0.0, None))
    filter_yaw_std = float(np.asarray(track.rotation_std_rad, dtype=np.float64).reshape(3)[1])
    flip_yaw_std = heading_flip_yaw_std(track.heading_confidence)
    yaw_std = max(filter_yaw_std, flip_yaw_std) if math.isfinite(filter_yaw_std) else math.nan
    R_cam_body = _body_to_cam(track)
    q_target = _quat_tuple(None if R_cam_body is None else FRD_FROM_CAM @ R_cam_body)
    return dialect.MAVLink_target_relative_message(
        timestamp_us,
        int(track.track_id) & 0xFF,
        dialect.TARGET_OBS_FRAME_BODY_FRD,
        float(p_frd[0]),
        float(p_frd[1]),
        float(p_frd[2]),
        [float(v) for v in pos_std],
        yaw_std,
        list(q_target),
        list(q_sensor),
        dialect.LANDING_TARGET_TYPE_VISION_OTHER,
    )


def target_absolute(dialect, track: Track, state: TargetGeodetic, geo: CameraGeo, timestamp_us: int):
    """TARGET_ABSOLUTE (510) of one track.

    vel : the track's velocity in the drone's body frame (FRD), m/s, when its attitude is known.
    q_target : drone body -> local NED at the camera (w, x, y, z).
    The message has no attitude uncertainty field: ``q_target`` and ``vel`` (whose x and y change
    sign with the front) are the published heading even while ``Track.heading_confidence`` is low;
    TARGET_RELATIVE's ``yaw_std`` of the same track says how far to trust them.
    position_std : (eph, epv) = (sqrt(var_north + var_east), sqrt(var_down)), m.
    Acceleration, rates and the velocity / acceleration standard deviations are not estimated:
    zeros (upstream's "invalid") and NaN.
    """
    caps = dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_POSITION
    R_cam_body = _body_to_cam(track)
    vel_body = (0.0, 0.0, 0.0)
    q_target = _NO_QUATERNION
    if R_cam_body is not None:
        caps |= dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_ATTITUDE
        q_target = _quat_tuple(geo.R_ned_cam @ R_cam_body)
        v_cam = np.asarray(track.velocity_mps, dtype=np.float64).reshape(3)
        if _finite(v_cam):
            caps |= dialect.TARGET_ABSOLUTE_SENSOR_CAPABILITY_VELOCITY
            vel_body = tuple(float(v) for v in R_cam_body.T @ v_cam)
    cov = state.position_cov_ned
    eph = math.sqrt(max(0.0, cov[0, 0] + cov[1, 1]))
    epv = math.sqrt(max(0.0, cov[2, 2]))
    return dialect.MAVLink_target_absolute_message(
        timestamp_us,
        int(track.track_id) & 0xFF,
        caps,
        _deg_e7(state.lat_deg),
        _deg_e7(state.lon_deg),
        float(state.alt_m),
        list(vel_body),
        [0.0, 0.0, 0.0],
        list(q_target),
        [0.0, 0.0, 0.0],
        [eph, epv],
        list(_UNKNOWN3),
        list(_UNKNOWN3),
    )


def adsb_vehicle(dialect, track: Track, state: TargetGeodetic, icao_base: int, simulated: bool = False):
    """ADSB_VEHICLE (246) of one track: emitter UAV, geometric altitude, callsign ``DKnnnnnn``."""
    flags = 0
    for name in (
        "ADSB_FLAGS_VALID_COORDS",
        "ADSB_FLAGS_VALID_ALTITUDE",
        "ADSB_FLAGS_VALID_VELOCITY",
        "ADSB_FLAGS_VALID_CALLSIGN",
        "ADSB_FLAGS_VERTICAL_VELOCITY_VALID",
    ):
        flags |= getattr(dialect, name)
    heading_cdeg = 0
    if state.course_deg is not None:
        flags |= dialect.ADSB_FLAGS_VALID_HEADING
        heading_cdeg = round(state.course_deg * 100) % 36000
    if simulated:
        flags |= dialect.ADSB_FLAGS_SIMULATED
    return dialect.MAVLink_adsb_vehicle_message(
        icao_address(track.track_id, icao_base),
        _deg_e7(state.lat_deg),
        _deg_e7(state.lon_deg),
        dialect.ADSB_ALTITUDE_TYPE_GEOMETRIC,
        _clip_int(state.alt_m * 1000.0, -(2**31), 2**31 - 1),
        heading_cdeg,
        _clip_int(state.ground_speed_mps * 100.0, 0, 0xFFFF),
        _clip_int(state.climb_rate_mps * 100.0, -(2**15), 2**15 - 1),
        callsign(track.track_id).encode("ascii"),
        dialect.ADSB_EMITTER_TYPE_UAV,
        0,
        flags,
        0,
    )


def track_messages(
    dialect,
    track: Track,
    timestamp_us: int,
    q_sensor: tuple[float, ...],
    geo: CameraGeo | None,
    icao_base: int,
    simulated: bool = False,
) -> list[tuple[int, object]]:
    """(message id, message) of one track: TARGET_RELATIVE, and with the camera's geodetic pose
    ``geo`` also TARGET_ABSOLUTE and ADSB_VEHICLE (``icao_base``, ``simulated``: ``adsb_vehicle``).

    Raises
    ------
    ValueError
        If the track's position is not finite, or naming ``heading_confidence`` if it is outside [0, 1].
    """
    if not _finite(np.asarray(track.position_m, dtype=np.float64)):
        raise ValueError("position is not finite")
    out = [(TARGET_RELATIVE, target_relative(dialect, track, q_sensor, timestamp_us))]
    if geo is not None:
        state = target_geodetic(track, geo)
        out.append((TARGET_ABSOLUTE, target_absolute(dialect, track, state, geo, timestamp_us)))
        out.append((ADSB_VEHICLE, adsb_vehicle(dialect, track, state, icao_base, simulated)))
    return out


def heartbeat(dialect, mav_type: int):
    """HEARTBEAT of a healthy DroneKey component: not an autopilot (MAV_AUTOPILOT_INVALID), active."""
    return dialect.MAVLink_heartbeat_message(
        mav_type,
        dialect.MAV_AUTOPILOT_INVALID,
        0,
        0,
        dialect.MAV_STATE_ACTIVE,
        3,  # mavlink_version: always 3 for MAVLink 1 and 2
    )


def encode_version(version: str) -> int:
    """MAVLink's 4-byte version word: major, minor, patch, FIRMWARE_VERSION_TYPE (official or dev)."""
    m = re.match(r"^(\d+)\.(\d+)(?:\.(\d+))?(.*)$", version.strip())
    if not m:
        return 0
    major, minor, patch = (min(int(g or 0), 255) for g in m.groups()[:3])
    kind = 255 if not m.group(4) else 0  # FIRMWARE_VERSION_TYPE_OFFICIAL / _DEV
    return (major << 24) | (minor << 16) | (patch << 8) | kind


def autopilot_version(dialect, version: str, uid: int = 0):
    """AUTOPILOT_VERSION, our identity: MAVLink 2 and COMMAND_INT capable, parameters as C casts
    (``parameters``), no MAVLink FTP (so ground stations need not try it), DroneKey's version."""
    caps = (
        dialect.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | dialect.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | dialect.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    )
    zeros8 = [0] * 8
    return dialect.MAVLink_autopilot_version_message(
        caps, encode_version(version), 0, 0, 0, zeros8, zeros8, zeros8, 0, 0, uid & 0xFFFFFFFFFFFFFFFF
    )


def _deg_e7(deg: float) -> int:
    return round(deg * 1e7)


def _clip_int(value: float, lo: int, hi: int) -> int:
    if not math.isfinite(value):
        return 0
    return int(min(max(round(value), lo), hi))
