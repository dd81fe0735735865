"""Train the tiny classifier on labelled views of procedural homes.

    python -m ssga_descriptor_tinyseg.train --out runs/tinyseg --export .

The learned-stage kit does the rest: views rendered once per home, a staged loop that
resumes where it stopped, provenance, the export (``tinyseg.pt``) and this command line.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ssga_bench import ArrayRecord, TrainingRun, cached_homes, training_main
from ssga_descriptor_tinyseg.plugin import network


@dataclass
class Labelled(ArrayRecord):
    rgb: np.ndarray  # (N, H, W, 3) uint8
    labels: np.ndarray  # (N, H, W) int8: procedural category id - 1, -1 where none


@dataclass(frozen=True)
class TrainConfig:
    train_seeds: tuple[int, ...] = (9000, 9001)  # homes of its own: the benchmark evaluates 0, 1, 2
    views_per_home: int = 60
    stages: tuple[tuple[int, int, int], ...] = ((256, 300, 8),)  # (image size, steps, batch)
    lr: tuple[float, ...] = (3e-3,)
    checkpoint_every: int = 50
    seed: int = 0


def render(seed: int, count: int) -> Labelled:
    from ssga_workspace_procedural.training_homes import bench_and_demo_sized, standing_views

    views = list(standing_views(seed, count, bench_and_demo_sized(seed)))
    return Labelled(np.stack([v.rgb for v in views]), np.stack([(v.semantic - 1).clip(-1).astype(np.int8) for v in views]))


class Run(TrainingRun):
    module = "ssga_descriptor_tinyseg.train"
    export_name = "tinyseg"
    what = "tiny per-pixel classifier of the procedural categories, trained on procedural homes"

    def training_data(self) -> Labelled:
        from ssga_workspace_procedural.training_homes import RENDERER_VERSION

        c = self.config
        settings = {"per_home": c.views_per_home, "renderer": RENDERER_VERSION}
        return self.cached("render", lambda folder: cached_homes(folder, "labelled", c.train_seeds, settings, lambda seed: render(seed, c.views_per_home), Labelled))

    def initial(self, data: Labelled) -> torch.nn.Module:
        torch.manual_seed(self.config.seed)
        return network()

    def network(self) -> torch.nn.Module:
        return network()

    def train_step(self, net, optimizer, stage, data, rng) -> tuple[float]:
        idx = rng.choice(len(data), self.config.stages[stage][2], replace=False)
        x = torch.from_numpy(data.rgb[idx]).permute(0, 3, 1, 2).float().div(255)
        y = torch.from_numpy(data.labels[idx]).long()
        loss = F.cross_entropy(F.interpolate(net(x), size=y.shape[1:], mode="bilinear", align_corners=False), y, ignore_index=-1)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        return (loss.item(),)


def main(argv: list[str] | None = None) -> int:
    return training_main(Run.module, __doc__, Run.run_training, TrainConfig(), argv, exports="tinyseg.pt and tinyseg.json")


if __name__ == "__main__":
    sys.exit(main())
