"""What ssga wrote in a folder the user named, known again by a marker: it replaces only that.

A command that writes into a user-named folder or file replaces a file there only if
it can tell it wrote it; anything else is refused with one line, before any work and
with nothing changed:

==========================  ==========================================================
command                     how ssga knows its own files
==========================  ==========================================================
``workspace build --out``   ``dataset.json`` with ssga's ``"format"`` key (:mod:`ssga_bench.dataset`)
``run --output``            ``run.json`` (:data:`RUN`), written before anything else
``bench --output``          ``run.json`` of a bench (:data:`BENCH`); each seed's folder is a run's
``parse --out``             ``NAME.regions.json`` as ``ssga parse`` writes it; its picture and
                            label PNG are ssga's where that record names them (:mod:`ssga_bench.parse`)
``synthesize --out``        ``synthesis.json`` (:data:`SYNTHESIS`), written before the pictures
``extract --out FILE.h5``   the HDF5 file's ``descriptor`` and ``config`` attributes (:mod:`ssga_bench.extract`)
==========================  ==========================================================

A folder made before its command wrote a marker is recognised by what it holds
(``legacy``) and gets the marker.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ssga_core.errors import InputError, SsgaError
from ssga_bench.io import exists, path_errors, read_json, writable_folder, write_json


@dataclass(frozen=True)
class Marker:
    """The file that says ssga wrote a folder, and what that folder's command writes there."""

    name: str
    """The marker's file name in the folder."""
    command: str
    """``"ssga run"``: recorded in the marker, and said in messages."""
    outputs: Collection[str]
    """The files and folders the command writes there (names in the folder): what it would replace."""
    option: str
    """The command-line option that names the folder, for messages (``--output``)."""
    legacy: Callable[[Path], bool] | None = None
    """Whether a folder without the marker is one the command wrote before it wrote markers."""

    def record(self) -> dict[str, Any]:
        return {"format": 1, "written_by": self.command}


def _variants_trained(out: Path) -> bool:
    return (out / "variants").is_dir() and any(exists(p / "training.json") for p in (out / "variants").iterdir())


def _timings_written(out: Path) -> bool:
    try:
        timings = read_json(out / "timings.json")
    except SsgaError:
        return False
    return isinstance(timings, dict) and {"wall", "work"} <= set(timings)


RUN = Marker(
    "run.json",
    "ssga run",
    (
        "cache", "scoring", "variants", "oracle", "report.md", "results.csv", "results.png", "predictions.jsonl", "queries",
        "protocol-fitted.json", "workspace.png", "scene-graphs", "fusion.json", "heading.json", "timings.json",
        "index.html",
    ),
    "--output",
    legacy=lambda out: _variants_trained(out) or _timings_written(out),
)
BENCH = Marker(
    "run.json",
    "ssga bench",
    ("bench.md", "bench.json", "index.html"),
    "--output",
    legacy=lambda out: exists(out / "bench.json") and any(exists(p / "report.md") for p in out.glob("seed-*")),
)
SYNTHESIS = Marker("synthesis.json", "ssga synthesize", ("synthetic.png", "depth.png", "holes.png", "side-by-side.png"), "--out")


def written_by(path: Path, command: str) -> bool:
    """Whether the marker at ``path`` says ``command`` wrote its folder."""
    try:
        value = read_json(path)
    except SsgaError:
        return False
    return isinstance(value, dict) and value.get("written_by") == command


def check_folder(out: str | Path, marker: Marker) -> None:
    """Nothing where ``marker.command`` may write into ``out`` (it holds the marker already, or
    nothing the command would replace); else one line, with nothing changed: the folder holds the
    marker of another command, or a file the command would replace and no marker (nor, by
    ``legacy``, shows the command wrote it). Writes nothing."""
    out = Path(out)
    own = out / marker.name
    with path_errors():
        try:
            if not out.is_dir():  # a path the system refuses (too long, through a file) is said now, before any work
                out.stat()
                return
        except FileNotFoundError:
            return
        if exists(own):
            if not written_by(own, marker.command):
                raise InputError(
                    f"{own}: not written by {marker.command}; {marker.command} replaces only the files it wrote: "
                    f"choose another {marker.option} (nothing was changed)"
                )
            return
        clash = next((out / name for name in marker.outputs if exists(out / name)), None)
        if clash is not None and not (marker.legacy and marker.legacy(out)):
            raise InputError(
                f"{clash}: not written by {marker.command} (the folder has no {marker.name}), and {marker.command} would replace it; "
                f"it replaces only the files it wrote: choose another {marker.option} (nothing was changed)"
            )


def claim_folder(out: str | Path, marker: Marker) -> Path:
    """``out`` as a folder ``marker.command`` may write into (:func:`check_folder`), made if needed, with the marker in it."""
    out = Path(out)
    check_folder(out, marker)
    with path_errors():
        if not exists(out / marker.name):
            writable_folder(out)
            write_json(out / marker.name, marker.record())
    return out
