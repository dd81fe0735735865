"""Depth-warp view synthesis for ssga: depth to point cloud, z-buffered forward splat at a new pose."""

from ssga_synthesizer_depth_warp.warp import (
    HOLE_FILLS,
    INTERIOR,
    LINKED_DOWN,
    LINKED_RIGHT,
    Source,
    Warp,
    fill_holes,
    forward_warp,
    forward_warp_many,
    reproject,
    small_holes,
    surface_links,
)

__all__ = [
    "HOLE_FILLS",
    "INTERIOR",
    "LINKED_DOWN",
    "LINKED_RIGHT",
    "Source",
    "Warp",
    "fill_holes",
    "forward_warp",
    "forward_warp_many",
    "reproject",
    "small_holes",
    "surface_links",
]
