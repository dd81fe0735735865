"""Ground-truth ids as scene-graph parts: the oracle parser.

A region is every pixel of one instance id (or one semantic category id), exactly as a
semantic sensor (Habitat's, or a procedural workspace's) labels the view. It stands in
for a perfect segmenter, giving an upper bound against which learned parsers (the
paper's cascade segmentation, P-SE) and appearance-based ones (SLICO) can be compared.
A synthetic view carries its source's ids forward-warped by the synthesizer's point
map, so the parser also works in orders that parse after synthesis (SPD).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field

from ssga_core import Data, InputError, Parser, Regions, StageConfig, View, boxes_from_labels, hookimpl


class SemanticConfig(StageConfig):
    by: Literal["instance", "category"] = Field(
        default="instance",
        description="'instance': one region per object instance id; 'category': one per semantic category id "
        "(all chairs together), whatever the instances.",
    )
    min_region_px: int = Field(
        default=64,
        ge=0,
        le=1 << 24,
        description="Ids covering fewer pixels than this get no region (their pixels are left out, not merged: merging "
        "would join different objects). 0 keeps every id.",
    )
    ignore_categories: tuple[Annotated[int, Field(ge=0)], ...] = Field(
        default=(),
        max_length=4096,
        description="Semantic category ids whose pixels get no region (e.g. wall, floor, ceiling); none by default.",
    )


class SemanticParser(Parser):
    """One region per ground-truth id; ``categories`` holds each region's semantic id (its majority; -1 if unknown)."""

    name = "semantic"
    abbrev = "GT"
    Config = SemanticConfig
    names_categories = True  # each region's semantic id (-1 where the sensor knows none)
    consumes = frozenset({Data.RGB, Data.SEMANTIC})
    presets = {
        "instances": {"by": "instance"},
        "categories": {"by": "category"},
    }

    def _parse(self, view: View) -> Regions:
        cfg = self.config
        ids = view.instance if cfg.by == "instance" else view.semantic
        if ids is None:
            other = "category" if cfg.by == "instance" else "instance"
            raise InputError(
                f"parser {self.name!r} with by={cfg.by!r} needs {cfg.by} ids, but this view carries only {other} ids; "
                f"use by={other!r}"
            )
        if cfg.ignore_categories and view.semantic is None:
            raise InputError(
                f"parser {self.name!r}: ignore_categories needs semantic category ids, which this view does not carry"
            )
        ids = ids.astype(np.int64)
        valid = ids >= 0
        if cfg.ignore_categories:
            valid &= ~np.isin(view.semantic, cfg.ignore_categories)
        present, inverse, counts = np.unique(ids[valid], return_inverse=True, return_counts=True)
        keep = counts >= cfg.min_region_px
        count = int(keep.sum())
        lut = np.full(len(present), -1, dtype=np.int32)
        lut[keep] = np.arange(count, dtype=np.int32)
        labels = np.full(ids.shape, -1, dtype=np.int32)
        labels[valid] = lut[inverse]
        categories = np.full(count, -1, np.int32)  # a view with instance ids alone: no region's category is known
        if view.semantic is not None:
            categories = (present[keep] if cfg.by == "category" else _majority(labels, view.semantic, count)).astype(np.int32)
        return Regions(labels=labels, boxes=boxes_from_labels(labels, count), categories=categories)


def _majority(labels: np.ndarray, semantic: np.ndarray, count: int) -> np.ndarray:
    """The most frequent known semantic id in each of ``count`` regions (ties: the smallest id; -1 if none known)."""
    out = np.full(count, -1, dtype=np.int64)
    known = (labels >= 0) & (semantic >= 0)
    if not known.any():
        return out
    cats, cat_index = np.unique(semantic[known], return_inverse=True)
    pairs, pair_counts = np.unique(labels[known].astype(np.int64) * len(cats) + cat_index, return_counts=True)
    region, cat = np.divmod(pairs, len(cats))
    # Sort by region, then most pixels first, then smallest id; the first row of each region wins.
    order = np.lexsort((cat, -pair_counts, region))
    region, cat = region[order], cat[order]
    first = np.ones(len(region), dtype=bool)
    first[1:] = region[1:] != region[:-1]
    out[region[first]] = cats[cat[first]]
    return out


@hookimpl
def ssga_register_parsers() -> list[type[Parser]]:
    return [SemanticParser]
