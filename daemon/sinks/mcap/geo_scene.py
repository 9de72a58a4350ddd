"""The map and the 3D scene of the Foxglove log: where the camera and each track are on the Earth
(``foxglove.LocationFix``, the camera's field of view as ``foxglove.GeoJSON``) and a 3D scene in the
camera frame (``foxglove.SceneUpdate``: the camera's frustum, a quadcopter per track at its pose,
the track's recent path).

Frames: the scene is drawn in the camera frame (OpenCV: x right, y down, z forward, metres), named
as the camera id like the images and ``/tf``; the drone model is in its body frame (FRD) placed by
the track's pose. LocationFix covariances are East-North-Up, m^2, as Foxglove wants them.
"""

from __future__ import annotations

import collections
import json
import math
from collections.abc import Iterable

import numpy as np
from foxglove import messages as fgm

from dronekey.daemon.geo import CameraGeo
from dronekey.daemon.sinks.mcap.foxglove import TRACK_RGBA, colour, timestamp
from dronekey.geometry.camera import CameraModel
from dronekey.types import Track, TrackStatus

__all__ = ["FOV_RANGE_M", "TrackPaths", "camera_fix", "fov_geojson", "scene_update", "track_fix"]

FOV_RANGE_M = 300.0  # how far the field-of-view wedge on the map reaches, m
FRUSTUM_DEPTH_M = 10.0  # depth of the frustum drawn in 3D, m
ARM_M = 0.15  # the drawn quadcopter: arm length from the centre, m (0.3 m across the rotors)
ROTOR_DIAMETER_M = 0.13
PATH_WINDOW_NS = 10_000_000_000  # a track's path shows its last 10 s
_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_CAMERA_RGBA = (0.2, 0.6, 1.0, 1.0)
_FRONT_RGBA = (1.0, 0.25, 0.25, 1.0)  # the two front arms: which way the track thinks is forward
_REAR_RGBA = (0.8, 0.8, 0.8, 1.0)


def _finite_pose(track: Track) -> tuple[np.ndarray, np.ndarray] | None:
    """(position_m, unit quaternion wxyz) of a track, or None when either is not finite."""
    p = np.asarray(track.position_m, dtype=np.float64).reshape(-1)
    q = np.asarray(track.quaternion_wxyz, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or q.shape != (4,) or not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        return None
    norm = float(np.linalg.norm(q))
    return (p, q / norm) if norm > 1e-12 else None


def camera_fix(t_ns: int, camera_id: str, geo: CameraGeo) -> fgm.LocationFix:
    """``foxglove.LocationFix`` of the camera (its configured position; covariance unknown)."""
    return fgm.LocationFix(
        timestamp=timestamp(t_ns),
        frame_id=camera_id,
        latitude=geo.lat_deg,
        longitude=geo.lon_deg,
        altitude=geo.alt_m,
        position_covariance=[0.0] * 9,
        position_covariance_type=fgm.LocationFixPositionCovarianceType.Unknown,
        color=colour(_CAMERA_RGBA),
    )


def track_fix(t_ns: int, track: Track, geo: CameraGeo) -> fgm.LocationFix | None:
    """``foxglove.LocationFix`` of a track (frame ``drone_<id>``), its position covariance rotated
    from the camera frame into East-North-Up; None without a finite position."""
    p = np.asarray(track.position_m, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return None
    lat, lon, alt = geo.geodetic(p)
    cov_cam = np.asarray(track.position_cov, dtype=np.float64).reshape(3, 3)
    rotation = _NED_TO_ENU @ geo.R_ned_cam
    cov_enu = rotation @ cov_cam @ rotation.T
    known = bool(np.all(np.isfinite(cov_enu)))
    status = track.status.value if isinstance(track.status, TrackStatus) else str(track.status)
    return fgm.LocationFix(
        timestamp=timestamp(t_ns),
        frame_id=f"drone_{int(track.track_id)}",
        latitude=lat,
        longitude=lon,
        altitude=alt,
        position_covariance=[float(v) for v in (cov_enu if known else np.zeros((3, 3))).ravel()],
        position_covariance_type=(
            fgm.LocationFixPositionCovarianceType.Known
            if known
            else fgm.LocationFixPositionCovarianceType.Unknown
        ),
        color=colour(TRACK_RGBA),
        metadata=[
            fgm.KeyValuePair(key="track_id", value=str(int(track.track_id))),
            fgm.KeyValuePair(key="status", value=status),
        ],
    )


def _edge_rays(camera: CameraModel, n: int) -> list[np.ndarray]:
    """Unit camera-frame rays through ``n`` points of the image's middle row, left to right
    (undistorted pinhole rays: the wedge is a picture of the coverage, not a measurement)."""
    k_inv = np.linalg.inv(camera.K)
    rays = []
    for u in np.linspace(-0.5, camera.width - 0.5, n):
        ray = k_inv @ np.array([u, camera.K[1, 2], 1.0])
        rays.append(ray / np.linalg.norm(ray))
    return rays


def fov_geojson(
    camera_id: str, camera: CameraModel, geo: CameraGeo, range_m: float = FOV_RANGE_M
) -> fgm.GeoJson:
    """``foxglove.GeoJSON``: the camera's horizontal field of view as a polygon (a wedge from the
    camera to ``range_m`` along the image's middle row), for the Map panel."""
    ring = [geo.geodetic(np.zeros(3))]
    ring += [geo.geodetic(ray * range_m) for ray in _edge_rays(camera, 9)]
    ring.append(ring[0])
    feature = {
        "type": "Feature",
        "properties": {"name": f"{camera_id} field of view", "range_m": range_m},
        "geometry": {"type": "Polygon", "coordinates": [[[lon, lat] for lat, lon, _ in ring]]},
    }
    return fgm.GeoJson(geojson=json.dumps({"type": "FeatureCollection", "features": [feature]}))


class TrackPaths:
    """Recent camera-frame positions of each live track (the last ``PATH_WINDOW_NS``), for its path."""

    def __init__(self, window_ns: int = PATH_WINDOW_NS) -> None:
        self._window_ns = int(window_ns)
        self._points: dict[int, collections.deque] = {}

    def update(self, t_ns: int, tracks: Iterable[Track]) -> None:
        """Add this frame's positions; forget lost tracks and points older than the window."""
        for track in tracks:
            tid = int(track.track_id)
            if track.status == TrackStatus.LOST:
                self._points.pop(tid, None)
                continue
            pose = _finite_pose(track)
            if pose is not None:
                self._points.setdefault(tid, collections.deque()).append((int(t_ns), pose[0]))
        for tid in list(self._points):
            points = self._points[tid]
            while points and (t_ns - points[0][0] > self._window_ns or points[0][0] > t_ns):
                points.popleft()  # too old, or time went back
            if not points:
                del self._points[tid]

    def path(self, track_id: int) -> list[np.ndarray]:
        return [p for _, p in self._points.get(int(track_id), ())]


def _point(p: Iterable[float]) -> fgm.Point3:
    x, y, z = (float(v) for v in p)
    return fgm.Point3(x=x, y=y, z=z)


def _frustum(t: fgm.Timestamp, camera_id: str, camera: CameraModel) -> fgm.SceneEntity:
    k_inv = np.linalg.inv(camera.K)
    w, h = camera.width - 0.5, camera.height - 0.5
    corners = [
        k_inv @ np.array([u, v, 1.0]) * FRUSTUM_DEPTH_M
        for u, v in ((-0.5, -0.5), (w, -0.5), (w, h), (-0.5, h))
    ]
    points = []
    for i, corner in enumerate(corners):
        points += [np.zeros(3), corner, corner, corners[(i + 1) % 4]]  # a ray and an edge of the far side
    line = fgm.LinePrimitive(
        type=fgm.LinePrimitiveLineType.LineList,
        pose=fgm.Pose(position=fgm.Vector3(), orientation=fgm.Quaternion(w=1.0)),
        thickness=2.0,
        scale_invariant=True,
        points=[_point(p) for p in points],
        color=colour(_CAMERA_RGBA),
    )
    return fgm.SceneEntity(timestamp=t, frame_id=camera_id, id="camera_frustum", lines=[line])


def _drone(t: fgm.Timestamp, track: Track, p: np.ndarray) -> fgm.SceneEntity:
    """A quadcopter in the track's body frame ``drone_<id>`` (FRD, placed by ``/tf``): 4 arms (the
    front two red), a rotor disc at each end and a label with the id and range."""
    identity = fgm.Quaternion(w=1.0)
    origin = fgm.Pose(position=fgm.Vector3(), orientation=identity)
    tips = [
        np.array([ARM_M * math.cos(a), ARM_M * math.sin(a), 0.0]) for a in np.radians([45, 135, 225, 315])
    ]
    arms = [
        fgm.LinePrimitive(
            type=fgm.LinePrimitiveLineType.LineStrip,
            pose=origin,
            thickness=0.03,
            points=[_point(np.zeros(3)), _point(tip)],
            color=colour(_FRONT_RGBA if tip[0] > 0 else _REAR_RGBA),
        )
        for tip in tips
    ]
    discs = [
        fgm.CylinderPrimitive(
            pose=fgm.Pose(position=fgm.Vector3(x=tip[0], y=tip[1], z=-0.02), orientation=identity),
            size=fgm.Vector3(x=ROTOR_DIAMETER_M, y=ROTOR_DIAMETER_M, z=0.01),
            bottom_scale=1.0,
            top_scale=1.0,
            color=colour((*TRACK_RGBA[:3], 0.7)),
        )
        for tip in tips
    ]
    label = fgm.TextPrimitive(
        pose=fgm.Pose(position=fgm.Vector3(z=-0.25), orientation=identity),
        billboard=True,
        font_size=14.0,
        scale_invariant=True,
        color=colour(TRACK_RGBA),
        text=f"#{int(track.track_id)} {float(np.linalg.norm(p)):.1f} m",
    )
    return fgm.SceneEntity(
        timestamp=t,
        frame_id=f"drone_{int(track.track_id)}",
        id=f"drone_{int(track.track_id)}",
        frame_locked=True,
        lines=arms,
        cylinders=discs,
        texts=[label],
    )


def scene_update(
    t_ns: int, camera_id: str, camera: CameraModel, tracks: Iterable[Track], paths: TrackPaths
) -> fgm.SceneUpdate:
    """``foxglove.SceneUpdate`` replacing the whole scene: the frustum, each live track's drone at its
    pose and its path over the last ``PATH_WINDOW_NS`` (``paths`` already holds this frame)."""
    t = timestamp(t_ns)
    entities = [_frustum(t, camera_id, camera)]
    for track in tracks:
        pose = _finite_pose(track)
        if track.status == TrackStatus.LOST or pose is None:
            continue
        entities.append(_drone(t, track, pose[0]))
        path = paths.path(track.track_id)
        if len(path) >= 2:
            line = fgm.LinePrimitive(
                type=fgm.LinePrimitiveLineType.LineStrip,
                pose=fgm.Pose(position=fgm.Vector3(), orientation=fgm.Quaternion(w=1.0)),
                thickness=2.0,
                scale_invariant=True,
                points=[_point(p) for p in path],
                color=colour((*TRACK_RGBA[:3], 0.8)),
            )
            entities.append(
                fgm.SceneEntity(
                    timestamp=t, frame_id=camera_id, id=f"path_{int(track.track_id)}", lines=[line]
                )
            )
    deletion = fgm.SceneEntityDeletion(timestamp=t, type=fgm.SceneEntityDeletionType.All)
    return fgm.SceneUpdate(deletions=[deletion], entities=entities)
