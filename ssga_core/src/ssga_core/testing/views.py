"""A deterministic test view with exactly known geometry."""

from __future__ import annotations

import numpy as np

from ssga_core.data import View
from ssga_core.geometry import Camera, Pose


def make_view(seed: int = 0, size: int = 256, distance: float = 3.0, pose: Pose | None = None, rectangles: int = 12) -> View:
    """A camera facing a flat wall ``distance`` metres ahead, painted with coloured rectangles.

    The wall is perpendicular to the optical axis, so the planar depth is ``distance``
    everywhere, which makes every warp of this view exactly predictable. Semantic ids
    are the rectangle index (``-1`` on the background), instance ids the same.
    """
    rng = np.random.default_rng(seed)
    camera = Camera(width=size, height=size)
    v, u = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    rgb = np.stack([60 + 80 * u, 70 + 60 * v, 90 + 40 * (1 - u) * v], axis=-1)
    semantic = np.full((size, size), -1, dtype=np.int32)
    for k in range(rectangles):
        w, h = rng.integers(size // 10, size // 3, size=2)
        x0, y0 = rng.integers(0, size - w), rng.integers(0, size - h)
        rgb[y0 : y0 + h, x0 : x0 + w] = rng.integers(0, 256, size=3)
        semantic[y0 : y0 + h, x0 : x0 + w] = k
    return View(
        rgb=np.clip(rgb, 0, 255).astype(np.uint8),
        pose=pose or Pose(0.0, 0.0, 0.0),
        camera=camera,
        depth=np.full((size, size), distance, dtype=np.float32),
        semantic=semantic,
        instance=semantic.copy(),
    )


def make_panorama_view(pose: Pose, seed: int = 0, size: int = 256, distance: float = 3.0, bands: int = 48) -> View:
    """The view from ``pose`` inside a round room painted with vertical colour bands.

    Each image column shows the band at the world bearing of its ray, so views depend
    on the heading (and turning moves the content as a camera would) but not on the
    position: enough for a stand-in workspace whose classes can be learned by heading.
    Depth is ``distance`` everywhere; semantic and instance ids are the band index.
    """
    rng = np.random.default_rng(seed)
    colours = rng.integers(30, 226, size=(bands, 3))
    camera = Camera(width=size, height=size)
    u = np.arange(size)
    bearing = pose.yaw + np.arctan2(camera.principal_point[0] - u, camera.focal_px)
    band = (np.floor(np.mod(bearing, 2 * np.pi) / (2 * np.pi) * bands)).astype(np.int32)
    shade = np.linspace(1.1, 0.8, size)[:, None, None]
    rgb = np.clip(colours[band][None, :, :] * shade, 0, 255).astype(np.uint8)
    ids = np.broadcast_to(band, (size, size)).astype(np.int32)
    depth = np.full((size, size), distance, dtype=np.float32)
    return View(rgb=rgb, pose=pose, camera=camera, depth=depth, semantic=ids, instance=ids.copy())
