"""Draws a ``DroneMesh`` into an image through a calibrated camera and returns its exact annotation.

Faces are projected with OpenCV's full distortion model, back faces culled, and drawn far to near
(painter's order) with anti-aliased polygons into a premultiplied colour + alpha layer the size of
the drone's footprint, which is then blurred (motion, defocus) and composited over the frame. Only
that footprint is touched, so a 30 px drone in a 1080p frame costs what a 30 px image costs.

The annotation is computed from geometry, not from pixels: keypoints are the projections of the
spec's hubs, and a keypoint is flagged hidden when the line of sight from the camera to its hub
passes through an opaque part of another rotor or the body (exact segment / convex-part tests).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from dronekey.geometry.camera import CameraModel
from dronekey.sim_replay.annotations import HIDDEN, VISIBLE, DroneAnnotation
from dronekey.sim_replay.drone_look import DroneStyle
from dronekey.sim_replay.mesh import EMISSIVE, PROP, DroneMesh, segment_hits

__all__ = ["Lighting", "render_drone"]

_SHIFT = 4  # sub-pixel bits for OpenCV polygon drawing (1/16 px)
_NEAR_M = 0.05


@dataclass(frozen=True)
class Lighting:
    """Directional light in the camera frame plus ambient light.

    direction : unit vector pointing towards the light (camera frame).
    """

    direction: tuple[float, float, float] = (0.3, -0.8, -0.5)
    ambient: float = 0.45
    diffuse: float = 0.65
    specular: float = 0.15
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)

    @classmethod
    def backlit(cls, rng: np.random.Generator) -> Lighting:
        """Sun behind the drone: almost no light on the faces the camera sees (a near-silhouette)."""
        d = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.2), 1.0])
        return cls(
            direction=tuple(d / np.linalg.norm(d)),
            ambient=float(rng.uniform(0.03, 0.2)),
            diffuse=float(rng.uniform(0.0, 0.3)),
            specular=float(rng.uniform(0.0, 0.1)),
        )

    @classmethod
    def random(cls, rng: np.random.Generator) -> Lighting:
        """Sun mostly from above (camera -y), any azimuth; overcast to harsh; warm to cool."""
        d = np.array([rng.uniform(-1, 1), rng.uniform(-1.6, 0.3), rng.uniform(-1, 0.6)])
        d /= np.linalg.norm(d)
        warm = rng.uniform(-0.12, 0.12)
        return cls(
            direction=tuple(d),
            ambient=float(rng.uniform(0.25, 0.7)),
            diffuse=float(rng.uniform(0.3, 0.9)),
            specular=float(rng.uniform(0.0, 0.35)),
            color=(1.0 - warm, 1.0, 1.0 + warm),
        )


def _shade(
    base: np.ndarray, normals: np.ndarray, centres: np.ndarray, light: Lighting, gloss: float = 1.0
) -> np.ndarray:
    """Lambert + Phong colours (F, 3) in [0, 1] of faces with unit ``normals`` at ``centres`` (camera).

    ``gloss`` scales the highlight: 0 for a matt livery, above 1 for a glossy one.
    """
    ldir = np.asarray(light.direction)
    ndotl = normals @ ldir
    lam = np.maximum(ndotl, 0.0)
    view = -centres / (np.linalg.norm(centres, axis=1, keepdims=True) + 1e-12)
    refl = 2 * ndotl[:, None] * normals - ldir
    spec = np.where(lam > 0, np.maximum(np.einsum("ij,ij->i", refl, view), 0.0) ** 12, 0.0)
    c = base * (light.ambient + light.diffuse * lam[:, None]) * np.asarray(light.color)
    return np.clip(c + gloss * light.specular * spec[:, None], 0, 1)


def render_drone(
    image: np.ndarray,
    camera: CameraModel,
    mesh: DroneMesh,
    R: np.ndarray,
    t: np.ndarray,
    style: DroneStyle,
    lighting: Lighting | None = None,
    motion_blur_px: tuple[float, float] = (0.0, 0.0),
    defocus_sigma_px: float = 0.0,
) -> DroneAnnotation | None:
    """Draw the drone at pose ``p_cam = R @ p_body + t`` into ``image`` (BGR uint8, modified in place).

    Parameters
    ----------
    image : (H, W, 3) uint8
        Frame of the camera's resolution.
    motion_blur_px : (dx, dy)
        Image-space blur streak of the drone during the exposure, pixels.
    defocus_sigma_px : float
        Gaussian defocus of the drone layer, pixels.

    Returns
    -------
    DroneAnnotation or None
        None when the drone is behind the camera, too close, or entirely outside the frame.
    """
    h_img, w_img = image.shape[:2]
    if (w_img, h_img) != camera.size:
        raise ValueError(f"image is {w_img}x{h_img} but the camera is {camera.width}x{camera.height}")
    lighting = lighting or Lighting()
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)

    verts_body = mesh.vertices
    verts_cam = verts_body @ R.T + t
    if verts_cam[:, 2].min() < _NEAR_M:
        return None
    kp_cam = mesh.keypoints @ R.T + t
    uv_all = camera.project(np.vstack([verts_cam, kp_cam]))
    uv, kp_px = uv_all[: len(verts_cam)], uv_all[len(verts_cam) :]

    x0f, y0f = uv.min(axis=0)
    x1f, y1f = uv.max(axis=0)
    bx0, by0 = max(x0f, -0.5), max(y0f, -0.5)
    bx1, by1 = min(x1f, w_img - 0.5), min(y1f, h_img - 0.5)
    if bx1 <= bx0 or by1 <= by0:
        return None

    blur_r = int(np.ceil(abs(motion_blur_px[0]) + abs(motion_blur_px[1]) + 3 * defocus_sigma_px)) + 2
    px0 = max(int(np.floor(x0f)) - blur_r, 0)
    py0 = max(int(np.floor(y0f)) - blur_r, 0)
    px1 = min(int(np.ceil(x1f)) + blur_r + 1, w_img)
    py1 = min(int(np.ceil(y1f)) + blur_r + 1, h_img)
    layer = _draw_layer(mesh, style, lighting, verts_cam, uv - [px0, py0], (py1 - py0, px1 - px0))
    _composite(image[py0:py1, px0:px1], layer, motion_blur_px, defocus_sigma_px)

    visibility = _visibility(mesh, R, t, kp_px, (w_img, h_img))
    bbox = (float(bx0), float(by0), float(bx1 - bx0), float(by1 - by0))
    return DroneAnnotation(kp_px, visibility, bbox, R.copy(), t.copy())


def _draw_layer(
    mesh: DroneMesh,
    style: DroneStyle,
    lighting: Lighting,
    verts_cam: np.ndarray,
    uv: np.ndarray,
    shape: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """Premultiplied BGR (uint8) and alpha (uint8) of the drone over transparent black."""
    col = np.zeros((*shape, 3), np.uint8)
    alpha = np.zeros(shape, np.uint8)
    tri = verts_cam[mesh.face_tri]  # (F, 3, 3): first three vertices of each face
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-15
    centres = mesh.face_mean @ verts_cam
    kinds = np.array([mesh.parts[k].kind for k in mesh.face_part])
    front = (np.einsum("ij,ij->i", normals, centres) < 0) | (kinds == PROP)  # cull back faces
    base = np.array([style.colour_of(p.role) for p in mesh.parts])[mesh.face_part]
    if style.camo:  # camouflage: body, underside and arm faces painted from the palette, face by face
        roles = np.array([mesh.parts[k].role for k in mesh.face_part])
        painted = np.isin(roles, ("body", "underside", "arms"))
        palette = np.asarray(style.camo, dtype=np.float64)
        pick = (np.arange(len(base)) * 7919 + 13) % len(palette)
        base = np.where(painted[:, None], palette[pick], base)
    # A lit LED glows (unshaded); an unlit one (its colour None) is a dark housing like any part.
    lit_part = [p.kind == EMISSIVE and getattr(style, p.role) is not None for p in mesh.parts]
    lit = np.asarray(lit_part, dtype=bool)[mesh.face_part]
    colours = np.where(
        lit[:, None], np.clip(base * 1.15, 0, 1), _shade(base, normals, centres, lighting, style.gloss)
    )
    scale = float(1 << _SHIFT)
    for fi in np.flatnonzero(front)[np.argsort(-centres[front, 2], kind="stable")]:
        idx = mesh.face_vertices[fi]
        pts = np.round(uv[idx] * scale).astype(np.int32)
        if kinds[fi] == PROP:
            _draw_prop(col, alpha, pts, uv[idx], style)
            continue
        cv2.fillConvexPoly(col, pts, tuple(float(v) for v in colours[fi] * 255), cv2.LINE_AA, _SHIFT)
        cv2.fillConvexPoly(alpha, pts, 255, cv2.LINE_AA, _SHIFT)
    return col, alpha


def _draw_prop(
    col: np.ndarray, alpha: np.ndarray, pts: np.ndarray, uv: np.ndarray, style: DroneStyle
) -> None:
    """A spinning propeller: a faint disc plus two smeared blades, blended over the layer."""
    x0, y0 = np.floor(uv.min(axis=0)).astype(int) - 1
    x1, y1 = np.ceil(uv.max(axis=0)).astype(int) + 2
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, col.shape[1]), min(y1, col.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    local = pts - np.array([x0, y0]) * (1 << _SHIFT)
    cv2.fillConvexPoly(mask, local, int(255 * style.prop_opacity), cv2.LINE_AA, _SHIFT)
    n = len(pts)
    centre = local.mean(axis=0)
    smear = max(2, int(round(style.blade_smear_deg / 360 * n)))
    start = int(style.blade_angle_deg / 360 * n)
    for k in (0, n // 2):  # two blades, opposite each other
        arc = [(start + k + j) % n for j in range(smear + 1)]
        blade = np.vstack([centre, local[arc]]).astype(np.int32)
        cv2.fillPoly(
            mask, [blade], int(255 * min(1.0, style.prop_opacity + style.blade_opacity)), cv2.LINE_AA, _SHIFT
        )
    m = mask.astype(np.float32)[..., None] / 255.0
    c = np.asarray(style.prop, dtype=np.float32) * 255
    region = col[y0:y1, x0:x1].astype(np.float32)
    col[y0:y1, x0:x1] = (region * (1 - m) + c * m).astype(np.uint8)
    a = alpha[y0:y1, x0:x1].astype(np.float32)
    alpha[y0:y1, x0:x1] = (a * (1 - m[..., 0]) + 255 * m[..., 0]).astype(np.uint8)


def _motion_kernel(dx: float, dy: float) -> np.ndarray | None:
    length = float(np.hypot(dx, dy))
    if length < 0.75:
        return None
    size = int(np.ceil(length)) | 1
    size += 2
    k = np.zeros((size, size), np.float32)
    c = (size - 1) / 2
    cv2.line(
        k,
        (int(round((c - dx / 2) * 16)), int(round((c - dy / 2) * 16))),
        (int(round((c + dx / 2) * 16)), int(round((c + dy / 2) * 16))),
        1.0,
        1,
        cv2.LINE_AA,
        4,
    )
    return k / k.sum()


def _composite(
    dst: np.ndarray, layer: tuple[np.ndarray, np.ndarray], motion_px: tuple[float, float], defocus: float
) -> None:
    col, alpha = layer
    colf = col.astype(np.float32)
    af = alpha.astype(np.float32)
    kernel = _motion_kernel(*motion_px)
    if kernel is not None:
        colf = cv2.filter2D(colf, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        af = cv2.filter2D(af, -1, kernel, borderType=cv2.BORDER_CONSTANT)
    if defocus > 0.3:
        colf = cv2.GaussianBlur(colf, (0, 0), defocus, borderType=cv2.BORDER_CONSTANT)
        af = cv2.GaussianBlur(af, (0, 0), defocus, borderType=cv2.BORDER_CONSTANT)
    a = (af / 255.0)[..., None]
    out = dst.astype(np.float32) * (1.0 - a) + colf
    np.clip(out, 0, 255, out=out)
    dst[...] = out.astype(np.uint8)


def _visibility(
    mesh: DroneMesh, R: np.ndarray, t: np.ndarray, kp_px: np.ndarray, size: tuple[int, int]
) -> np.ndarray:
    """VISIBLE / HIDDEN per keypoint: hidden behind an opaque part of the drone, or outside the frame."""
    cam_body = -R.T @ t  # camera centre in the body frame
    vis = np.full(4, VISIBLE, dtype=np.int64)
    w, h = size
    for i, hub in enumerate(mesh.keypoints):
        u, v = kp_px[i]
        if not (-0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
            vis[i] = HIDDEN
            continue
        for part in mesh.parts:
            if part.rotor == i or part.kind == PROP:
                continue
            if segment_hits(part, cam_body, hub):
                vis[i] = HIDDEN
                break
    return vis
