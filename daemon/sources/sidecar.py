"""Find the calibration that travels with a recorded video or image folder.

Looked up in this order for ``DIR/NAME.ext`` (or the folder ``DIR/NAME``):

1. ``DIR/NAME.json``: a sequence JSON (docs/design.md §5.1) whose ``camera`` object holds the intrinsics,
   read with ``sim_replay.io.sequence_reader.load_sequence``;
2. ``DIR/NAME/camera.yaml`` (folders only), then ``DIR/camera.yaml``: an OpenCV calibration YAML.
"""

from __future__ import annotations

import logging
from pathlib import Path

from dronekey.daemon.errors import UsageError
from dronekey.geometry.camera import CalibrationError, CameraModel

__all__ = ["sidecar_camera"]

log = logging.getLogger(__name__)


def sidecar_camera(path: Path) -> tuple[CameraModel, str] | None:
    """The camera beside ``path`` and a description of where it came from, or None if there is none.

    Raises
    ------
    UsageError
        If a sidecar file exists but cannot be used (the user should fix or remove it).
    """
    path = Path(path)
    sequence_json = path.with_suffix(".json") if path.is_file() else path.parent / f"{path.name}.json"
    if sequence_json.is_file():
        return _camera_from_sequence(sequence_json), f"{sequence_json} (sequence JSON beside the source)"
    candidates = [path / "camera.yaml"] if path.is_dir() else []
    candidates.append(path.parent / "camera.yaml")
    for yaml_path in candidates:
        if yaml_path.is_file():
            try:
                return CameraModel.load(yaml_path), f"{yaml_path} (camera.yaml beside the source)"
            except CalibrationError as exc:
                raise UsageError(f"calibration: {exc}") from None
    return None


def _camera_from_sequence(path: Path) -> CameraModel:
    from dronekey.sim_replay.io.sequence_reader import load_sequence

    try:
        return load_sequence(path).camera
    except (CalibrationError, ValueError, KeyError, OSError) as exc:
        raise UsageError(f"calibration: cannot read the camera of {path}: {exc}") from None
