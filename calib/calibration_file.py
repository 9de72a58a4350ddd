"""The calibration file: OpenCV FileStorage YAML as OpenCV's calibration sample writes it
(docs/design.md §5.2).

Written keys: ``calibration_time``, ``nr_of_frames``, ``image_width``, ``image_height``,
``pattern``, ``board_width``, ``board_height``, ``square_size`` (metres), ``marker_size`` and
``aruco_dictionary`` (ChArUco), ``flags``, ``fisheye_model`` (0 or 1), ``camera_matrix`` (3x3),
``distortion_coefficients`` (1xN: k1 k2 p1 p2 k3, or k1..k4 for the fisheye model),
``avg_reprojection_error`` (px), ``per_view_reprojection_errors`` (Nx1 px),
``extrinsic_parameters`` (Nx6: Rodrigues vector, translation in metres, board in camera frame)
and ``views`` (the picture of each row). ``dronekey.geometry.camera.CameraModel.load`` reads it.
"""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np

from dronekey.calib.calibrate import CalibrationResult
from dronekey.calib.errors import CalibInputError
from dronekey.calib.patterns import BoardPattern
from dronekey.geometry.camera import CalibrationError, CameraModel

__all__ = ["load_calibration", "write_calibration"]


def write_calibration(path: Path, result: CalibrationResult, pattern: BoardPattern) -> None:
    """Write ``result`` to ``path`` through a temporary file in the same folder, renamed at the end.

    A reader never sees a half-written file, and a failed run leaves an earlier calibration intact.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise CalibInputError(f"cannot write {path}: folder {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.yaml")
    fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise CalibInputError(f"cannot write {path}: the folder is not writable")
    written = False
    try:
        camera = result.camera
        fs.write("calibration_time", datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))
        fs.write("nr_of_frames", len(result.view_names))
        fs.write("image_width", camera.width)
        fs.write("image_height", camera.height)
        fs.write("pattern", pattern.kind)
        fs.write("board_width", pattern.cols)
        fs.write("board_height", pattern.rows)
        fs.write("square_size", float(pattern.square))
        if pattern.kind == "charuco":
            fs.write("marker_size", float(pattern.marker))
            fs.write("aruco_dictionary", pattern.dictionary_name)
        fs.write("flags", int(result.flags))
        fs.write("fisheye_model", 1 if result.fisheye else 0)
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.dist.reshape(1, -1))
        fs.write("avg_reprojection_error", float(result.rms))
        fs.write("per_view_reprojection_errors", result.per_view_rms.reshape(-1, 1).astype(np.float64))
        fs.write("extrinsic_parameters", np.hstack([result.rvecs, result.tvecs]).astype(np.float64))
        fs.startWriteStruct("views", cv2.FileNode_SEQ)
        for name in result.view_names:
            fs.write("", str(name))
        fs.endWriteStruct()
        fs.release()
        tmp.replace(path)
        written = True
    finally:
        fs.release()
        if not written:
            tmp.unlink(missing_ok=True)


def load_calibration(path: Path) -> tuple[CameraModel, bool]:
    """Read a calibration with ``CameraModel.load``; also say whether it is a fisheye model.

    Raises
    ------
    CalibInputError
        The file is missing or is not a usable calibration (the message says which).
    """
    try:
        camera = CameraModel.load(path, allow_fisheye=True)
    except CalibrationError as exc:
        raise CalibInputError(str(exc)) from None
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        node = fs.getNode("fisheye_model")
        fisheye = bool(not node.empty() and node.isInt() and int(node.real()) == 1)
    finally:
        fs.release()
    if fisheye and camera.dist.size != 4:
        raise CalibInputError(
            f"{path}: fisheye_model is 1 but there are {camera.dist.size} distortion coefficients"
        )
    return camera, fisheye
