"""Backgrounds behind the drone: procedural skies, clouds, horizons, terrain and city skylines,
real photographs that installed packages ship (``packaged_photos``), or photos from a folder.

The packaged photographs (scikit-image's ``skimage.data``, scikit-learn's sample images) are split
once and for all: ``TRAIN_PHOTOS`` feed the training sampler, ``HELD_OUT_PHOTOS`` only the
evaluation, so ``dronekey-eval robustness`` measures backgrounds the network never saw.

Everything is drawn from a ``numpy.random.Generator`` so a seed gives the same pictures. The
procedural textures are sums of bilinearly upsampled noise octaves (cheap fractal noise): enough
clutter at every scale for a detector not to learn "drone = only object in the sky".
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

__all__ = [
    "HELD_OUT_PHOTOS",
    "PROCEDURAL_KINDS",
    "TRAIN_PHOTOS",
    "BackgroundSource",
    "fractal_noise",
    "landscape",
    "packaged_photos",
    "sky",
    "urban",
]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff")
# Photographs that ship inside installed packages, by name: skimage.data functions, or
# "sklearn:<file>" for scikit-learn's sample images. None needs a download.
TRAIN_PHOTOS = (
    "astronaut",
    "coffee",
    "chelsea",
    "cat",
    "coins",
    "moon",
    "brick",
    "grass",
    "gravel",
    "hubble_deep_field",
)
HELD_OUT_PHOTOS = ("rocket", "camera", "sklearn:china.jpg", "sklearn:flower.jpg")
PROCEDURAL_KINDS = ("sky", "landscape", "urban")


def _load_packaged(name: str) -> np.ndarray | None:
    """One packaged photograph as BGR uint8, or None when its package is not installed."""
    try:
        if name.startswith("sklearn:"):
            from sklearn.datasets import load_sample_image

            rgb = load_sample_image(name.split(":", 1)[1])
        else:
            import skimage.data

            rgb = getattr(skimage.data, name)()
    except (ImportError, AttributeError, OSError, ValueError):
        return None
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = np.repeat(rgb[..., None], 3, axis=2)
    rgb = rgb[..., :3]
    if rgb.dtype != np.uint8:
        rgb = (np.clip(rgb.astype(np.float64) / max(float(rgb.max()), 1e-9), 0, 1) * 255).astype(np.uint8)
    return np.ascontiguousarray(rgb[..., ::-1])


_PACKAGED: dict[str, np.ndarray | None] = {}


def packaged_photos(names: tuple[str, ...] = TRAIN_PHOTOS) -> list[np.ndarray]:
    """The packaged photographs of ``names`` that are installed (BGR uint8), loaded once per process.

    scikit-image and scikit-learn come with the ``train`` and ``test`` extras; without them the list
    is empty and the backgrounds stay procedural.
    """
    out = []
    for name in names:
        if name not in _PACKAGED:
            _PACKAGED[name] = _load_packaged(name)
        if _PACKAGED[name] is not None:
            out.append(_PACKAGED[name])
    return out


def fractal_noise(
    h: int, w: int, rng: np.random.Generator, scale: float = 0.25, octaves: int = 5
) -> np.ndarray:
    """Fractal noise in [0, 1], (h, w) float32; ``scale``: largest feature as a fraction of max(h, w)."""
    out = np.zeros((h, w), np.float32)
    amp, total = 1.0, 0.0
    cell = max(2.0, scale * max(h, w))
    for _ in range(octaves):
        gh, gw = max(2, int(h / cell) + 2), max(2, int(w / cell) + 2)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
        total += amp
        amp *= 0.5
        cell /= 2.0
        if cell < 1.5:
            break
    out /= total
    lo, hi = np.percentile(out[:: max(1, h // 64), :: max(1, w // 64)], [1, 99])
    return np.clip((out - lo) / max(hi - lo, 1e-6), 0, 1)


def _gradient(h: int, w: int, top: np.ndarray, bottom: np.ndarray, y0: float, y1: float) -> np.ndarray:
    y = np.linspace(0, 1, h, dtype=np.float32)
    a = np.clip((y - y0) / max(y1 - y0, 1e-6), 0, 1)[:, None, None]
    col = top[None, None, :] * (1 - a) + bottom[None, None, :] * a
    return np.ascontiguousarray(np.broadcast_to(col, (h, w, 3)), dtype=np.float32)


def sky(h: int, w: int, rng: np.random.Generator, horizon: float | None = None) -> np.ndarray:
    """A sky (BGR float32 in [0, 1]): clear blue, hazy, overcast or sunset, with clouds."""
    kind = rng.choice(["clear", "hazy", "overcast", "sunset"], p=[0.4, 0.25, 0.2, 0.15])
    horizon = rng.uniform(0.6, 1.6) if horizon is None else horizon
    if kind == "clear":
        top, bottom = np.array([0.75, 0.45, 0.2]), np.array([0.95, 0.85, 0.75])
    elif kind == "hazy":
        top, bottom = np.array([0.85, 0.7, 0.55]), np.array([0.92, 0.9, 0.88])
    elif kind == "overcast":
        g = rng.uniform(0.45, 0.85)
        top, bottom = np.full(3, g * 0.9), np.full(3, min(1.0, g * 1.1))
    else:
        top, bottom = np.array([0.6, 0.35, 0.3]), np.array([0.45, 0.65, 0.98])
    top = np.clip(top + rng.normal(0, 0.05, 3), 0, 1)
    bottom = np.clip(bottom + rng.normal(0, 0.04, 3), 0, 1)
    img = _gradient(h, w, top, bottom, -0.2, horizon)
    cover = rng.uniform(0.0, 0.9) if kind != "overcast" else rng.uniform(0.5, 1.0)
    if cover > 0.05:
        n = fractal_noise(h, w, rng, scale=rng.uniform(0.15, 0.6), octaves=6)
        thr = 1.0 - cover
        clouds = np.clip((n - thr) / max(1 - thr, 1e-3) * rng.uniform(1.0, 3.0), 0, 1)[..., None]
        shade = fractal_noise(h, w, rng, scale=0.1, octaves=4)[..., None]
        tone = rng.uniform(0.75, 1.0) - 0.35 * shade * rng.uniform(0.2, 1.0)
        img = img * (1 - clouds) + tone * clouds
    return img


def landscape(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Sky over a horizon with fields, forest edges or hills (BGR float32 in [0, 1])."""
    hy = rng.uniform(0.35, 0.95)
    img = sky(h, w, rng, horizon=hy)
    tilt = rng.uniform(-0.05, 0.05)
    x = np.linspace(-0.5, 0.5, w, dtype=np.float32)
    ridge = fractal_noise(1, w, rng, scale=rng.uniform(0.1, 0.5), octaves=5)[0] - 0.5
    skyline = (hy + tilt * x + ridge * rng.uniform(0.0, 0.15)) * h
    rows = np.arange(h, dtype=np.float32)[:, None]
    ground = rows >= skyline[None, :]
    base = np.array(rng.choice([[0.25, 0.45, 0.3], [0.3, 0.5, 0.55], [0.35, 0.45, 0.5], [0.2, 0.3, 0.25]]))
    tex = fractal_noise(h, w, rng, scale=rng.uniform(0.05, 0.3), octaves=6)[..., None]
    fine = fractal_noise(h, w, rng, scale=0.01, octaves=3)[..., None]
    ground_col = base * (0.55 + 0.6 * tex) * (0.85 + 0.3 * fine)
    haze = np.clip(1.0 - (rows - skyline[None, :]) / (0.25 * h + 1), 0, 1)[..., None] * rng.uniform(0.0, 0.6)
    ground_col = ground_col * (1 - haze) + img * haze
    return np.where(ground[..., None], ground_col, img)


def urban(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Sky over a city skyline: buildings with window grids, masts and wires (BGR float32 in [0, 1])."""
    img = sky(h, w, rng, horizon=rng.uniform(0.7, 1.3))
    base_y = int(h * rng.uniform(0.75, 1.05))
    for _ in range(int(rng.integers(4, 14))):
        bw = int(w * rng.uniform(0.05, 0.3))
        bh = int(h * rng.uniform(0.1, 0.7))
        x0 = int(rng.uniform(-0.1, 1.0) * w)
        y0 = base_y - bh
        col = np.clip(rng.uniform(0.15, 0.75) + rng.normal(0, 0.05, 3), 0, 1)
        xa, xb, ya = max(x0, 0), min(x0 + bw, w), max(y0, 0)
        if xb <= xa or ya >= h:
            continue
        img[ya:, xa:xb] = col
        win = max(3, int(bw * rng.uniform(0.04, 0.12)))
        wc = np.clip(col * rng.uniform(0.4, 1.6), 0, 1)
        for yy in range(y0 + win, min(h, base_y) - win, 2 * win):
            for xx in range(x0 + win // 2, x0 + bw - win, 2 * win):
                if 0 <= yy < h and 0 <= xx < w and rng.random() < 0.8:
                    img[yy : yy + win, xx : xx + win] = wc
    for _ in range(int(rng.integers(0, 4))):  # masts and power lines: thin clutter
        x = int(rng.uniform(0, w))
        cv2.line(img, (x, h), (x + int(rng.normal(0, 5)), int(h * rng.uniform(0.1, 0.6))), (0.1, 0.1, 0.1), 2)
    for _ in range(int(rng.integers(0, 3))):
        y1, y2 = (int(h * v) for v in rng.uniform(0.05, 0.6, 2))
        cv2.line(img, (0, y1), (w, y2), (0.15, 0.15, 0.15), 1, cv2.LINE_AA)
    return img


class BackgroundSource:
    """Draws backgrounds of a requested size: procedural, or photos when given.

    Parameters
    ----------
    folder : path or None
        Folder of images (searched recursively for jpg/png/bmp/webp/tiff). Photos are cropped at a
        random position and scale to the requested aspect ratio.
    photo_fraction : float
        Share of photos among the backgrounds when there are photos.
    images : list of BGR uint8 arrays, optional
        Photos already in memory (``packaged_photos``), drawn beside the folder's.
    kinds : tuple of str
        Procedural kinds to draw from (``PROCEDURAL_KINDS``), at their usual odds.
    """

    def __init__(
        self,
        folder: str | Path | None = None,
        photo_fraction: float = 0.7,
        images: list[np.ndarray] | None = None,
        kinds: tuple[str, ...] = PROCEDURAL_KINDS,
    ) -> None:
        unknown = set(kinds) - set(PROCEDURAL_KINDS)
        if not kinds or unknown:
            raise ValueError(f"kinds must be a non-empty subset of {PROCEDURAL_KINDS}, got {kinds}")
        self.images: list[np.ndarray] = list(images or [])
        self.photos: list[Path] = []
        if folder is not None:
            folder = Path(folder)
            if not folder.is_dir():
                raise FileNotFoundError(f"backgrounds folder not found: {folder}")
            self.photos = sorted(p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES)
            if not self.photos:
                raise FileNotFoundError(
                    f"no images ({', '.join(IMAGE_SUFFIXES)}) in backgrounds folder {folder}"
                )
        self.photo_fraction = photo_fraction if (self.photos or self.images) else 0.0
        odds = {"sky": (0.4, sky), "landscape": (0.35, landscape), "urban": (0.25, urban)}
        self._kinds: list[tuple[float, Callable]] = [odds[k] for k in kinds]

    def draw(self, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
        """A (h, w, 3) uint8 BGR background."""
        if self.photo_fraction and rng.random() < self.photo_fraction:
            n_files = len(self.photos)
            k = int(rng.integers(n_files + len(self.images)))
            img = self._photo(h, w, rng, k) if k < n_files else _fit(self.images[k - n_files], h, w, rng)
            if img is not None:
                return img
        probs = np.array([p for p, _ in self._kinds])
        fn = self._kinds[int(rng.choice(len(self._kinds), p=probs / probs.sum()))][1]
        # Procedural textures are smooth: draw large ones at half resolution and upsample (4x faster).
        half = h * w > 640 * 480
        img = fn(h // 2, w // 2, rng) if half else fn(h, w, rng)
        img = (np.clip(img, 0, 1) * 255).astype(np.uint8)
        return cv2.resize(img, (w, h), interpolation=cv2.INTER_LINEAR) if half else img

    def _photo(self, h: int, w: int, rng: np.random.Generator, k: int) -> np.ndarray | None:
        img = cv2.imread(str(self.photos[k]), cv2.IMREAD_COLOR)
        return None if img is None else _fit(img, h, w, rng)


def _fit(img: np.ndarray, h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A random part of a photo at the requested aspect ratio, maybe mirrored, resized to (h, w)."""
    ih, iw = img.shape[:2]
    s = rng.uniform(0.5, 1.0) * min(iw / w, ih / h)
    cw, ch = max(1, int(w * s)), max(1, int(h * s))
    x0, y0 = int(rng.integers(0, iw - cw + 1)), int(rng.integers(0, ih - ch + 1))
    crop = img[y0 : y0 + ch, x0 : x0 + cw]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    interp = cv2.INTER_AREA if cw > w else cv2.INTER_LINEAR
    return cv2.resize(np.ascontiguousarray(crop), (w, h), interpolation=interp)
