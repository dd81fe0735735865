"""The semantics of each order, checked exactly with stand-in stages.

make_view() is a flat wall 3 m ahead, and ShiftWarp moves a camera sideways exactly:
0.3 m to the right shifts the image content 128 * 0.3 / 3 = 12.8 px to the left.
The stand-in parser cuts 4 vertical stripes of 64 px; the local descriptor has 144
patches on a 12 x 12 grid whose columns sit at u = 10.17, 31.5, 52.8, ...
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ssga_core import InputError, PluginError, Pose, Regions, boxes_from_labels, parse_variant
from ssga_core.pipeline import BoundVariant, build_graph, table_label
from ssga_core.testing import make_view
from ssga_core.testing.stages import PatchColour, RegionColour, ShiftWarp, StripesParser, StripesConfig

SHIFT = -128 * 0.3 / 3


@pytest.fixture
def view():
    return make_view(seed=3)


def target_right(view, metres=0.3):
    return Pose(view.pose.x, view.pose.y - metres, view.pose.yaw)  # yaw 0: right is -y


def bind(order, descriptor=None, stripes=4):
    return BoundVariant(
        parse_variant(order),
        descriptor=descriptor or PatchColour(),
        parser=StripesParser(StripesConfig(stripes=stripes)) if "P" in order else None,
        synthesizer=ShiftWarp() if "S" in order else None,
    )


def test_d_is_one_whole_image_node(view):
    graph = build_graph(bind("D"), view)
    assert graph.num_nodes == 1 and len(graph.edges) == 0
    local = PatchColour().extract(view)
    np.testing.assert_allclose(graph.features[0], local.descriptors.mean(axis=0), rtol=1e-6)


def test_pd_has_whole_image_and_parts_with_proximity_edges(view):
    graph = build_graph(bind("PD"), view)
    assert graph.num_nodes == 5
    np.testing.assert_allclose(graph.weights, [1, 0.25, 0.25, 0.25, 0.25])
    np.testing.assert_array_equal(graph.boxes[1], [0, 0, 63, 255])
    # Whole image to every stripe; neighbouring stripes touch; stripes two apart are 65 px apart.
    assert graph.edges.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [2, 3], [3, 4]]
    local = PatchColour().extract(view)
    first_stripe = local.positions[:, 0] < 64
    np.testing.assert_allclose(graph.features[1], local.descriptors[first_stripe].mean(axis=0), rtol=1e-6)


def test_pds_moves_boxes_by_the_point_map_and_drops_features_that_leave(view):
    graph = build_graph(bind("PDS"), view, target_right(view))
    assert graph.num_nodes == 5
    # Stripe 0 spans u = 0..63: its corners land at -12.8 (clipped to 0) and 50.2.
    np.testing.assert_allclose(graph.boxes[1], [0, 0, 63 + SHIFT, 255], atol=1e-4)
    np.testing.assert_allclose(graph.boxes[4], [192 + SHIFT, 0, 255 + SHIFT, 255], atol=1e-4)
    # The first grid column (u = 10.17) leaves the image; stripe 0 keeps the other two
    # columns it had in the real image, described as they were there.
    local = PatchColour().extract(view)
    u = local.positions[:, 0]
    np.testing.assert_allclose(graph.features[0], local.descriptors[u + SHIFT > -0.5].mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(graph.features[1], local.descriptors[(u < 64) & (u + SHIFT > -0.5)].mean(axis=0), rtol=1e-6)


def test_pds_drops_parts_whose_centroid_leaves_the_view(view):
    graph = build_graph(bind("PDS"), view, target_right(view, metres=1.0))  # 42.7 px
    assert graph.num_nodes == 4  # stripe 0's centroid (31.5) lands at -11.2
    np.testing.assert_allclose(graph.weights[1:], 1 / 3)


def test_psd_describes_the_synthetic_image_within_the_carried_regions(view):
    target = target_right(view)
    graph = build_graph(bind("PSD"), view, target)
    synthetic = ShiftWarp().synthesize(view, target).view
    local = PatchColour().extract(synthetic)
    # Warped stripe 0 covers synthetic u = 0..50 (its pixels shifted by 12.8 and rounded).
    in_stripe0 = local.positions[:, 0] <= 50
    np.testing.assert_allclose(graph.features[1], local.descriptors[in_stripe0].mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(graph.features[0], local.descriptors.mean(axis=0), rtol=1e-6)


def test_spd_parses_and_describes_the_synthetic_image(view):
    target = target_right(view)
    synthetic = ShiftWarp().synthesize(view, target).view
    np.testing.assert_allclose(build_graph(bind("SPD"), view, target).features, build_graph(bind("PD"), synthetic).features)
    np.testing.assert_allclose(build_graph(bind("SD"), view, target).features, build_graph(bind("D"), synthetic).features)


def test_ds_carries_the_real_description_and_sd_redescribes(view):
    target = target_right(view)
    ds = build_graph(bind("DS"), view, target)
    sd = build_graph(bind("SD"), view, target)
    local = PatchColour().extract(view)
    np.testing.assert_allclose(ds.features[0], local.descriptors[local.positions[:, 0] + SHIFT > -0.5].mean(axis=0), rtol=1e-6)
    assert not np.allclose(ds.features, sd.features)


def test_dsp_groups_moved_real_features_by_regions_of_the_synthetic_image(view):
    target = target_right(view)
    graph = build_graph(bind("DSP"), view, target)
    local = PatchColour().extract(view)
    moved = local.positions[:, 0] + SHIFT
    kept = moved > -0.5
    # Synthetic stripe 0 is u = 0..63 of the *synthetic* image, i.e. real u up to 76.8.
    in_stripe0 = kept & (np.rint(moved) <= 63)
    np.testing.assert_allclose(graph.features[1], local.descriptors[in_stripe0].mean(axis=0), rtol=1e-6)


@pytest.mark.parametrize(("order", "same_as"), [("DP", "PD"), ("DPS", "PDS"), ("SDP", "SPD")])
def test_equivalent_orders_build_identical_graphs(view, order, same_as):
    target = target_right(view)
    for t in (None, target) if "S" in order else (None,):
        a, b = build_graph(bind(order), view, t), build_graph(bind(same_as), view, t)
        np.testing.assert_array_equal(a.features, b.features)
        np.testing.assert_array_equal(a.boxes, b.boxes)
        np.testing.assert_array_equal(a.edges, b.edges)


@pytest.mark.parametrize("order", ["PDS", "PSD", "SPD", "DSP"])
def test_queries_take_the_pd_path(view, order):
    query = build_graph(bind(order), view)
    reference = build_graph(bind("PD"), view)
    np.testing.assert_array_equal(query.features, reference.features)


def test_region_descriptor_in_psd_describes_carried_regions(view):
    graph = build_graph(bind("PSD", descriptor=RegionColour()), view, target_right(view))
    assert graph.num_nodes == 5
    assert graph.features.shape == (5, 3)


def test_semantic_ids_are_warped_into_synthetic_views(view):
    from ssga_core.pipeline import _State

    state = _State(view)
    state.synthesize(ShiftWarp().synthesize(view, target_right(view)))
    assert state.view.synthetic and state.view.semantic is not None
    # Content moved 12.8 px left: synthetic column 100 shows real column 113 (rounding 112.8).
    np.testing.assert_array_equal(state.view.semantic[:, 100], view.semantic[:, 113])


def test_a_variant_without_s_cannot_build_graphs_for_other_poses(view):
    with pytest.raises(InputError, match="has no S"):
        build_graph(bind("PD"), view, target_right(view))


def test_bound_variants_are_checked_on_construction():
    with pytest.raises(InputError, match="cannot use descriptor 'test-region-colour'"):
        bind("DSP", descriptor=RegionColour())
    with pytest.raises(InputError, match="needs a synthesizer"):
        BoundVariant(parse_variant("SD"), descriptor=PatchColour())


def test_table_labels_follow_the_papers_notation():
    assert table_label(parse_variant("SPD1"), StripesParser, PatchColour) == "PC-ST (SPD1)"
    assert table_label(parse_variant("DS"), StripesParser, PatchColour) == "PC (DS)"
    assert bind("PDS").label == "PC-ST (PDS)"


def test_several_sources_fuse_into_one_view_and_join_what_each_carried():
    # Two cameras on the same wall, 1 m apart; the target stands between them. Each sees
    # the wall, so both carry their features and stripes across.
    left = make_view(seed=3)
    right = make_view(seed=3, pose=Pose(left.pose.x, left.pose.y - 1.0, left.pose.yaw))
    target = Pose(left.pose.x, left.pose.y - 0.5, left.pose.yaw)
    bound = bind("PDS")
    alone = [build_graph(bound, v, target) for v in (left, right)]
    both = build_graph(bound, [left, right], target)
    # Parts of both sources (each keeps the stripes that stay in view), one whole-image node.
    assert both.num_nodes - 1 == sum(g.num_nodes - 1 for g in alone)
    syntheses = ShiftWarp().synthesize_from([left, right], target)
    assert syntheses[0].view is syntheses[1].view  # one fused image
    fused = syntheses[0].view
    singles = [ShiftWarp().synthesize(v, target).view for v in (left, right)]
    assert (fused.depth > 0).sum() >= max((s.depth > 0).sum() for s in singles)
    # Order S first: the stages after S run once, on the fused view.
    np.testing.assert_allclose(build_graph(bind("SD"), [left, right], target).features, build_graph(bind("D"), fused).features)


def test_a_query_is_built_from_one_view():
    view = make_view(seed=3)
    with pytest.raises(InputError, match="one view"):
        build_graph(bind("PD"), [view, view])


def test_fusing_keeps_the_nearest_surface_and_hides_what_is_behind_it():
    from ssga_core.stages import fuse_syntheses
    from ssga_core import Synthesis, View

    near_view = make_view(seed=3)
    h, w = near_view.camera.shape
    uv = near_view.camera.pixel_grid()
    everywhere = np.ones((h, w), bool)

    def synthesis(depth, colour):
        rgb = np.full((h, w, 3), colour, np.uint8)
        view = View(rgb=rgb, pose=near_view.pose, camera=near_view.camera, depth=np.full((h, w), depth, np.float32), synthetic=True)
        return Synthesis(view=view, target_uv=uv, visible=everywhere)

    near, far = fuse_syntheses([synthesis(1.0, 200), synthesis(2.0, 50)])
    assert (near.view.rgb == 200).all() and (near.view.depth == 1.0).all()
    assert near.visible.all() and not far.visible.any()


def test_a_descriptor_that_learns_nothing_has_an_empty_state_and_refuses_one():
    from ssga_core.testing.stages import PatchColour

    d = PatchColour()
    assert d.state_dict() == {}
    d.load_state_dict({})
    with pytest.raises(InputError, match="descriptor 'test-patch-colour' learns nothing, but got a fitted state of centroids"):
        d.load_state_dict({"centroids": np.zeros((2, 2))})


def test_holes_skip_describes_only_what_the_synthesizer_drew(view):
    # 0.6 m to the right: content moves 25.6 px left, columns 230-255 of the synthetic view are a
    # hole. The last column of patches (u = 244.8) sees only hole in its 26 px square and is
    # dropped; the one before (u = 223.5) sees 19 of 27 columns drawn and stays.
    target = target_right(view, 0.6)
    skipping = PatchColour(PatchColour.Config(holes="skip"))
    synthetic = ShiftWarp().synthesize(view, target).view
    every = PatchColour().extract(synthetic)
    drawn = every.positions[:, 0] < 240
    kept = skipping.extract(synthetic)
    np.testing.assert_array_equal(kept.positions, every.positions[drawn])
    assert [len(f) for f in skipping.extract_many([synthetic, view])] == [len(kept), 144]
    assert len(skipping.extract(view)) == 144  # a real view has no holes
    skip_graph = build_graph(bind("SD", skipping), view, target)
    keep_graph = build_graph(bind("SD"), view, target)
    np.testing.assert_allclose(keep_graph.features[0], every.descriptors.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(skip_graph.features[0], every.descriptors[drawn].mean(axis=0), rtol=1e-6)
    # The hole is black: describing it darkens the whole image's feature.
    assert (skip_graph.features[0] > keep_graph.features[0]).all()


class FillingShift(ShiftWarp):
    """ShiftWarp that draws its hole (the columns no source pixel reached) as a grey wall 3 m away."""

    def _synthesize(self, view, target):
        syn = super()._synthesize(view, target)
        hole = ~syn.view.valid_depth()
        rgb, depth = syn.view.rgb.copy(), syn.view.depth.copy()
        rgb[hole], depth[hole] = 128, 3.0
        return dataclasses.replace(syn, view=dataclasses.replace(syn.view, rgb=rgb, depth=depth))


def test_parse_invented_makes_parts_of_what_s_drew_where_no_part_landed(view):
    # 0.6 m to the right: content moves 25.6 px left and FillingShift draws columns 230-255. Of the
    # synthetic view's 32 px stripes, the last (224-255) lies 26/32 in them: a part, cut to 230-255.
    # Its one column of patches (u = 244.8) describes it; the carried parts are as without the option.
    target = target_right(view, 0.6)
    plain = dataclasses.replace(bind("PSD", stripes=8), synthesizer=FillingShift())
    inventing = dataclasses.replace(plain, parse_invented=True)
    before, after = build_graph(plain, view, target), build_graph(inventing, view, target)
    assert after.num_nodes == before.num_nodes + 1
    np.testing.assert_array_equal(after.boxes[1:-1], before.boxes[1:])
    np.testing.assert_array_equal(after.boxes[-1], [230, 0, 255, 255])
    local = PatchColour().extract(FillingShift().synthesize(view, target).view)
    np.testing.assert_allclose(after.features[-1], local.descriptors[local.positions[:, 0] > 230].mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(after.features[:-1], before.features)
    # Described before S, nothing describes the invented pixels: PDS is as without the option.
    pds = dataclasses.replace(plain, variant=parse_variant("PDS"))
    np.testing.assert_array_equal(build_graph(dataclasses.replace(pds, parse_invented=True), view, target).features, build_graph(pds, view, target).features)


def test_describe_invented_describes_what_s_drew_where_no_source_pixel_landed(view):
    # 0.6 m to the right: content moves 25.6 px left and FillingShift draws columns 230-255, which no
    # source pixel reached. The synthetic view's one column of patches there (u = 244.8) is described
    # beside the real view's carried patches; the carried ones are as without the option.
    target = target_right(view, 0.6)
    syn = FillingShift().synthesize(view, target)
    fresh = PatchColour().extract(syn.view)
    invented = fresh.descriptors[fresh.positions[:, 0] > 232]
    assert len(invented) == 12
    carried = int(syn.map_points(PatchColour().extract(view).positions)[1].sum())

    def graphs(order, synthesizer=FillingShift()):
        plain = dataclasses.replace(bind(order, stripes=8), synthesizer=synthesizer)
        return build_graph(plain, view, target), build_graph(dataclasses.replace(plain, describe_invented=True), view, target)

    before, after = graphs("DS")
    np.testing.assert_allclose(after.features[0], (carried * before.features[0] + invented.sum(axis=0)) / (carried + len(invented)), rtol=1e-5)
    # PDS parses them into a part of their own first (the last stripe, cut to the invented columns), as
    # parse_invented does for PSD; the carried parts keep the real view's features.
    before, after = graphs("PDS")
    assert after.num_nodes == before.num_nodes + 1
    np.testing.assert_array_equal(after.boxes[-1], [230, 0, 255, 255])
    np.testing.assert_allclose(after.features[-1], invented.mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(after.features[1:-1], before.features[1:])
    # DSP parses after S: the invented column's patches join whichever part they fall in.
    before, after = graphs("DSP")
    assert not np.allclose(after.features[-1], before.features[-1])
    # Orders that describe after S describe those pixels anyway; with nothing drawn there, nothing is added.
    for order in ("SPD", "PSD", "SD"):
        before, after = graphs(order)
        np.testing.assert_array_equal(after.features, before.features, err_msg=order)
    for order in ("DS", "PDS", "DSP"):
        before, after = graphs(order, ShiftWarp())
        np.testing.assert_array_equal(after.features, before.features, err_msg=order)


class CategoryStripes(StripesParser):
    """Stripes, each a piece of a category of its own (its index), as a segmenter's regions are."""

    regions_are_category_pieces = True

    def _parse(self, view):
        regions = super()._parse(view)
        return dataclasses.replace(regions, categories=np.arange(len(regions), dtype=np.int32))


def joining(order, join=True):
    plain = dataclasses.replace(bind(order), parser=CategoryStripes(StripesConfig(stripes=8)), synthesizer=FillingShift())
    return dataclasses.replace(plain, parse_invented=True, describe_invented=True, join_split_parts=join)


def test_join_split_parts_makes_a_carried_part_and_what_s_drew_beside_it_one_part(view):
    # 0.6 m to the right: content moves 25.6 px left, the real view's last stripe lands on columns
    # 198-229 and FillingShift draws 230-255, which parse_invented makes a part of the same category
    # (the synthetic view's last stripe). Joined, they are one part, as a query's parse would have it.
    target = target_right(view, 0.6)
    split, joined = build_graph(joining("PSD", join=False), view, target), build_graph(joining("PSD"), view, target)
    assert joined.num_nodes == split.num_nodes - 1
    np.testing.assert_allclose(joined.boxes[-1], [split.boxes[-2][0], 0, 255, 255])
    local = PatchColour().extract(FillingShift().synthesize(view, target).view)
    np.testing.assert_allclose(joined.features[-1], local.descriptors[local.positions[:, 0] > split.boxes[-2][0]].mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(joined.features[:-1], split.features[:-2])
    # 0.3 m: what S drew (columns 243-255) is under half of the synthetic view's last stripe, so
    # parse_invented leaves it out; joining, it goes to the carried stripe beside it (211-242).
    target = target_right(view, 0.3)
    split, joined = build_graph(joining("PSD", join=False), view, target), build_graph(joining("PSD"), view, target)
    assert joined.num_nodes == split.num_nodes
    assert split.boxes[-1][2] < 243 and joined.boxes[-1][2] == 255
    local = PatchColour().extract(FillingShift().synthesize(view, target).view)
    np.testing.assert_allclose(joined.features[-1], local.descriptors[local.positions[:, 0] > split.boxes[-1][0]].mean(axis=0), rtol=1e-6)


def test_join_split_parts_in_pds_pools_the_carried_and_the_added_features_of_the_joined_part(view):
    target = target_right(view, 0.6)
    split, joined = build_graph(joining("PDS", join=False), view, target), build_graph(joining("PDS"), view, target)
    assert joined.num_nodes == split.num_nodes - 1
    syn = FillingShift().synthesize(view, target)
    real = PatchColour().extract(view)
    _, visible = syn.map_points(real.positions)
    last_stripe = np.rint(real.positions[:, 0]).astype(int) * 8 // 256 == 7
    fresh = PatchColour().extract(syn.view)
    members = np.concatenate([real.descriptors[visible & last_stripe], fresh.descriptors[fresh.positions[:, 0] > 232]])
    np.testing.assert_allclose(joined.features[-1], members.mean(axis=0), rtol=1e-5)
    np.testing.assert_allclose(joined.features[:-1], split.features[:-2])


def test_join_split_parts_leaves_parsers_of_other_regions_and_orders_without_carried_parts_as_they_were(view):
    target = target_right(view, 0.6)
    for order in ("PSD", "PDS"):  # superpixels or instances: touching regions are not pieces of one
        plain = dataclasses.replace(joining(order), parser=StripesParser(StripesConfig(stripes=8)))
        np.testing.assert_array_equal(build_graph(plain, view, target).features, build_graph(dataclasses.replace(plain, join_split_parts=False), view, target).features)
    for order in ("SPD", "DSP"):  # parsed after S: the synthetic view's own pieces
        np.testing.assert_array_equal(build_graph(joining(order), view, target).features, build_graph(joining(order, join=False), view, target).features)


class PairedStripes(StripesParser):
    """Stripes in touching pairs of one category: pieces cut in two, as cascade-seg's ``split_px`` cuts them."""

    regions_are_category_pieces = True
    regions_cut_from_pieces = True

    def _parse(self, view):
        regions = super()._parse(view)
        return dataclasses.replace(regions, categories=(np.arange(len(regions)) // 2).astype(np.int32))


def test_join_split_parts_keeps_the_parts_of_a_parser_that_cuts_pieces_apart_and_gives_them_what_s_drew(view):
    # 0.3 m: what S drew (columns 243-255) is under half of the synthetic view's last stripe, so it is
    # optional; it joins the carried last stripe, and the carried stripes of one category stay two parts.
    target = target_right(view, 0.3)
    paired = dataclasses.replace(joining("PSD"), parser=PairedStripes(StripesConfig(stripes=8)))
    split, joined = build_graph(dataclasses.replace(paired, join_split_parts=False), view, target), build_graph(paired, view, target)
    assert joined.num_nodes == split.num_nodes
    assert split.boxes[-1][2] < 243 and joined.boxes[-1][2] == 255
    np.testing.assert_allclose(joined.boxes[:-1], split.boxes[:-1])
    # The same pairs as whole pieces' halves (a parser that does not cut) are joined into one part each.
    whole = dataclasses.replace(paired, parser=type("WholePairs", (PairedStripes,), {"regions_cut_from_pieces": False})(StripesConfig(stripes=8)))
    assert build_graph(whole, view, target).num_nodes < split.num_nodes - 2


def test_the_graph_keeps_each_parts_category_through_s_and_none_for_a_parser_that_names_none(view):
    target = target_right(view, 0.6)
    named = type("NamedPairs", (PairedStripes,), {"names_categories": True})(StripesConfig(stripes=8))
    for order in ("PSD", "PDS", "SPD", "DSP"):
        bound = dataclasses.replace(joining(order), parser=named)
        real, synthetic = build_graph(bound, view), build_graph(bound, view, target)
        np.testing.assert_array_equal(real.categories, [-1, *(np.arange(8) // 2)], err_msg=order)
        assert synthetic.categories[0] == -1 and len(synthetic.categories) == synthetic.num_nodes, order
        # Each part's category is the pair of stripes it lies in: its box centre's column says which.
        centre = (synthetic.boxes[1:, 0] + synthetic.boxes[1:, 2]) / 2
        expected = np.clip((centre + 25.6 * (order[0] == "P")) // 64, 0, 3)
        np.testing.assert_array_equal(synthetic.categories[1:], expected, err_msg=order)
        plain = dataclasses.replace(bound, parser=StripesParser(StripesConfig(stripes=8)))
        assert build_graph(plain, view, target).categories is None, order
    assert build_graph(bind("SD"), view, target).categories is None  # no parts


class ScoredPairs(PairedStripes):
    """PairedStripes that names its categories and is surer of each the higher it is: score 0.2 + 0.1 x category."""

    names_categories = True

    def _parse(self, view):
        regions = super()._parse(view)
        return dataclasses.replace(regions, scores=(0.2 + 0.1 * regions.categories).astype(np.float32))


def test_the_graph_keeps_how_sure_the_parser_is_of_each_category_through_s_and_what_s_drew(view):
    # Without joining, what S drew at 0.6 m right (columns 230-255) is a part of its own from a fresh parse of the
    # synthetic view (parse_invented): its score comes with it, as the carried parts' do with them.
    target = target_right(view, 0.6)
    for order in ("PSD", "PDS", "SPD", "DSP"):
        for join in (True, False):
            bound = dataclasses.replace(joining(order, join), parser=ScoredPairs(StripesConfig(stripes=8)))
            for graph in (build_graph(bound, view), build_graph(bound, view, target)):
                assert graph.category_scores is not None and np.isnan(graph.category_scores[0]), (order, join)
                np.testing.assert_allclose(graph.category_scores[1:], 0.2 + 0.1 * graph.categories[1:], rtol=1e-6, err_msg=f"{order} {join}")
    invented = build_graph(dataclasses.replace(joining("PSD", False), parser=ScoredPairs(StripesConfig(stripes=8))), view, target)
    assert invented.boxes[-1][2] == 255 and invented.boxes[-1][0] >= 229  # the part S drew, on its own
    # A parser that names categories without scores (ground truth) gives none.
    named = type("NamedPairs", (PairedStripes,), {"names_categories": True})(StripesConfig(stripes=8))
    assert build_graph(dataclasses.replace(joining("PSD"), parser=named), view, target).category_scores is None


def test_a_parser_that_says_it_names_categories_and_gives_none_is_refused(view):
    class Unnamed(StripesParser):
        names_categories = True

    with pytest.raises(PluginError, match="says its regions carry their categories but gave no Regions.categories"):
        Unnamed(StripesConfig(stripes=4)).parse(view)


def test_joining_unites_touching_parts_of_one_category_and_drops_the_optional_ones_left_alone():
    from ssga_core.pipeline import _State

    labels = np.full((4, 10), -1, np.int32)
    labels[:, 0:3], labels[:, 4:6], labels[:, 6:8], labels[:, 9] = 0, 1, 2, 3  # a one-pixel gap between 0 and 1
    regions = Regions(labels=labels, boxes=boxes_from_labels(labels, 4), categories=np.array([0, 0, 1, 0], np.int32))
    state = _State(make_view(seed=3), regions=regions)
    state.join_split_parts(np.array([False, False, False, True]))  # 3 touches only 2, of another category
    expected = np.full((4, 10), -1, np.int32)
    expected[:, 0:3], expected[:, 4:6], expected[:, 6:8] = 0, 0, 1
    np.testing.assert_array_equal(state.regions.labels, expected)
    np.testing.assert_array_equal(state.regions.boxes, [[0, 0, 5, 3], [6, 0, 7, 3]])
    # Three pixels apart is not touching.
    labels[:, 3:6] = -1
    labels[:, 6:10] = 1
    state = _State(make_view(seed=3), regions=Regions(labels=labels, boxes=boxes_from_labels(labels, 2), categories=np.zeros(2, np.int32)))
    state.join_split_parts(None)
    assert len(state.regions) == 2


def test_joining_keeps_the_parts_of_a_parser_that_cuts_pieces_apart_and_gives_a_sliver_to_one_of_them():
    from ssga_core.pipeline import _State

    labels = np.full((4, 12), -1, np.int32)
    labels[:, 0:3], labels[:, 3:6], labels[:, 6:7], labels[:, 7:10], labels[:, 11] = 0, 1, 2, 3, 4
    # 0 and 1: two carried parts of one piece, side by side; 2: a sliver S drew between 1 and 3, all of
    # category 0; 4: an added part of its own, one pixel from 3.
    categories = np.array([0, 0, 0, 0, 0], np.int32)
    optional = np.array([False, False, True, False, False])

    def joined(keep_apart):
        state = _State(make_view(seed=3), regions=Regions(labels=labels, boxes=boxes_from_labels(labels, 5), categories=categories))
        state.join_split_parts(optional, keep_apart=keep_apart)
        return state.regions

    assert len(joined(False)) == 1  # pieces of one category: everything that touches is one
    apart = joined(True)
    assert len(apart) == 4

    def original(column):  # the parts before joining that the joined part at this column holds
        return set(np.unique(labels[apart.labels == apart.labels[0, column]]).tolist())

    assert original(0) == {0} and original(11) == {4}
    assert original(6) in ({1, 2}, {2, 3}), "the sliver joins one carried part, not both"
    assert original(4) != original(8)


def test_a_synthetic_views_graph_records_where_it_was_drawn(view):
    # 0.6 m to the right: content moves 25.6 px left, so columns 230-255 of the synthetic view are a hole.
    target = target_right(view, 0.6)
    for order in ("SPD", "PSD", "PDS", "DSP", "SD"):
        drawn = build_graph(bind(order), view, target).drawn
        np.testing.assert_allclose(drawn, ShiftWarp().synthesize(view, target).view.drawn_blocks(16), err_msg=order)
        assert drawn[:, -1].max() < 0.5 and drawn[:, :-2].min() == 1.0
    assert build_graph(bind("PD"), view).drawn is None  # a real view: all of it seen


def test_each_part_keeps_the_real_region_it_began_as(view):
    # 1.0 m to the right: stripe 0 (of 4) leaves the view, so the carried parts are stripes 1-3.
    target = target_right(view, 1.0)
    assert build_graph(bind("PD"), view).part_origins.tolist() == [[-1, -1], [0, 0], [0, 1], [0, 2], [0, 3]]
    for order in ("PDS", "PSD"):
        assert build_graph(bind(order), view, target).part_origins.tolist() == [[-1, -1], [0, 1], [0, 2], [0, 3]], order
    # Parsed on the synthetic view, a part is no real region; nor is the whole image, nor a graph without parts.
    for order in ("SPD", "DSP", "SD", "DS"):
        assert build_graph(bind(order), view, target).part_origins is None, order
    # Two sources: each one's parts are its own, by the source's index.
    right = make_view(seed=3, pose=Pose(view.pose.x, view.pose.y - 1.0, view.pose.yaw))
    both = build_graph(bind("PSD"), [view, right], target_right(view, 0.5))
    sources = both.part_origins[1:, 0]
    assert set(sources.tolist()) == {0, 1} and np.all(np.diff(sources) >= 0)
    # What S drew is a part of no real region, and a joined part is the carried part it began as.
    drawn = target_right(view, 0.6)
    inventing = dataclasses.replace(bind("PSD", stripes=8), synthesizer=FillingShift(), parse_invented=True)
    assert build_graph(inventing, view, drawn).part_origins[-1].tolist() == [-1, -1]
    joined = build_graph(joining("PSD"), view, drawn)
    split = build_graph(joining("PSD", join=False), view, drawn)
    assert split.part_origins[-1].tolist() == [-1, -1] and joined.part_origins[-1].tolist() == split.part_origins[-2].tolist() != [-1, -1]
