"""Training views of homes, cached once per home: what every learned plugin's training data stands on.

A learned plugin trains on views it renders of procedural homes (views with labels,
RGB-D views, pairs, places). Rendering is the slow part, so each home's views are
rendered once and cached; a rerun, a resumed run or a held-out evaluation reads them
back. Two pieces, so a plugin writes only what its views are:

* :class:`ArrayRecord`: a dataclass of equal-length arrays (one row per view, pair or
  place) that concatenates, saves whole-or-not-at-all and loads itself::

      @dataclass
      class Labelled(ArrayRecord):
          rgb: np.ndarray        # (N, H, W, 3) uint8
          labels: np.ndarray     # (N, H, W) int8
          home: np.ndarray       # (N,) seeds

* :func:`cached_homes`: ``render(seed)`` of each home, cached in a folder under a name
  that holds the home, a digest of the settings the views depend on, and the renderer's
  version, so that changing any of them renders again instead of reading stale views.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar, Self, TypeVar

import numpy as np


class ArrayRecord:
    """Base of a dataclass whose array fields share their first axis (rows: views, pairs, places).

    Fields that are not arrays (a camera height) are scalars shared by every row: a
    concatenation keeps the first part's. :attr:`stored` names fields kept in the file
    at another dtype (depth as float16) and read back at the field's own.
    """

    stored: ClassVar[Mapping[str, Any]] = {}
    """Field -> dtype it is written at (read back at the dtype it had when written, unless :attr:`loaded` says)."""
    loaded: ClassVar[Mapping[str, Any]] = {}
    """Field -> dtype it is read back at."""

    def __len__(self) -> int:
        return len(getattr(self, dataclasses.fields(self)[0].name))  # type: ignore[arg-type]

    @classmethod
    def concat(cls, parts: Sequence[Self]) -> Self:
        values = {}
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            first = getattr(parts[0], f.name)
            values[f.name] = np.concatenate([getattr(p, f.name) for p in parts]) if isinstance(first, np.ndarray) else first
        return cls(**values)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every field as an array (scalars as 0-d arrays), at its stored dtype."""
        out = {}
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = np.asarray(getattr(self, f.name))
            out[f.name] = value.astype(self.stored[f.name]) if f.name in self.stored else value
        return out

    def save(self, path: Path) -> None:
        """As ``.npz``, written whole or not at all."""
        tmp = path.with_name(path.stem + ".tmp.npz")
        np.savez(tmp, **self.arrays())
        tmp.replace(path)

    @classmethod
    def load(cls, path: Path) -> Self:
        values: dict[str, Any] = {}
        with np.load(path, allow_pickle=False) as f:
            for field in dataclasses.fields(cls):  # type: ignore[arg-type]
                value = f[field.name]
                if field.name in cls.loaded:
                    value = value.astype(cls.loaded[field.name])
                values[field.name] = value.item() if value.ndim == 0 else value
        return cls(**values)


def settings_digest(settings: Mapping[str, Any]) -> str:
    """A short digest of JSON-able ``settings`` (key order does not matter)."""
    return hashlib.blake2b(json.dumps(settings, sort_keys=True, default=list).encode(), digest_size=4).hexdigest()


R = TypeVar("R", bound=ArrayRecord)


def cached_homes(
    folder: Path,
    kind: str,
    seeds: Sequence[int],
    settings: Mapping[str, Any],
    render: Callable[[int], R],
    record: type[R],
    *,
    progress: Callable[[str], None] | None = None,
) -> R:
    """``render(seed)`` of every home, concatenated; each home cached in ``folder`` as
    ``KIND-SEED-DIGEST.npz``, where DIGEST covers ``settings``: every setting the views
    depend on, the renderer's version among them (a change renders the home again)."""
    folder.mkdir(parents=True, exist_ok=True)
    digest = settings_digest(settings)
    parts = []
    for seed in seeds:
        path = folder / f"{kind}-{seed}-{digest}.npz"
        if not path.is_file():
            render(seed).save(path)
            if progress:
                progress(f"home {seed}: {kind} rendered into {path}")
        parts.append(record.load(path))
    return record.concat(parts)
