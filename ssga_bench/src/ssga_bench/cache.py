"""A cache of what is costly to recompute for real views: parsed regions and local features.

Keys are a hash of the view's content (its arrays) and of the stage's name and config,
so a cache folder can be shared by runs and variants: the eight variants of one
experiment parse and describe each real query image once, and a resumed or repeated
run reuses everything. Entries are ``.npz`` files written atomically; those of synthetic
views are kept in memory only, for the variants of one run that render the same view.
"""

from __future__ import annotations

import hashlib
import io
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

from ssga_core.data import LocalFeatures, Regions, View
from ssga_core.errors import SsgaError
from ssga_bench.io import atomic_write_bytes, warn
from ssga_core.stages import LocalDescriptor, Parser, Stage

T = TypeVar("T")


def view_key(view: View) -> str:
    h = hashlib.blake2b(digest_size=16)
    for name in ("rgb", "depth", "semantic", "instance"):
        a = getattr(view, name)
        if a is not None:
            h.update(name.encode())
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def stage_key(stage: Stage) -> str:
    config = stage.config.model_dump_json()
    return f"{stage.kind}-{stage.name}-{hashlib.blake2b(config.encode(), digest_size=6).hexdigest()}"


class FeatureCache:
    """Regions and local features of real views, in memory and (given a folder) on disk."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = Path(root) if root is not None else None
        self._memory: dict[tuple[str, str], object] = {}

    def _load(self, stage: Stage, view: View, unpack: Callable[[dict[str, np.ndarray]], T]) -> tuple[tuple[str, str], T | None]:
        key = (stage_key(stage), view_key(view))
        if key in self._memory:
            return key, unpack(self._memory[key])  # type: ignore[arg-type]
        if self.root is not None:
            path = self.root / key[0] / f"{key[1]}.npz"
            if path.exists():
                # A damaged entry is recomputed: unreadable, not an archive (TypeError: a bare
                # .npy), or readable but not what the stage stores (a missing array, a bad shape).
                try:
                    with np.load(path, allow_pickle=False) as data:
                        arrays = {k: data[k] for k in data.files}
                    value = unpack(arrays)
                except (OSError, ValueError, EOFError, TypeError, KeyError, zipfile.BadZipFile, SsgaError) as exc:
                    detail = " ".join(str(exc).split())[:120]
                    warn(f"{path}: damaged cache entry ({type(exc).__name__}: {detail}); computing it again")
                    return key, None
                self._memory[key] = arrays
                return key, value
        return key, None

    def _store(self, key: tuple[str, str], arrays: dict[str, np.ndarray]) -> None:
        self._memory[key] = arrays
        if self.root is not None:
            buf = io.BytesIO()
            np.savez_compressed(buf, **arrays)
            atomic_write_bytes(self.root / key[0] / f"{key[1]}.npz", buf.getvalue())

    def _cached(self, stage: Stage, view: View, compute: Callable[[View], T], pack: Callable[[T], dict[str, np.ndarray]], unpack: Callable[[dict[str, np.ndarray]], T]) -> T:
        if view.synthetic:
            # Kept in memory only, for the run: variants that render the same pseudo-view
            # (SD, SPD and DSP share their syntheses) describe and parse it once.
            key = (stage_key(stage), view_key(view))
            if key not in self._memory:
                self._memory[key] = pack(compute(view))
            return unpack(self._memory[key])  # type: ignore[arg-type]
        key, value = self._load(stage, view, unpack)
        if value is None:
            arrays = pack(compute(view))
            self._store(key, arrays)
            value = unpack(arrays)
        return value

    def regions(self, parser: Parser, view: View) -> Regions:
        return self._cached(parser, view, parser.parse, _pack_regions, _unpack_regions)

    def local_features(self, descriptor: LocalDescriptor, view: View) -> LocalFeatures:
        return self._cached(
            descriptor,
            view,
            descriptor.extract,
            lambda f: {"positions": f.positions, "descriptors": f.descriptors},
            lambda a: LocalFeatures(positions=a["positions"], descriptors=a["descriptors"]),
        )


def _pack_regions(regions: Regions) -> dict[str, np.ndarray]:
    arrays = {"labels": regions.labels, "boxes": regions.boxes}
    for name, value in regions.attributes().items():
        # Names as a fixed-width unicode array: npz stores it without pickling.
        arrays[name] = np.array(value, dtype=str) if isinstance(value, tuple) else value
    return arrays


def _unpack_regions(arrays: dict[str, np.ndarray]) -> Regions:
    attributes = {name: arrays[name] for name in Regions.PER_REGION if name in arrays}
    if "names" in attributes:
        attributes["names"] = tuple(str(n) for n in attributes["names"])
    return Regions(labels=arrays["labels"], boxes=arrays["boxes"], **attributes)
