"""The plugin as ssga sees it: registration, config, the synthesizer contract, use in the pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig

from ssga_core import Camera, InputError, Pose, View
from ssga_core.testing import get_plugin_manager
from ssga_core.testing import check_synthesizer, check_synthesizer_in_all_orders, make_view


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("synthesizer", "depth-warp")
    assert entry.cls is DepthWarp
    assert entry.plugin.distribution == "ssga-synthesizer-depth-warp"


def test_is_discovered_by_a_fresh_plugin_manager():
    assert get_plugin_manager().registry().get("synthesizer", "depth-warp") is DepthWarp


@pytest.mark.parametrize(
    "config",
    [
        DepthWarpConfig(),
        DepthWarpConfig(splat=2, fill_holes="none"),
        DepthWarpConfig(splat=3, fill_holes="inpaint", max_hole=4),
        DepthWarpConfig(resample="nearest"),
        DepthWarpConfig(footprint="adaptive"),
        DepthWarpConfig(footprint="adaptive", resample="nearest", max_footprint=4, depth_edge=0.2),
        DepthWarpConfig(fill_unseen="layout"),
    ],
    ids=["default", "splat2-raw", "splat3-inpaint", "v0.1", "adaptive", "adaptive-nearest", "layout"],
)
def test_meets_the_synthesizer_contract(config):
    check_synthesizer(DepthWarp(config))
    check_synthesizer(DepthWarp(config), make_view(seed=7, size=96, distance=1.2))


@pytest.mark.parametrize("config", [DepthWarpConfig(), DepthWarpConfig(fill_unseen="layout")], ids=["default", "layout"])
def test_runs_in_every_order(config):
    check_synthesizer_in_all_orders(DepthWarp(config))


def test_a_view_without_depth_is_refused():
    view = make_view()
    flat = View(rgb=view.rgb, pose=view.pose, camera=view.camera)
    with pytest.raises(InputError, match="synthesizer 'depth-warp' needs depth"):
        DepthWarp().synthesize(flat, view.pose)


def test_config_is_validated():
    assert DepthWarpConfig() == DepthWarpConfig(
        splat=1,
        footprint="adaptive",
        max_footprint=32,
        resample="bilinear",
        depth_edge=0.03,
        fill_holes="nearest",
        max_hole=16,
        fill_unseen="none",
        wall_band=0.45,
        max_depth=50.0,
    )
    bad_values = (
        {"splat": 0}, {"splat": 5}, {"fill_holes": "blur"}, {"max_depth": 0.0}, {"max_hole": 1}, {"radius": 2},
        {"footprint": "round"}, {"resample": "cubic"}, {"max_footprint": 0}, {"depth_edge": 0.0}, {"depth_edge": 2.0},
        {"fill_unseen": "inpaint"}, {"wall_band": 0.0}, {"wall_band": 3.0},
    )  # fmt: skip
    for bad in bad_values:
        with pytest.raises(ValidationError):
            DepthWarpConfig(**bad)
    for name, params in DepthWarp.presets.items():
        assert DepthWarpConfig(**params), name
    assert all(field.description for field in DepthWarpConfig.model_fields.values())


def test_visible_points_round_to_pixels_of_the_target():
    """The core's label warping indexes the target at rint(target_uv) of visible points."""
    rng = np.random.default_rng(1)
    camera = Camera(width=80, height=60, hfov_deg=75.0)
    for _ in range(20):
        depth = rng.uniform(0.5, 6.0, (60, 80)).astype(np.float32)
        depth[rng.random((60, 80)) < 0.1] = 0.0
        source = Pose(*rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi))
        view = View(rgb=rng.integers(0, 256, (60, 80, 3), dtype=np.uint8), pose=source, camera=camera, depth=depth)
        target = Pose(source.x + rng.normal(0, 0.5), source.y + rng.normal(0, 0.5), source.yaw + rng.normal(0, 0.4))
        syn = DepthWarp(DepthWarpConfig(splat=int(rng.integers(1, 4)))).synthesize(view, target)
        uv = np.rint(syn.target_uv[syn.visible])
        assert ((uv >= 0) & (uv < [80, 60])).all()
        assert camera.contains(syn.target_uv[syn.visible]).all()
        # A visible point's colour is what the target shows at its pixel, unless a
        # same-surface neighbour (within the depth tolerance) won that pixel.
        drawn = syn.view.depth[uv[:, 1].astype(int), uv[:, 0].astype(int)]
        assert (drawn > 0).all()
        labels = syn.warp_labels(np.arange(60 * 80, dtype=np.int32).reshape(60, 80))
        assert labels.shape == (60, 80)
