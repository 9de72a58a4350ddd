"""The site file (docs/design.md §5.4): where each camera of a multi-camera rendering stands.

``<out>/site.json`` written by ``dronekey-sim --cameras N`` names a geodetic origin, a local
East-North-Up frame at it (x east, y north, z up, metres) and, per camera, its folder and pose:

- ``geo``: the ``--camera-geo LAT,LON,ALT_M,YAW,PITCH,ROLL`` string the daemon takes for that camera
  (``daemon/geo.py``: yaw = heading of the optical axis from north, pitch up, roll clockwise seen from
  behind);
- ``R_site_cam``, ``t_site_cam_m``: ``p_site = R_site_cam @ p_cam + t_site_cam_m`` with the camera
  frame OpenCV's (x right, y down, z forward), metres.

The rotation and translation are exact for the rendering; ``geo`` gives the same pose through WGS84
(its angles are relative to north and the horizon at the camera, which differ from the origin's ENU
axes by the Earth's curvature: under 1e-5 rad over 50 m).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field, field_validator, model_validator

from dronekey.sim_replay.io.validation import (
    ReaderModel,
    RotationMatrix,
    Text,
    Vector3,
    problem,
    read_json_document,
    validate_at,
)

__all__ = [
    "SITE_FILE",
    "SITE_FORMAT",
    "SITE_FRAME",
    "SiteCamera",
    "SiteDocument",
    "SiteOrigin",
    "enu_from_ned",
    "load_site",
    "save_site",
]

SITE_FORMAT = "dronekey-site/1"
SITE_FILE = "site.json"
SITE_FRAME = "ENU at origin: x east, y north, z up, metres"

# Local North-East-Down -> East-North-Up (a proper rotation's sign flip: swap x/y, negate z).
enu_from_ned = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


class SiteOrigin(ReaderModel):
    """The site frame's origin on the WGS84 ellipsoid (degrees, metres above the ellipsoid)."""

    lat: float = Field(ge=-90, le=90, allow_inf_nan=False)
    lon: float = Field(ge=-180, le=180, allow_inf_nan=False)
    alt_m: float = Field(allow_inf_nan=False)


class SiteCamera(ReaderModel):
    """One camera: its id, its folder (relative to the site file) and its pose in the site frame."""

    id: Text
    folder: Text
    geo: Text
    R_site_cam: RotationMatrix
    t_site_cam_m: Vector3

    @field_validator("geo")
    @classmethod
    def _six_numbers(cls, value: str) -> str:
        parts = value.split(",")
        try:
            numbers = [float(p) for p in parts]
        except ValueError:
            raise problem(f"must be LAT,LON,ALT_M,YAW,PITCH,ROLL numbers, got {value!r}") from None
        if len(numbers) != 6 or not all(math.isfinite(n) for n in numbers):
            raise problem(f"must be six finite numbers LAT,LON,ALT_M,YAW,PITCH,ROLL, got {value!r}")
        return value

    @field_validator("folder")
    @classmethod
    def _relative(cls, value: str) -> str:
        if Path(value).is_absolute() or ".." in Path(value).parts:
            raise problem(f"must be a folder relative to the site file, got {value!r}")
        return value

    def site_from_cam(self, p_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) in metres -> site ENU metres."""
        return np.asarray(p_cam, dtype=np.float64) @ self.R_site_cam.T + self.t_site_cam_m

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "folder": self.folder,
            "geo": self.geo,
            "R_site_cam": np.asarray(self.R_site_cam, dtype=np.float64).tolist(),
            "t_site_cam_m": np.asarray(self.t_site_cam_m, dtype=np.float64).tolist(),
        }


class SiteDocument(ReaderModel):
    """A whole site file: ``format`` must be ``SITE_FORMAT``; camera ids and folders are distinct."""

    format: Text
    origin: SiteOrigin
    frame: Text = SITE_FRAME
    cameras: list[SiteCamera] = Field(min_length=1)

    @field_validator("format")
    @classmethod
    def _known_format(cls, value: str) -> str:
        if value != SITE_FORMAT:
            raise problem(f"must be {SITE_FORMAT!r}, got {value!r}")
        return value

    @model_validator(mode="after")
    def _distinct(self) -> SiteDocument:
        for key in ("id", "folder"):
            values = [getattr(c, key) for c in self.cameras]
            repeated = sorted({v for v in values if values.count(v) > 1})
            if repeated:
                raise problem(f"camera {key}s must be distinct, {repeated[0]!r} repeats")
        return self

    def camera(self, camera_id: str) -> SiteCamera:
        """The camera with this id (KeyError naming the known ids otherwise)."""
        for cam in self.cameras:
            if cam.id == camera_id:
                return cam
        raise KeyError(f"no camera {camera_id!r} in the site file; it has {[c.id for c in self.cameras]}")

    def to_dict(self) -> dict[str, Any]:
        return {
            "format": self.format,
            "origin": {"lat": self.origin.lat, "lon": self.origin.lon, "alt_m": self.origin.alt_m},
            "frame": self.frame,
            "cameras": [c.to_dict() for c in self.cameras],
        }


def load_site(path: str | Path) -> SiteDocument:
    """Read and validate a site file.

    Raises
    ------
    FileNotFoundError
        No such file.
    dronekey.sim_replay.io.validation.SequenceFormatError
        Not JSON, or a key is missing or wrong (the message names the file, key path and value).
    """
    path = Path(path)
    return validate_at(path, SiteDocument, read_json_document(path))


def save_site(site: SiteDocument, path: str | Path) -> None:
    """Write a site file, one camera per line, through a temporary file renamed at the end."""
    path = Path(path)
    doc = site.to_dict()
    head = {k: v for k, v in doc.items() if k != "cameras"}
    lines = ["{"] + [f" {json.dumps(k)}: {json.dumps(v, allow_nan=False)}," for k, v in head.items()]
    cameras = [f"  {json.dumps(c, allow_nan=False)}" for c in doc["cameras"]]
    lines += [' "cameras": [', ",\n".join(cameras), " ]", "}"]
    text = "\n".join(lines) + "\n"
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
