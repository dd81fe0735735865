"""Each batched learned stage's own rate (views per second) on the CPU and on CUDA, by batch size.

The numbers for choosing ``[execution] batch`` and ``workers`` on a GPU box
(docs/scaling.md, "A GPU"). Every case feeds the stage painted 256 x 256 views
(``ssga_core.testing.make_view``: a network's cost does not depend on the content) in
calls of ``batch`` views, after one warm-up call, for at least ``--seconds`` or every view:

* ``cpu x1``: one torch thread, as each worker of the ``processes`` and ``ray`` executors
  runs (batch 1 only: on the CPU the stages cut a batch into calls of one view anyway,
  ``ssga_bench.learned.CPU_VIEWS_PER_CALL``);
* ``cpu xN``: every core in one process;
* ``cuda``: where torch sees a CUDA device, the batch in one network call.

Stages: pnv (the packaged light network, and the official VGG16 layout on random weights,
**for timing only**), cascade-seg (the packaged light network, and the official
resnet50dilated layout on random weights, for timing only, at one scale of 450 px).

    .venv/bin/python scripts/stage_rates.py --batches 1,16,64 --out runs/stage-rates.json

Ratios are measured in one run on one machine: compare them, not the seconds of another day.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable
from pathlib import Path

import torch
from ssga_core.testing import make_view


def stages(device: str) -> dict[str, Callable[[], Callable[[list], object]]]:
    """Each case's maker: a function of a list of views that runs the stage on them."""
    from ssga_descriptor_pnv.plugin import Pnv, PnvConfig
    from ssga_parser_cascade_seg.plugin import CascadeSeg, CascadeSegConfig

    return {
        "pnv light": lambda: Pnv(PnvConfig(device=device)).extract_many,
        "pnv vgg16 (random weights, timing only)": lambda: Pnv(PnvConfig(device=device, weights="random", network="vgg16")).extract_many,
        "cascade-seg light": lambda: CascadeSeg(CascadeSegConfig(device=device)).parse_many,
        "cascade-seg resnet50dilated @450 (random weights, timing only)": lambda: CascadeSeg(
            CascadeSegConfig(device=device, network="resnet50dilated", classes="ade20k", weights="random", image_sizes=(450,))
        ).parse_many,
    }


def rate(run: Callable[[list], object], views: list, batch: int, seconds: float, sync: Callable[[], None]) -> float:
    """Views per second, calls of ``batch`` views, after one warm-up call."""
    run(views[:batch])  # warm-up: first-call allocations, cuDNN's choice of kernels for this shape
    sync()
    done, start = 0, time.perf_counter()
    while done < len(views) and (time.perf_counter() - start < seconds or done == 0):
        chunk = views[done : done + batch]
        run(chunk)
        done += len(chunk)
    sync()
    return done / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batches", default="1,16,64", help="Views per call, comma-separated.")
    parser.add_argument("--views", type=int, default=256, help="Most views per case.")
    parser.add_argument("--seconds", type=float, default=3.0, help="Least time per case (or every view).")
    parser.add_argument("--only", default="", help="Cases whose name contains this (default: all).")
    parser.add_argument("--out", type=Path, default=Path("runs/stage-rates.json"))
    args = parser.parse_args()

    views = [make_view(seed=i) for i in range(args.views)]
    cores = os.cpu_count() or 1
    settings = [("cpu x1", "cpu", 1), (f"cpu x{cores}", "cpu", cores)]
    if torch.cuda.is_available():
        settings.append(("cuda", "cuda", cores))
    rows = []
    for setting, device, threads in settings:
        torch.set_num_threads(threads)
        sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
        for name, make in stages(device).items():
            if args.only not in name:
                continue
            run = make()
            # On the CPU a stage cuts every batch into calls of one view (CPU_VIEWS_PER_CALL): one size says it.
            for batch in [int(b) for b in args.batches.split(",")] if device == "cuda" else [1]:
                per_second = rate(run, views, batch, args.seconds, sync)
                rows.append({"stage": name, "setting": setting, "batch": batch, "views_per_s": round(per_second, 2)})
                print(f"{name:<66} {setting:<8} batch {batch:>4}: {per_second:9.2f} views/s", flush=True)
    device_name = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"torch": torch.__version__, "cuda_device": device_name, "cpu_cores": cores, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
