"""Fusing a run's variants: the ensemble row (every variant, or the members chosen on the
validation views, :func:`choose_members`), the other fusion rules asked for, and the
reference rows beside them (the nearest neighbour of the best single variant, the oracles)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ssga_bench.config import Experiment
from ssga_bench.dataset import Dataset
from ssga_bench.evaluation import NEAREST, fused_label, truth_ranks
from ssga_bench.io import write_json
from ssga_bench.timings import Timings
from ssga_bench.variant_training import VariantResult
from ssga_core.errors import SsgaError
from ssga_core.stages import Fuser


def choose_members(val_scores: Mapping[str, np.ndarray], truth: np.ndarray, fuser: Fuser, levels: np.ndarray | None = None) -> list[str]:
    """Variants to fuse, chosen on the validation views: forward selection by fused MRR.

    Starts from the best single variant and adds, one at a time, the variant that raises
    the fused MRR most, while one does. With ``levels`` (each validation view's difficulty
    level), the MRR is the mean of the levels' own: a member strong only on the easy views,
    which are most of them, no longer outweighs one that holds up on the hard ones.
    """
    groups = [np.ones(len(truth), bool)] if levels is None else [levels == level for level in np.unique(levels)]

    def mrr(labels: Sequence[str]) -> float:
        reciprocal = 1.0 / truth_ranks(fuser.fuse(np.stack([val_scores[label] for label in labels])), truth)
        return float(np.mean([reciprocal[group].mean() for group in groups]))

    chosen = [max(val_scores, key=lambda label: mrr([label]))]
    best = mrr(chosen)
    while True:
        gains = {label: mrr([*chosen, label]) for label in val_scores if label not in chosen}
        if not gains or max(gains.values()) <= best:
            return chosen
        label = max(gains, key=gains.__getitem__)
        chosen.append(label)
        best = gains[label]


@dataclass(frozen=True)
class Fusion:
    """The rows fusion gives a run's report (:func:`fuse_variants`).

    Attributes:
        labels: the variants that ran, in the config's order.
        ensemble: the reported ensemble row: its label and test scores.
        best_single: the best single variant on the validation views (None without them).
        references: the rows reported beside the variants (other fusions, the nearest
            neighbour, the oracles), in the report's order.
        series: the name each fused or reference row has in the plot.
    """

    labels: list[str]
    ensemble: tuple[str, np.ndarray]
    best_single: str | None
    references: dict[str, np.ndarray]
    series: dict[str, str]


def fuse_variants(
    experiment: Experiment,
    dataset: Dataset,
    results: Mapping[str, VariantResult],
    oracle_results: Mapping[str, VariantResult],
    out: Path,
    timings: Timings,
) -> Fusion:
    """The ensemble and reference rows of a run from its variants' (and oracles') scores; the
    weights of a learned rule go to ``out/fusion.json``."""
    config = experiment.config
    vals = dataset.split("val")
    val_truth = np.array([s.place for s in vals])
    by_level = config.ensemble.selection == "levels"
    val_levels = np.array([s.level or 0 for s in vals]) if by_level else None  # a captured view without a level: a group of its own
    fuser = experiment.fuser.create()
    assert isinstance(fuser, Fuser)
    labels = [rv.label for rv in experiment.variants if rv.label in results]
    references: dict[str, np.ndarray] = {}
    series: dict[str, str] = {}
    best_single = None
    learned: dict[str, Any] = {}
    val_scores = {label: results[label].val for label in labels}

    def fused(rule: Fuser, members: list[str]) -> np.ndarray:
        """The test views' fused scores; a learned rule is first fitted on the validation views."""
        if rule.learns:
            if not len(vals):
                raise SsgaError(f"fuser {rule.name!r} is learned on the validation views, but the workspace has none (protocol.val_per_class)")
            rule.fit(np.stack([results[label].val for label in members]), val_truth)
            learned[fused_label(rule.tag())] = {"members": members, **rule.learned()}
        return rule.fuse(np.stack([results[label].test for label in members]))

    def over_chosen(rule: Fuser) -> tuple[str, np.ndarray]:
        """``rule`` over the members forward selection picks for it on the validation views: its row."""
        members = choose_members(val_scores, val_truth, rule, val_levels)
        how = "chosen on validation, each level equal" if by_level else "chosen on validation"
        label = f"{fused_label(rule.tag())} of {len(members)} {how}: " + ", ".join(members)
        series[label] = f"{fused_label(rule.tag())} {how}"
        return label, fused(rule, members)

    if len(vals):
        best_single = max(labels, key=lambda label: float(np.mean(1.0 / truth_ranks(val_scores[label], val_truth))))
    ensemble_label = fused_label(fuser.tag())
    with timings.phase("evaluate"):
        fused_all = fused(fuser, labels)
        # A rule that learns weighs its members itself (config validation says so); any other is
        # reported over all the variants and over the members chosen for it.
        chosen = over_chosen(fuser) if len(vals) and not fuser.learns else None
    if config.ensemble.members == "validation" and chosen is not None:
        ensemble = chosen
        references[ensemble_label + " of all"] = fused_all
    else:
        ensemble = (ensemble_label, fused_all)
        if chosen is not None:
            references[chosen[0]] = chosen[1]
    for also in experiment.also:
        rule = also.create()
        assert isinstance(rule, Fuser)
        with timings.phase("evaluate"):
            label = f"{fused_label(rule.tag())} of all" + (", learned on validation" if rule.learns else "")
            references[label] = fused(rule, labels)
            series[label] = fused_label(rule.tag())
            if len(vals) and not rule.learns:
                references.update([over_chosen(rule)])
    if learned:
        write_json(out / "fusion.json", learned)
    else:  # a rerun with no learned rule leaves no stale weights
        (out / "fusion.json").unlink(missing_ok=True)
    reference_variant = best_single or labels[0]
    references[f"{NEAREST} ({reference_variant})"] = results[reference_variant].nearest
    series[f"{NEAREST} ({reference_variant})"] = f"{NEAREST} (best single)"

    for label in labels:  # the config's order, whichever finished first
        if label in oracle_results:
            references[f"oracle: {label} on true renders"] = oracle_results[label].test

    return Fusion(labels, ensemble, best_single, references, series)
