"""Any parser's scene graph of a set of images, drawn and written out to check (``ssga parse``).

The graph is the one the pipeline builds from a parser's regions (:func:`ssga_core.graph.assemble`):
node 0 the whole image, node ``k + 1`` region ``k``, edges between boxes closer than the
core's gap, weights 1 and ``1/K``. Each image is parsed at its own size. For an image
``NAME`` (its path relative to the images' common folder, without the suffix), the
output folder gets

* ``NAME.graph.png``: the picture (:mod:`ssga_bench.scene_graph_figure`);
* ``NAME.labels.png``: 16-bit, each pixel's node number (region index + 1), 0 for no
  region: lossless, ``ids_from_png16`` gives back the parser's label map;
* ``NAME.regions.json``: per region its node, index, box, area, centroid, category,
  name, score and weight; the edges; the parser, its preset, its config and its caveat.

An image keeps the channels ssga wrote beside it, so parsers that need more than RGB
can be looked at too:

* in a workspace folder (``ssga workspace build``), ``rgb/ID.png`` is read with
  ``depth/ID.png``, ``semantic/ID.png`` and ``instance/ID.png`` where they exist;
* ``synthetic.png`` of ``ssga synthesize`` is read as a synthetic view, with the
  ``depth.png`` beside it (0: holes).

Every image is read, and checked to carry what the parser consumes, before any is
parsed, and no output may replace an input nor a file ``ssga parse`` did not write (a
``NAME.regions.json`` it wrote says so, and names the picture and label PNG beside it),
so a broken or misplaced file stops the run with its name before work is done and
before anything is written. Files are written atomically, the record first.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.extract import image_names, refuse_repeats
from ssga_bench.execution import Executor, SerialExecutor
from ssga_bench.io import (
    WORKING_SIDE,
    atomic_write_bytes,
    depth_from_png16,
    exists,
    fit_channel,
    is_file,
    ids_from_png16,
    ids_to_png16,
    path_errors,
    png_bytes,
    read_json,
    read_png,
    read_rgb,
    writable_folder,
    write_json,
)
from ssga_bench.tasks import chunks, span
from ssga_core.config import ResolvedStage
from ssga_bench.scene_graph_figure import draw_scene_graph
from ssga_core.data import VIEW_DATA, Regions, SceneGraph, View
from ssga_core.errors import InputError, SsgaError
from ssga_core.geometry import Camera, Pose
from ssga_core.graph import EDGE_GAP_PX, assemble
from ssga_core.stages import Parser

PICTURE, LABELS, REGIONS = ".graph.png", ".labels.png", ".regions.json"
WORKSPACE_CHANNELS = ("depth", "semantic", "instance")
"""What a workspace folder stores beside ``rgb/`` (``ssga_bench.dataset``), one PNG per view in each."""
SYNTHETIC_IMAGE, SYNTHETIC_DEPTH = "synthetic.png", "depth.png"
"""What ``ssga synthesize`` writes (``ssga_bench.synthesize``)."""
EDGE_RULE = f"boxes within {EDGE_GAP_PX:g} px of each other at 256 px image width (scaled with the width); node 0 to every part"


@dataclass(frozen=True)
class ParsedImage:
    """One image's outcome: where its files went and the size of its graph."""

    image: Path
    picture: Path
    regions: int
    edges: int
    """Edges between parts (the whole-image node's edges, one per part, not counted)."""
    channels: tuple[str, ...]
    resized_from: tuple[int, int] | None = None
    """The image's own ``(width, height)`` where it was parsed reduced (``max_side``)."""


def companion_files(image: Path) -> tuple[dict[str, Path], bool]:
    """The channel files ssga wrote beside ``image`` (by channel name), and whether it is a synthetic view."""
    if image.parent.name == "rgb":
        root = image.parent.parent
        found = {ch: root / ch / image.name for ch in WORKSPACE_CHANNELS}
        return {ch: path for ch, path in found.items() if is_file(path)}, False
    if image.name == SYNTHETIC_IMAGE and is_file(image.parent / SYNTHETIC_DEPTH):
        return {"depth": image.parent / SYNTHETIC_DEPTH}, True
    return {}, False


def _read_16bit(path: Path, channel: str, shape: tuple[int, int]) -> np.ndarray:
    raw = read_png(path, color=False)
    if raw.dtype != np.uint16 or raw.shape != shape:
        what = "millimetres" if channel == "depth" else "ids + 1"
        raise InputError(f"{path}: expected a 16-bit PNG of {what} of the image's {shape[1]} x {shape[0]}, got {raw.dtype} of {raw.shape[1]} x {raw.shape[0]}")
    return raw


def load_view(image: Path, *, companions: bool = True, max_side: int | None = WORKING_SIDE) -> tuple[View, tuple[str, ...], tuple[int, int] | None]:
    """``image`` as a view (a 90 degree pinhole at the origin) with its companion channels, its
    longest side at most ``max_side``; the channels read; and the image's own ``(width, height)``
    if it was reduced."""
    if not is_file(image):  # said here: OpenCV would print a warning of its own before the error
        raise InputError(f"{image}: {'a folder, expected an image' if exists(image) and image.is_dir() else 'no such file'}")
    rgb, resized_from = read_rgb(image, max_side)
    h, w = rgb.shape[:2]
    files, synthetic = companion_files(image) if companions else ({}, False)
    channels: dict[str, np.ndarray] = {}
    for channel, path in files.items():
        raw = _read_16bit(path, channel, (resized_from[1], resized_from[0]) if resized_from else (h, w))
        channels[channel] = fit_channel(depth_from_png16(raw) if channel == "depth" else ids_from_png16(raw), (h, w))
    view = View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=w, height=h), synthetic=synthetic, **channels)
    return view, ("rgb", *channels), resized_from


def scene_graph(view: View, regions: Regions) -> SceneGraph:
    """The graph the pipeline builds from these regions, without features (the core's edge rule and weights)."""
    return assemble(view.camera, regions.boxes, np.zeros((1 + len(regions), 0), dtype=np.float32))


def _finite(values: np.ndarray, digits: int) -> list[float] | None:
    """A vector as JSON numbers rounded to ``digits``, or None (JSON has no NaN) if any is not finite."""
    return [round(float(v), digits) for v in values] if np.isfinite(values).all() else None


def regions_record(regions: Regions, graph: SceneGraph) -> list[dict[str, Any]]:
    """Per region: node, index, box, area, centroid, category, name, score, weight (None where the parser gives none)."""
    areas = np.bincount(regions.labels[regions.labels >= 0], minlength=len(regions))
    centroids = regions.centroids()
    return [
        {
            "node": k + 1,
            "index": k,
            "box": _finite(regions.boxes[k], 3),
            "area": int(areas[k]),
            "centroid": _finite(centroids[k], 2),
            "category": None if regions.categories is None or regions.categories[k] < 0 else int(regions.categories[k]),
            "name": None if regions.names is None else regions.names[k],
            "score": None if regions.scores is None else round(float(regions.scores[k]), 6),
            "weight": round(float(graph.weights[k + 1]), 6),
        }
        for k in range(len(regions))
    ]


def parser_record(parser: Parser, preset: str | None) -> dict[str, Any]:
    record: dict[str, Any] = {"name": parser.name, "preset": preset, "config": parser.config.model_dump(mode="json")}
    caveat = type(parser).caveat(parser.config)
    if caveat:
        record["caveat"] = caveat
    return record


def output_names(paths: Sequence[Path]) -> list[str]:
    """Each image's ``NAME``: its path relative to the images' common folder, without the suffix; one per image."""
    stems = [str(Path(name).with_suffix("")) for name in image_names(paths)]
    refuse_repeats(stems, paths, lambda stem, earlier: f"would write the same {stem}.* files as {earlier}; rename one of them or parse them apart")
    return stems


def written_by_parse(out: Path, name: str) -> set[Path]:
    """The files of image ``NAME`` in ``out`` that ``ssga parse`` wrote: its record (a ``NAME.regions.json``
    of the shape it writes), and the picture and label PNG that record names."""
    record_path = out / f"{name}{REGIONS}"
    try:
        record = read_json(record_path) if exists(record_path) else None
    except SsgaError:
        return set()
    if not (isinstance(record, dict) and {"parser", "labels_encoding", "edge_rule", "regions"} <= set(record)):
        return set()
    return {record_path, *(out / f"{name}{suffix}" for suffix, key in ((PICTURE, "picture"), (LABELS, "labels")) if record.get(key) == Path(f"{name}{suffix}").name)}


def check_carries(parser: type[Parser], view: View, image: Path, *, companions: bool) -> None:
    """Before any parsing: the image carries what the parser consumes (RGB, depth, ids), or a line saying how to give it."""
    missing = (parser.consumes & VIEW_DATA) - view.available
    if missing:
        names = ", ".join(sorted(m.value for m in missing))
        how = (
            "an image rgb/ID.png of a workspace folder brings the depth/, semantic/ and instance/ files beside rgb/"
            if companions
            else "without --rgb-only, the files ssga wrote beside it are read"
        )
        raise InputError(f"{image}: parser {parser.name!r} needs {names}, which this image does not carry; {how}")


@dataclass(frozen=True)
class ParseJob:
    """A chunk of images for :func:`parse_chunk` (a task: it runs on any executor's worker)."""

    parser: ResolvedStage
    images: tuple[str, ...]
    """As the user gave them, relative to ``folder``."""
    names: tuple[str, ...]
    folder: str
    companions: bool
    preset: str | None
    max_side: int | None = WORKING_SIDE

    def what(self) -> str:
        return span("image", self.images)


@dataclass(frozen=True)
class ParsedFiles:
    """One image's outputs, made by a worker, written by the driver."""

    labels: bytes
    record: dict[str, Any]
    picture: bytes
    regions: int
    edges: int
    channels: tuple[str, ...]
    resized_from: tuple[int, int] | None


def parse_chunk(job: ParseJob) -> list[ParsedFiles]:
    """Parse a chunk of images as one batch, and make each one's label PNG, JSON record and picture."""
    from ssga_bench.tasks import in_folder, opened_stage

    parser = opened_stage(job.parser)
    with in_folder(job.folder):
        loaded = [load_view(Path(image), companions=job.companions, max_side=job.max_side) for image in job.images]
    try:
        parsed = parser.parse_many([view for view, _, _ in loaded])
    except InputError as exc:
        raise InputError(f"{job.what()}: {exc}") from None
    record = parser_record(parser, job.preset)
    title = parser.name + (f" ({job.preset})" if job.preset else "")
    out = []
    for image, name, (view, channels, resized_from), regions in zip(job.images, job.names, loaded, parsed):
        graph = scene_graph(view, regions)
        json_record = {
            "image": image,
            "size": [view.camera.width, view.camera.height],
            # Regions and boxes are in the pixels of "size"; the image's own size, where it was parsed reduced.
            "resized_from": list(resized_from) if resized_from else None,
            "channels": list(channels),
            "synthetic": view.synthetic,
            "parser": record,
            "picture": Path(f"{name}{PICTURE}").name,
            "labels": Path(f"{name}{LABELS}").name,
            "labels_encoding": "16-bit PNG: node number (region index + 1), 0 for no region",
            "whole_image": {"node": SceneGraph.WHOLE_IMAGE, "box": graph.boxes[SceneGraph.WHOLE_IMAGE].tolist(), "weight": float(graph.weights[SceneGraph.WHOLE_IMAGE])},
            "regions": regions_record(regions, graph),
            "edges": graph.edges.tolist(),
            "edge_rule": EDGE_RULE,
        }
        between = int(np.all(graph.edges != SceneGraph.WHOLE_IMAGE, axis=1).sum())
        out.append(
            ParsedFiles(
                labels=png_bytes(ids_to_png16(regions.labels, f"{image}: region labels")),
                record=json_record,
                picture=png_bytes(draw_scene_graph(view.rgb, regions, graph, title=title)),
                regions=len(regions),
                edges=between,
                channels=channels,
                resized_from=resized_from,
            )
        )
    return out


def parse_images(
    images: Sequence[str | Path],
    parser: ResolvedStage,
    out: str | Path,
    *,
    preset: str | None = None,
    companions: bool = True,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
    batch: int = 16,
    max_side: int | None = WORKING_SIDE,
) -> list[ParsedImage]:
    """Parse every image, and write its picture, label PNG and JSON into ``out`` (see the module docstring).

    Args:
        parser: the resolved parser; each worker builds it once.
        preset: the parser's preset, if it was made from one (recorded in the JSON).
        companions: read the channel files ssga wrote beside an image (depth, ids).
        progress: called with ``("parse", done, total)``.
        executor: parses the images in chunks of ``batch`` on its workers (default: in
            this process).
        max_side: an image whose longest side is larger is parsed reduced to it (read reduced:
            a 12000 x 12000 photo is never decoded whole); ``None``: every image at its own size.
    """
    with path_errors():
        return _parse_images(images, parser, Path(out), preset=preset, companions=companions, progress=progress, executor=executor, batch=batch, max_side=max_side)


def _parse_images(
    images: Sequence[str | Path],
    parser: ResolvedStage,
    out: Path,
    *,
    preset: str | None,
    companions: bool,
    progress: Callable[[str, int, int], None] | None,
    executor: Executor | None,
    batch: int,
    max_side: int | None,
) -> list[ParsedImage]:
    paths = [Path(p) for p in images]
    if not paths:
        raise InputError("ssga parse: no image given")
    names = output_names(paths)
    inputs = {p.resolve() for p in paths}
    for path in paths:
        inputs.update(f.resolve() for f in (companion_files(path)[0] if companions else {}).values())
    for name, path in zip(names, paths):
        for suffix in (PICTURE, LABELS, REGIONS):
            if (out / f"{name}{suffix}").resolve() in inputs:
                raise InputError(f"{out / f'{name}{suffix}'}: is an input; the output of {path} would replace it; choose another --out")
    for name in names:
        ours = written_by_parse(out, name)
        for suffix in (REGIONS, PICTURE, LABELS):
            if exists(out / f"{name}{suffix}") and out / f"{name}{suffix}" not in ours:
                raise InputError(
                    f"{out / f'{name}{suffix}'}: not written by ssga parse, which would replace it; it replaces only the files it wrote: "
                    "choose another --out (nothing was changed)"
                )
    for path in paths:
        check_carries(parser.cls, load_view(path, companions=companions, max_side=max_side)[0], path, companions=companions)
    writable_folder(out)
    jobs = [
        ParseJob(parser, tuple(str(paths[i]) for i in chunk), tuple(names[i] for i in chunk), os.getcwd(), companions, preset, max_side)
        for chunk in chunks(range(len(paths)), batch)
    ]
    parsed: list[ParsedImage] = []
    with ExitStack() as stack:
        executor = executor or stack.enter_context(SerialExecutor())
        made = (files for chunk in executor.map(parse_chunk, jobs, describe=ParseJob.what) for files in chunk)
        for n, (path, name, files) in enumerate(zip(paths, names, made), 1):
            picture = out / f"{name}{PICTURE}"
            write_json(out / f"{name}{REGIONS}", files.record)  # first: it says the other two are ssga's
            atomic_write_bytes(out / f"{name}{LABELS}", files.labels)
            atomic_write_bytes(picture, files.picture)
            parsed.append(ParsedImage(path, picture, files.regions, files.edges, files.channels, files.resized_from))
            if progress:
                progress("parse", n, len(paths))
    return parsed
