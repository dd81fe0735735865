"""The per-view tasks the executors map: plain functions of one picklable job.

Each opens what it needs through :func:`ssga_bench.execution.memo` (a dataset, a stage, a
workspace: once per worker process, not per task) and sends back arrays or encoded
files; the driver alone writes the dataset and the feature cache. A job never depends
on the number of workers (the caller cuts jobs into fixed chunks of views), so a result
is the same whichever worker computes it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from ssga_bench.cache import FeatureCache, compute_many, encode_entry, stage_key, view_key
from ssga_bench.execution import memo
from ssga_core.config import ResolvedStage
from ssga_core.data import View
from ssga_core.errors import InputError, MissingWeightsError
from ssga_core.geometry import Pose
from ssga_core.stages import LocalDescriptor, Parser

T = TypeVar("T")


def chunks(items: Sequence[T], size: int) -> Iterator[tuple[T, ...]]:
    """``items`` in consecutive chunks of ``size`` (the last shorter): the same cut whatever the executor."""
    for start in range(0, len(items), size):
        yield tuple(items[start : start + size])


def span(noun: str, items: Sequence[str]) -> str:
    """A chunk's items for a message: ``"view a"``, or ``"views a ... z"``."""
    return f"{noun}s {items[0]} ... {items[-1]}" if len(items) > 1 else f"{noun} {items[0]}"


@contextmanager
def in_folder(folder: str) -> Iterator[None]:
    """Run in ``folder`` (where the user's command ran): a worker opens the user's relative
    paths, and its errors name them as the user wrote them (a Ray worker runs elsewhere)."""
    before = os.getcwd()
    if folder == before:
        yield
        return
    try:
        os.chdir(folder)
    except OSError as exc:
        raise InputError(f"{folder}: {exc.strerror} on this worker's machine; every node needs the shared folder at the same path") from None
    try:
        yield
    finally:
        os.chdir(before)


def opened_stage(stage: ResolvedStage) -> Any:
    """The stage ``stage`` describes, built once per process (a learned stage loads its network once)."""
    return memo(("stage", stage.cls.__module__, stage.cls.__qualname__, stage.config.model_dump_json()), stage.create)


def opened_dataset(root: str) -> Any:
    """The dataset at ``root`` (an absolute path: Ray's workers do not run in the driver's
    folder), opened once per process while its manifest stays the same."""
    from ssga_bench.dataset import Dataset

    manifest = Path(root) / "manifest.jsonl"
    stamp = manifest.stat().st_mtime_ns if manifest.exists() else None
    return memo(("dataset", root, stamp), lambda: Dataset.open(root))


def opened_workspace(source: ResolvedStage) -> Any:
    """The workspace ``source`` opens (a generated home, a loaded mesh), once per process."""
    return memo(("workspace", source.cls.__module__, source.cls.__qualname__, source.config.model_dump_json()), lambda: source.create().open())


# -- parse and describe real views ------------------------------------------------------------


@dataclass(frozen=True)
class DescribeJob:
    """A chunk of a dataset's real views to parse and describe with each of ``stages``.

    Attributes:
        dataset: the dataset folder.
        ids: the views' sample ids.
        stages: parsers and local descriptors (what the feature cache holds).
        cache: the feature cache's folder: entries already there are not computed again.
    """

    dataset: str
    ids: tuple[str, ...]
    stages: tuple[ResolvedStage, ...]
    cache: str | None = None

    def what(self) -> str:
        return f"{span('view', self.ids)} of {self.dataset}"


@dataclass(frozen=True)
class Described:
    """What :func:`describe_views` sends back: new cache entries, and seconds per stage kind."""

    entries: list[tuple[tuple[str, str], bytes]]
    """``(stage key, view key)`` and the entry's encoded ``.npz``."""
    seconds: dict[str, float]
    counts: dict[str, int]
    """Views handled per phase (``load views``: the chunk; ``parse``, ``describe``: computed, summed over stages)."""
    without_weights: tuple[str, ...] = ()
    """Stages (their cache keys) that could not run for want of their weights."""
    view_keys: tuple[tuple[str, str], ...] = ()
    """``(sample id, content key)`` of every view of the chunk."""


def describe_views(job: DescribeJob) -> Described:
    """Regions and local features of a chunk of real views, each stage over the chunk as one batch."""
    dataset = opened_dataset(job.dataset)
    cache = FeatureCache(job.cache) if job.cache is not None else None
    start = time.perf_counter()
    views = [dataset.view(dataset.sample(sample_id)) for sample_id in job.ids]
    keys = [view_key(view) for view in views]
    seconds = {"load views": time.perf_counter() - start}
    counts = {"load views": len(views)}
    entries = []
    without_weights = []
    for ref in job.stages:
        try:
            stage = opened_stage(ref)
            assert isinstance(stage, (Parser, LocalDescriptor)), f"{ref.name}: the cache holds parsers' and local descriptors' output"
            skey = stage_key(stage)
            todo = [i for i, key in enumerate(keys) if cache is None or not cache.has((skey, key))]
            if not todo:
                continue
            start = time.perf_counter()
            computed = compute_many(stage, [views[i] for i in todo])
        except MissingWeightsError:
            without_weights.append(stage_key(ref))  # its variants report themselves "not run", with the field to set
            continue
        phase = "parse" if isinstance(stage, Parser) else "describe"
        seconds[phase] = seconds.get(phase, 0.0) + time.perf_counter() - start
        counts[phase] = counts.get(phase, 0) + len(todo)
        entries.extend(((skey, keys[i]), encode_entry(arrays)) for i, arrays in zip(todo, computed))
    return Described(entries, seconds, counts, tuple(without_weights), tuple(zip(job.ids, keys)))


# -- render a workspace's views ---------------------------------------------------------------


@dataclass(frozen=True)
class RenderJob:
    """A chunk of a plan's samples to render (or, for a captured workspace, to load) from ``source``.

    Attributes:
        source: the workspace source, opened once per worker.
        samples: ``(id, pose, capture)`` per view: the pose to render, or the capture to load.
        captured: whether the workspace is a captured one (views are loaded, not rendered).
    """

    source: ResolvedStage
    samples: tuple[tuple[str, Pose, Any], ...]
    captured: bool = False

    def what(self) -> str:
        return span("view", [sample[0] for sample in self.samples])


def render_views(job: RenderJob) -> list[tuple[str, dict[str, bytes]]]:
    """Each view of the chunk rendered (or loaded) and encoded as the dataset's PNG files, by channel."""
    from ssga_bench.dataset_build import encode_view

    workspace = opened_workspace(job.source)
    out = []
    for sample_id, pose, capture in job.samples:
        view: View = workspace.load(capture) if job.captured else workspace.render(pose)
        out.append((sample_id, encode_view(view)))
    return out
