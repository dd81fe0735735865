"""scripts/preset_rule.py: two bench outputs read by the rule the presets' changes are decided by."""

from __future__ import annotations

import csv
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "preset_rule.py"


@pytest.fixture(scope="module")
def preset_rule():
    spec = importlib.util.spec_from_file_location("preset_rule", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up there
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        del sys.modules[spec.name]


def write_run(folder: Path, seed: int, mrr: dict[str, tuple[float, float, float]]) -> None:
    """A seed's results.csv with each row's MRR at L1 / L2 / L3 (and an `all` row the rule must ignore)."""
    kinds = {"Ensemble (STK)": "ensemble", "nearest neighbour (SIFT (SD))": "reference", "random": "random"}
    (folder / f"seed-{seed}").mkdir(parents=True)
    with (folder / f"seed-{seed}" / "results.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["row", "kind", "group", "n", "mrr"])
        for row, values in mrr.items():
            for group, value in zip(("L1", "L2", "L3", "all"), (*values, 0.0)):
                writer.writerow([row, kinds.get(row, "variant"), group, 100, value])


BEFORE = {
    "SIFT-SL (PSD)": (60.0, 50.0, 40.0),
    "SIFT (SD)": (58.0, 51.0, 39.0),
    "Ensemble (STK)": (63.0, 53.0, 42.0),
    "nearest neighbour (SIFT (SD))": (58.0, 51.0, 39.0),
    "random": (4.5, 4.5, 4.5),
}


def judged(preset_rule, folder: Path, capsys, after: dict[str, tuple[float, float, float]], *options: str) -> str:
    """What the script prints for :data:`BEFORE` against ``after`` (seed 1 each, in ``folder``)."""
    if not (folder / "before").exists():
        write_run(folder / "before", 1, BEFORE)
    changed = folder / f"after-{len(list(folder.glob('after-*')))}"
    write_run(changed, 1, after)
    assert preset_rule.main([str(folder / "before"), str(changed), *options]) == 0
    return capsys.readouterr().out


def test_a_change_that_lifts_the_ensemble_past_its_bar_meets_the_rule(preset_rule, tmp_path, capsys):
    out = judged(preset_rule, tmp_path, capsys, {**BEFORE, "Ensemble (STK)": (64.0, 54.0, 43.0)})
    # Margins before: 63 - max(60, 58 + 2) = +3, 53 - max(51, 53) = 0, 42 - max(40, 41) = +1; each +1 after.
    assert "| mean margin | 1.33 | 2.33 |" in out
    # PSD - SD above zero at L3 only (L1 is not counted), before and after.
    assert "| SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3 | 1 | 1 |" in out
    assert "rule met (mean MRR +1.00, mean margin +1.00" in out


def test_members_that_rise_with_the_ensemble_fail_the_margin_and_a_lost_twin_fails_the_parts(preset_rule, tmp_path, capsys):
    # The ensemble +1 everywhere, but SD rises by 2 (its whole image is the nearest neighbour's): the bar rises with it,
    # and PSD - SD falls below zero at L3.
    sd = (60.0, 53.0, 41.0)
    out = judged(preset_rule, tmp_path, capsys, {**BEFORE, "Ensemble (STK)": (64.0, 54.0, 43.0), "SIFT (SD)": sd, "nearest neighbour (SIFT (SD))": sd})
    assert "rule not met: (b) mean margin; (c) SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3" in out
    assert "| SIFT (SD) | +2.00 |" in out


def test_keeping_the_margin_asks_its_floor_and_every_goals_count(preset_rule, tmp_path, capsys):
    # The members rise with the ensemble: its margin falls from +1.33 to +0.33 (64 - 63, 54 - 54, 43 - 43), while every
    # goal holds in all 3 cells before and after, and PSD - SD is above zero at L2 and L3 now.
    sd = (61.0, 52.0, 41.0)
    after = {**BEFORE, "Ensemble (STK)": (64.0, 54.0, 43.0), "SIFT-SL (PSD)": (62.0, 53.0, 42.0), "SIFT (SD)": sd, "nearest neighbour (SIFT (SD))": sd}
    assert "rule not met: (b) mean margin (" in judged(preset_rule, tmp_path, capsys, after)
    out = judged(preset_rule, tmp_path, capsys, after, "--keep-margin", "0")
    assert "| nearest neighbour + 2 | 3 | 3 |" in out and "| at or above every single variant | 3 | 3 |" in out
    assert "rule met (mean MRR +1.00, mean margin -1.00" in out
    assert "rule not met: (b) mean margin below +1 (" in judged(preset_rule, tmp_path, capsys, after, "--keep-margin", "1")
    # A goal's count that falls fails it too, whatever the margin: the nearest neighbour 1 point higher at L2.
    closer = {**after, "nearest neighbour (SIFT (SD))": (61.0, 53.0, 41.0)}
    assert "rule not met: (b) nearest neighbour + 2 (" in judged(preset_rule, tmp_path, capsys, closer, "--keep-margin", "-5")


def test_runs_without_common_seeds_are_a_one_line_error(preset_rule, tmp_path, capsys):
    write_run(tmp_path / "before", 1, BEFORE)
    write_run(tmp_path / "after", 2, BEFORE)
    assert preset_rule.main([str(tmp_path / "before"), str(tmp_path / "after")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no seed has a results.csv in both" in err and err.count("\n") == 1


def write_views(folder: Path, seed: int, ranks: dict[str, list[int]], levels: list[int]) -> None:
    """A seed's predictions.jsonl of views at ``levels`` with each row's rank of the true class, and its results.csv."""
    import json

    write_run(folder, seed, {row: tuple(float(np.mean([100 / r for r, v in zip(rs, levels) if v == g])) for g in (1, 2, 3)) for row, rs in ranks.items()})
    with (folder / f"seed-{seed}" / "predictions.jsonl").open("w") as f:
        for i, level in enumerate(levels):
            f.write(json.dumps({"id": f"test-{i}", "level": level, "rows": {row: {"rank": rs[i]} for row, rs in ranks.items()}}) + "\n")


def test_beyond_the_interval_a_cell_is_lost_only_where_the_shortfall_is_beyond_its_paired_interval(preset_rule, tmp_path, capsys):
    # 30 views a level; the ensemble ranks every view first. Before, PSD ranks the first 3 views of L2 and L3 first and
    # the rest second, SD all second: PSD − SD +5 points at each. After, SD ranks 6 other L3 views first (PSD − SD -5,
    # a tie by its paired interval, about ±10) in one run, and 25 (-37, beyond it) in another.
    levels = [1] * 30 + [2] * 30 + [3] * 30
    psd = [2] * 30 + ([1] * 3 + [2] * 27) * 2
    before = {"Ensemble (STK)": [1] * 90, "nearest neighbour (SIFT (SD))": [2] * 90, "SIFT-SL (PSD)": psd, "SIFT (SD)": [2] * 90, "random": [50] * 90}
    write_views(tmp_path / "before", 1, before, levels)
    for name, first in (("tie", 6), ("beyond", 25)):
        sd = [2] * 63 + [1] * first + [2] * (27 - first)
        write_views(tmp_path / name, 1, {**before, "SIFT (SD)": sd, "nearest neighbour (SIFT (SD))": sd}, levels)
    args = [str(tmp_path / "before"), "--keep-margin", "-100"]
    assert preset_rule.main([args[0], str(tmp_path / "tie"), *args[1:]]) == 0
    assert "(c) SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3 (" in capsys.readouterr().out  # L3 below zero: counted lost
    assert preset_rule.main([args[0], str(tmp_path / "tie"), *args[1:], "--beyond-interval"]) == 0
    out = capsys.readouterr().out
    assert "| SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3, not short beyond its interval | 2 | 2 |" in out
    assert "(c)" not in out
    assert preset_rule.main([args[0], str(tmp_path / "beyond"), *args[1:], "--beyond-interval"]) == 0
    out = capsys.readouterr().out
    assert "| SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3, not short beyond its interval | 2 | 1 |" in out
    assert "(c) SIFT-SL (PSD) − SIFT (SD) > 0 at L2 and L3, not short beyond its interval" in out


def test_beyond_the_interval_needs_the_predictions(preset_rule, tmp_path, capsys):
    write_run(tmp_path / "before", 1, BEFORE)
    write_run(tmp_path / "after", 1, BEFORE)
    assert preset_rule.main([str(tmp_path / "before"), str(tmp_path / "after"), "--beyond-interval"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "predictions.jsonl" in err and err.count("\n") == 1
