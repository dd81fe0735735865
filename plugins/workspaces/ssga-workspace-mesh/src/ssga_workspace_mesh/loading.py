"""Loading mesh files (GLB/glTF, OBJ+MTL, PLY) into ssga's world frame, with their semantic sidecar.

Habitat, HM3D and glTF store scenes ``y`` up; ssga's world is ``z`` up
(:mod:`ssga_core.geometry`). Loading converts with ``(x, y, z) = (x_h, -z_h, y_h)``,
the same change of frame as :meth:`ssga_core.Pose.from_habitat`, so a pose read from
a Habitat episode and a view rendered here agree.

The sidecar ``<file without extension>.semantic.json`` gives each geometry a semantic
category and an instance id (format in the package README)::

    {"categories": {"wall": 1, "chair": 5},
     "geometries": {"wall_0": {"category": "wall", "semantic_id": 1, "instance_id": 7}}}

Two things Habitat's scenes need are handled here too: textures compressed with Basis
Universal are decoded (:mod:`.basisu`), and HM3D's semantic mesh and table beside
the scene (``NAME.semantic.glb``, ``NAME.semantic.txt``) are added to it as label
surfaces (:mod:`.hm3d`), before the change of frame, so that they move with it.

PLY files (scans: ScanNet, phones, MeshLab) are read by :mod:`.ply`, GLB/glTF and OBJ by
trimesh.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import trimesh

from ssga_core import InputError
from ssga_bench import atomic_write_bytes
from ssga_workspace_mesh.basisu import with_decoded_textures
from ssga_workspace_mesh.gravity import UpAxis, level_scene, parse_up_axis
from ssga_workspace_mesh.hm3d import load_semantic_surface, semantic_files
from ssga_workspace_mesh.meshdata import geometry_ids
from ssga_workspace_mesh.ply import ply_problem, read_ply

Y_UP_TO_Z_UP = np.array(
    [
        [1.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, -1.0, 0.0],
        [0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
"""Homogeneous transform from a ``y``-up file's frame to ssga's ``z``-up world."""

Z_UP_TO_Y_UP = Y_UP_TO_Z_UP.T
"""Its inverse, for writing ``y``-up files from an ssga scene."""

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply")


def sidecar_path(path: str | Path) -> Path:
    """Where the semantic sidecar of a mesh file lives: ``scene.glb`` -> ``scene.semantic.json``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.semantic.json")


def floor_plan_path(path: str | Path) -> Path:
    """Where a mesh file's floor plan lives if it has one: ``scene.glb`` -> ``scene.floorplan.json``."""
    path = Path(path)
    return path.with_name(f"{path.stem}.floorplan.json")


def mesh_file_problem(path: Path) -> str | None:
    """What a glance at a mesh file shows to be wrong (missing, unreadable, an unknown format, a PLY
    header or a GLB header that does not hold), before minutes of loading; None where nothing is."""
    if not path.is_file():
        return f"no such mesh file {path} (expected a {', '.join(MESH_SUFFIXES[:-1])} or {MESH_SUFFIXES[-1]} file)"
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        return f"{path}: unsupported mesh format {path.suffix!r} (expected {', '.join(MESH_SUFFIXES)})"
    if suffix == ".ply":
        problem = ply_problem(path)
        return f"{path}: {problem}" if problem else None
    try:
        with path.open("rb") as f:
            head = f.read(12)
    except OSError as exc:
        return f"{path}: cannot read the file ({exc.strerror or exc})"
    if suffix == ".glb":
        # Binary glTF: magic, version, and the length of the whole file.
        if len(head) < 12 or head[:4] != b"glTF":
            return f"{path}: not a binary glTF file (expected it to start with 'glTF')"
        declared = int.from_bytes(head[8:12], "little")
        if declared > path.stat().st_size:
            return f"{path}: truncated: its header declares {declared} bytes, the file holds {path.stat().st_size}"
    return None


def load_mesh_scene(
    path: str | Path, up_axis: UpAxis = "y"
) -> tuple[trimesh.Scene, dict[str, tuple[int, int]]]:
    """Load a mesh file into ssga's world frame, with the ids from its sidecar.

    Args:
        path: a ``.glb``, ``.gltf``, ``.obj`` or ``.ply`` file (an OBJ's ``.mtl`` and
            textures, a PLY's ``TextureFile``, beside it).
        up_axis: ``"y"`` for files in glTF/Habitat's ``y``-up convention (the default),
            ``"z"`` for files already ``z`` up; ``"auto"`` finds up from the mesh, or an
            ``[x, y, z]`` vector gives it (:mod:`.gravity`): the scene is then levelled
            and its floor put at ``z = 0``, and ``scene.metadata["levelling"]`` says how
            (a :class:`~ssga_workspace_mesh.gravity.Levelling`).

    Returns:
        The scene, and geometry name -> ``(semantic_id, instance_id)`` from the sidecar
        (empty without one). With HM3D's ``NAME.semantic.glb`` and ``NAME.semantic.txt``
        beside ``NAME.basis.glb`` (or ``NAME.glb``), the scene also holds their label
        surfaces, which give every view its ids.

    Raises:
        InputError: the file is missing, unreadable, not a triangle mesh, its textures
            need a decoder that is not installed, or its sidecar or semantic files are
            malformed or only half there; one line naming the file.
    """
    path = Path(path)
    up_axis = parse_up_axis(up_axis, str(path))
    if not path.is_file():
        raise InputError(f"{path}: no such mesh file (expected a {', '.join(MESH_SUFFIXES)} file)")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"{path}: unsupported mesh format {path.suffix!r} (expected {', '.join(MESH_SUFFIXES)})")
    if path.suffix.lower() == ".ply":
        scene = read_ply(path)
    else:
        scene = _load_with_trimesh(path)
    if not any(isinstance(g, trimesh.Trimesh) and len(g.faces) for g in scene.geometry.values()):
        raise InputError(f"{path}: cannot read a triangle mesh (the file has no triangles)")
    _add_hm3d_semantics(scene, path)
    if up_axis == "y":
        scene.apply_transform(Y_UP_TO_Z_UP)
    elif up_axis != "z":
        try:
            scene.metadata["levelling"] = level_scene(scene, up_axis)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from None
    return scene, read_sidecar(sidecar_path(path), list(scene.geometry))


def _load_with_trimesh(path: Path) -> trimesh.Scene:
    """A GLB/glTF or OBJ file as trimesh reads it, its Basis Universal textures decoded."""
    decoded = with_decoded_textures(path)
    try:
        if decoded is None:
            scene = trimesh.load(path, force="scene")
        else:
            data, file_type = decoded
            scene = trimesh.load(io.BytesIO(data), file_type=file_type, force="scene", resolver=trimesh.resolvers.FilePathResolver(path))
    except Exception as exc:  # noqa: BLE001 - any loader failure is a bad file, reported in one line
        raise InputError(f"{path}: cannot read a triangle mesh ({_one_line(exc)})") from None
    return scene


def _add_hm3d_semantics(scene: trimesh.Scene, path: Path) -> None:
    """Add the label surfaces of HM3D's semantic files beside ``path``, if it has them."""
    mesh_file, table_file = semantic_files(path)
    if not (mesh_file.exists() or table_file.exists()):
        return
    for required in (mesh_file, table_file):
        if not required.exists():
            raise InputError(f"{required}: missing; HM3D's semantic annotations need both {mesh_file.name} and {table_file.name}")
    labels = load_semantic_surface(mesh_file, table_file)
    for node in labels.graph.nodes_geometry:
        transform, name = labels.graph[node]
        scene.add_geometry(labels.geometry[name], geom_name=f"semantic:{name}", transform=transform)


def save_mesh_scene(
    scene: trimesh.Scene,
    path: str | Path,
    *,
    ids: Mapping[str, tuple[int, int]] | None = None,
    categories: Mapping[str, int] | None = None,
    up_axis: Literal["y", "z"] = "y",
) -> Path:
    """Write an ssga scene to a mesh file with its sidecar: what :func:`load_mesh_scene` reads back.

    Args:
        scene: the scene in ssga's world frame.
        path: the file to write; its suffix picks the format (``.glb`` recommended:
            one self-contained file).
        ids: geometry name -> ``(semantic_id, instance_id)``; by default each
            geometry's metadata, as the renderer reads it.
        categories: category name -> semantic id, written to the sidecar, and used to
            name each geometry's category.
        up_axis: the file's up axis; ``"y"`` writes glTF's convention.

    Returns:
        The sidecar's path.
    """
    path = Path(path)
    exported = scene.copy()
    if up_axis == "y":
        exported.apply_transform(Z_UP_TO_Y_UP)
    atomic_write_bytes(path, exported.export(file_type=path.suffix.lstrip(".").lower()))
    names = {semantic: name for name, semantic in (categories or {}).items()}
    geometries = {}
    for name, (semantic, instance) in geometry_ids(scene, ids).items():
        entry: dict[str, Any] = {"semantic_id": semantic, "instance_id": instance}
        if semantic in names:
            entry["category"] = names[semantic]
        geometries[name] = entry
    sidecar = sidecar_path(path)
    atomic_write_bytes(sidecar, json.dumps({"categories": dict(categories or {}), "geometries": geometries}, indent=1).encode())
    return sidecar


def read_sidecar(path: Path, geometry_names: Sequence[str] | None = None) -> dict[str, tuple[int, int]]:
    """Geometry name -> ``(semantic_id, instance_id)`` from a sidecar file; empty if there is none.

    An entry may give ``semantic_id`` directly or a ``category`` named in ``categories``.
    ``instance_id`` defaults to the geometry's index in ``geometry_names``, as for a
    scene without a sidecar. Names absent from ``geometry_names`` (when given) are
    ignored, so one sidecar serves a scene exported with fewer parts.
    """
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: cannot read the semantic sidecar as JSON ({_one_line(exc)})") from None
    expected = 'expected {"categories": {name: id}, "geometries": {geometry: {"category"|"semantic_id", "instance_id"}}}'
    if not isinstance(data, dict) or not isinstance(data.get("geometries", {}), dict):
        raise InputError(f"{path}: {expected}")
    categories = data.get("categories", {})
    if not isinstance(categories, dict) or not all(_is_int(v) for v in categories.values()):
        raise InputError(f"{path}: 'categories' must map names to integer ids")
    index = {name: i for i, name in enumerate(geometry_names)} if geometry_names is not None else None
    out: dict[str, tuple[int, int]] = {}
    for name, entry in data.get("geometries", {}).items():
        if index is not None and name not in index:
            continue
        out[name] = _entry_ids(path, name, entry, categories, index.get(name, -1) if index else -1)
    return out


def _entry_ids(path: Path, name: str, entry: Any, categories: dict[str, int], default_instance: int) -> tuple[int, int]:
    if not isinstance(entry, dict):
        raise InputError(f"{path}: geometry {name!r}: expected an object with 'category' or 'semantic_id'")
    if "semantic_id" in entry:
        semantic = entry["semantic_id"]
    elif entry.get("category") in categories:
        semantic = categories[entry["category"]]
    else:
        raise InputError(f"{path}: geometry {name!r}: needs 'semantic_id' or a 'category' listed in 'categories'")
    instance = entry.get("instance_id", default_instance)
    if not (_is_int(semantic) and _is_int(instance)):
        raise InputError(f"{path}: geometry {name!r}: semantic_id and instance_id must be integers")
    return int(semantic), int(instance)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
