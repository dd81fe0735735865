"""Stacking: a fusion rule learned on the validation views.

Reciprocal-rank fusion gives every variant the same vote, so weak members (variants that
describe before synthesizing, those without synthesis) can outvote the strong ones, and
it throws away how sure each member is. Stacking learns both from the validation views:
the fused score of class ``c`` is

    sum over members v of  a_v * log p_v(c)  +  b_v / rank_v(c)

with non-negative weights ``a`` (a per-member inverse temperature: how far to trust its
calibration) and ``b`` (a weighted reciprocal-rank vote). The weights maximise the
likelihood of the validation views' true classes under a softmax of the fused scores (a
conditional-logit model, convex in the weights), with a small L2 penalty so that a few
validation views cannot make one weight run away. A member whose weights are both zero
is dropped, so stacking also chooses members, without the all-or-nothing of forward
selection.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from ssga_core import Fuser, InputError, PluginError, StageConfig, hookimpl
from ssga_core import reciprocal_ranks

Input = Literal["log-probability", "reciprocal-rank"]
FLOOR = 1e-6
"""Probabilities are floored here before the log: a member that gives a class zero must not veto it."""


class StackingConfig(StageConfig):
    inputs: list[Input] = Field(
        default=["log-probability", "reciprocal-rank"],
        min_length=1,
        description="What of each member's scores is weighted: its log-probabilities (scores must lie in [0, 1]) and/or its reciprocal ranks.",
    )
    l2: float = Field(default=1e-3, ge=0.0, le=10.0, description="L2 penalty on the weights (per validation view), against overfitting a small validation split.")


class Stacking(Fuser):
    name = "stacking"
    abbrev = "STK"
    Config = StackingConfig
    learns = True

    def __init__(self, config: StageConfig | None = None) -> None:
        super().__init__(config)
        self.weights: np.ndarray | None = None
        """``(members, inputs)`` after :meth:`fit`."""

    def _inputs(self, scores: np.ndarray) -> np.ndarray:
        """``(V, I, Q, C)``: each member's inputs, in the config's order."""
        out = []
        for name in self.config.inputs:
            if name == "log-probability":
                if scores.min() < 0.0 or scores.max() > 1.0:
                    raise InputError(
                        f"fuser 'stacking': input 'log-probability' needs class probabilities in [0, 1], got scores in "
                        f"[{scores.min():.3g}, {scores.max():.3g}]; use inputs = ['reciprocal-rank']"
                    )
                out.append(np.log(np.maximum(scores, FLOOR)))
            else:
                out.append(reciprocal_ranks(scores, axis=-1, ties="average"))  # tied classes share their votes, as in rrf
        return np.stack(out, axis=1)

    def fit(self, scores: np.ndarray, truth: np.ndarray) -> None:
        from scipy.optimize import minimize  # here: listing the plugins stays fast

        scores = self.checked_scores(scores)
        truth = np.asarray(truth)
        if truth.shape != scores.shape[1:2] or not np.issubdtype(truth.dtype, np.integer) or truth.min() < 0 or truth.max() >= scores.shape[2]:
            raise InputError(f"fuser 'stacking': expected {scores.shape[1]} true classes in [0, {scores.shape[2]}), got {truth.shape} {truth.dtype}")
        members, inputs = scores.shape[0], len(self.config.inputs)
        # (Q, V*I, C): one column of the conditional-logit model per member and input.
        x = self._inputs(scores).reshape(members * inputs, *scores.shape[1:]).transpose(1, 0, 2)
        at_truth = x[np.arange(len(truth)), :, truth]  # (Q, V*I)
        l2 = self.config.l2

        def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
            logits = np.einsum("qfc,f->qc", x, w)
            logits -= logits.max(axis=1, keepdims=True)
            log_norm = np.log(np.exp(logits).sum(axis=1))
            p = np.exp(logits - log_norm[:, None])
            nll = float(np.mean(log_norm - logits[np.arange(len(truth)), truth]))
            grad = np.einsum("qc,qfc->f", p, x) / len(truth) - at_truth.mean(axis=0)
            return nll + l2 * float(w @ w), grad + 2.0 * l2 * w

        start = np.full(members * inputs, 1.0 / (members * inputs))
        found = minimize(loss, start, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * len(start))
        if not np.isfinite(found.x).all():
            raise PluginError(f"fuser 'stacking': fitting the weights failed ({found.message})")
        self.weights = found.x.reshape(members, inputs)

    def learned(self) -> dict[str, Any]:
        if self.weights is None:
            return {}
        return {"inputs": list(self.config.inputs), "weights": self.weights.round(6).tolist()}

    def _fuse(self, scores: np.ndarray) -> np.ndarray:
        if self.weights is None:
            raise PluginError("fuser 'stacking' fuses only after fit() on validation scores (protocol.val_per_class > 0)")
        if scores.shape[0] != self.weights.shape[0]:
            raise InputError(f"fuser 'stacking': fitted on {self.weights.shape[0]} members, got scores of {scores.shape[0]}")
        return np.einsum("viqc,vi->qc", self._inputs(scores), self.weights)


@hookimpl
def ssga_register_fusers() -> list[type[Fuser]]:
    return [Stacking]
