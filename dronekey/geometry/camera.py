"""Pinhole camera with OpenCV distortion: projection, undistortion, rescaling, calibration files.

Frames and units follow docs/design.md §4: camera frame x right, y down, z forward (metres); image
coordinates in pixels of the full frame with the origin at the centre of the top-left pixel.
Calibration files are OpenCV FileStorage YAML as OpenCV's calibration sample writes them (§5.2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

__all__ = ["CalibrationError", "CameraModel"]


class CalibrationError(ValueError):
    """A calibration file or camera model is unusable; the message says why."""


def _as_matrix3(K) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise CalibrationError(f"K must be 3x3, got shape {K.shape}")
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CalibrationError(f"K must be finite with fx, fy > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
    return K


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of one camera at one resolution.

    Parameters
    ----------
    width, height : int
        Image size in pixels that ``K`` refers to.
    K : (3, 3) array
        Camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels.
    dist : array of 4, 5, 8, 12 or 14 floats
        OpenCV distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6[, ...]]]); zeros if absent.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    rms_px: float | None = None

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise CalibrationError(f"image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "K", _as_matrix3(self.K))
        dist = np.asarray(self.dist, dtype=np.float64).ravel()
        if dist.size not in (0, 4, 5, 8, 12, 14):
            raise CalibrationError(f"dist must have 4, 5, 8, 12 or 14 coefficients, got {dist.size}")
        if not np.all(np.isfinite(dist)):
            raise CalibrationError(f"dist must be finite, got {dist.tolist()}")
        object.__setattr__(self, "dist", dist if dist.size else np.zeros(5))

    # ------------------------------------------------------------------ properties
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    # ------------------------------------------------------------------ geometry
    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project (N, 3) points in the camera frame (m) to (N, 2) distorted pixel coordinates."""
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
        return uv.reshape(-1, 2)

    def project_body(self, points_body: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Project (N, 3) body-frame points through the pose ``p_cam = R @ p_body + t`` to pixels."""
        rvec, _ = cv2.Rodrigues(np.asarray(R, dtype=np.float64))
        pts = np.asarray(points_body, dtype=np.float64).reshape(-1, 3)
        uv, _ = cv2.projectPoints(pts, rvec, np.asarray(t, dtype=np.float64).reshape(3), self.K, self.dist)
        return uv.reshape(-1, 2)

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Remove lens distortion from (N, 2) pixels; returns (N, 2) ideal pixels under the same K."""
        pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
        if not np.any(self.dist):
            return pts.reshape(-1, 2).copy()
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4.x
            und = cv2.undistortPointsIter(pts, self.K, self.dist, None, self.K, criteria)
        else:  # OpenCV 5 folded the criteria into undistortPoints
            und = cv2.undistortPoints(pts, self.K, self.dist, None, None, self.K, criteria)
        return und.reshape(-1, 2)

    def scaled_to(self, width: int, height: int) -> CameraModel:
        """The same camera at another resolution of the same aspect ratio.

        With the pixel-centre origin, a pixel coordinate maps as ``u' = (u + 0.5) * s - 0.5``, so
        ``fx' = s fx`` and ``cx' = (cx + 0.5) s - 0.5``. Distortion is resolution-independent.

        Raises
        ------
        CalibrationError
            If the aspect ratio differs by more than half a pixel.
        """
        width, height = int(width), int(height)
        if (width, height) == (self.width, self.height):
            return self
        sx, sy = width / self.width, height / self.height
        if abs(self.width * sy - width) > 0.5 or abs(self.height * sx - height) > 0.5:
            raise CalibrationError(
                f"calibration is for {self.width}x{self.height} but the source is {width}x{height}: "
                "the aspect ratio differs, so the intrinsics cannot be scaled; calibrate at this "
                "resolution (dronekey-calib)"
            )
        K = self.K.copy()
        K[0, 0] *= sx
        K[0, 1] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return CameraModel(width, height, K, self.dist.copy(), self.rms_px)

    def horizontal_fov_deg(self) -> float:
        return math.degrees(2.0 * math.atan2(self.width / 2.0, self.fx))

    # ------------------------------------------------------------------ I/O
    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float, dist=None) -> CameraModel:
        """A centred pinhole camera with square pixels and the given horizontal field of view."""
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1.0]])
        return cls(width, height, K, np.zeros(5) if dist is None else dist)

    def to_dict(self) -> dict:
        """The ``camera`` object of a sequence JSON (docs/design.md §5.1)."""
        return {
            "width": self.width,
            "height": self.height,
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> CameraModel:
        try:
            return cls(int(d["width"]), int(d["height"]), d["K"], d.get("dist", []))
        except KeyError as exc:
            raise CalibrationError(f"camera object lacks the key {exc.args[0]!r}") from None

    def save_yaml(self, path: str | Path) -> None:
        """Write OpenCV FileStorage YAML (§5.2) through a temporary file renamed at the end."""
        path = Path(path)
        tmp = path.with_name(f".{path.name}.tmp.yaml")
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        if not fs.isOpened():
            raise CalibrationError(f"cannot write calibration file {path}")
        fs.write("image_width", self.width)
        fs.write("image_height", self.height)
        fs.write("camera_matrix", self.K)
        fs.write("distortion_coefficients", self.dist.reshape(1, -1))
        fs.write("avg_reprojection_error", float(self.rms_px) if self.rms_px is not None else 0.0)
        fs.release()
        tmp.replace(path)

    @classmethod
    def load(cls, path: str | Path, allow_fisheye: bool = False) -> CameraModel:
        """Read an OpenCV FileStorage calibration (YAML or XML).

        Accepts the keys of OpenCV's calibration sample (``camera_matrix``,
        ``distortion_coefficients``, ``image_width``, ``image_height``) and, for stereo rigs, any one
        key starting with ``camera_matrix`` / ``distortion_coefficients``. A fisheye calibration
        (``fisheye_model: 1``) is refused unless ``allow_fisheye``: its four coefficients mean
        something else than this model's k1, k2, p1, p2.
        """
        path = Path(path)
        if not path.is_file():
            raise CalibrationError(f"calibration file not found: {path}")
        try:
            fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        except cv2.error as exc:
            raise CalibrationError(f"{path} is not an OpenCV FileStorage file: {exc.err}") from None
        if not fs.isOpened():
            raise CalibrationError(f"{path} is not an OpenCV FileStorage file")
        try:
            root = fs.root()
            keys = list(root.keys())
            K = _read_mat(fs, keys, "camera_matrix", path)
            dist = _read_mat(fs, keys, "distortion_coefficients", path)
            width = _read_int(fs, keys, "image_width", path)
            height = _read_int(fs, keys, "image_height", path)
            fisheye = fs.getNode("fisheye_model")
            if not allow_fisheye and not fisheye.empty() and fisheye.isInt() and int(fisheye.real()) == 1:
                raise CalibrationError(
                    f"{path} is a fisheye calibration (fisheye_model: 1); DroneKey uses OpenCV's pinhole "
                    "model with radial-tangential distortion: calibrate again without --fisheye"
                )
            rms_keys = [k for k in keys if k.startswith("avg_reprojection_error")]
            rms = float(fs.getNode(rms_keys[0]).real()) if len(rms_keys) == 1 else None
        finally:
            fs.release()
        return cls(width, height, K, dist.ravel(), rms)


def _find_key(keys: list[str], prefix: str, path: Path) -> str:
    if prefix in keys:
        return prefix
    cands = [k for k in keys if k.startswith(prefix)]
    if len(cands) == 1:
        return cands[0]
    raise CalibrationError(f"{path} has no '{prefix}' entry (keys: {', '.join(keys) or 'none'})")


def _read_mat(fs: cv2.FileStorage, keys: list[str], prefix: str, path: Path) -> np.ndarray:
    mat = fs.getNode(_find_key(keys, prefix, path)).mat()
    if mat is None:
        raise CalibrationError(f"{path}: '{prefix}' is not a matrix")
    return np.asarray(mat, dtype=np.float64)


def _read_int(fs: cv2.FileStorage, keys: list[str], prefix: str, path: Path) -> int:
    node = fs.getNode(_find_key(keys, prefix, path))
    value = node.real() if (node.isInt() or node.isReal()) else float("nan")
    if not math.isfinite(value) or value <= 0:
        raise CalibrationError(f"{path}: '{prefix}' must be a positive integer")
    return int(value)
