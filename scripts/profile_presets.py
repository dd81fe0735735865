"""Numbers to plan with: each packaged preset end to end with 1 and 2 (or more) workers.

For every preset and worker count, one seed runs from nothing (its own workspace folder,
so rendering is measured too) and the table gives

* wall time and end-to-end test views per second;
* each per-view stage's own rate on one worker (views it handled / its seconds of work);
* the end-to-end rate over the slowest stage's rate with that many workers (how much of
  the machine the pipeline keeps busy);
* the speed-up of N workers over one, for the whole run and for each wall phase.

    .venv/bin/python scripts/profile_presets.py --presets demo,bench,paper --workers 1,2 \\
        --test-per-class 6 --out runs/profile

Ratios are measured in one run on one machine: compare them, not the seconds of another day.
``make profile`` runs the default set.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import time
from pathlib import Path

from ssga_bench.bench import SeedRun, run_bench, stage_rates
from ssga_bench.config import load_experiment
from ssga_bench.execution import ExecutionConfig
from ssga_core.plugins import default_registry


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", default="demo,bench,paper", help="Packaged experiments (or config files), comma-separated.")
    parser.add_argument("--workers", default="1,2", help="Worker counts to compare, comma-separated.")
    parser.add_argument("--executor", default="processes", choices=["processes", "ray"])
    parser.add_argument("--test-per-class", type=int, default=None, help="Override protocol.test_per_class (default: the preset's).")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/profile"))
    args = parser.parse_args()

    registry = default_registry()
    rows = []
    home = Path.cwd()
    for preset in args.presets.split(","):
        base_runs: dict[int, SeedRun] = {}
        for workers in (int(w) for w in args.workers.split(",")):
            base = load_experiment(preset, registry)
            execution = ExecutionConfig(executor=args.executor, workers=workers, batch=base.config.execution.batch)
            base = dataclasses.replace(base, config=base.config.model_copy(update={"execution": execution}))
            folder = (args.out / f"{Path(preset).stem}-{args.executor}-{workers}").resolve()
            folder.mkdir(parents=True, exist_ok=True)
            os.chdir(folder)  # its own runs/workspaces: rendering is part of what is measured
            try:
                start = time.perf_counter()
                _, runs = run_bench(base=base, seeds=[args.seed], registry=registry, output=folder / "bench", test_per_class=args.test_per_class)
                wall = time.perf_counter() - start
            finally:
                os.chdir(home)
            run = runs[args.seed]
            base_runs.setdefault(workers, run)
            tests = sum(run.report.counts.get(level, 0) for level in ("L1", "L2", "L3"))
            rates = stage_rates(run)
            slowest = min(rates.items(), key=lambda kv: kv[1]) if rates else ("-", float("nan"))
            one = base_runs[min(base_runs)]
            rows.append(
                {
                    "preset": preset,
                    "executor": args.executor,
                    "workers": workers,
                    "test views": tests,
                    "wall s": round(wall, 1),
                    "end-to-end views/s": round(tests / wall, 2),
                    "stage rates views/s (one worker)": {k: round(v, 1) for k, v in rates.items()},
                    "slowest stage": slowest[0],
                    "end-to-end / slowest stage x workers %": round(100 * (tests / wall) / (slowest[1] * workers), 1),
                    "speed-up over 1 worker": round(one.wall / run.wall, 2),
                    "phase speed-ups": {p: round(one.phases[p] / s, 2) for p, s in run.phases.items() if s > 0 and one.phases.get(p)},
                    "phases s": {p: round(s, 1) for p, s in run.phases.items()},
                    "peak RSS MiB (this process / largest worker)": [
                        round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024),
                        round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024),
                    ],
                }
            )
            print(json.dumps(rows[-1]), flush=True)
    (args.out / "profile.json").write_text(json.dumps(rows, indent=1))
    lines = [
        "| preset | workers | test views | wall [s] | views/s | slowest stage (one worker) | end-to-end / slowest x workers | speed-up over 1 |",
        "|---|---:|---:|---:|---:|---|---:|---:|",
    ]
    for r in rows:
        slow = r["slowest stage"]
        rate = r["stage rates views/s (one worker)"].get(slow, float("nan"))
        lines.append(
            f"| {r['preset']} | {r['workers']} | {r['test views']} | {r['wall s']} | {r['end-to-end views/s']} | {slow} {rate} | "
            f"{r['end-to-end / slowest stage x workers %']}% | {r['speed-up over 1 worker']}x |"
        )
    (args.out / "profile.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
