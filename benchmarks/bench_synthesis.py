"""Speed of the depth-warp synthesizer (``make bench``).

One 256 x 256 view (hfov 90) of a corridor with a box in it, so that the depth varies and
the warps open cracks, disocclusions and strips the source never saw; each call renders
it at the next of 32 nearby poses (up to 0.5 m away, turned up to 30 degrees), as the
pipeline does for pseudo-training views. ``v0.1`` is the configuration that was the
default before bilinear resampling (the ``v0.1`` preset): compare the two within one
run. Run alone with
``pytest benchmarks/bench_synthesis.py -o python_files=bench_*.py --benchmark-enable``.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ssga_synthesizer_depth_warp")

from ssga_core import Camera, Pose, View  # noqa: E402
from ssga_core.stages import fuse_syntheses  # noqa: E402
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig  # noqa: E402

CONFIGS = {
    "default": {},
    "default-raw": {"fill_holes": "none"},
    "v0.1": {"footprint": "square", "resample": "nearest", "max_hole": 8},
    "v0.1-raw": {"footprint": "square", "resample": "nearest", "fill_holes": "none"},
    "square": {"footprint": "square"},
    "square-raw": {"footprint": "square", "fill_holes": "none"},
    "square-inpaint": {"footprint": "square", "fill_holes": "inpaint"},
    "closed": {"footprint": "square", "splat": 2},
}


def corridor_view(size: int = 256, pose: Pose | None = None) -> View:
    """A 4 m wide corridor (floor 1.5 m below the camera, ceiling 1 m above, end wall 8 m ahead) and a box."""
    camera = Camera(width=size, height=size, hfov_deg=90.0)
    grid = camera.pixel_grid()
    cx, cy = camera.principal_point
    x = (grid[..., 0] - cx) / camera.focal_px  # ray direction (x, y, 1) in the camera frame
    y = (grid[..., 1] - cy) / camera.focal_px
    with np.errstate(divide="ignore"):
        hits = [np.where(y > 0, 1.5 / y, np.inf), np.where(y < 0, -1.0 / y, np.inf), np.where(x != 0, 2.0 / np.abs(x), np.inf)]
    depth = np.minimum.reduce([*hits, np.full_like(x, 8.0)])
    box = (np.abs(x * 2.5 + 0.6) < 0.5) & (y * 2.5 > 0.3)  # a box 2.5 m ahead, left of centre, on the floor
    depth = np.where(box, np.minimum(depth, 2.5), depth).astype(np.float32)
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 128, (size // 8, size // 8, 3), dtype=np.uint8).repeat(8, 0).repeat(8, 1)
    rgb = texture + (depth[..., None] * 12).astype(np.uint8)
    return View(rgb=rgb, pose=pose or Pose(0.0, 0.0, 0.0), camera=camera, depth=depth)


@pytest.fixture(scope="module")
def view() -> View:
    return corridor_view()


@pytest.mark.parametrize("name", list(CONFIGS))
def test_synthesize_one_view(benchmark, record_rate, view, targets, name):
    """One 256 x 256 view per call, one thread."""
    synthesizer = DepthWarp(DepthWarpConfig(**CONFIGS[name]))
    it = iter(targets * 10_000)
    syn = benchmark(lambda: synthesizer.synthesize(view, next(it)))
    assert syn.view.rgb.shape == (256, 256, 3)
    benchmark.extra_info["covered"] = round(float((syn.view.depth > 0).mean()), 3)
    record_rate()


@pytest.mark.parametrize("footprint", ["square", "adaptive"])
@pytest.mark.parametrize("how", ["fused", "composed"])
def test_synthesize_from_four_views(benchmark, record_rate, targets, how, footprint):
    """One target from four views (the corridor seen from four places 1 m apart): one joint
    render (``synthesize_from``) or the core's default, four renders composed by depth."""
    views = [corridor_view(pose=Pose(float(dx), float(dy), 0.0)) for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1))]
    synthesizer = DepthWarp(DepthWarpConfig(footprint=footprint))
    it = iter(targets * 10_000)

    def composed() -> list:
        target = next(it)
        return fuse_syntheses([synthesizer.synthesize(v, target) for v in views])

    result = benchmark((lambda: synthesizer.synthesize_from(views, next(it))) if how == "fused" else composed)
    assert len(result) == 4
    record_rate()
