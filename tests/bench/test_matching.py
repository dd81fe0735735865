"""The nearest-graph classifier: whole image and parts matched part to part."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ssga_bench.matching import GraphMatcher
from ssga_core import InputError
from ssga_core.data import SceneGraph


def graph(*nodes, parts_boxes=None) -> SceneGraph:
    """A graph of the given node features (the whole image first) in a 100 x 50 image; its parts' boxes random by default."""
    features = np.asarray(nodes, dtype=np.float32)
    n = len(features)
    if parts_boxes is None:
        corner = np.random.default_rng(n).random((n - 1, 2)) * [80, 40]
        parts_boxes = np.concatenate([corner, corner + [20, 10]], axis=1)
    boxes = np.concatenate([[[0, 0, 100, 50]], np.reshape(parts_boxes, (n - 1, 4))]).astype(np.float32)
    return SceneGraph(boxes=boxes, features=features, weights=np.ones(n, np.float32), edges=np.zeros((0, 2), np.int64))


DIMS = 24
"""Feature length of the hand-built graphs below (axes to spare for near copies)."""


def near(i: int, cosine: float, spare: int) -> np.ndarray:
    """A unit vector at ``cosine`` to axis ``i``, the rest along the spare axis ``spare``."""
    e = np.eye(DIMS)
    return cosine * e[i] + np.sqrt(1 - cosine**2) * e[spare]


def unit(x):
    x = np.asarray(x, dtype=np.float64)
    return x / np.linalg.norm(x)


def centre(box) -> np.ndarray:
    """A part's box centre in a 100 x 50 image, in widths and heights."""
    return np.array([(box[0] + box[2]) / 200, (box[1] + box[3]) / 100])


def naive_similarity(
    query: SceneGraph, train: SceneGraph, whole_weight: float, layout_weight: float = 0.0, sigma: float = 0.3, category_penalty: float = 0.0
) -> float:
    """The docstring's rule, one pair at a time (with ``category_penalty``: parts matched within their category)."""
    whole = float(unit(query.features[0]) @ unit(train.features[0]))
    if query.num_parts == 0 or train.num_parts == 0:
        return whole

    def both_ways(query_side, train_side):
        return (query_side.max(axis=1).mean() + train_side.max(axis=0).mean()) / 2

    pairs = np.array([[unit(a) @ unit(b) for b in train.features[1:]] for a in query.features[1:]])
    nearness = np.array(
        [
            [np.exp(-np.sum((centre(a) - centre(b)) ** 2) / (2 * sigma**2)) for b in train.boxes[1:]]
            for a in query.boxes[1:]
        ]
    )
    q, t = across_categories(query, train, category_penalty)
    plain = both_ways(pairs - q, pairs - t)
    parts = (1 - layout_weight) * plain + layout_weight * both_ways(pairs * nearness - q, pairs * nearness - t)
    return whole_weight * whole + (1 - whole_weight) * parts


def across_categories(query: SceneGraph, train: SceneGraph, penalty: float) -> tuple[np.ndarray, np.ndarray]:
    """The penalty on each (query part, training part) pair of different categories, one pair at a time, for each
    query part's twin in the training graph (where that graph holds a part of its category) and for each training
    part's twin in the query (where the query holds one of its)."""
    q, t = np.zeros((query.num_parts, train.num_parts)), np.zeros((query.num_parts, train.num_parts))
    if query.categories is not None and train.categories is not None:
        in_train, in_query = set(train.categories[1:].tolist()), set(query.categories[1:].tolist())
        for i, a in enumerate(query.categories[1:]):
            for j, b in enumerate(train.categories[1:]):
                across = a >= 0 and b >= 0 and a != b
                q[i, j], t[i, j] = penalty * (across and a in in_train), penalty * (across and b in in_query)
    return q, t


def z(x):
    x = np.asarray(x, dtype=np.float64)
    return (x - x.mean()) / x.std()


def drawn_at(train: SceneGraph, box) -> float:
    """The share of ``train``'s image drawn in the block of its grid where ``box``'s centre stands (a real view: 1)."""
    if train.drawn is None:
        return 1.0
    u, v = centre(box)
    side = len(train.drawn)
    return float(train.drawn[min(int(v * side), side - 1), min(int(u * side), side - 1)])


def repeat_votes(g: SceneGraph, threshold: float | None, power: float) -> list[float]:
    """Each part's vote with repeated parts counted once: 1 / (its parts above ``threshold`` cosine, itself included) ** power."""
    parts = [unit(f) for f in g.features[1:]]
    if threshold is None:
        return [1.0] * len(parts)
    return [sum(float(a @ b) > threshold for b in parts) ** -power for a in parts]


def naive_standardised(
    query: SceneGraph,
    train: list[SceneGraph],
    whole_weight: float,
    layout_weight: float,
    judged_where_drawn: bool = False,
    prior: float = 0.0,
    burst: float | None = None,
    burst_power: float = 1.0,
    category_penalty: float = 0.0,
) -> np.ndarray:
    """Standardised parts, one pair at a time: each query part's best twins and the training parts' mean best twins
    standardised over the training graphs (with parts), then mixed as the plain rule mixes them; judged where drawn,
    each query part's standardised twin in a graph counts by the share of that graph drawn at the part's centre (plus
    ``prior`` parts' worth of the graph's plain mean of them), and each training part's best twin in the query by the
    share of its own graph drawn at its centre; with ``burst``, every part's count also by :func:`repeat_votes`."""
    whole = z([unit(query.features[0]) @ unit(t.features[0]) for t in train])
    with_parts = [i for i, t in enumerate(train) if t.num_parts]
    out = whole.copy()

    def both_ways(weighted: bool) -> np.ndarray:
        twins, means = [], []
        for i in with_parts:
            pairs = np.array([[unit(a) @ unit(b) for b in train[i].features[1:]] for a in query.features[1:]])
            if weighted:
                pairs = pairs * np.array(
                    [[np.exp(-np.sum((centre(a) - centre(b)) ** 2) / (2 * 0.3**2)) for b in train[i].boxes[1:]] for a in query.boxes[1:]]
                )
            q, t = across_categories(query, train[i], category_penalty)
            twins.append((pairs - q).max(axis=1))
            own = [drawn_at(train[i], box) if judged_where_drawn else 1.0 for box in train[i].boxes[1:]]
            own = np.multiply(own, repeat_votes(train[i], burst, burst_power))
            means.append(np.sum((pairs - t).max(axis=0) * own) / np.sum(own))
        per_part = np.array([z(row) for row in np.array(twins).T])  # (query parts, graphs with parts), standardised
        votes = np.array(repeat_votes(query, burst, burst_power))[:, None]
        plain = (votes * per_part).sum(axis=0) / votes.sum()
        counts = np.ones_like(per_part)
        if judged_where_drawn:
            counts = np.array([[drawn_at(train[g], box) for g in with_parts] for box in query.boxes[1:]])
        counts = counts * votes
        query_side = ((counts * per_part).sum(axis=0) + prior * plain) / (counts.sum(axis=0) + prior)
        return (query_side + z(means)) / 2

    parts = (1 - layout_weight) * both_ways(False) + layout_weight * both_ways(True)
    out[with_parts] = whole_weight * whole[with_parts] + (1 - whole_weight) * parts
    return out


@pytest.mark.parametrize(("whole_weight", "layout_weight"), [(0.0, 0.0), (0.3, 0.5)])
def test_standardised_parts_are_the_rule_written_out(whole_weight, layout_weight):
    rng = np.random.default_rng(5)
    train = [graph(*rng.random((1 + k, 6))) for k in (3, 0, 5, 1, 2, 4)]
    matcher = GraphMatcher.of(train, [0, 1, 1, 2, 0, 3], 4, whole_weight, layout_weight, standardise=True)
    for q in [graph(*rng.random((1 + k, 6))) for k in (4, 2, 0)]:
        expected = naive_standardised(q, train, whole_weight, layout_weight) if q.num_parts else z([unit(q.features[0]) @ unit(t.features[0]) for t in train])
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-4, atol=1e-4)


def repeating(rng: np.random.Generator, parts: int, dims: int = 6) -> SceneGraph:
    """A graph whose parts come in groups of near copies (cosines about 0.99 within a group), as a brick wall's do."""
    looks = rng.random((max(parts // 2, 1), dims))
    copies = looks[rng.integers(0, len(looks), parts)] + 0.02 * rng.random((parts, dims))
    return graph(rng.random(dims), *copies)


@pytest.mark.parametrize(("layout_weight", "prior", "burst", "burst_power"), [(0.0, 0.0, 0.95, 1.0), (0.5, 2.0, 0.95, 0.5), (0.5, 2.0, 0.9, 1.0)])
def test_repeated_parts_counted_once_are_the_rule_written_out(layout_weight, prior, burst, burst_power):
    rng = np.random.default_rng(11)
    train = [repeating(rng, k) for k in (3, 5, 4, 6, 2)] + [graph(rng.random(6))]
    grids = [rng.choice([0.0, 0.5, 1.0], size=(4, 4)).astype(np.float32) for _ in range(3)]
    train = [replace(t, drawn=d) for t, d in zip(train, [grids[0], None, grids[1], grids[2], None, None])]
    labels = [0, 1, 1, 2, 0, 3]
    matcher = GraphMatcher.of(train, labels, 4, 0.0, layout_weight, standardise=True, weigh_drawn=True, drawn_prior=prior, burst=burst, burst_power=burst_power)
    every_part = GraphMatcher.of(train, labels, 4, 0.0, layout_weight, standardise=True, weigh_drawn=True, drawn_prior=prior)
    for q in [repeating(rng, k) for k in (6, 4)]:
        expected = naive_standardised(q, train, 0.0, layout_weight, judged_where_drawn=True, prior=prior, burst=burst, burst_power=burst_power)
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-4, atol=1e-4)
        assert not np.allclose(matcher.similarities(q), every_part.similarities(q))
    # The `paper` preset's rule with parts matched within their category (categories 0-2, -1 unknown).
    named = [with_categories(t, *rng.integers(-1, 3, t.num_parts)) for t in train]
    within = GraphMatcher.of(
        named, labels, 4, 0.0, layout_weight, standardise=True, weigh_drawn=True, drawn_prior=prior, burst=burst, burst_power=burst_power, category_penalty=2.0
    )
    for q in [with_categories(g, *rng.integers(-1, 3, g.num_parts)) for g in (repeating(rng, 6), repeating(rng, 4))]:
        expected = naive_standardised(q, named, 0.0, layout_weight, True, prior, burst, burst_power, category_penalty=2.0)
        np.testing.assert_allclose(within.similarities(q), expected, rtol=1e-4, atol=1e-4)
        assert not np.allclose(within.similarities(q), matcher.similarities(q))
    # Parts that repeat nothing (no two above the threshold) vote as they did.
    distinct = [graph(*np.eye(6)[: 1 + k]) for k in (3, 5, 2)]
    q = graph(*np.eye(6)[[0, 2, 4, 5]])
    np.testing.assert_allclose(
        GraphMatcher.of(distinct, [0, 1, 2], 3, 0.0, standardise=True, burst=0.5).similarities(q),
        GraphMatcher.of(distinct, [0, 1, 2], 3, 0.0, standardise=True).similarities(q),
        rtol=1e-6,
    )


def test_a_wall_of_one_texture_does_not_outvote_the_part_that_tells_the_place():
    # The query sees a brick wall, cut into four near-identical parts, and a tiled floor. The true place has the same
    # wall and floor; a place elsewhere in the home has a brick wall too, more like the query's, and a floor half like
    # it. Every brick part votes for the second place; counted as one repeated element, the wall's four votes weigh
    # as one, and the floor decides.
    e = np.eye(DIMS)
    brick = [near(1, 0.995, 20 + k) for k in range(4)]  # the same texture, a little different in each part
    query = graph(e[0], *brick, e[2])
    true_place = graph(e[0], near(1, 0.8, 5), near(1, 0.8, 6), near(2, 0.9, 7))  # its wall seen in other light
    other_brick = graph(e[0], near(1, 0.97, 8), near(1, 0.97, 9), near(2, 0.5, 10))  # brick again, a floor half like it
    others = [graph(e[0], near(1, 0.5, 11 + k), near(2, 0.5, 15 + k)) for k in range(4)]
    train, labels = [true_place, other_brick, *others], list(range(6))
    every_part = GraphMatcher.of(train, labels, 6, 0.0, standardise=True)
    assert every_part.predict([query]).argmax() == 1
    counted_once = GraphMatcher.of(train, labels, 6, 0.0, standardise=True, burst=0.85)
    assert counted_once.predict([query]).argmax() == 0
    for bad in ({"burst": 1.5}, {"burst": 0.8, "burst_power": -1.0}):
        with pytest.raises(InputError, match="burst"):
            GraphMatcher.of(train, labels, 6, 0.0, standardise=True, **bad)


@pytest.mark.parametrize(("layout_weight", "prior"), [(0.0, 0.0), (0.5, 0.0), (0.5, 2.0)])
def test_parts_judged_where_drawn_are_the_rule_written_out(layout_weight, prior):
    rng = np.random.default_rng(7)
    train = [graph(*rng.random((1 + k, 6))) for k in (3, 0, 5, 1, 2, 4)]
    # Four pseudo-views drawn in random patches of a 4 x 4 grid (some of it holes), one real view (None: all seen).
    grids = [rng.choice([0.0, 0.25, 1.0], size=(4, 4)).astype(np.float32) for _ in range(4)] + [None]
    grids[0][:] = 1.0  # drawn everywhere: counts as a real view does
    train = [replace(t, drawn=d) for t, d in zip(train, [*grids[:2], None, *grids[2:]])]
    labels = [0, 1, 1, 2, 0, 3]
    matcher = GraphMatcher.of(train, labels, 4, 0.0, layout_weight, standardise=True, weigh_drawn=True, drawn_prior=prior)
    plain = GraphMatcher.of(train, labels, 4, 0.0, layout_weight, standardise=True)
    for q in [graph(*rng.random((1 + k, 6))) for k in (4, 2)]:
        expected = naive_standardised(q, train, 0.0, layout_weight, judged_where_drawn=True, prior=prior)
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-4, atol=1e-4)
        assert not np.allclose(matcher.similarities(q), plain.similarities(q))
    # Drawn everywhere, judging where drawn changes nothing.
    whole = [replace(t, drawn=np.ones((4, 4), np.float32)) for t in train]
    q = graph(*rng.random((4, 6)))
    np.testing.assert_allclose(
        GraphMatcher.of(whole, labels, 4, 0.0, layout_weight, standardise=True, weigh_drawn=True, drawn_prior=prior).similarities(q),
        plain.similarities(q),
        rtol=1e-5,
    )


def test_a_half_drawn_pseudo_view_is_judged_on_what_it_shows():
    # The query turned from the real view towards its neighbouring heading: the lamp the real view saw stands on its
    # left, a window the real view never saw on its right. The true class's pseudo-view, rendered from the real view,
    # has the lamp in place and a hole where the window is (its hole, described, looks like nothing). The real
    # view's class, rendered nearly whole, has a lamp and a window like them but not the same. Judged everywhere, the
    # hole costs the true class the window; judged where drawn, the window does not count against it.
    e = np.eye(DIMS)
    left, right = [5, 10, 45, 40], [55, 10, 95, 40]
    query = graph(e[0], e[1], e[2], parts_boxes=[left, right])
    hole = e[15]
    half_drawn = np.zeros((4, 4), np.float32)
    half_drawn[:, :2] = 1.0  # the left half drawn
    true_class = replace(graph(e[0], e[1], hole, parts_boxes=[left, right]), drawn=half_drawn)
    whole_render = graph(e[0], near(1, 0.6, 3), near(2, 0.6, 4), parts_boxes=[left, right])
    others = [graph(e[0], near(1, 0.3, 5 + k), near(2, 0.3, 9 + k), parts_boxes=[left, right]) for k in range(4)]
    train, labels = [true_class, whole_render, *others], list(range(6))
    everywhere = GraphMatcher.of(train, labels, 6, 0.0, standardise=True)
    assert everywhere.predict([query]).argmax() == 1
    where_drawn = GraphMatcher.of(train, labels, 6, 0.0, standardise=True, weigh_drawn=True)
    assert where_drawn.predict([query]).argmax() == 0


def test_a_prior_keeps_a_pseudo_view_drawn_under_one_part_from_winning_on_it_alone():
    # Far from its source views a pseudo-view is drawn in a sliver: under one of the query's four parts, where it matches
    # the query exactly; the rest is holes. Judged where drawn alone, that one part is its whole query side, and it
    # outscores the true class's render, which matches every part well but none exactly. A prior of one part's worth of
    # its plain mean (holes and all) weighs in what the sliver does not show.
    e = np.eye(DIMS)
    boxes = [[5, 10, 20, 40], [30, 10, 45, 40], [55, 10, 70, 40], [80, 10, 95, 40]]
    query = graph(*e[:5], parts_boxes=boxes)
    hole = e[23]
    first_quarter = np.zeros((4, 4), np.float32)
    first_quarter[:, 0] = 1.0
    sliver = replace(graph(e[0], e[1], hole, hole, hole, parts_boxes=boxes), drawn=first_quarter)
    true_class = graph(e[0], *(near(i, 0.9, 4 + i) for i in range(1, 5)), parts_boxes=boxes)
    others = [graph(e[0], near(1, 0.5, 9 + k), near(2, 0.5, 13 + k), near(3, 0.5, 17 + k), near(4, 0.4, 21), parts_boxes=boxes) for k in range(4)]
    train, labels = [true_class, sliver, *others], list(range(6))
    alone = GraphMatcher.of(train, labels, 6, 0.0, standardise=True, weigh_drawn=True)
    assert alone.predict([query]).argmax() == 1
    with_prior = GraphMatcher.of(train, labels, 6, 0.0, standardise=True, weigh_drawn=True, drawn_prior=1.0)
    assert with_prior.predict([query]).argmax() == 0
    # The true class is drawn everywhere: the prior leaves its score as it was.
    assert with_prior.similarities(query)[0] == pytest.approx(alone.similarities(query)[0], rel=1e-5)
    with pytest.raises(InputError, match="drawn_prior"):
        GraphMatcher.of(train, labels, 6, 0.0, standardise=True, weigh_drawn=True, drawn_prior=-1.0)


def test_standardised_parts_give_every_part_an_equal_say():
    # Three of the query's parts look a little more like place 0's than like any other's; one part (an accident of
    # segmentation) matches one part of place 1 exactly and no other place's at all. A plain mean follows the one
    # part whose similarities spread widest; standardised, the three that agree outvote it.
    e = np.eye(DIMS)
    query = graph(e[0], e[1], e[2], e[3], e[4])
    places = [graph(e[0], near(1, 0.9, 6), near(2, 0.9, 6), near(3, 0.9, 6))]
    places.append(graph(e[0], near(1, 0.8, 7), near(2, 0.8, 7), near(3, 0.8, 7), e[4]))
    places += [graph(e[0], near(1, 0.8, 8 + k), near(2, 0.8, 8 + k), near(3, 0.8, 8 + k)) for k in range(4)]
    labels = range(len(places))
    plain = GraphMatcher.of(places, labels, len(places), whole_weight=0.0)
    assert plain.predict([query]).argmax() == 1
    equal_say = GraphMatcher.of(places, labels, len(places), whole_weight=0.0, standardise=True)
    assert equal_say.predict([query]).argmax() == 0


@pytest.mark.parametrize(("whole_weight", "layout_weight", "sigma"), [(0.3, 0.0, 0.3), (0.3, 0.5, 0.3), (0.0, 1.0, 0.1)])
def test_similarities_are_the_rule_written_out(whole_weight, layout_weight, sigma):
    rng = np.random.default_rng(3)
    train = [graph(*rng.random((1 + k, 6))) for k in (3, 0, 5, 1, 2)]
    queries = [graph(*rng.random((1 + k, 6))) for k in (4, 0, 2)]
    matcher = GraphMatcher.of(train, [0, 1, 1, 2, 0], 4, whole_weight, layout_weight, sigma)
    for q in queries:
        expected = [naive_similarity(q, t, whole_weight, layout_weight, sigma) for t in train]
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-5, atol=1e-6)
    # A class scores its best training graph; a class without one scores below every other.
    sims = matcher.class_similarities(queries)
    every = np.stack([matcher.similarities(q) for q in queries])
    np.testing.assert_allclose(sims[:, 0], every[:, [0, 4]].max(axis=1), rtol=1e-6)
    np.testing.assert_allclose(sims[:, 1], every[:, [1, 2]].max(axis=1), rtol=1e-6)
    assert (sims[:, 3] < sims[:, :3].min(axis=1)).all()
    probs = matcher.predict(queries)
    np.testing.assert_allclose(probs.sum(axis=1), 1.0, rtol=1e-5)
    assert (probs.argmax(axis=1) == sims.argmax(axis=1)).all()


def with_categories(g: SceneGraph, *categories: int) -> SceneGraph:
    return replace(g, categories=np.array([-1, *categories], np.int32))


@pytest.mark.parametrize(("layout_weight", "penalty"), [(0.0, 0.25), (0.5, 2.0)])
def test_parts_matched_within_their_category_are_the_rule_written_out(layout_weight, penalty):
    rng = np.random.default_rng(5)
    # Categories 0-2, -1 unknown; one training graph and one query name none (a parser of superpixels).
    train = [with_categories(graph(*rng.random((1 + k, 6))), *rng.integers(-1, 3, k)) for k in (3, 4, 2)]
    train += [graph(*rng.random((3, 6))), with_categories(graph(rng.random(6)))]
    queries = [with_categories(graph(*rng.random((1 + k, 6))), *rng.integers(-1, 3, k)) for k in (4, 2)] + [graph(*rng.random((3, 6)))]
    matcher = GraphMatcher.of(train, [0, 1, 2, 0, 1], 3, 0.3, layout_weight, category_penalty=penalty)
    for q in queries:
        expected = [naive_similarity(q, t, 0.3, layout_weight, category_penalty=penalty) for t in train]
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-5, atol=1e-6)
    assert not np.allclose(matcher.similarities(queries[0]), GraphMatcher.of(train, [0, 1, 2, 0, 1], 3, 0.3, layout_weight).similarities(queries[0]))
    again = GraphMatcher.from_state(matcher.state_dict())
    assert again.category_penalty == penalty
    np.testing.assert_array_equal(again.predict(queries), matcher.predict(queries))
    # Without a penalty nothing of it is saved; a state saved before it existed matched whatever the category.
    plain = GraphMatcher.of(train, [0, 1, 2, 0, 1], 3, 0.3, layout_weight).state_dict()
    assert "categories" not in plain and "category_penalty" not in plain
    older = GraphMatcher.from_state({k: v for k, v in matcher.state_dict().items() if not k.startswith("categor")})
    assert older.category_penalty == 0.0
    with pytest.raises(InputError, match="a category for each of the"):
        GraphMatcher.from_state({**matcher.state_dict(), "categories": matcher.categories[:-1]})
    with pytest.raises(InputError, match="category_penalty is a cosine to subtract"):
        GraphMatcher.of(train, [0, 1, 2, 0, 1], 3, 0.3, category_penalty=-1.0)


def with_scores(g: SceneGraph, rng: np.random.Generator) -> SceneGraph:
    if g.categories is None:
        return g
    return replace(g, category_scores=np.concatenate([[np.nan], rng.random(g.num_parts)]).astype(np.float32))


def unsure_unnamed(g: SceneGraph, min_score: float) -> SceneGraph:
    """``g`` with the categories scored below ``min_score`` named -1, written out part by part."""
    if g.categories is None or g.category_scores is None:
        return g
    named = [c if k > 0 and g.category_scores[k] >= min_score else -1 for k, c in enumerate(g.categories.tolist())]
    return replace(g, categories=np.array(named, np.int32), category_scores=None)


def test_only_the_categories_the_parser_is_sure_of_keep_parts_to_their_category():
    rng = np.random.default_rng(8)
    train = [with_categories(graph(*rng.random((1 + k, 6))), *rng.integers(0, 3, k)) for k in (3, 4, 2, 5)]
    train = [with_scores(g, rng) for g in train[:3]] + [train[3]]  # the last: a parser without scores (ground truth)
    queries = [with_scores(with_categories(graph(*rng.random((1 + k, 6))), *rng.integers(0, 3, k)), rng) for k in (4, 3)]
    queries.append(with_categories(graph(*rng.random((4, 6))), 0, 1, 2))  # no scores: every category counts
    labels = [0, 1, 2, 0]
    matcher = GraphMatcher.of(train, labels, 3, 0.3, 0.5, category_penalty=2.0, category_min_score=0.5)
    sure = [unsure_unnamed(g, 0.5) for g in train]
    assert any((a.categories != b.categories).any() for a, b in zip(train, sure, strict=True))
    for q in queries:
        expected = [naive_similarity(unsure_unnamed(q, 0.5), t, 0.3, 0.5, category_penalty=2.0) for t in sure]
        np.testing.assert_allclose(matcher.similarities(q), expected, rtol=1e-5, atol=1e-6)
    # Every category counts at 0, and the scores change nothing without a penalty.
    every = GraphMatcher.of(train, labels, 3, 0.3, 0.5, category_penalty=2.0)
    assert not np.allclose(every.similarities(queries[0]), matcher.similarities(queries[0]))
    np.testing.assert_allclose(every.similarities(queries[0]), [naive_similarity(queries[0], t, 0.3, 0.5, category_penalty=2.0) for t in train], rtol=1e-5, atol=1e-6)
    off = GraphMatcher.of(train, labels, 3, 0.3, 0.5, category_min_score=0.5)
    assert off.category_min_score == 0.0 and "category_min_score" not in off.state_dict()
    np.testing.assert_array_equal(off.predict(queries), GraphMatcher.of(train, labels, 3, 0.3, 0.5).predict(queries))
    # Saved and read back, the query's categories are judged by the same score; a state from before it: every one counts.
    again = GraphMatcher.from_state(matcher.state_dict())
    assert again.category_min_score == 0.5
    np.testing.assert_array_equal(again.predict(queries), matcher.predict(queries))
    older = GraphMatcher.from_state({k: v for k, v in every.state_dict().items() if k != "category_min_score"})
    np.testing.assert_array_equal(older.predict(queries), every.predict(queries))
    with pytest.raises(InputError, match="category_min_score is a parser's score"):
        GraphMatcher.of(train, labels, 3, 0.3, category_penalty=2.0, category_min_score=1.5)


def test_a_part_of_another_category_is_no_twin_where_the_graph_holds_one_of_its_own():
    # The query's wall has the texture of place 0's floor; place 0's wall looks otherwise, place 1's a
    # little different. Matched whatever the category, the floor passes for the wall and place 0 wins.
    whole, texture, door, plain = [1, 1, 1, 1, 0], [0, 0, 1, 0, 0], [0, 0, 0, 1, 0], [0, 0, 0, 0, 1]
    wall, floor, doorway = 0, 1, 2
    place0 = with_categories(graph(whole, texture, door, plain), floor, doorway, wall)
    place1 = with_categories(graph(whole, [0, 0.5, 1, 0, 0], door, plain), wall, doorway, floor)
    query = with_categories(graph(whole, texture, door), wall, doorway)
    anywhere = GraphMatcher.of([place0, place1], [0, 1], 2, whole_weight=0.0)
    assert anywhere.predict([query]).argmax() == 0
    within = GraphMatcher.of([place0, place1], [0, 1], 2, whole_weight=0.0, category_penalty=2.0)
    assert within.predict([query]).argmax() == 1
    # A graph that holds no wall is judged on its parts' looks, as without the penalty: its floor is the twin.
    no_wall = with_categories(graph(whole, texture, door), floor, doorway)
    lone = GraphMatcher.of([no_wall], [0], 1, whole_weight=0.0, category_penalty=2.0)
    assert lone.similarities(query)[0] == pytest.approx(GraphMatcher.of([no_wall], [0], 1, whole_weight=0.0).similarities(query)[0])


def test_parts_decide_where_the_whole_images_tie():
    # Two places whose whole images look alike; their parts differ (a bed, a desk).
    whole, bed, desk, wall = [1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1], [1, 0, 0, 0]
    matcher = GraphMatcher.of([graph(whole, bed, wall), graph(whole, desk, wall)], [0, 1], num_classes=2, whole_weight=0.5)
    seen_bed = graph([1, 1, 0.1, 0], bed)  # a new view: the bed is still in it, the wall left the frame
    assert matcher.predict([seen_bed]).argmax() == 0
    whole_only = GraphMatcher.of([graph(whole, bed, wall), graph(whole, desk, wall)], [0, 1], num_classes=2, whole_weight=1.0)
    sims = whole_only.class_similarities([seen_bed])[0]
    assert sims[0] == pytest.approx(sims[1])  # the whole image alone cannot tell them apart


def test_parts_in_place_tell_apart_views_that_hold_the_same_things_elsewhere():
    # Two headings of one corner see the same lamp and door, swapped left and right (the camera turned).
    whole, lamp, door = [1, 1, 1, 1], [0, 0, 1, 0], [0, 0, 0, 1]
    left, right = [5, 10, 35, 40], [65, 10, 95, 40]
    lamp_left = graph(whole, lamp, door, parts_boxes=[left, right])
    lamp_right = graph(whole, lamp, door, parts_boxes=[right, left])
    query = graph([1, 1, 0.9, 1], lamp, door, parts_boxes=[[10, 10, 40, 40], [60, 10, 90, 40]])  # the lamp on the left
    anywhere = GraphMatcher.of([lamp_left, lamp_right], [0, 1], 2, whole_weight=0.0)
    sims = anywhere.class_similarities([query])[0]
    assert sims[0] == pytest.approx(sims[1])  # matched wherever they stand, the parts cannot tell the headings apart
    in_place = GraphMatcher.of([lamp_left, lamp_right], [0, 1], 2, whole_weight=0.0, layout_weight=0.5)
    assert in_place.predict([query]).argmax() == 0
    sims = in_place.class_similarities([query])[0]
    assert sims[0] > sims[1] + 0.1


def test_the_saved_state_scores_the_same_and_a_broken_one_is_refused():
    rng = np.random.default_rng(0)
    train = [graph(*rng.random((1 + k, 5))) for k in (2, 3, 0)]
    matcher = GraphMatcher.of(train, [2, 0, 1], 3, whole_weight=0.25, layout_weight=0.5, layout_sigma=0.2)
    query = [graph(*rng.random((4, 5)))]
    again = GraphMatcher.from_state(matcher.state_dict())
    np.testing.assert_array_equal(again.predict(query), matcher.predict(query))
    standardised = GraphMatcher.of(train, [2, 0, 1], 3, whole_weight=0.25, layout_weight=0.5, standardise=True)
    again = GraphMatcher.from_state(standardised.state_dict())
    assert again.standardise
    np.testing.assert_array_equal(again.predict(query), standardised.predict(query))
    drawn = [replace(t, drawn=np.full((2, 2), 0.5 + 0.25 * k, np.float32)) for k, t in enumerate(train)]
    judged = GraphMatcher.of(drawn, [2, 0, 1], 3, whole_weight=0.0, layout_weight=0.5, standardise=True, weigh_drawn=True, drawn_prior=2.0)
    again = GraphMatcher.from_state(judged.state_dict())
    np.testing.assert_array_equal(again.drawn, judged.drawn)
    assert again.drawn_prior == 2.0
    np.testing.assert_array_equal(again.predict(query), judged.predict(query))
    # A state saved before the prior existed weighed by what was drawn alone.
    assert GraphMatcher.from_state({k: v for k, v in judged.state_dict().items() if k != "drawn_prior"}).drawn_prior == 0.0
    once = GraphMatcher.of(drawn, [2, 0, 1], 3, whole_weight=0.0, standardise=True, weigh_drawn=True, burst=0.3, burst_power=0.5)
    again = GraphMatcher.from_state(once.state_dict())
    assert (again.burst, again.burst_power) == (pytest.approx(0.3), 0.5)
    np.testing.assert_array_equal(again.predict(query), once.predict(query))
    # A state saved before repeated parts were counted once let every part vote.
    assert GraphMatcher.from_state({k: v for k, v in once.state_dict().items() if not k.startswith("burst")}).burst is None
    with pytest.raises(InputError, match="drawn grids"):
        GraphMatcher.from_state({**judged.state_dict(), "drawn": judged.drawn[:2]})
    state = matcher.state_dict()
    assert "drawn" not in state  # not judged where drawn: nothing of it saved
    # A state saved before standardised parts existed matched without them.
    older = GraphMatcher.from_state({k: v for k, v in state.items() if k != "standardise"})
    np.testing.assert_array_equal(older.predict(query), matcher.predict(query))
    for field in ("node_ptr", "centres", "layout_weight"):
        with pytest.raises(InputError, match=f"saved state without '{field}'"):
            GraphMatcher.from_state({k: v for k, v in state.items() if k != field})
    with pytest.raises(InputError, match="do not fit together"):
        GraphMatcher.from_state({**state, "centres": state["centres"][:-1]})
    with pytest.raises(InputError, match="do not fit together"):
        GraphMatcher.from_state({**state, "node_ptr": state["node_ptr"][:-1]})
    with pytest.raises(InputError, match="classes in 0..2"):
        GraphMatcher.from_state({**state, "labels": np.array([0, 1, 5])})


def whole_only(features: np.ndarray) -> list[SceneGraph]:
    return [graph(f) for f in features]


def test_the_whole_image_whitened_is_the_rule_written_out():
    rng = np.random.default_rng(3)
    labels = np.repeat([0, 1, 2, 3], 6)
    features = rng.normal(size=(len(labels), 8)) + 3 * rng.normal(size=(4, 8))[labels]
    matcher = GraphMatcher.of(whole_only(features), labels, 4, whole_weight=1.0, whiten=0.5)
    x = features / np.linalg.norm(features, axis=1, keepdims=True)
    deviations = x - np.stack([x[labels == c].mean(0) for c in range(4)])[labels]
    within = deviations.T @ deviations / len(x)
    shrunk = within + 0.5 * np.trace(within) / 8 * np.eye(8)
    # Whitened by the shrunk within-class covariance: (x - mean) W has that covariance's inverse for its Gram matrix.
    mean, matrix = matcher._whitening
    np.testing.assert_allclose(matrix @ matrix.T, np.linalg.inv(shrunk), rtol=1e-3, atol=1e-3)
    query = rng.normal(size=8)
    inverse_root = np.linalg.cholesky(np.linalg.inv(shrunk))  # any W with W W^T = inv(shrunk) gives the same cosines
    a = (unit(query) - x.mean(0)) @ inverse_root
    b = (x - x.mean(0)) @ inverse_root
    expected = b @ a / np.linalg.norm(b, axis=1) / np.linalg.norm(a)
    np.testing.assert_allclose(matcher.similarities(graph(query)), expected, atol=1e-5)


def test_whitening_turns_down_what_varies_among_one_places_graphs():
    # Two places told apart by a faint trait (axes 0 / 1); their pseudo-views vary widely along axes 2-3 (what synthesis
    # guessed). A query of place 0 that shares a place-1 pseudo-view's guess looks most like that view to a plain cosine.
    rng = np.random.default_rng(0)
    labels = np.repeat([0, 1], 20)
    trait = np.where(labels[:, None] == 0, [1.0, 0.0], [0.0, 1.0])
    guess = rng.normal(size=(40, 2)) * 3
    features = np.concatenate([trait, guess, np.full((40, 1), 2.0)], axis=1)
    query = graph(np.concatenate([[1.0, 0.0], guess[25] + 0.1, [2.0]]))
    plain = GraphMatcher.of(whole_only(features), labels, 2, whole_weight=1.0)
    whitened = GraphMatcher.of(whole_only(features), labels, 2, whole_weight=1.0, whiten=0.1)
    assert plain.predict([query]).argmax() == 1
    assert whitened.predict([query]).argmax() == 0


def test_whitening_needs_two_graphs_of_a_class_and_a_shrinkage_above_zero():
    rng = np.random.default_rng(1)
    train = whole_only(rng.normal(size=(3, 5)))
    query = [graph(rng.normal(size=5))]
    one_each = GraphMatcher.of(train, [0, 1, 2], 3, whole_weight=1.0, whiten=1.0)
    np.testing.assert_array_equal(one_each.predict(query), GraphMatcher.of(train, [0, 1, 2], 3, whole_weight=1.0).predict(query))
    for shrink in (0.0, -1.0, float("nan")):
        with pytest.raises(InputError, match="whiten is a shrinkage"):
            GraphMatcher.of(train, [0, 1, 2], 3, whole_weight=1.0, whiten=shrink)


def test_a_whitened_matcher_saves_its_shrinkage_and_scores_the_same():
    rng = np.random.default_rng(2)
    train = [graph(*rng.random((1 + k % 3, 5))) for k in range(9)]
    labels = [k % 3 for k in range(9)]
    matcher = GraphMatcher.of(train, labels, 3, whole_weight=0.5, whiten=2.0)
    query = [graph(*rng.random((3, 5)))]
    again = GraphMatcher.from_state(matcher.state_dict())
    assert again.whiten == 2.0
    np.testing.assert_allclose(again.predict(query), matcher.predict(query), rtol=1e-6)
    plain = GraphMatcher.of(train, labels, 3, whole_weight=0.5)
    assert "whiten" not in plain.state_dict()  # a state saved before whitening existed (or without it) is plain
    assert GraphMatcher.from_state(plain.state_dict()).whiten is None
    assert not np.allclose(matcher.predict(query), plain.predict(query))


def test_whitened_parts_are_the_plain_part_match_of_the_whitened_parts():
    rng = np.random.default_rng(4)
    labels = [k % 3 for k in range(12)]
    train = [graph(*rng.normal(size=(2 + k % 3, 6))) for k in range(12)]
    query = graph(*rng.normal(size=(4, 6)))
    matcher = GraphMatcher.of(train, labels, 3, whole_weight=0.0, layout_weight=0.5, whiten=1.0, whiten_parts=True)
    mean, matrix = matcher._whitening
    parts = np.concatenate([unit_rows(g.features[1:]) for g in train])

    def moved(g):  # each part less the training parts' mean, whitened; the whole image as it was
        return replace(g, features=np.concatenate([g.features[:1], (unit_rows(g.features[1:]) - parts.mean(0)) @ matrix]).astype(np.float32))

    by_hand = GraphMatcher.of([moved(g) for g in train], labels, 3, whole_weight=0.0, layout_weight=0.5)
    np.testing.assert_allclose(matcher.similarities(query), by_hand.similarities(moved(query)), atol=1e-5)
    whole_only_whitened = GraphMatcher.of(train, labels, 3, whole_weight=0.0, layout_weight=0.5, whiten=1.0)
    assert not np.allclose(matcher.similarities(query), whole_only_whitened.similarities(query))
    again = GraphMatcher.from_state(matcher.state_dict())
    assert again.whiten_parts
    np.testing.assert_allclose(again.predict([query]), matcher.predict([query]), rtol=1e-6)



def test_parts_in_groups_are_whitened_by_their_scatter_within_their_groups():
    rng = np.random.default_rng(5)
    labels = [k % 3 for k in range(12)]
    train = [graph(*rng.normal(size=(2 + k % 3, 6))) for k in range(12)]
    parts = np.concatenate([unit_rows(g.features[1:]) for g in train])
    groups = rng.integers(0, 6, size=len(parts))
    groups[:3] = -1  # parts of no real part: compared, but not fitted on
    query = graph(*rng.normal(size=(4, 6)))
    matcher = GraphMatcher.of(train, labels, 3, 0.0, 0.5, whiten=1.0, whiten_parts=True, part_groups=groups)
    # The rule written out: the grouped parts' scatter about their group's mean, shrunk by its mean eigenvalue.
    x = parts[groups >= 0]
    g = groups[groups >= 0]
    deviations = x - np.stack([x[g == k].mean(0) for k in range(6)])[g]
    within = deviations.T @ deviations / len(x)
    shrunk = within + np.trace(within) / 6 * np.eye(6)
    inverse_root = np.linalg.cholesky(np.linalg.inv(shrunk))

    def moved(graph_):  # each part less the grouped parts' mean, whitened; the whole image as it was
        whitened = (unit_rows(graph_.features[1:]) - x.mean(0)) @ inverse_root
        return replace(graph_, features=np.concatenate([graph_.features[:1], whitened]).astype(np.float32))

    by_hand = GraphMatcher.of([moved(t) for t in train], labels, 3, 0.0, 0.5)
    np.testing.assert_allclose(matcher.similarities(query), by_hand.similarities(moved(query)), atol=1e-5)
    whole_space = GraphMatcher.of(train, labels, 3, 0.0, 0.5, whiten=1.0, whiten_parts=True)
    assert not np.allclose(matcher.similarities(query), whole_space.similarities(query))
    again = GraphMatcher.from_state(matcher.state_dict())
    np.testing.assert_array_equal(again.part_groups, groups)
    np.testing.assert_allclose(again.predict([query]), matcher.predict([query]), rtol=1e-6)
    # Groups given without whitening the parts change nothing; a group per part is asked for.
    np.testing.assert_array_equal(
        GraphMatcher.of(train, labels, 3, 0.0, 0.5, whiten=1.0, part_groups=groups).similarities(query),
        GraphMatcher.of(train, labels, 3, 0.0, 0.5, whiten=1.0).similarities(query),
    )
    with pytest.raises(InputError, match="a group for each of the"):
        GraphMatcher.of(train, labels, 3, 0.0, 0.5, whiten=1.0, whiten_parts=True, part_groups=groups[:-1])


def test_whitening_a_part_by_its_group_turns_down_what_synthesis_varied_in_it():
    # Two places whose one part each is told apart by a faint trait (axes 0 / 1); each pseudo-view carries the part with
    # a wide guess along axes 2-3. The whole images are alike, so whitened on them the parts gain nothing; a query part
    # of place 0 that shares a place-1 pseudo-view's guess looks most like that view's part until its group says the
    # guess is what varies in one part.
    rng = np.random.default_rng(0)
    labels = np.repeat([0, 1], 20)
    trait = np.where(labels[:, None] == 0, [1.0, 0.0], [0.0, 1.0])
    guess = rng.normal(size=(40, 2)) * 3
    parts = np.concatenate([trait, guess, np.full((40, 1), 2.0)], axis=1)
    whole = np.tile([0.0, 0.0, 0.0, 0.0, 1.0], (40, 1)) + rng.normal(size=(40, 5)) * 0.01
    train = [graph(w, p, parts_boxes=[40, 20, 60, 30]) for w, p in zip(whole, parts)]
    query = graph(whole[0], np.concatenate([[1.0, 0.0], guess[25] + 0.1, [2.0]]), parts_boxes=[40, 20, 60, 30])
    whole_space = GraphMatcher.of(train, labels, 2, 0.0, whiten=0.1, whiten_parts=True)
    grouped = GraphMatcher.of(train, labels, 2, 0.0, whiten=0.1, whiten_parts=True, part_groups=labels)
    assert whole_space.predict([query]).argmax() == 1
    assert grouped.predict([query]).argmax() == 0


def unit_rows(x):
    x = np.asarray(x, np.float64)
    return x / np.linalg.norm(x, axis=1, keepdims=True)
