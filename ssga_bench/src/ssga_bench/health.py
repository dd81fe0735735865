"""A dataset folder's health, checked without changing anything (``ssga workspace verify``).

Every file of a dataset (:mod:`ssga_bench.dataset`) is checked against what the folder
itself records: the header (``dataset.json``), the plan, the floor plan, the fitted
values and the manifest must read as ssga wrote them, and every view file the manifest
lists must be there, whole, and of the camera's size and the channel's kind. A view
file is checked cheaply: its size, its first 26 bytes (signature, width, height, bit
depth, colour type) and its last 12 (the IEND chunk that a file cut short lacks); with
``decode``, every chunk's CRC and the inflated image data too (a bit flipped inside).

What is damaged is re-made from the workspace's source by ``ssga workspace build`` over
the folder (and before ``ssga run`` or ``bench`` start), bit for bit as it was written
(:func:`ssga_bench.dataset_build.build_dataset`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ssga_core.errors import InputError, SsgaError
from ssga_bench.dataset import CHANNELS, FITTED, RECORDS, header_problem, plan_from_records
from ssga_bench.io import exists, path_errors, png_problem, read_json, read_jsonl
from ssga_bench.protocol import Plan, ProtocolConfig
from ssga_bench.workspace import FloorPlan

HEAL = "re-make them with `ssga workspace build --config CONFIG --out {root}` (CONFIG: the config it was built from; `ssga run` with it does the same)"
"""How a dataset's damaged files are re-made, for messages."""


def damage_line(damage: dict[str, str], *, why: bool = True, first: int = 3) -> str:
    """``"2 damaged or missing files: rgb/a.png (missing), depth/b.png (empty (0 bytes))"``: the first few, and how many more."""
    n = len(damage)
    shown = ", ".join(f"{path} ({reason})" if why else path for path, reason in list(damage.items())[:first])
    more = f" and {n - first} more" if n > first else ""
    return f"{n} damaged or missing file{'s' if n != 1 else ''}: {shown}{more}"


@dataclass
class DatasetHealth:
    """What :func:`check_dataset` found: every damaged or missing file, and what could be read."""

    root: Path
    damaged: dict[str, str] = field(default_factory=dict)
    """Path relative to the folder -> why (``"missing"``, ``"empty (0 bytes)"``, ``"truncated (...)"``)."""
    finished: bool = False
    """Whether the build finished (``manifest.jsonl`` is there, readable or not)."""
    files: int = 0
    """Files checked."""
    views: int = 0
    """Views whose files were checked."""
    decoded: bool = False
    seconds: float = 0.0
    header: dict[str, Any] | None = None
    plan: Plan | None = None
    rows: list[dict[str, Any]] | None = None
    """The manifest's rows, if it reads as ssga wrote it."""

    @property
    def healthy(self) -> bool:
        return self.finished and not self.damaged

    def view_damage(self) -> dict[str, set[str]]:
        """Sample id -> the channels whose files are damaged or missing."""
        found: dict[str, set[str]] = {}
        for path in self.damaged:
            channel, _, name = path.partition("/")
            if channel in CHANNELS and name.endswith(".png"):
                found.setdefault(name.removesuffix(".png"), set()).add(channel)
        return found

    def records(self) -> set[str]:
        """The dataset's own files (``plan.json``, ...) that are damaged or missing."""
        return {path for path in self.damaged if "/" not in path}

    def lines(self) -> list[str]:
        """One line per damaged or missing file: ``root/path: why``."""
        return [f"{self.root / path}: {why}" for path, why in self.damaged.items()]

    def summary(self) -> str:
        """One line: healthy, or how many files are damaged, which (the first few), and the command that re-makes them."""
        how = f"{self.files} files of {self.views} views checked ({'decoded' if self.decoded else 'sizes, headers and ends'}) in {self.seconds:.2f} s"
        if self.healthy:
            return f"{self.root}: healthy: {how}"
        if not self.damaged:
            return f"{self.root}: the build did not finish (no manifest.jsonl); `ssga workspace build --config CONFIG --out {self.root}` resumes it"
        unfinished = "" if self.finished else "the build did not finish (no manifest.jsonl); "
        return f"{self.root}: {unfinished}{damage_line(self.damaged)}; {HEAL.format(root=self.root)}"


def check_dataset(root: str | Path, *, decode: bool = False) -> DatasetHealth:
    """Check every file of the dataset at ``root`` against what the folder records; nothing is written.

    Args:
        decode: check every view file's chunk CRCs and image data as well (a bit flipped
            inside a file); default: sizes, headers and ends only (a missing, empty or
            truncated file, one of another size or kind).
    """
    with path_errors():
        return _check(Path(root), decode)


def _check(root: Path, decode: bool) -> DatasetHealth:
    start = time.perf_counter()
    try:
        root.stat()  # a path the system refuses (too long, through a file): a PathError naming it
    except FileNotFoundError:
        raise InputError(f"{root}: no such folder; a dataset is a folder made by `ssga workspace build`") from None
    if not root.is_dir():
        raise InputError(f"{root}: not a folder; a dataset is a folder made by `ssga workspace build`")
    if not any(exists(root / name) for name in RECORDS):
        raise InputError(f"{root}: not an ssga dataset (no dataset.json); build one with `ssga workspace build`")
    health = DatasetHealth(root, decoded=decode)
    damaged = health.damaged

    def record(name: str) -> Any:
        health.files += 1
        if not exists(root / name):
            damaged[name] = "missing"
            return None
        if (root / name).stat().st_size == 0:
            damaged[name] = "empty (0 bytes)"
            return None
        try:
            return read_json(root / name)
        except SsgaError as exc:
            damaged[name] = str(exc).removeprefix(f"{root / name}: ")
            return None

    header = record("dataset.json")
    if header is not None:
        problem = header_problem(header)
        if problem:
            damaged["dataset.json"] = problem
            header = None
    health.header = header

    floor = record("floorplan.json")
    if floor is not None:
        try:
            FloorPlan.from_json(floor, "floorplan.json")
        except SsgaError as exc:
            damaged["floorplan.json"] = f"not a floor plan ({exc})"

    fitted = None
    if exists(root / FITTED):
        fitted = record(FITTED)
        if fitted is not None and not (isinstance(fitted, dict) and isinstance(fitted.get("fitted"), dict)):
            damaged[FITTED] = "not the fitted values ssga wrote"
            fitted = None

    raw_plan = record("plan.json")
    if raw_plan is not None and header is not None:
        try:
            health.plan = plan_from_records(raw_plan, fitted, str(header["workspace"]), ProtocolConfig.model_validate(header["protocol"]))
        except (SsgaError, ValueError) as exc:
            damaged["plan.json"] = f"not a plan written by ssga ({' '.join(str(exc).split())[:160]})"
    plan = health.plan
    if plan is not None and not exists(root / FITTED) and FITTED not in damaged:
        configured = ProtocolConfig.model_validate(header["protocol"]) if header else None
        if configured is not None and (plan.grid.cell_size != configured.cell_size or len(plan.cells) != configured.cells):
            damaged[FITTED] = "missing (plan.json was planned with values fitted to the workspace)"

    health.finished = exists(root / "manifest.jsonl")
    rows = None
    if health.finished:
        health.files += 1
        try:
            rows = list(read_jsonl(root / "manifest.jsonl"))
            problem = _manifest_problem(rows, plan)
        except SsgaError as exc:
            problem = str(exc).removeprefix(f"{root / 'manifest.jsonl'}")
        if problem:
            damaged["manifest.jsonl"] = problem
            rows = None
    health.rows = rows

    camera = header.get("camera") if header else None
    size = (camera["width"], camera["height"]) if isinstance(camera, dict) else None
    if rows is not None:
        listed = [(row["id"], ch) for row in rows for ch in CHANNELS if row.get(ch)]
        health.views = len(rows)
    else:  # no manifest to say which files a view has: those that are there
        ids = [s.id for s in plan.samples] if plan is not None else []
        listed = [(i, ch) for i in ids for ch in CHANNELS if exists(root / ch / f"{i}.png")]
        health.views = len({i for i, _ in listed})
    for sample_id, channel in listed:
        path = f"{channel}/{sample_id}.png"
        problem = png_problem(root / path, size=size, kind="rgb" if channel == "rgb" else "grey16", decode=decode)
        health.files += 1
        if problem:
            damaged[path] = problem
    health.seconds = time.perf_counter() - start
    return health


def _manifest_problem(rows: list[Any], plan: Plan | None) -> str | None:
    """Why ``rows`` are not the manifest ssga writes for ``plan`` (None: they are)."""
    for n, row in enumerate(rows, 1):
        if not isinstance(row, dict) or not isinstance(row.get("id"), str):
            return f"line {n}: not a manifest row written by ssga (no id)"
        for channel in CHANNELS:
            if row.get(channel) not in (None, f"{channel}/{row['id']}.png"):
                return f"line {n}: {channel} {row.get(channel)!r} is not the file ssga writes for view {row['id']!r}"
    if plan is not None and [row["id"] for row in rows] != [s.id for s in plan.samples]:
        return f"its {len(rows)} rows are not plan.json's {len(plan.samples)} views"
    return None

