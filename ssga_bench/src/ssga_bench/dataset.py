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

Building is resumable: an interrupted build keeps its plan and every view already
written (each file appears atomically), and the next build renders only what is missing.
A finished dataset is only read when it is reused, so it may be read-only. Replacing
a dataset (``overwrite``) deletes only the files ssga wrote there, never anything else
the folder holds.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable, Collection
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ssga_core.config import ResolvedStage
from ssga_core.data import View
from ssga_core.errors import InputError, SsgaError
from ssga_core.geometry import Camera, Pose
from ssga_bench.io import (
    atomic_write_bytes,
    depth_from_png16,
    exists,
    path_errors,
    depth_to_png16,
    ids_from_png16,
    ids_to_png16,
    read_json,
    read_jsonl,
    png_bytes,
    read_png,
    warn,
    write_json,
    write_jsonl,
)
from ssga_bench.execution import Executor
from ssga_bench.protocol import Grid, Plan, Protocol, ProtocolConfig, Sample, capture_height, fit_protocol
from ssga_bench.workspace import AnyWorkspace, FloorPlan, Workspace

FORMAT = 1
CHANNELS = ("rgb", "depth", "semantic", "instance")
FITTED = "fitted.json"
"""The protocol values a build chose because the configured ones did not fit the workspace (``protocol.fit``)."""
RECORDS = ("manifest.jsonl", "plan.json", FITTED, "floorplan.json", "dataset.json")
"""The dataset's own files, in the order a replaced dataset's are deleted (the header last)."""
_SAMPLE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
"""What a sample id ssga writes looks like (no path separator, no leading dot)."""


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


def _header(workspace: AnyWorkspace, source: dict[str, Any], protocol: ProtocolConfig) -> dict[str, Any]:
    cam = workspace.camera
    return {
        "format": FORMAT,
        "workspace": workspace.name,
        "source": source,
        "protocol": protocol_record(protocol),
        "camera": {"width": cam.width, "height": cam.height, "hfov_deg": cam.hfov_deg},
    }


def build_workspace(
    source: ResolvedStage,
    protocol: ProtocolConfig,
    *,
    out: Path | None = None,
    overwrite: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
    batch: int = 16,
    decode: bool = False,
) -> Dataset:
    """Open a workspace source and build its benchmark dataset (see :func:`build_dataset`).

    Args:
        source: the resolved workspace source (from a config, or from command-line options).
        out: the dataset folder; default ``runs/workspaces/<workspace>-<settings hash>``,
            so experiments that differ only in their stages share the rendered workspace.
        executor: renders the views in chunks of ``batch`` on its workers, each of
            which opens the workspace once; default: in this process.
    """
    from ssga_bench.tasks import opened_workspace

    with path_errors():
        workspace = opened_workspace(source)  # the serial executor's task finds it open
    record = {"name": source.name, **source.config.model_dump(mode="json")}
    fit = protocol.fit == "auto" or (protocol.fit is None and source.cls.fits_protocol)
    if out is None:
        digest = hashlib.blake2b(json.dumps([record, protocol_record(protocol)], sort_keys=True).encode(), digest_size=4)
        out = Path("runs") / "workspaces" / f"{workspace.name}-{digest.hexdigest()}"
    return build_dataset(
        workspace,
        out,
        source=record,
        protocol=protocol,
        overwrite=overwrite,
        progress=progress,
        render=(executor, source, batch) if executor else None,
        fit=fit,
        decode=decode,
    )


def build_dataset(
    workspace: AnyWorkspace,
    out: str | Path,
    *,
    source: dict[str, Any],
    protocol: ProtocolConfig,
    overwrite: bool = False,
    progress: Callable[[str, int, int], None] | None = None,
    render: tuple[Executor, ResolvedStage, int] | None = None,
    fit: bool = False,
    decode: bool = False,
) -> Dataset:
    """Plan and render a benchmark workspace into ``out``, resuming a build left unfinished and
    re-making what is missing or damaged in a finished one.

    Whose the folder is decides what may be written: a new or empty folder (or one without
    a file ssga would write) gets a new dataset; a folder whose ``dataset.json`` ssga wrote
    with these settings is checked (:func:`ssga_bench.health.check_dataset`: sizes, headers
    and ends of its files, nothing decoded unless ``decode``) and whatever is missing or
    damaged is re-made from the workspace, the same bit for bit, and said on stderr
    (``Dataset.remade``); a healthy one is read without writing. A ``dataset.json`` that is
    damaged is re-made if the folder's plan is the one these settings give. Anything else
    is refused with one line, changing nothing: a ``dataset.json`` ssga did not write (no
    ``"format"`` key), a file of this build's that ssga did not write, a dataset built with
    other settings (unless ``overwrite``), and ``overwrite`` on a folder without ssga's
    ``dataset.json``.

    Args:
        workspace: the opened workspace: rendered at the plan's poses (at its camera
            height), or, if it is a captured workspace, its captures selected by the
            protocol and copied.
        out: the dataset folder.
        source: the workspace source's name and config, recorded so a resumed build
            can refuse a folder that holds another workspace.
        protocol: the protocol's config.
        overwrite: replace what ssga wrote in ``out`` if it was built differently.
        progress: called with ``(phase, done, total)``; phases ``"plan"`` and ``"render"``.
        render: ``(executor, source, batch)``: render on the executor's workers, each
            opening ``source`` (the workspace's source) itself, ``batch`` views per task;
            default: here, with ``workspace``.
        fit: where the protocol does not fit the workspace, plan with values that do
            (:func:`~ssga_bench.protocol.fit_protocol`), say which on stderr and record them
            in ``fitted.json``; else the planning error stands.
        decode: check the data of every view file too (a bit flipped inside one), not only its size,
            header and end.
    """
    out = Path(out)
    with path_errors():
        return _Build(workspace, out, source, protocol, progress, render, fit, decode).run(overwrite)


def _manifest_row(out: Path, sample: Sample) -> dict[str, Any]:
    files = {ch: f"{ch}/{sample.id}.png" for ch in CHANNELS}
    return {**sample_record(sample), **{ch: (path if exists(out / path) else None) for ch, path in files.items()}}


def _plan_record(plan: Plan) -> dict[str, Any]:
    return {"grid": asdict(plan.grid), "cells": list(plan.cells), "samples": [sample_record(s) for s in plan.samples]}


def _as_json(obj: Any) -> Any:
    """``obj`` as it reads back from the JSON ssga writes (tuples as lists)."""
    return json.loads(json.dumps(obj))


class _Build:
    """One ``build_dataset``: decide whose the folder is, then make what is missing or damaged."""

    def __init__(
        self, workspace: AnyWorkspace, out: Path, source: dict[str, Any], protocol: ProtocolConfig, progress: Any, render: Any, fit: bool, decode: bool
    ) -> None:
        self.workspace, self.out, self.protocol, self.progress, self.render, self.fit = workspace, out, protocol, progress, render, fit
        self.decode = decode
        self.header = _header(workspace, source, protocol)
        self.captured = not isinstance(workspace, Workspace)
        self._planned: tuple[Plan, dict[str, Any] | None] | None = None

    def planned(self) -> tuple[Plan, dict[str, Any] | None]:
        """The plan these settings give (deterministic), and the fitted values' record if the protocol was fitted."""
        if self._planned is None:
            self._planned = _make_plan(self.workspace, self.protocol, fit=self.fit, progress=self.progress, captured=self.captured)
        return self._planned

    def run(self, overwrite: bool) -> Dataset:
        out = self.out
        if exists(out) and not out.is_dir():
            raise InputError(f"{out}: is a file; the dataset needs a folder")
        kind, old, why = _marker(out)
        if kind == "foreign":
            raise InputError(f"{out / 'dataset.json'}: not written by ssga ({why}); ssga replaces only the files it wrote: choose another folder (nothing was changed)")
        if kind == "ours" and old != self.header:
            if not overwrite:
                changed = sorted(k for k in self.header if old.get(k) != self.header[k])
                raise InputError(f"{out}: holds a dataset built with other settings ({', '.join(changed)}); use another folder or --overwrite")
            remove_dataset(out)
            kind = "absent"
        elif kind in ("absent", "damaged"):
            ours = [name for name in RECORDS if name != "dataset.json" and exists(out / name)]
            if ours or kind == "damaged":
                self._claim(ours, why if kind == "damaged" else "missing")
                kind = "proven"
            elif overwrite and out.is_dir() and any(out.iterdir()):
                raise InputError(
                    f"{out}: not a dataset folder ssga wrote (no dataset.json); --overwrite replaces only what ssga wrote: use a new or empty folder (nothing was changed)"
                )
        if kind == "absent":
            return self._fresh()
        return self._heal(proven=kind == "proven")

    def _claim(self, records: list[str], why: str) -> None:
        """The folder's dataset.json is missing or damaged: it is this build's if its plan is the one these settings give."""
        out = self.out
        what = f"{out / 'dataset.json'}: {why}"
        if "plan.json" not in records:
            held = f" but holds {', '.join(records)}" if records else ""
            raise InputError(
                f"{what}{held}, and no plan.json shows which dataset ssga wrote here: choose another folder, or delete the folder yourself (nothing was changed)"
            )
        try:
            same = read_json(out / "plan.json") == _as_json(_plan_record(self.planned()[0]))
        except SsgaError:
            same = False
        if not same:
            raise InputError(
                f"{what}, and its plan.json is not the one these settings give (another build's, or damaged): use the settings it was built with, "
                "another folder, or delete the folder yourself (nothing was changed)"
            )

    def _fresh(self) -> Dataset:
        """A new dataset: plan, refuse to replace a file ssga did not write, then write everything."""
        out = self.out
        plan, fitted = self.planned()
        wanted = self._wanted(plan)
        present = [ch for ch in CHANNELS if (out / ch).is_dir()]
        clash = next((out / ch / f"{s.id}.png" for s in wanted for ch in present if exists(out / ch / f"{s.id}.png")), None)
        if clash is not None:
            raise InputError(
                f"{clash}: not written by ssga (the folder has no dataset.json), and a view of this build would replace it; "
                "ssga replaces only the files it wrote: choose another folder (nothing was changed)"
            )
        self._write_records(plan, fitted, header=True, floor=True)
        self._render(plan, {s.id: set(CHANNELS) for s in wanted})
        write_jsonl(out / "manifest.jsonl", (_manifest_row(out, s) for s in plan.samples))
        return Dataset.open(out)

    def _write_records(self, plan: Plan | None, fitted: dict[str, Any] | None, *, header: bool, floor: bool) -> None:
        out = self.out
        if header:
            write_json(out / "dataset.json", self.header)
        if floor:
            write_json(out / "floorplan.json", self.workspace.floor_plan.to_json())
        if plan is not None:
            if fitted is not None:
                write_json(out / FITTED, fitted)
            write_json(out / "plan.json", _plan_record(plan))

    def _wanted(self, plan: Plan) -> list[Sample]:
        # A captured workspace cannot show its synthesis targets: they have no image.
        return [s for s in plan.samples if not (self.captured and s.split == "target")]

    def _heal(self, *, proven: bool) -> Dataset:
        """This build's folder, finished or not: check it, and re-make what is missing or damaged
        (a finished, healthy one is read without writing: it may be read-only)."""
        from ssga_bench.health import HEAL, check_dataset, damage_line

        out = self.out
        health = check_dataset(out, decode=self.decode)
        if health.healthy:
            return Dataset.from_health(health)
        records = health.records()
        # Of an unfinished build, what is missing is work still to do, not damage.
        damage = {path: why for path, why in health.damaged.items() if health.finished or why != "missing"}
        plan_damaged = bool({"plan.json", FITTED} & records)
        plan, fitted = self.planned() if plan_damaged or health.plan is None else (health.plan, None)
        by_view = health.view_damage()
        todo: dict[str, set[str]] = {}
        for sample in self._wanted(plan):
            channels = by_view.get(sample.id, set())
            if not exists(out / "rgb" / f"{sample.id}.png"):  # not written yet, or lost: every channel not there whole
                channels |= {ch for ch in CHANNELS if not exists(out / ch / f"{sample.id}.png")}
                if health.finished:
                    damage.setdefault(f"rgb/{sample.id}.png", "missing")
            if channels:
                todo[sample.id] = channels
        try:
            self._write_records(plan if plan_damaged else None, fitted, header=proven or "dataset.json" in records, floor="floorplan.json" in records)
            self._render(plan, todo)
            rows = "".join(json.dumps(_manifest_row(out, s)) + "\n" for s in plan.samples).encode()
            manifest = out / "manifest.jsonl"
            if not (exists(manifest) and manifest.read_bytes() == rows):
                atomic_write_bytes(manifest, rows)
        except SsgaError as exc:
            if not damage:
                raise
            raise InputError(f"{out}: cannot re-make its {damage_line(damage, why=False)}: {exc}; {HEAL.format(root=out)}") from None
        dataset = Dataset.open(out)
        dataset.remade = tuple(damage)
        if damage:
            warn(f"{out}: re-made its {damage_line(damage)}")
        return dataset

    def _render(self, plan: Plan, todo: dict[str, set[str]]) -> None:
        """Render (or copy) the views of ``todo`` and write each one's channels named there; the rest of
        its channels are left as they are (a re-made view is the same, bit for bit)."""
        out, workspace, progress = self.out, self.workspace, self.progress
        samples = [s for s in plan.samples if s.id in todo]
        phase = "render" if not self.captured else "copy"
        total = len(self._wanted(plan))
        done = total - len(samples)

        def write(sample_id: str, files: dict[str, bytes]) -> None:
            write_view(out, sample_id, {ch: data for ch, data in files.items() if ch in todo[sample_id]})

        if self.render is None:
            for sample in samples:
                view = workspace.load(sample.source) if self.captured else workspace.render(sample.pose)
                write(sample.id, encode_view(view))
                done += 1
                if progress:
                    progress(phase, done, total)
            return
        from ssga_bench.tasks import RenderJob, chunks, render_views

        executor, opener, batch = self.render
        jobs = [RenderJob(opener, tuple((s.id, s.pose, s.source) for s in chunk), self.captured) for chunk in chunks(samples, batch)]
        for rendered in executor.map(render_views, jobs, describe=RenderJob.what):
            for sample_id, files in rendered:
                write(sample_id, files)
            done += len(rendered)
            if progress:
                progress(phase, done, total)


def _marker(out: Path) -> tuple[str, Any, str]:
    """Whose ``out/dataset.json`` is: ``("ours", header, "")`` (a JSON object with ssga's ``format``
    key), ``("foreign", value, why)`` (valid JSON without it: a user's file), ``("damaged", None, why)``
    (empty or unreadable) or ``("absent", None, "")``."""
    path = out / "dataset.json"
    if not exists(path):
        return "absent", None, ""
    if path.is_dir():
        return "foreign", None, "a folder"
    if path.stat().st_size == 0:
        return "damaged", None, "empty (0 bytes)"
    try:
        value = read_json(path)
    except SsgaError as exc:
        return "damaged", None, str(exc).removeprefix(f"{path}: ")
    if not isinstance(value, dict):
        return "foreign", value, f"a JSON {type(value).__name__}, without ssga's \"format\" key"
    if "format" not in value:
        return "foreign", value, "no \"format\" key"
    return "ours", value, ""


def _make_plan(workspace: AnyWorkspace, protocol: ProtocolConfig, *, fit: bool, progress: Any, captured: bool) -> tuple[Plan, dict[str, Any] | None]:
    """The protocol's plan on the workspace (the same, every time), fitted if ``fit`` and it must be,
    with the record of the fitted values (``fitted.json``), said on stderr."""

    def planned(config: ProtocolConfig) -> Plan:
        protocol_run = Protocol(workspace.floor_plan, workspace.camera, config)
        if captured:
            return protocol_run.select(workspace.name, workspace.captures)
        report = (lambda done, total: progress("plan", done, total)) if progress else None
        return protocol_run.plan(workspace.name, workspace.camera_height, report)

    try:
        return planned(protocol), None
    except InputError as failure:
        if not fit:
            raise
        height = capture_height(workspace.captures) if captured else workspace.camera_height
        fitted, changes = fit_protocol(workspace.floor_plan, workspace.camera, protocol, height=height, captures=workspace.captures if captured else None)
        plan = planned(fitted)
        chose = ", ".join(f"protocol.{k} = {v:g} (configured {getattr(protocol, k):g})" for k, v in changes.items())
        warn(f"workspace {workspace.name!r}: the protocol was fitted to it: {chose}; as configured: {failure}")
        return plan, {"fitted": changes, "configured": {k: getattr(protocol, k) for k in changes}, "because": str(failure)}


def remove_dataset(out: Path) -> None:
    """Delete what ssga wrote in ``out``: each view's files of its plan, then its records.

    Anything else in the folder (the user's notes, other data) stays; folders are
    removed only if that leaves them empty.
    """
    try:
        ids = [r["id"] for r in read_json(out / "plan.json")["samples"]] if (out / "plan.json").exists() else []
    except (SsgaError, KeyError, TypeError):
        ids = None
    # ssga's ids are plain names (test-0003-00001); another (``../notes``) would delete
    # a file that is no view ssga wrote, in the folder or outside it.
    if ids is None or not all(isinstance(i, str) and _SAMPLE_ID.fullmatch(i) for i in ids):
        raise InputError(f"{out / 'plan.json'}: damaged, so which views ssga wrote is unknown; delete the folder yourself")
    try:
        for channel in CHANNELS:
            for sample_id in ids:
                (out / channel / f"{sample_id}.png").unlink(missing_ok=True)
            folder = out / channel
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()
        for name in RECORDS:
            (out / name).unlink(missing_ok=True)
    except OSError as exc:
        raise InputError(f"{exc.filename or out}: cannot delete the old dataset: {exc.strerror}") from None


def encode_view(view: View) -> dict[str, bytes]:
    """A view's files as the dataset stores them: PNG bytes by channel (those the view carries)."""
    files = {"rgb": png_bytes(view.rgb)}
    if view.depth is not None:
        files["depth"] = png_bytes(depth_to_png16(view.depth))
    for name in ("semantic", "instance"):
        ids = getattr(view, name)
        if ids is not None:
            files[name] = png_bytes(ids_to_png16(ids, name))
    return files


def write_view(out: Path, sample_id: str, files: dict[str, bytes]) -> None:
    """Write a view's encoded files (:func:`encode_view`). RGB last: a view counts as written
    once its RGB file exists, and each file appears whole."""
    for channel in sorted(files, key=lambda c: c == "rgb"):
        atomic_write_bytes(out / channel / f"{sample_id}.png", files[channel])


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


def _read_plan(out: Path, name: str, config: ProtocolConfig) -> Plan:
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
        plan = _read_plan(root, str(header["workspace"]), ProtocolConfig.model_validate(header["protocol"]))
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
