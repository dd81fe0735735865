from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_parser_semantic.plugin import SemanticConfig, SemanticParser

from ssga_core import ConfigError, InputError, Pose, Regions, View
from ssga_core import resolve_stage
from ssga_core.testing import get_plugin_manager
from ssga_core.testing import check_parser, check_parser_in_all_orders, make_view
from ssga_core.testing.stages import ShiftWarp


def _two_instance_kinds() -> View:
    """make_view with instances numbered apart from categories: rectangle k is instance 100 + k of category k % 3."""
    view = make_view(seed=0)
    painted = view.semantic >= 0
    instance = np.where(painted, 100 + view.semantic, -1).astype(np.int32)
    semantic = np.where(painted, view.semantic % 3, -1).astype(np.int32)
    return dataclasses.replace(view, semantic=semantic, instance=instance)


def test_is_installed_and_registered(ssga_installed_registry):
    assert get_plugin_manager().registry().get("parser", "semantic") is SemanticParser
    assert ssga_installed_registry.entry("parser", "semantic").plugin.distribution == "ssga-parser-semantic"
    assert SemanticParser.tag() == "GT"


@pytest.mark.parametrize("by", ["instance", "category"])
def test_meets_the_parser_contract(by):
    check_parser(SemanticParser(SemanticConfig(by=by)), make_view(seed=1))


def test_runs_in_every_order():
    # In SPD it parses the synthetic view, whose ids the core forward-warps from the real one.
    assert "SPD" in check_parser_in_all_orders(SemanticParser())


def test_reproduces_the_painted_rectangles_exactly():
    view = make_view(seed=0)
    regions = SemanticParser(SemanticConfig(min_region_px=0)).parse(view)
    visible = np.unique(view.semantic[view.semantic >= 0])
    assert len(regions) == len(visible)
    np.testing.assert_array_equal(regions.categories, visible)
    for k, rect in enumerate(regions.categories):
        np.testing.assert_array_equal(regions.mask(k), view.semantic == rect)
        v, u = np.nonzero(view.semantic == rect)
        np.testing.assert_array_equal(regions.boxes[k], [u.min(), v.min(), u.max(), v.max()])
    assert ((regions.labels == -1) == (view.semantic == -1)).all(), "the unpainted wall belongs to no region"


def test_is_deterministic_across_instances():
    view = make_view(seed=4)
    np.testing.assert_array_equal(SemanticParser().parse(view).labels, SemanticParser().parse(view).labels)


def test_by_category_joins_instances_and_categories_are_the_majority():
    view = _two_instance_kinds()
    by_instance = SemanticParser(SemanticConfig(min_region_px=0)).parse(view)
    by_category = SemanticParser(SemanticConfig(by="category", min_region_px=0)).parse(view)
    assert len(by_instance) == len(np.unique(view.instance[view.instance >= 0]))
    np.testing.assert_array_equal(by_category.categories, [0, 1, 2])
    for k, cat in enumerate(by_category.categories):
        np.testing.assert_array_equal(by_category.mask(k), view.semantic == cat)
    # Each instance's category is its pixels' semantic id.
    for k, cat in enumerate(by_instance.categories):
        assert (view.semantic[by_instance.mask(k)] == cat).all()
    # A mixed instance takes its most frequent known id; unknown pixels do not vote.
    first = by_instance.mask(0)
    v, u = np.nonzero(first)
    n = len(v)

    def category_of_first(value: int, share: float) -> int:
        semantic = view.semantic.copy()
        cut = int(share * n)
        semantic[v[:cut], u[:cut]] = value
        regions = SemanticParser(SemanticConfig(min_region_px=0)).parse(dataclasses.replace(view, semantic=semantic))
        return int(regions.categories[0])

    own = int(by_instance.categories[0])
    assert category_of_first(7, 1 / 3) == own
    assert category_of_first(7, 2 / 3) == 7
    assert category_of_first(-1, 2 / 3) == own, "two thirds unknown, the rest known: the known id wins"
    assert category_of_first(-1, 1.0) == -1


def test_min_region_px_leaves_small_ids_out():
    view = make_view(seed=0)
    sizes = dict(zip(*np.unique(view.semantic[view.semantic >= 0], return_counts=True), strict=True))
    threshold = int(np.median(list(sizes.values())))
    regions = SemanticParser(SemanticConfig(min_region_px=threshold)).parse(view)
    kept = sorted(k for k, n in sizes.items() if n >= threshold)
    np.testing.assert_array_equal(regions.categories, kept)
    small = np.isin(view.semantic, [k for k, n in sizes.items() if n < threshold])
    assert (regions.labels[small] == -1).all(), "small ids are dropped, not merged into a neighbour"
    assert np.bincount(regions.labels[regions.labels >= 0]).min() >= threshold


def test_ignore_categories():
    view = make_view(seed=0)
    regions = SemanticParser(SemanticConfig(ignore_categories=[0, 3], min_region_px=0)).parse(view)
    assert not np.isin(regions.categories, [0, 3]).any()
    assert (regions.labels[np.isin(view.semantic, [0, 3])] == -1).all()
    assert len(regions) == len(SemanticParser(SemanticConfig(min_region_px=0)).parse(view)) - 2


def test_parses_the_warped_ids_of_a_synthetic_view():
    view = make_view(seed=0)
    right = view.pose.rotation()[:, 0]
    syn = ShiftWarp().synthesize(view, Pose(view.pose.x + 0.3 * right[0], view.pose.y + 0.3 * right[1], view.pose.yaw))
    synthetic = dataclasses.replace(syn.view, semantic=syn.warp_labels(view.semantic), instance=syn.warp_labels(view.instance))
    regions = SemanticParser(SemanticConfig(min_region_px=0)).parse(synthetic)
    assert ((regions.labels >= 0) == (synthetic.instance >= 0)).all()
    for k, cat in enumerate(regions.categories):
        np.testing.assert_array_equal(regions.mask(k), synthetic.semantic == cat)


def test_a_view_without_semantic_ids_is_refused():
    view = dataclasses.replace(make_view(), semantic=None, instance=None)
    with pytest.raises(InputError, match=r"^parser 'semantic' needs semantic, which this view does not carry$"):
        SemanticParser().parse(view)


def test_a_view_missing_the_ids_asked_for_is_refused():
    only_categories = dataclasses.replace(make_view(), instance=None)
    message = r"by='instance' needs instance ids, but this view carries only category ids; use by='category'"
    with pytest.raises(InputError, match=message):
        SemanticParser().parse(only_categories)
    assert len(SemanticParser(SemanticConfig(by="category")).parse(only_categories)) > 0
    only_instances = dataclasses.replace(make_view(), semantic=None)
    regions = SemanticParser().parse(only_instances)
    assert len(regions) > 0 and np.all(regions.categories == -1)  # no category known
    with pytest.raises(InputError, match="ignore_categories needs semantic category ids"):
        SemanticParser(SemanticConfig(ignore_categories=[1])).parse(only_instances)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"by": "object"}, "Input should be 'instance' or 'category'"),
        ({"min_region_px": -1}, "greater than or equal to 0"),
        ({"ignore_categories": [-1]}, "greater than or equal to 0"),
        ({"ignore_categories": "wall"}, "valid tuple"),
        ({"ignore": [1]}, "Extra inputs are not permitted"),
    ],
)
def test_bad_config_fails_validation(params, message):
    with pytest.raises(ValidationError, match=message):
        SemanticConfig(**params)


def test_config_resolves_presets_and_reports_bad_values(ssga_installed_registry):
    assert resolve_stage("parser", {"name": "semantic", "preset": "categories"}, ssga_installed_registry).config == SemanticConfig(by="category")
    with pytest.raises(ConfigError, match=r"parser\.by: Input should be 'instance' or 'category'"):
        resolve_stage("parser", {"name": "semantic", "by": "object"}, ssga_installed_registry)
    assert all(f.description for f in SemanticConfig.model_fields.values())


@pytest.mark.parametrize(
    "config", [SemanticConfig(), SemanticConfig(by="category", min_region_px=0), SemanticConfig(ignore_categories=[1, 2])]
)
def test_regions_match_the_cores_from_labels(config):
    # The parser numbers its regions itself; numbering, boxes and categories must be the core's.
    for view in (make_view(seed=0), make_view(seed=3, size=100), _two_instance_kinds()):
        regions = SemanticParser(config).parse(view)
        core = Regions.from_labels(regions.labels, categories=regions.categories)
        np.testing.assert_array_equal(regions.labels, core.labels)
        np.testing.assert_array_equal(regions.boxes, core.boxes)
        np.testing.assert_array_equal(regions.categories, core.categories)
        assert regions.categories.dtype == np.int32


def test_a_view_with_no_known_id_has_no_region():
    view = make_view()
    blank = dataclasses.replace(view, semantic=np.full_like(view.semantic, -1), instance=np.full_like(view.instance, -1))
    regions = SemanticParser().parse(blank)
    assert len(regions) == 0 and (regions.labels == -1).all() and regions.boxes.shape == (0, 4)
