"""The ``camera`` section: the camera's id, its calibration file and its pose (``geo`` on the
Earth, or ``extrinsics`` in a site frame; ``daemon/camera_pose.py``).

The camera id is a Zenoh key chunk (``dronekey/<id>/tracks``) and part of the MCAP file names, so
one rule (``CAMERA_ID``) holds wherever an id is taken: here, and in ``check_camera_id`` for the
message builders and the outputs that put it into a key or a file name.
"""

from __future__ import annotations

import re

from pydantic import Field, FilePath, field_validator, model_validator

from dronekey.daemon.camera_pose import CameraPlacement, ExtrinsicsError, load_extrinsics
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
    """Identity, intrinsics and (optional) pose of the camera: ``geo`` or ``extrinsics``, not both."""

    id: str = Field("cam0", description="camera id: Zenoh key segment and MCAP frame ids")
    calibration: FilePath | None = Field(
        None, description="OpenCV calibration YAML; null: the file's sidecar, the sim preset's camera"
    )
    geo: str | None = Field(None, description="LAT,LON,ALT_M[,YAW,PITCH,ROLL] (degrees, metres)")
    extrinsics: FilePath | None = Field(
        None,
        description="site file (docs/design.md §5.4) with this camera id's R_site_cam, t_site_cam_m and "
        "the site's geodetic origin; the alternative to geo",
    )

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

    @model_validator(mode="after")
    def _one_pose(self) -> CameraConfig:
        if self.geo is not None and self.extrinsics is not None:
            raise ValueError(
                f"camera.geo ({self.geo!r}) and camera.extrinsics ({str(self.extrinsics)!r}) both give the "
                "camera's pose; set one"
            )
        if self.extrinsics is not None:
            try:
                load_extrinsics(self.extrinsics, self.id)
            except ExtrinsicsError as exc:
                raise ValueError(str(exc)) from None
        return self

    def placement(self) -> CameraPlacement | None:
        """The camera's pose (on the Earth, and in the site frame with ``extrinsics``), or None."""
        if self.extrinsics is not None:
            site = load_extrinsics(self.extrinsics, self.id)
            return CameraPlacement(site.camera_geo(), site)
        if self.geo is not None:
            return CameraPlacement(CameraGeo.parse(self.geo))
        return None

    def camera_geo(self) -> CameraGeo | None:
        """The geodetic pose (``geo`` parsed, or derived from ``extrinsics``), or None when neither."""
        placement = self.placement()
        return placement.geo if placement is not None else None
