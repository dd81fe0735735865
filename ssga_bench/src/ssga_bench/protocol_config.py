"""The benchmark protocol's settings (``[protocol]`` of an experiment file): cells, classes,
sampling and difficulty levels (:mod:`ssga_bench.protocol` defines what each means)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class ProtocolConfig(BaseModel):
    """Cells, classes, sampling and difficulty levels of the benchmark.

    Every value is bounded to what a build can do (a 1 nm cell or an infinite radius
    would validate and then never finish), and non-finite numbers are refused.
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    cell_size: float = Field(default=2.0, ge=0.1, le=100.0, description="Side of a location cell, metres.")
    cells: int = Field(default=10, ge=1, le=1000, description="Location cells drawn at random.")
    orientations: int = Field(default=12, ge=1, le=360, description="Heading classes per cell.")
    test_per_class: int = Field(default=20, ge=1, le=100_000, description="Test views per class (the paper: 1500).")
    test_per_level: int = Field(
        default=0,
        ge=0,
        le=100_000,
        description="Keep drawing test views (up to twice test_per_class per class) until each level has this many; 0: no quota.",
    )
    val_per_class: int = Field(
        default=0,
        ge=0,
        le=100_000,
        description="Validation views per class, drawn as test views are but apart from them: used only to choose among "
        "variants (the best single variant, fusion selection), never for training or for the reported scores.",
    )
    val_per_level: int = Field(
        default=0,
        ge=0,
        le=100_000,
        description="Keep drawing validation views (up to twice val_per_class per class) until each level has this many, "
        "so a fusion learned on them (stacking) sees the hard levels too; 0: no quota.",
    )
    test_radius: float = Field(
        default=3.0, gt=0.0, le=100.0, description="Test cameras stand within this distance of their cell's centroid, metres."
    )
    viewpoint_distance: float = Field(
        default=1.0,
        gt=0.0,
        le=100.0,
        description="Canonical viewpoints stand this far behind the cell centroid, or nearer (down to an eighth of it) where "
        "that spot is not free, metres.",
    )
    max_range: float = Field(default=10.0, gt=0.0, le=1000.0, description="Visibility cones end here, metres.")
    rays: int = Field(default=121, ge=3, le=10_000, description="Rays cast per visibility cone.")
    level_bounds: tuple[float, float] = Field(default=(60.0, 30.0), description="VO above the first is L1, above the second L2, else L3.")
    level_reference: Literal["class", "landmark"] = Field(
        default="class",
        description="Levels from the VO with the class's training viewpoint ('class') or with the cell's one real image ('landmark').",
    )
    max_candidates: int = Field(default=200, ge=1, le=100_000, description="Candidate poses tried per test view wanted before giving up.")
    fit: Literal["auto", "fixed"] | None = Field(
        default=None,
        description="'auto': where the configured cell_size, viewpoint_distance or test_radius do not fit the workspace, "
        "choose values that do, say which and record them (the dataset's fitted.json); 'fixed': fail, naming what would fit. "
        "Left out: the workspace source's default (auto for meshes and captured folders, fixed for the embedded homes).",
    )
    seed: int = Field(default=0, ge=0, lt=2**32, description="Seed of every random draw of the protocol.")

    @field_validator("level_bounds")
    @classmethod
    def _ordered_percentages(cls, bounds: tuple[float, float]) -> tuple[float, float]:
        if not 0.0 <= bounds[1] <= bounds[0] <= 100.0:
            raise ValueError(f"expected [L1 bound, L2 bound] with 100 >= L1 bound >= L2 bound >= 0, got {list(bounds)}")
        return bounds
