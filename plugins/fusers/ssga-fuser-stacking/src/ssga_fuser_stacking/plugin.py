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

With a ``gate`` the weights depend on the query (feature-weighted linear stacking, Sill et
al. 2009): each weight is ``alpha * (1 - m) + beta * m`` with ``alpha, beta >= 0`` and a
query's meta-feature ``m`` in [0, 1], which spans every non-negative weight linear in ``m``
and keeps the fit convex. A fixed weight per member trusts it as much on a view every member
finds easy as on one far from anything it trained on, where other members may be the ones
that still rank well. ``m`` is a member's sharpness, ``1 - H(p) / log C`` of its class
probabilities, scaled to [0, 1] between its 5th and 95th percentiles on the validation views:
per member (``"sharpness"``: a sure member speaks louder) or their mean, one for all members
(``"consensus"``: how easy the query is).
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field

from ssga_core import Fuser, InputError, PluginError, StageConfig, hookimpl
from ssga_core import reciprocal_ranks

Input = Literal["log-probability", "reciprocal-rank"]
Gate = Literal["none", "sharpness", "consensus"]
FLOOR = 1e-6
"""Probabilities are floored here before the log: a member that gives a class zero must not veto it."""


class StackingConfig(StageConfig):
    inputs: list[Input] = Field(
        default=["log-probability", "reciprocal-rank"],
        min_length=1,
        description="What of each member's scores is weighted: its log-probabilities (scores must lie in [0, 1]) and/or its reciprocal ranks.",
    )
    l2: float = Field(default=1e-3, ge=0.0, le=10.0, description="L2 penalty on the weights (per validation view), against overfitting a small validation split.")
    gate: Gate = Field(
        default="none",
        description="Weights that depend on the query: 'sharpness' (each member's own), 'consensus' (the members' mean sharpness), or 'none' (one weight per member and input).",
    )


class Stacking(Fuser):
    name = "stacking"
    abbrev = "STK"
    Config = StackingConfig
    learns = True

    def __init__(self, config: StageConfig | None = None) -> None:
        super().__init__(config)
        self.weights: np.ndarray | None = None
        """``(members, inputs)`` after :meth:`fit`; ``(members, inputs, 2)`` (alpha, beta) with a gate."""
        self.sharpness_range: np.ndarray | None = None
        """``(members, 2)``: each member's sharpness that scales to 0 and to 1, from the validation views (with a gate)."""

    def _check_probabilities(self, scores: np.ndarray, needed_by: str) -> None:
        if scores.min() < 0.0 or scores.max() > 1.0:
            raise InputError(
                f"fuser 'stacking': {needed_by} needs class probabilities in [0, 1], got scores in "
                f"[{scores.min():.3g}, {scores.max():.3g}]; use inputs = ['reciprocal-rank'] and gate = 'none'"
            )

    def _inputs(self, scores: np.ndarray) -> np.ndarray:
        """``(V, I, Q, C)``: each member's inputs, in the config's order; ``(V, I, 2, Q, C)`` with a
        gate, each input times ``1 - m`` and times ``m``."""
        out = []
        for name in self.config.inputs:
            if name == "log-probability":
                self._check_probabilities(scores, "input 'log-probability'")
                out.append(np.log(np.maximum(scores, FLOOR)))
            else:
                out.append(reciprocal_ranks(scores, axis=-1, ties="average"))  # tied classes share their votes, as in rrf
        inputs = np.stack(out, axis=1)
        if self.config.gate == "none":
            return inputs
        m = self._gate(scores)[:, None, :, None]  # (V, 1, Q, 1)
        return np.stack([inputs * (1.0 - m), inputs * m], axis=2)

    @staticmethod
    def _sharpness(scores: np.ndarray) -> np.ndarray:
        """``(V, Q)``: ``1 - H(p) / log C`` of each member's scores normalised to sum to one."""
        p = np.maximum(scores, FLOOR)
        p = p / p.sum(axis=-1, keepdims=True)
        return 1.0 - (-(p * np.log(p)).sum(axis=-1)) / np.log(scores.shape[-1])

    def _gate(self, scores: np.ndarray) -> np.ndarray:
        """``(V, Q)``: each query's meta-feature for each member, in [0, 1] (scaled by :attr:`sharpness_range`)."""
        assert self.sharpness_range is not None
        self._check_probabilities(scores, f"gate {self.config.gate!r}")
        low, high = self.sharpness_range[:, :1], self.sharpness_range[:, 1:]
        m = np.clip((self._sharpness(scores) - low) / (high - low), 0.0, 1.0)
        if self.config.gate == "consensus":
            m = np.broadcast_to(m.mean(axis=0, keepdims=True), m.shape)
        return m

    def fit(self, scores: np.ndarray, truth: np.ndarray) -> None:
        from scipy.optimize import minimize  # here: listing the plugins stays fast

        scores = self.checked_scores(scores)
        truth = np.asarray(truth)
        if truth.shape != scores.shape[1:2] or not np.issubdtype(truth.dtype, np.integer) or truth.min() < 0 or truth.max() >= scores.shape[2]:
            raise InputError(f"fuser 'stacking': expected {scores.shape[1]} true classes in [0, {scores.shape[2]}), got {truth.shape} {truth.dtype}")
        self.sharpness_range = None
        if self.config.gate != "none":  # the validation views set the gate's scale (_gate checks they are probabilities)
            low, high = np.percentile(self._sharpness(scores), [5.0, 95.0], axis=1)
            self.sharpness_range = np.stack([low, np.maximum(high, low + 1e-12)], axis=1)
        # (Q, F, C): one column of the conditional-logit model per member and input (and gate basis).
        features = self._inputs(scores)
        shape = features.shape[:-2]
        x = features.reshape(-1, *scores.shape[1:]).transpose(1, 0, 2)
        at_truth = x[np.arange(len(truth)), :, truth]  # (Q, F)
        l2 = self.config.l2

        def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
            logits = np.einsum("qfc,f->qc", x, w)
            logits -= logits.max(axis=1, keepdims=True)
            log_norm = np.log(np.exp(logits).sum(axis=1))
            p = np.exp(logits - log_norm[:, None])
            nll = float(np.mean(log_norm - logits[np.arange(len(truth)), truth]))
            grad = np.einsum("qc,qfc->f", p, x) / len(truth) - at_truth.mean(axis=0)
            return nll + l2 * float(w @ w), grad + 2.0 * l2 * w

        start = np.full(x.shape[1], 1.0 / x.shape[1])
        found = minimize(loss, start, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * len(start))
        if not np.isfinite(found.x).all():
            raise PluginError(f"fuser 'stacking': fitting the weights failed ({found.message})")
        self.weights = found.x.reshape(shape)

    def learned(self) -> dict[str, Any]:
        if self.weights is None:
            return {}
        out: dict[str, Any] = {"inputs": list(self.config.inputs), "weights": self.weights.round(6).tolist()}
        if self.sharpness_range is not None:
            out |= {"gate": self.config.gate, "sharpness_range": self.sharpness_range.round(6).tolist()}
        return out

    def _fuse(self, scores: np.ndarray) -> np.ndarray:
        if self.weights is None:
            raise PluginError("fuser 'stacking' fuses only after fit() on validation scores (protocol.val_per_class > 0)")
        if scores.shape[0] != self.weights.shape[0]:
            raise InputError(f"fuser 'stacking': fitted on {self.weights.shape[0]} members, got scores of {scores.shape[0]}")
        features = self._inputs(scores)
        return np.einsum("fqc,f->qc", features.reshape(-1, *features.shape[-2:]), self.weights.ravel())


@hookimpl
def ssga_register_fusers() -> list[type[Fuser]]:
    return [Stacking]
