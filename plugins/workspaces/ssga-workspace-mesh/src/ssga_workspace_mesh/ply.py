"""Reading PLY meshes (Stanford's polygon format), as scanners and MeshLab write them.

ScanNet's ``*_vh_clean.ply``, phone and tablet scans, and MeshLab's exports are PLY:
vertices with colours, faces as lists of vertex indices. trimesh reads PLY too, but it
cannot read a binary file whose faces mix triangles and quads, lets a face name a vertex
the file does not have, and fails on a bad file with whatever numpy raised; so this is a
small reader of its own, in numpy, and every bad file is one line saying what was
expected (:class:`ssga_core.InputError`).

What it reads:

* ``format ascii 1.0``, ``binary_little_endian 1.0`` and ``binary_big_endian 1.0``;
  every property type of the format (``char uchar short ushort int uint float double``
  and their sized names ``int8 ... float64``); elements other than ``vertex`` and
  ``face`` (edges, cameras, materials) are read past and ignored.
* ``vertex``: ``x y z``; colours ``red green blue [alpha]`` (or ``diffuse_red ...``) as
  8- or 16-bit integers or as floats in ``[0, 1]`` (floats above 1 are taken as 0-255);
  texture coordinates ``s t``, ``u v``, ``texture_u texture_v`` or ``texture_s texture_t``.
* ``face``: a list ``vertex_indices`` or ``vertex_index`` (triangles, quads, any polygon:
  fanned from its first corner into triangles); per-face colours; texture coordinates as
  MeshLab writes them, a list ``texcoord`` of ``2 k`` floats per face of ``k`` corners,
  and ``texnumber`` where the file names several textures.
* Textures: the images the header's ``comment TextureFile name.png`` lines name, beside
  the file. Texture coordinates have their origin at the image's bottom-left, as in OBJ
  and trimesh. Where a file has a texture its vertex colours are not used.

A binary element whose lists all have the length of its first record's (a mesh of
triangles only, ScanNet's) is read with one ``numpy.frombuffer``; one that mixes
polygons is walked record by record, about a second per million faces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import SimpleMaterial

from ssga_core import InputError
from ssga_workspace_mesh.ply_format import Columns, Header, PlyError, Ragged, parse_header, read_body

FACE_LISTS = ("vertex_indices", "vertex_index")
"""Names exporters give the face's list of vertex indices."""

COLOUR_NAMES = (("red", "green", "blue", "alpha"), ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"))
UV_NAMES = (("s", "t"), ("u", "v"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def read_ply(path: str | Path) -> trimesh.Scene:
    """A PLY file as a scene: one geometry named after the file (one per texture where it has several).

    Raises:
        InputError: the file is missing, is not PLY, is truncated, has a property of an
            unknown type, no faces, or a face naming a vertex it does not have, or its
            texture image is missing; one line naming the file and what was expected.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the file ({exc.strerror or exc})") from None
    try:
        # Corrupt numbers (NaN cast to an integer type) are caught below, not warned about.
        with np.errstate(invalid="ignore", over="ignore"):
            header = parse_header(data)
            elements = read_body(data, header)
            return build_scene(path, header, elements)
    except PlyError as exc:
        raise InputError(f"{path}: {exc}") from None


def ply_problem(path: Path) -> str | None:
    """What is wrong with a PLY file, found by reading it as :func:`read_ply` does (its header and
    body: a tenth of a second for a ScanNet scan) without building the mesh; None where nothing is."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"cannot read the file ({exc.strerror or exc})"
    try:
        with np.errstate(invalid="ignore", over="ignore"):
            header = parse_header(data)
            if not any(e.name == "face" and e.count for e in header.elements):
                return "no faces (expected an element 'face' with a vertex_indices list: a mesh, not a point cloud)"
            read_body(data, header)
    except PlyError as exc:
        return str(exc)
    return None


def build_scene(path: Path, header: Header, elements: dict[str, Columns]) -> trimesh.Scene:
    """The scene of a read file: triangles fanned, indices checked, colours or textures attached."""
    vertex = elements.get("vertex", {})
    if not all(isinstance(vertex.get(k), np.ndarray) for k in "xyz"):
        raise PlyError("expected a 'vertex' element with properties x, y and z")
    vertices = np.column_stack([vertex[k] for k in "xyz"]).astype(np.float64)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        at = int(np.argmin(finite))
        raise PlyError(f"vertex {at} is at ({', '.join(f'{v:g}' for v in vertices[at])}) (expected finite coordinates)")
    face = elements.get("face", {})
    name = next((n for n in FACE_LISTS if n in face), None)
    if name is None or not isinstance(face[name], Ragged) or len(face[name].counts) == 0:
        raise PlyError("no faces (expected a 'face' element with a list 'vertex_indices' or 'vertex_index'; point clouds cannot be rendered)")
    polygons: Ragged = face[name]  # type: ignore[assignment]
    _check_indices(polygons, len(vertices))
    corners, poly = fan(polygons.counts)
    if len(corners) == 0:
        raise PlyError("no faces with three or more corners")
    triangles = polygons.values[corners].astype(np.int64)

    uv, texnumber = _corner_uv(vertex, face, polygons, corners, poly)
    scene = trimesh.Scene()
    if header.textures and uv is not None:
        images = [_image(path, name) for name in header.textures]
        which = np.zeros(len(triangles), np.int64) if texnumber is None else np.clip(texnumber[poly], 0, len(images) - 1)
        for k in np.unique(which):
            mine = which == k
            mesh = _textured(vertices, triangles[mine], uv[mine], images[k])
            scene.add_geometry(mesh, geom_name=path.stem if len(images) == 1 else f"{path.stem}_{k}")
        return scene
    colours = _colours(vertex)
    if colours is not None:
        mesh = trimesh.Trimesh(vertices, triangles, vertex_colors=colours, process=False, validate=False)
    else:
        face_colours = _colours(face)
        mesh = trimesh.Trimesh(vertices, triangles, process=False, validate=False)
        if face_colours is not None:
            mesh.visual.face_colors = face_colours[poly]
    scene.add_geometry(mesh, geom_name=path.stem)
    return scene


def fan(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of polygons with ``counts`` corners, fanned from each one's first corner.

    Returns:
        ``(T, 3)`` positions in the polygons' concatenated corner list, and ``(T,)`` the
        polygon each triangle comes from. Polygons of fewer than three corners give none.
    """
    counts = np.asarray(counts, dtype=np.int64)
    if len(counts) and bool(np.all(counts == 3)):
        return np.arange(3 * len(counts), dtype=np.int64).reshape(-1, 3), np.arange(len(counts), dtype=np.int64)
    per = np.maximum(counts - 2, 0)
    poly = np.repeat(np.arange(len(counts), dtype=np.int64), per)
    j = np.arange(int(per.sum()), dtype=np.int64) - np.repeat(np.cumsum(per) - per, per) + 1
    first = (np.cumsum(counts) - counts)[poly]
    return np.stack([first, first + j, first + j + 1], axis=1), poly


def _check_indices(polygons: Ragged, num_vertices: int) -> None:
    values = polygons.values
    bad = (values < 0) | (values >= num_vertices)
    if bad.any():
        at = int(np.argmax(bad))
        face = int(np.searchsorted(np.cumsum(polygons.counts), at, side="right"))
        raise PlyError(
            f"face {face} refers to vertex {int(values[at])}, but the file has {num_vertices} vertices "
            f"(expected indices 0 to {num_vertices - 1})"
        )


def _colours(columns: Columns) -> np.ndarray | None:
    """``(n, 4)`` uint8 RGBA from an element's colour properties, or None if it has none."""
    for names in COLOUR_NAMES:
        if all(isinstance(columns.get(k), np.ndarray) for k in names[:3]):
            channels = [_to_8bit(columns[k]) for k in names if isinstance(columns.get(k), np.ndarray)]
            if len(channels) == 3:
                channels.append(np.full(len(channels[0]), 255, dtype=np.uint8))
            return np.column_stack(channels)
    return None


def _to_8bit(channel: np.ndarray) -> np.ndarray:
    """A colour channel as 0-255: floats in [0, 1] (or 0-255 if any is above 1), 16-bit
    integers over their range, other integers as they are."""
    if channel.dtype.kind == "f":
        channel = np.nan_to_num(channel)
        scale = 255.0 if channel.size == 0 or float(channel.max()) <= 1.0 else 1.0
        return np.rint(np.clip(channel * scale, 0.0, 255.0)).astype(np.uint8)
    if channel.dtype.itemsize == 2:
        return np.rint(np.clip(channel, 0, 65535) / 257.0).astype(np.uint8)
    return np.clip(channel, 0, 255).astype(np.uint8)


def _corner_uv(
    vertex: Columns, face: Columns, polygons: Ragged, corners: np.ndarray, poly: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(T, 3, 2)`` texture coordinates of the triangles' corners (per face, else per vertex), and
    ``(P,)`` each polygon's texture number where the file gives one."""
    texnumber = face.get("texnumber")
    texnumber = texnumber.astype(np.int64) if isinstance(texnumber, np.ndarray) else None
    texcoord = face.get("texcoord")
    if isinstance(texcoord, Ragged):
        # Corner c of a polygon has u, v at 2c, 2c + 1 of its texcoord list; faces whose
        # list does not have two numbers per corner get (0, 0).
        local = corners - polygons.starts()[poly][:, None]
        ok = (texcoord.counts == 2 * polygons.counts)[poly]
        at = texcoord.starts()[poly][:, None] + 2 * local
        at = np.where(ok[:, None], at, 0)
        values = texcoord.values.astype(np.float32)
        if len(values) == 0:
            return None, texnumber
        uv = np.stack([values[at], values[np.minimum(at + 1, len(values) - 1)]], axis=-1)
        uv[~ok] = 0.0
        return uv, texnumber
    for u, v in UV_NAMES:
        if isinstance(vertex.get(u), np.ndarray) and isinstance(vertex.get(v), np.ndarray):
            per_vertex = np.column_stack([vertex[u], vertex[v]]).astype(np.float32)
            return per_vertex[polygons.values[corners].astype(np.int64)], texnumber
    return None, texnumber


def _textured(vertices: np.ndarray, triangles: np.ndarray, corner_uv: np.ndarray, image: Image.Image) -> trimesh.Trimesh:
    """A textured mesh of ``triangles``, its vertices split where faces meeting there disagree on their uv."""
    used, inverse = np.unique(triangles, return_inverse=True)
    faces = inverse.reshape(-1, 3)
    uv = np.zeros((len(used), 2), dtype=np.float32)
    uv[faces.reshape(-1)] = corner_uv.reshape(-1, 2)
    if np.array_equal(uv[faces], corner_uv):
        points = vertices[used]
    else:  # a seam: every corner its own vertex
        points, faces, uv = vertices[triangles.reshape(-1)], np.arange(3 * len(triangles)).reshape(-1, 3), corner_uv.reshape(-1, 2)
    mesh = trimesh.Trimesh(points, faces, process=False, validate=False)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=SimpleMaterial(image=image))
    return mesh


def _image(path: Path, name: str) -> Image.Image:
    file = path.parent / name
    try:
        with Image.open(file) as image:
            return image.convert("RGB")
    except FileNotFoundError:
        raise PlyError(f"its texture {name!r} (comment TextureFile) is missing (expected {file})") from None
    except (OSError, ValueError) as exc:
        raise PlyError(f"cannot read its texture {name!r} (expected an image: {' '.join(str(exc).split())})") from None
