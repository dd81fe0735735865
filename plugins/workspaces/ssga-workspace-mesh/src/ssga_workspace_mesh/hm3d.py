"""HM3D's semantic annotations: a mesh whose vertex colours code object ids, and their table.

HM3D-Semantics ships, beside a scene's ``NAME.basis.glb``:

* ``NAME.semantic.glb``: the scene's surfaces again, each vertex coloured with the
  colour of the object it belongs to (Habitat renders its semantic sensor from it);
* ``NAME.semantic.txt``: one object a line after a header line that contains
  ``HM3D Semantic Annotations``::

      HM3D Semantic Annotations
      1,9E5BAD,"wall",0
      2,4CB33C,"kitchen cabinet",1

  the object's id, its colour (hex RGB), its category name (quoted; it may contain
  commas) and the id of the region (room) it is in.

:func:`load_semantic_surface` turns the pair into a label surface
(:data:`~ssga_workspace_mesh.meshdata.LABEL_SURFACE`): a mesh that is never seen in
RGB but gives each face an instance id (the object's id) and a semantic id (its
category's). Category ids number the scene's category names in sorted order, from 0;
:attr:`SemanticTable.categories` lists them. Surfaces whose colour is not in the table
are unannotated: instance 0 (Habitat's "unknown" object) and semantic ``-1``.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from ssga_core import InputError
from ssga_workspace_mesh.meshdata import FACE_INSTANCE, FACE_SEMANTIC, LABEL_SURFACE, UNANNOTATED

HEADER = "HM3D Semantic Annotations"


@dataclass(frozen=True)
class SemanticTable:
    """The objects of a ``*.semantic.txt``.

    Attributes:
        ids: ``(N,)`` int64 object ids.
        colours: ``(N,)`` int64 colours as ``0xRRGGBB``.
        categories: category name -> semantic id (the names sorted, numbered from 0).
        semantic: ``(N,)`` int32 semantic id of each object.
        regions: ``(N,)`` int64 region of each object.
    """

    ids: np.ndarray
    colours: np.ndarray
    categories: dict[str, int]
    semantic: np.ndarray
    regions: np.ndarray

    def lookup(self, colours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(semantic, instance)`` ids of ``0xRRGGBB`` colours; unannotated where a colour is not in the table.

        A colour listed twice means the first object listed, as in Habitat's colour map.
        """
        semantic = np.full(len(colours), -1, dtype=np.int32)
        instance = np.full(len(colours), UNANNOTATED, dtype=np.int32)
        if len(self.colours):
            order = np.argsort(self.colours, kind="stable")
            at = np.minimum(np.searchsorted(self.colours[order], colours), len(order) - 1)
            known = self.colours[order][at] == colours
            row = order[at[known]]
            semantic[known], instance[known] = self.semantic[row], self.ids[row]
        return semantic, instance


def semantic_files(mesh_path: str | Path) -> tuple[Path, Path]:
    """Where HM3D keeps a scene's annotations: ``NAME.basis.glb`` (or ``NAME.glb``) -> ``NAME.semantic.glb``, ``NAME.semantic.txt``."""
    path = Path(mesh_path)
    name = path.stem.removesuffix(".basis")
    return path.with_name(f"{name}.semantic.glb"), path.with_name(f"{name}.semantic.txt")


def read_semantic_table(path: str | Path) -> SemanticTable:
    """Read a ``*.semantic.txt``.

    Raises:
        InputError: the file is missing, has no HM3D header, or a line is not
            ``id,RRGGBB,"category",region``; one line naming the file (and the line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the semantic table ({type(exc).__name__})") from None
    lines = text.splitlines()
    if not lines or HEADER not in lines[0]:
        raise InputError(f"{path}: not an HM3D semantic table (its first line should contain {HEADER!r})")
    rows = []
    for number, row in enumerate(csv.reader(io.StringIO("\n".join(lines[1:]))), start=2):
        if "".join(row).strip():
            try:
                rows.append(_parse_row(row))
            except ValueError:
                raise InputError(f'{path}:{number}: expected id,RRGGBB,"category",region; got {",".join(row)!r}') from None
    ids, colours, names, regions = (list(column) for column in zip(*rows, strict=True)) if rows else ([], [], [], [])
    categories = {name: index for index, name in enumerate(sorted(set(names)))}
    return SemanticTable(
        ids=np.array(ids, dtype=np.int64),
        colours=np.array(colours, dtype=np.int64),
        categories=categories,
        semantic=np.array([categories[n] for n in names], dtype=np.int32),
        regions=np.array(regions, dtype=np.int64),
    )


def load_semantic_surface(mesh_path: Path, table_path: Path) -> trimesh.Scene:
    """The label surfaces of an HM3D ``*.semantic.glb`` with the ids of its ``*.semantic.txt``.

    Each geometry of the returned scene (in the file's frame, node transforms as in the
    file) is marked :data:`LABEL_SURFACE` and carries per-face ids in its metadata
    (:data:`FACE_SEMANTIC`, :data:`FACE_INSTANCE`). A face takes the object of the colour
    at least two of its corners share (else its first corner's), so that a face on the
    boundary of two objects goes to the one it mostly belongs to.

    Raises:
        InputError: either file is unreadable or malformed, or the mesh has no vertex
            colours; one line naming the file.
    """
    table = read_semantic_table(table_path)
    if not mesh_path.is_file():
        raise InputError(f"{mesh_path}: no such semantic mesh (HM3D's *.semantic.glb)")
    try:
        # Unprocessed: merging vertices could join corners of different objects.
        scene = trimesh.load(mesh_path, force="scene", process=False)
    except Exception as exc:  # noqa: BLE001 - any loader failure is a bad file, reported in one line
        raise InputError(f"{mesh_path}: cannot read the semantic mesh ({type(exc).__name__}: {' '.join(str(exc).split())})") from None
    for name, geometry in list(scene.geometry.items()):
        colours = _vertex_colours(geometry) if isinstance(geometry, trimesh.Trimesh) and len(geometry.faces) else None
        if colours is None:
            scene.delete_geometry(name)  # none in HM3D's files; dropped rather than taken as unannotated
            continue
        faces = np.asarray(geometry.faces, dtype=np.int64)
        semantic, instance = table.lookup(colours)
        corner = faces[np.arange(len(faces)), _majority_corner(instance[faces])]
        geometry.metadata.update({LABEL_SURFACE: True, FACE_SEMANTIC: semantic[corner], FACE_INSTANCE: instance[corner]})
    if not scene.geometry:
        raise InputError(f"{mesh_path}: the semantic mesh has no vertex colours (COLOR_0) to read object ids from")
    return scene


def _parse_row(row: list[str]) -> tuple[int, int, str, int]:
    object_id, colour, name, region = (field.strip() for field in row)
    if not re.fullmatch(r"[0-9A-Fa-f]{6}", colour):
        raise ValueError(colour)
    return int(object_id), int(colour, 16), name, int(region)


def _vertex_colours(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """``0xRRGGBB`` of each vertex, from glTF's COLOR_0 (8-bit, normalised 16-bit or float), or None."""
    visual = mesh.visual
    if visual.kind == "vertex":
        raw = np.asarray(visual.vertex_colors)  # trimesh made them 8-bit
    else:
        # With a material, trimesh keeps COLOR_0 as it is stored, as a vertex attribute.
        raw = getattr(visual, "vertex_attributes", {}).get("color")
        if raw is None or len(raw) != len(mesh.vertices):
            return None
        raw = np.asarray(raw)
    if raw.dtype.kind == "f":
        rgb = np.rint(np.clip(raw[:, :3], 0.0, 1.0) * 255.0)
    elif raw.dtype == np.uint16:  # normalised: 8-bit value v is stored as v * 257
        rgb = np.rint(raw[:, :3] / 257.0)
    else:
        rgb = raw[:, :3]
    rgb = rgb.astype(np.int64)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def _majority_corner(corner_ids: np.ndarray) -> np.ndarray:
    """Per face, a corner whose id at least one other corner shares (corner 0 if all differ)."""
    return np.where((corner_ids[:, 1] == corner_ids[:, 2]) & (corner_ids[:, 0] != corner_ids[:, 1]), 1, 0)
