"""Drone specifications: the 3D propeller-hub keypoints of a known drone model (docs/design.md §5.3).

Body frame FRD (x forward, y right, z down), origin at the centroid of the four propeller hubs,
metres. Keypoint order as listed in the file; the shipped specs use 1 front-right, 2 rear-right,
3 rear-left, 4 front-left (clockwise seen from above).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

__all__ = ["DroneSpec", "DroneSpecError", "available_specs", "load_spec"]


class DroneSpecError(ValueError):
    """A drone spec file is missing or malformed; the message names the problem."""


@dataclass(frozen=True)
class DroneSpec:
    """One drone model.

    Attributes
    ----------
    name : str
        Short id used in files and metadata (``mini2``, ``air2s``).
    keypoints_3d : (4, 3) array
        Propeller hub centres in the body frame (m), in keypoint order.
    keypoint_names : list of str
    prop_diameter_m : float
        Propeller diameter, used by the renderer and for the drone's extent.
    body : dict
        Renderer dimensions of the fuselage (length, width, height in m).
    sources : dict
        Where each dimension comes from.
    """

    name: str
    display_name: str
    keypoints_3d: np.ndarray
    keypoint_names: tuple[str, ...]
    prop_diameter_m: float
    body: dict = field(default_factory=dict)
    sources: dict = field(default_factory=dict)

    @cached_property
    def diagonal_m(self) -> float:
        """Largest hub-to-hub distance (the manufacturer's 'diagonal wheelbase'); computed once (the
        localiser asks for it several times a frame)."""
        k = self.keypoints_3d
        return float(max(np.linalg.norm(k[i] - k[j]) for i in range(4) for j in range(i + 1, 4)))

    @cached_property
    def extent_points_m(self) -> np.ndarray:
        """(36, 3) body-frame points (m) that bound the drone's image, read-only: 8 on each
        propeller disc's rim and the 4 bottom corners of a box under the hubs that holds the body
        and gimbal (``body``'s length and width, 1.4 times its height down; defaults from the
        wheelbase). Computed once: the localiser projects them for every tracked crop."""
        r = self.prop_diameter_m / 2
        ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        rim = np.c_[r * np.cos(ang), r * np.sin(ang), np.zeros(8)]
        pts = [hub + rim for hub in self.keypoints_3d]
        length = float(self.body.get("length", 0.65 * self.diagonal_m))
        width = float(self.body.get("width", 0.3 * self.diagonal_m))
        depth = 1.4 * float(self.body.get("height", 0.23 * self.diagonal_m))
        pts.append(np.array([[sx * length / 2, sy * width / 2, depth] for sx in (-1, 1) for sy in (-1, 1)]))
        points = np.vstack(pts)
        points.flags.writeable = False
        return points

    @property
    def extent_m(self) -> float:
        """Diameter of the circle that holds every propeller disc (for sizing crops)."""
        return self.diagonal_m + self.prop_diameter_m

    def to_dict(self) -> dict:
        """The ``drone`` object of a sequence JSON (docs/design.md §5.1)."""
        return {"model": self.name, "keypoints_3d": self.keypoints_3d.tolist()}


def _parse(data: dict, origin: str) -> DroneSpec:
    if not isinstance(data, dict):
        raise DroneSpecError(f"{origin}: top level must be a mapping")
    try:
        kp = np.asarray(data["keypoints_3d"], dtype=np.float64)
        name = str(data["name"])
    except KeyError as exc:
        raise DroneSpecError(f"{origin}: missing key {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise DroneSpecError(f"{origin}: keypoints_3d must be 4 rows of 3 numbers") from None
    if kp.shape != (4, 3) or not np.all(np.isfinite(kp)):
        raise DroneSpecError(f"{origin}: keypoints_3d must be 4 x 3 finite numbers, got shape {kp.shape}")
    if np.linalg.norm(kp.mean(axis=0)) > 1e-6:
        raise DroneSpecError(f"{origin}: keypoints_3d must be centred on the body origin (mean {kp.mean(0)})")
    names = tuple(data.get("keypoint_names", ["prop1", "prop2", "prop3", "prop4"]))
    if len(names) != 4:
        raise DroneSpecError(f"{origin}: keypoint_names must list 4 names, got {len(names)}")
    return DroneSpec(
        name=name,
        display_name=str(data.get("display_name", name)),
        keypoints_3d=kp,
        keypoint_names=names,
        prop_diameter_m=float(data.get("prop_diameter_m", 0.12)),
        body=dict(data.get("body", {})),
        sources=dict(data.get("sources", {})),
    )


def available_specs() -> list[str]:
    """Names of the specs shipped with the package."""
    folder = resources.files("dronekey.geometry") / "specs"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".yaml"))


def load_spec(name_or_path: str | Path) -> DroneSpec:
    """Load a shipped spec by name (``mini2``, ``air2s``) or a YAML file by path."""
    text: str
    origin = str(name_or_path)
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") or path.exists():
        if not path.is_file():
            raise DroneSpecError(f"drone spec file not found: {path}")
        text = path.read_text()
    else:
        res = resources.files("dronekey.geometry") / "specs" / f"{name_or_path}.yaml"
        if not res.is_file():
            raise DroneSpecError(
                f"unknown drone spec {name_or_path!r}; shipped: {', '.join(available_specs())}"
            )
        text = res.read_text()
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DroneSpecError(f"{origin}: not valid YAML ({exc})") from None
    return _parse(data, origin)
