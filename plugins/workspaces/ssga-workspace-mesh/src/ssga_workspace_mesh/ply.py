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

import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import SimpleMaterial

from ssga_core import InputError

TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
"""PLY's property types -> numpy type codes (byte order added per file)."""

FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
"""PLY's formats -> numpy byte order (none for text)."""

FACE_LISTS = ("vertex_indices", "vertex_index")
"""Names exporters give the face's list of vertex indices."""

COLOUR_NAMES = (("red", "green", "blue", "alpha"), ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"))
UV_NAMES = (("s", "t"), ("u", "v"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


class PlyError(ValueError):
    """What is wrong with a PLY file; :func:`read_ply` reports it as an :class:`InputError` naming the file."""


@dataclass(frozen=True)
class Property:
    name: str
    code: str
    """numpy type code of the values, without byte order (``"f4"``)."""
    count: str | None = None
    """numpy type code of a list's length, None for a scalar property."""


@dataclass(frozen=True)
class Element:
    name: str
    count: int
    properties: tuple[Property, ...]


@dataclass(frozen=True)
class Header:
    format: str
    elements: tuple[Element, ...]
    textures: tuple[str, ...]
    """Image files named by ``comment TextureFile ...`` lines, in order."""
    body: int
    """Offset of the first byte after the header."""


@dataclass(frozen=True)
class Ragged:
    """A list property: every record's values one after another, and each record's count."""

    values: np.ndarray
    counts: np.ndarray

    def starts(self) -> np.ndarray:
        return np.cumsum(self.counts) - self.counts


Columns = dict[str, np.ndarray | Ragged]
"""One element's properties: a ``(n,)`` array per scalar property, a :class:`Ragged` per list."""


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


def parse_header(data: bytes) -> Header:
    """The header at the start of ``data``."""
    if not data.startswith(b"ply") or data[3:4] not in (b"\n", b"\r"):
        raise PlyError("not a PLY file (expected its first line to be 'ply')")
    end = data.find(b"end_header")
    if end < 0:
        raise PlyError("the PLY header never ends (expected an 'end_header' line)")
    newline = data.find(b"\n", end)
    body = len(data) if newline < 0 else newline + 1
    lines = data[:end].decode("latin-1").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[Property]]] = []
    textures: list[str] = []
    for number, raw in enumerate(lines[1:], start=2):
        words = raw.split()
        if not words or words[0] in ("obj_info",):
            continue
        keyword = words[0]
        where = f"header line {number}"
        if keyword == "comment":
            if len(words) > 2 and words[1].lower() == "texturefile":
                textures.append(raw.split(None, 2)[2].strip())
        elif keyword == "format":
            if len(words) != 3 or words[1] not in FORMATS or words[2] != "1.0":
                raise PlyError(f"{where}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0', got {raw.strip()!r}")
            fmt = words[1]
        elif keyword == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{where}: expected 'element <name> <count>', got {raw.strip()!r}")
            elements.append((words[1], int(words[2]), []))
        elif keyword == "property":
            if not elements:
                raise PlyError(f"{where}: a property before any element")
            elements[-1][2].append(_property(words, where, raw))
        else:
            raise PlyError(f"{where}: expected comment, format, element or property, got {raw.strip()!r}")
    if fmt is None:
        raise PlyError("the header has no format line (expected 'format ascii|binary_little_endian|binary_big_endian 1.0')")
    return Header(fmt, tuple(Element(n, c, tuple(p)) for n, c, p in elements), tuple(textures), body)


def _property(words: list[str], where: str, raw: str) -> Property:
    expected = f"one of {', '.join(t for t in TYPES if not t[-1].isdigit())} (or int8 ... float64)"
    if len(words) == 3:
        if words[1] not in TYPES:
            raise PlyError(f"{where}: unknown property type {words[1]!r} (expected {expected})")
        return Property(words[2], TYPES[words[1]])
    if len(words) == 5 and words[1] == "list":
        for word in words[2:4]:
            if word not in TYPES:
                raise PlyError(f"{where}: unknown property type {word!r} (expected {expected})")
        if TYPES[words[2]][0] == "f":
            raise PlyError(f"{where}: a list's length must be an integer type, got {words[2]!r}")
        return Property(words[4], TYPES[words[3]], TYPES[words[2]])
    raise PlyError(f"{where}: expected 'property <type> <name>' or 'property list <count type> <type> <name>', got {raw.strip()!r}")


def read_body(data: bytes, header: Header) -> dict[str, Columns]:
    """Every element's properties, read from the body of ``data`` in the header's order."""
    if header.format == "ascii":
        return _read_ascii(data[header.body :], header.elements)
    return _read_binary(data, header.body, header.elements, FORMATS[header.format])


# -- binary -----------------------------------------------------------------------------


def _read_binary(data: bytes, offset: int, elements: tuple[Element, ...], order: str) -> dict[str, Columns]:
    out: dict[str, Columns] = {}
    for element in elements:
        smallest = sum(int((p.count or p.code)[1]) for p in element.properties)  # every list empty
        _room_for(element, (len(data) - offset) // max(smallest, 1))
        read = _binary_uniform(data, offset, element, order)
        if read is None:
            read = _binary_walk(data, offset, element, order)
        out[element.name], offset = read
    return out


def _binary_uniform(data: bytes, offset: int, element: Element, order: str) -> tuple[Columns, int] | None:
    """The element read in one go, if every record's lists have the lengths of the first's; else None."""
    if element.count == 0:
        return _empty(element), offset
    fields: list[tuple] = []
    lengths: dict[int, int] = {}
    at = offset
    for i, prop in enumerate(element.properties):
        if prop.count is None:
            fields.append((f"p{i}", order + prop.code))
            at += int(prop.code[1])
            continue
        if at + int(prop.count[1]) > len(data):
            return None
        length = int(np.frombuffer(data, order + prop.count, 1, at)[0])
        if length == 0:
            return None  # a zero-size field: the walk handles it
        lengths[i] = length
        fields += [(f"n{i}", order + prop.count), (f"p{i}", order + prop.code, (length,))]
        at += int(prop.count[1]) + length * int(prop.code[1])
        if at > len(data):
            return None  # not even the first record fits: the walk says where the file ends
    dtype = np.dtype(fields)
    size = element.count * dtype.itemsize
    if offset + size > len(data):
        if not lengths:
            raise _truncated(element, (len(data) - offset) // dtype.itemsize)
        return None  # truncated, or later records' lists are shorter: the walk tells which
    records = np.frombuffer(data, dtype, element.count, offset)
    if any(np.any(records[f"n{i}"] != n) for i, n in lengths.items()):
        return None
    columns: Columns = {}
    for i, prop in enumerate(element.properties):
        values = records[f"p{i}"].astype(np.dtype(prop.code))  # native order, contiguous
        if prop.count is None:
            columns[prop.name] = values
        else:
            columns[prop.name] = Ragged(values.reshape(-1), np.full(element.count, lengths[i], dtype=np.int64))
    return columns, offset + size


def _binary_walk(data: bytes, offset: int, element: Element, order: str) -> tuple[Columns, int]:
    """The element read record by record: lists of any length."""
    n = element.count
    props = element.properties
    sizes = [int(p.code[1]) for p in props]
    at = np.empty((len(props), n), dtype=np.int64)  # where each property's value (or list's count) starts
    counts = {i: np.empty(n, dtype=np.int64) for i, p in enumerate(props) if p.count is not None}
    unpack = {i: struct.Struct(order + _STRUCT[props[i].count]).unpack_from for i in counts}  # type: ignore[index]
    end = len(data)
    pos = offset
    for r in range(n):
        for i, size in enumerate(sizes):
            at[i, r] = pos
            if i not in counts:
                pos += size
                continue
            count_size = int(props[i].count[1])  # type: ignore[index]
            if pos + count_size > end:
                raise _truncated(element, r)
            k = unpack[i](data, pos)[0]
            if k < 0:
                raise PlyError(f"element {element.name!r} record {r}: a list of length {k}")
            counts[i][r] = k
            pos += count_size + k * size
        if pos > end:
            raise _truncated(element, r)
    raw = np.frombuffer(data, np.uint8)
    columns: Columns = {}
    for i, prop in enumerate(props):
        dtype = np.dtype(order + prop.code)
        if prop.count is None:
            columns[prop.name] = _gather(raw, at[i], dtype)
        else:
            k = counts[i]
            first = np.repeat(at[i] + int(prop.count[1]), k)
            within = np.arange(int(k.sum()), dtype=np.int64) - np.repeat(np.cumsum(k) - k, k)
            columns[prop.name] = Ragged(_gather(raw, first + within * dtype.itemsize, dtype), k)
    return columns, pos


_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I"}


def _gather(raw: np.ndarray, starts: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Values of ``dtype`` at byte offsets ``starts`` of ``raw``, in native byte order."""
    picked = raw[starts[:, None] + np.arange(dtype.itemsize)]
    return picked.reshape(-1).view(dtype).astype(dtype.newbyteorder("="))


def _room_for(element: Element, records: int) -> None:
    """Refuse an element whose records cannot all fit in what is left of the file (before allocating for them)."""
    if element.count > records:
        raise PlyError(
            f"truncated: the header declares {element.count} {element.name!r} records, the rest of the file has room for at most {records}"
        )


def _truncated(element: Element, record: int) -> PlyError:
    return PlyError(f"truncated: the file ends in {element.name!r} record {record} of the {element.count} its header declares")


# -- ascii ------------------------------------------------------------------------------


def _read_ascii(body: bytes, elements: tuple[Element, ...]) -> dict[str, Columns]:
    text = body.decode("latin-1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy warns, and stops, at the first word that is not a number
        try:
            tokens = np.fromstring(text, sep=" ")  # its text mode: the fast tokenizer (only the binary mode is deprecated)
        except (ValueError, DeprecationWarning):
            bad = next((word for word in body.split() if not _is_number(word.decode("latin-1"))), None)
            found = f", found {bad.decode('latin-1')[:40]!r}" if bad is not None else ""
            raise PlyError(f"expected numbers separated by spaces after the header{found}") from None
    out: dict[str, Columns] = {}
    pos = 0
    for element in elements:
        _room_for(element, (len(tokens) - pos) // max(len(element.properties), 1))
        read = _ascii_uniform(tokens, pos, element)
        if read is None:
            read = _ascii_walk(tokens, pos, element)
        out[element.name], pos = read
    return out


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _ascii_uniform(tokens: np.ndarray, pos: int, element: Element) -> tuple[Columns, int] | None:
    n = element.count
    if n == 0:
        return _empty(element), pos
    offsets, lengths, width = [], {}, 0
    for i, prop in enumerate(element.properties):
        offsets.append(width)
        if prop.count is None:
            width += 1
            continue
        if pos + width >= len(tokens):
            return None
        lengths[i] = int(tokens[pos + width])
        width += 1 + lengths[i]
    if pos + n * width > len(tokens):
        if not lengths:
            raise _truncated(element, (len(tokens) - pos) // width)
        return None  # truncated, or later records' lists are shorter: the walk tells which
    block = tokens[pos : pos + n * width].reshape(n, width)
    if any(np.any(block[:, offsets[i]] != k) for i, k in lengths.items()):
        return None
    columns: Columns = {}
    for i, prop in enumerate(element.properties):
        if prop.count is None:
            columns[prop.name] = _cast(block[:, offsets[i]], prop.code)
        else:
            k = lengths[i]
            values = block[:, offsets[i] + 1 : offsets[i] + 1 + k]
            columns[prop.name] = Ragged(_cast(values.reshape(-1), prop.code), np.full(n, k, dtype=np.int64))
    return columns, pos + n * width


def _ascii_walk(tokens: np.ndarray, pos: int, element: Element) -> tuple[Columns, int]:
    n = element.count
    props = element.properties
    at = np.empty((len(props), n), dtype=np.int64)
    counts = {i: np.empty(n, dtype=np.int64) for i, p in enumerate(props) if p.count is not None}
    end = len(tokens)
    for r in range(n):
        for i in range(len(props)):
            at[i, r] = pos
            if i not in counts:
                pos += 1
                continue
            if pos >= end:
                raise _truncated(element, r)
            k = tokens[pos]
            if k < 0 or k != int(k):
                raise PlyError(f"element {element.name!r} record {r}: a list's length must be a whole number, got {k:g}")
            counts[i][r] = int(k)
            pos += 1 + int(k)
        if pos > end:
            raise _truncated(element, r)
    columns: Columns = {}
    for i, prop in enumerate(props):
        if prop.count is None:
            columns[prop.name] = _cast(tokens[at[i]], prop.code)
        else:
            k = counts[i]
            first = np.repeat(at[i] + 1, k)
            within = np.arange(int(k.sum()), dtype=np.int64) - np.repeat(np.cumsum(k) - k, k)
            columns[prop.name] = Ragged(_cast(tokens[first + within], prop.code), k)
    return columns, pos


def _empty(element: Element) -> Columns:
    """The columns of an element with no records."""
    return {
        p.name: np.empty(0, np.dtype(p.code)) if p.count is None else Ragged(np.empty(0, np.dtype(p.code)), np.empty(0, np.int64))
        for p in element.properties
    }


def _cast(values: np.ndarray, code: str) -> np.ndarray:
    return values.astype(np.dtype(code)) if code[0] != "f" else values.astype(np.dtype(code), copy=False)


# -- the mesh ---------------------------------------------------------------------------


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
