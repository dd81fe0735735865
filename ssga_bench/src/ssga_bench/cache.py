"""A cache of what is costly to recompute for real views: parsed regions and local features.

Keys are a hash of the view's content (its arrays) and of the stage's name and config,
so a cache folder can be shared by runs and variants: the eight variants of one
experiment parse and describe each real query image once, and a resumed or repeated
run reuses everything. Entries are ``.npz`` files written atomically.

Memory stays bounded by :data:`MEMORY_ENTRIES`, not by the run: with a folder, real
views' entries are read from disk when asked for (a few hundred microseconds each), not
kept; synthetic views' entries (as many as the pseudo-views, whatever the number of test
views) are kept, the least recently used dropped first.

Before the variants run, the experiment fills the cache for every real view in batches
(:func:`ssga_bench.tasks.describe_views`, on the executor's workers): :func:`compute_many`
runs a stage over a batch, :meth:`FeatureCache.put` stores what a worker sent back.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections import OrderedDict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

import numpy as np

from ssga_core.config import ResolvedStage
from ssga_core.data import LocalFeatures, Regions, View
from ssga_core.errors import SsgaError
from ssga_bench.io import atomic_write_bytes, warn
from ssga_core.stages import LocalDescriptor, Parser, Stage

T = TypeVar("T")

MEMORY_ENTRIES = 4096
"""Entries kept in memory at most (synthetic views' local features: ~75 kB each with dense SIFT)."""


def view_key(view: View) -> str:
    h = hashlib.blake2b(digest_size=16)
    for name in ("rgb", "depth", "semantic", "instance"):
        a = getattr(view, name)
        if a is not None:
            h.update(name.encode())
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def stage_key(stage: Stage | ResolvedStage) -> str:
    """The cache folder of a stage's entries: its kind, name and a hash of its config."""
    config = stage.config.model_dump_json(exclude=stage.config.unkeyed())
    return f"{stage.kind}-{stage.name}-{hashlib.blake2b(config.encode(), digest_size=6).hexdigest()}"


class FeatureCache:
    """Regions and local features of real views, in memory and (given a folder) on disk."""

    def __init__(self, root: str | Path | None = None) -> None:
        self.root = Path(root) if root is not None else None
        self._memory: OrderedDict[tuple[str, str], dict[str, np.ndarray]] = OrderedDict()
        self._last_view: tuple[View, str] | None = None

    def _remember(self, key: tuple[str, str], arrays: dict[str, np.ndarray]) -> None:
        self._memory[key] = arrays
        self._memory.move_to_end(key)
        while len(self._memory) > MEMORY_ENTRIES:
            self._memory.popitem(last=False)

    def has(self, key: tuple[str, str]) -> bool:
        """Whether the entry ``(stage key, view key)`` is stored (in memory or on disk)."""
        return key in self._memory or (self.root is not None and (self.root / key[0] / f"{key[1]}.npz").exists())

    def view_keys(self, dataset: str) -> dict[str, str]:
        """The content key of every real view of ``dataset`` (a digest of what it holds) by
        sample id, as the describing phase recorded them; empty if it did not."""
        if self.root is None:
            return {}
        path = self.root / f"views-{hashlib.blake2b(dataset.encode(), digest_size=8).hexdigest()}.json"
        try:
            keys = json.loads(path.read_text())
        except (OSError, ValueError):
            return {}
        return keys if isinstance(keys, dict) else {}

    def record_view_keys(self, dataset: str, keys: dict[str, str]) -> None:
        if self.root is not None and keys:
            path = self.root / f"views-{hashlib.blake2b(dataset.encode(), digest_size=8).hexdigest()}.json"
            atomic_write_bytes(path, json.dumps(keys, sort_keys=True).encode())

    def _marker(self, stage: ResolvedStage, dataset: str) -> Path | None:
        if self.root is None:
            return None
        digest = hashlib.blake2b(dataset.encode(), digest_size=8).hexdigest()
        return self.root / stage_key(stage) / f"complete-{digest}.json"

    def complete(self, stage: ResolvedStage, dataset: str) -> bool:
        """Whether every real view of ``dataset`` (a digest of what it holds) was stored for ``stage``:
        a rerun then loads none of them to look."""
        marker = self._marker(stage, dataset)
        return marker is not None and marker.exists()

    def mark_complete(self, stage: ResolvedStage, dataset: str) -> None:
        marker = self._marker(stage, dataset)
        if marker is not None:
            atomic_write_bytes(marker, b"{}\n")

    def put(self, key: tuple[str, str], entry: bytes) -> None:
        """Store an entry computed and encoded elsewhere (by a worker: :func:`compute_many`, :func:`encode_entry`)."""
        if self.root is None:
            self._remember(key, decode_entry(entry))
        else:
            atomic_write_bytes(self.root / key[0] / f"{key[1]}.npz", entry)

    def know(self, view: View, key: str) -> None:
        """Take ``key`` as ``view``'s content key without hashing it: a query view loaded with only
        the channels its stages read, whose full content (``key``) was hashed when it was described."""
        self._last_view = (view, key)

    def _view_key(self, view: View) -> str:
        # A view is usually asked for by two stages in a row (its regions, then its local
        # features): hashing its arrays once saves a millisecond per view and variant.
        last = self._last_view
        if last is not None and last[0] is view:
            return last[1]
        key = view_key(view)
        self._last_view = (view, key)
        return key

    def _load(self, stage: Stage, view: View, unpack: Callable[[dict[str, np.ndarray]], T]) -> tuple[tuple[str, str], T | None]:
        key = (stage_key(stage), self._view_key(view))
        if key in self._memory:
            self._memory.move_to_end(key)
            return key, unpack(self._memory[key])
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
                return key, value
        return key, None

    def _store(self, key: tuple[str, str], arrays: dict[str, np.ndarray]) -> None:
        if self.root is None:
            self._remember(key, arrays)
        else:
            atomic_write_bytes(self.root / key[0] / f"{key[1]}.npz", encode_entry(arrays))

    def _cached(self, stage: Stage, view: View, compute: Callable[[View], T], pack: Callable[[T], dict[str, np.ndarray]], unpack: Callable[[dict[str, np.ndarray]], T]) -> T:
        key, value = self._load(stage, view, unpack)
        if value is None:
            arrays = pack(compute(view))
            self._store(key, arrays)
            if view.synthetic:
                # Kept in memory too: variants that render the same pseudo-view (SD, SPD and
                # DSP share their syntheses) parse and describe it once per process, and
                # once per run where the disk entry is there before the next one asks.
                self._remember(key, arrays)
            value = unpack(arrays)
        elif view.synthetic and key not in self._memory:  # read from disk (another worker wrote it): kept too
            self._remember(key, pack(value))
        return value

    def regions(self, parser: Parser, view: View) -> Regions:
        return self._cached(parser, view, parser.parse, _pack_regions, _unpack_regions)

    def stored_regions(self, parser: ResolvedStage, view: View, key: str) -> Regions | None:
        """The regions ``parser`` gave the view whose content key is ``key`` (:meth:`view_keys`),
        read back without making the parser or parsing again; ``None`` if none are stored."""
        self.know(view, key)
        return self._load(parser, view, _unpack_regions)[1]  # type: ignore[arg-type]  # stage_key takes a resolved stage too

    def local_features(self, descriptor: LocalDescriptor, view: View) -> LocalFeatures:
        return self._cached(descriptor, view, descriptor.extract, _pack_local, _unpack_local)


def encode_entry(arrays: dict[str, np.ndarray]) -> bytes:
    """An entry as its ``.npz`` file holds it (compressed: a worker does it, not the one writer)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def decode_entry(data: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(data), allow_pickle=False) as archive:
        return {k: archive[k] for k in archive.files}


def compute_many(stage: Parser | LocalDescriptor, views: Sequence[View]) -> list[dict[str, np.ndarray]]:
    """What the cache stores for each of ``views``, computed in one batch of ``stage``
    (a parser's regions, a local descriptor's features)."""
    if isinstance(stage, Parser):
        return [_pack_regions(r) for r in stage.parse_many(views)]
    return [_pack_local(f) for f in stage.extract_many(views)]


def _pack_local(features: LocalFeatures) -> dict[str, np.ndarray]:
    return {"positions": features.positions, "descriptors": features.descriptors}


def _unpack_local(arrays: dict[str, np.ndarray]) -> LocalFeatures:
    return LocalFeatures(positions=arrays["positions"], descriptors=arrays["descriptors"])


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
