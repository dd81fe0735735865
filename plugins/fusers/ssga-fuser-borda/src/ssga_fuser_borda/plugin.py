"""Two baselines for the paper's reciprocal-rank fusion.

* ``borda``: each variant gives a class ``C - rank`` points (C classes), so every rank
  counts linearly, where reciprocal ranks count mostly the top few. Tied classes take
  their mean rank.
* ``mean-prob``: the mean of the variants' class probabilities, which lets a confident
  variant outvote hesitant ones.
"""

from __future__ import annotations

import numpy as np

from ssga_core import Fuser, hookimpl
from ssga_core import ranks


class BordaCount(Fuser):
    name = "borda"
    abbrev = "Borda"

    def _fuse(self, scores: np.ndarray) -> np.ndarray:
        num_classes = scores.shape[-1]
        return (num_classes - ranks(scores, axis=-1, ties="average")).sum(axis=0)


class MeanProbability(Fuser):
    name = "mean-prob"
    abbrev = "Mean"

    def _fuse(self, scores: np.ndarray) -> np.ndarray:
        return scores.mean(axis=0)


@hookimpl
def ssga_register_fusers() -> list[type[Fuser]]:
    return [BordaCount, MeanProbability]
