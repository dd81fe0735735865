"""Contract checks for stage implementations: call them from your plugin's tests.

Each check runs the stage on real inputs and asserts what every implementation of
its kind must guarantee; the ``*_in_all_orders`` checks run it in every variant order
it can take part in, with stand-in stages for the others.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ssga_core.data import Data, SceneGraph, View
from ssga_core.geometry import Pose
from ssga_core.pipeline import BoundVariant, build_graph
from ssga_core.stages import Descriptor, Fuser, LocalDescriptor, Parser, RegionDescriptor, Synthesizer
from ssga_core.testing.stages import PatchColour, ShiftWarp, StripesParser
from ssga_core.testing.views import make_view
from ssga_core.variants import all_orders, check_binding, parse_variant

def _target(view: View, metres: float = 0.3) -> Pose:
    """A pose ``metres`` to the right of ``view``'s camera, same heading."""
    right = view.pose.rotation()[:, 0]
    return Pose(view.pose.x + metres * right[0], view.pose.y + metres * right[1], view.pose.yaw, view.pose.height)


def check_parser(parser: Parser, view: View | None = None) -> None:
    """Regions cover the image with in-range labels, boxes hold their masks, parsing is deterministic."""
    view = view or make_view()
    regions = parser.parse(view)
    assert len(regions) >= 1, f"{parser.name}: no region"
    labels = regions.labels
    assert labels.shape == view.camera.shape
    present = np.unique(labels[labels >= 0])
    assert present.size and present.max() < len(regions), f"{parser.name}: labels out of range"
    v, u = np.nonzero(labels >= 0)
    k = labels[v, u]
    b = regions.boxes[k]
    inside = (u >= b[:, 0] - 1) & (u <= b[:, 2] + 1) & (v >= b[:, 1] - 1) & (v <= b[:, 3] + 1)
    assert inside.all(), f"{parser.name}: {int((~inside).sum())} region pixels lie outside their boxes"
    again = parser.parse(view)
    np.testing.assert_array_equal(again.labels, labels, err_msg=f"{parser.name}: parsing is not deterministic")


def check_descriptor(descriptor: Descriptor, views: Sequence[View] | None = None) -> None:
    """Fitting works, features have ``dim`` columns, are finite and deterministic."""
    views = list(views or [make_view(seed=s) for s in range(3)])
    descriptor.fit(views)
    view = views[0]
    if isinstance(descriptor, LocalDescriptor):
        local = descriptor.extract(view)
        assert len(local) > 0, f"{descriptor.name}: no local feature"
        assert view.camera.contains(local.positions).all(), f"{descriptor.name}: local features outside the image"
        members = [np.arange(len(local)), np.arange(len(local) // 2), np.array([], dtype=int)]
        pooled = descriptor.pool(local, members)
        again = descriptor.pool(descriptor.extract(view), members)
    else:
        assert isinstance(descriptor, RegionDescriptor)
        regions = StripesParser().parse(view)
        pooled = descriptor.describe(view, regions)
        again = descriptor.describe(view, regions)
    assert pooled.shape[1] == descriptor.dim and np.isfinite(pooled).all(), f"{descriptor.name}: bad features"
    np.testing.assert_allclose(again, pooled, err_msg=f"{descriptor.name}: description is not deterministic")


def check_synthesizer(synthesizer: Synthesizer, view: View | None = None) -> None:
    """At its own pose a view maps onto itself; moving right shifts the content left."""
    view = view or make_view()
    same = synthesizer.synthesize(view, view.pose)
    grid = view.camera.pixel_grid()
    vis = same.visible
    assert vis.mean() > 0.9, f"{synthesizer.name}: only {vis.mean():.0%} of pixels visible from the same pose"
    err = np.abs(same.target_uv[vis] - grid[vis]).max()
    assert err <= 0.5, f"{synthesizer.name}: the same pose moves pixels by up to {err:.2f} px"
    assert same.view.synthetic and same.view.pose == view.pose
    diff = np.abs(same.view.rgb.astype(int) - view.rgb.astype(int)).mean()
    assert diff < 20, f"{synthesizer.name}: re-rendering at the same pose changes colours by {diff:.1f} on average"
    moved = synthesizer.synthesize(view, _target(view))
    shift = np.nanmedian(moved.target_uv[..., 0] - grid[..., 0])
    assert shift < -1, f"{synthesizer.name}: moving the camera right should move the image content left (median shift {shift:.2f} px)"
    p = view.pose
    turned = synthesizer.synthesize(view, Pose(p.x, p.y, p.yaw + 0.2, p.height))
    shift = np.nanmedian(turned.target_uv[..., 0] - grid[..., 0])
    assert shift > 1, f"{synthesizer.name}: turning left (yaw + 0.2 rad) should move the image content right (median shift {shift:.2f} px)"


def check_fuser(fuser: Fuser, seed: int = 0) -> None:
    """One variant keeps its own ranking; the order of the variants does not matter.

    A fuser that :attr:`~Fuser.learns` is first fitted on the same variants, in the same
    order, with true classes its members mostly agree on.
    """
    rng = np.random.default_rng(seed)
    scores = rng.random((4, 30, 12))
    scores /= scores.sum(axis=-1, keepdims=True)  # probabilities, as variants give them
    truth = np.where(rng.random(30) < 0.7, scores.mean(axis=0).argmax(axis=1), rng.integers(0, 12, 30))

    def fused(members: np.ndarray) -> np.ndarray:
        if fuser.learns:
            fuser.fit(members, truth)
        return fuser.fuse(members)

    one = fused(scores[:1])
    assert one.shape == (30, 12)
    np.testing.assert_array_equal(np.argsort(-one, axis=1, kind="stable"), np.argsort(-scores[0], axis=1, kind="stable"))
    np.testing.assert_allclose(fused(scores[::-1]), fused(scores), rtol=1e-5, atol=1e-8)


def _check_graph(graph: SceneGraph, dim: int, order: str) -> None:
    assert graph.features.shape[1] == dim, order
    assert graph.weights[SceneGraph.WHOLE_IMAGE] == 1.0, order
    if graph.num_parts:
        np.testing.assert_allclose(graph.weights[1:], 1.0 / graph.num_parts, err_msg=order)
        # The whole image's box overlaps every part, so it is joined to all of them.
        assert {tuple(e) for e in graph.edges if e[0] == 0} == {(0, k) for k in range(1, graph.num_nodes)}, order
    assert np.isfinite(graph.features).all(), order


def _run_orders(parser: Parser, descriptor: Descriptor, synthesizer: Synthesizer, view: View) -> list[str]:
    ran = []
    stages = {stage.kind: stage for stage in (parser, descriptor, synthesizer)}
    descriptor.fit([view])
    for order in all_orders():
        variant = parse_variant(order)
        used = {kind: stages[kind] for kind in variant.kinds()}
        if check_binding(variant, {kind: type(stage) for kind, stage in used.items()}, view.available):
            continue
        bound = BoundVariant(variant, **used)  # type: ignore[arg-type]
        _check_graph(build_graph(bound, view), descriptor.dim, order)
        if variant.synthesizes:
            _check_graph(build_graph(bound, view, _target(view)), descriptor.dim, order)
        ran.append(order)
    return ran


def check_parser_in_all_orders(parser: Parser, view: View | None = None) -> list[str]:
    """Build graphs with ``parser`` in every order that parses; returns the orders run."""
    ran = _run_orders(parser, PatchColour(), ShiftWarp(), view or make_view())
    assert {"PD", "PDS", "PSD", "SPD", "DSP"} <= set(ran), ran
    return ran


def check_descriptor_in_all_orders(descriptor: Descriptor, view: View | None = None) -> list[str]:
    """Build graphs with ``descriptor`` in every order its kind allows; returns the orders run."""
    ran = _run_orders(StripesParser(), descriptor, ShiftWarp(), view or make_view())
    expected = set(all_orders()) if Data.LOCAL_FEATURES in descriptor.produces else {"D", "PD", "SD", "PSD", "SPD"}
    assert expected <= set(ran), sorted(expected - set(ran))
    return ran


def check_synthesizer_in_all_orders(synthesizer: Synthesizer, view: View | None = None) -> list[str]:
    """Build graphs with ``synthesizer`` in every order that synthesizes; returns the orders run."""
    ran = _run_orders(StripesParser(), PatchColour(), synthesizer, view or make_view())
    assert {o for o in all_orders() if "S" in o} <= set(ran), ran
    return ran
