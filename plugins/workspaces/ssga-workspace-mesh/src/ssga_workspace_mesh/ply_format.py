"""The PLY format itself: a file's header, and its bodies (ASCII or binary, either byte
order) decoded into one numpy column per property; :mod:`ssga_workspace_mesh.ply` builds the
mesh from these columns and says what is read."""

from __future__ import annotations

import struct
import warnings
from dataclasses import dataclass

import numpy as np

TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
"""PLY's property types -> numpy type codes (byte order added per file)."""

FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
"""PLY's formats -> numpy byte order (none for text)."""



class PlyError(ValueError):
    """What is wrong with a PLY file; :func:`ssga_workspace_mesh.ply.read_ply` reports it as an :class:`InputError` naming the file."""


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
