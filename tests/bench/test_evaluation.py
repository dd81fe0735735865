"""Top-1, Top-5, MRR and Recall@N per group with 95% intervals; the references; the report; the bench summary."""

from __future__ import annotations

import csv
import io
import itertools
import json

import numpy as np
import pytest

from ssga_bench.evaluation import (
    AT_CHANCE,
    Report,
    level_groups,
    mean_interval,
    metrics,
    random_metrics,
    rate_interval,
    recall_at,
    t95,
    truth_ranks,
    verdict,
)


def test_ranks_and_metrics_by_hand():
    scores = np.array([[0.1, 0.7, 0.2], [0.5, 0.3, 0.2], [0.2, 0.2, 0.6]])
    ranks = truth_ranks(scores, np.array([1, 2, 0]))
    assert ranks.tolist() == [1, 3, 2]  # ties break by class index: class 0 before class 1
    m = metrics(ranks)
    assert m["top1"] == pytest.approx(100 / 3)
    assert m["top5"] == pytest.approx(100)
    assert m["mrr"] == pytest.approx(100 * (1 + 1 / 3 + 1 / 2) / 3)


def test_recall_at_n_on_a_hand_made_ranking():
    ranks = np.array([1, 2, 5, 6, 10, 11, 20, 21, 40, 100])
    assert [recall_at(ranks, n) for n in (1, 5, 10, 20)] == pytest.approx([10, 30, 50, 70])
    m = metrics(ranks)
    assert (m["top1"], m["top5"], m["r10"], m["r20"]) == pytest.approx((10, 30, 50, 70))  # R@1 is Top-1, R@5 Top-5
    recalls = [recall_at(np.random.default_rng(0).integers(1, 60, 500), n) for n in range(1, 61)]
    assert all(a <= b for a, b in itertools.pairwise(recalls)) and recalls[-1] == 100


def test_random_reference_matches_simulation():
    rng = np.random.default_rng(0)
    ranks = np.concatenate([rng.permutation(120) + 1 for _ in range(2000)])[::120]
    sim, exact = metrics(ranks), random_metrics(120)
    for key in exact:
        assert sim[key] == pytest.approx(exact[key], abs=1.5)
    assert exact["top5"] == pytest.approx(100 * 5 / 120) and exact["r20"] == pytest.approx(100 * 20 / 120)
    assert random_metrics(8)["r10"] == 100  # fewer classes than N: every query is found


def test_t_quantiles():
    assert t95(1) == pytest.approx(12.706, abs=1e-3)
    assert t95(16) == pytest.approx(2.120, abs=2e-3)
    assert t95(1000) == pytest.approx(1.962, abs=1e-3)


@pytest.mark.parametrize("interval", [rate_interval, mean_interval])
def test_intervals_contain_the_mean_and_shrink_with_n(interval):
    rng = np.random.default_rng(3)
    widths = []
    for n in (20, 200, 2000):
        values = rng.random(n) < 0.3
        e = interval(values if interval is rate_interval else 100.0 * values)
        assert e.n == n and e.low < e.value < e.high
        assert e.value == pytest.approx(100 * values.mean())
        widths.append(e.high - e.low)
    assert widths[0] > widths[1] > widths[2]


def test_wilson_interval_is_not_zero_width_at_the_edges():
    e = rate_interval(np.ones(20, dtype=bool))
    assert e.value == 100 and e.high == 100 and 80 < e.low < 90
    assert np.isnan(rate_interval(np.array([], dtype=bool)).value)


def _data(seed=1, q=120, c=10):
    rng = np.random.default_rng(seed)
    truth = rng.integers(0, c, q)
    groups = level_groups(np.repeat([1, 2, 3], q // 3)) | {"near": np.arange(q) % 2 == 0, "far": np.arange(q) % 2 == 1}
    return rng, truth, groups


def test_report_rows_groups_and_flags():
    rng, truth, groups = _data()
    good = np.eye(10)[truth] + 0.1 * rng.random((120, 10))
    bad = rng.random((120, 10))
    report = Report.build(
        "ws",
        {"good": good, "bad": bad},
        truth,
        groups=groups,
        num_classes=10,
        ensemble=("Ensemble (RRF)", (good + bad) / 2),
        best_single="bad",  # the caller's choice on validation data, kept even where the test views disagree
        references={"oracle: DS on true renders": np.eye(10)[truth]},
        flags={"good": "training stopped at the epoch cap"},
    )
    assert list(report.rows) == [
        "good", "bad", "Ensemble (RRF)", "best single (validation): bad", "oracle: DS on true renders", "random"
    ]  # fmt: skip
    assert list(report.counts) == ["L1", "L2", "L3", "near", "far", "all"]
    assert report.counts["L2"] == 40 and report.counts["all"] == 120
    assert report.best_single == "bad" and report.table["best single (validation): bad"] == report.table["bad"]
    assert report.table["good"]["L2"]["top1"] == 100.0
    # random: the exact expected values, with no interval
    rnd = report.rows["random"].stats["near"]["mrr"]
    assert rnd.value == rnd.low == rnd.high == pytest.approx(random_metrics(10)["mrr"]) and rnd.n == 60
    # at chance: random scores are, perfect ones are not; the caller's flags are kept
    assert AT_CHANCE in report.rows["bad"].flags and AT_CHANCE in report.rows["best single (validation): bad"].flags
    assert report.rows["good"].flags == ("training stopped at the epoch cap",)
    assert report.rows["oracle: DS on true renders"].flags == ()
    md = report.markdown()
    assert "| **Ensemble (RRF)** |" in md and "| good ⚠ | 100.0 ±" in md
    assert "- good: training stopped at the epoch cap" in md and "- bad: at chance" in md
    assert "#### By group" in md and "R@10[%] near" in md and "Every group has at least 30 test views." in md
    assert "Wilson" in md  # the footer says how the intervals were made


def test_csv_json_and_plot():
    rng, truth, groups = _data()
    scores = np.eye(10)[truth] + rng.random((120, 10))
    report = Report.build("ws", {"a": scores}, truth, groups=groups, num_classes=10, ensemble=("E", scores))
    rows = list(csv.DictReader(io.StringIO(report.csv())))
    assert len(rows) == 3 * 6  # (a, E, random) x (L1, L2, L3, near, far, all)
    first = rows[0]
    assert first["row"] == "a" and first["group"] == "L1" and first["n"] == "40"
    assert float(first["top1_low"]) <= float(first["top1"]) <= float(first["top1_high"]) and "r20_high" in first
    data = json.loads(json.dumps(report.to_json()))
    assert [r["key"] for r in data["rows"]] == ["a", "E", "random"]
    assert data["rows"][0]["stats"]["all"]["mrr"]["n"] == 120
    assert report.plot()[:8] == b"\x89PNG\r\n\x1a\n"


def test_ensemble_against_each_variant():
    rng, truth, groups = _data()
    perfect, noise = np.eye(10)[truth], rng.random((120, 10))
    report = Report.build("ws", {"same": perfect, "noise": noise}, truth, groups=groups, num_classes=10, ensemble=("E", perfect))
    same, better = report.compare("same", "L2"), report.compare("noise", "L2")
    assert same.value == 0 and verdict(same) == "tie"
    assert better.value > 0 and verdict(better) == "better"
    md = report.markdown()
    assert "| noise | +" in md and "- L2: does not beat every variant (better than 1, tie with 1, worse than 0 of 2)" in md


def test_ceilings_of_a_choice_among_the_variants_by_hand():
    # Four views of three classes; "a" is right on views 0 and 1, "b" on views 1 and 2, neither on view 3.
    truth = np.array([0, 1, 2, 0])
    a = np.array([[3, 2, 1], [1, 3, 2], [3, 2, 1], [1, 3, 2]], dtype=float)  # truth ranks 1, 1, 3, 3
    b = np.array([[2, 3, 1], [1, 3, 2], [1, 2, 3], [2, 3, 1]], dtype=float)  # truth ranks 2, 1, 1, 2
    groups = {"L1": np.array([True, True, False, False]), "L2": np.array([False, False, True, True])}
    report = Report.build("ws", {"a": a, "b": b}, truth, groups=groups, num_classes=3, ensemble=("E", a))
    # Per view the better rank is 1, 1, 1, 2.
    assert report.best_variant_per_view("L1") == pytest.approx(100)
    assert report.best_variant_per_view("L2") == pytest.approx(100 * (1 + 1 / 2) / 2)
    assert report.best_variant_per_view("all", "top1") == pytest.approx(75)
    # a's hits {0, 1}, b's {1, 2}: one shared of the three either gets.
    shared = report.shared_hits()
    assert shared["a"]["b"] == pytest.approx(100 / 3) and shared["a"]["a"] == pytest.approx(100)
    md = report.markdown()
    assert "| the best variant for each view | 100.0 | 75.0 | 87.5 |" in md
    # a: MRR 100 at L1, 33.3 at L2, 66.7 in all; b: 75, 75, 75.
    assert "| the best variant of each level | 100.0 (a) | 75.0 (b) | 75.0 (b) |" in md
    assert "| a | 100 | 33 |" in md
    js = report.to_json()
    assert js["shared_top1_hits"]["b"]["a"] == pytest.approx(100 / 3, abs=1e-4)
    assert js["best_variant_per_view_mrr"]["L2"] == pytest.approx(75)


def test_the_ensemble_against_the_variant_chosen_on_the_other_half():
    # 400 views of 50 classes at one level. The ensemble ranks the truth 1st on half of them and 3rd on the others; eight
    # variants each rank it 1st or 3rd at random, as likely, so none is better than the ensemble but the best of the
    # eight on these very views is the luckiest of eight draws.
    rng = np.random.default_rng(3)
    n, classes = 400, 50
    truth = rng.integers(0, classes, n)
    groups = {"L1": np.ones(n, bool)}

    def scores_ranking_truth(ranks: np.ndarray) -> np.ndarray:
        scores = np.tile(-np.arange(classes, dtype=float), (n, 1))  # class k ranks k + 1 ...
        for i, (t, r) in enumerate(zip(truth, ranks)):
            scores[i, [t, r - 1]] = scores[i, [r - 1, t]]  # ... but the truth swaps into rank r
        return scores

    ensemble = ("E", scores_ranking_truth(np.repeat([1, 3], n // 2)))
    variants = {f"v{k}": scores_ranking_truth(rng.choice([1, 3], n)) for k in range(8)}
    report = Report.build("ws", variants, truth, groups=groups, num_classes=classes, ensemble=ensemble)
    on_the_same_views = report.compare(report.best_variant_of_level("L1"), "L1").value
    on_the_other_half = report.against_chosen_on_other_half("L1")
    assert on_the_same_views < -1.0  # the lucky best of eight
    assert on_the_other_half > on_the_same_views + 1.0  # the luck taken out
    # One variant, the ensemble itself: chosen on either half, it ties.
    itself = Report.build("ws", {"v0": variants["v0"]}, truth, groups=groups, num_classes=classes, ensemble=("E", variants["v0"]))
    assert itself.against_chosen_on_other_half("L1") == 0
    # A variant that ranks the truth first on every view is chosen on any half and stays better by as much.
    first = scores_ranking_truth(np.ones(n, int))
    top = Report.build("ws", {"v0": variants["v0"], "top": first}, truth, groups=groups, num_classes=classes, ensemble=ensemble)
    assert top.against_chosen_on_other_half("L1") == pytest.approx(100 * (1 + 1 / 3) / 2 - 100)


def test_top1_of_the_location_by_hand():
    # Six classes at two locations (cells 0 and 1, three headings each); four views.
    cells = np.array([0, 0, 0, 1, 1, 1])
    truth = np.array([0, 1, 4, 5])
    a = np.array(
        [
            [9, 1, 1, 1, 1, 1],  # first: class 0, right
            [1, 1, 9, 1, 1, 1],  # first: class 2, the right cell, another heading
            [1, 1, 1, 9, 1, 1],  # first: class 3, the right cell
            [9, 1, 1, 1, 1, 1],  # first: class 0, another cell
        ],
        dtype=float,
    )
    tie = np.ones((4, 6))  # every class ties: the first is class 0 (ties break by class index)
    groups = {"L1": np.array([True, True, False, False]), "L2": np.array([False, False, True, True])}
    report = Report.build("ws", {"a": a, "tie": tie}, truth, groups=groups, num_classes=6, ensemble=("E", a), place_locations=cells)
    assert report.has_location
    loc = {g: report.rows["a"].stats[g]["loc1"].value for g in ("L1", "L2", "all")}
    assert loc == pytest.approx({"L1": 100, "L2": 50, "all": 75})
    assert report.rows["a"].stats["all"]["top1"].value == pytest.approx(25)
    assert report.rows["tie"].stats["all"]["loc1"].value == pytest.approx(50)  # class 0: right for views 0 and 1
    # A random ranking puts its first class at the true location with 3 chances in 6.
    assert report.rows["random"].stats["L2"]["loc1"].value == pytest.approx(50)
    md = report.markdown()
    assert "#### Top-1 of the location" in md and "| 100.0 ±32.9 | 50.0 ±40.5 | 75.0 ±32.7 |" in md.split("#### Top-1 of the location")[1]
    assert report.to_json()["rows"][0]["stats"]["all"]["loc1"]["value"] == pytest.approx(75)
    # The plot gives it a panel of its own beside Table 1's three (5 inches at 100 dpi each).
    from PIL import Image

    assert Image.open(io.BytesIO(report.plot())).width == 4 * 500
    # Without the locations nothing of it is shown; wrong ones are refused.
    plain = Report.build("ws", {"a": a}, truth, groups=groups, num_classes=6, ensemble=("E", a))
    assert not plain.has_location and "location" not in plain.markdown()
    assert Image.open(io.BytesIO(plain.plot())).width == 3 * 500
    with pytest.raises(ValueError, match="place_locations"):
        Report.build("ws", {"a": a}, truth, groups=groups, num_classes=6, ensemble=("E", a), place_locations=cells[:5])


def test_thin_and_empty_groups_are_named():
    truth = np.array([0, 1])
    groups = level_groups(np.array([1, 1]))
    report = Report.build("ws", {"a": np.eye(2)}, truth, groups=groups, num_classes=2, ensemble=("E", np.eye(2)))
    md = report.markdown()
    assert "| a | 100.0 ±" in md and "| – | – |" in md  # L2 and L3 are empty
    assert "Too thin to read (n < 30): L1 (n=2), L2 (n=0), L3 (n=0), all (n=2)" in md


def test_build_refuses_what_it_cannot_score():
    truth = np.array([0, 1])
    kwargs = {"groups": {}, "num_classes": 2, "ensemble": ("E", np.eye(2))}
    with pytest.raises(ValueError, match="best single 'b' is not a variant"):
        Report.build("ws", {"a": np.eye(2)}, truth, best_single="b", **kwargs)
    with pytest.raises(ValueError, match="shape"):
        Report.build("ws", {"a": np.eye(3)}, truth, **kwargs)
    with pytest.raises(ValueError, match="flags for rows that do not exist"):
        Report.build("ws", {"a": np.eye(2)}, truth, flags={"typo": "x"}, **kwargs)


def test_bench_summary_over_seeds():
    from ssga_bench.bench import SeedRun, bench_summary

    runs = {}
    for seed in (0, 1):
        rng, truth, groups = _data(seed)
        good, noise = np.eye(10)[truth] + rng.random((120, 10)), rng.random((120, 10))
        variants, best = {"good": good, "noise": noise}, ["good", "noise"][seed]
        nn = f"nearest neighbour ({best})"
        report = Report.build(
            "ws", variants, truth, groups=groups, num_classes=10, ensemble=(f"E of {best}", good + noise), best_single=best,
            references={nn: good}, series={nn: "nearest neighbour (best single)", f"E of {best}": "E chosen on validation"},
            place_locations=np.arange(10) // 5,
        )  # fmt: skip
        runs[seed] = SeedRun(report, {"train": 1.0 + seed, "describe": 4.0}, 10.0, {"variants": 6.0}, {"describe": 80})
    md = bench_summary(runs)
    # A reference whose label names this seed's choice is one row across seeds, under its series.
    assert "| nearest neighbour (best single) |" in md and "nearest neighbour (good)" not in md
    mean = mean_interval(np.array([runs[s].report.table["good"]["L1"]["top1"] for s in (0, 1)]))
    assert f"| good | {mean.text()} |" in md and "t-interval across seeds" in md
    assert "| best single (validation) |" in md  # one row, whichever variant each seed chose
    assert "E chosen on validation" in md and "E of good" not in md  # so is an ensemble whose members were chosen
    assert "| 0 | 40 | 40 | 40 | 60 | 60 | 120 |" in md
    location = md.split("## Top-1 of the location")[1].split("##")[0]
    loc = mean_interval(np.array([runs[s].report.table["noise"]["L1"]["loc1"] for s in (0, 1)]))
    assert f"| noise | {loc.text()} |" in location
    assert "seed 1 L3" in md and "| noise | +" in md
    r = runs[1].report
    ceiling = " / ".join(f"{r.best_variant_per_view(g):.1f}" for g in ("L1", "L2", "L3"))
    of_level = " / ".join(f"{max(r.table[v][g]['mrr'] for v in r.variants):.1f}" for g in ("L1", "L2", "L3"))
    assert f"| {of_level} | {ceiling} |" in md
    assert "| variants | 6.0 | 6.0 | 60.0 |" in md and "| train | 1.0 | 2.0 |" in md
    assert "takes 26.7% of the work: over the target" in md  # (1/5 + 2/6) / 2
    # 120 test views in 10 s, against 80 views in 4 s of describing on one worker.
    assert "| end to end [test views/s] | 12.00 | 12.00 |" in md and "| describe, one worker [views/s] | 20.0 | 20.0 |" in md
    assert "| end to end / slowest stage on every worker [%] | 60 | 60 |" in md  # one worker


def test_a_numbered_variant_pairs_with_its_numbered_twin_or_else_the_plain_order():
    from ssga_bench.bench import part_twins

    labels = ["P-SL (SPD1)", "P-SL (SPD2)", "P-SL (PSD)", "P-SE (PSD)", "P (SD)", "P (SD2)", "P (DS)", "P-SL (PD)"]
    assert part_twins(labels) == [
        ("P-SL (SPD1)", "P (SD)"), ("P-SL (SPD2)", "P (SD2)"), ("P-SL (PSD)", "P (SD)"), ("P-SE (PSD)", "P (SD)"),
    ]  # fmt: skip


def test_the_methods_claims_are_counted_cell_by_cell():
    from ssga_bench.bench import SeedRun, bench_summary, part_twins

    # Six views of class 0, two per level. The part-based order ranks the truth first at L1 and L2 and second at L3;
    # its twin without P the other way round. The ensemble is the part-based order; the nearest neighbour the twin.
    by_rank = {1: [3.0, 2.0, 1.0], 2: [2.0, 3.0, 1.0]}
    parts = np.array([by_rank[r] for r in (1, 1, 1, 1, 2, 2)])
    whole = np.array([by_rank[r] for r in (2, 2, 2, 2, 1, 1)])
    truth = np.zeros(6, np.int64)
    groups = level_groups(np.repeat([1, 2, 3], 2))
    report = Report.build(
        "ws", {"SIFT-SL (PDS)": parts, "SIFT (DS)": whole, "SIFT (D)": whole}, truth, groups=groups, num_classes=3,
        ensemble=("Ensemble (RRF)", parts),
        references={"nearest neighbour (SIFT (DS))": whole, "Ensemble (STK) of all, learned on validation": whole},
    )  # fmt: skip
    assert report.nearest_neighbour == "nearest neighbour (SIFT (DS))"
    assert report.fused == ["Ensemble (RRF)", "Ensemble (STK) of all, learned on validation"]
    assert part_twins(report.variants) == [("SIFT-SL (PDS)", "SIFT (DS)")]
    md = bench_summary({0: SeedRun(report, {}, 1.0)})
    assert "| seed | level | ensemble − nearest neighbour | ensemble − its best variant there | SIFT-SL (PDS) − SIFT (DS) |" in md
    assert "| 0 | L1 | +50.0 better | +0.0 tie (SIFT-SL (PDS)) | +50.0 better |" in md
    assert "| 0 | L3 | -50.0 worse | -50.0 worse (SIFT (DS)) | -50.0 worse |" in md
    assert "- the ensemble 2 points or more above the nearest neighbour: 2 of 3 (seed, level) cells" in md
    assert "- the ensemble at or above every single variant: 2 of 3 (2 not below one beyond its interval; 2 at or above the one chosen best on the other half of the cell's views, 500 random halvings)" in md
    assert "- the ensemble at or above every single variant and above the nearest neighbour at L1 and L2: 2 of 2" in md
    assert "- each part-based variant above its twin without P at L2 and L3: SIFT-SL (PDS) − SIFT (DS) 1 of 2" in md
    # The bar per level is the higher of the best variant (100 / 100 / 100) and the nearest neighbour + 2 (52 / 52 / 102):
    # the ensemble (100 / 100 / 50) is 0 / 0 / -52 off it, the stacked row (the whole image, 50 / 50 / 100) -50 / -50 / -2.
    assert "| **Ensemble (RRF)** (the ensemble row) | 3 | 2 | -17.33 |" in md
    assert "| Ensemble (STK) of all, learned on validation | 3 | 1 | -34.00 |" in md
    # A nearest neighbour that ties the ensemble at L1 and L2: still at or above every single variant there, not above it.
    tied = Report.build(
        "ws", {"SIFT-SL (PDS)": parts, "SIFT (DS)": whole}, truth, groups=groups, num_classes=3,
        ensemble=("Ensemble (RRF)", parts), references={"nearest neighbour (SIFT-SL (PDS))": parts},
    )  # fmt: skip
    md = bench_summary({0: SeedRun(tied, {}, 1.0)})
    assert "- the ensemble at or above every single variant: 2 of 3 (2 not below one beyond its interval; 2 at or above the one chosen best on the other half of the cell's views, 500 random halvings)" in md
    assert "- the ensemble at or above every single variant and above the nearest neighbour at L1 and L2: 0 of 2" in md
    # Over both seeds, a row per level gives each difference's mean, its interval across the seeds.
    md = bench_summary({0: SeedRun(report, {}, 1.0), 1: SeedRun(tied, {}, 1.0)})
    assert "| mean | L1 | +25.0 ±317.6 tie | +0.0 tie | +50.0 better |" in md
    assert "| mean | L3 | -25.0 ±317.6 tie | -50.0 worse | -50.0 worse |" in md
    assert "| mean |" not in bench_summary({0: SeedRun(report, {}, 1.0)})
