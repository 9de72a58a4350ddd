"""Where the camera stands and looks: its pose from the config, on the Earth and in a site frame.

Two ways to give it (``camera`` section, docs/fleet.md):

- ``camera.geo`` (``--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL``): WGS84 position and mount
  attitude (daemon/geo.py);
- ``camera.extrinsics`` (``--camera-extrinsics FILE``): a site file (docs/design.md §5.4, what
  ``dronekey-sim --cameras N`` writes, or a surveyed one) holding a geodetic origin, a local
  East-North-Up frame at it, and per camera id ``R_site_cam`` / ``t_site_cam_m`` with
  ``p_site = R_site_cam @ p_cam + t_site_cam_m``. The daemon's camera is the entry whose id is
  ``camera.id``.

Either way the pose is also put on the Earth (ECEF, and the ``CameraGeo`` the geodetic outputs
use), so extrinsics serve MAVLink, SBS-1 and the track messages' lat/lon as ``geo`` does. The
``info`` queryable publishes it (``CameraPlacement.to_message``) for ``dronekey-fuse``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dronekey.daemon.geo import CameraGeo, ecef_from_lla, ecef_from_ned_rotation, lla_from_ecef
from dronekey.geometry.rotations import ned_from_camera
from dronekey.sim_replay.io.site import SITE_FRAME, enu_from_ned, load_site
from dronekey.sim_replay.io.validation import SequenceFormatError

__all__ = ["CameraPlacement", "ExtrinsicsError", "SitePlacement", "load_extrinsics"]

_FRD_FROM_CAMERA = ned_from_camera(0.0, 0.0, 0.0)  # camera axes -> the mount's forward-right-down


class ExtrinsicsError(ValueError):
    """An extrinsics file that cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class SitePlacement:
    """The camera's pose in a site frame (ENU at ``origin``: x east, y north, z up, metres)."""

    file: Path
    origin_lat_deg: float
    origin_lon_deg: float
    origin_alt_m: float
    R_site_cam: np.ndarray
    t_site_cam_m: np.ndarray

    @property
    def origin_ecef_m(self) -> np.ndarray:
        """The site origin in ECEF, m."""
        return ecef_from_lla(self.origin_lat_deg, self.origin_lon_deg, self.origin_alt_m)

    @property
    def R_ecef_site(self) -> np.ndarray:
        """Rotation from the site's ENU axes to ECEF axes."""
        return ecef_from_ned_rotation(self.origin_lat_deg, self.origin_lon_deg) @ enu_from_ned.T

    def camera_geo(self) -> CameraGeo:
        """The same pose as WGS84 position and yaw / pitch / roll at the camera (daemon/geo.py)."""
        lat, lon, alt = lla_from_ecef(self.origin_ecef_m + self.R_ecef_site @ self.t_site_cam_m)
        R_ned_cam = ecef_from_ned_rotation(lat, lon).T @ self.R_ecef_site @ self.R_site_cam
        yaw, pitch, roll = Rotation.from_matrix(R_ned_cam @ _FRD_FROM_CAMERA.T).as_euler("ZYX", degrees=True)
        return CameraGeo(lat, lon, alt, float(yaw) % 360.0, float(pitch), float(roll))


def load_extrinsics(path: str | Path, camera_id: str) -> SitePlacement:
    """The pose of ``camera_id`` from a site file (docs/design.md §5.4).

    Raises
    ------
    ExtrinsicsError
        Naming the file: unreadable, not a site file, or no camera ``camera_id`` in it.
    """
    path = Path(path)
    try:
        site = load_site(path)
    except FileNotFoundError:
        raise ExtrinsicsError(f"extrinsics file {path} does not exist") from None
    except SequenceFormatError as exc:  # its message names the file, the key and the value
        raise ExtrinsicsError(f"extrinsics file {exc}") from None
    except OSError as exc:
        raise ExtrinsicsError(f"extrinsics file {path}: {exc.strerror or exc}") from None
    try:
        camera = site.camera(camera_id)
    except KeyError as exc:
        raise ExtrinsicsError(f"extrinsics file {path}: {exc.args[0]} (camera.id / --camera-id)") from None
    return SitePlacement(
        file=path,
        origin_lat_deg=site.origin.lat,
        origin_lon_deg=site.origin.lon,
        origin_alt_m=site.origin.alt_m,
        R_site_cam=np.asarray(camera.R_site_cam, dtype=np.float64),
        t_site_cam_m=np.asarray(camera.t_site_cam_m, dtype=np.float64),
    )


@dataclass(frozen=True)
class CameraPlacement:
    """The camera's configured pose: ``geo`` always (derived from the site for extrinsics), and
    the site placement when the pose came from an extrinsics file."""

    geo: CameraGeo
    site: SitePlacement | None = None

    @property
    def source(self) -> str:
        """``geo`` or ``extrinsics``: which setting gave the pose."""
        return "geo" if self.site is None else "extrinsics"

    @property
    def ecef_m(self) -> np.ndarray:
        """The camera centre in ECEF, m (exact from the site when there is one)."""
        if self.site is None:
            return self.geo.ecef_m
        return self.site.origin_ecef_m + self.site.R_ecef_site @ self.site.t_site_cam_m

    @property
    def R_ecef_cam(self) -> np.ndarray:
        """Rotation camera frame -> ECEF axes."""
        return self.geo.R_ecef_cam if self.site is None else self.site.R_ecef_site @ self.site.R_site_cam

    def to_message(self) -> dict:
        """The ``camera_pose`` object of the info message (schema ``info``)."""
        site = None
        if self.site is not None:
            s = self.site
            site = {
                "file": str(s.file),
                "origin": {"lat": s.origin_lat_deg, "lon": s.origin_lon_deg, "alt_m": s.origin_alt_m},
                "frame": SITE_FRAME,
                "R_site_cam": s.R_site_cam.tolist(),
                "t_site_cam_m": s.t_site_cam_m.tolist(),
            }
        return {
            "source": self.source,
            "ecef": {"position_m": self.ecef_m.tolist(), "R_ecef_cam": self.R_ecef_cam.tolist()},
            "site": site,
        }
