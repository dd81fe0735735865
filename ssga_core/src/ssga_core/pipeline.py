"""What each variant order does: the pipeline semantics, written once for every plugin.

A variant's letters run left to right over one *state*: the current image, and what
has been parsed and described of it so far.

* **P** parses the current image into regions (part nodes).
* **D** describes the current image. A :class:`~ssga_core.LocalDescriptor` extracts
  local features at pixel positions, pooled into node features at the end; a
  :class:`~ssga_core.RegionDescriptor` describes the whole image and the regions
  parsed so far (so it must come after P, or without P).
* **S** renders the current image at the target pose and carries everything across
  with the synthesizer's point map:

  - regions: each part's centroid and box corners are mapped (paper §3.2) and the new
    box is their bounding box, clipped to the image; the label map is forward-warped.
    A part survives if its centroid lands inside the new image and some of its pixels
    stay visible;
  - local features: positions are mapped; features that are occluded or leave the
    image are dropped. If regions were parsed before S, each feature keeps the node
    it belonged to in the real image;
  - semantic/instance ids of the real view are warped too, so ground-truth parsers
    can parse synthetic views;
  - what S drew where no source's part landed (a room's walls that no real view saw,
    filled in by the synthesizer) belongs to no part: the paper's reading. With
    ``parse_invented``, an order that parses before S and describes after it (PSD,
    ``Variant.describes_carried_parts``) parses the synthetic view too and adds, as parts,
    its regions that lie at least half in those pixels (cut to them); the carried parts
    stay as they were. With ``describe_invented``, an order that describes before S (PDS,
    DSP, DS, ``Variant.describes_before_synthesis``) also describes the synthetic view where
    no source pixel landed (its local features there join the carried ones); PDS, whose
    parts are fixed before S, first parses those pixels into parts of their own as above.
    The carried features and parts stay as the real view gave them.
  - parts that S split: the real view's frame ends where the synthetic view goes on, so a
    wall the query sees as one part arrives as a carried piece beside what S drew. With
    ``join_split_parts``, an order that parses before S (PDS, PSD, ``Variant.carries_parts``)
    with a parser whose regions are connected pieces of one category
    (``Parser.regions_are_category_pieces``) joins the parts of one category that touch in
    the synthetic view, as the parser would have cut it; and what S drew of a region that
    is mostly carried (left out above) joins the carried part of its category it touches.
    A parser that cuts large pieces into smaller parts of one category
    (``Parser.regions_cut_from_pieces``) keeps its parts apart: only what S drew of a
    mostly carried region joins one part it touches.

At the end the graph is assembled: node 0 is the whole image (all local features, or
the region descriptor's image feature), nodes 1..K the surviving parts; a part with no
local feature in it is dropped (it has nothing to describe it). Weights are 1 for the
whole image and 1/K per part; edges join boxes that overlap or are within 20 px. The
graph of a synthetic view also records where on its image the synthesizer drew
(``SceneGraph.drawn``), and every graph which region of which real view each part is
(``SceneGraph.part_origins``): a part carried through S stays the real part it began as
(a joined part its first carried member), a part parsed on the synthetic view is none.

Real images (queries, and the one real training image per cell) take the query path:
the order without S. So ``PDS``, ``PSD`` and ``SPD`` all parse-and-describe a query
like ``PD``; ``DS`` and ``SD`` like ``D``.

**Several sources.** A pseudo-view may be rendered from several real views at once
(every landmark that sees its content, not only its own cell's): the stages before S
run on each source alone, S fuses the sources into one synthetic view, and what each
source carried across (parts, local features) is joined into one state; the stages
after S run once, on the fused view. With one source this is the paper's synthesis.

Training data (paper §4.1), :func:`training_graphs`: each cell has one real view, of
one of its classes. A variant with S renders the real views at poses of every class
(:class:`PseudoView`: which class, where, from which cells' views), so each class gets
graphs of its own; a variant without S has only the real graph, which stands for every
class of its cell (they "simply use available training images as they are"), or for
its own class only if so asked. The descriptor is fitted first, on the views the
graphs will be built from. Which poses and which sources is the caller's choice.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ssga_core.data import Data, LocalFeatures, Regions, SceneGraph, Synthesis, View
from ssga_core.errors import InputError
from ssga_core.geometry import Pose
from ssga_core.graph import DRAWN_BLOCKS, assemble
from ssga_core.kinds import PIPELINE_KIND_NAMES
from ssga_core.stages import Descriptor, LocalDescriptor, Parser, RegionDescriptor, Synthesizer
from ssga_core.variants import Variant, check_binding


class FeatureMemo(Protocol):
    """Somewhere to reuse the regions and local features of views (a cache).

    The eight variants of an experiment parse and describe the same real images, and
    several render the same pseudo-views; a memo (such as the benchmark's cache) computes
    each once.
    """

    def regions(self, parser: Parser, view: View) -> Regions: ...

    def local_features(self, descriptor: LocalDescriptor, view: View) -> LocalFeatures: ...


@dataclass(frozen=True)
class BoundVariant:
    """A variant with its stage instances; checked on construction."""

    variant: Variant
    descriptor: Descriptor
    parser: Parser | None = None
    synthesizer: Synthesizer | None = None
    label: str = ""
    parse_invented: bool = False
    """An order that parses before S and describes after it (PSD) also parses what S invented:
    see the module docstring. Off: the paper's reading, where those pixels belong to no part."""
    describe_invented: bool = False
    """An order that describes before S (PDS, DSP, DS) also describes what S invented: see the
    module docstring. Off: the paper's reading, where only the real view's features are carried."""
    join_split_parts: bool = False
    """An order that parses before S (PDS, PSD), with a parser of category pieces, joins the touching
    parts of one category after S: see the module docstring. Off: the paper's reading, where each
    carried part stays one node."""

    def __post_init__(self) -> None:
        bound = {kind: type(stage) if (stage := getattr(self, kind)) is not None else None for kind in PIPELINE_KIND_NAMES}
        # Only the stage contract is checked here; what the workspace's views carry is
        # checked by the config, which knows the workspace.
        problems = check_binding(self.variant, bound, frozenset(Data))
        if problems:
            raise InputError("; ".join(problems))
        if not self.label:
            object.__setattr__(self, "label", table_label(self.variant, self.parser, self.descriptor))


def table_label(variant: Variant, parser: Parser | type[Parser] | None, descriptor: Descriptor | type[Descriptor]) -> str:
    """The paper's table notation: descriptor tag, parser tag, then the variant, e.g. ``P-SL (SPD1)``."""
    head = descriptor.tag() + (f"-{parser.tag()}" if parser is not None and "P" in variant.order else "")
    return f"{head} ({variant})"


def build_graph(
    bound: BoundVariant,
    view: View | Sequence[View],
    target: Pose | None = None,
    memo: FeatureMemo | None = None,
    *,
    synthesis: Synthesis | Sequence[Synthesis] | None = None,
) -> SceneGraph:
    """The scene graph of ``view`` under ``bound``'s order.

    Args:
        bound: the variant and its stages.
        view: a real view; or, for a pseudo-training graph, several real views that
            all see the target: each runs the stages before S on its own, S fuses them
            into one synthetic view (:meth:`~ssga_core.Synthesizer.synthesize_from`),
            and what each carried across is joined (parts, local features) before the
            stages after S run once on the fused view.
        target: the pose to synthesize for a pseudo-training graph; ``None`` for a
            real image (a query, or a cell's real training view): the query path.
        memo: reuse the regions and local features of real views computed before.
        synthesis: the views already rendered at ``target`` by ``bound``'s synthesizer,
            one per view (the synthesizer always sees the real views, whatever the order).
    """
    views = [view] if isinstance(view, View) else list(view)
    if target is None:
        order = bound.variant.query_order
        if len(views) != 1:
            raise InputError(f"a query graph is built from one view, got {len(views)}")
    elif bound.variant.synthesizes:
        order = bound.variant.order
    else:
        raise InputError(f"variant {bound.variant} has no S: it cannot build a graph for another pose")
    states = [_State(v, memo=memo, source=i) for i, v in enumerate(views)]
    for stage in order:
        if stage == "S":
            assert bound.synthesizer is not None and target is not None
            if synthesis is None:
                syntheses = bound.synthesizer.synthesize_from(views, target)
            else:
                syntheses = [synthesis] if isinstance(synthesis, Synthesis) else list(synthesis)
            for state, syn in zip(states, syntheses, strict=True):
                state.synthesize(syn)
            states = [_join(states)]
            parser = bound.parser
            join = bound.join_split_parts and bound.variant.carries_parts and parser is not None and parser.regions_are_category_pieces
            optional = None
            if bound.parse_invented and bound.variant.describes_carried_parts:
                assert bound.parser is not None
                optional = states[0].parse_invented(bound.parser, join)
            if bound.describe_invented and bound.variant.describes_before_synthesis:
                optional = states[0].describe_invented(bound.descriptor, bound.parser, join)
            if join:
                states[0].join_split_parts(optional, keep_apart=parser.regions_cut_from_pieces)
            continue
        for state in states:
            if stage == "P":
                assert bound.parser is not None
                state.parse(bound.parser)
            else:
                state.describe(bound.descriptor)
    return states[0].graph(bound.descriptor)


@dataclass(frozen=True)
class CellTraining:
    """One location cell's real training view (paper §4.1: one per cell).

    Attributes:
        real: the cell's one real view.
        real_class: the class that view belongs to.
        classes: every class of the cell (the real one included): what the real graph
            stands for in a variant without S.
    """

    real: View
    real_class: int
    classes: Sequence[int]


@dataclass(frozen=True)
class PseudoView:
    """A pseudo-training graph to synthesize: a class, a pose of it, and the real views to render it from.

    Attributes:
        place: the class.
        pose: where to render.
        sources: indices of the cells (in the ``cells`` list) whose real views render
            it, fused into one point cloud; the paper's setting is the class's own cell
            alone.
    """

    place: int
    pose: Pose
    sources: tuple[int, ...]


Progress = Callable[[str, int, int], None]
"""Called with ``(phase, done, total)`` as long work advances (the CLI draws bars)."""


def training_graphs(
    bound: BoundVariant,
    cells: Sequence[CellTraining],
    pseudo: Sequence[PseudoView],
    *,
    real_for_every_class: bool = True,
    memo: FeatureMemo | None = None,
    progress: Progress | None = None,
) -> tuple[list[SceneGraph], list[int]]:
    """Fit ``bound``'s descriptor and build every training graph with its class (see the module docstring).

    The three steps are also public, so that a caller can run the pseudo-views' graphs
    elsewhere (in chunks, on other workers) once the descriptor is fitted: this function is
    :func:`fit_training_descriptor`, :func:`real_training_graphs`, then
    :func:`pseudo_training_graph` for each pseudo-view.

    Args:
        cells: the real views.
        pseudo: the pseudo-views to synthesize (used only by a variant with S).
        real_for_every_class: without S, the real graph stands for every class of its
            cell (the paper's setting); false: for its own class only.
        progress: called with ``("training graphs", done, total)``.

    Returns:
        the graphs and their classes: every cell's real graph first (repeated for each
        class it stands for), then one graph per pseudo-view, in ``pseudo``'s order.
    """
    first = fit_training_descriptor(bound, cells, pseudo)
    graphs, labels = real_training_graphs(bound, cells, real_for_every_class=real_for_every_class, memo=memo)
    if bound.synthesizer is None:
        return graphs, labels
    for n, p in enumerate(pseudo):
        graphs.append(pseudo_training_graph(bound, cells, p, memo, synthesis=first.pop(n, None)))
        labels.append(p.place)
        if progress:
            progress("training graphs", n + 1, len(pseudo))
    return graphs, labels


def fitting_pseudo_views(cells: Sequence[CellTraining], pseudo: Sequence[PseudoView]) -> list[int]:
    """The pseudo-views a variant with S fits its descriptor on, by index into ``pseudo``:
    the first of every class that has no real view."""
    real_classes = {cell.real_class for cell in cells}
    seen: set[int] = set()
    chosen = []
    for i, p in enumerate(pseudo):
        if p.place not in real_classes and p.place not in seen:
            seen.add(p.place)
            chosen.append(i)
    return chosen


def fit_training_descriptor(bound: BoundVariant, cells: Sequence[CellTraining], pseudo: Sequence[PseudoView]) -> dict[int, list[Synthesis]]:
    """Fit ``bound``'s descriptor on the views its training graphs are built from: each real
    view and, with S, the pseudo-views of :func:`fitting_pseudo_views`.

    Returns:
        those pseudo-views' syntheses by index into ``pseudo``, to pass to
        :func:`pseudo_training_graph`, so that none is rendered twice (empty without S).
    """
    first: dict[int, list[Synthesis]] = {}
    fit_views = [cell.real for cell in cells]
    fit_labels = [cell.real_class for cell in cells]
    if bound.synthesizer is not None:
        for i in fitting_pseudo_views(cells, pseudo):
            p = pseudo[i]
            first[i] = bound.synthesizer.synthesize_from([cells[c].real for c in p.sources], p.pose)
            fit_views.append(first[i][0].view)
            fit_labels.append(p.place)
    bound.descriptor.fit(fit_views, fit_labels)
    return first


def real_training_graphs(
    bound: BoundVariant, cells: Sequence[CellTraining], *, real_for_every_class: bool = True, memo: FeatureMemo | None = None
) -> tuple[list[SceneGraph], list[int]]:
    """Every cell's real graph, repeated for each class it stands for, with those classes
    (the descriptor fitted: :func:`fit_training_descriptor`)."""
    graphs: list[SceneGraph] = []
    labels: list[int] = []
    for cell in cells:
        real = build_graph(bound, cell.real, memo=memo)
        stands_for = [cell.real_class]
        if bound.synthesizer is None and real_for_every_class:
            stands_for = sorted({cell.real_class, *cell.classes})
        graphs.extend([real] * len(stands_for))
        labels.extend(stands_for)
    return graphs, labels


def pseudo_training_graph(
    bound: BoundVariant,
    cells: Sequence[CellTraining],
    pseudo: PseudoView,
    memo: FeatureMemo | None = None,
    *,
    synthesis: Sequence[Synthesis] | None = None,
) -> SceneGraph:
    """The training graph of one pseudo-view, of class ``pseudo.place`` (the descriptor fitted:
    :func:`fit_training_descriptor`; ``synthesis``: what it rendered of this pseudo-view)."""
    return build_graph(bound, [cells[c].real for c in pseudo.sources], pseudo.pose, memo, synthesis=synthesis)


def _join(states: Sequence[_State]) -> _State:
    """One state from the states several source views carried into one fused synthetic view.

    Parts and local features are concatenated (part indices offset per source); a
    pixel of the fused label map belongs to the first source whose part landed there.
    """
    if len(states) == 1:
        return states[0]
    if any(s.region_features is not None for s in states):
        raise InputError("a region descriptor describes before S from one view only; synthesize it from one view")
    view = states[0].view
    carried = {}
    for name in ("semantic", "instance"):
        maps = [getattr(s.view, name) for s in states]
        if all(m is not None for m in maps):
            carried[name] = _first_labelled(maps, offsets=[0] * len(maps))
    if carried:
        view = dataclasses.replace(view, **carried)
    joined = _State(view, memo=states[0].memo)
    if all(s.reached is not None for s in states):
        joined.reached = np.logical_or.reduce([s.reached for s in states])
    if all(s.regions is not None for s in states):
        sizes = [len(s.regions) for s in states]
        offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
        labels = _first_labelled([s.regions.labels for s in states], offsets.tolist())
        joined.regions = Regions.concatenate([s.regions for s in states], labels)
        joined.origins = np.concatenate([s.part_origins() for s in states])
    else:
        offsets = np.zeros(len(states), np.int32)
    if all(s.local is not None for s in states):
        joined.local = LocalFeatures(
            positions=np.concatenate([s.local.positions for s in states]).astype(np.float32),
            descriptors=np.concatenate([s.local.descriptors for s in states]).astype(np.float32),
        )
        if all(s.local_nodes is not None for s in states):
            joined.local_nodes = np.concatenate(
                [np.where(s.local_nodes >= 0, s.local_nodes + off, -1) for s, off in zip(states, offsets)]
            ).astype(np.int32)
    return joined


def _first_labelled(maps: Sequence[np.ndarray], offsets: Sequence[int]) -> np.ndarray:
    """Per pixel, the first map's label ``>= 0`` (plus that map's offset), else -1."""
    out = np.full(maps[0].shape, -1, dtype=np.int32)
    for m, off in zip(maps, offsets):
        free = (out < 0) & (m >= 0)
        out[free] = m[free] + off
    return out


@dataclass
class _State:
    view: View
    regions: Regions | None = None
    local: LocalFeatures | None = None
    local_nodes: np.ndarray | None = None
    """Per local feature, its part index fixed before synthesis (-1 for none)."""
    region_features: np.ndarray | None = field(default=None)
    memo: FeatureMemo | None = None
    reached: np.ndarray | None = None
    """After S, for a state that carried local features: ``(H, W)`` bool, the synthetic view's pixels
    some visible source pixel landed on."""
    source: int = 0
    """Which of the views the graph is built from this state began as (``SceneGraph.part_origins``)."""
    origins: np.ndarray | None = None
    """``(K, 2)`` int32, per region: the (source, region) of the real view's parse it is, -1 for a part
    parsed on a synthetic view. It follows every step that drops, adds or joins regions."""

    def parse(self, parser: Parser) -> None:
        self.regions = self.memo.regions(parser, self.view) if self.memo else parser.parse(self.view)
        k = len(self.regions)
        if self.view.synthetic:
            self.origins = np.full((k, 2), -1, np.int32)
        else:
            self.origins = np.stack([np.full(k, self.source), np.arange(k)], axis=1).astype(np.int32)

    def part_origins(self) -> np.ndarray:
        """``(K, 2)``: :attr:`origins` (-1 for every region where no step set them)."""
        assert self.regions is not None
        return self.origins if self.origins is not None else np.full((len(self.regions), 2), -1, np.int32)

    def parse_invented(self, parser: Parser, join: bool) -> np.ndarray | None:
        """Add parts for the drawn pixels no carried part covers (the module docstring); returns
        which parts stay only if joined (:meth:`_add_invented_parts`)."""
        assert self.regions is not None and self.local is None and self.region_features is None
        return self._add_invented_parts(parser, join)

    def describe_invented(self, descriptor: Descriptor, parser: Parser | None, join: bool) -> np.ndarray | None:
        """Describe the drawn pixels no source pixel reached, after S, for an order that described
        before it (the module docstring); with carried parts, parse them into parts first, and return
        which parts stay only if joined (:meth:`_add_invented_parts`)."""
        assert isinstance(descriptor, LocalDescriptor) and self.local is not None and self.reached is not None
        # A source pixel splats to one target pixel, so a stretched surface leaves gaps between its
        # splats: those are carried content, not invented, and a feature there is not added.
        invented = self.view.valid_depth() & ~_dilated(self.reached, INVENTED_MARGIN)
        if not invented.any():
            return None
        optional = None
        if self.regions is not None:
            assert parser is not None
            optional = self._add_invented_parts(parser, join)
        fresh = self.memo.local_features(descriptor, self.view) if self.memo else descriptor.extract(self.view)
        added = fresh.select(_pixel_at(invented, fresh.positions, False))
        self.local = LocalFeatures(
            positions=np.concatenate([self.local.positions, added.positions]).astype(np.float32),
            descriptors=np.concatenate([self.local.descriptors, added.descriptors]).astype(np.float32),
        )
        if self.local_nodes is not None:  # parts fixed before S: an added feature belongs to an added part or none
            assert self.regions is not None
            # Carried labels lie only where a source pixel landed, so a part here is an added one.
            nodes = _region_at(self.regions.labels, added.positions)
            self.local_nodes = np.concatenate([self.local_nodes, nodes]).astype(np.int32)
        return optional

    def _add_invented_parts(self, parser: Parser, join: bool) -> np.ndarray:
        """Add the regions of a fresh parse that are mostly invented, cut to the invented pixels;
        with ``join``, the invented pixels of the other regions too, as parts that stay only if they
        join a carried part (:meth:`join_split_parts`). Returns those parts' mask, ``(K,)`` bool."""
        assert self.regions is not None
        carried = self.regions
        invented = self.view.valid_depth() & (carried.labels < 0)
        if not invented.any():
            return np.zeros(len(carried), bool)
        fresh = self.memo.regions(parser, self.view) if self.memo else parser.parse(self.view)
        labelled = fresh.labels >= 0
        area = np.bincount(fresh.labels[labelled], minlength=len(fresh))
        inside = np.bincount(fresh.labels[labelled & invented], minlength=len(fresh))
        # Mostly invented, so a region that is mainly carried content does not come back as a sliver.
        mostly = (inside > 0) & (2 * inside >= area)
        wanted = np.append(mostly | (join & (inside > 0)), False)
        taken = invented & wanted[np.where(labelled, fresh.labels, -1)]
        added = Regions.from_labels(np.where(taken, fresh.labels, -1), fresh.categories, fresh.scores)
        present = np.flatnonzero(np.bincount(fresh.labels[taken], minlength=len(fresh)))  # from_labels' order
        labels = np.where(added.labels >= 0, added.labels + len(carried), carried.labels).astype(np.int32)
        self.origins = np.concatenate([self.part_origins(), np.full((len(added), 2), -1, np.int32)])
        self.regions = Regions.concatenate([carried, added], labels)
        return np.concatenate([np.zeros(len(carried), bool), ~mostly[present]])

    def join_split_parts(self, optional: np.ndarray | None, keep_apart: bool = False) -> None:
        """Join the parts of one category that touch (the module docstring); a part marked in
        ``optional`` stays only in a group with a part that is not. With ``keep_apart`` (a parser
        that cuts pieces into parts, ``Parser.regions_cut_from_pieces``) the parts not marked are
        never joined to one another: an optional part joins at most one of them."""
        regions = self.regions
        assert regions is not None
        if regions.categories is None:
            raise InputError("join_split_parts: the parser says its regions are pieces of categories but gave no Regions.categories")
        k = len(regions)
        parent = list(range(k))

        def root(a: int) -> int:
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            return a

        optional = np.zeros(k, bool) if optional is None else optional
        anchors = (~optional).astype(np.int64)  # per root: how many parts not marked its group holds
        for a, b in _touching_pairs(regions.labels, JOIN_REACH):
            ra, rb = root(a), root(b)
            if ra == rb or regions.categories[a] != regions.categories[b]:
                continue
            if keep_apart and anchors[ra] + anchors[rb] > 1:
                continue
            parent[ra] = rb
            anchors[rb] += anchors[ra]
        roots = np.array([root(a) for a in range(k)], dtype=np.int64)
        anchored = np.zeros(k, bool)
        anchored[roots[~optional]] = True
        kept_roots = [r for r in dict.fromkeys(roots.tolist()) if anchored[r]]  # in order of first member
        lut = np.full(k, -1, dtype=np.int32)
        lut[kept_roots] = np.arange(len(kept_roots), dtype=np.int32)
        groups = lut[roots]
        # A joined part is the real part it began as: its first carried member's (the parts S drew have none).
        origins = self.part_origins()
        drawn_by_s = origins[:, 0] < 0
        self.origins = np.array(
            [origins[min(np.flatnonzero(groups == g), key=lambda m: (drawn_by_s[m], m))] for g in range(len(kept_roots))], np.int32
        ).reshape(-1, 2)
        self.regions = regions.merge(groups)
        if self.local_nodes is not None:
            self.local_nodes = np.where(self.local_nodes >= 0, groups[np.clip(self.local_nodes, 0, None)], -1).astype(np.int32)

    def describe(self, descriptor: Descriptor) -> None:
        if isinstance(descriptor, LocalDescriptor):
            self.local = self.memo.local_features(descriptor, self.view) if self.memo else descriptor.extract(self.view)
        elif isinstance(descriptor, RegionDescriptor):
            self.region_features = descriptor.describe(self.view, self.regions)
        else:
            raise TypeError(f"{type(descriptor).__name__} must subclass LocalDescriptor or RegionDescriptor")

    def synthesize(self, syn: Synthesis) -> None:
        if self.local is not None:  # only carried features need it (describe_invented)
            self.reached = syn.warp_labels(np.zeros(syn.visible.shape, np.int32)) >= 0
        keep_parts = None
        if self.regions is not None:
            keep_parts, moved = carry_regions(self.regions, syn)
            if self.local is not None:
                self.local_nodes = _renumber(_region_at(self.regions.labels, self.local.positions), keep_parts)
            self.origins = self.part_origins()[keep_parts]
            self.regions = moved
        if self.local is not None:
            uv, visible = syn.map_points(self.local.positions)
            self.local = LocalFeatures(positions=uv[visible], descriptors=self.local.descriptors[visible])
            if self.local_nodes is not None:
                self.local_nodes = self.local_nodes[visible]
        self.view = _carry_view_labels(self.view, syn)

    def graph(self, descriptor: Descriptor) -> SceneGraph:
        camera = self.view.camera
        regions = self.regions
        origins = self.part_origins() if regions is not None else None
        if self.local is not None:
            assert isinstance(descriptor, LocalDescriptor)
            nodes = self.local_nodes
            if nodes is None:
                nodes = _region_at(regions.labels, self.local.positions) if regions is not None else None
            if regions is not None and nodes is not None:
                counts = np.bincount(nodes[nodes >= 0], minlength=len(regions))
                keep = counts > 0
                nodes = _renumber(nodes, keep)
                regions = regions.select(keep)
                origins = origins[keep]
            parts = [np.flatnonzero(nodes == k) for k in range(len(regions))] if regions is not None else []
            features = descriptor.pool(self.local, [np.arange(len(self.local)), *parts])
        else:
            assert self.region_features is not None
            features = self.region_features
        boxes = regions.boxes if regions is not None else np.zeros((0, 4), np.float32)
        drawn = self.view.drawn_blocks(DRAWN_BLOCKS) if self.view.synthetic else None
        categories = regions.categories if regions is not None else None
        return assemble(camera, boxes, features, drawn, origins, categories, regions.scores if regions is not None else None)


def carry_regions(regions: Regions, syn: Synthesis) -> tuple[np.ndarray, Regions]:
    """Move regions into the synthetic view (see the module docstring).

    Returns:
        which parts survive (``(K,)`` bool) and the surviving regions, renumbered.
    """
    k = len(regions)
    b = regions.boxes
    corners = np.stack([b[:, [0, 1]], b[:, [2, 1]], b[:, [0, 3]], b[:, [2, 3]]], axis=1)
    points = np.concatenate([regions.centroids()[:, None, :], corners], axis=1)  # (K, 5, 2)
    mapped, _ = syn.map_points(points.reshape(-1, 2))
    mapped = mapped.reshape(k, 5, 2)
    camera = syn.view.camera
    labels = syn.warp_labels(regions.labels)
    seen = np.bincount(labels[labels >= 0], minlength=k) > 0
    keep = camera.contains(mapped[:, 0]) & seen
    # A kept part's centroid is finite, so each box has at least that point.
    kept = mapped[keep]
    limit = np.array([camera.width - 1, camera.height - 1], dtype=np.float32)
    boxes = np.zeros((k, 4), dtype=np.float32)
    boxes[keep] = np.concatenate([np.clip(np.nanmin(kept, axis=1), 0, limit), np.clip(np.nanmax(kept, axis=1), 0, limit)], axis=1)
    moved = dataclasses.replace(regions, labels=labels, boxes=boxes)
    return keep, moved.select(keep)


INVENTED_MARGIN = 2
"""Pixels: how far from every pixel a source reached a drawn pixel must be to count as invented
(``describe_invented``): wider than the gaps a moderately stretched surface leaves between splats."""


JOIN_REACH = 2
"""Pixels: two parts this close touch (``join_split_parts``): the gaps a stretched surface leaves
between its splats do not keep apart the pieces of one region."""


def _touching_pairs(labels: np.ndarray, reach: int) -> list[tuple[int, int]]:
    """The pairs of different labels ``>= 0`` within ``reach`` pixels of each other (a square), each once."""
    h, w = labels.shape
    k = int(labels.max(initial=-1)) + 1
    seen = np.zeros(k * k, dtype=bool)  # pair (a, b), a < b, at a * k + b: marking is cheaper than np.unique
    for dv in range(0, reach + 1):
        for du in range(-reach, reach + 1):
            if dv == 0 and du <= 0:  # each offset once: the other half is the same pairs reversed
                continue
            a = labels[: h - dv, max(-du, 0) : w - max(du, 0)]
            b = labels[dv:, max(du, 0) : w - max(-du, 0)]
            both = (a != b) & (a >= 0) & (b >= 0)
            seen[np.minimum(a[both], b[both]).astype(np.int64) * k + np.maximum(a[both], b[both])] = True
    codes = np.flatnonzero(seen)
    return list(zip((codes // k).tolist(), (codes % k).tolist()))


def _dilated(mask: np.ndarray, radius: int) -> np.ndarray:
    """``mask`` grown by ``radius`` pixels (a square), with shifts: the core has no image library."""
    out = mask.copy()
    h, w = mask.shape
    for dv in range(-radius, radius + 1):
        for du in range(-radius, radius + 1):
            out[max(dv, 0) : h + min(dv, 0), max(du, 0) : w + min(du, 0)] |= mask[max(-dv, 0) : h + min(-dv, 0), max(-du, 0) : w + min(-du, 0)]
    return out


def _pixel_at(grid: np.ndarray, positions: np.ndarray, outside: int | bool) -> np.ndarray:
    """``grid``'s value at each ``(u, v)`` position (nearest pixel); ``outside`` beyond the image."""
    h, w = grid.shape
    # A position that is not a number counts as outside (casting NaN to an integer is undefined).
    col = np.rint(np.nan_to_num(positions[:, 0], nan=-1.0)).astype(np.intp)
    row = np.rint(np.nan_to_num(positions[:, 1], nan=-1.0)).astype(np.intp)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    out = np.full(len(positions), outside, dtype=grid.dtype)
    out[inside] = grid[row[inside], col[inside]]
    return out


def _region_at(labels: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Region index at each ``(u, v)`` position (nearest pixel), -1 outside any region or the image."""
    return _pixel_at(labels.astype(np.int32, copy=False), positions, -1)


def _renumber(nodes: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Map old part indices to their index among the kept parts (-1 if dropped)."""
    lut = np.full(len(keep) + 1, -1, dtype=np.int32)
    lut[np.flatnonzero(keep)] = np.arange(int(keep.sum()), dtype=np.int32)
    return lut[np.where(nodes >= 0, nodes, len(keep))]


def _carry_view_labels(source: View, syn: Synthesis) -> View:
    """The synthetic view, with the source's semantic/instance ids warped in if it has none."""
    carried = {
        name: syn.warp_labels(getattr(source, name))
        for name in ("semantic", "instance")
        if getattr(source, name) is not None and getattr(syn.view, name) is None
    }
    return dataclasses.replace(syn.view, **carried) if carried else syn.view
