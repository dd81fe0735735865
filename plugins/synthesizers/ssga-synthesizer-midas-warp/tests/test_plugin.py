"""The plugin as ssga sees it: registration, config, the synthesizer contract, RGB-only views, fusion, the device."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_synthesizer_depth_warp.plugin import DepthWarp, DepthWarpConfig
from ssga_synthesizer_midas_warp.plugin import MidasWarp, MidasWarpConfig

from ssga_core import Data, InputError, Pose, Synthesizer, View
from ssga_bench.testing import check_installed
from ssga_core.testing import check_synthesizer, check_synthesizer_in_all_orders, make_view


@pytest.fixture(scope="module")
def packaged() -> MidasWarp:
    return MidasWarp(MidasWarpConfig(device="cpu"))


def without_depth(view: View) -> View:
    return View(rgb=view.rgb, pose=view.pose, camera=view.camera)


def test_is_installed_and_registered(ssga_installed_registry):
    check_installed(ssga_installed_registry, "synthesizer", "midas-warp", MidasWarp, "ssga-synthesizer-midas-warp")


def test_declares_rgb_in_and_depth_out():
    assert MidasWarp.consumes == {Data.RGB}
    assert {Data.RGB, Data.DEPTH, Data.POINT_MAP} <= MidasWarp.produces


def test_config_is_depth_warps_plus_the_network():
    assert set(DepthWarpConfig.model_fields) < set(MidasWarpConfig.model_fields)
    assert MidasWarpConfig().weights == "midas-light.pt" and MidasWarpConfig().network is None  # None: the file's
    for bad in ({"depth_range": (2.0, 1.0)}, {"depth_range": (0.0, 5.0)}, {"network": "dpt"}, {"splat": 0}, {"calibration": ""}):
        with pytest.raises(ValidationError):
            MidasWarpConfig(**bad)
    for name, params in MidasWarp.presets.items():
        assert MidasWarpConfig(**params), name
    assert set(DepthWarp.presets) < set(MidasWarp.presets)
    assert MidasWarp.presets["v21-small"] == {"weights": "midas_v21_small_256.pt"}  # the file says its network
    assert [layout.name for layout in MidasWarp.layouts] == ["light", "v21-small"]
    assert all(field.description for field in MidasWarpConfig.model_fields.values())


@pytest.mark.parametrize("weights", ["packaged", "random"])
def test_meets_the_synthesizer_contract(weights, packaged):
    if weights == "packaged":
        synthesizer = packaged
    else:
        # Random weights' depth is pixel noise spread over 0.2-20 m: steep ramps everywhere, on which
        # depth-warp's adaptive footprints leave ~11% of points not 'visible' even at the source's own
        # pose (a depth-warp matter, reported); one pixel per point keeps them all.
        synthesizer = MidasWarp(MidasWarpConfig(weights="random", device="cpu", footprint="square"))
    check_synthesizer(synthesizer)
    check_synthesizer(synthesizer, make_view(seed=7, size=96, distance=1.2))


def test_runs_in_every_order(packaged):
    check_synthesizer_in_all_orders(packaged)


def test_every_order_with_s_runs_on_rgb_only_views(packaged):
    """The point of the plugin: the variant checks accept it where the views carry no depth (depth-warp's are refused)."""
    flat = without_depth(make_view(seed=2))
    ran = check_synthesizer_in_all_orders(packaged, flat)  # asserts every order with S ran
    assert any("S" in order for order in ran)
    with pytest.raises(AssertionError):
        check_synthesizer_in_all_orders(DepthWarp(), flat)


def test_a_view_without_depth_synthesizes(packaged):
    """What depth-warp refuses: an RGB-only view. The synthetic view carries the metric depth it used."""
    view = make_view()
    flat = without_depth(view)
    with pytest.raises(InputError, match="needs depth"):
        DepthWarp().synthesize(flat, view.pose)
    target = Pose(view.pose.x, view.pose.y, view.pose.yaw + 0.15)
    synthesis = packaged.synthesize(flat, target)
    depth = synthesis.view.depth
    assert synthesis.view.synthetic and depth is not None
    near, far = packaged.config.depth_range
    drawn = depth > 0
    assert drawn.mean() > 0.8 and depth[drawn].min() >= near * 0.95 and depth[drawn].max() <= far * 1.05
    assert synthesis.visible.mean() > 0.5


def test_the_views_own_depth_is_never_read(packaged):
    view = make_view(seed=3)
    wrong = View(rgb=view.rgb, pose=view.pose, camera=view.camera, depth=np.full(view.camera.shape, 0.4, dtype=np.float32))
    target = Pose(view.pose.x + 0.2, view.pose.y, view.pose.yaw)
    a, b = packaged.synthesize(without_depth(view), target), packaged.synthesize(wrong, target)
    np.testing.assert_array_equal(a.view.rgb, b.view.rgb)
    np.testing.assert_array_equal(a.target_uv, b.target_uv)


def test_depth_is_estimated_once_per_view(packaged, monkeypatch):
    view = without_depth(make_view(seed=4))
    calls = []
    original = packaged.estimate_depth
    monkeypatch.setattr(packaged, "estimate_depth", lambda images: calls.append(len(images)) or original(images))
    for dx in (0.1, 0.2, 0.3):
        packaged.synthesize(view, Pose(dx, 0.0, 0.0))
    assert calls == [1]


def test_several_views_fuse(packaged):
    """Jointly (depth-warp's one z-buffer) and by the core's depth composition, which needs the synthetic depth."""
    views = [without_depth(make_view(seed=s, pose=Pose(0.3 * s, 0.0, 0.0))) for s in range(3)]
    target = Pose(0.3, -0.2, 0.1)
    joint = packaged.synthesize_from(views, target)
    assert len(joint) == 3 and all(s.view is joint[0].view for s in joint)
    assert (joint[0].view.depth > 0).mean() > 0.5
    composed = Synthesizer._synthesize_from(packaged, views, target)  # the core's default: each view alone, composed by depth
    assert len(composed) == 3 and composed[0].view.depth is not None
    assert (composed[0].view.depth > 0).mean() > 0.5


def test_random_weights_say_so():
    assert MidasWarp.caveat(MidasWarpConfig(weights="random")) == "random weights"
    assert MidasWarp.caveat(MidasWarpConfig()) == ""


def test_runs_on_the_cpu(packaged):
    assert str(packaged.device) == "cpu"
    assert next(packaged.net.parameters()).device.type == "cpu"
    depth = packaged.estimate_depth([make_view(size=64).rgb])
    assert depth.shape == (1, 64, 64) and np.isfinite(depth).all()
