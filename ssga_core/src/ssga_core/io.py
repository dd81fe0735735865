"""Files written atomically and read with one-line errors naming the file.

Every output goes to a temporary file beside its destination and is renamed into
place, so an interrupted run never leaves a half-written file that a resumed run
would mistake for a finished one.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ssga_core.errors import InputError


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: str | Path, obj: Any) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, sort_keys=False) + "\n").encode())


def write_jsonl(path: str | Path, rows: Iterable[Any]) -> None:
    atomic_write_bytes(path, "".join(json.dumps(r) + "\n" for r in rows).encode())


def read_json(path: str | Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None


def read_jsonl(path: str | Path) -> Iterator[Any]:
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    for n, line in enumerate(lines, 1):
        if line.strip():
            try:
                yield json.loads(line)
            except ValueError as exc:
                raise InputError(f"{path}:{n}: not a valid JSON line ({exc})") from None


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write uint8 RGB / grey or uint16 grey as PNG (RGB order in, as ssga holds images)."""
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise InputError(f"{path}: could not encode a {image.shape} {image.dtype} image as PNG")
    atomic_write_bytes(path, buf.tobytes())


def read_png(path: str | Path, *, color: bool) -> np.ndarray:
    """Read a PNG as RGB uint8 (``color``) or as stored, single channel (8 or 16 bit)."""
    flags = cv2.IMREAD_COLOR if color else cv2.IMREAD_UNCHANGED
    image = cv2.imread(str(path), flags)
    if image is None:
        why = "no such file" if not Path(path).exists() else "not a readable image"
        raise InputError(f"{path}: {why}")
    if color:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if image.ndim != 2:
        raise InputError(f"{path}: expected a single-channel image, got shape {image.shape}")
    return image


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
