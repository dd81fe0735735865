"""Building a dataset (:mod:`ssga_bench.dataset`): planning, rendering, resuming and healing.

Building is resumable: an interrupted build keeps its plan and every view already
written (each file appears atomically), and the next build renders only what is missing.
A finished dataset is checked (:mod:`ssga_bench.health`) and only read when it is healthy,
so it may be read-only; a damaged one has its missing or broken files made again, bit for
bit. Replacing a dataset (``overwrite``) deletes only the files ssga wrote there, never
anything else the folder holds.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any


from ssga_core.config import ResolvedStage
from ssga_core.data import View
from ssga_core.errors import InputError, SsgaError
from ssga_bench.dataset import (
    CHANNELS, FITTED, FORMAT, RECORDS, Dataset, protocol_record, sample_record,
)
from ssga_bench.io import (
    atomic_write_bytes, depth_to_png16, exists, ids_to_png16, path_errors, png_bytes,
    read_json, warn, write_json, write_jsonl,
)
from ssga_bench.execution import Executor
from ssga_bench.protocol import Plan, Protocol, ProtocolConfig, Sample, capture_height, fit_protocol
from ssga_bench.seeds import DRAWS
from ssga_bench.workspace import AnyWorkspace, Workspace

_SAMPLE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*")
"""What a sample id ssga writes looks like (no path separator, no leading dot)."""


def _header(workspace: AnyWorkspace, source: dict[str, Any], protocol: ProtocolConfig) -> dict[str, Any]:
    cam = workspace.camera
    return {
        "format": FORMAT,
        "draws": DRAWS,
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
        digest = hashlib.blake2b(json.dumps([record, protocol_record(protocol), DRAWS], sort_keys=True).encode(), digest_size=4)
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
