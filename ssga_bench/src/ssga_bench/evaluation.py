"""Scoring rankings as the paper does (§4.2): Top-1, Top-5 and MRR per difficulty level, in percent.

Also the two references every table needs: a random ranking (its expected scores,
exactly) and the best single variant (by MRR over all test views).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ssga_core.ranking import ranks

METRICS = ("top1", "top5", "mrr")
METRIC_TITLES = {"top1": "Top-1[%]", "top5": "Top-5[%]", "mrr": "MRR[%]"}
LEVELS = ("L1", "L2", "L3", "all")


def truth_ranks(scores: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """1-based rank of the true class of each query (ties broken by class index)."""
    scores = np.asarray(scores)
    return ranks(scores, axis=-1)[np.arange(len(truth)), np.asarray(truth)]


def metrics(rank: np.ndarray) -> dict[str, float]:
    rank = np.asarray(rank, dtype=np.float64)
    if not len(rank):
        return {m: float("nan") for m in METRICS}
    return {"top1": 100 * float(np.mean(rank <= 1)), "top5": 100 * float(np.mean(rank <= 5)), "mrr": 100 * float(np.mean(1.0 / rank))}


def random_metrics(num_classes: int) -> dict[str, float]:
    """Expected scores of a uniformly random ranking of ``num_classes`` classes."""
    harmonic = float(np.sum(1.0 / np.arange(1, num_classes + 1)))
    return {"top1": 100 / num_classes, "top5": 100 * min(5, num_classes) / num_classes, "mrr": 100 * harmonic / num_classes}


Table = dict[str, dict[str, dict[str, float]]]
"""row label -> level -> metric -> value."""


def score_rows(scores: Mapping[str, np.ndarray], truth: np.ndarray, levels: np.ndarray) -> Table:
    """Metrics per level (and over all test views) of each row's ``(Q, C)`` scores."""
    table: Table = {}
    for label, s in scores.items():
        r = truth_ranks(s, truth)
        table[label] = {f"L{k}": metrics(r[levels == k]) for k in (1, 2, 3)} | {"all": metrics(r)}
    return table


def _cell(value: float) -> str:
    return "–" if np.isnan(value) else f"{value:.1f}"


@dataclass(frozen=True)
class Report:
    """A Table-1-style result: variant rows, the ensemble, the best single variant, random."""

    title: str
    table: Table
    counts: dict[str, int]
    """Test views per level."""
    variants: Sequence[str]
    ensemble: str
    best_single: str

    @classmethod
    def build(cls, title: str, variant_scores: Mapping[str, np.ndarray], ensemble_label: str, fused: np.ndarray, truth: np.ndarray, levels: np.ndarray, num_classes: int) -> Report:
        table = score_rows({**variant_scores, ensemble_label: fused}, truth, levels)
        best = max(variant_scores, key=lambda label: table[label]["all"]["mrr"])
        table[f"best single: {best}"] = table[best]
        rnd = random_metrics(num_classes)
        table["random"] = {level: dict(rnd) for level in LEVELS}
        counts = {f"L{k}": int(np.sum(levels == k)) for k in (1, 2, 3)} | {"all": int(len(levels))}
        return cls(title, table, counts, list(variant_scores), ensemble_label, best)

    def markdown(self) -> str:
        head = "| | " + " | ".join(f"{METRIC_TITLES[m]} {lv}" for m in METRICS for lv in LEVELS) + " |"
        rule = "|---|" + "---:|" * (len(METRICS) * len(LEVELS))
        lines = [f"### {self.title}", "", head, rule]
        for label, row in self.table.items():
            name = f"**{label}**" if label == self.ensemble else label
            lines.append(f"| {name} | " + " | ".join(_cell(row[lv][m]) for m in METRICS for lv in LEVELS) + " |")
        lines += ["", "Test views: " + ", ".join(f"{lv} {n}" for lv, n in self.counts.items())]
        return "\n".join(lines) + "\n"

    def csv(self) -> str:
        out = io.StringIO()
        writer = csv.writer(out)
        writer.writerow(["row", "level", "n", *METRICS])
        for label, row in self.table.items():
            for lv in LEVELS:
                writer.writerow([label, lv, self.counts[lv], *(f"{row[lv][m]:.4f}" for m in METRICS)])
        return out.getvalue()

    def plot(self) -> bytes:
        """PNG: one panel per metric, bars per level for each variant, the ensemble and random."""
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        rows = [*self.variants, self.ensemble, "random"]
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.8), sharey=False)
        width = 0.8 / len(rows)
        cmap = plt.get_cmap("tab20")
        for ax, m in zip(axes, METRICS):
            for i, label in enumerate(rows):
                values = [self.table[label][lv][m] for lv in LEVELS[:3]]
                colour = "black" if label == self.ensemble else ("lightgrey" if label == "random" else cmap(i % 20))
                ax.bar(np.arange(3) + (i - len(rows) / 2 + 0.5) * width, values, width, label=label, color=colour)
            ax.set_xticks(range(3), [f"{lv} (n={self.counts[lv]})" for lv in LEVELS[:3]])
            ax.set_title(METRIC_TITLES[m])
            ax.grid(axis="y", alpha=0.3)
        axes[-1].legend(fontsize=7, loc="upper right")
        fig.suptitle(self.title)
        fig.tight_layout()
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=100)
        plt.close(fig)
        return buf.getvalue()
