"""What every variant of an experiment learns from: each cell's real view, and the pose and
source views of every class's pseudo-views (:func:`training_plan`); the pipeline
(:func:`ssga_core.pipeline.training_graphs`) builds the variant's graphs from them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ssga_bench.config import TrainingConfig
from ssga_bench.dataset import Dataset
from ssga_bench.protocol import Protocol, Sample
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
    rng = np.random.default_rng(config.seed)
    train = dataset.split("train")
    rank_of_cell = {cell: rank for rank, cell in enumerate(dataset.plan.cells)}
    orientations = dataset.plan.config.orientations
    cells = training_cells(dataset, views)
    index_of_rank = {rank_of_cell[s.cell]: i for i, s in enumerate(train)}
    protocol = Protocol(dataset.floor_plan, dataset.camera, dataset.plan.config)

    drawn: list[tuple[int, Pose, int]] = []  # (place, pose, group)
    if config.poses == "class":
        height = train[0].pose.height
        level_polygons = None
        if config.synthetic_per_level:
            viewpoints = {s.place: s.pose for s in train + dataset.split("target")}
            real_place = sorted(s.place for s in train)  # by cell rank: a cell's classes are rank * orientations + o
            level_polygons = protocol.level_reference_polygons(viewpoints, real_place)
        class_poses = protocol.class_poses(
            dataset.plan.cells, config.synthetic_per_class, height, rng, config.synthetic_per_level, level_polygons
        )
        for place, poses in sorted(class_poses.items()):
            drawn.extend([(place, pose, len(drawn) + i) for i, pose in enumerate(poses)])
    else:
        for group, s in enumerate(sorted(dataset.split("train") + dataset.split("target"), key=lambda s: s.place)):
            first = [] if s.split == "train" else [s.pose]
            jitters = [jittered(s.pose, rng, config.jitter_m, config.jitter_deg) for _ in range(config.synthetic_per_class - 1)]
            drawn.extend((s.place, pose, group) for pose in first + jitters)

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
