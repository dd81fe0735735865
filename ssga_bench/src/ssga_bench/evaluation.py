"""Scoring rankings as the paper does (§4.2), with the uncertainty the paper leaves out.

Every scored row (each variant, the ensemble, references such as a nearest-neighbour
baseline or an oracle) is scored per group of test views (the difficulty levels L1,
L2, L3, any other groups the caller passes, such as near/far, and all views) by:

* Top-1, Top-5 and MRR (the paper's Table 1), in percent;
* Recall@N, the share of queries whose true class ranks N or better (one true class
  per query), for N = 10 and 20; R@1 is Top-1 and R@5 is Top-5, so they are not repeated;
* where the caller says which location (cell) each class is at, the Top-1 of the location:
  the share of queries whose first class is at the true class's location, whatever its
  heading. Top-1 counts a query right only with its heading too, so the difference is the
  queries that found the place but not the way the camera faces.

Each value comes with n and a 95% interval: a Wilson score interval for the rates
(Top-k, Recall@N: it stays inside 0-100% and is not zero-width at 0% or 100%), a
t-interval on the per-query reciprocal ranks for MRR. The ensemble is compared with each
variant on the same queries (a paired t-interval on the per-query differences).

Two references need no scores: ``random`` (the exact expected values of a uniformly
random ranking) and the best single variant, chosen by the caller on validation data:
choosing it here, on the test views, would flatter it.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from ssga_core.ranking import ranks

METRICS = ("top1", "top5", "mrr")
"""Table 1's metrics."""
RECALLS = ("r10", "r20")
ALL_METRICS = METRICS + RECALLS
CUTOFFS = {"top1": 1, "top5": 5, "r10": 10, "r20": 20}
"""The rate metrics: the share of queries whose true class ranks this or better."""
LOCATION = "loc1"
"""The Top-1 of the location, scored only where the caller gives each class's location."""
LOCATION_NOTE = (
    "Top-1 counts a test view right only with its heading as well; the difference between the two is the views "
    "whose place was found but not the way the camera faces, and 100 less this is the share sent to another place."
)
METRIC_TITLES = {"top1": "Top-1[%]", "top5": "Top-5[%]", "mrr": "MRR[%]", "r10": "R@10[%]", "r20": "R@20[%]", LOCATION: "Top-1 location[%]"}
LEVELS = ("L1", "L2", "L3", "all")
THIN = 30
"""Groups with fewer test views than this are reported as too thin to read."""
AT_CHANCE = "at chance"
INTERVALS = (
    "95% intervals: Wilson score for Top-k and Recall@N, t-interval on the per-query reciprocal ranks for MRR, "
    "paired t-interval on the per-query differences for the ensemble comparison; ± is half the interval's width "
    "(Wilson intervals are asymmetric: the exact bounds are in results.csv)."
)

Z95 = 1.959963984540054
_T95 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131)
"""Two-sided 95% quantiles of Student's t for 1..15 degrees of freedom (no scipy needed)."""


def t95(df: int) -> float:
    """Two-sided 95% quantile of Student's t with ``df`` degrees of freedom."""
    if df < 1:
        return math.nan
    if df <= len(_T95):
        return _T95[df - 1]
    # Cornish-Fisher expansion around the normal quantile: within 0.001 of the table beyond 15.
    z = Z95
    return z + (z**3 + z) / (4 * df) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * df**2)


@dataclass(frozen=True)
class Estimate:
    """A value with its 95% interval and the number of values behind it."""

    value: float
    low: float
    high: float
    n: int

    @property
    def half_width(self) -> float:
        return (self.high - self.low) / 2

    def contains(self, x: float) -> bool:
        return bool(self.low <= x <= self.high)

    def text(self, signed: bool = False) -> str:
        """``12.3 ±4.5`` (``+12.3 ±4.5`` if ``signed``); ``–`` without a value; the bare value
        without an interval (an exact value, or fewer than two queries)."""
        if math.isnan(self.value):
            return "–"
        value = f"{self.value:+.1f}" if signed else f"{self.value:.1f}"
        if math.isnan(self.half_width) or self.half_width == 0:
            return value
        return f"{value} ±{self.half_width:.1f}"

    def to_json(self) -> dict[str, Any]:
        return {"value": _finite(self.value), "low": _finite(self.low), "high": _finite(self.high), "n": self.n}


def _finite(x: float) -> float | None:
    return None if math.isnan(x) else round(float(x), 6)


def exact(value: float, n: int) -> Estimate:
    return Estimate(value, value, value, n)


def mean_interval(values: np.ndarray) -> Estimate:
    """Mean of ``values`` with its 95% t-interval (no interval below two values)."""
    values = np.asarray(values, dtype=np.float64)
    n = len(values)
    if n == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    mean = float(values.mean())
    half = t95(n - 1) * float(values.std(ddof=1)) / math.sqrt(n) if n > 1 else math.nan
    return Estimate(mean, mean - half, mean + half, n)


def seeds_estimate(estimates: Sequence[Estimate]) -> Estimate:
    """Mean over seeds with a 95% t-interval across them; one seed: its own per-query interval.

    Across seeds rather than pooled queries: the seeds differ in their training and test
    draws, and that spread is what a rerun would see.
    """
    present = [e for e in estimates if not np.isnan(e.value)]  # a seed whose draw left a group empty
    if len(present) == 1:
        return present[0]
    return mean_interval(np.array([e.value for e in present]))


def rate_interval(hits: np.ndarray) -> Estimate:
    """Share of true ``hits``, in percent, with its 95% Wilson score interval."""
    hits = np.asarray(hits, dtype=bool)
    n = len(hits)
    if n == 0:
        return Estimate(math.nan, math.nan, math.nan, 0)
    p = float(hits.mean())
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    # Clipped to p: the bounds' rounding error must not leave 0% or 100% outside its own interval.
    return Estimate(100 * p, 100 * min(p, centre - half), 100 * max(p, centre + half), n)


def truth_ranks(scores: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """1-based rank of the true class of each query (ties broken by class index)."""
    scores = np.asarray(scores)
    return ranks(scores, axis=-1)[np.arange(len(truth)), np.asarray(truth)]


def per_query(rank: np.ndarray, metric: str) -> np.ndarray:
    """Each query's contribution to ``metric``, in percent: 100 / rank for MRR, 100 or 0 for a rate."""
    rank = np.asarray(rank, dtype=np.float64)
    return 100.0 / rank if metric == "mrr" else 100.0 * (rank <= CUTOFFS[metric])


def recall_at(rank: np.ndarray, n: int) -> float:
    """Recall@n in percent: the share of queries whose true class ranks ``n`` or better."""
    rank = np.asarray(rank)
    return 100 * float(np.mean(rank <= n)) if len(rank) else math.nan


def estimates(rank: np.ndarray) -> dict[str, Estimate]:
    """Every metric of these ranks of the true class, with its interval."""
    rank = np.asarray(rank)
    return {m: mean_interval(per_query(rank, m)) if m == "mrr" else rate_interval(rank <= CUTOFFS[m]) for m in ALL_METRICS}


def metrics(rank: np.ndarray) -> dict[str, float]:
    """Every metric of these ranks of the true class (NaN for no query)."""
    return {m: e.value for m, e in estimates(rank).items()}


HALVINGS = 500
"""Random halvings of a group's test views behind :meth:`Report.against_chosen_on_other_half`: over five sets of them
the figure spread over 0.08 to 0.23 points on 100 views (the L3 of `bench` home 103 and `paper` home 102), against
paired intervals of about ±4 on the same views."""


def random_metrics(num_classes: int) -> dict[str, float]:
    """Expected scores of a uniformly random ranking of ``num_classes`` classes."""
    harmonic = float(np.sum(1.0 / np.arange(1, num_classes + 1)))
    rates = {m: 100 * min(n, num_classes) / num_classes for m, n in CUTOFFS.items()}
    return rates | {"mrr": 100 * harmonic / num_classes}


def location_hits(scores: np.ndarray, truth: np.ndarray, place_locations: np.ndarray) -> np.ndarray:
    """Per query, whether its first class (ties broken by class index, as the ranks do) is at the
    true class's location: ``place_locations`` is the ``(C,)`` location of each class."""
    first = np.argmax(np.asarray(scores), axis=-1)
    return place_locations[first] == place_locations[np.asarray(truth)]


def random_location_top1(truth: np.ndarray, place_locations: np.ndarray) -> float:
    """The expected Top-1 of the location of a uniformly random ranking, in percent: each query's
    first class is at its location with the share of classes that are."""
    at_each = np.bincount(place_locations)
    return 100.0 * float(np.mean(at_each[place_locations[np.asarray(truth)]])) / len(place_locations) if len(truth) else math.nan


def level_groups(levels: np.ndarray) -> dict[str, np.ndarray]:
    """``{"L1": mask, "L2": mask, "L3": mask}`` of the test views' difficulty levels."""
    levels = np.asarray(levels)
    return {f"L{k}": levels == k for k in (1, 2, 3)}


Stats = dict[str, dict[str, Estimate]]
"""group -> metric -> estimate."""


def group_estimates(rank: np.ndarray, groups: Mapping[str, np.ndarray]) -> Stats:
    """Every metric per group of queries, of these ranks of the true class."""
    return {g: estimates(rank[mask]) for g, mask in groups.items()}


def score_rows(scores: Mapping[str, np.ndarray], truth: np.ndarray, groups: Mapping[str, np.ndarray]) -> dict[str, Stats]:
    """Every metric per group of each row's ``(Q, C)`` scores."""
    return {label: group_estimates(truth_ranks(s, truth), groups) for label, s in scores.items()}


def verdict(difference: Estimate) -> str:
    """``better``/``worse`` where the interval of a difference excludes zero, else ``tie``."""
    if math.isnan(difference.value):
        return "–"
    return "better" if difference.low > 0 else "worse" if difference.high < 0 else "tie"


def difference_text(difference: Estimate) -> str:
    """``+1.2 ±0.8 better``; ``–`` for no queries."""
    return "–" if math.isnan(difference.value) else f"{difference.text(signed=True)} {verdict(difference)}"


Kind = Literal["variant", "ensemble", "best single", "reference", "random"]

NEAREST = "nearest neighbour"
"""The nearest-neighbour reference row's name; its label adds the variant whose features it uses, ``nearest neighbour (SIFT (SD))``."""
FUSED = "Ensemble"
"""How every fused row's label begins, ``Ensemble (<fuser tag>)``: the ensemble row and the fusion rules reported beside it."""


def fused_label(tag: str) -> str:
    """The label a fused row begins with, for a fuser's tag (``Ensemble (RRF)``)."""
    return f"{FUSED} ({tag})"


@dataclass(frozen=True)
class Row:
    label: str
    kind: Kind
    stats: Stats
    flags: tuple[str, ...] = ()
    source: str | None = None
    """Best single: the variant it repeats."""
    series: str | None = None
    """The row's name across seeds where its label names what this seed chose (``nearest neighbour (SIFT (SD))``)."""

    @property
    def key(self) -> str:
        """The row's name across seeds: the best single variant, the chosen members... may differ from seed to seed."""
        if self.series is not None:
            return self.series
        return self.label.partition(": ")[0] if self.kind == "best single" else self.label


@dataclass(frozen=True, eq=False)
class Report:
    """A Table-1-style result: variant rows, the ensemble, the best single variant, references, random."""

    title: str
    rows: dict[str, Row]
    counts: dict[str, int]
    """Test views per group, ``all`` last."""
    num_classes: int
    true_ranks: dict[str, np.ndarray] = field(repr=False)
    """Rank of the true class per query, for every scored row."""
    masks: dict[str, np.ndarray] = field(repr=False)
    not_run: dict[str, str] = field(default_factory=dict)
    """Variants that could not run (a checkpoint that is not there), with why: shown, never dropped."""
    notes: tuple[str, ...] = ()
    """What the reader must know of every row's scores (e.g. a heading prior they carry), shown under the title."""

    @classmethod
    def build(
        cls,
        title: str,
        variant_scores: Mapping[str, np.ndarray],
        truth: np.ndarray,
        *,
        groups: Mapping[str, np.ndarray],
        num_classes: int,
        ensemble: tuple[str, np.ndarray],
        best_single: str | None = None,
        best_single_basis: str = "validation",
        references: Mapping[str, np.ndarray] | None = None,
        flags: Mapping[str, str] | None = None,
        not_run: Mapping[str, str] | None = None,
        series: Mapping[str, str] | None = None,
        place_locations: np.ndarray | None = None,
    ) -> Report:
        """Score every row.

        Args:
            variant_scores: ``(Q, C)`` scores of each variant on the test views.
            truth: ``(Q,)`` true class of each test view.
            groups: ``(Q,)`` boolean masks of test views, in display order (``L1``, ``L2``,
                ``L3`` for Table 1, then e.g. ``near``, ``far``); ``all`` is added.
            ensemble: the fused row's label and ``(Q, C)`` scores.
            best_single: the variant chosen on ``best_single_basis`` data, repeated as
                ``best single (<basis>): <label>``; None for no such row.
            references: further ``(Q, C)`` rows (baselines, oracles), shown after the ensemble.
            flags: a warning per row label, shown beside it; ``at chance`` is added to
                every scored row whose all-views MRR interval holds the random MRR.
            not_run: variants without scores (their weights are missing) and why; each
                is listed in the tables as not run.
            series: for the ensemble and reference rows whose label depends on what was
                chosen on this seed's data, the name that joins them across seeds.
            place_locations: ``(C,)`` the location (grid cell) of each class, non-negative
                integers; with it every row is also scored by the Top-1 of the location
                (:data:`LOCATION`).
        """
        references, flags = dict(references or {}), dict(flags or {})
        truth = np.asarray(truth)
        ens_label, fused = ensemble
        scored = {**variant_scores, ens_label: fused, **references}
        if len(scored) != len(variant_scores) + 1 + len(references):
            raise ValueError(
                f"row labels must differ: variants {list(variant_scores)}, ensemble {ens_label!r}, references {list(references)}"
            )
        for label, s in scored.items():
            if np.shape(s) != (len(truth), num_classes):
                raise ValueError(f"row {label!r}: scores of shape {np.shape(s)}, expected {(len(truth), num_classes)}")
        if best_single is not None and best_single not in variant_scores:
            raise ValueError(f"best single {best_single!r} is not a variant: {list(variant_scores)}")
        unknown = set(flags) - set(scored)
        if unknown:
            raise ValueError(f"flags for rows that do not exist: {sorted(unknown)}")
        masks = {g: np.asarray(m, dtype=bool) for g, m in groups.items() if g != "all"} | {"all": np.ones(len(truth), dtype=bool)}
        for g, m in masks.items():
            if m.shape != truth.shape:
                raise ValueError(f"group {g!r}: mask of shape {m.shape}, expected {truth.shape}")

        rank = {label: truth_ranks(s, truth) for label, s in scored.items()}
        stats = {label: group_estimates(r, masks) for label, r in rank.items()}
        counts = {g: int(m.sum()) for g, m in masks.items()}
        chance = {g: random_metrics(num_classes) for g in masks}
        if place_locations is not None:
            place_locations = np.asarray(place_locations)
            integer = np.issubdtype(place_locations.dtype, np.integer)
            if place_locations.shape != (num_classes,) or not integer or np.any(place_locations < 0):
                raise ValueError(
                    f"place_locations: expected {num_classes} non-negative integer locations, "
                    f"got {place_locations.dtype} of shape {place_locations.shape}"
                )
            for label, s in scored.items():
                hits = location_hits(s, truth, place_locations)
                for g, m in masks.items():
                    stats[label][g][LOCATION] = rate_interval(hits[m])
            for g, m in masks.items():
                chance[g][LOCATION] = random_location_top1(truth[m], place_locations)

        def row(label: str, kind: Kind, source: str | None = None) -> Row:
            of = source or label
            at_chance = (AT_CHANCE,) if stats[of]["all"]["mrr"].contains(chance["all"]["mrr"]) else ()
            return Row(label, kind, stats[of], tuple(f for f in (flags.get(of),) if f) + at_chance, source)

        # The ensemble's label names its members where they were chosen on this seed's
        # validation views: its series joins it across seeds, as for the references.
        rows = [row(v, "variant") for v in variant_scores] + [dataclasses.replace(row(ens_label, "ensemble"), series=(series or {}).get(ens_label))]
        if best_single is not None:
            rows.append(row(f"best single ({best_single_basis}): {best_single}", "best single", best_single))
        rows += [dataclasses.replace(row(r, "reference"), series=(series or {}).get(r)) for r in references]
        rows.append(Row("random", "random", {g: {m: exact(v, counts[g]) for m, v in chance[g].items()} for g in masks}))
        return cls(title, {r.label: r for r in rows}, counts, num_classes, rank, masks, dict(not_run or {}))

    # -- what the rows are -----------------------------------------------------------

    def labels(self, *kinds: Kind) -> list[str]:
        return [label for label, row in self.rows.items() if row.kind in kinds]

    @property
    def variants(self) -> list[str]:
        return self.labels("variant")

    @property
    def ensemble(self) -> str:
        return self.labels("ensemble")[0]

    @property
    def best_single(self) -> str | None:
        chosen = [row.source for row in self.rows.values() if row.kind == "best single"]
        return chosen[0] if chosen else None

    @property
    def table(self) -> dict[str, dict[str, dict[str, float]]]:
        """row label -> group -> metric -> value, without the intervals."""
        return {label: {g: {m: e.value for m, e in s.items()} for g, s in row.stats.items()} for label, row in self.rows.items()}

    @property
    def levels(self) -> list[str]:
        """The difficulty-level groups present (and ``all``), in Table 1's order."""
        return [g for g in LEVELS if g in self.counts]

    @property
    def other_groups(self) -> list[str]:
        return [g for g in self.counts if g not in LEVELS]

    @property
    def has_location(self) -> bool:
        """Whether the rows are also scored by the Top-1 of the location (the classes' locations were given)."""
        return all(LOCATION in row.stats["all"] for row in self.rows.values())

    def thin_groups(self) -> dict[str, int]:
        return {g: n for g, n in self.counts.items() if n < THIN}

    def compare(self, member: str, group: str = "all", metric: str = "mrr") -> Estimate:
        """The ensemble minus ``member`` on the same queries, in percentage points, with a paired interval."""
        return self.difference(self.ensemble, member, group, metric)

    def difference(self, row: str, other: str, group: str = "all", metric: str = "mrr") -> Estimate:
        """``row`` minus ``other`` on the same queries, in percentage points, with a paired interval."""
        mask = self.masks[group]
        a, b = (per_query(self.true_ranks[label][mask], metric) for label in (row, other))
        return mean_interval(a - b)

    @property
    def fused(self) -> list[str]:
        """The ensemble row, then the fusion rules reported beside it."""
        return [self.ensemble] + [label for label in self.labels("reference") if label.startswith(FUSED + " (")]

    @property
    def nearest_neighbour(self) -> str | None:
        """The nearest-neighbour reference row (the best single variant's whole image, matched to the nearest training
        graph), if it was scored."""
        found = [label for label, row in self.rows.items() if row.kind == "reference" and row.label.startswith(NEAREST + " (")]
        return found[0] if found else None

    # -- what a choice among the variants could reach ------------------------------------------
    # These read the test labels: they say how much a fusion of these variants could gain, never
    # what one gains (the ensemble row does, choosing only on validation views).

    def best_variant_of_level(self, group: str, metric: str = "mrr") -> str:
        """The variant with the best ``metric`` on this group's test views."""
        return max(self.variants, key=lambda v: self.rows[v].stats[group][metric].value)

    def against_chosen_on_other_half(self, group: str, halvings: int = HALVINGS, metric: str = "mrr", seed: int = 0) -> float:
        """The ensemble minus the single variant chosen best on the other half of this group's test views, in percentage
        points, averaged over random halvings (each half chosen on in turn).

        The best of several variants measured on the very views it is compared on is the luckiest of several noisy
        figures, above what it would score on other views; choosing on one half and comparing on the other takes that
        luck out, at the cost of choosing on half the views."""
        mask = self.masks[group]
        n = int(mask.sum())
        if not self.variants or n < 2:
            return math.nan
        members = np.stack([per_query(self.true_ranks[v][mask], metric) for v in self.variants])  # (variants, views)
        ensemble = per_query(self.true_ranks[self.ensemble][mask], metric)
        rng = np.random.default_rng(seed)
        differences = []
        for _ in range(halvings):
            order = rng.permutation(n)
            halves = (order[: n // 2], order[n // 2 :])
            for choose, judge in (halves, halves[::-1]):
                chosen = int(np.argmax(members[:, choose].mean(axis=1)))
                differences.append(ensemble[judge].mean() - members[chosen, judge].mean())
        return float(np.mean(differences))

    def best_variant_per_view(self, group: str = "all", metric: str = "mrr") -> float:
        """``metric`` if each test view took the variant that ranks its true class best."""
        if not self.variants or not self.counts[group]:
            return math.nan
        best = np.min(np.stack([self.true_ranks[v][self.masks[group]] for v in self.variants]), axis=0)
        return float(per_query(best, metric).mean())

    def shared_hits(self) -> dict[str, dict[str, float]]:
        """For two variants, the share (%) of the test views that either puts first (its Top-1)
        which both put first: 100 where they are right on the same views, so fusing them can
        add nothing; low where each knows views the other does not."""
        hits = {v: self.true_ranks[v] == 1 for v in self.variants}
        out: dict[str, dict[str, float]] = {}
        for a in self.variants:
            out[a] = {}
            for b in self.variants:
                either = int(np.sum(hits[a] | hits[b]))
                out[a][b] = 100.0 * np.sum(hits[a] & hits[b]) / either if either else math.nan
        return out

    def ceiling_lines(self, metric: str = "mrr") -> list[str]:
        """Markdown: the ensemble beside what choosing among its variants on the test labels would reach."""
        groups = [g for g in self.levels if self.counts[g]]
        by_level = {g: self.best_variant_of_level(g, metric) for g in groups}
        lines = ["| " + METRIC_TITLES[metric] + " | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
        lines.append(f"| {self.ensemble} | " + " | ".join(f"{self.rows[self.ensemble].stats[g][metric].value:.1f}" for g in groups) + " |")
        lines.append(
            "| the best variant of each level | "
            + " | ".join(f"{self.rows[v].stats[g][metric].value:.1f} ({v})" for g, v in by_level.items())
            + " |"
        )
        lines.append("| the best variant for each view | " + " | ".join(f"{self.best_variant_per_view(g, metric):.1f}" for g in groups) + " |")
        shared = self.shared_hits()
        lines += [
            "",
            "Top-1 hits two variants share: of the test views either puts first, the share (%) both do. Fusion can "
            "only gain on the views where they differ, and only if their scores tell which one is right there.",
            "",
            "| | " + " | ".join(self.variants) + " |",
            "|---|" + "---:|" * len(self.variants),
            *(f"| {a} | " + " | ".join("–" if math.isnan(x) else f"{x:.0f}" for x in shared[a].values()) + " |" for a in self.variants),
        ]
        return lines + [""]

    # -- outputs ---------------------------------------------------------------------------

    def _name(self, label: str) -> str:
        row = self.rows[label]
        name = f"**{label}**" if row.kind == "ensemble" else label
        return f"{name} ⚠" if row.flags else name

    def _table(self, metrics: Sequence[str], groups: Sequence[str]) -> list[str]:
        head = "| | " + " | ".join(f"{METRIC_TITLES[m]} {g}" for m in metrics for g in groups) + " |"
        lines = [head, "|---|" + "---:|" * (len(metrics) * len(groups))]
        for label, row in self.rows.items():
            lines.append(f"| {self._name(label)} | " + " | ".join(row.stats[g][m].text() for m in metrics for g in groups) + " |")
        for label in self.not_run:
            lines.append(f"| {label} ⚠ | " + " | ".join("not run" for _ in metrics for _ in groups) + " |")
        return lines + [""]

    def comparison_lines(self, metric: str = "mrr") -> list[str]:
        """Markdown: the ensemble against each variant, per level group, and whether it beats them all."""
        groups = self.levels
        lines = ["| ensemble − variant | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
        diffs = {v: {g: self.compare(v, g, metric) for g in groups} for v in self.variants}
        for v, by_group in diffs.items():
            lines.append(f"| {v} | " + " | ".join(difference_text(d) for d in by_group.values()) + " |")
        lines.append("")
        for g in groups:
            if not self.counts[g]:
                lines.append(f"- {g}: no test views")
                continue
            verdicts = [verdict(diffs[v][g]) for v in self.variants]
            better, tie, worse = (verdicts.count(x) for x in ("better", "tie", "worse"))
            beats = "beats every variant" if better == len(verdicts) else "does not beat every variant"
            lines.append(f"- {g}: {beats} (better than {better}, tie with {tie}, worse than {worse} of {len(verdicts)})")
        return lines + [""]

    def markdown(self) -> str:
        lines = [f"### {self.title}", "", *(f"_{note}_\n" for note in self.notes), *self._table(METRICS, self.levels)]
        lines += ["Test views: " + ", ".join(f"{g} {n}" for g, n in self.counts.items()), ""]
        if self.other_groups:
            lines += ["#### By group", "", *self._table(METRICS, [*self.other_groups, "all"])]
        lines += ["#### Recall@N (R@1 is Top-1, R@5 is Top-5)", "", *self._table(RECALLS, list(self.counts))]
        if self.has_location:
            lines += ["#### Top-1 of the location (the first class at the right cell, whatever its heading)", "", LOCATION_NOTE, ""]
            lines += self._table((LOCATION,), list(self.counts))
        flagged = [(label, row.flags) for label, row in self.rows.items() if row.flags]
        flagged += [(label, (f"not run, {why}",)) for label, why in self.not_run.items()]
        if flagged:
            lines += ["#### Flags (⚠)", "", *(f"- {label}: {'; '.join(flags)}" for label, flags in flagged), ""]
        if self.variants:
            lines += [f"#### {self.ensemble} against each variant (MRR, percentage points)", "", *self.comparison_lines()]
            lines += ["#### What choosing among the variants could reach (read on the test labels: ceilings, not results)", ""]
            lines += self.ceiling_lines()
        thin = self.thin_groups()
        lines.append(
            f"Too thin to read (n < {THIN}): " + ", ".join(f"{g} (n={n})" for g, n in thin.items())
            if thin
            else f"Every group has at least {THIN} test views."
        )
        lines += ["", f"_{INTERVALS}_"]
        return "\n".join(lines) + "\n"

    def csv(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(["row", "kind", "group", "n", *(f"{m}{s}" for m in ALL_METRICS for s in ("", "_low", "_high")), "flags"])
        for label, row in self.rows.items():
            for g, stats in row.stats.items():
                values = [f"{x:.4f}" for m in ALL_METRICS for x in (stats[m].value, stats[m].low, stats[m].high)]
                writer.writerow([label, row.kind, g, self.counts[g], *values, "; ".join(row.flags)])
        for label, why in self.not_run.items():
            writer.writerow([label, "not run", "all", 0, *([""] * (3 * len(ALL_METRICS))), why])
        return out.getvalue()

    def to_json(self) -> dict[str, Any]:
        """Everything the tables show, JSON-safe (NaN as null)."""
        return {
            "title": self.title,
            "num_classes": self.num_classes,
            "counts": self.counts,
            "intervals": INTERVALS,
            "rows": [
                {
                    "label": row.label,
                    "kind": row.kind,
                    "key": row.key,
                    "flags": list(row.flags),
                    "stats": {g: {m: e.to_json() for m, e in s.items()} for g, s in row.stats.items()},
                }
                for row in self.rows.values()
            ],
            "not_run": self.not_run,
            "notes": list(self.notes),
            "ensemble_vs_variant_mrr": {v: {g: self.compare(v, g).to_json() for g in self.counts} for v in self.variants},
            "best_variant_per_view_mrr": {g: _finite(self.best_variant_per_view(g)) for g in self.counts},
            "shared_top1_hits": {a: {b: _finite(x) for b, x in row.items()} for a, row in self.shared_hits().items()},
        }

    def plot(self) -> bytes:
        """PNG: one panel per Table 1 metric (and the Top-1 of the location, where scored), bars per
        level group for each row, with 95% error bars."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        rows = [label for label, row in self.rows.items() if row.kind != "best single"]  # a repeat
        groups = self.levels
        metrics = METRICS + ((LOCATION,) if self.has_location else ())
        fig, axes = plt.subplots(1, len(metrics), figsize=(5 * len(metrics), 4.8))
        width = 0.8 / len(rows)
        cmap = plt.get_cmap("tab20")
        for ax, m in zip(axes, metrics):
            for i, label in enumerate(rows):
                kind, est = self.rows[label].kind, [self.rows[label].stats[g][m] for g in groups]
                values = np.array([e.value for e in est])
                errors = np.nan_to_num(np.array([[e.value - e.low for e in est], [e.high - e.value for e in est]]))
                colour = "black" if kind == "ensemble" else "lightgrey" if kind == "random" else cmap(i % 20)
                x = np.arange(len(groups)) + (i - len(rows) / 2 + 0.5) * width
                ax.bar(x, values, width, yerr=errors, label=label, color=colour, error_kw={"elinewidth": 0.8, "capsize": 1.5})
            ax.set_xticks(range(len(groups)), [f"{g} (n={self.counts[g]})" for g in groups])
            ax.set_title(METRIC_TITLES[m])
            ax.grid(axis="y", alpha=0.3)
        # Below the panels: inside one it would hide the bars.
        fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=min(len(rows), 5), fontsize=8, frameon=False)
        fig.suptitle(f"{self.title} (95% intervals)")
        fig.tight_layout(rect=(0, 0.06 * math.ceil(len(rows) / 5), 1, 1))
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        return buf.getvalue()
