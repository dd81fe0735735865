"""Files written atomically and read with one-line errors naming the file.

Every output goes to a temporary file beside its destination and is renamed into
place, so an interrupted run never leaves a half-written file that a resumed run
would mistake for a finished one. A file that cannot be written (a read-only folder,
a full disk, a path through a file) is an :class:`OutputError` naming the path, with
nothing left behind; files get the permissions the user's umask gives, as any
program's do (a temporary file alone would be private, 0600).

The API speaks as the CLI does: a path the file system refuses (too long, through a
file, not permitted) is a :class:`PathError`, an :class:`~ssga_core.errors.InputError`
whose message is the line the CLI prints (:func:`path_errors` converts an ``OSError``
where a library function raises it).
"""

from __future__ import annotations

import io
import json
import os
import sys
import tempfile
import zipfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ssga_core.errors import InputError, SsgaError


class PathError(InputError, OSError):
    """A path the file system refuses (too long, through a file, not permitted); the message names it and says why.

    An :class:`InputError`, so the API raises what the CLI reports as one line, and an
    ``OSError``, so ``except OSError`` still catches it (with its ``errno`` and ``filename``
    where it came from one)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


class OutputError(PathError):
    """A file or folder ssga cannot write; the message names it and says why."""


def path_error(exc: OSError) -> PathError:
    """``exc`` as the one line the CLI prints for it: ``PATH: why`` (``why`` alone if it names no path)."""
    why = exc.strerror or str(exc) or type(exc).__name__
    error = PathError(f"{exc.filename}: {why}" if exc.filename else why)
    error.errno, error.filename = exc.errno, exc.filename
    return error


@contextmanager
def path_errors() -> Iterator[None]:
    """An ``OSError`` raised inside (a path too long, a folder that is a file, a permission
    refused) as a :class:`PathError` with the CLI's message; ssga's own errors pass as they are.
    Also a decorator."""
    try:
        yield
    except SsgaError:
        raise
    except OSError as exc:
        raise path_error(exc) from None


def is_file(path: str | Path) -> bool:
    """Whether ``path`` is a file; a path the system cannot look at (too long, through a file) is none."""
    try:
        return Path(path).is_file()
    except OSError:
        return False


def exists(path: str | Path) -> bool:
    """Whether anything is at ``path``; a path the system cannot look at (too long, through a file) holds nothing."""
    try:
        return Path(path).exists()
    except OSError:
        return False


def warn(message: str) -> None:
    """Tell the user about something ssga handled (a damaged file recomputed), on stderr."""
    print(f"warning: {message}", file=sys.stderr)


def _file_mode() -> int:
    # The umask can only be read by setting it; set it back at once.
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def _why(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def make_folder(path: str | Path) -> Path:
    """``path`` as a folder, created with its parents if needed; one-line error if it cannot be."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{path}: cannot create the folder: a file is in the way") from None
    except OSError as exc:
        raise OutputError(f"{path}: cannot create the folder: {_why(exc)}") from None
    if not path.is_dir():
        raise OutputError(f"{path}: expected a folder, found a file")
    return path


def writable_folder(path: str | Path) -> Path:
    """:func:`make_folder`, and checked writable now rather than after an hour of work."""
    path = make_folder(path)
    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise OutputError(f"{path}: cannot write in this folder: {_why(exc)}") from None
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all."""
    path = Path(path)
    make_folder(path.parent)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {_why(exc)}") from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, _file_mode())
        os.replace(tmp, path)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise OutputError(f"{path}: cannot write: {_why(exc)}") from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def npy_bytes(array: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.save(out, array)
    return out.getvalue()


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """Named arrays as an ``.npz`` file holds them (uncompressed)."""
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


def load_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file ssga wrote; a damaged or missing one is a one-line error."""
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, TypeError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not an .npz file of arrays ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})") from None


def load_npy(path: str | Path, shape: tuple[int, ...], *, what: str) -> np.ndarray | None:
    """A saved array of ``shape`` with finite values, or None with a warning if the file is damaged."""
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        warn(f"{path}: damaged {what} ({' '.join(str(exc).split())[:120]}); computing them again")
        return None
    # Numbers first: np.isfinite raises on strings or records, which np.load reads as well.
    if array.dtype.kind not in "biuf" or array.shape != shape or not np.isfinite(array).all():
        warn(f"{path}: {what} of shape {array.shape} and type {array.dtype}, expected {shape} and finite numbers; computing them again")
        return None
    return array


def write_json(path: str | Path, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def write_jsonl(path: str | Path, rows: Iterable[Any]) -> None:
    atomic_write_bytes(path, "".join(json.dumps(r) + "\n" for r in rows).encode())


def read_json(path: str | Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {_why(exc)}") from None
    except ValueError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None


def read_jsonl(path: str | Path) -> Iterator[Any]:
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:  # unreadable, or not UTF-8
        raise InputError(f"{path}: cannot read: {_why(exc) if isinstance(exc, OSError) else exc}") from None
    for n, line in enumerate(lines, 1):
        if line.strip():
            try:
                yield json.loads(line)
            except ValueError as exc:
                raise InputError(f"{path}:{n}: not a valid JSON line ({exc})") from None


def png_bytes(image: np.ndarray, what: str | Path = "image") -> bytes:
    """uint8 RGB / grey or uint16 grey encoded as PNG (RGB order in, as ssga holds images)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise InputError(f"{what}: could not encode a {image.shape} {image.dtype} image as PNG")
    return buf.tobytes()


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write uint8 RGB / grey or uint16 grey as PNG, atomically."""
    atomic_write_bytes(path, png_bytes(image, path))


def read_png(path: str | Path, *, color: bool) -> np.ndarray:
    """Read a PNG as RGB uint8 (``color``) or as stored, single channel (8 or 16 bit)."""
    flags = cv2.IMREAD_COLOR if color else cv2.IMREAD_UNCHANGED
    image = cv2.imread(str(path), flags)
    if image is None:
        why = "no such file" if not exists(path) else "not a readable image"
        raise InputError(f"{path}: {why}")
    if color:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.ndim != 2:
        raise InputError(f"{path}: expected a single-channel image, got shape {image.shape}")
    return image


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""The last chunk of every PNG (IEND, empty, with its CRC): a file cut short lacks it."""
PNG_KINDS = {"rgb": (8, 2), "grey16": (16, 0)}
"""What :func:`png_bytes` writes: ``(bit depth, colour type)`` of 8-bit RGB and of 16-bit grey."""
_PNG_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}


def png_problem(path: str | Path, *, size: tuple[int, int] | None = None, kind: str | None = None, decode: bool = False) -> str | None:
    """What is wrong with the PNG file at ``path`` (None: nothing), cheaply: its size, its first
    26 bytes (signature, width, height, bit depth, colour type) and its last 12 (the IEND chunk
    a file cut short lacks); no pixel is decoded. ``size`` ``(width, height)`` and ``kind``
    (:data:`PNG_KINDS`) are what it should hold. With ``decode``, every chunk's CRC is checked
    too and the image data inflated to its full length (a bit flipped inside the file)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"cannot read ({_why(exc)})"
    try:
        length = os.fstat(fd).st_size
        if length == 0:
            return "empty (0 bytes)"
        head = os.pread(fd, 26, 0)
        tail = os.pread(fd, 12, max(0, length - 12))
        data = os.pread(fd, length, 0) if decode else b""
    except OSError as exc:
        return f"cannot read ({_why(exc)})"
    finally:
        os.close(fd)
    if len(head) < 26 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return "not a PNG"
    if tail != PNG_END:
        return f"truncated ({length} bytes, no IEND chunk at its end)"
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if size is not None and (width, height) != tuple(size):
        return f"a {width} x {height} image, expected {size[0]} x {size[1]}"
    if kind is not None and (head[24], head[25]) != PNG_KINDS[kind]:
        return f"bit depth {head[24]}, colour type {head[25]}; expected bit depth {PNG_KINDS[kind][0]}, colour type {PNG_KINDS[kind][1]}"
    return _png_data_problem(data, width, height, head[24], head[25]) if decode else None


def _png_data_problem(data: bytes, width: int, height: int, depth: int, colour: int) -> str | None:
    """Every chunk's CRC, and the image data inflated to the length the header gives (non-interlaced)."""
    import zlib

    at, idat = 8, []
    while at + 12 <= len(data):
        n = int.from_bytes(data[at : at + 4], "big")
        kind, body, crc = data[at + 4 : at + 8], data[at + 8 : at + 8 + n], data[at + 8 + n : at + 12 + n]
        if len(crc) < 4 or zlib.crc32(kind + body) != int.from_bytes(crc, "big"):
            return f"damaged: chunk {kind.decode('latin-1')!r} at byte {at} fails its CRC"
        if kind == b"IDAT":
            idat.append(body)
        at += 12 + n
        if kind == b"IEND":
            break
    try:
        pixels = zlib.decompress(b"".join(idat))
    except zlib.error as exc:
        return f"damaged: its image data do not inflate ({exc})"
    interlaced = data[28] if len(data) > 28 else 0
    expected = height * (1 + (width * _PNG_CHANNELS.get(colour, 1) * depth + 7) // 8)
    if not interlaced and len(pixels) != expected:
        return f"damaged: {len(pixels)} bytes of image data, expected {expected}"
    return None


WORKING_SIDE = 1024
"""Longest side ``ssga parse`` and ``ssga synthesize`` read an image at by default (``--max-side``):
a 12-megapixel photo or a 4K frame is parsed at a size its regions still show, in bounded memory."""

_REDUCTIONS = (8, 4, 2)
"""The factors OpenCV can decode an image at (``IMREAD_REDUCED_COLOR_*``): a JPEG is then
decoded at that size by libjpeg's DCT scaling and never exists in memory at full size."""


def image_size(path: str | Path) -> tuple[int, int] | None:
    """``(width, height)`` from the file's header (nothing decoded), or ``None`` if Pillow cannot tell."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            return image.size
    except (UnidentifiedImageError, OSError, ValueError):
        return None


def read_rgb(path: str | Path, max_side: int | None = None) -> tuple[np.ndarray, tuple[int, int] | None]:
    """The image at ``path`` as uint8 RGB whose longest side is at most ``max_side``, and its
    original ``(width, height)`` if it was reduced.

    Reduced while decoded where the format allows (a JPEG by 2, 4 or 8), then resized
    with area averaging to the exact size, so memory stays a small multiple of the
    result's. OpenCV honours EXIF orientation, and reads grey, RGBA, palette and 16-bit
    images as 8-bit RGB.
    """
    size = image_size(path) if max_side else None
    flags = cv2.IMREAD_COLOR
    if size is not None and max_side is not None:
        longest = max(size)
        factor = next((f for f in _REDUCTIONS if longest // f >= max_side), 1)
        flags = {8: cv2.IMREAD_REDUCED_COLOR_8, 4: cv2.IMREAD_REDUCED_COLOR_4, 2: cv2.IMREAD_REDUCED_COLOR_2}.get(factor, flags)
    image = cv2.imread(str(path), flags)
    if image is None:
        why = "no such file" if not exists(path) else "not a readable image"
        raise InputError(f"{path}: {why}")
    rgb = cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    del image
    h, w = rgb.shape[:2]
    if max_side is None or max(h, w) <= max_side:
        return rgb, None if size is None or size in ((w, h), (h, w)) else size
    scale = max_side / max(h, w)
    shape = (max(1, round(w * scale)), max(1, round(h * scale)))
    original = size if size is not None else (w, h)
    return cv2.resize(rgb, shape, interpolation=cv2.INTER_AREA), original


def fit_channel(channel: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A depth or id map at the image's reduced ``(height, width)``: nearest samples, never blends of two surfaces or ids."""
    if channel.shape[:2] == shape:
        return channel
    return cv2.resize(channel, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


def depth_to_png16(depth: np.ndarray) -> np.ndarray:
    """Metric depth as 16-bit millimetres (0 = unknown), as Habitat and most RGB-D datasets store it."""
    d = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0)
    return np.clip(np.rint(d * 1000.0), 0, 65535).astype(np.uint16)


def depth_from_png16(mm: np.ndarray) -> np.ndarray:
    return mm.astype(np.float32) / 1000.0


def ids_to_png16(ids: np.ndarray, name: str) -> np.ndarray:
    """Ids ``-1..65534`` stored as ``0..65535`` (0 = unknown)."""
    if ids.size and (ids.min() < -1 or ids.max() > 65534):
        raise InputError(f"{name}: ids must lie in -1..65534 to be stored as 16-bit PNG, got {ids.min()}..{ids.max()}")
    return (ids + 1).astype(np.uint16)


def ids_from_png16(stored: np.ndarray) -> np.ndarray:
    return stored.astype(np.int32) - 1
