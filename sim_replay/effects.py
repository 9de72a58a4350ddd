"""Image-level domain randomisation: camera response, sensor noise, compression, clutter.

Each function takes a ``numpy.random.Generator`` and an image (BGR uint8) and returns a new image,
so the training sampler and the sequence renderer apply the same effects from the same code.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "camera_response",
    "draw_distractors",
    "draw_edge_clutter",
    "draw_occluder",
    "jpeg_roundtrip",
    "sensor_noise",
]


def camera_response(img: np.ndarray, rng: np.random.Generator, strength: float = 1.0) -> np.ndarray:
    """Exposure, contrast, gamma, white balance and saturation changes, as cameras differ."""
    f = img.astype(np.float32) / 255.0
    gain = np.exp(rng.normal(0, 0.25 * strength))
    wb = np.exp(rng.normal(0, 0.06 * strength, 3)).astype(np.float32)
    f = f * gain * wb
    contrast = np.exp(rng.normal(0, 0.15 * strength))
    mean = f.mean()
    f = (f - mean) * contrast + mean
    sat = np.exp(rng.normal(0, 0.25 * strength))
    grey = f.mean(axis=2, keepdims=True)
    f = grey + (f - grey) * sat
    gamma = np.exp(rng.normal(0, 0.15 * strength))
    f = np.clip(f, 0, 1) ** gamma
    return (f * 255 + 0.5).astype(np.uint8)


def sensor_noise(img: np.ndarray, rng: np.random.Generator, sigma: float | None = None) -> np.ndarray:
    """Read noise (Gaussian, ``sigma`` in 8-bit levels) plus shot noise proportional to sqrt(signal)."""
    sigma = float(rng.uniform(0.5, 6.0)) if sigma is None else sigma
    f = img.astype(np.float32)
    shot = np.sqrt(np.maximum(f, 0)) * rng.uniform(0.0, 0.5)
    noise = rng.standard_normal(f.shape, dtype=np.float32) * (sigma + shot)
    return np.clip(f + noise, 0, 255).astype(np.uint8)


def jpeg_roundtrip(img: np.ndarray, quality: int) -> np.ndarray:
    """Encode and decode as JPEG at ``quality`` (1-100): blocking and ringing as in streamed video."""
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        return img
    return cv2.imdecode(buf, cv2.IMREAD_COLOR)


def _bird(img: np.ndarray, rng: np.random.Generator, cx: float, cy: float, size: float) -> None:
    span = size / 2
    flap = rng.uniform(-0.6, 0.6) * span
    pts = np.array(
        [
            [cx - span, cy - flap],
            [cx - span * 0.3, cy - flap * 0.2],
            [cx, cy],
            [cx + span * 0.3, cy - flap * 0.2],
            [cx + span, cy - flap],
        ]
    )
    ang = rng.uniform(-0.5, 0.5)
    rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    pts = (pts - [cx, cy]) @ rot.T + [cx, cy]
    col = tuple(float(v) for v in np.full(3, rng.uniform(10, 70)))
    thick = max(1, int(round(size / 12)))
    cv2.polylines(img, [np.round(pts * 16).astype(np.int32)], False, col, thick, cv2.LINE_AA, 4)
    cv2.ellipse(img, (int(cx), int(cy)), (max(1, thick), max(1, thick // 2)), 0, 0, 360, col, -1, cv2.LINE_AA)


def _blob(img: np.ndarray, rng: np.random.Generator, cx: float, cy: float, size: float) -> None:
    """Balloons, kites, small planes, insects: a convex-ish shape with a highlight."""
    n = int(rng.integers(3, 9))
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))
    rad = size / 2 * rng.uniform(0.4, 1.0, n)
    pts = np.c_[cx + rad * np.cos(ang), cy + rad * np.sin(ang) * rng.uniform(0.3, 1.0)]
    col = tuple(float(v) for v in rng.uniform(0, 255, 3))
    cv2.fillPoly(img, [np.round(pts * 16).astype(np.int32)], col, cv2.LINE_AA, 4)
    if rng.random() < 0.5:  # a thin line: kite string, antenna, wing
        x2, y2 = cx + rng.normal(0, size), cy + rng.normal(0, size)
        cv2.line(img, (int(cx), int(cy)), (int(x2), int(y2)), col, max(1, int(size / 15)), cv2.LINE_AA)


def draw_distractors(
    img: np.ndarray, rng: np.random.Generator, count: int, size_range: tuple[float, float]
) -> None:
    """Draw ``count`` birds and flying objects (sizes in pixels) anywhere in ``img`` (in place)."""
    h, w = img.shape[:2]
    for _ in range(count):
        size = float(np.exp(rng.uniform(np.log(size_range[0]), np.log(size_range[1]))))
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        (_bird if rng.random() < 0.6 else _blob)(img, rng, cx, cy, size)


def draw_occluder(
    img: np.ndarray, rng: np.random.Generator, box_xywh: tuple[float, float, float, float], cover: float
) -> np.ndarray:
    """Cover part of a box with foliage, a pole or a wire, in place; returns the occluder's bool mask.

    ``cover`` is the rough fraction of the box's longer side the occluder reaches into the box.
    """
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    x, y, bw, bh = box_xywh
    size = max(bw, bh)
    kind = rng.choice(["leaves", "pole", "edge"])
    side = int(rng.integers(4))
    # Anchor just outside one side of the box; reach ``cover`` into it.
    cx, cy = x + bw / 2, y + bh / 2
    dx, dy = [(-1, 0), (1, 0), (0, -1), (0, 1)][side]
    ax = cx + dx * (size / 2 + size * 0.3 - cover * size)
    ay = cy + dy * (size / 2 + size * 0.3 - cover * size)
    col = tuple(float(v) for v in rng.uniform(10, 120, 3))
    if kind == "leaves":
        for _ in range(int(rng.integers(3, 10))):
            r = size * rng.uniform(0.08, 0.25)
            ox, oy = ax + rng.normal(0, size * 0.15), ay + rng.normal(0, size * 0.15)
            ang = rng.uniform(0, 180)
            cv2.ellipse(mask, (int(ox), int(oy)), (int(r), int(r * 0.5)), ang, 0, 360, 255, -1, cv2.LINE_AA)
    elif kind == "pole":
        thick = max(2, int(size * rng.uniform(0.05, 0.2)))
        p0 = (int(ax - dy * 2 * h), int(ay - dx * 2 * h))
        p1 = (int(ax + dy * 2 * h), int(ay + dx * 2 * h))
        cv2.line(mask, p0, p1, 255, thick, cv2.LINE_AA)
    else:  # a building edge / roof: a big half-plane polygon
        far = 4 * (w + h)
        poly = np.array(
            [
                [ax, ay],
                [ax + dy * far, ay + dx * far],
                [ax + dy * far + dx * far, ay + dx * far + dy * far],
                [ax - dy * far + dx * far, ay - dx * far + dy * far],
                [ax - dy * far, ay - dx * far],
            ]
        )
        cv2.fillPoly(mask, [np.round(poly).astype(np.int32)], 255, cv2.LINE_AA)
    m = (mask.astype(np.float32) / 255.0)[..., None]
    tex = rng.normal(0, 12, img.shape).astype(np.float32)
    img[...] = np.clip(
        img.astype(np.float32) * (1 - m) + (np.asarray(col, np.float32) + tex) * m, 0, 255
    ).astype(np.uint8)
    return mask > 127


def _inward_point(
    rng: np.random.Generator,
    edge: tuple[float, float],
    inward: tuple[float, float],
    reach: float,
    spread: float,
) -> tuple[float, float]:
    """A point up to ``reach`` px in from ``edge`` along ``inward``, scattered ``spread`` x reach along it."""
    d = rng.uniform(0, reach)
    along = rng.normal(0, reach * spread)
    return edge[0] + inward[0] * d + along * inward[1], edge[1] + inward[1] * d + along * inward[0]


def draw_edge_clutter(img: np.ndarray, rng: np.random.Generator, count: int = 1) -> np.ndarray:
    """Clouds, building edges, trees or wires entering ``img`` from its edges, in place.

    These are what the localiser's candidates land on when no drone is there (a bright cloud rim at
    the top of the frame, a roof corner at the side), so the network must see them at the crop's
    edges with and without a drone. Returns the clutter's bool mask (what it covers).
    """
    h, w = img.shape[:2]
    mask = np.zeros((h, w), np.uint8)
    for _ in range(count):
        kind = rng.choice(["cloud", "building", "tree", "wires"], p=[0.3, 0.3, 0.25, 0.15])
        side = int(rng.integers(4))
        # A point on one edge and the inward direction.
        along = rng.uniform(0, 1)
        ex, ey, nx, ny = [
            (along * w, 0, 0, 1),
            (along * w, h, 0, -1),
            (0, along * h, 1, 0),
            (w, along * h, -1, 0),
        ][side]
        reach = rng.uniform(0.1, 0.45) * max(h, w)
        one = np.zeros((h, w), np.uint8)
        if kind == "cloud":
            for _ in range(int(rng.integers(4, 12))):
                cx, cy = _inward_point(rng, (ex, ey), (nx, ny), reach, 0.5)
                r = reach * rng.uniform(0.2, 0.6)
                cv2.ellipse(
                    one, (int(cx), int(cy)), (int(r), int(r * rng.uniform(0.4, 0.9))), 0, 0, 360, 255, -1
                )
            col = np.full(3, rng.uniform(200, 255)) * rng.uniform(0.85, 1.0, 3) ** 0.2
        elif kind == "building":
            half = rng.uniform(0.15, 0.6) * max(h, w)
            c = np.array([ex, ey]) + np.array([ny, nx]) * rng.normal(0, 0.3 * max(h, w))
            inner = c + np.array([nx, ny]) * reach
            t = np.array([ny, nx]) * half
            poly = np.array(
                [c - t - [nx * 4 * w, ny * 4 * h], inner - t, inner + t, c + t - [nx * 4 * w, ny * 4 * h]]
            )
            cv2.fillPoly(one, [np.round(poly).astype(np.int32)], 255, cv2.LINE_AA)
            col = np.clip(rng.uniform(20, 200) + rng.normal(0, 12, 3), 0, 255)
        elif kind == "tree":
            for _ in range(int(rng.integers(6, 20))):
                cx, cy = _inward_point(rng, (ex, ey), (nx, ny), reach, 0.4)
                r = reach * rng.uniform(0.05, 0.25)
                ang = rng.uniform(0, 180)
                cv2.ellipse(
                    one, (int(cx), int(cy)), (int(r), int(r * 0.6)), ang, 0, 360, 255, -1, cv2.LINE_AA
                )
            col = np.clip(np.array([30, 70, 40]) * rng.uniform(0.4, 1.5) + rng.normal(0, 8, 3), 0, 255)
        else:
            for _ in range(int(rng.integers(1, 4))):
                p0 = (
                    int(rng.uniform(-0.1, 1.1) * w),
                    int(rng.uniform(-0.1, 0.3) * h if side == 0 else rng.uniform(0, h)),
                )
                p1 = (int(rng.uniform(-0.1, 1.1) * w), int(rng.uniform(0, h)))
                cv2.line(one, p0, p1, 255, max(1, int(rng.uniform(1, 0.01 * max(h, w) + 1.5))), cv2.LINE_AA)
            col = np.full(3, rng.uniform(10, 80))
        if kind == "cloud":  # soft edges: blur only around what was drawn
            x, y, bw, bh = cv2.boundingRect(one)
            pad = int(3 * max(1.0, reach * 0.08)) + 1
            xa, ya, xb, yb = max(x - pad, 0), max(y - pad, 0), min(x + bw + pad, w), min(y + bh + pad, h)
            if xb > xa and yb > ya:
                one[ya:yb, xa:xb] = cv2.GaussianBlur(one[ya:yb, xa:xb], (0, 0), max(1.0, reach * 0.08))
        x, y, bw, bh = cv2.boundingRect(one)
        if bw == 0 or bh == 0:
            continue
        region = (slice(y, y + bh), slice(x, x + bw))
        m = (one[region].astype(np.float32) / 255.0)[..., None]
        tex = rng.normal(0, 8, (bh, bw, 3)).astype(np.float32) if kind != "cloud" else 0.0
        f = img[region].astype(np.float32)
        f = f * (1 - m) + (np.asarray(col, np.float32) + tex) * m
        img[region] = np.clip(f, 0, 255).astype(np.uint8)
        mask[region] = np.maximum(mask[region], one[region])
    return mask > 127
