"""Surface textures: scikit-image's photographs and procedural patterns made with numpy.

Every texture knows its physical size (``size``: metres covered by one repeat), so the
mesh builders can UV-map in metres and a brick is the same size on every wall. Tiling
textures are periodic, so repeats meet without seams: procedural ones are made periodic
(noise filtered in the Fourier domain, patterns on a whole number of periods), and
photographs are mirror-tiled. Images follow trimesh's UV convention (``v = 0`` is the
image's bottom row), so a texture is upright when ``v`` grows with height.

All randomness comes from the ``rng`` passed in; nothing here touches a global RNG.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
from PIL import Image

RESOLUTION = 256
"""Pixels per side of a tiling texture (one repeat)."""


@dataclass(frozen=True, eq=False)
class Texture:
    """An RGB image and the physical size of one repeat of it.

    Attributes:
        name: what it is (``"oak-planks"``); used for material names in exports.
        image: the RGB image.
        size: ``(width, height)`` in metres covered by one repeat of ``image``.
    """

    name: str
    image: Image.Image
    size: tuple[float, float] = (1.0, 1.0)


Rgb = tuple[float, float, float]
"""A colour as three floats in ``[0, 1]``."""


def to_image(rgb: np.ndarray) -> Image.Image:
    """An 8-bit RGB image from floats in ``[0, 1]``."""
    return Image.fromarray(np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8), "RGB")


def tint(gray: np.ndarray, dark: Rgb, light: Rgb) -> np.ndarray:
    """Colour a ``[0, 1]`` grey image by blending two colours (``(H, W, 3)`` floats)."""
    g = gray[..., None]
    return (1.0 - g) * np.asarray(dark) + g * np.asarray(light)


def jitter(rng: np.random.Generator, colour: Rgb, amount: float = 0.06) -> Rgb:
    """``colour`` with a small random change, so rooms built from one recipe still differ."""
    c = np.clip(np.asarray(colour) + rng.uniform(-amount, amount, 3), 0.0, 1.0)
    return (float(c[0]), float(c[1]), float(c[2]))


def periodic_noise(rng: np.random.Generator, shape: tuple[int, int], scale: tuple[float, float]) -> np.ndarray:
    """Smooth noise in ``[0, 1]`` that tiles seamlessly.

    White noise low-pass filtered in the Fourier domain is periodic by construction.
    ``scale`` is the filter's standard deviation in pixels along ``(rows, cols)``;
    unequal scales give streaks (wood grain).
    """
    white = rng.standard_normal(shape)
    fy = np.fft.fftfreq(shape[0])[:, None]
    fx = np.fft.rfftfreq(shape[1])[None, :]
    kernel = np.exp(-2.0 * np.pi**2 * ((fy * scale[0]) ** 2 + (fx * scale[1]) ** 2))
    smooth = np.fft.irfft2(np.fft.rfft2(white) * kernel, s=shape)
    lo, hi = smooth.min(), smooth.max()
    return (smooth - lo) / (hi - lo + 1e-12)


# --- procedural tiling textures ------------------------------------------------------


def wood_planks(rng: np.random.Generator, colour: Rgb, planks: int = 6) -> Texture:
    """Floorboards running along ``u``: per-plank tone, streaky grain, staggered joints."""
    n = RESOLUTION
    grain = periodic_noise(rng, (n, n), (1.0, 24.0))
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (np.arange(n)[:, None] / n * planks * 3 + 4.0 * grain))
    tone = np.zeros((n, n))
    rows = np.arange(n) * planks // n
    seams = np.zeros((n, n), dtype=bool)
    for p in range(planks):
        mask = rows == p
        tone[mask] = rng.uniform(-0.08, 0.08)
        seams[np.flatnonzero(mask)[[0, -1]]] = True
        joint = int(rng.integers(0, n))
        seams[mask, joint : joint + 2] = True
    shade = 0.75 + 0.15 * rings + 0.15 * grain + tone
    rgb = np.asarray(colour) * shade[..., None]
    rgb[seams] *= 0.55
    return Texture("wood-planks", to_image(rgb), (1.0, 1.0))


def tiles(rng: np.random.Generator, colour: Rgb, count: int = 4, tile_m: float = 0.3) -> Texture:
    """``count`` x ``count`` square tiles with grout, each tile a slightly different shade."""
    cell = RESOLUTION // count
    n = cell * count
    shade = np.repeat(np.repeat(rng.uniform(0.9, 1.05, (count, count)), cell, 0), cell, 1)
    speckle = periodic_noise(rng, (n, n), (1.5, 1.5))
    rgb = np.asarray(colour) * (shade * (0.93 + 0.1 * speckle))[..., None]
    grout = (np.arange(n) % cell) < max(2, cell // 24)
    rgb[grout, :] = rgb[:, grout] = 0.45 * np.asarray(colour) + 0.25
    return Texture("tiles", to_image(rgb), (count * tile_m, count * tile_m))


def plaster(rng: np.random.Generator, colour: Rgb) -> Texture:
    """Painted plaster: a flat colour with faint blotches, 2 m per repeat."""
    n = RESOLUTION
    blotch = periodic_noise(rng, (n, n), (12.0, 12.0))
    fine = periodic_noise(rng, (n, n), (1.0, 1.0))
    rgb = np.asarray(colour) * (0.9 + 0.08 * blotch + 0.04 * fine)[..., None]
    return Texture("plaster", to_image(rgb), (2.0, 2.0))


def wallpaper(rng: np.random.Generator, colour: Rgb, accent: Rgb) -> Texture:
    """Vertical stripes (alternating widths) with a dotted accent stripe, 0.5 m per repeat."""
    n = RESOLUTION
    u = np.arange(n) / n
    stripe = (np.sin(2 * np.pi * 4 * u) > 0.3)[None, :].repeat(n, 0)
    dots = ((np.arange(n)[:, None] % 16) < 5) & (np.abs(u[None, :] * 4 % 1 - 0.88) < 0.02)
    rgb = np.broadcast_to(np.asarray(colour), (n, n, 3)).copy()
    rgb[stripe] = 0.92 * np.asarray(colour)
    rgb[dots] = np.asarray(accent)
    rgb *= (0.96 + 0.04 * periodic_noise(rng, (n, n), (1.0, 1.0)))[..., None]
    return Texture("wallpaper", to_image(rgb), (0.5, 0.5))


def rug(rng: np.random.Generator, colour: Rgb, accent: Rgb) -> Texture:
    """A whole rug (not tiling): a border, an inner border and a woven field."""
    n = RESOLUTION
    v, u = np.mgrid[0:n, 0:n] / (n - 1)
    edge = np.minimum(np.minimum(u, 1 - u), np.minimum(v, 1 - v))
    weave = periodic_noise(rng, (n, n), (0.8, 0.8))
    rgb = tint(0.85 + 0.15 * weave, (0, 0, 0), colour)
    band = (edge < 0.08) | ((edge > 0.12) & (edge < 0.14))
    rgb[band] = tint(0.85 + 0.15 * weave[band], (0, 0, 0), accent)
    diamond = np.abs(np.abs(u - 0.5) + np.abs(v - 0.5) - 0.22) < 0.025
    rgb[diamond] = np.asarray(accent)
    return Texture("rug", to_image(rgb), (1.0, 1.0))


# --- scikit-image photographs --------------------------------------------------------


@cache
def _photo(name: str) -> np.ndarray:
    """A scikit-image sample image (they ship with the package; no download), as floats."""
    import skimage.data

    img = getattr(skimage.data, name)()
    return img.astype(np.float64) / 255.0


def _mirror_tile(img: np.ndarray) -> np.ndarray:
    """Make a photograph periodic by mirroring it into a 2 x 2 block, at the texture resolution."""
    from skimage.transform import resize

    half = resize(img, (RESOLUTION // 2, RESOLUTION // 2), anti_aliasing=True)
    top = np.concatenate([half, half[:, ::-1]], axis=1)
    return np.concatenate([top, top[::-1]], axis=0)


def brick(rng: np.random.Generator, dark: Rgb, light: Rgb) -> Texture:
    """``skimage.data.brick`` turned so the courses are horizontal, tinted, 1.6 m per repeat."""
    gray = _photo("brick")[96:416, 96:416].T  # the centre, where the perspective is mildest
    return Texture("brick", to_image(tint(_mirror_tile(gray), dark, light)), (1.6, 1.6))


def carpet(rng: np.random.Generator, dark: Rgb, light: Rgb) -> Texture:
    """``skimage.data.grass`` tinted into a deep-pile carpet, 1 m per repeat."""
    return Texture("carpet", to_image(tint(_mirror_tile(_photo("grass")), dark, light)), (1.0, 1.0))


def stone(rng: np.random.Generator, dark: Rgb, light: Rgb) -> Texture:
    """``skimage.data.gravel`` tinted into a pebble/terrazzo floor, 1.2 m per repeat."""
    return Texture("stone", to_image(tint(_mirror_tile(_photo("gravel")), dark, light)), (1.2, 1.2))


POSTERS: tuple[str, ...] = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "immunohistochemistry",
    "hubble_deep_field",
    "colorwheel",
    "camera",
    "coins",
    "moon",
    "retina",
    "text",
    "page",
    "cell",
)
"""scikit-image sample photographs hung as paintings and posters."""

FRAME_FRACTION = 0.05
"""Width of a poster's frame as a fraction of the image's shorter side."""


@cache
def _poster_photo(name: str, long_side_px: int) -> np.ndarray:
    """A sample photograph as RGB floats, resized so its longer side is ``long_side_px``."""
    from skimage.transform import resize

    img = _photo(name)
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    img = img[..., :3]
    h, w = img.shape[:2]
    scale = long_side_px / max(h, w)
    return resize(img, (max(1, round(h * scale)), max(1, round(w * scale))), anti_aliasing=True)


def poster(name: str, frame: Rgb, long_side_px: int = 320) -> Texture:
    """A framed photograph; ``size`` is its aspect ratio (width, height) with the longer side 1.

    The frame is painted into the image, so the sides and back of the poster's box can
    sample its corner pixel and the whole poster stays one geometry with one material.
    """
    img = _poster_photo(name, long_side_px)
    b = max(2, round(FRAME_FRACTION * min(img.shape[:2])))
    out = np.empty((img.shape[0] + 2 * b, img.shape[1] + 2 * b, 3))
    out[:] = np.asarray(frame)
    out[b:-b, b:-b] = img
    hh, ww = out.shape[:2]
    return Texture(f"poster-{name}", to_image(out), (ww / max(hh, ww), hh / max(hh, ww)))


# --- per-room choices ----------------------------------------------------------------

WOODS: tuple[Rgb, ...] = ((0.62, 0.42, 0.24), (0.78, 0.6, 0.4), (0.45, 0.28, 0.16), (0.7, 0.55, 0.42))
PAINTS: tuple[Rgb, ...] = (
    (0.93, 0.91, 0.86),
    (0.85, 0.89, 0.92),
    (0.9, 0.84, 0.78),
    (0.8, 0.87, 0.8),
    (0.95, 0.88, 0.7),
    (0.84, 0.8, 0.88),
)


def _pick(rng: np.random.Generator, options: tuple[Rgb, ...]) -> Rgb:
    return jitter(rng, options[int(rng.integers(len(options)))], 0.04)


FLOORS: dict[str, Callable[[np.random.Generator], Texture]] = {
    "wood": lambda rng: wood_planks(rng, _pick(rng, WOODS)),
    "tiles": lambda rng: tiles(rng, jitter(rng, (0.82, 0.8, 0.76), 0.1), count=int(rng.integers(2, 5))),
    "carpet": lambda rng: carpet(rng, jitter(rng, (0.15, 0.12, 0.2), 0.05), jitter(rng, (0.6, 0.5, 0.55), 0.15)),
    "stone": lambda rng: stone(rng, jitter(rng, (0.3, 0.28, 0.25), 0.05), jitter(rng, (0.85, 0.82, 0.76), 0.06)),
}
"""Floor recipes; :func:`room_surfaces` draws one per room."""

WALLS: dict[str, Callable[[np.random.Generator], Texture]] = {
    "plaster": lambda rng: plaster(rng, _pick(rng, PAINTS)),
    "wallpaper": lambda rng: wallpaper(rng, _pick(rng, PAINTS), jitter(rng, (0.55, 0.35, 0.3), 0.2)),
    "brick": lambda rng: brick(rng, jitter(rng, (0.25, 0.1, 0.06), 0.05), jitter(rng, (0.85, 0.5, 0.38), 0.08)),
    "tiles": lambda rng: tiles(rng, _pick(rng, PAINTS), count=4, tile_m=0.15),
}
"""Wall recipes; :func:`room_surfaces` draws one per room."""

ROOM_STYLES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "living": (("wood", "carpet", "stone"), ("plaster", "wallpaper", "brick")),
    "bedroom": (("wood", "carpet"), ("plaster", "wallpaper")),
    "kitchen": (("tiles", "stone"), ("tiles", "plaster", "brick")),
    "office": (("wood", "carpet", "tiles"), ("plaster", "wallpaper", "brick")),
}
"""For each room kind, the floor and wall recipes it may use."""


def room_surfaces(rng: np.random.Generator, kind: str) -> tuple[Texture, Texture]:
    """A floor and a wall texture for a room of ``kind``, drawn from its style."""
    floors, walls = ROOM_STYLES[kind]
    floor = FLOORS[floors[int(rng.integers(len(floors)))]](rng)
    wall = WALLS[walls[int(rng.integers(len(walls)))]](rng)
    return floor, wall


def ceiling(rng: np.random.Generator) -> Texture:
    """White ceiling plaster."""
    return plaster(rng, jitter(rng, (0.96, 0.96, 0.94), 0.02))


def facade(rng: np.random.Generator) -> Texture:
    """The outside of the outer walls (seen only from outside, in a viewer)."""
    return plaster(rng, jitter(rng, (0.8, 0.78, 0.72), 0.05))
