"""How the protocol samples: the real training view and synthesis targets of each chosen
cell, and test (and validation) views drawn around the cells until every class, and every
level's quota, has its share (the definitions: :mod:`ssga_bench.protocol`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import shapely

from ssga_core.errors import InputError
from ssga_core.geometry import Pose
from ssga_bench.protocol_geometry import ProtocolGeometry
from ssga_bench.protocol_plan import Sample, Split, level_of
from ssga_bench.visibility import view_overlap, visibility_polygon


RESERVE_TRIES = 20.0
"""Candidates drawn per pseudo-view pose wanted while slots wait for the rare levels."""


class ProtocolSampling(ProtocolGeometry):
    """Training samples, test views and poses drawn over a class's region, on one floor plan
    and camera (:class:`~ssga_bench.protocol.Protocol` chooses the cells they are drawn for)."""

    def _training_samples(
        self,
        chosen: list[tuple[int, list[Pose]]],
        reals: list[int],
        real_poses: dict[int, Pose],
        sources: dict[int, int] | None = None,
    ) -> tuple[list[Sample], dict[int, Pose], list[int]]:
        """The real training sample and the synthesis targets of each chosen cell.

        Returns the samples, each class's training viewpoint, and each cell's real class.
        """
        c = self.config
        samples: list[Sample] = []
        training: dict[int, Pose] = {}
        real_place: list[int] = []
        for rank, ((cell, views), real) in enumerate(zip(chosen, reals)):
            real_place.append(rank * c.orientations + real)
            for o, canonical in enumerate(views):
                place = rank * c.orientations + o
                split: Split = "train" if o == real else "target"
                pose = real_poses.get(place, canonical)
                source = (sources or {}).get(place)
                samples.append(Sample(f"{split}-{place:04d}", split, place, cell, o, pose, source=source))
                training[place] = pose
        return samples, training, real_place

    def _test_sample(
        self,
        place: int,
        cell: int,
        orientation: int,
        pose: Pose,
        distances: np.ndarray,
        polygons: dict[int, shapely.Polygon],
        real_place: list[int],
        number: int,
        source: int | None = None,
    ) -> Sample:
        c = self.config
        seen = visibility_polygon(pose, self.camera.hfov_deg, distances)
        vo = view_overlap(seen, polygons[place])
        vo_landmark = view_overlap(seen, polygons[real_place[place // c.orientations]])
        level = level_of(vo if c.level_reference == "class" else vo_landmark, c.level_bounds)
        return Sample(f"test-{place:04d}-{number:05d}", "test", place, cell, orientation, pose, vo, vo_landmark, level, source)

    def _candidates(
        self, cells: list[int], around_ranks: Callable[[], np.ndarray], height: float, rng: np.random.Generator, batch: int = 64
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """One batch of candidate views drawn as test views are: a position uniform in the free
        floor within ``test_radius`` of a cell centroid (cells by rank from ``around_ranks()``,
        one per candidate), a uniform heading. Returns positions, yaws, ray distances and the
        grid cell each belongs to (``-1``: none), for the candidates on free floor."""
        c = self.config
        around = self.centroids[np.asarray(cells)[around_ranks()]]
        r = c.test_radius * np.sqrt(rng.random(batch))
        phi = rng.random(batch) * 2 * math.pi
        xy = around + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)
        yaw = rng.random(batch) * 2 * math.pi
        free = self.is_free(xy)
        xy, yaw = xy[free], yaw[free]
        if not len(xy):
            return xy, yaw, np.zeros((0, c.rays)), np.zeros(0, dtype=int)
        distances = self.rays(xy, yaw)
        return xy, yaw, distances, self.assign(xy, yaw, distances)

    def class_poses(
        self,
        cells: Sequence[int],
        per_class: int,
        height: float,
        rng: np.random.Generator,
        per_level: int = 0,
        level_polygons: Mapping[int, shapely.Polygon] | None = None,
    ) -> dict[int, list[Pose]]:
        """``per_class`` poses of every class of ``cells`` (grid cells in class order), drawn
        over the region of poses that belong to the class, the way test views are drawn.

        With ``per_level``, each class keeps that many of its poses for each of L2 and L3 (the
        view overlap with the class's polygon in ``level_polygons``, the levels as its test
        views have them): drawn as test views are, 1-2% of poses are at L3, so most classes would
        have none like the L3 test views. The kept slots wait for up to ``RESERVE_TRIES``
        candidates per pose wanted, then open to any pose, so each class keeps its count.

        A class whose poses are too rare to find within ``max_candidates`` tries per pose
        wanted gets fewer (possibly none).
        """
        c = self.config
        cells = list(cells)
        rank_of = {cell: rank for rank, cell in enumerate(cells)}
        poses: dict[int, list[Pose]] = {place: [] for place in range(len(cells) * c.orientations)}
        levels = {place: np.zeros(4, dtype=int) for place in poses}
        reserve = min(per_level, per_class // 3) if level_polygons is not None else 0
        wanted = per_class * len(poses)
        reserve_tries = int(RESERVE_TRIES * wanted) if reserve else 0

        def takes(place: int, level: int | None, reserving: bool) -> bool:
            have = len(poses[place])
            if have >= per_class:
                return False
            if not reserving or level is None:
                return True
            unmet = [max(reserve - levels[place][lv], 0) for lv in (2, 3)]
            return (level in (2, 3) and unmet[level - 2] > 0) or per_class - have > sum(unmet)

        tried, batch = 0, 64
        while sum(len(p) for p in poses.values()) < wanted and tried < wanted * c.max_candidates + reserve_tries:
            reserving = tried < reserve_tries
            short = np.array([place // c.orientations for place, p in poses.items() if len(p) < per_class])
            xy, yaw, distances, cell = self._candidates(cells, lambda: rng.choice(short, size=batch), height, rng, batch)
            tried += batch
            orientation = self.orientation_of(yaw)
            for k in range(len(xy)):
                if cell[k] not in rank_of:
                    continue
                place = rank_of[cell[k]] * c.orientations + int(orientation[k])
                if len(poses[place]) >= per_class:
                    continue
                pose = Pose(float(xy[k, 0]), float(xy[k, 1]), float(yaw[k]), height)
                level = None
                if reserving:  # levels matter only while slots are kept
                    seen = visibility_polygon(pose, self.camera.hfov_deg, distances[k])
                    level = level_of(view_overlap(seen, level_polygons[place]), c.level_bounds)  # type: ignore[index]
                if takes(place, level, reserving):
                    poses[place].append(pose)
                    if level is not None:
                        levels[place][level] += 1
        return poses

    def level_reference_polygons(self, training: Mapping[int, Pose], real_place: Sequence[int]) -> dict[int, shapely.Polygon]:
        """The polygon each class's levels are measured against: its training viewpoint's
        (``level_reference = "class"``) or its cell's real view's (``"landmark"``)."""
        c = self.config
        own = {place: self.polygon(pose) for place, pose in training.items()}
        if c.level_reference == "class":
            return own
        return {place: own[real_place[place // c.orientations]] for place in own}

    def _sample_tests(
        self,
        cells: list[int],
        training: dict[int, Pose],
        real_place: list[int],
        height: float,
        rng: np.random.Generator,
        progress: Callable[[int, int], None] | None,
        split: Split = "test",
        per_class: int | None = None,
    ) -> list[Sample]:
        """``per_class`` views of every class (default ``test_per_class``); views then continue
        (up to twice that per class) until every level has the split's quota (``test_per_level``,
        ``val_per_level``)."""
        c = self.config
        per_class = c.test_per_class if per_class is None else per_class
        quota = c.test_per_level if split == "test" else c.val_per_level
        rank_of = {cell: rank for rank, cell in enumerate(cells)}
        wanted = per_class * len(cells) * c.orientations
        counts = np.zeros(len(cells) * c.orientations, dtype=int)
        levels = np.zeros(4, dtype=int)
        polygons = {place: self.polygon(pose) for place, pose in training.items()}
        tests: list[Sample] = []
        tried, batch = 0, 64

        def short_levels() -> bool:
            return bool(quota) and bool((levels[1:] < quota).any())

        while ((counts < per_class).any() or short_levels()) and tried < wanted * c.max_candidates:
            # Draw around cells that still need views, so rare classes do not starve.
            short = np.flatnonzero(counts < per_class) // c.orientations
            if not len(short):
                short = np.flatnonzero(counts < 2 * per_class) // c.orientations
            if not len(short):
                break
            xy, yaw, distances, cell = self._candidates(cells, lambda: rng.choice(short, size=batch), height, rng, batch)
            tried += batch
            orientation = self.orientation_of(yaw)
            for k in range(len(xy)):
                if cell[k] not in rank_of:
                    continue
                place = rank_of[cell[k]] * c.orientations + int(orientation[k])
                if counts[place] >= (2 * per_class if quota else per_class):
                    continue
                pose = Pose(float(xy[k, 0]), float(xy[k, 1]), float(yaw[k]), height)
                sample = self._test_sample(place, int(cell[k]), int(orientation[k]), pose, distances[k], polygons, real_place, int(counts[place]))
                if counts[place] >= per_class and levels[sample.level] >= quota:
                    continue  # beyond the class's share, only a level still short of its quota takes a view
                tests.append(dataclasses.replace(sample, id=sample.id.replace("test", split, 1), split=split) if split != "test" else sample)
                counts[place] += 1
                levels[sample.level] += 1
            if progress is not None:  # a level's quota can draw past the classes' share: the total grows with it
                progress(len(tests), max(wanted, len(tests)))
        missing = int((per_class - counts).clip(0).sum())
        if missing:
            raise InputError(
                f"protocol: {missing} of {wanted} {split} views could not be placed after {tried} candidate poses; "
                f"raise protocol.test_radius or protocol.max_candidates, or lower protocol.{split}_per_class "
                "(`ssga workspace build --suggest` tries other test radii)"
            )
        return sorted(tests, key=lambda s: s.id)
