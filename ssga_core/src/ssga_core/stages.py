"""Stage base classes (the stage protocols): what a parser, descriptor, synthesizer, fuser or workspace source is.

Each implementation is a subclass that declares, as class attributes,

* ``name``: the name configs use (``parser = { name = "slico" }``);
* ``Config``: its pydantic config model (a :class:`StageConfig`: unknown keys are
  errors, instances are frozen);
* ``consumes`` / ``produces``: the :class:`~ssga_core.data.Data` it needs and gives,
  from which the core checks a bound variant before anything runs;
* optionally ``abbrev`` (its tag in the paper's table notation, ``P-SL (SPD)``) and
  ``presets`` (named parameter sets).

The base classes do the checking and the bookkeeping; an implementation writes one
``_method`` (``_parse``, ``_extract``...). Plugins never see which variant they run
in: the order semantics live in :mod:`ssga_core.pipeline`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from ssga_core.data import Data, LocalFeatures, Regions, Synthesis, View
from ssga_core.errors import InputError, PluginError
from ssga_core.geometry import Pose

class KeyedConfig(BaseModel):
    """A config that keys stored work (a stage's cached features, a variant's stored run), and may
    grow settings after that work exists."""

    added_since: ClassVar[frozenset[str]] = frozenset()
    """Fields of this config (not of a config nested in it) added after runs were keyed by it: while
    at their defaults they are left out of the keys of caches and runs (:meth:`unkeyed`), so that
    the runs made before them keep their keys and resume."""

    def unkeyed(self) -> set[str]:
        """The fields a key leaves out: those of :attr:`added_since` at their defaults."""
        fields = type(self).model_fields
        return {name for name in self.added_since if getattr(self, name) == fields[name].default}


class StageConfig(KeyedConfig):
    """Base of every stage's config: unknown keys are errors, instances are immutable, and
    numbers are finite (an ``inf`` room size or a ``nan`` threshold would validate and
    then fail deep inside a library)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Stage(ABC):
    """Common base: identity, config and declared data flow of a stage implementation."""

    kind: ClassVar[str]
    name: ClassVar[str]
    Config: ClassVar[type[StageConfig]] = StageConfig
    consumes: ClassVar[frozenset[Data]] = frozenset()
    produces: ClassVar[frozenset[Data]] = frozenset()
    abbrev: ClassVar[str] = ""
    presets: ClassVar[Mapping[str, Mapping[str, Any]]] = {}

    def __init__(self, config: StageConfig | None = None) -> None:
        if config is None:
            config = self.Config()
        elif not isinstance(config, self.Config):
            raise TypeError(f"{type(self).__name__} takes a {self.Config.__name__}, got {type(config).__name__}")
        self.config = config

    @classmethod
    def tag(cls) -> str:
        """Short name used in table labels: ``abbrev`` if set, else ``name``."""
        return cls.abbrev or cls.name

    @classmethod
    def caveat(cls, config: StageConfig) -> str:
        """What every reader of a result made with this config must be told, or ``""``.

        A learned stage on random weights says ``"random weights"``: such output is for
        tests only, never a result, so the core appends the caveat to every variant
        label the stage takes part in (and so to every table, plot and file named by it).
        """
        return ""

    def _require(self, view: View) -> None:
        missing = set(self.consumes) & {Data.RGB, Data.DEPTH, Data.SEMANTIC} - view.available
        if missing:
            names = ", ".join(sorted(m.value for m in missing))
            raise InputError(f"{self.kind} {self.name!r} needs {names}, which this view does not carry")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.config!r})"


class Parser(Stage):
    """Scene parsing (P): cut an image into regions, the scene graph's part nodes."""

    kind = "parser"
    consumes = frozenset({Data.RGB})
    produces = frozenset({Data.REGIONS})
    names_categories: bool = False
    """True when every region it gives carries its semantic category (``Regions.categories``), as a
    segmenter's or a detector's do; the scene graph keeps them (``SceneGraph.categories``), and graph
    matching can pair a part only with parts of its own category. False for superpixels."""
    regions_are_category_pieces: bool = False
    """True when each region is one connected piece of one category (``Regions.categories``), as a
    segmenter's: two touching regions of one category are then one region split apart, which is how
    synthesis can leave them (``BoundVariant.join_split_parts``). False for superpixels and instances."""
    regions_cut_from_pieces: bool = False
    """With :attr:`regions_are_category_pieces`: True when the parser cuts large pieces into smaller
    parts of one category, so that two touching regions of one category may be two parts on purpose.
    Joining after S then only attaches to a part what S drew of it (``BoundVariant.join_split_parts``).
    A parser whose config decides it overrides this per instance."""

    def parse(self, view: View) -> Regions:
        self._require(view)
        return self._checked(view, self._parse(view))

    def parse_many(self, views: Sequence[View]) -> list[Regions]:
        """The regions of each of ``views``, as :meth:`parse` gives them, in one batch.

        The runner hands a parser its views in batches (``[execution] batch``); a learned
        parser overrides :meth:`_parse_many` to run its network once per batch on its
        device. Its result for a view must not depend on the batch it came in.
        """
        for view in views:
            self._require(view)
        regions = self._parse_many(views)
        if len(regions) != len(views):
            raise InputError(f"parser {self.name!r} returned {len(regions)} results for {len(views)} views")
        return [self._checked(view, r) for view, r in zip(views, regions)]

    def _checked(self, view: View, regions: Regions) -> Regions:
        if regions.labels.shape != view.camera.shape:
            raise InputError(
                f"parser {self.name!r} returned labels of shape {regions.labels.shape} for a {view.camera.shape} image"
            )
        if self.names_categories and regions.categories is None:
            raise PluginError(f"parser {self.name!r} says its regions carry their categories but gave no Regions.categories")
        return regions

    @abstractmethod
    def _parse(self, view: View) -> Regions: ...

    def _parse_many(self, views: Sequence[View]) -> list[Regions]:
        """Default: one view at a time."""
        return [self._parse(view) for view in views]


class Descriptor(Stage):
    """Scene description (D): a feature for each scene-graph node.

    Subclass :class:`LocalDescriptor` or :class:`RegionDescriptor`, never this one.
    """

    kind = "descriptor"
    consumes = frozenset({Data.RGB})

    def fit(self, views: Sequence[View], labels: Sequence[int] | None = None) -> None:
        """Learn what the descriptor needs from the training views (a dictionary, a classifier).

        Called once per variant before any graph is built, with the training views
        (each cell's real view and, for variants with S, a synthetic view of each other
        class) and their place classes. The default learns nothing.

        A descriptor that learns here also writes :meth:`state_dict` and
        :meth:`load_state_dict`: the runner fits it once, then scores query views in
        other processes (or machines) from that state.
        """

    def state_dict(self) -> dict[str, np.ndarray]:
        """What :meth:`fit` learned, as named arrays (a dictionary, a classifier's weights and
        classes): with the config, everything a fitted descriptor is. The default: nothing."""
        return {}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Become the descriptor :meth:`state_dict` was taken from, without fitting.

        Raises:
            InputError: ``state`` is not what this descriptor stores (a missing array, a
                wrong shape).
        """
        if state:
            raise InputError(f"descriptor {self.name!r} learns nothing, but got a fitted state of {', '.join(sorted(state))}")

    @property
    @abstractmethod
    def dim(self) -> int:
        """Length of a node feature (known after :meth:`fit`)."""


HOLE_WINDOW = 0.1
"""The square :meth:`LocalDescriptor.extract` looks at around a feature to tell a hole,
as a share of the image's side (``sqrt(H W)``): 26 px at 256 x 256, about a dense SIFT
keypoint's size, wider than the cracks a synthesizer fills in."""

HOLE_SHARE = 0.5
"""A feature of a synthetic view is kept (``holes = "skip"``) where at least this share of
that square was drawn."""


class LocalDescriptorConfig(StageConfig):
    """Base config of a :class:`LocalDescriptor`; a plugin's config subclasses it."""

    holes: Literal["describe", "skip"] = Field(
        default="describe",
        description="In a synthetic view, 'skip' drops the features that lie on holes (where the synthesizer "
        "drew less than half of the square around them: a hole shows no place, and a real query never has one); "
        "'describe' keeps every feature, holes included.",
    )


class LocalDescriptor(Descriptor):
    """Features at pixel positions, pooled into node features per region.

    Because the features sit at positions, a synthesizer's point map can move them,
    so this kind supports every order, also those that describe before parsing or
    before synthesis (``DS``, ``DSP``, ``PDS``).

    With ``holes = "skip"`` in its config (:class:`LocalDescriptorConfig`), the features
    a subclass extracts from a synthetic view are kept only where the synthesizer drew
    (:meth:`View.drawn_share`): here, once, for every order, the dictionary fit and the cache.
    """

    Config: ClassVar[type[StageConfig]] = LocalDescriptorConfig
    produces = frozenset({Data.LOCAL_FEATURES})

    def extract(self, view: View) -> LocalFeatures:
        self._require(view)
        return self._drop_holes(view, self._extract(view))

    def _drop_holes(self, view: View, features: LocalFeatures) -> LocalFeatures:
        if getattr(self.config, "holes", "describe") != "skip" or not view.synthetic:
            return features
        h, w = view.camera.shape
        side = round(HOLE_WINDOW * (h * w) ** 0.5)
        return features.select(view.drawn_share(features.positions, side) >= HOLE_SHARE)

    def extract_many(self, views: Sequence[View]) -> list[LocalFeatures]:
        """The local features of each of ``views``, as :meth:`extract` gives them, in one batch.

        The runner hands a descriptor its views in batches (``[execution] batch``); a
        learned descriptor overrides :meth:`_extract_many` to run its network once per
        batch on its device. Its result for a view must not depend on the batch it came in.
        """
        for view in views:
            self._require(view)
        features = self._extract_many(views)
        if len(features) != len(views):
            raise InputError(f"descriptor {self.name!r} returned {len(features)} results for {len(views)} views")
        return [self._drop_holes(view, f) for view, f in zip(views, features)]

    def _extract_many(self, views: Sequence[View]) -> list[LocalFeatures]:
        """Default: one view at a time."""
        return [self._extract(view) for view in views]

    def pool(self, features: LocalFeatures, members: Sequence[np.ndarray]) -> np.ndarray:
        """Node features ``(N, dim)`` from the local features of each node.

        Args:
            features: every local feature of the view.
            members: for each node, the indices into ``features`` that belong to it.
        """
        out = np.asarray(self._pool(features, members), dtype=np.float32)
        if out.shape != (len(members), self.dim):
            raise InputError(f"descriptor {self.name!r} pooled shape {out.shape}, expected {(len(members), self.dim)}")
        return out

    @abstractmethod
    def _extract(self, view: View) -> LocalFeatures: ...

    @abstractmethod
    def _pool(self, features: LocalFeatures, members: Sequence[np.ndarray]) -> np.ndarray: ...


class RegionDescriptor(Descriptor):
    """Features of given regions only (e.g. a CNN classifying the image or a crop)."""

    produces = frozenset({Data.REGION_FEATURES})

    def describe(self, view: View, regions: Regions | None) -> np.ndarray:
        """``(1 + K, dim)``: the whole image's feature, then one per region (K = 0 without regions)."""
        self._require(view)
        out = np.asarray(self._describe(view, regions), dtype=np.float32)
        n = 1 + (len(regions) if regions is not None else 0)
        if out.shape != (n, self.dim):
            raise InputError(f"descriptor {self.name!r} returned shape {out.shape}, expected {(n, self.dim)}")
        return out

    @abstractmethod
    def _describe(self, view: View, regions: Regions | None) -> np.ndarray: ...


class Synthesizer(Stage):
    """Scene synthesis (S): render a view from another pose, with the point map that did it."""

    kind = "synthesizer"
    consumes = frozenset({Data.RGB})
    produces = frozenset({Data.RGB, Data.POINT_MAP})

    def synthesize(self, view: View, target: Pose) -> Synthesis:
        self._require(view)
        result = self._synthesize(view, target)
        if result.visible.shape != view.camera.shape:
            raise InputError(f"synthesizer {self.name!r} returned a point map for {result.visible.shape}, expected {view.camera.shape}")
        return result

    @abstractmethod
    def _synthesize(self, view: View, target: Pose) -> Synthesis: ...

    def synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        """Render ``target`` from several real views at once, as one fused point cloud.

        Returns one :class:`Synthesis` per view, all holding the same synthetic image;
        each view's point map says where its pixels land, and a pixel is ``visible``
        only if it is on the front-most surface of *all* the views' points there. With
        one view this is :meth:`synthesize`.
        """
        if not views:
            raise InputError(f"synthesizer {self.name!r}: no view to synthesize from")
        for view in views:
            self._require(view)
        if len(views) == 1:
            return [self.synthesize(views[0], target)]
        results = self._synthesize_from(views, target)
        if len(results) != len(views) or any(r.visible.shape != v.camera.shape for r, v in zip(results, views)):
            raise InputError(f"synthesizer {self.name!r} returned {len(results)} point maps for {len(views)} views, or of the wrong size")
        return results

    def _synthesize_from(self, views: Sequence[View], target: Pose) -> list[Synthesis]:
        """Default: render from each view alone, then keep the nearest surface at every pixel.

        Needs depth in the synthetic views (to know which surface is in front); a
        synthesizer that can render a fused cloud in one pass (one z-buffer, holes filled
        once) overrides this.
        """
        return fuse_syntheses([self.synthesize(view, target) for view in views], self.name)


def fuse_syntheses(syntheses: Sequence[Synthesis], name: str = "synthesizer", depth_tolerance: float = 0.02) -> list[Synthesis]:
    """Compose single-view syntheses of one target into one image, by depth.

    Each target pixel shows the nearest surface any view drew there (pixels no view
    has a depth for, such as filled holes, take the first view that drew something).
    A source pixel stays ``visible`` only if its surface is within ``depth_tolerance``
    (relative) of the nearest one at its target pixel.
    """
    views = [s.view for s in syntheses]
    if any(v.depth is None for v in views):
        raise InputError(f"synthesizer {name!r}: its synthetic views carry no depth, so several views cannot be fused; synthesize from one")
    depth = np.stack([np.where(v.depth > 0, v.depth, np.inf) for v in views])  # (S, H, W)
    nearest = depth.argmin(axis=0)
    known = np.isfinite(depth.min(axis=0))
    drawn = np.stack([v.rgb.any(axis=-1) for v in views])
    first_drawn = np.where(drawn.any(axis=0), drawn.argmax(axis=0), 0)
    source = np.where(known, nearest, first_drawn)
    rows, cols = np.indices(source.shape)
    rgb = np.stack([v.rgb for v in views])[source, rows, cols]
    fused_depth = np.where(known, depth.min(axis=0), 0.0).astype(np.float32)
    fused = View(rgb=rgb, pose=views[0].pose, camera=views[0].camera, depth=fused_depth, synthetic=True)
    h, w = fused.camera.shape
    out = []
    for s, d in zip(syntheses, depth):
        uv = s.target_uv[s.visible]
        col = np.clip(np.rint(uv[:, 0]), 0, w - 1).astype(np.intp)
        row = np.clip(np.rint(uv[:, 1]), 0, h - 1).astype(np.intp)
        front = d[row, col] <= fused_depth[row, col] * (1.0 + depth_tolerance)
        visible = s.visible.copy()
        visible[s.visible] = front
        out.append(Synthesis(view=fused, target_uv=s.target_uv, visible=visible))
    return out


class Fuser(Stage):
    """Late fusion of the class scores of several variants into one ranking."""

    kind = "fuser"
    learns: ClassVar[bool] = False
    """Whether the rule is learned from the validation views (:meth:`fit`) before it fuses;
    a rank or probability rule is not. A learning fuser needs a validation split."""

    def fit(self, scores: np.ndarray, truth: np.ndarray) -> None:
        """Learn the rule from the validation views: ``(V, Q, C)`` scores of the same variants,
        in the same order, that :meth:`fuse` will be given, and ``(Q,)`` true classes.
        Called once per experiment, only where :attr:`learns`; the default learns nothing."""

    def learned(self) -> dict[str, Any]:
        """What :meth:`fit` learned, as JSON (weights per member): recorded beside the report. Default: nothing."""
        return {}

    def fuse(self, scores: np.ndarray) -> np.ndarray:
        """Fuse ``(V, Q, C)`` scores (V variants, Q queries, C classes; higher is better) into ``(Q, C)``."""
        return self._fuse(self.checked_scores(scores))

    def checked_scores(self, scores: np.ndarray) -> np.ndarray:
        """``scores`` as float64 ``(V, Q, C)``, or a one-line :class:`InputError` naming the shape."""
        scores = np.asarray(scores, dtype=np.float64)
        if scores.ndim != 3 or 0 in scores.shape:
            raise InputError(f"fuser {self.name!r}: expected non-empty (variants, queries, classes) scores, got shape {scores.shape}")
        return scores

    @abstractmethod
    def _fuse(self, scores: np.ndarray) -> np.ndarray: ...


class WorkspaceSource(Stage):
    """Where views come from: a generated or rendered scene, or a user's folder of images.

    ``produces`` declares what its views carry (RGB always; depth and semantic ids
    if the source has them), which decides the stages a variant may use on them.
    """

    kind = "workspace"
    produces = frozenset({Data.RGB})
    fits_protocol: ClassVar[bool] = False
    """Whether a protocol whose cells, viewpoints or test radius do not fit this source's
    scenes is fitted to them by default (``protocol.fit``): a user's scans and captures vary
    in size and shape; generated homes are made for the configured protocol."""

    @classmethod
    def carries(cls, config: StageConfig) -> frozenset[Data]:
        """What the views of the workspace ``config`` describes carry: ``produces`` unless
        the source can tell more from its files (captures without depth), so that a
        variant whose stages need what is missing is refused before anything runs."""
        return cls.produces

    @classmethod
    def missing(cls, config: StageConfig) -> list[str]:
        """What the workspace ``config`` describes lacks to open (a folder, a file, anything
        to take a floor plan from), found from its files before anything runs: one line
        each, starting with the parameter at fault (``"path: no such folder scene/"``).
        ``ssga config validate`` reports them with the config's other problems."""
        return []

    @abstractmethod
    def open(self) -> Any:
        """Open the workspace this source's config describes.

        The workspace interfaces belong to the benchmark layer, which is the only user
        of workspaces: return a :class:`ssga_bench.Workspace` (renders any pose) or a
        :class:`ssga_bench.CapturedWorkspace` (a fixed set of captured views).
        """
