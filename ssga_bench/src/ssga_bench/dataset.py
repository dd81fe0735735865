"""A benchmark workspace on disk: the protocol's plan, rendered, with a manifest.

Layout of a dataset folder::

    dataset.json     what was built: source and its config, protocol config, camera, format
    floorplan.json   the floor plan (FloorPlan.to_json), for visibility and plots
    plan.json        the grid, the selected cells and every sample (written before rendering)
    rgb/<id>.png     RGB, 8-bit
    depth/<id>.png   metric planar depth, 16-bit millimetres (0 = unknown), where the source has it
    semantic/<id>.png, instance/<id>.png
                     ids + 1, 16-bit (0 = unknown), where the source has them
    manifest.jsonl   one line per view: id, split, place, cell, orientation, pose, VO, level,
                     and its files; written last, so its presence means the build finished

Splits: ``train`` is the one real image per cell, ``test`` the test views, ``target``
the synthesis targets of the classes without a real image (their images are rendered
as an oracle for judging synthesis, and never used for training).

This module is what a dataset on disk is, and reading it (:class:`Dataset`); building,
resuming and healing one is :mod:`ssga_bench.dataset_build`.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ssga_core.data import View
from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose
from ssga_bench.io import (
    depth_from_png16,
    exists,
    path_errors,
    ids_from_png16,
    read_json,
    read_jsonl,
    read_png,
)
from ssga_bench.protocol import Grid, Plan, ProtocolConfig, Sample
from ssga_bench.workspace import FloorPlan

FORMAT = 1
CHANNELS = ("rgb", "depth", "semantic", "instance")
FITTED = "fitted.json"
"""The protocol values a build chose because the configured ones did not fit the workspace (``protocol.fit``)."""
RECORDS = ("manifest.jsonl", "plan.json", FITTED, "floorplan.json", "dataset.json")
"""The dataset's own files, in the order a replaced dataset's are deleted (the header last)."""


def sample_record(sample: Sample) -> dict[str, Any]:
    record = asdict(sample)
    pose = record.pop("pose")
    return {**record, **{k: pose[k] for k in ("x", "y", "yaw", "height")}}


def sample_from_record(record: dict[str, Any]) -> Sample:
    try:
        pose = Pose(record["x"], record["y"], record["yaw"], record["height"])
        fields = {k: record.get(k) for k in ("vo", "vo_landmark", "level", "source")}
        return Sample(record["id"], record["split"], int(record["place"]), int(record["cell"]), int(record["orientation"]), pose, **fields)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"sample record {record.get('id', record)!r}: missing or bad field ({exc})") from None


def protocol_record(protocol: ProtocolConfig) -> dict[str, Any]:
    """The protocol as a dataset records it: without ``fit`` (it changes nothing a finished dataset
    holds; a fitted one says so in fitted.json), and without a setting added since at its default,
    so that datasets built before it stay valid."""
    added_since = {"val_per_level"} if protocol.val_per_level == 0 else set()
    return protocol.model_dump(mode="json", exclude={"fit", *added_since})


def header_problem(header: Any) -> str | None:
    """Why ``header`` is not a ``dataset.json`` this ssga reads (None: it is)."""
    if not isinstance(header, dict):
        return f"not a dataset header written by ssga (a JSON {type(header).__name__})"
    if header.get("format") != FORMAT:
        return f"dataset format {header.get('format')!r}, this ssga reads format {FORMAT}"
    try:
        ProtocolConfig.model_validate(header["protocol"])
        Camera(**header["camera"])
        str(header["workspace"])
    except (KeyError, TypeError, ValueError) as exc:
        detail = " ".join(str(exc).split())[:200]
        return f"not a dataset header written by ssga ({type(exc).__name__}: {detail})"
    return None


def plan_from_records(raw: Any, fitted: Any, name: str, config: ProtocolConfig) -> Plan:
    """The plan of a ``plan.json`` (and the ``fitted.json`` beside it, if any); InputError if it is not one ssga wrote."""
    try:
        if fitted is not None:  # planned with the values fitted to the workspace, not the configured ones
            config = config.model_copy(update=fitted["fitted"])
        grid = Grid(**raw["grid"])
        return Plan(name, config, grid, tuple(raw["cells"]), tuple(sample_from_record(r) for r in raw["samples"]))
    except (KeyError, TypeError) as exc:
        raise InputError(f"not a plan written by ssga ({exc})") from None


def read_plan(out: Path, name: str, config: ProtocolConfig) -> Plan:
    raw = read_json(out / "plan.json")
    fitted = read_json(out / FITTED) if (out / FITTED).exists() else None
    try:
        return plan_from_records(raw, fitted, name, config)
    except InputError as exc:
        raise InputError(f"{out / 'plan.json'}: {exc}") from None


class Dataset:
    """A finished benchmark dataset folder (see the module docstring)."""

    def __init__(self, root: Path, header: dict[str, Any], plan: Plan, rows: dict[str, dict[str, Any]]) -> None:
        self.root = root
        self.header = header
        self.plan = plan
        self._rows = rows
        self.remade: tuple[str, ...] = ()
        """The files the build that opened it re-made because they were damaged or missing (paths relative to ``root``)."""

    @classmethod
    @path_errors()
    def open(cls, root: str | Path) -> Dataset:
        root = Path(root)
        if not exists(root / "dataset.json"):
            raise InputError(f"{root}: not an ssga dataset (no dataset.json); build one with `ssga workspace build`")
        if not exists(root / "manifest.jsonl"):
            raise InputError(f"{root}: the build did not finish (no manifest.jsonl); run `ssga workspace build` again to resume it")
        header = read_json(root / "dataset.json")
        # A damaged header or manifest (valid JSON of another shape) is a one-line error naming it.
        problem = header_problem(header)
        if problem:
            raise InputError(f"{root / 'dataset.json'}: {problem}")
        plan = read_plan(root, str(header["workspace"]), ProtocolConfig.model_validate(header["protocol"]))
        try:
            rows = {row["id"]: row for row in read_jsonl(root / "manifest.jsonl")}
        except (KeyError, TypeError) as exc:
            raise InputError(f"{root / 'manifest.jsonl'}: not a manifest written by ssga (a row without an id: {exc!r})") from None
        return cls(root, header, plan, rows)

    @classmethod
    def from_health(cls, health: Any) -> Dataset:
        """The dataset a healthy :class:`~ssga_bench.health.DatasetHealth` read (its files are not read again)."""
        assert health.healthy and health.header is not None and health.plan is not None and health.rows is not None
        return cls(health.root, health.header, health.plan, {row["id"]: row for row in health.rows})

    @property
    def name(self) -> str:
        return str(self.header["workspace"])

    @property
    def camera(self) -> Camera:
        return Camera(**self.header["camera"])

    @property
    def num_classes(self) -> int:
        return self.plan.num_classes

    def split(self, split: str) -> list[Sample]:
        return self.plan.split(split)  # type: ignore[arg-type]

    @property
    def place_cells(self) -> np.ndarray | None:
        """``(C,)`` the grid cell of each class (its location), read from the plan's samples; None
        where some class has no sample to say it."""
        cells = np.full(self.num_classes, -1, dtype=np.int64)
        for s in self.plan.samples:
            cells[s.place] = s.cell
        return cells if np.all(cells >= 0) else None

    def sample(self, sample_id: str) -> Sample:
        """The sample of the plan with this id."""
        if not hasattr(self, "_by_id"):
            self._by_id = {s.id: s for s in self.plan.samples}
        try:
            return self._by_id[sample_id]
        except KeyError:
            raise InputError(f"{self.root}: no view {sample_id!r} in plan.json") from None

    def has_image(self, sample: Sample) -> bool:
        """Whether the dataset holds the sample's image (a captured workspace's synthesis targets have none)."""
        return (self._rows.get(sample.id) or {}).get("rgb") is not None

    def view(self, sample: Sample, channels: Collection[str] = CHANNELS) -> View:
        """Load a sample's view: RGB and, of depth, semantic and instance ids, those in ``channels`` it has."""
        row = self._rows.get(sample.id)
        if row is None or row.get("rgb") is None:
            raise InputError(f"{self.root}: no image of view {sample.id!r} in manifest.jsonl")

        def read(name: str, color: bool) -> np.ndarray:
            try:
                return read_png(self.root / row[name], color=color)
            except InputError as exc:
                raise InputError(f"{exc}; `ssga workspace verify {self.root}` lists what is damaged, `ssga workspace build` over it re-makes it") from None

        rgb = read("rgb", True)

        def single(name: str) -> np.ndarray | None:
            return read(name, False) if row.get(name) and name in channels else None

        depth, semantic, instance = single("depth"), single("semantic"), single("instance")
        depth = depth_from_png16(depth) if depth is not None else None
        semantic = ids_from_png16(semantic) if semantic is not None else None
        instance = ids_from_png16(instance) if instance is not None else None
        try:
            return View(rgb=rgb, pose=sample.pose, camera=self.camera, depth=depth, semantic=semantic, instance=instance)
        except InputError as exc:
            raise InputError(f"{self.root / row['rgb']} (view {sample.id}): {exc}") from None

    @property
    def floor_plan(self) -> FloorPlan:
        return FloorPlan.from_json(read_json(self.root / "floorplan.json"), str(self.root / "floorplan.json"))
