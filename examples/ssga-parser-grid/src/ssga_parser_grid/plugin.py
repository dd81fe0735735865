"""A scene parser that cuts the image into a regular grid of regions."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssga_core import Parser, Regions, StageConfig, View, hookimpl


class GridConfig(StageConfig):
    rows: int = Field(default=4, ge=1, le=64, description="Grid rows.")
    cols: int = Field(default=4, ge=1, le=64, description="Grid columns.")


class GridParser(Parser):
    """Region ``r * cols + c`` is the cell in row ``r``, column ``c``."""

    name = "grid"
    abbrev = "GR"
    Config = GridConfig
    presets = {"coarse": {"rows": 2, "cols": 2}, "fine": {"rows": 8, "cols": 8}}

    def _parse(self, view: View) -> Regions:
        h, w = view.camera.shape
        row = np.arange(h) * self.config.rows // h
        col = np.arange(w) * self.config.cols // w
        labels = (row[:, None] * self.config.cols + col[None, :]).astype(np.int32)
        return Regions.from_labels(labels)


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [GridParser]
