"""Moving clutter of drone-free sequences: birds, flying objects and clouds crossing the frame in
straight lines, drawn at random for a frame size (sizes and speeds scale with the frame width).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["Flyer", "random_flyers"]


@dataclass(frozen=True)
class Flyer:
    """A bird, a flying object or a cloud crossing the frame in a straight line (pixels, seconds).

    Positions wrap round a frame grown by ``margin`` on every side: one that leaves comes back in
    from the opposite edge, so long sequences keep their clutter.
    """

    kind: str  # "bird", "blob" or "cloud"
    start: tuple[float, float]
    velocity: tuple[float, float]  # px/s
    size: float  # px: wing span, blob diameter, cloud width
    colour: tuple[float, float, float]  # BGR 0-255
    margin: float
    bank: float = 0.0  # rad
    flap_hz: float = 0.0
    phase: float = 0.0
    outline: np.ndarray | None = None  # blob: (M + 1, 2) outline, then its string's end (0, 0: none), x size
    alpha: np.ndarray | None = None  # cloud: (h, w) float32 opacity patch

    def centre(self, t_s: float, w: int, h: int) -> tuple[float, float]:
        m = self.margin
        x = (self.start[0] + self.velocity[0] * t_s + m) % (w + 2 * m) - m
        y = (self.start[1] + self.velocity[1] * t_s + m) % (h + 2 * m) - m
        return x, y

    def draw(self, img: np.ndarray, t_s: float) -> None:
        """Draw at time ``t_s`` into ``img`` (BGR uint8, in place)."""
        h, w = img.shape[:2]
        cx, cy = self.centre(t_s, w, h)
        if self.kind == "cloud":
            _blend_patch(img, self.alpha, self.colour, cx, cy)
        elif self.kind == "bird":
            span = self.size / 2
            flap = 0.6 * span * math.sin(2 * math.pi * (self.flap_hz * t_s + self.phase))
            pts = np.array(
                [[-span, -flap], [-0.3 * span, -0.2 * flap], [0, 0], [0.3 * span, -0.2 * flap], [span, -flap]]
            )
            c, s = math.cos(self.bank), math.sin(self.bank)
            pts = pts @ np.array([[c, s], [-s, c]]) + [cx, cy]
            thick = max(1, round(self.size / 12))
            cv2.polylines(
                img, [np.round(pts * 16).astype(np.int32)], False, self.colour, thick, cv2.LINE_AA, 4
            )
            body = (max(1, thick), max(1, thick // 2))
            cv2.ellipse(img, (round(cx), round(cy)), body, 0, 0, 360, self.colour, -1, cv2.LINE_AA)
        else:
            outline = self.outline[:-1] * self.size + [cx, cy]
            cv2.fillPoly(img, [np.round(outline * 16).astype(np.int32)], self.colour, cv2.LINE_AA, 4)
            tail = self.outline[-1]
            if np.any(tail):  # a kite string, an antenna, a wing
                end = (round(cx + tail[0] * self.size), round(cy + tail[1] * self.size))
                width = max(1, round(self.size / 15))
                cv2.line(img, (round(cx), round(cy)), end, self.colour, width, cv2.LINE_AA)


def _blend_patch(img: np.ndarray, alpha: np.ndarray, colour: tuple, cx: float, cy: float) -> None:
    """Blend ``colour`` over ``img`` with the opacity patch ``alpha`` centred at (cx, cy), in place."""
    h, w = img.shape[:2]
    ph, pw = alpha.shape
    x0, y0 = round(cx - pw / 2), round(cy - ph / 2)
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + pw, w), min(y0 + ph, h)
    if xb <= xa or yb <= ya:
        return
    a = alpha[ya - y0 : yb - y0, xa - x0 : xb - x0, None]
    region = img[ya:yb, xa:xb].astype(np.float32)
    img[ya:yb, xa:xb] = (region * (1 - a) + np.asarray(colour, np.float32) * a + 0.5).astype(np.uint8)


def _cloud_alpha(rng: np.random.Generator, width: float) -> np.ndarray:
    """A soft cloud's opacity (float32 in [0, 1]) about ``width`` x ``width / 2`` pixels."""
    pw, ph = max(8, int(width)), max(6, int(width / 2))
    mask = np.zeros((ph, pw), np.uint8)
    for _ in range(int(rng.integers(4, 10))):
        cx, cy = rng.uniform(0.25, 0.75) * pw, rng.uniform(0.4, 0.6) * ph
        axes = (max(1, int(pw * rng.uniform(0.1, 0.22))), max(1, int(ph * rng.uniform(0.15, 0.3))))
        cv2.ellipse(mask, (int(cx), int(cy)), axes, 0, 0, 360, 255, -1)
    soft = cv2.GaussianBlur(mask, (0, 0), max(1.0, width * 0.05)).astype(np.float32) / 255.0
    return soft * float(rng.uniform(0.45, 0.9))


def random_flyers(rng: np.random.Generator, w: int, h: int) -> list[Flyer]:
    """Clouds, then flying objects, then birds (drawn in that order), sized for a (w, h) frame."""
    k = w / 1920.0  # the sizes and speeds below are for a 1080p frame
    out: list[Flyer] = []
    for _ in range(int(rng.integers(1, 4))):
        width = float(rng.uniform(0.1, 0.35)) * w
        speed = float(rng.uniform(3.0, 20.0)) * k * rng.choice([-1.0, 1.0])
        alpha = _cloud_alpha(rng, width)
        colour = tuple(float(v) for v in np.full(3, rng.uniform(200, 255)) * rng.uniform(0.9, 1.0, 3))
        start = (float(rng.uniform(0, w)), float(rng.uniform(0, 0.7 * h)))
        out.append(Flyer("cloud", start, (speed, 0.0), width, colour, margin=width, alpha=alpha))
    for _ in range(int(rng.integers(0, 3))):
        size = float(np.exp(rng.uniform(np.log(8), np.log(60)))) * k
        speed, heading = float(rng.uniform(10, 150)) * k, float(rng.uniform(0, 2 * np.pi))
        n = int(rng.integers(3, 9))
        ang = np.sort(rng.uniform(0, 2 * np.pi, n))
        rad = 0.5 * rng.uniform(0.4, 1.0, n)
        outline = np.c_[rad * np.cos(ang), rad * np.sin(ang) * rng.uniform(0.3, 1.0)]
        tail = rng.normal(0, 1.0, 2) if rng.random() < 0.5 else np.zeros(2)
        out.append(
            Flyer(
                "blob",
                (float(rng.uniform(0, w)), float(rng.uniform(0, h))),
                (speed * math.cos(heading), speed * math.sin(heading)),
                size,
                tuple(float(v) for v in rng.uniform(0, 255, 3)),
                margin=2 * size,
                outline=np.vstack([outline, tail]),
            )
        )
    for _ in range(int(rng.integers(2, 7))):
        size = float(np.exp(rng.uniform(np.log(6), np.log(40)))) * k
        speed = float(rng.uniform(40, 250)) * k
        heading = float(rng.normal(0, 0.3)) + (math.pi if rng.random() < 0.5 else 0.0)
        out.append(
            Flyer(
                "bird",
                (float(rng.uniform(0, w)), float(rng.uniform(0, 0.8 * h))),
                (speed * math.cos(heading), speed * math.sin(heading)),
                size,
                tuple(float(v) for v in np.full(3, rng.uniform(10, 70))),
                margin=size,
                bank=float(rng.uniform(-0.5, 0.5)),
                flap_hz=float(rng.uniform(2.0, 6.0)),
                phase=float(rng.uniform(0, 1)),
            )
        )
    return out
