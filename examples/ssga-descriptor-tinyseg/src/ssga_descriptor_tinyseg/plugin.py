"""A learned region descriptor: each pixel's class probabilities from a tiny network, averaged over each region."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from ssga_bench import Learned, LearnedConfig, load_checkpoint, load_strict, seeded
from ssga_core import RegionDescriptor, Regions, View, hookimpl

CLASSES = 13
"""The procedural homes' categories (wall ... rug), what the training command teaches it."""


def network():  # -> torch.nn.Module; torch loads when a descriptor is made, not when the plugin registers
    from torch import nn

    return nn.Sequential(nn.Conv2d(3, 16, 5, 2, 2), nn.ReLU(), nn.Conv2d(16, 32, 3, 2, 1), nn.ReLU(), nn.Conv2d(32, CLASSES, 1))


class TinySegConfig(LearnedConfig):
    weights: str = Field(
        default="tinyseg.pt",
        min_length=1,
        description="Checkpoint written by `python -m ssga_descriptor_tinyseg.train` (relative: the working directory), or 'random' (tests only).",
    )


class TinySeg(Learned, RegionDescriptor):
    name = "tinyseg"
    abbrev = "TS"
    Config = TinySegConfig
    reloaded = ("net",)  # self._load() when the stage is made; a worker process loads its own copy instead of receiving it
    dim = CLASSES

    def _load(self):  # once per process per file, on the device; a missing file: one line naming `weights`
        return self.load_network((), lambda: (seeded(network), {}), self._from_file)[0]

    def _from_file(self, path):
        net = network()
        load_strict(net, load_checkpoint(path, self.name)["state_dict"], self.name, path)
        return net, {}  # no config field comes from the file

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        """``(H, W, CLASSES)``: what the network sees at each pixel."""
        import torch
        import torch.nn.functional as F

        x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float().div(255).to(self.device)
        with torch.inference_mode():
            logits = F.interpolate(self.net(x), size=rgb.shape[:2], mode="bilinear", align_corners=False)
        return logits.softmax(1)[0].permute(1, 2, 0).cpu().numpy()

    def _describe(self, view: View, regions: Regions | None) -> np.ndarray:
        p = self.probabilities(view.rgb).reshape(-1, CLASSES)
        rows = [p.mean(axis=0)]
        if regions is not None:
            label = regions.labels.ravel()
            inside = label >= 0
            sums = np.zeros((len(regions), CLASSES))
            np.add.at(sums, label[inside], p[inside])
            rows.extend(sums / np.maximum(np.bincount(label[inside], minlength=len(regions)), 1)[:, None])
        return np.stack(rows)


@hookimpl
def ssga_register_descriptors() -> list[type[RegionDescriptor]]:
    return [TinySeg]
