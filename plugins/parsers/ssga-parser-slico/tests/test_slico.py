from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_parser_slico.plugin import SlicoConfig, SlicoParser

from ssga_core import ConfigError, Pose, View
from ssga_core import resolve_stage
from ssga_core.testing import get_plugin_manager
from ssga_core.testing import check_parser, check_parser_in_all_orders, make_view
from ssga_core.testing.stages import ShiftWarp


def _edges(labels: np.ndarray) -> np.ndarray:
    """Pixels with a 4-neighbour of another label (both sides of every boundary)."""
    out = np.zeros(labels.shape, dtype=bool)
    dx = labels[:, 1:] != labels[:, :-1]
    dy = labels[1:, :] != labels[:-1, :]
    out[:, 1:] |= dx
    out[:, :-1] |= dx
    out[1:, :] |= dy
    out[:-1, :] |= dy
    return out


def _dilate(mask: np.ndarray) -> np.ndarray:
    """One step of 8-connected dilation."""
    rows = mask.copy()
    rows[1:, :] |= mask[:-1, :]
    rows[:-1, :] |= mask[1:, :]
    out = rows.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


def _boundary_recall(labels: np.ndarray, truth: np.ndarray) -> float:
    """Share of the true boundary pixels within 1 px of a region boundary."""
    true_edges = _edges(truth)
    return float((true_edges & _dilate(_edges(labels))).sum() / true_edges.sum())


def _grid(shape: tuple[int, int], cells: int) -> np.ndarray:
    h, w = shape
    side = round(np.sqrt(cells))
    return (np.arange(h)[:, None] * side // h) * side + np.arange(w)[None, :] * side // w


def _noise_view(seed: int = 0, size: int = 128) -> View:
    rgb = np.random.default_rng(seed).integers(0, 256, size=(size, size, 3), dtype=np.uint8)
    return dataclasses.replace(make_view(size=size), rgb=rgb)


def test_is_installed_and_registered(ssga_installed_registry):
    assert get_plugin_manager().registry().get("parser", "slico") is SlicoParser
    entry = ssga_installed_registry.entry("parser", "slico")
    assert entry.plugin.distribution == "ssga-parser-slico"
    assert SlicoParser.tag() == "SL"


@pytest.mark.parametrize("preset", [None, "coarse", "fine"])
def test_meets_the_parser_contract(preset):
    config = SlicoConfig(**SlicoParser.presets[preset]) if preset else SlicoConfig()
    check_parser(SlicoParser(config), make_view(seed=1))


def test_runs_in_every_order():
    ran = check_parser_in_all_orders(SlicoParser())
    assert "SPD" in ran


def test_is_deterministic_across_instances():
    view = make_view(seed=2)
    first = SlicoParser().parse(view)
    second = SlicoParser(SlicoConfig()).parse(view)
    np.testing.assert_array_equal(first.labels, second.labels)
    np.testing.assert_array_equal(first.boxes, second.boxes)


def test_covers_a_real_view_with_about_n_segments_regions():
    regions = SlicoParser().parse(make_view(seed=0))
    assert (regions.labels >= 0).all()
    assert 0.8 * 64 <= len(regions) <= 1.2 * 64
    assert regions.categories is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_boundaries_follow_the_painted_rectangles(seed):
    # make_view paints uniform rectangles on a smooth gradient; their outlines are the
    # image's only sharp edges, and SLICO's boundaries should snap to them. A grid of
    # the same cell count, blind to content, meets far fewer of them.
    view = make_view(seed=seed)
    labels = SlicoParser().parse(view).labels
    recall = _boundary_recall(labels, view.semantic)
    assert recall >= 0.75, recall
    assert _boundary_recall(_grid(labels.shape, 64), view.semantic) < 0.45
    # Inside the largest rectangle, regions rarely leak across its edge: most of its
    # pixels belong to regions lying mostly inside it.
    ids, counts = np.unique(view.semantic[view.semantic >= 0], return_counts=True)
    rect = view.semantic == ids[counts.argmax()]
    inside_share = np.bincount(labels[rect], minlength=labels.max() + 1) / np.bincount(labels.ravel())
    assert (inside_share[labels[rect]] > 0.8).mean() > 0.8


def test_min_region_px_merges_fragments():
    view = _noise_view()
    loose = SlicoParser(SlicoConfig(n_segments=16, min_region_px=0)).parse(view)
    assert np.bincount(loose.labels.ravel()).min() < 50, "pure noise should leave small fragments when nothing is merged"
    tight = SlicoParser(SlicoConfig(n_segments=16, min_region_px=200)).parse(view)
    assert (tight.labels >= 0).all(), "merging keeps every pixel in a region"
    assert np.bincount(tight.labels.ravel()).min() >= 200
    assert len(tight) < len(loose)


@pytest.mark.parametrize(
    ("size", "n_segments", "min_region_px", "noise"),
    # Sizes where SLIC's seed grid holds more or fewer seeds than asked for.
    [(91, 25, 908, False), (139, 25, 1962, False), (65, 200, 205, False), (68, 200, 302, True), (155, 200, 305, True)],
)
def test_min_region_px_holds_at_any_size(size, n_segments, min_region_px, noise):
    view = _noise_view(size=size) if noise else make_view(seed=size, size=size)
    regions = SlicoParser(SlicoConfig(n_segments=n_segments, min_region_px=min_region_px)).parse(view)
    assert (regions.labels >= 0).all()
    assert np.bincount(regions.labels.ravel()).min() >= min_region_px


def test_n_segments_is_per_256_squared_and_scales_with_area():
    parser = SlicoParser()
    assert parser.segments((256, 256)) == 64
    assert parser.segments((512, 512)) == 256
    assert parser.segments((128, 256)) == 32
    assert parser.segments((8, 8)) == 1
    small, large = parser.parse(make_view(size=128)), parser.parse(make_view(size=512))
    assert 0.7 * 16 <= len(small) <= 1.3 * 16
    assert 0.8 * 256 <= len(large) <= 1.2 * 256
    # So a superpixel keeps its size in pixels: about 32 x 32 at the default.
    for regions in (small, large):
        assert 700 < regions.labels.size / len(regions) < 1400


def test_presets_order_the_region_counts():
    view = make_view(seed=3)
    counts = {p: len(SlicoParser(SlicoConfig(**SlicoParser.presets[p])).parse(view)) for p in ("coarse", "fine")}
    assert counts["coarse"] < len(SlicoParser().parse(view)) < counts["fine"]


def test_holes_of_a_synthetic_view_get_no_region():
    view = make_view(seed=0)
    right = view.pose.rotation()[:, 0]
    target = Pose(view.pose.x + 0.4 * right[0], view.pose.y + 0.4 * right[1], view.pose.yaw, view.pose.height)
    synthetic = ShiftWarp().synthesize(view, target).view
    holes = ~synthetic.valid_depth()
    assert 0.05 < holes.mean() < 0.5
    regions = SlicoParser().parse(synthetic)
    assert (regions.labels[holes] == -1).all()
    assert (regions.labels[~holes] >= 0).mean() > 0.97
    assert np.bincount(regions.labels[regions.labels >= 0]).min() >= SlicoConfig().min_region_px
    kept = SlicoParser(SlicoConfig(drop_holes=False)).parse(synthetic)
    assert (kept.labels >= 0).all()
    # A real view's missing depth (sky, no return) is content, not a hole.
    real = dataclasses.replace(view, depth=np.zeros_like(view.depth))
    assert (SlicoParser().parse(real).labels >= 0).all()


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"n_segments": 0}, "greater than or equal to 1"),
        ({"n_segments": 5000}, "less than or equal to 4096"),
        ({"compactness": 0}, "greater than 0"),
        ({"sigma": -1}, "greater than or equal to 0"),
        ({"max_iterations": 0}, "greater than or equal to 1"),
        ({"min_region_px": -1}, "greater than or equal to 0"),
        ({"n_segments": 100, "min_region_px": 700}, "below the nominal superpixel size, 655 px at n_segments=100"),
        ({"segments": 64}, "Extra inputs are not permitted"),
    ],
)
def test_bad_config_fails_validation(params, message):
    with pytest.raises(ValidationError, match=message):
        SlicoConfig(**params)


def test_config_resolves_presets_and_reports_bad_values(ssga_installed_registry):
    stage = resolve_stage("parser", {"name": "slico", "preset": "coarse", "sigma": 1.0}, ssga_installed_registry)
    assert stage.config == SlicoConfig(n_segments=25, min_region_px=640, sigma=1.0)
    with pytest.raises(ConfigError, match=r"parser\.n_segments: Input should be greater than or equal to 1"):
        resolve_stage("parser", {"name": "slico", "n_segments": 0}, ssga_installed_registry)
    every_field = SlicoConfig.model_fields.values()
    assert all(f.description for f in every_field)
