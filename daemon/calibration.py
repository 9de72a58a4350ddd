"""Which intrinsics the daemon uses: ``--calib``, else what travels with the source, else stop.

The intrinsics are then scaled to the resolution the source actually delivers (same aspect ratio
only; another aspect ratio is refused, docs/design.md §5.2).
"""

from __future__ import annotations

from pathlib import Path

from dronekey.daemon.errors import UsageError
from dronekey.daemon.sources import FrameReader, SourceOpenError
from dronekey.geometry.camera import CalibrationError, CameraModel

__all__ = ["NO_CALIBRATION_HINT", "camera_at_resolution", "resolve_calibration"]

NO_CALIBRATION_HINT = (
    "pass --calib FILE or set camera.calibration (an OpenCV calibration YAML; make one with "
    "`dronekey-calib`, see docs/daemon.md), "
    "or put camera.yaml or the sequence JSON beside the video"
)


def resolve_calibration(calibration: Path | None, reader: FrameReader) -> tuple[CameraModel, str]:
    """The camera model and a description of where it came from.

    Raises
    ------
    UsageError
        The file is unusable, or there is no calibration at all (the message says how to get one).
    """
    if calibration is not None:
        try:
            return CameraModel.load(calibration), str(calibration)
        except CalibrationError as exc:
            raise UsageError(f"calibration: {exc}") from None
    try:
        bundled = reader.bundled_camera()
    except SourceOpenError as exc:
        raise UsageError(f"source: {exc}") from None
    if bundled is not None:
        return bundled
    raise UsageError(f"no calibration for {reader.description}: {NO_CALIBRATION_HINT}")


def camera_at_resolution(camera: CameraModel, width: int, height: int) -> CameraModel:
    """``camera`` scaled to the source's ``width`` x ``height``; UsageError if the aspect differs."""
    try:
        return camera.scaled_to(width, height)
    except CalibrationError as exc:
        raise UsageError(f"calibration: {exc}") from None
