"""Speed of the detic parser on the CPU (``make bench``): seconds per 256 x 256 view.

Random weights (Detic's checkpoint is not shipped): **timing only**; the cost is the
same as the released network's, except for the mask head, which runs once per kept
detection (about 0.5 G multiply-adds each), so the cases cap the detections and record
the regions they gave (random weights detect arbitrary things). Cases:

* the default config: the view resized to 640 x 640 (Detic's max-size 640), at most 10
  detections (an assumed count for the demo's 0.5 threshold on a real image) and at most 100;
* the ``demo`` preset: resized to 800 x 800 as detectron2's ``DefaultPredictor`` does;
* ``test_size = 256``: the view at its own size (not Detic's setting; a cheaper option).

Each records ``s_per_image`` (the median wall clock), ``cpu_s_per_image`` (the median CPU
time of all threads: steadier on a shared machine), the regions and the torch threads
(the default case with one and two).
Run alone with ``pytest benchmarks/bench_detic.py -o python_files='bench_*.py' --benchmark-enable``.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("ssga_parser_detic")

import torch
from ssga_core.testing import make_view
from ssga_parser_detic.plugin import DeticConfig, DeticParser

CASES = {
    "640-max10": {"max_detections": 10},
    "640-max100": {"max_detections": 100},
    "demo-800-max10": {"resize": "shortest-edge", "test_size": 800, "max_detections": 10},
    "256-max10": {"test_size": 256, "max_detections": 10},
}


@pytest.fixture(scope="module")
def lvis_sized_vocabulary(tmp_path_factory) -> dict[str, str]:
    """1203 random class embeddings and names: the LVIS vocabulary's size."""
    folder = tmp_path_factory.mktemp("vocabulary")
    np.save(folder / "vocab.npy", np.random.default_rng(0).normal(size=(1203, 512)).astype(np.float16))
    (folder / "names.txt").write_text("\n".join(f"class {k}" for k in range(1203)))
    return {"vocabulary": str(folder / "vocab.npy"), "class_names": str(folder / "names.txt")}


@pytest.fixture
def threads(request):
    before = torch.get_num_threads()
    torch.set_num_threads(request.param)
    yield request.param
    torch.set_num_threads(before)


@pytest.mark.parametrize(
    ("case", "threads"),
    [("640-max10", 1), ("640-max10", 2), ("640-max100", 1), ("demo-800-max10", 1), ("256-max10", 1)],
    indirect=["threads"],
)
def test_detic_parse_one_256px_view(benchmark, case, threads, lvis_sized_vocabulary):
    """Wall clock (pytest-benchmark) and CPU time (``process_time``, all threads) per parse; see the plugin's README."""
    parser = DeticParser(DeticConfig(weights="random", device="cpu", **lvis_sized_vocabulary, **CASES[case]))
    view = make_view(seed=0)
    cpu: list[float] = []

    def parse():
        start = time.process_time()
        regions = parser.parse(view)
        cpu.append(time.process_time() - start)
        return regions

    regions = benchmark.pedantic(parse, rounds=3, warmup_rounds=1)
    assert len(regions) > 0
    benchmark.extra_info.update(
        regions=len(regions), threads=threads, caveat="random weights: timing only", cpu_s_per_image=round(float(np.median(cpu[1:])), 3)
    )
    stats = getattr(benchmark, "stats", None)
    if stats is not None and getattr(stats, "stats", None) is not None:
        benchmark.extra_info["s_per_image"] = round(stats.stats.median, 3)
