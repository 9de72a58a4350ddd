"""A quadcopter as a few convex parts in the FRD body frame, built from a ``DroneSpec`` and a
``drone_look.BodyShape``.

The propeller hubs sit exactly on the spec's ``keypoints_3d`` (z = 0 is the propeller plane; +z is
down): they are the labels and never move. The rest (shell, nose, battery, gimbal, arms, motors,
guards, legs, stripe, LED housings, end sensors, propeller discs) follows the shape, which is drawn
at random (``BodyShape.random``), so no single part marks a keypoint or the front in every drone and
a network trained on these renders has to read the whole shape. The default ``BodyShape()`` is the
first round's drone (gimbal under the nose, LEDs under the motors). Colours come at render time
(``drone_look.DroneStyle``).

Every opaque part is a convex polyhedron, so the renderer can test a line of sight against it
exactly (see ``segment_hits``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dronekey.geometry.drone_spec import DroneSpec
from dronekey.sim_replay.drone_look import BodyShape

__all__ = ["EMISSIVE", "OPAQUE", "PROP", "DroneMesh", "Part", "build_mesh", "segment_hits"]

OPAQUE, PROP, EMISSIVE = "opaque", "prop", "emissive"
NOSE_TIP_SCALE = 0.35  # a nose cone's tip section over its base
_POD_ENDS = {"none": (), "front": ("front",), "rear": ("rear",), "both": ("front", "rear")}


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


def _prism(
    section: np.ndarray,
    p0: np.ndarray,
    p1: np.ndarray,
    up: np.ndarray,
    end_scale: tuple[float, float] = (1.0, 1.0),
) -> tuple:
    """Prism (or frustum) from p0 to p1 with a convex 2D cross-section (M, 2) in the plane (side, up).

    ``end_scale`` scales the section at p1 along (side, up): every edge stays parallel to its
    counterpart at p0, so the side faces stay planar and the solid convex.
    """
    axis = p1 - p0
    axis = axis / np.linalg.norm(axis)
    up = up - axis * (up @ axis)
    up /= np.linalg.norm(up)
    side = np.cross(up, axis)
    ring0 = section[:, 0:1] * side + section[:, 1:2] * up
    ring1 = section[:, 0:1] * end_scale[0] * side + section[:, 1:2] * end_scale[1] * up
    verts = np.concatenate([p0 + ring0, p1 + ring1])
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
def build_mesh(spec: DroneSpec, shape: BodyShape | None = None) -> DroneMesh:
    """The drone of ``spec`` in ``shape`` (default: the spec's own body, gimbal under the nose).

    Cached per (spec, shape): colours come at render time. Dimensions the shape leaves at None come
    from ``spec.body`` (length, width, height, arm_width, motor_radius, motor_height) with defaults
    scaled from the wheelbase.
    """
    shape = shape or BodyShape()
    key = (spec.name, spec.keypoints_3d.tobytes(), spec.prop_diameter_m, tuple(sorted(spec.body.items())))
    key = (*key, shape.key())
    mesh = _MESH_CACHE.get(key)
    if mesh is None:
        if len(_MESH_CACHE) >= _MESH_CACHE_SIZE:
            _MESH_CACHE.pop(next(iter(_MESH_CACHE)))
        mesh = _MESH_CACHE[key] = _build_mesh(spec, shape)
    return mesh


_MESH_CACHE: dict[tuple, DroneMesh] = {}
_MESH_CACHE_SIZE = 64  # random shapes are rarely drawn twice: keep the cache bounded


def _build_mesh(spec: DroneSpec, shape: BodyShape) -> DroneMesh:
    kp = spec.keypoints_3d
    diag = spec.diagonal_m
    b = spec.body
    length = shape.length * diag if shape.length is not None else float(b.get("length", 0.65 * diag))
    width = shape.width * diag if shape.width is not None else float(b.get("width", 0.3 * diag))
    height = shape.height * diag if shape.height is not None else float(b.get("height", 0.23 * diag))
    arm_w = float(b.get("arm_width", 0.055 * diag)) * shape.arm_scale
    motor_r = float(b.get("motor_radius", 0.042 * diag))
    motor_h = float(b.get("motor_height", 0.075 * diag))
    prop_r = spec.prop_diameter_m / 2
    down = np.array([0.0, 0.0, 1.0])
    fwd = np.array([1.0, 0.0, 0.0])
    parts: list[Part] = []
    taper = (shape.nose_taper, shape.nose_taper)

    # Fuselage: a chamfered box (a frustum when the nose tapers) hanging below the propeller plane.
    # Top shell in the body colour, underside darker (two prisms, so each is convex and has its own
    # colour).
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
    x_rear, x_front = -length / 2, length / 2
    v, f = _prism(upper, np.array([x_rear, 0, zc]), np.array([x_front, 0, zc]), -down, taper)
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
    lower_end = 1.0 - (1.0 - shape.nose_taper) * 0.96
    v, f = _prism(
        lower, np.array([x_rear, 0, zc2]), np.array([length * 0.46, 0, zc2]), -down, (lower_end, lower_end)
    )
    parts.append(_part("underside", v, f, "underside"))
    # The body's frontmost face: the nose cone's tip (NOSE_TIP_SCALE of its base) or the shell's front.
    x_nose, nose_scale = x_front + shape.nose_length * diag, shape.nose_taper
    if shape.nose_length > 0:  # a tapered nose cone ahead of the shell
        nose = upper * shape.nose_taper
        tip = np.array([x_nose, 0, zc])
        v, f = _prism(nose, np.array([x_front, 0, zc]), tip, -down, (NOSE_TIP_SCALE, NOSE_TIP_SCALE))
        nose_scale *= NOSE_TIP_SCALE
        parts.append(_part("nose", v, f, "body"))
    if shape.battery > 0:  # battery pack bulging out of the rear top
        bl = shape.battery * length
        bw, bh = width * 0.7, height * 0.22
        v, f = _prism(
            _rect(bw, bh),
            np.array([x_rear - 0.1 * bl, 0, z_top - bh / 2 + 0.001]),
            np.array([x_rear + 0.9 * bl, 0, z_top - bh / 2 + 0.001]),
            -down,
        )
        parts.append(_part("battery", v, f, "underside"))
    if shape.stripe != "none":  # a light stripe on the top shell (seen from above only)
        lo, hi = {"front": (0.05, 0.45), "rear": (-0.45, -0.05), "full": (-0.45, 0.45)}[shape.stripe]
        v, f = _prism(
            _rect(width * 0.35, 0.002),
            np.array([length * lo, 0, z_top - 0.0017]),
            np.array([length * hi, 0, z_top - 0.0017]),
            -down,
        )
        parts.append(_part("stripe", v, f, "stripe"))
    if shape.gimbal != "none":  # gimbal camera: a box and a dark lens looking forward
        g = height * 0.5 * shape.gimbal_size
        if shape.gimbal == "nose":
            gx, gz = x_front - g * 0.3, z_bot - g * 0.2
        else:
            gx, gz = x_front * 0.55, z_top - g / 2 - 0.002
        v, f = _prism(_rect(g, g), np.array([gx - g / 2, 0, gz]), np.array([gx + g / 2, 0, gz]), -down)
        parts.append(_part("gimbal", v, f, "gimbal"))
        v, f = _prism(
            _circle(g * 0.3, 10),
            np.array([gx + g / 2, 0, gz]),
            np.array([gx + g / 2 + g * 0.15, 0, gz]),
            -down,
        )
        parts.append(_part("lens", v, f, "lens"))
    for end in _POD_ENDS[shape.end_sensors]:
        # Obstacle-sensor pod: a dark plate on the body's end face, level with the upper shell, two
        # lenses looking out along the body axis. At the front that face is the nose cone's tip
        # when there is one (on the shell's front face the cone would hide it).
        x, scale = (x_nose, nose_scale) if end == "front" else (x_rear, 1.0)
        pw, ph = width * 0.55 * scale, (z_mid - z_top) * 0.55 * scale
        out = np.sign(x) * fwd
        face = np.array([x, 0.0, zc])
        v, f = _prism(_rect(pw, ph), face - out * 0.002, face + out * 0.003, -down)
        parts.append(_part(f"sensor_{end}", v, f, "gimbal"))
        for side in (-1.0, 1.0):
            eye = face + np.array([0.0, side * pw * 0.28, 0.0]) + out * 0.003
            v, f = _prism(_circle(ph * 0.3, 10), eye, eye + out * 0.002, -down)
            parts.append(_part(f"sensor_lens_{end}", v, f, "lens"))
    if shape.led_place == "body":
        size = min(width, height) * 0.18
        for name, lit, x in (("front", shape.led_front, x_front), ("rear", shape.led_rear, x_rear)):
            if lit:
                p = np.array([x + np.sign(x) * 0.004, 0, zc])
                v, f = _prism(_rect(size, size), p - np.sign(x) * fwd * 0.004, p, -down)
                parts.append(_part(f"led_{name}", v, f, f"{name}_led", EMISSIVE))
    if shape.legs:  # landing legs: four thin struts under the body
        leg = max(arm_w * 0.5, 0.003)
        for sx in (-0.3, 0.3):
            for sy in (-0.5, 0.5):
                top = np.array([sx * length, sy * width * 0.8, z_bot - 0.002])
                foot = top + np.array([0.0, sy * width * 0.3, height * 0.9])
                v, f = _prism(_rect(leg, leg), top, foot, fwd)
                parts.append(_part("leg", v, f, "arms"))

    for i in range(4):
        hub = kp[i]
        front = hub[0] > 0
        lit = shape.led_front if front else shape.led_rear
        role = "front_led" if front else "rear_led"
        # Arm from the fuselage side to the motor, level with the shell's top half.
        drop = 0.0 if front else shape.rear_arm_drop * height
        root = np.array([hub[0] * 0.35, np.sign(hub[1]) * width * 0.4, z_top + height * 0.25 + drop])
        tip = np.array([hub[0], hub[1], motor_h * 0.75])
        v, f = _prism(_rect(arm_w, arm_w * 0.8), root, tip, -down)
        parts.append(_part(f"arm{i + 1}", v, f, "arms", rotor=i))
        # Motor can: a cylinder from just below the propeller plane down to the arm.
        v, f = _prism(_circle(motor_r, 12), hub + down * (motor_h * 1.05), hub + down * 0.002, fwd)
        parts.append(_part(f"motor{i + 1}", v, f, "motor", rotor=i))
        if lit and shape.led_place == "motor":
            led = hub + down * (motor_h * 1.05 + 0.002)
            v, f = _prism(_rect(motor_r * 0.9, motor_r * 0.9), led - down * 0.002, led + down * 0.003, fwd)
            parts.append(_part(f"led{i + 1}", v, f, role, EMISSIVE, i))
        elif lit and shape.led_place == "arm":  # under the arm, half-way out
            mid = 0.5 * (root + tip) + down * (arm_w * 0.4 + 0.002)
            s = arm_w * 0.8
            v, f = _prism(_rect(s, s), mid - down * 0.002, mid + down * 0.003, fwd)
            parts.append(_part(f"led{i + 1}", v, f, role, EMISSIVE, i))
        if shape.guards:  # propeller guard: an octagon of thin bars just outside the disc
            rg, bar = prop_r * 1.08, max(arm_w * 0.35, 0.002)
            corners = hub[None, :] + np.c_[_circle(rg, 8), np.full(8, motor_h * 0.2)]
            for k in range(8):
                a, e = corners[k], corners[(k + 1) % 8]
                v, f = _prism(_rect(bar, bar * 2.5), a, e, -down)
                parts.append(_part(f"guard{i + 1}", v, f, "arms", rotor=i))
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
