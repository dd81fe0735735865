"""Reciprocal-rank fusion (Cormack et al., 2009), the paper's late fusion (§3.2).

Each variant's class probabilities become a reciprocal-rank vector ``1 / (k + rank)``;
the fused score of a class is the sum over variants. Only ranks matter, so variants
whose probabilities are calibrated differently (a confident GCN beside a hesitant one)
vote with equal weight, in the spirit of a majority vote. Classes a variant scores
alike share their ranks' votes equally (a variant without synthesis scores every heading
of a cell alike): breaking the tie by class index would vote for the lowest one.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssga_core import Fuser, StageConfig, hookimpl
from ssga_core import reciprocal_ranks


class RRFConfig(StageConfig):
    k: float = Field(
        default=0.0,
        ge=0.0,
        description="Rank offset: 0 gives the plain reciprocal rank the paper describes; Cormack et al. use 60, which flattens the weight of the top ranks.",
    )


class ReciprocalRankFusion(Fuser):
    name = "rrf"
    abbrev = "RRF"
    Config = RRFConfig

    def _fuse(self, scores: np.ndarray) -> np.ndarray:
        return reciprocal_ranks(scores, k=self.config.k, axis=-1, ties="average").sum(axis=0)


@hookimpl
def ssga_register_fusers() -> list[type[Fuser]]:
    return [ReciprocalRankFusion]
