"""A quadcopter as a few convex parts in the FRD body frame, built from a ``DroneSpec`` and a shape.

The propeller hubs sit exactly on the spec's ``keypoints_3d`` (z = 0 is the propeller plane; +z is
down): they are the labels and never move. Everything else is a look that real drones do not share,
so it is drawn at random (``BodyShape.random``, ``DroneStyle.random``): body length, width and
height, nose taper, a battery bulge at the rear, the gimbal (under the nose, on top, or none), arm
thickness, rear arms that leave the body lower (folding-arm drones), propeller guards, landing
legs, the light stripe (anywhere or absent) and the LEDs (absent on many drones; any colours; under
the motors, under the arms or on the body; front/back convention either way). No single part marks
a keypoint or the front in every drone, so a network trained on these renders has to read the whole
shape. The default ``BodyShape()`` is the first
round's drone (gimbal under the nose, LEDs under the motors).

Every opaque part is a convex polyhedron, so the renderer can test a line of sight against it
exactly (see ``segment_hits``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

from dronekey.geometry.drone_spec import DroneSpec

__all__ = [
    "GIMBAL_PLACES",
    "LED_MODES",
    "LED_PLACES",
    "PROP_LOOKS",
    "BodyShape",
    "DroneMesh",
    "DroneStyle",
    "Part",
    "build_mesh",
    "segment_hits",
]

OPAQUE, PROP, EMISSIVE = "opaque", "prop", "emissive"
GIMBAL_PLACES = ("nose", "top", "none")
LED_PLACES = ("motor", "arm", "body")
PROP_LOOKS = ("disc", "blades", "stopped")
# --leds of dronekey-sim: red at the front and green at the rear (the usual DJI convention), the
# other way round, none, or drawn at random like the training sampler does.
LED_MODES = ("red-front", "green-front", "off", "random")

_RED, _GREEN = (0.15, 0.15, 1.0), (0.3, 1.0, 0.35)  # BGR


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
class BodyShape:
    """The drone's shape around the fixed keypoints; lengths are fractions of the hub diagonal.

    ``None`` for a dimension means the spec's own (``DroneSpec.body``) or its wheelbase default.
    """

    length: float | None = None
    width: float | None = None
    height: float | None = None
    nose_taper: float = 1.0  # front-face size over the rear-face size of the shell (1: a box)
    nose_length: float = 0.0  # extra tapered nose ahead of the shell
    battery: float = 0.0  # battery bulge on the rear top, as a fraction of the body length (0: none)
    gimbal: str = "nose"
    gimbal_size: float = 1.0  # times the default (half the body height)
    arm_scale: float = 1.0
    rear_arm_drop: float = 0.0  # rear arms leave the body this fraction of its height lower (folding arms)
    guards: bool = False
    legs: bool = False
    stripe: str = "front"  # "front", "rear", "full" or "none"
    led_place: str = "motor"
    led_front: bool = True  # LEDs under the front rotors (place "motor"/"arm") or on the nose ("body")
    led_rear: bool = True

    def __post_init__(self) -> None:
        if self.gimbal not in GIMBAL_PLACES:
            raise ValueError(f"gimbal must be one of {GIMBAL_PLACES}, got {self.gimbal!r}")
        if self.led_place not in LED_PLACES:
            raise ValueError(f"led_place must be one of {LED_PLACES}, got {self.led_place!r}")
        if self.stripe not in ("front", "rear", "full", "none"):
            raise ValueError(f"stripe must be front, rear, full or none, got {self.stripe!r}")

    @classmethod
    def random(cls, rng: np.random.Generator, leds: bool = True) -> BodyShape:
        """A consumer-to-prosumer quadcopter; ``leds`` False gives a shape with no LED parts."""
        # Camera drones, the kind a counter-drone sensor meets, carry their camera at the front: it is
        # the one front cue real drones share, so most shapes have one (the rest must stay doubtful).
        gimbal = str(rng.choice(GIMBAL_PLACES, p=[0.85, 0.1, 0.05]))
        return cls(
            length=float(rng.uniform(0.45, 0.8)),
            width=float(rng.uniform(0.2, 0.38)),
            height=float(rng.uniform(0.14, 0.3)),
            nose_taper=float(rng.uniform(0.55, 1.0)) if rng.random() < 0.6 else 1.0,
            nose_length=float(rng.uniform(0.03, 0.12)) if rng.random() < 0.5 else 0.0,
            battery=float(rng.uniform(0.2, 0.4)) if rng.random() < 0.55 else 0.0,
            gimbal=gimbal,
            gimbal_size=float(rng.uniform(1.0, 1.8)),
            arm_scale=float(rng.uniform(0.6, 1.8)),
            rear_arm_drop=float(rng.uniform(0.2, 0.7)) if rng.random() < 0.4 else 0.0,
            guards=bool(rng.random() < 0.15),
            legs=bool(rng.random() < 0.3),
            stripe=str(rng.choice(["front", "rear", "full", "none"], p=[0.25, 0.15, 0.15, 0.45])),
            led_place=str(rng.choice(LED_PLACES, p=[0.4, 0.35, 0.25])),
            led_front=leds and bool(rng.random() < 0.9),
            led_rear=leds and bool(rng.random() < 0.9),
        )

    def key(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self))


@dataclass(frozen=True)
class DroneStyle:
    """Colours and propeller look of one rendered drone (randomised per sequence or sample).

    ``front_led`` / ``rear_led`` are BGR colours, or None for an unlit (dark) LED housing.
    ``camo`` is a palette of BGR colours painted face by face over the body, or empty.
    ``gloss`` scales the light's specular highlight (0 matt, 1 the light's own, >1 glossy).
    """

    body: tuple[float, float, float] = (0.55, 0.56, 0.58)
    underside: tuple[float, float, float] = (0.18, 0.18, 0.2)
    arms: tuple[float, float, float] = (0.45, 0.46, 0.48)
    stripe: tuple[float, float, float] = (0.92, 0.92, 0.9)
    motor: tuple[float, float, float] = (0.12, 0.12, 0.13)
    prop: tuple[float, float, float] = (0.1, 0.1, 0.1)
    front_led: tuple[float, float, float] | None = _RED
    rear_led: tuple[float, float, float] | None = _GREEN
    prop_opacity: float = 0.35
    blade_opacity: float = 0.5
    blade_angle_deg: float = 0.0
    blade_smear_deg: float = 40.0
    gimbal: tuple[float, float, float] = (0.2, 0.2, 0.22)
    lens: tuple[float, float, float] = (0.05, 0.04, 0.04)
    gloss: float = 1.0
    camo: tuple[tuple[float, float, float], ...] = ()
    led_housing: tuple[float, float, float] = (0.12, 0.12, 0.13)

    def colour_of(self, role: str) -> np.ndarray:
        """BGR colour in [0, 1] of a part role (an unlit LED is its dark housing)."""
        value = getattr(self, role)
        if value is None:
            value = self.led_housing
        return np.asarray(value, dtype=np.float64)

    def with_leds(self, mode: str, rng: np.random.Generator | None = None) -> DroneStyle:
        """This style with the LEDs of ``mode`` (one of ``LED_MODES``)."""
        if mode not in LED_MODES:
            raise ValueError(f"leds must be one of {', '.join(LED_MODES)}, got {mode!r}")
        if mode == "red-front":
            return replace(self, front_led=_RED, rear_led=_GREEN)
        if mode == "green-front":
            return replace(self, front_led=_GREEN, rear_led=_RED)
        if mode == "off":
            return replace(self, front_led=None, rear_led=None)
        front, rear = _random_leds(rng if rng is not None else np.random.default_rng())
        return replace(self, front_led=front, rear_led=rear)

    @classmethod
    def random(cls, rng: np.random.Generator) -> DroneStyle:
        """Any livery from white to black (matt, glossy or camouflage), any LEDs, any propeller look."""
        family = int(rng.choice(5, p=[0.25, 0.22, 0.25, 0.13, 0.15]))
        if family == 4:  # coloured shell (red, yellow, orange, blue racing and survey drones)
            body = np.clip(rng.uniform(0.05, 0.95, 3), 0.03, 0.97)
        else:
            base = {0: 0.55, 1: 0.86, 2: 0.16, 3: 0.06}[family] + rng.uniform(-0.08, 0.08)
            body = np.clip(base + rng.normal(0, 0.02, 3), 0.02, 0.97)
        camo: tuple = ()
        if rng.random() < 0.12:
            greens = np.array([[0.2, 0.35, 0.3], [0.15, 0.25, 0.35], [0.35, 0.45, 0.5], [0.1, 0.12, 0.12]])
            camo = tuple(
                tuple(np.clip(c + rng.normal(0, 0.04, 3), 0, 1)) for c in greens[rng.permutation(4)[:3]]
            )
            body = np.asarray(camo[0])
        arms = (
            np.clip(body * rng.uniform(0.6, 1.05), 0, 1) if rng.random() < 0.7 else rng.uniform(0.03, 0.9, 3)
        )
        front, rear = _random_leds(rng)
        look = str(rng.choice(PROP_LOOKS, p=[0.55, 0.3, 0.15]))
        if look == "disc":
            prop_op, blade_op, smear = rng.uniform(0.1, 0.45), rng.uniform(0.1, 0.6), rng.uniform(60, 160)
        elif look == "blades":
            prop_op, blade_op, smear = rng.uniform(0.05, 0.25), rng.uniform(0.4, 0.8), rng.uniform(8, 40)
        else:
            prop_op, blade_op, smear = 0.0, rng.uniform(0.85, 1.0), rng.uniform(3, 8)
        # gimbals are mostly black or dark grey, whatever the shell
        gimbal_grey = rng.uniform(0.03, 0.25) if rng.random() < 0.75 else rng.uniform(0.05, 0.8)
        under = body * rng.uniform(0.3, 1.0) if rng.random() < 0.7 else rng.uniform(0.05, 0.5) * np.ones(3)
        return cls(
            body=tuple(body),
            underside=tuple(np.clip(under, 0, 1)),
            arms=tuple(arms),
            stripe=tuple(np.clip(rng.uniform(0, 1, 3) if rng.random() < 0.5 else 1.2 - body, 0.03, 1)),
            motor=tuple(np.full(3, rng.uniform(0.05, 0.6))),
            prop=tuple(np.full(3, rng.uniform(0.03, 0.7))),
            prop_opacity=float(prop_op),
            blade_opacity=float(blade_op),
            blade_angle_deg=float(rng.uniform(0, 360)),
            blade_smear_deg=float(smear),
            gimbal=tuple(np.full(3, gimbal_grey)),
            gloss=float(rng.choice([0.0, rng.uniform(0.2, 1.0), rng.uniform(1.5, 4.0)], p=[0.3, 0.45, 0.25])),
            camo=camo,
            front_led=front,
            rear_led=rear,
        )


def _random_leds(rng: np.random.Generator) -> tuple[tuple | None, tuple | None]:
    """Absent on 45 % of drones; otherwise red/green either way round, or any two colours."""
    if rng.random() < 0.45:
        return None, None
    r = rng.random()
    if r < 0.3:
        pair = (_RED, _GREEN)
    elif r < 0.6:
        pair = (_GREEN, _RED)
    else:
        palette = np.array([_RED, _GREEN, (1.0, 0.4, 0.1), (1.0, 1.0, 1.0), (0.2, 0.8, 1.0), (1.0, 0.2, 0.9)])
        pair = tuple(tuple(palette[i]) for i in rng.choice(len(palette), 2))
    jitter = [tuple(np.clip(np.asarray(c) + rng.normal(0, 0.05, 3), 0, 1)) for c in pair]
    if rng.random() < 0.15:  # one end only
        jitter[int(rng.integers(2))] = None
    return jitter[0], jitter[1]


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
    if shape.nose_length > 0:  # a tapered nose cone ahead of the shell
        nose = upper * shape.nose_taper
        tip = np.array([x_front + shape.nose_length * diag, 0, zc])
        v, f = _prism(nose, np.array([x_front, 0, zc]), tip, -down, (0.35, 0.35))
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
