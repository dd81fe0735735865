"""What every variant of an experiment learns from: each cell's real view, and the pose and
source views of every class's pseudo-views (:func:`training_plan`); the pipeline
(:func:`ssga_core.pipeline.training_graphs`) builds the variant's graphs from them.

The plan knows only what the deployed robot has: its real views (their images, depth and
poses) and the classes they stand for (the cells' grid, the headings). Where pseudo-views may
stand, what they see and which real views see the same floor come from a floor plan of what
the real views' depth saw (:func:`seen_floor_plan`), never the workspace's own floor plan,
which is for evaluation (test views, levels) and the oracle row."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from ssga_bench.config import TrainingConfig
from ssga_bench.dataset import Dataset
from ssga_bench.protocol import Protocol, Sample
from ssga_bench.seeds import stream
from ssga_bench.seen_floor import FloorEvidence
from ssga_bench.workspace import FloorPlan
from ssga_bench.timings import Timings
from ssga_core.data import View
from ssga_core.geometry import Pose
from ssga_core.pipeline import CellTraining, PseudoView


class Views:
    """Loads dataset views (timed), keeping the few real training views in memory."""

    def __init__(self, dataset: Dataset, timings: Timings) -> None:
        self.dataset, self.timings = dataset, timings
        self._kept: dict[str, View] = {}

    def __call__(self, sample: Sample, keep: bool = False) -> View:
        if sample.id in self._kept:
            return self._kept[sample.id]
        with self.timings.phase("load views"):
            view = self.dataset.view(sample)
        self.timings.views["load views"] += 1
        if keep:
            self._kept[sample.id] = view
        return view


def jittered(pose: Pose, rng: np.random.Generator, metres: float, degrees: float) -> Pose:
    r, phi = metres * math.sqrt(rng.random()), rng.random() * 2 * math.pi
    yaw = pose.yaw + math.radians(degrees) * (2 * rng.random() - 1)
    return Pose(pose.x + r * math.cos(phi), pose.y + r * math.sin(phi), yaw, pose.height)


@dataclass(frozen=True)
class TrainingPlan:
    """What every variant of an experiment learns from (the same for all of them).

    Attributes:
        cells: each cell's real view.
        pseudo: the pseudo-views a variant with S synthesizes.
        pose_groups: per pseudo-view, the pose it was drawn as (jittered copies of one
            canonical viewpoint share one): the classifier holds out whole groups for
            early stopping, so its validation never differs from training by a jitter only.
    """

    cells: list[CellTraining]
    pseudo: list[PseudoView]
    pose_groups: list[int]

    def groups(self, real_graphs: int, synthesizes: bool) -> np.ndarray:
        """The group of every training graph (:func:`ssga_core.pipeline.training_graphs`'s order):
        the real graphs each their own, then, for a variant with S, the pseudo-views'."""
        pseudo = real_graphs + np.asarray(self.pose_groups if synthesizes else [], dtype=np.int64)
        return np.concatenate([np.arange(real_graphs), pseudo]).astype(np.int64)


def training_cells(dataset: Dataset, views: Views) -> list[CellTraining]:
    """Each cell's real view (the ``train`` split, in its order) with the classes it stands for."""
    rank_of_cell = {cell: rank for rank, cell in enumerate(dataset.plan.cells)}
    orientations = dataset.plan.config.orientations
    cells = []
    for s in dataset.split("train"):
        rank = rank_of_cell[s.cell]
        cells.append(CellTraining(views(s, keep=True), s.place, range(rank * orientations, (rank + 1) * orientations)))
    return cells


def seen_floor_plan(cells: list[CellTraining], around: np.ndarray | None = None, radius: float = 0.0) -> FloorPlan:
    """The floor plan of what the cells' real views saw (:mod:`ssga_bench.seen_floor`): free where
    their depth saw floor or clear sight, and, within ``radius`` of the points ``around`` (the cells'
    centroids), wherever it saw no obstacle; what stands at camera height occludes. A view without
    depth adds only where its camera stood."""
    camera = cells[0].real.camera
    poses = [cell.real.pose for cell in cells]
    evidence = FloorEvidence(camera, float(np.median([p.height for p in poses])), source="real views")
    for k, cell in enumerate(cells):
        evidence.add(k, cell.real.pose.world_from_camera(), cell.real.pose.height, cell.real.depth)
    presumed = shapely.union_all(shapely.buffer(shapely.points(around), radius)) if around is not None else None
    return evidence.plan(poses, free_in_sight=True, presumed_free=presumed).plan


def training_protocol(dataset: Dataset, cells: list[CellTraining]) -> Protocol:
    """The protocol on the floor the real views saw (:func:`seen_floor_plan`, unseen floor presumed
    free within ``test_radius`` of the drawn cells), on the dataset's grid of cells."""
    plan = dataset.plan
    floor = seen_floor_plan(cells, plan.grid.centroids()[list(plan.cells)], plan.config.test_radius)
    return Protocol(floor, dataset.camera, plan.config, grid=plan.grid)


def class_viewpoints(protocol: Protocol, dataset: Dataset, cells: list[CellTraining]) -> dict[int, Pose]:
    """Each class's viewpoint as the robot can know it: the real view for its class, else the
    canonical viewpoint on the seen floor (:meth:`Protocol.canonical_viewpoints`), or, where the
    seen floor has none, the spot ``viewpoint_distance`` behind the cell's centroid."""
    c = dataset.plan.config
    viewpoints: dict[int, Pose] = {}
    height_of_rank = {cell.real_class // c.orientations: cell.real.pose.height for cell in cells}
    for rank, cell in enumerate(dataset.plan.cells):
        height = height_of_rank[rank]
        found = protocol.canonical_viewpoints(cell, height)
        for o, seen in enumerate(found):
            if seen is not None:
                viewpoints[rank * c.orientations + o] = seen[0]
            else:
                yaw = protocol.heading(o)
                x, y = protocol.centroids[cell] - c.viewpoint_distance * np.array([math.cos(yaw), math.sin(yaw)])
                viewpoints[rank * c.orientations + o] = Pose(float(x), float(y), yaw, height)
    viewpoints.update({cell.real_class: cell.real.pose for cell in cells})
    return viewpoints


def training_plan(dataset: Dataset, config: TrainingConfig, views: Views) -> TrainingPlan:
    """Each cell's real view, and the pose and source views of every class's pseudo-views, seeded.

    Poses (``config.poses``): ``"class"`` draws ``synthetic_per_class`` poses over the
    region of poses of each class, as the protocol draws test views (keeping up to
    ``synthetic_per_level`` of them for each of L2 and L3); ``"canonical"`` gives
    a class without a real view its training viewpoint and ``synthetic_per_class - 1``
    jittered copies (the real class: the jittered copies beside its real view).

    Sources (``config.sources``): ``"own"`` renders a class from its cell's real view;
    ``"seen"`` adds the other cells' real views that see at least ``min_source_coverage``
    of the floor the pose sees, most first, up to ``max_sources`` in all.
    """
    rng = stream(config.seed, "pseudo_poses")
    train = dataset.split("train")
    rank_of_cell = {cell: rank for rank, cell in enumerate(dataset.plan.cells)}
    orientations = dataset.plan.config.orientations
    cells = training_cells(dataset, views)
    index_of_rank = {rank_of_cell[s.cell]: i for i, s in enumerate(train)}
    protocol = training_protocol(dataset, cells)
    viewpoints = class_viewpoints(protocol, dataset, cells)
    real_classes = {cell.real_class for cell in cells}

    drawn: list[tuple[int, Pose, int]] = []  # (place, pose, group)
    if config.poses == "class":
        height = train[0].pose.height
        level_polygons = None
        if config.synthetic_per_level:
            real_place = sorted(real_classes)  # by cell rank: a cell's classes are rank * orientations + o
            level_polygons = protocol.level_reference_polygons(viewpoints, real_place)
        class_poses = protocol.class_poses(
            dataset.plan.cells, config.synthetic_per_class, height, rng, config.synthetic_per_level, level_polygons
        )
        for place, poses in sorted(class_poses.items()):
            drawn.extend([(place, pose, len(drawn) + i) for i, pose in enumerate(poses)])
    else:
        for group, (place, pose) in enumerate(sorted(viewpoints.items())):
            first = [] if place in real_classes else [pose]
            jitters = [jittered(pose, rng, config.jitter_m, config.jitter_deg) for _ in range(config.synthetic_per_class - 1)]
            drawn.extend((place, p, group) for p in first + jitters)

    real_polygons = [protocol.polygon(s.pose) for s in train]
    pseudo = []
    for place, pose, _ in drawn:
        own = index_of_rank[place // orientations]
        sources = [own]
        if config.sources == "seen" and config.max_sources > 1:
            seen = protocol.polygon(pose)
            area = seen.area
            coverage = [(seen.intersection(poly).area / area if area > 0 else 0.0, i) for i, poly in enumerate(real_polygons) if i != own]
            ranked = sorted((c, i) for c, i in coverage if c >= config.min_source_coverage)[::-1]
            sources += [i for _, i in ranked[: config.max_sources - 1]]
        pseudo.append(PseudoView(place, pose, tuple(sources)))
    return TrainingPlan(cells, pseudo, [group for _, _, group in drawn])


PSEUDO_VIEWS = "pseudo_views.jsonl"
"""Where a run records its pseudo-views (:func:`pseudo_view_records`)."""


def pseudo_view_records(plan: TrainingPlan, dataset: Dataset) -> list[dict[str, object]]:
    """One record per pseudo-view: its ``class``, ``pose`` (``x``, ``y`` in metres, ``yaw`` in
    radians, as ``predictions.jsonl``'s test poses) and ``sources``, the ids of the real views it
    is synthesized from."""
    train = dataset.split("train")
    return [
        {"class": p.place, "pose": {"x": p.pose.x, "y": p.pose.y, "yaw": p.pose.yaw}, "sources": [train[i].id for i in p.sources]}
        for p in plan.pseudo
    ]
