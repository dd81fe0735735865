"""``ssga compare``: two rows of a run, paired view by view, per seed and over seeds."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from ssga_bench.compare import compare, paired_differences
from ssga_core import InputError
from ssga_core.cli import app_with_plugin_commands


def write_run(folder, ranks_a, ranks_b, levels):
    folder.mkdir(parents=True)
    with open(folder / "predictions.jsonl", "w") as f:
        for i, (ra, rb, level) in enumerate(zip(ranks_a, ranks_b, levels, strict=True)):
            f.write(json.dumps({"id": f"t{i}", "level": level, "truth": 0, "rows": {"A": {"rank": ra}, "B": {"rank": rb}}}) + "\n")


def test_a_paired_difference_is_the_mean_of_per_view_differences(tmp_path):
    # B ranks every L1 view first where A ranked it second: +50 MRR points, no spread, "better".
    write_run(tmp_path / "run", [2, 2, 2, 1, 3], [1, 1, 1, 1, 3], [1, 1, 1, 2, 2])
    records = [json.loads(line) for line in (tmp_path / "run" / "predictions.jsonl").read_text().splitlines()]
    diffs = paired_differences(records, "A", "B", "mrr", "run")
    assert diffs["L1"].value == pytest.approx(50.0) and diffs["L1"].low == pytest.approx(50.0)
    assert diffs["L2"].value == 0.0 and diffs["L3"].n == 0
    assert diffs["all"].value == pytest.approx(30.0) and diffs["all"].n == 5
    top1 = paired_differences(records, "A", "B", "top1", "run")
    assert top1["L1"].value == pytest.approx(100.0)
    text = compare(tmp_path / "run", "A", "B")
    assert "| run | +50.0 better (n 3) |" in text and "mean of" not in text


def test_a_bench_folder_gives_each_seed_and_the_mean_over_seeds(tmp_path):
    write_run(tmp_path / "bench" / "seed-0", [2, 1, 4, 4], [1, 1, 2, 4], [1, 1, 1, 1])
    write_run(tmp_path / "bench" / "seed-10", [1, 1, 1, 1], [1, 1, 1, 2], [1, 1, 1, 1])
    text = compare(tmp_path / "bench", "A", "B", metrics=("mrr",))
    lines = [line for line in text.splitlines() if line.startswith("| seed") or line.startswith("| mean")]
    assert [line.split(" |")[0] for line in lines] == ["| seed 0", "| seed 10", "| mean of 2 seeds"]
    seed0 = (50 + 0 + 25 + 0) / 4
    seed10 = -50 / 4
    assert f"| mean of 2 seeds | {(seed0 + seed10) / 2:+.1f} ±" in text


def test_unknown_rows_and_folders_are_one_line_errors(tmp_path):
    write_run(tmp_path / "run", [1], [1], [1])
    with pytest.raises(InputError, match="no row 'C'; the rows are: 'A', 'B'"):
        compare(tmp_path / "run", "A", "C")
    runner = CliRunner()
    result = runner.invoke(app_with_plugin_commands(), ["compare", str(tmp_path / "nothing"), "A", "B"])
    assert result.exit_code == 1 and "expected the output folder of `ssga run` or `ssga bench`" in result.output
    result = runner.invoke(app_with_plugin_commands(), ["compare", str(tmp_path / "run"), "A", "B", "--out", str(tmp_path / "c.md")])
    assert result.exit_code == 0 and (tmp_path / "c.md").read_text() == result.output


def test_row_b_may_come_from_another_run_of_the_same_views(tmp_path):
    # Two configs of one bench: the same row of each, paired view by view.
    write_run(tmp_path / "gcn" / "seed-2", [2, 2, 1], [9, 9, 9], [1, 1, 2])
    write_run(tmp_path / "match" / "seed-2", [9, 9, 9], [1, 2, 1], [1, 1, 2])
    text = compare(tmp_path / "gcn", "A", "B", metrics=("mrr",), b_output=tmp_path / "match")
    assert text.startswith(f"# B of {tmp_path / 'match'} − A of {tmp_path / 'gcn'}")
    assert "| seed 2 | +25.0 ±" in text  # L1: (1 - 1/2) and (1/2 - 1/2), in percent, averaged
    result = CliRunner().invoke(
        app_with_plugin_commands(), ["compare", str(tmp_path / "gcn"), "A", "B", "--b-from", str(tmp_path / "match")]
    )
    assert result.exit_code == 0 and result.output == compare(tmp_path / "gcn", "A", "B", b_output=tmp_path / "match")
    # Other test views, or other seeds: refused in one line.
    write_run(tmp_path / "other" / "seed-2", [1, 1], [1, 1], [1, 1])
    with pytest.raises(InputError, match="other test views than"):
        compare(tmp_path / "gcn", "A", "B", b_output=tmp_path / "other")
    write_run(tmp_path / "seeds" / "seed-3", [1, 1, 1], [1, 1, 1], [1, 1, 2])
    with pytest.raises(InputError, match="holds seed 3, .* holds seed 2; compare outputs of the same seeds"):
        compare(tmp_path / "gcn", "A", "B", b_output=tmp_path / "seeds")


def test_the_ensemble_row_is_named_alike_whatever_members_each_seed_chose(tmp_path):
    for seed, label in ((0, "Ensemble (RRF) of 1 chosen on validation: A"), (1, "Ensemble (RRF) of 2 chosen on validation: A, B")):
        folder = tmp_path / "bench" / f"seed-{seed}"
        folder.mkdir(parents=True)
        records = [{"id": f"t{i}", "level": 1, "truth": 0, "rows": {"A": {"rank": 2}, label: {"rank": r}}} for i, r in enumerate([1, 2])]
        (folder / "predictions.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    text = compare(tmp_path / "bench", "A", "ensemble", metrics=("mrr",))
    assert "| seed 0 | +25.0 ±" in text and "| seed 1 | +25.0 ±" in text  # (1 - 1/2 + 0) / 2, in percent
    # With two ensemble rows the name is ambiguous: refused, naming the rows.
    records = [{"id": "t0", "level": 1, "truth": 0, "rows": {"Ensemble (RRF)": {"rank": 1}, "Ensemble (STK)": {"rank": 1}}}]
    with pytest.raises(InputError, match="no row 'ensemble'; the rows are: 'Ensemble \\(RRF\\)', 'Ensemble \\(STK\\)'"):
        paired_differences(records, "ensemble", "Ensemble (RRF)", "mrr", "run")


def test_the_marked_ensemble_and_the_nearest_neighbour_are_found_among_every_fused_row(tmp_path):
    # A run's predictions hold every row of its report: here two fusions beside the ensemble,
    # and a nearest neighbour named by each seed's best single variant.
    for seed, best in ((0, "A"), (1, "B")):
        folder = tmp_path / "bench" / f"seed-{seed}"
        folder.mkdir(parents=True)
        records = [
            {
                "id": f"t{i}",
                "level": 1,
                "truth": 0,
                "rows": {
                    "Ensemble (RRF) of 1 chosen on validation: A": {"rank": rank, "ensemble": True},
                    "Ensemble (RRF) of all": {"rank": 1},
                    "Ensemble (STK) of all, learned on validation": {"rank": 3},
                    f"nearest neighbour ({best})": {"rank": 4},
                },
            }
            for i, rank in enumerate([1, 2])
        ]
        (folder / "predictions.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    text = compare(tmp_path / "bench", "nearest neighbour", "ensemble", metrics=("mrr",))
    assert "| seed 0 | +50.0 ±" in text and "| seed 1 | +50.0 ±" in text  # (1 + 1/2) / 2 - 1/4, in percent
    text = compare(tmp_path / "bench", "Ensemble (RRF) of all", "ensemble", metrics=("mrr",))
    assert "| seed 0 | -25.0 ±" in text
