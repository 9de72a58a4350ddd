"""The ``camera`` section: the camera's id, its calibration file and its geodetic pose.

The camera id is a Zenoh key chunk (``dronekey/<id>/tracks``) and part of the MCAP file names, so
one rule (``CAMERA_ID``) holds wherever an id is taken: here, and in ``check_camera_id`` for the
message builders and the outputs that put it into a key or a file name.
"""

from __future__ import annotations

import re

from pydantic import Field, FilePath, field_validator

from dronekey.daemon.config.section import Section
from dronekey.daemon.geo import CameraGeo, GeoError

__all__ = ["CAMERA_ID", "CameraConfig", "check_camera_id"]

# No separators, wildcards or spaces: one key chunk and a safe file-name part.
CAMERA_ID = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
_CAMERA_ID_RULE = "1-64 characters of A-Z a-z 0-9 _ - . (it is a Zenoh key segment and a file-name part)"


def check_camera_id(camera_id: str) -> str:
    """Return ``camera_id`` if it matches ``CAMERA_ID``, else raise ValueError naming it."""
    if not isinstance(camera_id, str) or not CAMERA_ID.match(camera_id):
        raise ValueError(f"camera_id must be {_CAMERA_ID_RULE}, got {camera_id!r}")
    return camera_id


class CameraConfig(Section):
    """Identity, intrinsics and (optional) geodetic pose of the camera."""

    id: str = Field("cam0", description="camera id: Zenoh key segment and MCAP frame ids")
    calibration: FilePath | None = Field(
        None, description="OpenCV calibration YAML; null: the file's sidecar, the sim preset's camera"
    )
    geo: str | None = Field(None, description="LAT,LON,ALT_M[,YAW,PITCH,ROLL] (degrees, metres)")

    @field_validator("id")
    @classmethod
    def _id_chars(cls, v: str) -> str:
        if not CAMERA_ID.match(v):
            raise ValueError(f"must be {_CAMERA_ID_RULE}")
        return v

    @field_validator("geo")
    @classmethod
    def _geo_parses(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                CameraGeo.parse(v)
            except GeoError as exc:
                raise ValueError(str(exc)) from None
        return v

    def camera_geo(self) -> CameraGeo | None:
        """The parsed geodetic pose, or None when not configured."""
        return CameraGeo.parse(self.geo) if self.geo is not None else None
