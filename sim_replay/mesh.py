"""A quadcopter as a few convex parts in the FRD body frame, built from a ``DroneSpec``.

The propeller hubs sit exactly on the spec's ``keypoints_3d`` (z = 0 is the propeller plane; the
body hangs below it, +z is down). Real drones are not symmetric front to back, and neither is this
one: a gimbal camera under the nose, red LEDs under the front motors, a light stripe on the front of
the top shell, a dark battery bay underneath. Those cues are what lets a network tell propeller 1
from propeller 2 (DESIGN.md §4 keypoint order).

Every opaque part is a convex polyhedron, so the renderer can test a line of sight against it
exactly (see ``segment_hits``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dronekey.drone_spec import DroneSpec

__all__ = ["DroneMesh", "DroneStyle", "Part", "build_mesh", "segment_hits"]

OPAQUE, PROP, EMISSIVE = "opaque", "prop", "emissive"


@dataclass(frozen=True)
class Part:
    """A convex polyhedron (or a flat disc for propellers).

    vertices : (N, 3) body frame, metres.
    faces : polygons as vertex-index arrays, counter-clockwise seen from outside.
    role : which ``DroneStyle`` colour paints it ("body", "underside", "arms", ...).
    kind : "opaque", "prop" (translucent spinning disc) or "emissive" (LED, unlit).
    rotor : index 0-3 of the rotor this part belongs to, or -1.
    """

    name: str
    vertices: np.ndarray
    faces: tuple[np.ndarray, ...]
    role: str
    kind: str = OPAQUE
    rotor: int = -1
    planes: np.ndarray = field(
        default=None, repr=False
    )  # (F, 4): outward normal n, offset d; n.x <= d inside


@dataclass(frozen=True)
class DroneStyle:
    """Colours and propeller look of one rendered drone (randomised per sequence or sample)."""

    body: tuple[float, float, float] = (0.55, 0.56, 0.58)
    underside: tuple[float, float, float] = (0.18, 0.18, 0.2)
    arms: tuple[float, float, float] = (0.45, 0.46, 0.48)
    stripe: tuple[float, float, float] = (0.92, 0.92, 0.9)
    motor: tuple[float, float, float] = (0.12, 0.12, 0.13)
    prop: tuple[float, float, float] = (0.1, 0.1, 0.1)
    front_led: tuple[float, float, float] = (0.15, 0.15, 1.0)
    rear_led: tuple[float, float, float] = (0.3, 1.0, 0.35)
    prop_opacity: float = 0.35
    blade_opacity: float = 0.5
    blade_angle_deg: float = 0.0
    blade_smear_deg: float = 40.0
    gimbal: tuple[float, float, float] = (0.2, 0.2, 0.22)
    lens: tuple[float, float, float] = (0.05, 0.04, 0.04)

    def colour_of(self, role: str) -> np.ndarray:
        """BGR colour in [0, 1] of a part role."""
        return np.asarray(getattr(self, role), dtype=np.float64)

    @classmethod
    def random(cls, rng: np.random.Generator) -> DroneStyle:
        """A plausible consumer drone: grey, white or dark shell; spinning propellers."""
        family = rng.choice(3, p=[0.45, 0.35, 0.2])
        base = {0: 0.55, 1: 0.85, 2: 0.22}[int(family)] + rng.uniform(-0.08, 0.08)
        tint = rng.normal(0, 0.02, 3)
        body = np.clip(base + tint, 0.05, 0.97)
        arms = np.clip(body * rng.uniform(0.75, 1.0), 0, 1)
        return cls(
            body=tuple(body),
            underside=tuple(np.clip(body * rng.uniform(0.3, 0.6), 0, 1)),
            arms=tuple(arms),
            stripe=tuple(np.clip(1.2 - body + rng.normal(0, 0.03, 3), 0.05, 1)),
            motor=tuple(np.full(3, rng.uniform(0.06, 0.25))),
            prop=tuple(np.full(3, rng.uniform(0.03, 0.5))),
            prop_opacity=float(rng.uniform(0.12, 0.45)),
            blade_opacity=float(rng.uniform(0.25, 0.7)),
            blade_angle_deg=float(rng.uniform(0, 360)),
            blade_smear_deg=float(rng.uniform(8, 120)),
            front_led=tuple(np.clip(np.array([0.15, 0.2, 1.0]) + rng.normal(0, 0.05, 3), 0, 1)),
            rear_led=tuple(np.clip(np.array([0.3, 1.0, 0.35]) + rng.normal(0, 0.05, 3), 0, 1)),
        )


@dataclass(frozen=True)
class DroneMesh:
    """All parts of one drone, plus the keypoints (propeller hubs) in body coordinates.

    The ``face_*`` arrays flatten every face of every part for vectorised shading: vertex indices
    into ``vertices`` (the parts' vertices stacked), the first three of each face, and its part.
    """

    parts: tuple[Part, ...]
    keypoints: np.ndarray  # (4, 3)
    prop_radius: float
    vertices: np.ndarray = field(init=False, repr=False)
    face_vertices: tuple[np.ndarray, ...] = field(init=False, repr=False)
    face_tri: np.ndarray = field(init=False, repr=False)
    face_part: np.ndarray = field(init=False, repr=False)
    face_mean: np.ndarray = field(init=False, repr=False)  # (F, V): face centre = face_mean @ vertices

    def __post_init__(self) -> None:
        offsets = np.cumsum([0] + [len(p.vertices) for p in self.parts])
        faces, part_of = [], []
        for k, part in enumerate(self.parts):
            for f in part.faces:
                faces.append(f + offsets[k])
                part_of.append(k)
        object.__setattr__(self, "vertices", np.concatenate([p.vertices for p in self.parts]))
        object.__setattr__(self, "face_vertices", tuple(faces))
        object.__setattr__(self, "face_tri", np.array([f[:3] for f in faces]))
        object.__setattr__(self, "face_part", np.array(part_of))
        mean = np.zeros((len(faces), offsets[-1]))
        for i, f in enumerate(faces):
            mean[i, f] = 1.0 / len(f)
        object.__setattr__(self, "face_mean", mean)


# ----------------------------------------------------------------------------- primitives
def _planes(vertices: np.ndarray, faces: tuple[np.ndarray, ...]) -> np.ndarray:
    tri = vertices[np.array([f[:3] for f in faces])]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.c_[n, np.einsum("ij,ij->i", n, tri[:, 0])]


def _prism(section: np.ndarray, p0: np.ndarray, p1: np.ndarray, up: np.ndarray) -> tuple:
    """Prism from p0 to p1 with a convex 2D cross-section (M, 2) in the plane (side, up)."""
    axis = p1 - p0
    axis = axis / np.linalg.norm(axis)
    up = up - axis * (up @ axis)
    up /= np.linalg.norm(up)
    side = np.cross(up, axis)
    ring = section[:, 0:1] * side + section[:, 1:2] * up
    verts = np.concatenate([p0 + ring, p1 + ring])
    m = len(section)
    # section is counter-clockwise in (side, up); side x up = axis, so the p1 cap faces +axis.
    faces = [np.arange(m, 2 * m), np.arange(m - 1, -1, -1)]
    for i in range(m):
        j = (i + 1) % m
        faces.append(np.array([i, j, m + j, m + i]))
    return verts, tuple(faces)


def _rect(w: float, h: float) -> np.ndarray:
    return np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])


def _circle(r: float, n: int) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[r * np.cos(a), r * np.sin(a)]


def _part(name, verts, faces, role, kind=OPAQUE, rotor=-1) -> Part:
    verts = np.asarray(verts, dtype=np.float64)
    planes = _planes(verts, faces) if kind != PROP else None
    return Part(name, verts, faces, role, kind, rotor, planes)


# ----------------------------------------------------------------------------- the drone
def build_mesh(spec: DroneSpec) -> DroneMesh:
    """The drone of ``spec`` (cached per spec: the geometry never changes, colours come at render time).

    Dimensions come from ``spec.body`` (length, width, height, arm_width, motor_radius,
    motor_height) with defaults scaled from the wheelbase.
    """
    key = (spec.name, spec.keypoints_3d.tobytes(), spec.prop_diameter_m, tuple(sorted(spec.body.items())))
    if key not in _MESH_CACHE:
        _MESH_CACHE[key] = _build_mesh(spec)
    return _MESH_CACHE[key]


_MESH_CACHE: dict[tuple, DroneMesh] = {}


def _build_mesh(spec: DroneSpec) -> DroneMesh:
    kp = spec.keypoints_3d
    diag = spec.diagonal_m
    b = spec.body
    length = float(b.get("length", 0.65 * diag))
    width = float(b.get("width", 0.3 * diag))
    height = float(b.get("height", 0.23 * diag))
    arm_w = float(b.get("arm_width", 0.055 * diag))
    motor_r = float(b.get("motor_radius", 0.042 * diag))
    motor_h = float(b.get("motor_height", 0.075 * diag))
    prop_r = spec.prop_diameter_m / 2
    down = np.array([0.0, 0.0, 1.0])
    fwd = np.array([1.0, 0.0, 0.0])
    parts: list[Part] = []

    # Fuselage: a chamfered box hanging below the propeller plane. Top shell in the body colour,
    # underside darker (split into two prisms so each is convex and has its own colour).
    z_top = motor_h * 0.55
    z_mid = z_top + height * 0.6
    z_bot = z_top + height
    c = min(width, height) * 0.18
    upper = np.array(
        [
            [-width / 2, -(z_mid - z_top) / 2],
            [width / 2, -(z_mid - z_top) / 2],
            [width / 2 - c, (z_mid - z_top) / 2],
            [-width / 2 + c, (z_mid - z_top) / 2],
        ]
    )
    zc = (z_top + z_mid) / 2
    # The section's "up" is -z (towards the propellers); sections are symmetric left/right.
    v, f = _prism(upper, np.array([-length / 2, 0, zc]), np.array([length / 2, 0, zc]), -down)
    parts.append(_part("shell", v, f, "body"))
    lower = np.array(
        [
            [-width / 2 + c, -(z_bot - z_mid) / 2],
            [width / 2 - c, -(z_bot - z_mid) / 2],
            [width / 2, (z_bot - z_mid) / 2],
            [-width / 2, (z_bot - z_mid) / 2],
        ]
    )
    zc2 = (z_mid + z_bot) / 2
    v, f = _prism(lower, np.array([-length / 2, 0, zc2]), np.array([length * 0.46, 0, zc2]), -down)
    parts.append(_part("underside", v, f, "underside"))
    # A light stripe on the front half of the top shell (seen from above only).
    v, f = _prism(
        _rect(width * 0.35, 0.002),
        np.array([length * 0.05, 0, z_top - 0.0012 - 0.0005]),
        np.array([length * 0.45, 0, z_top - 0.0012 - 0.0005]),
        -down,
    )
    parts.append(_part("stripe", v, f, "stripe"))
    # Gimbal camera under the nose: a box and a dark lens looking forward.
    g = height * 0.5
    gx = length / 2 - g * 0.3
    v, f = _prism(
        _rect(g, g),
        np.array([gx - g / 2, 0, z_bot - g * 0.2]),
        np.array([gx + g / 2, 0, z_bot - g * 0.2]),
        -down,
    )
    parts.append(_part("gimbal", v, f, "gimbal"))
    v, f = _prism(
        _circle(g * 0.3, 10),
        np.array([gx + g / 2, 0, z_bot - g * 0.2]),
        np.array([gx + g / 2 + g * 0.15, 0, z_bot - g * 0.2]),
        -down,
    )
    parts.append(_part("lens", v, f, "lens"))

    for i in range(4):
        hub = kp[i]
        front = hub[0] > 0
        # Arm from the fuselage side to the motor, level with the shell's top half.
        root = np.array([hub[0] * 0.35, np.sign(hub[1]) * width * 0.4, z_top + height * 0.25])
        tip = np.array([hub[0], hub[1], motor_h * 0.75])
        v, f = _prism(_rect(arm_w, arm_w * 0.8), root, tip, -down)
        parts.append(_part(f"arm{i + 1}", v, f, "arms", rotor=i))
        # Motor can: a cylinder from just below the propeller plane down to the arm.
        v, f = _prism(_circle(motor_r, 12), hub + down * (motor_h * 1.05), hub + down * 0.002, fwd)
        parts.append(_part(f"motor{i + 1}", v, f, "motor", rotor=i))
        # LED under the motor: red at the front, green at the back.
        led = hub + down * (motor_h * 1.05 + 0.002)
        v, f = _prism(_rect(motor_r * 0.9, motor_r * 0.9), led - down * 0.002, led + down * 0.003, fwd)
        parts.append(_part(f"led{i + 1}", v, f, "front_led" if front else "rear_led", EMISSIVE, i))
        # Propeller disc just above the hub.
        n = 32
        ring = _circle(prop_r, n)
        verts = np.c_[hub[0] + ring[:, 0], hub[1] + ring[:, 1], np.full(n, hub[2] - 0.003)]
        parts.append(_part(f"prop{i + 1}", verts, (np.arange(n),), "prop", PROP, i))

    return DroneMesh(tuple(parts), kp.copy(), prop_r)


def segment_hits(part: Part, p0: np.ndarray, p1: np.ndarray, margin: float = -1e-4) -> bool:
    """Whether the open segment p0 -> p1 passes through the convex ``part`` (Cyrus-Beck clipping).

    Both points and the part's planes must be in the same frame; ``margin`` (m) grows (> 0) or
    shrinks (< 0) the part, so grazing rays do not count. Used for keypoint visibility.
    """
    if part.planes is None:
        return False
    d = p1 - p0
    t0, t1 = 0.0, 1.0
    for nx, ny, nz, off in part.planes:
        n = np.array([nx, ny, nz])
        denom = n @ d
        num = off + margin - n @ p0
        if abs(denom) < 1e-15:
            if num < 0:
                return False
            continue
        t = num / denom
        if denom > 0:
            t1 = min(t1, t)
        else:
            t0 = max(t0, t)
        if t0 > t1:
            return False
    return t1 - t0 > 1e-9 and t0 < 1.0 - 1e-9
