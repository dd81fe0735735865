"""What Detic detects: class embeddings (its classifier) and the names that go with them.

Detic classifies a box by the cosine similarity of its feature with each class's CLIP
text embedding, so the vocabulary is data, not weights: a ``(C, 512)`` ``.npy`` file
(Detic's ``datasets/metadata/lvis_v1_clip_a+cname.npy`` for the 1203 LVIS classes, stored
as float16; any other list embedded the same way, CLIP ViT-B/32 text features of
"a <name>") and ``C`` names in the same order.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ssga_core import CheckpointError

EMBEDDINGS_EXPECTED = "a (classes, 512) array of CLIP text embeddings in a .npy file, such as Detic's lvis_v1_clip_a+cname.npy"
NAMES_EXPECTED = (
    "class names in the embeddings' order: a text file of one name per line, a JSON list of names, or LVIS "
    "categories (a JSON list of objects with 'id' and 'name', such as Detic's lvis_v1_train_cat_info.json)"
)


def read_embeddings(path: Path, who: str) -> np.ndarray:
    """``(C, 512)`` float32 class embeddings from a ``.npy`` file; anything else is one :class:`CheckpointError` line."""
    try:
        embeddings = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"{who}: config field 'vocabulary': {path} is not a .npy array ({exc}); expected {EMBEDDINGS_EXPECTED}") from None
    if embeddings.ndim != 2 or embeddings.shape[0] < 1 or embeddings.shape[1] != 512 or not np.issubdtype(embeddings.dtype, np.floating):
        raise CheckpointError(
            f"{who}: config field 'vocabulary': {path} holds a {embeddings.shape} array of {embeddings.dtype}; expected {EMBEDDINGS_EXPECTED}"
        )
    embeddings = embeddings.astype(np.float32)
    if not np.isfinite(embeddings).all() or not (np.abs(embeddings).sum(axis=1) > 0).all():
        raise CheckpointError(f"{who}: config field 'vocabulary': {path} has non-finite or all-zero rows; expected {EMBEDDINGS_EXPECTED}")
    return embeddings


def read_names(path: Path, who: str) -> tuple[str, ...]:
    """Class names from a text or JSON file (see :data:`NAMES_EXPECTED`); anything else is one :class:`CheckpointError` line."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise CheckpointError(f"{who}: config field 'class_names': cannot read {path} ({exc}); expected {NAMES_EXPECTED}") from None
    if path.suffix.lower() != ".json":
        names = tuple(line.strip() for line in text.splitlines() if line.strip())
    else:
        try:
            names = _json_names(json.loads(text))
        except (ValueError, KeyError, TypeError) as exc:
            raise CheckpointError(f"{who}: config field 'class_names': {path} is not a list of names ({exc}); expected {NAMES_EXPECTED}") from None
    if not names:
        raise CheckpointError(f"{who}: config field 'class_names': {path} names no class; expected {NAMES_EXPECTED}")
    return names


def _json_names(data: object) -> tuple[str, ...]:
    if not isinstance(data, list):
        raise TypeError(f"a JSON {type(data).__name__}")
    if all(isinstance(item, str) for item in data):
        return tuple(data)
    # LVIS categories: the classifier's rows follow the category ids.
    return tuple(str(item["name"]) for item in sorted(data, key=lambda item: int(item["id"])))
