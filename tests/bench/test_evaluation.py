"""Top-1, Top-5, MRR per level; the random reference; the report."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from ssga_bench.evaluation import Report, metrics, random_metrics, truth_ranks


def test_ranks_and_metrics_by_hand():
    scores = np.array([[0.1, 0.7, 0.2], [0.5, 0.3, 0.2], [0.2, 0.2, 0.6]])
    ranks = truth_ranks(scores, np.array([1, 2, 0]))
    assert ranks.tolist() == [1, 3, 2]  # ties break by class index: class 0 before class 1
    m = metrics(ranks)
    assert m["top1"] == pytest.approx(100 / 3)
    assert m["top5"] == pytest.approx(100)
    assert m["mrr"] == pytest.approx(100 * (1 + 1 / 3 + 1 / 2) / 3)


def test_random_reference_matches_simulation():
    rng = np.random.default_rng(0)
    ranks = np.concatenate([rng.permutation(120) + 1 for _ in range(2000)])[::120]
    sim, exact = metrics(ranks), random_metrics(120)
    for key in exact:
        assert sim[key] == pytest.approx(exact[key], abs=1.0)
    assert exact["top5"] == pytest.approx(100 * 5 / 120)


def test_report_rows_levels_and_outputs():
    rng = np.random.default_rng(1)
    truth = rng.integers(0, 10, 60)
    levels = np.repeat([1, 2, 3], 20)
    good = np.eye(10)[truth] + 0.1 * rng.random((60, 10))
    bad = rng.random((60, 10))
    report = Report.build("ws", {"good": good, "bad": bad}, "Ensemble (RRF)", (good + bad) / 2, truth, levels, 10)
    assert report.best_single == "good"
    assert report.table["good"]["L2"]["top1"] == 100.0
    assert report.table["random"]["L1"]["top1"] == pytest.approx(10.0)
    assert report.counts == {"L1": 20, "L2": 20, "L3": 20, "all": 60}
    md = report.markdown()
    assert "| **Ensemble (RRF)** |" in md and "| best single: good |" in md
    rows = list(csv.DictReader(io.StringIO(report.csv())))
    assert len(rows) == 5 * 4 and {r["level"] for r in rows} == {"L1", "L2", "L3", "all"}
    png = report.plot()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_empty_levels_show_a_dash():
    truth = np.array([0, 1])
    report = Report.build("ws", {"a": np.eye(2)}, "E", np.eye(2), truth, np.array([1, 1]), 2)
    assert "| a | 100.0 | – | – |" in report.markdown()
