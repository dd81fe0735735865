"""Bag-of-words node features: k-means, reciprocal-rank votes, NBNN, pooling, colour, the descriptor base."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from ssga_core import InputError, LocalFeatures, View
from ssga_bench.seeds import stream
from ssga_bench.colour import COLOUR_BINS, COLOUR_DIM, colour_histograms
from ssga_bench.bow import (
    BagOfWords,
    BoWConfig,
    BoWDescriptor,
    BoWDescriptorConfig,
    NotFittedError,
    grid_cells,
    kmeans,
    normalise_rows,
    reciprocal_rank_votes,
)
from ssga_core.testing import check_descriptor, check_descriptor_in_all_orders, make_view
from ssga_core.testing.stages import PatchColour


def _dictionary(similarity: str = "nbnn", **config) -> BagOfWords:
    """Two 1-d words: word 0 has prototypes {0, 10} (centroid 5), word 1 prototypes {4, 4} (centroid 4)."""
    bow = BagOfWords(BoWConfig(k=2, prototypes=2, similarity=similarity, **config))
    bow.load_state_dict({"centroids": np.array([[5.0], [4.0]]), "prototypes": np.array([[[0.0], [10.0]], [[4.0], [4.0]]])})
    return bow


def _blobs(n_per: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    centres = rng.normal(0, 20, (5, 8))
    labels = np.repeat(np.arange(5), n_per)
    return (centres[labels] + rng.normal(0, 0.5, (len(labels), 8))).astype(np.float32), labels, centres


# --------------------------------------------------------------------------- votes


def test_reciprocal_rank_votes_by_hand():
    d = np.array([[3.0, 1.0, 2.0], [0.0, 5.0, 9.0]])
    # Ranks: row 0 is 3, 1, 2; row 1 is 1, 2, 3.
    np.testing.assert_allclose(reciprocal_rank_votes(d), [[1 / 3, 1, 1 / 2], [1, 1 / 2, 1 / 3]])
    np.testing.assert_allclose(reciprocal_rank_votes(d, top_n=2), [[0, 1, 1 / 2], [1, 1 / 2, 0]])
    np.testing.assert_allclose(reciprocal_rank_votes(d, offset=1.0), [[1 / 4, 1 / 2, 1 / 3], [1 / 2, 1 / 3, 1 / 4]])


def test_ties_go_to_the_lower_word_index():
    np.testing.assert_allclose(reciprocal_rank_votes(np.array([[1.0, 1.0, 0.0]])), [[1 / 2, 1 / 3, 1]])


def test_votes_depend_on_the_order_of_distances_only():
    d = np.random.default_rng(0).random((10, 7))
    np.testing.assert_array_equal(reciprocal_rank_votes(d), reciprocal_rank_votes(np.exp(3 * d) + 5))


# --------------------------------------------------------------------------- NBNN vs centroid


def test_nbnn_uses_the_nearest_prototype_and_centroid_the_mean():
    x = np.array([[0.5], [9.0]])
    # x = 0.5: nearest prototypes 0 (word 0, d = 0.25) and 4 (word 1, 12.25); centroids 5 (20.25) and 4 (12.25).
    np.testing.assert_allclose(_dictionary("nbnn").distances(x), [[0.25, 12.25], [1.0, 25.0]])
    np.testing.assert_allclose(_dictionary("centroid").distances(x), [[20.25, 12.25], [16.0, 25.0]])
    # So the two readings disagree on which word x = 0.5 belongs to, and agree for x = 9.
    np.testing.assert_allclose(_dictionary("nbnn").encode(x), [[1, 1 / 2], [1, 1 / 2]])
    np.testing.assert_allclose(_dictionary("centroid").encode(x), [[1 / 2, 1], [1, 1 / 2]])


def test_nbnn_with_every_member_as_prototype_is_nearest_neighbour_to_each_word():
    x, labels, _ = _blobs(n_per=20)
    bow = BagOfWords(BoWConfig(k=5, prototypes=1000)).fit(x)
    query = np.random.default_rng(1).normal(0, 20, (30, 8)).astype(np.float32)
    dist = ((query[:, None, :] - x[None, :, :]) ** 2).sum(-1)
    word_of = kmeans(x, 5, rng=stream(0, "fitting"))[1]  # the same fit: the same stream, the same data
    expected = np.stack([dist[:, word_of == w].min(1) for w in range(5)], axis=1)
    np.testing.assert_allclose(bow.distances(query), expected, rtol=1e-4, atol=1e-2)


# --------------------------------------------------------------------------- pooling


def test_pool_sums_codes_and_normalises_each_node():
    codes = np.array([[1.0, 0.5], [0.5, 1.0], [1.0, 0.5]], dtype=np.float32)
    members = [np.arange(3), np.array([1]), np.array([], dtype=int), np.array([0, 2])]
    raw = np.array([[2.5, 2.0], [0.5, 1.0], [0.0, 0.0], [2.0, 1.0]])
    np.testing.assert_allclose(_dictionary(norm="none").pool(codes, members), raw)
    np.testing.assert_allclose(_dictionary(norm="l1").pool(codes, members), raw / np.maximum(raw.sum(1, keepdims=True), 1e-9))
    l2 = _dictionary().pool(codes, members)
    np.testing.assert_allclose(l2, raw / np.maximum(np.linalg.norm(raw, axis=1, keepdims=True), 1e-9), rtol=1e-6)
    assert l2.dtype == np.float32 and l2.shape == (4, 2)


def test_empty_member_lists_pool_to_zeros():
    bow = _dictionary()
    out = bow.pool(bow.encode(np.array([[1.0], [3.0]])), [np.array([], dtype=int), np.array([], dtype=np.int64)])
    np.testing.assert_array_equal(out, np.zeros((2, 2)))
    assert bow.encode(np.zeros((0, 1))).shape == (0, 2)


def test_normalise_rows_leaves_zero_rows_alone():
    np.testing.assert_array_equal(normalise_rows(np.zeros((2, 3), np.float32), "l2"), np.zeros((2, 3)))


# --------------------------------------------------------------------------- k-means and fitting


@pytest.mark.parametrize("init", ["k-means++", "random"])
def test_kmeans_recovers_well_separated_clusters(init):
    x, truth, centres = _blobs()
    centroids, labels = kmeans(x, 5, init=init, rng=3)
    # Every true cluster maps to exactly one found cluster and back.
    pairs = set(zip(truth.tolist(), labels.tolist(), strict=True))
    assert len(pairs) == 5 and len({p[1] for p in pairs}) == 5
    for t, found in pairs:
        assert np.linalg.norm(centroids[found] - centres[t]) < 0.3


def test_fit_is_deterministic_with_its_seed():
    x = np.random.default_rng(0).random((2000, 16), dtype=np.float32)
    a = BagOfWords(BoWConfig(k=20, seed=4)).fit(x).state_dict()
    b = BagOfWords(BoWConfig(k=20, seed=4)).fit(x).state_dict()
    c = BagOfWords(BoWConfig(k=20, seed=5)).fit(x).state_dict()
    np.testing.assert_array_equal(a["centroids"], b["centroids"])
    np.testing.assert_array_equal(a["prototypes"], b["prototypes"])
    assert not np.array_equal(a["centroids"], c["centroids"])


def test_prototypes_are_members_of_their_word():
    x, _, _ = _blobs(n_per=50)
    bow = BagOfWords(BoWConfig(k=5, prototypes=8)).fit(x)
    assert bow.prototypes.shape == (5, 8, 8)
    for w in range(5):
        for p in bow.prototypes[w]:
            assert np.any(np.all(x == p, axis=1)), "a prototype is not a training descriptor"
            assert np.argmin(((bow.centroids - p) ** 2).sum(1)) == w


def test_fewer_distinct_descriptors_than_words_still_fits():
    x = np.repeat(np.eye(3, dtype=np.float32), 10, axis=0)  # 30 descriptors, 3 distinct
    bow = BagOfWords(BoWConfig(k=5, prototypes=4)).fit(x)
    assert np.isfinite(bow.centroids).all() and np.isfinite(bow.prototypes).all()
    codes = bow.encode(x)
    assert codes.shape == (30, 5) and np.allclose(np.sort(codes, 1)[:, ::-1], 1 / np.arange(1, 6))


def test_too_few_descriptors_for_k_is_an_input_error():
    with pytest.raises(InputError, match=r"k = 100 words need at least 100 training descriptors, got 99"):
        BagOfWords().fit(np.zeros((99, 4)))


def test_max_train_subsamples_deterministically():
    x = np.random.default_rng(0).random((3000, 8), dtype=np.float32)
    a = BagOfWords(BoWConfig(k=10, max_train=500)).fit(x).state_dict()
    b = BagOfWords(BoWConfig(k=10, max_train=500)).fit(x).state_dict()
    np.testing.assert_array_equal(a["centroids"], b["centroids"])


def test_bad_descriptors_are_input_errors():
    bow = BagOfWords(BoWConfig(k=2)).fit(np.eye(4))
    with pytest.raises(InputError, match="expected 4-d descriptors"):
        bow.encode(np.zeros((3, 5)))
    with pytest.raises(InputError, match="NaN"):
        bow.encode(np.full((1, 4), np.nan))


def test_unfitted_dictionary_says_so():
    with pytest.raises(NotFittedError, match="not fitted"):
        BagOfWords().encode(np.zeros((3, 4)))


# --------------------------------------------------------------------------- state


def test_state_dict_round_trips_through_npz(tmp_path):
    x, _, _ = _blobs()
    bow = BagOfWords(BoWConfig(k=5, prototypes=6)).fit(x)
    np.savez(tmp_path / "bow.npz", **bow.state_dict())
    again = BagOfWords(BoWConfig(k=5, prototypes=6))
    again.load_state_dict(dict(np.load(tmp_path / "bow.npz")))
    np.testing.assert_array_equal(again.encode(x[:50]), bow.encode(x[:50]))


def test_dictionaries_with_the_same_words_encode_a_view_once(monkeypatch):
    x, _, _ = _blobs()
    a = BagOfWords(BoWConfig(k=5, prototypes=6)).fit(x)
    b = BagOfWords(BoWConfig(k=5, prototypes=6))
    b.load_state_dict(a.state_dict())  # another variant's descriptor, fitted on the same views
    other = BagOfWords(BoWConfig(k=5, prototypes=6, seed=9)).fit(x)
    computed = []
    distances = BagOfWords.distances
    monkeypatch.setattr(BagOfWords, "distances", lambda self, d: computed.append(len(d)) or distances(self, d))
    query = x[7:40].copy()
    first = a.encode(query)
    np.testing.assert_array_equal(b.encode(query.copy()), first)
    assert computed == [33]  # b reused a's codes: same words, same features
    assert not first.flags.writeable  # shared, so nobody may change them
    other.encode(query)  # other words: encoded again
    a.encode(query[:-1])  # other features: encoded again
    assert computed == [33, 33, 32]
    assert a.fingerprint() == b.fingerprint() != other.fingerprint()


def test_state_dict_must_match_the_config():
    state = BagOfWords(BoWConfig(k=5, prototypes=6)).fit(_blobs()[0]).state_dict()
    with pytest.raises(InputError, match="k = 4"):
        BagOfWords(BoWConfig(k=4, prototypes=6)).load_state_dict(state)
    with pytest.raises(InputError, match="prototypes = 3"):
        BagOfWords(BoWConfig(k=5, prototypes=3)).load_state_dict(state)
    with pytest.raises(InputError, match="missing prototypes"):
        BagOfWords(BoWConfig(k=5, prototypes=6)).load_state_dict({"centroids": state["centroids"]})


# --------------------------------------------------------------------------- config


def test_config_bounds():
    with pytest.raises(ValidationError, match="top_n"):
        BoWConfig(k=10, top_n=11)
    with pytest.raises(ValidationError):
        BoWConfig(k=1)
    with pytest.raises(ValidationError):
        BoWConfig(similarity="cosine")
    with pytest.raises(ValidationError):
        BoWConfig(kk=3)
    assert BoWConfig().k == 100


# --------------------------------------------------------------------------- the descriptor base


class _ColourConfig(BoWDescriptorConfig):
    pass


class _ColourBoW(BoWDescriptor):
    """PatchColour's 144 patch colours as local features, pooled by the bag of words."""

    name = "test-colour-bow"
    Config = _ColourConfig

    def _extract(self, view: View) -> LocalFeatures:
        return PatchColour()._extract(view)


def _small(**config) -> _ColourBoW:
    return _ColourBoW(_ColourConfig(bow=BoWConfig(k=8, prototypes=4), **config))


def _fitted(views: list[View], **config) -> _ColourBoW:
    d = _small(**config)
    d.fit(views)
    return d


def test_a_bow_descriptor_meets_the_descriptor_contract():
    check_descriptor(_small())


def test_a_bow_descriptor_runs_in_every_order():
    check_descriptor_in_all_orders(_small())


def test_a_bow_descriptor_has_dim_k_and_pools_to_it():
    d = _small()
    assert d.dim == 8
    d.fit([make_view(seed=s) for s in range(2)], labels=[0, 1])  # the dictionary is unsupervised: labels are ignored
    local = d.extract(make_view(seed=0))
    out = d.pool(local, [np.arange(len(local)), np.array([], dtype=int)])
    assert out.shape == (2, 8)
    np.testing.assert_allclose(np.linalg.norm(out[0]), 1.0, rtol=1e-6)
    np.testing.assert_array_equal(out[1], 0)


def test_pooling_before_fit_names_the_descriptor():
    d = _small()
    local = d.extract(make_view())
    with pytest.raises(NotFittedError, match="'test-colour-bow' is not fitted"):
        d.pool(local, [np.arange(len(local))])


def test_fit_errors_name_the_descriptor():
    d = _ColourBoW()  # k = 100 from one view's 144 features is fine; from none it is not
    with pytest.raises(InputError, match="descriptor 'test-colour-bow': .*k = 100"):
        d.fit([])


def test_fit_caps_training_descriptors_per_view():
    d = _ColourBoW(_ColourConfig(bow=BoWConfig(k=8, max_train=100)))
    x = d.training_descriptors([make_view(seed=s) for s in range(4)])
    assert x.shape == (4 * 25, 3)


def test_descriptor_state_round_trip():
    d = _small()
    d.fit([make_view(seed=1)])
    other = _small()
    other.load_state_dict(d.state_dict())
    local = d.extract(make_view(seed=2))
    members = [np.arange(len(local)), np.arange(10)]
    np.testing.assert_array_equal(other.pool(local, members), d.pool(local, members))


def test_a_config_without_bow_is_refused():
    class NoBow(BoWDescriptor):
        name = "test-no-bow"
        Config = PatchColour.Config

        def _extract(self, view: View) -> LocalFeatures:
            raise AssertionError

    with pytest.raises(TypeError, match="bow: BoWConfig"):
        NoBow()


# --------------------------------------------------------------------------- colour


def test_colour_histograms_are_the_shares_of_each_windows_pixels():
    # Left half pure grey (L 128 -> bin 2, a = b = 128 -> bin 2), right half saturated red.
    rgb = np.full((64, 64, 3), 128, np.uint8)
    rgb[:, 32:] = (200, 30, 30)
    positions = np.array([[10.0, 32.0], [50.0, 32.0], [31.5, 32.0]], np.float32)
    hist = colour_histograms(rgb, positions, side=9)
    np.testing.assert_allclose(hist.sum(axis=1), 1.0, rtol=1e-5)
    grey = (2 * COLOUR_BINS + 2) * COLOUR_BINS + 2
    assert hist[0, grey] == pytest.approx(1.0) and hist[1, grey] == 0.0 and hist[1].max() == pytest.approx(1.0)
    assert hist[2, grey] == pytest.approx(4 / 9, abs=1e-5)  # columns 28-36 round 31.5 to 32: 4 grey of 9


def test_colour_windows_are_mirrored_at_the_border():
    rgb = np.full((32, 32, 3), 128, np.uint8)
    rgb[:, 0] = (200, 30, 30)  # one red column at the left edge
    hist = colour_histograms(rgb, np.array([[0.0, 16.0]], np.float32), side=5)  # columns -2..2 read as 1, 0, 0, 1, 2
    # 2 of 5 columns red (clamping to the edge would give 3, dropping what lies outside 1)
    red = np.argmax(colour_histograms(rgb, np.array([[0.0, 0.0]], np.float32), side=1)[0])
    grey = (2 * COLOUR_BINS + 2) * COLOUR_BINS + 2
    assert hist[0, red] == pytest.approx(2 / 5, abs=1e-5) and hist[0, grey] == pytest.approx(3 / 5, abs=1e-5)


def test_colour_mixes_the_cosines_of_words_and_colours():
    views = [make_view(seed=s) for s in range(4)]
    plain, coloured = _fitted(views), _fitted(views, colour=0.3)
    a, b = coloured.extract(views[0]), coloured.extract(views[1])
    own = plain.extract(views[0])
    assert a.descriptors.shape == (len(own), own.descriptors.shape[1] + COLOUR_DIM) and coloured.dim == 8 + COLOUR_DIM
    np.testing.assert_array_equal(a.descriptors[:, :-COLOUR_DIM], own.descriptors)
    # The default window: a tenth of the view's side.
    side = round(0.1 * np.sqrt(views[0].camera.width * views[0].camera.height))
    np.testing.assert_array_equal(a.descriptors[:, -COLOUR_DIM:], colour_histograms(views[0].rgb, a.positions, side))
    # The dictionary sees the descriptor's own columns alone: the same words as without colour.
    np.testing.assert_array_equal(coloured.bow.centroids, plain.bow.centroids)
    everything = [np.arange(len(a))]
    na, nb = coloured.pool(a, everything)[0], coloured.pool(b, everything)[0]
    wa, wb = plain.pool(plain.extract(views[0]), everything)[0], plain.pool(plain.extract(views[1]), everything)[0]
    ca, cb = (x.descriptors[:, -COLOUR_DIM:].sum(axis=0) for x in (a, b))
    colour_cosine = ca @ cb / np.linalg.norm(ca) / np.linalg.norm(cb)
    assert np.linalg.norm(na) == pytest.approx(1.0, abs=1e-5)
    assert na @ nb == pytest.approx(0.7 * (wa @ wb) + 0.3 * colour_cosine, abs=1e-5)
    assert colour_cosine < 0.999 and abs(na @ nb - wa @ wb) > 1e-3  # colour moved the cosine


def test_a_coloured_bow_descriptor_meets_the_contract_in_every_order():
    coloured = _ColourBoW(_ColourConfig(bow=BoWConfig(k=8, prototypes=4), colour=0.5))
    check_descriptor(coloured)
    check_descriptor_in_all_orders(coloured)


# --------------------------------------------------------------------------- words in place (spatial pyramid)


def test_grid_cells_split_members_by_where_they_stand_in_their_box():
    positions = np.array([[0, 0], [10, 0], [0, 10], [10, 10], [4, 6], [np.nan, 1.0]])
    cells = grid_cells(positions, np.arange(6), 2)
    # u across, v down; a feature on the far edge is in the last cell, one with no position in none.
    assert [c.tolist() for c in cells] == [[0], [1], [2, 4], [3]]
    # The box is the members', not the image's: two features side by side fill the two top cells.
    assert [c.tolist() for c in grid_cells(positions, np.array([0, 1]), 2)] == [[0], [1], [], []]
    assert all(c.size == 0 for c in grid_cells(positions, np.array([], dtype=int), 3))


def test_a_pyramid_keeps_the_node_beside_its_cells():
    views = [make_view(seed=s) for s in range(3)]
    plain, pyramid = _fitted(views, colour=0.5), _fitted(views, colour=0.5, pyramid=2)
    assert pyramid.dim == plain.dim * 5
    local = pyramid.extract(views[0])
    members = [np.arange(len(local)), np.array([], dtype=int)]
    node, empty = pyramid.pool(local, members)
    base = plain.pool(local, members)[0]
    np.testing.assert_allclose(node[: plain.dim], np.sqrt(0.5) * base, atol=1e-6)
    assert np.linalg.norm(node) == pytest.approx(1.0, abs=1e-5)  # every cell of a full grid holds features
    np.testing.assert_array_equal(empty, 0)
    check_descriptor(pyramid)
    check_descriptor_in_all_orders(pyramid)


def test_a_pyramid_tells_apart_the_same_words_standing_elsewhere():
    views = [make_view(seed=s) for s in range(3)]
    plain, pyramid = _fitted(views), _fitted(views, pyramid=2)
    local = pyramid.extract(views[0])
    width = views[0].camera.width
    mirrored = LocalFeatures(positions=np.stack([width - 1 - local.positions[:, 0], local.positions[:, 1]], axis=1), descriptors=local.descriptors)
    everything = [np.arange(len(local))]

    def cosine(d, a, b):
        return float(d.pool(a, everything)[0] @ d.pool(b, everything)[0])

    assert cosine(plain, local, mirrored) == pytest.approx(1.0, abs=1e-6)  # a bag of words forgets where
    assert cosine(pyramid, local, local) == pytest.approx(1.0, abs=1e-6)
    assert cosine(pyramid, local, mirrored) < 0.99  # left and right swapped: the cells differ


def test_a_setting_added_since_leaves_the_keys_of_earlier_runs_alone():
    from ssga_bench.cache import stage_key
    from ssga_descriptor_dense_sift.plugin import DenseSift, DenseSiftConfig

    # The bench preset's dense SIFT, keyed as its runs were before `pyramid` existed (their cache folders).
    assert stage_key(DenseSift(DenseSiftConfig(colour=0.75))) == "descriptor-dense-sift-e8d578c4b07a"
    assert DenseSiftConfig().unkeyed() == {"pyramid", "pyramid_share"}
    assert DenseSiftConfig(pyramid=2).unkeyed() == {"pyramid_share"}
    assert stage_key(DenseSift(DenseSiftConfig(colour=0.75, pyramid=2))) != stage_key(DenseSift(DenseSiftConfig(colour=0.75)))
    with pytest.raises(ValidationError):
        DenseSiftConfig(pyramid=5)
