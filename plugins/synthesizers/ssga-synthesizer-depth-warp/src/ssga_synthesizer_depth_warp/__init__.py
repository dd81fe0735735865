"""Depth-warp view synthesis for ssga: depth to point cloud, z-buffered forward splat at a new pose."""

from ssga_synthesizer_depth_warp.warp import HOLE_FILLS, Warp, fill_holes, forward_warp, reproject, small_holes

__all__ = ["HOLE_FILLS", "Warp", "fill_holes", "forward_warp", "reproject", "small_holes"]
