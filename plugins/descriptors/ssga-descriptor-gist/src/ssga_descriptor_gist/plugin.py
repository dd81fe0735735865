"""GIST, a layout descriptor: what the image looks like from across the room, not what its patches show.

A bag of local words (``dense-sift``, ``pnv``) forgets where each word stood; two views of
one room from different places share their words and differ in their layout. This one keeps
the layout, in the spirit of Oliva and Torralba's GIST (2001):

* **gradients**: the image (or a region's box) in grey at ``size`` x ``size``, its gradient
  orientations in ``orientations`` bins (unsigned), each pixel voting its gradient magnitude,
  the votes averaged over a ``grid`` x ``grid`` grid; square-rooted (Hellinger) and
  L2-normalised. The room's corners, the floor's and the ceiling's edges and the furniture's
  outlines, each where it stands;
* **colour** (``colour > 0``): the image at ``colour_grid`` x ``colour_grid`` in CIELAB
  (area-averaged), less its mean, L2-normalised, weighted by ``colour``;

concatenated and L2-normalised, so the cosine of two features weighs the colour layout
``colour**2`` against the gradients. A pseudo-view drawn by a synthesizer that fills in
the room where no real view looked has the room's shape right where its texture is guessed,
which this descriptor reads and a bag of words does not (docs/experiments.md, "A layout
descriptor"). Weight-free: nothing is fitted, so it describes the same in every process.
"""

from __future__ import annotations

import cv2
import numpy as np
from pydantic import Field

from ssga_core import InputError, RegionDescriptor, Regions, StageConfig, View, box_pixels, hookimpl


class GistConfig(StageConfig):
    size: int = Field(default=64, ge=8, description="Side in pixels the image (or a region's box) is resized to before its gradients are taken.")
    grid: int = Field(default=8, ge=1, description="Cells per side of the grid the gradient energy is averaged on.")
    orientations: int = Field(default=8, ge=2, description="Bins of gradient orientation (unsigned, over 180 degrees).")
    colour: float = Field(
        default=0.5,
        ge=0.0,
        description="Weight of the colour layout beside the gradients (0: gradients only). Chosen on bench tuning "
        "homes 0-1 of 0 / 0.5 / 1, by its sum with SIFT-SL (SPD)'s scores (docs/experiments.md, 'A layout descriptor').",
    )
    colour_grid: int = Field(default=8, ge=1, description="Cells per side of the colour layout (CIELAB, area-averaged).")


class Gist(RegionDescriptor):
    name = "gist"
    abbrev = "GIST"
    Config = GistConfig

    @property
    def dim(self) -> int:
        c = self.config
        return c.grid**2 * c.orientations + (c.colour_grid**2 * 3 if c.colour > 0 else 0)

    def _describe(self, view: View, regions: Regions | None) -> np.ndarray:
        rgb = view.rgb
        crops = [rgb] + ([box_pixels(rgb, box) for box in regions.boxes] if regions is not None else [])
        return np.stack([self.feature(crop) for crop in crops])

    def feature(self, rgb: np.ndarray) -> np.ndarray:
        """The ``(dim,)`` feature of one ``(H, W, 3)`` uint8 image."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise InputError(f"descriptor 'gist': expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
        c = self.config
        grey = cv2.resize(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32), (c.size, c.size), interpolation=cv2.INTER_AREA)
        gx, gy = cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1)
        magnitude = np.hypot(gx, gy)
        bins = np.minimum(((np.arctan2(gy, gx) % np.pi) / np.pi * c.orientations).astype(np.int64), c.orientations - 1)
        votes = np.zeros((c.size, c.size, c.orientations), np.float32)
        np.put_along_axis(votes, bins[..., None], magnitude[..., None], axis=2)
        # Area-averaging to the grid is the mean over each cell (exact when the grid divides the size).
        energy = cv2.resize(votes, (c.grid, c.grid), interpolation=cv2.INTER_AREA).reshape(-1)
        parts = [_unit(np.sqrt(np.maximum(energy, 0.0)))]
        if c.colour > 0:
            lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
            layout = cv2.resize(lab, (c.colour_grid, c.colour_grid), interpolation=cv2.INTER_AREA).reshape(-1)
            parts.append(c.colour * _unit(layout - layout.mean()))
        return _unit(np.concatenate(parts)).astype(np.float32)


def _unit(x: np.ndarray) -> np.ndarray:
    norm = float(np.linalg.norm(x))
    return x / norm if norm > 0 else x


@hookimpl
def ssga_register_descriptors() -> list[type[RegionDescriptor]]:
    return [Gist]
