"""The data model validates what stages hand over."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core import Camera, InputError, LocalFeatures, Pose, Regions, SceneGraph, Synthesis, View
from ssga_core.data import Data
from ssga_core.testing import make_view


def test_view_checks_shapes_and_dtypes_against_the_camera():
    rgb = np.zeros((256, 256, 3), np.uint8)
    with pytest.raises(InputError, match=r"View.rgb: expected shape \(256, 256, 3\) of uint8, got shape \(256, 256, 3\) of float64"):
        View(rgb=rgb.astype(float), pose=Pose(0, 0, 0))
    with pytest.raises(InputError, match=r"View.depth: expected shape \(256, 256\)"):
        View(rgb=rgb, pose=Pose(0, 0, 0), depth=np.zeros((128, 128), np.float32))
    with pytest.raises(InputError, match="View.semantic"):
        View(rgb=rgb, pose=Pose(0, 0, 0), semantic=np.zeros((256, 256), np.float32))
    with pytest.raises(InputError, match="expected a numpy array"):
        View(rgb=[[0]], pose=Pose(0, 0, 0))  # type: ignore[arg-type]


def test_view_reports_what_it_carries():
    view = make_view()
    assert view.available == {Data.RGB, Data.DEPTH, Data.SEMANTIC}
    bare = View(rgb=view.rgb, pose=view.pose)
    assert bare.available == {Data.RGB}
    assert not bare.valid_depth().any()


def test_regions_from_labels_renumber_and_box():
    labels = np.full((6, 8), -1, np.int32)
    labels[1:3, 2:5] = 7
    labels[4:6, 0:2] = 3
    regions = Regions.from_labels(labels, categories=np.arange(10) * 10)
    assert len(regions) == 2
    # Label 3 becomes 0 and label 7 becomes 1 (sorted), categories follow them.
    np.testing.assert_array_equal(regions.boxes, [[0, 4, 1, 5], [2, 1, 4, 2]])
    np.testing.assert_array_equal(regions.categories, [30, 70])
    scored = Regions.from_labels(labels, categories=np.arange(10) * 10, scores=np.arange(10, dtype=np.float32) / 10)
    np.testing.assert_allclose(scored.scores, [0.3, 0.7])
    assert regions.scores is None
    np.testing.assert_allclose(regions.centroids(), [[0.5, 4.5], [3.0, 1.5]])
    kept = regions.select(np.array([False, True]))
    assert len(kept) == 1 and kept.labels.max() == 0
    np.testing.assert_array_equal(kept.mask(0), labels == 7)


def test_region_attributes_travel_with_their_regions():
    labels = np.array([[0, 0, 1], [2, 2, 1]], np.int32)
    regions = Regions(
        labels=labels,
        boxes=np.array([[0, 0, 1, 0], [2, 0, 2, 1], [0, 1, 1, 1]], np.float32),
        categories=np.array([5, 6, 7], np.int32),
        names=("sofa", "lamp", "rug"),
        scores=np.array([0.9, 0.5, 0.7], np.float32),
    )
    kept = regions.select(np.array([True, False, True]))
    assert kept.names == ("sofa", "rug")
    np.testing.assert_array_equal(kept.scores, np.array([0.9, 0.7], np.float32))
    np.testing.assert_array_equal(kept.categories, [5, 7])
    # Joined: names survive where every part has them, scores vanish where one lacks them.
    other = Regions(labels=np.zeros((2, 3), np.int32), boxes=np.array([[0, 0, 2, 1]], np.float32), names=("wall",))
    joined = Regions.concatenate([kept, other], np.where(kept.labels >= 0, kept.labels, 2))
    assert joined.names == ("sofa", "rug", "wall")
    assert joined.scores is None and joined.categories is None
    with pytest.raises(InputError, match="Regions.names: expected a tuple of 3 strings"):
        Regions(labels=labels, boxes=regions.boxes, names=("sofa",))
    with pytest.raises(InputError, match="Regions.scores"):
        Regions(labels=labels, boxes=regions.boxes, scores=np.ones(2, np.float32))


def test_merging_regions_joins_their_pixels_and_unites_their_boxes():
    labels = np.array([[0, 0, 1, 2], [3, 3, 1, 2]], np.int32)
    regions = Regions(
        labels=labels,
        boxes=np.array([[0, 0, 1.5, 0], [2, 0, 2, 1], [3, 0, 3, 1], [0, 1, 1, 1]], np.float32),  # 0's box is wider than its mask, as a carried one
        categories=np.array([5, 5, 6, 7], np.int32),
        names=("wall", "wall", "door", "rug"),
    )
    merged = regions.merge(np.array([0, 0, 1, -1]))
    np.testing.assert_array_equal(merged.labels, [[0, 0, 0, 1], [-1, -1, 0, 1]])
    np.testing.assert_array_equal(merged.boxes, [[0, 0, 2, 1], [3, 0, 3, 1]])
    np.testing.assert_array_equal(merged.categories, [5, 6])
    assert merged.names == ("wall", "door")
    with pytest.raises(InputError, match="none empty"):
        regions.merge(np.array([0, 2, 2, -1]))


def test_regions_reject_labels_without_boxes():
    with pytest.raises(InputError, match="label 2 has no box"):
        Regions(labels=np.full((4, 4), 2, np.int32), boxes=np.zeros((1, 4), np.float32))


def test_local_features_check_their_shapes():
    with pytest.raises(InputError, match="LocalFeatures.descriptors"):
        LocalFeatures(positions=np.zeros((5, 2), np.float32), descriptors=np.zeros((4, 8), np.float32))


def test_point_map_lookup_and_label_warp():
    cam = Camera(width=4, height=2)
    target_uv = cam.pixel_grid() + np.array([1.0, 0.0], np.float32)
    visible = cam.contains(target_uv)
    view = View(rgb=np.zeros((2, 4, 3), np.uint8), pose=Pose(0, 0, 0), camera=cam, synthetic=True)
    syn = Synthesis(view=view, target_uv=target_uv, visible=visible)
    uv, vis = syn.map_points(np.array([[0.2, 0.9], [3.0, 0.0]]))
    np.testing.assert_allclose(uv, [[1, 1], [4, 0]])
    np.testing.assert_array_equal(vis, [True, False])
    labels = np.array([[0, 1, 2, 3], [4, 5, 6, 7]], np.int32)
    np.testing.assert_array_equal(syn.warp_labels(labels), [[-1, 0, 1, 2], [-1, 4, 5, 6]])


def test_drawn_share_counts_known_depth_around_each_position_of_a_synthetic_view():
    real = make_view(seed=0)
    depth = real.depth.copy()
    depth[:, 128:] = 0.0  # the right half is a hole
    depth[40, 20] = np.nan  # one unknown pixel inside the drawn half
    synthetic = View(rgb=real.rgb, pose=real.pose, camera=real.camera, depth=depth, synthetic=True)
    positions = [[10, 10], [127, 50], [200, 100], [20, 40], [0, 0], [-5, 3], [np.nan, 4]]
    share = synthetic.drawn_share(positions, side=11)
    # 11 x 11 around (127, 50): columns 122-132, of which 122-127 drawn; around (20, 40) one pixel of 121
    # unknown; the square around (0, 0) is clipped to 6 x 6, all drawn; outside the image or NaN: 0.
    np.testing.assert_allclose(share, [1, 6 / 11, 0, 120 / 121, 1, 0, 0], rtol=1e-6)
    # A real view, or a synthetic one without depth, says nothing about holes: all drawn.
    np.testing.assert_array_equal(real.drawn_share(positions, side=11), np.ones(7))
    no_depth = View(rgb=real.rgb, pose=real.pose, camera=real.camera, synthetic=True)
    np.testing.assert_array_equal(no_depth.drawn_share(positions, side=11), np.ones(7))


def test_drawn_blocks_are_the_share_of_each_block_a_synthetic_view_drew():
    real = make_view(seed=0)
    depth = real.depth.copy()
    depth[:, 160:] = 0.0  # columns 160-255 are a hole: blocks of 64 px, the third half drawn, the fourth not at all
    synthetic = View(rgb=real.rgb, pose=real.pose, camera=real.camera, depth=depth, synthetic=True)
    np.testing.assert_allclose(synthetic.drawn_blocks(4), np.tile([1.0, 1.0, 0.5, 0.0], (4, 1)))
    assert synthetic.drawn_blocks(4).dtype == np.float32
    # Blocks need not divide the image: columns 0-84, 85-170 (75 of its 86 drawn) and 171-255.
    np.testing.assert_allclose(synthetic.drawn_blocks(3), np.tile([1.0, 75 / 86, 0.0], (3, 1)), rtol=1e-6)
    np.testing.assert_array_equal(real.drawn_blocks(4), np.ones((4, 4)))  # a real view: all of it seen
    with pytest.raises(InputError, match="blocks must be positive"):
        synthetic.drawn_blocks(0)


def test_scene_graph_records_where_it_was_drawn_as_a_square_grid_of_shares():
    ok = dict(boxes=np.zeros((2, 4), np.float32), features=np.zeros((2, 5), np.float32), weights=np.ones(2, np.float32), edges=np.zeros((0, 2), int))
    assert SceneGraph(**ok).drawn is None
    SceneGraph(**ok, drawn=np.full((4, 4), 0.5, np.float32))
    with pytest.raises(InputError, match="SceneGraph.drawn"):
        SceneGraph(**ok, drawn=np.ones((4, 3), np.float32))
    with pytest.raises(InputError, match="SceneGraph.drawn"):
        SceneGraph(**ok, drawn=np.full((2, 2), 1.5, np.float32))
    with pytest.raises(InputError, match="SceneGraph.drawn"):
        SceneGraph(**ok, drawn=np.ones((2, 2), np.int64))



def test_scene_graph_part_origins_are_source_region_pairs_with_none_for_the_whole_image():
    ok = dict(boxes=np.zeros((3, 4), np.float32), features=np.zeros((3, 5), np.float32), weights=np.ones(3, np.float32), edges=np.zeros((0, 2), int))
    assert SceneGraph(**ok).part_origins is None
    SceneGraph(**ok, part_origins=np.array([[-1, -1], [0, 4], [-1, -1]], np.int32))
    for bad in ([[-1, -1], [0, 4]], [[0, 0], [0, 1], [0, 2]], [[-1, -1], [0, -1], [1, 2]]):
        with pytest.raises(InputError, match="SceneGraph.part_origins"):
            SceneGraph(**ok, part_origins=np.array(bad, np.int32))
    with pytest.raises(InputError, match="SceneGraph.part_origins"):
        SceneGraph(**ok, part_origins=np.zeros((3, 2), np.float32))


def test_scene_graph_categories_are_one_per_node_with_none_for_the_whole_image():
    ok = dict(boxes=np.zeros((3, 4), np.float32), features=np.zeros((3, 5), np.float32), weights=np.ones(3, np.float32), edges=np.zeros((0, 2), int))
    assert SceneGraph(**ok).categories is None
    SceneGraph(**ok, categories=np.array([-1, 4, -1], np.int32))  # a part of unknown category: -1
    for bad in (np.array([-1, 4], np.int32), np.array([2, 4, 5], np.int32), np.array([-1, 4, 5], np.float32)):
        with pytest.raises(InputError, match="SceneGraph.categories"):
            SceneGraph(**ok, categories=bad)
    named = np.array([-1, 4, -1], np.int32)
    SceneGraph(**ok, categories=named, category_scores=np.array([np.nan, 0.9, 0.2], np.float32))
    for bad in (np.array([np.nan, 0.9], np.float32), np.array([0, 1, 0])):
        with pytest.raises(InputError, match="SceneGraph.category_scores"):
            SceneGraph(**ok, categories=named, category_scores=bad)
    with pytest.raises(InputError, match="SceneGraph.category_scores: given without SceneGraph.categories"):
        SceneGraph(**ok, category_scores=np.array([np.nan, 0.9, 0.2], np.float32))

def test_scene_graph_validates_edges_and_needs_the_whole_image():
    ok = dict(boxes=np.zeros((3, 4), np.float32), features=np.zeros((3, 5), np.float32), weights=np.ones(3, np.float32))
    SceneGraph(**ok, edges=np.array([[0, 1], [1, 2]]))
    with pytest.raises(InputError, match="pairs i < j"):
        SceneGraph(**ok, edges=np.array([[1, 0]]))
    with pytest.raises(InputError, match="pairs i < j"):
        SceneGraph(**ok, edges=np.array([[0, 3]]))
    with pytest.raises(InputError, match="whole-image node"):
        SceneGraph(boxes=np.zeros((0, 4), np.float32), features=np.zeros((0, 5), np.float32), weights=np.ones(0, np.float32), edges=np.zeros((0, 2), int))


def test_boxes_from_labels_match_per_label_extremes():
    from ssga_core.data import boxes_from_labels

    rng = np.random.default_rng(0)
    labels = rng.integers(-1, 9, size=(37, 53)).astype(np.int32)
    labels[labels == 4] = -1  # a label with no pixel
    boxes = boxes_from_labels(labels, 10)
    for k in range(10):
        v, u = np.nonzero(labels == k)
        if len(u):
            np.testing.assert_array_equal(boxes[k], [u.min(), v.min(), u.max(), v.max()])
        else:
            assert np.isnan(boxes[k]).all()

def test_box_pixels_are_the_box_inclusive_at_least_two_by_two_and_inside_the_image():
    from ssga_core import box_pixels

    image = np.arange(20 * 30 * 2).reshape(20, 30, 2)
    np.testing.assert_array_equal(box_pixels(image, np.array([3, 4, 10, 12], np.float32)), image[4:13, 3:11])
    np.testing.assert_array_equal(box_pixels(image, np.array([2.4, 5.6, 7.2, 9.5], np.float32)), image[5:11, 2:9])  # widened to whole pixels
    assert box_pixels(image, np.array([29, 19, 29, 19], np.float32)).shape == (2, 2, 2)  # one pixel, in the corner
    assert box_pixels(image[..., 0], np.array([5, 5, 5, 5], np.float32)).shape == (2, 2)
    np.testing.assert_array_equal(box_pixels(image, np.array([-3, -2, 40, 25], np.float32)), image)
