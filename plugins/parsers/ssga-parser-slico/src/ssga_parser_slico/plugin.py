"""SLICO superpixels (zero-parameter SLIC) as scene-graph parts: the paper's P-SL parser (§3.1.1).

SLIC clusters pixels by colour (CIELAB) and position around seeds laid on a regular
grid, so its regions follow image edges yet stay roughly grid cells: "region
decomposition resembling regular grids that are view-independent". SLICO (SLIC zero)
replaces the fixed colour/space trade-off by each superpixel's own colour spread, which
leaves the superpixel count as the only real parameter. scikit-image does the work;
this module picks its parameters, keeps tiny fragments out of the graph and scales
with the image.
"""

from __future__ import annotations

import math
from typing import Self

import numpy as np
from pydantic import Field, model_validator

from ssga_core import Parser, Regions, StageConfig, View, hookimpl

REFERENCE_AREA = 256 * 256
"""``n_segments`` counts superpixels per this many pixels (the paper's 256 x 256 images)."""


class SlicoConfig(StageConfig):
    n_segments: int = Field(
        default=64,
        ge=1,
        le=4096,
        description=(
            "Superpixels per 256 x 256 pixels, scaled by the image's area, so a superpixel keeps its size in pixels "
            "(64: about 32 x 32 px). At 64, about four regions in five hold two or more of the 144 patch features the "
            "paper's descriptor extracts per 256 x 256 image; at 100, fewer than half do."
        ),
    )
    compactness: float = Field(
        default=10.0,
        gt=0.0,
        le=1000.0,
        description="SLICO's initial weight of position against colour; higher gives squarer, more grid-like regions. "
        "SLICO adapts it to each superpixel after the first iteration, so it matters little.",
    )
    sigma: float = Field(
        default=0.0,
        ge=0.0,
        le=10.0,
        description="Width in pixels of a Gaussian blur applied before clustering (0: none); "
        "raise it for noisy or finely textured images.",
    )
    max_iterations: int = Field(
        default=10,
        ge=1,
        le=100,
        description="k-means iterations; 5 is about 1.5x faster with slightly looser boundaries.",
    )
    min_region_px: int = Field(
        default=256,
        ge=0,
        le=REFERENCE_AREA,
        description=(
            "Connected pieces smaller than this many pixels are merged into an adjacent region, so every region of a real "
            "view has at least this many pixels (0 keeps every fragment). Must stay below the nominal superpixel size, "
            "65536 / n_segments."
        ),
    )
    drop_holes: bool = Field(
        default=True,
        description=(
            "In a synthetic view with depth, pixels the synthesizer left empty (no depth) get no region, and what is left "
            "of a region there below min_region_px is dropped, so the holes do not become parts of the graph."
        ),
    )

    @model_validator(mode="after")
    def _min_below_nominal(self) -> Self:
        nominal = REFERENCE_AREA / self.n_segments
        if self.min_region_px >= nominal:
            raise ValueError(
                f"min_region_px ({self.min_region_px}) must be below the nominal superpixel size, "
                f"{nominal:.0f} px at n_segments={self.n_segments}; lower one of them"
            )
        return self


class SlicoParser(Parser):
    """SLICO superpixels; every pixel of a real view belongs to exactly one region."""

    name = "slico"
    abbrev = "SL"
    Config = SlicoConfig
    presets = {
        "coarse": {"n_segments": 25, "min_region_px": 640},
        "fine": {"n_segments": 100, "min_region_px": 160},
    }

    def segments(self, shape: tuple[int, int]) -> int:
        """The superpixel count asked of SLIC for an image of ``(height, width)`` pixels."""
        h, w = shape
        return max(1, round(self.config.n_segments * h * w / REFERENCE_AREA))

    def _parse(self, view: View) -> Regions:
        from skimage.segmentation import slic  # imported here: keeps plugin discovery light

        cfg = self.config
        h, w = view.camera.shape
        n = self.segments((h, w))
        # SLIC merges connected pieces smaller than min_size_factor * (h * w / seeds) into a
        # neighbour, where seeds is the number of grid seeds it laid (near n, rarely equal);
        # the half pixel keeps int() in SLIC from rounding the threshold down.
        min_size_factor = (cfg.min_region_px + 0.5) * _seeds((h, w), n) / (h * w) if cfg.min_region_px else 0.0
        labels = slic(
            view.rgb,
            n_segments=n,
            compactness=cfg.compactness,
            max_num_iter=cfg.max_iterations,
            sigma=cfg.sigma,
            slic_zero=True,
            start_label=0,
            enforce_connectivity=True,
            min_size_factor=min_size_factor,
            channel_axis=-1,
        ).astype(np.int32)
        if cfg.drop_holes and view.synthetic and view.depth is not None:
            labels = _drop_holes(labels, ~view.valid_depth(), cfg.min_region_px)
        return Regions.from_labels(labels)


def _seeds(shape: tuple[int, int], n: int) -> int:
    """How many seeds ``slic`` lays on its regular grid when asked for ``n`` superpixels."""
    from skimage.util import regular_grid

    full = (1, *shape)  # slic works on (depth, height, width)
    return math.prod(len(range(*s.indices(d))) for s, d in zip(regular_grid(full, n), full, strict=True))


def _drop_holes(labels: np.ndarray, holes: np.ndarray, min_px: int) -> np.ndarray:
    """Unlabel ``holes``, then the regions left with fewer than ``min_px`` pixels."""
    if not holes.any():
        return labels
    labels = np.where(holes, -1, labels)
    inside = labels >= 0
    sizes = np.bincount(labels[inside], minlength=int(labels.max(initial=-1)) + 1)
    small = np.zeros(labels.shape, dtype=bool)
    small[inside] = sizes[labels[inside]] < min_px
    labels[small] = -1
    return labels


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [SlicoParser]
