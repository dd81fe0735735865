"""Every random draw of a run has a stream of its own, keyed from its seed: the one place they are named.

Two draws that shared a generator (or two generators seeded alike) would repeat each other's
values: test views and pseudo-views drawn with the same pattern of calls from ``default_rng(seed)``
landed on the same poses. Each stream here is ``default_rng([seed, key])`` with its own key, so no
draw depends on how much another one consumed.

| stream | seed | what it draws |
|---|---|---|
| ``cells`` | ``protocol.seed`` | the order cells are drawn in, each cell's real class (captured workspaces: its real capture) |
| ``test`` | ``protocol.seed`` | test views (rendered: poses; captured: which captures) |
| ``val`` | ``protocol.seed`` | validation views |
| ``pseudo_poses`` | ``training.seed`` | pseudo-view poses and their jitter |
| ``classifier`` | ``training.seed`` | the classifier's initialisation, batch order and early-stopping split |
| ``fitting`` | the descriptor's ``seed`` | a fitted descriptor's subsampling and k-means (the bag of words) |
"""

from __future__ import annotations

import numpy as np

STREAMS = {"cells": 101, "test": 102, "val": 103, "pseudo_poses": 104, "classifier": 105, "fitting": 106}
"""Each stream's key: never reuse one, never renumber one (runs would be drawn differently)."""

DRAWS = 2
"""Which way of drawing made a dataset or a trained variant (in their keys): 1 drew several streams
from one generator. Bump it when a draw changes, so stored datasets and runs are re-made, not reused."""


def stream(seed: int, name: str) -> np.random.Generator:
    """The generator of stream ``name`` (:data:`STREAMS`) for ``seed``."""
    return np.random.default_rng([int(seed), STREAMS[name]])


def torch_seed(seed: int, name: str) -> int:
    """An integer seed for torch's generator, drawn from stream ``name``: its own, as numpy's are."""
    return int(np.random.SeedSequence([int(seed), STREAMS[name]]).generate_state(1)[0])
