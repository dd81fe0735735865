"""Patch-NetVLAD (PNV) local features, pooled into bag-of-words node features (paper §3.1.2).

Each view is resized to ``image_size`` x ``image_size`` (256 by default, the paper's
view size: 256 x 256 views pass unchanged), normalised with ImageNet's mean and std,
and described by Patch-NetVLAD (:mod:`.model`): at 256 x 256, 144 patch descriptors
of ``num_pcs`` = 512 dimensions (L2-normalised), one per 5 x 5-cell patch of the 16 x 16
conv5_3 map, at its centre ``39.5 + 16 j`` px (the positions the ``dense-sift``
descriptor uses). Everything after extraction is :class:`ssga_bench.BoWDescriptor`'s.

Weights: the default is the light network trained on procedural homes that the
benchmark never shows (``weights/pnv-light.pt``; how it was made: the README and
``weights/pnv-light.json``). An official file (``mapillary_WPCA512.pth.tar``...), which
the user places, loads by itself: its keys and shapes say its network (:data:`LAYOUTS`),
and its cluster count and WPCA size are read from it, as Patch-NetVLAD's loader does.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from pydantic import Field, model_validator

from ssga_core import Descriptor, InputError, LocalFeatures, View, hookimpl
from ssga_bench import (
    BoWDescriptor, BoWDescriptorConfig, Layout, Learned, LearnedConfig, load_checkpoint, load_strict, meta_shapes,
    network_calls, network_field, read_layout, seeded, tensor_state, weights_field,
)
from ssga_descriptor_pnv.layout import LIGHT_WIDTHS, STRIDE, VGG16_WIDTHS, patch_grid

if TYPE_CHECKING:  # torch and the network load when a descriptor is made, not when the plugin registers
    from ssga_descriptor_pnv.model import PatchNetVLAD

WEIGHTS_DIR = Path(__file__).parent / "weights"
"""Where relative ``weights`` are looked up first (then the working directory)."""

LIGHT_WEIGHTS = "pnv-light.pt"
"""The packaged light network's file in :data:`WEIGHTS_DIR`."""

NETWORKS = {"light": LIGHT_WIDTHS, "vgg16": VGG16_WIDTHS}

LAYOUTS = (
    Layout("light", "trained here on procedural homes: weights/pnv-light.pt, the default"),
    Layout("vgg16", "the official Patch-NetVLAD releases: mapillary_WPCA{128,512,4096}.pth.tar, pittsburgh_WPCA{128,512,4096}.pth.tar"),
)
"""The networks a ``weights`` file can hold; which one, the file's keys and shapes say."""

RANDOM_NETWORK, RANDOM_PCS = "light", 512
"""The network random weights build (tests only), where the config leaves it out."""

RANDOM_CLUSTERS = 16
"""K of a network on random weights (PNV's ``train.ini``); with a file, K is the file's."""




class PnvConfig(BoWDescriptorConfig, LearnedConfig):
    weights: str = weights_field(LIGHT_WEIGHTS, "an official file such as 'mapillary_WPCA512.pth.tar'")
    network: Literal["light", "vgg16"] | None = network_field("Encoder: 'light' (VGG16 4x narrower, the packaged weights) or 'vgg16' (the official models).")
    num_pcs: int | None = Field(
        default=None,
        ge=1,
        le=65536,
        description="WPCA output dimension, the local features' length. Left out: the weights file's (512 for random weights); set, the file must hold it.",
    )
    patch_size: int = Field(default=5, ge=1, le=16, description="Patch side in conv5_3 cells (16 px each); PNV's speed/storage setting: 5.")
    stride: int = Field(default=1, ge=1, le=16, description="Cells between neighbouring patches.")
    image_size: int | None = Field(
        default=256,
        ge=16,
        le=4096,
        description="Views are resized to image_size x image_size before description (PNV resizes every image to one size); "
        "None: described at their own size. Positions are always in the view's pixels.",
    )

    @model_validator(mode="after")
    def _a_patch_fits(self) -> PnvConfig:
        if self.image_size is not None and self.image_size // STRIDE < self.patch_size:
            raise ValueError(
                f"image_size {self.image_size} gives a {self.image_size // STRIDE}-cell conv5_3 map, smaller than patch_size {self.patch_size}"
            )
        return self


class Pnv(Learned, BoWDescriptor):
    """Patch-NetVLAD patch descriptors at their patch centres; node features are BoW histograms.

    The network loads when the descriptor is made (a bad ``weights`` file is reported
    before any work), once per process for all instances that use the same file.
    """

    name = "pnv"
    abbrev = "P"  # the paper's tables: "P (DS)", "P-SL (PDS)"
    Config = PnvConfig
    reloaded = ("net",)
    layouts = LAYOUTS
    packaged_weights = WEIGHTS_DIR
    trained_on = "procedural"  # the workspace source whose homes the packaged weights saw
    presets = {
        "light": {},
        "mapillary": {"weights": "mapillary_WPCA512.pth.tar"},
        "pittsburgh": {"weights": "pittsburgh_WPCA512.pth.tar"},
    }

    def _load(self) -> PatchNetVLAD:
        """The network, once per process per file; ``self.config`` gets the file's ``network`` and ``num_pcs``."""
        cfg: PnvConfig = self.config  # type: ignore[assignment]
        net, _ = self.load_network((cfg.network, cfg.num_pcs, cfg.patch_size, cfg.stride), self._random, self._from_file)
        return net  # type: ignore[return-value]

    def _random(self) -> tuple[PatchNetVLAD, dict[str, Any]]:
        from ssga_descriptor_pnv.model import PatchNetVLAD

        cfg: PnvConfig = self.config  # type: ignore[assignment]
        fields = {"network": cfg.network or RANDOM_NETWORK, "num_pcs": cfg.num_pcs or RANDOM_PCS}
        return seeded(lambda: PatchNetVLAD(NETWORKS[fields["network"]], RANDOM_CLUSTERS, fields["num_pcs"], cfg.patch_size, cfg.stride)), fields

    def _from_file(self, path: Path) -> tuple[PatchNetVLAD, dict[str, Any]]:
        from ssga_descriptor_pnv.model import PatchNetVLAD

        cfg: PnvConfig = self.config  # type: ignore[assignment]
        expected = "a Patch-NetVLAD checkpoint ({'state_dict': encoder.*, pool.*, WPCA.*}) of the 'light' or 'vgg16' network"
        checkpoint = load_checkpoint(path, self.who, expected)
        state = tensor_state(checkpoint.get("state_dict", checkpoint) if isinstance(checkpoint, dict) else checkpoint, self.who, path, expected)
        _, fields = read_layout(cfg, state, LAYOUTS, self._network_of, self.who, path)
        net = PatchNetVLAD(NETWORKS[fields["network"]], _clusters(state), fields["num_pcs"], cfg.patch_size, cfg.stride)
        load_strict(net, state, self.who, path, expected)
        return net, fields

    def _network_of(self, layout: Layout, state: Any) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
        """The fields and keys and shapes of ``layout``'s network with the file's cluster count and WPCA size."""
        from ssga_descriptor_pnv.model import PatchNetVLAD

        cfg: PnvConfig = self.config  # type: ignore[assignment]
        bias = state.get("WPCA.0.bias")
        num_pcs = int(bias.shape[0]) if bias is not None and bias.ndim == 1 else cfg.num_pcs or RANDOM_PCS
        fields = {"network": layout.name, "num_pcs": num_pcs}
        return fields, meta_shapes(lambda: PatchNetVLAD(NETWORKS[layout.name], _clusters(state), num_pcs, cfg.patch_size, cfg.stride))

    def _extract(self, view: View) -> LocalFeatures:
        return self._extract_many([view])[0]

    def _extract_many(self, views: Sequence[View]) -> list[LocalFeatures]:
        """One network call per group of views that reach it at the same size (on the CPU: per view).

        With ``image_size`` set every view is resized to it, so the whole batch is one
        call; with ``None`` views are grouped by their own size (padding them to a common
        size would change the features near the borders).
        """
        import torch

        from ssga_descriptor_pnv.model import preprocess

        cfg: PnvConfig = self.config  # type: ignore[assignment]
        sides = [self._side(view) for view in views]  # every view checked before any network work
        out: dict[int, LocalFeatures] = {}
        for members in network_calls(sides, self.device):
            side = sides[members[0]]
            x = torch.cat([preprocess(views[i].rgb, cfg.image_size) for i in members]).to(self.device)
            with torch.inference_mode():
                local, _ = self.net(x)
            descriptors = local.float().cpu().numpy()
            grid = patch_grid((side[0] // STRIDE, side[1] // STRIDE), cfg.patch_size, cfg.stride)
            for row, i in enumerate(members):
                # A copy: each view's features outlive the batch (the cache keeps them per view), and a
                # slice would keep the whole batch's array alive with them.
                positions = _in_view_pixels(grid, side, views[i].camera.shape)
                out[i] = LocalFeatures(positions=positions, descriptors=descriptors[row].copy())
        return [out[i] for i in range(len(views))]

    def _side(self, view: View) -> tuple[int, int]:
        """The ``(height, width)`` the network sees ``view`` at; :class:`InputError` if it holds no patch."""
        cfg: PnvConfig = self.config  # type: ignore[assignment]
        h, w = view.camera.shape
        side = (cfg.image_size, cfg.image_size) if cfg.image_size is not None else (h, w)
        if min(side) // STRIDE < cfg.patch_size:
            raise InputError(f"{self.who}: a {w}x{h} view is too small for {cfg.patch_size}-cell patches (needs {STRIDE * cfg.patch_size} px a side)")
        return side



def _clusters(state: Any) -> int:
    """K, read from ``pool.centroids`` as Patch-NetVLAD's loader reads it."""
    centroids = state.get("pool.centroids")
    return int(centroids.shape[0]) if centroids is not None and centroids.ndim == 2 else RANDOM_CLUSTERS


def _in_view_pixels(positions: np.ndarray, side: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """Patch centres in the network input's pixels (``side``, as ``(height, width)``) moved to the view's (``shape``)."""
    (side_h, side_w), (h, w) = side, shape
    if (side_h, side_w) != (h, w):  # pixel i covers [i - 0.5, i + 0.5]
        positions = (positions + 0.5) * np.array([w / side_w, h / side_h], dtype=np.float32) - 0.5
    return positions.astype(np.float32)


@hookimpl
def ssga_register_descriptors() -> list[type[Descriptor]]:
    return [Pnv]
