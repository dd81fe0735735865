"""Patch-NetVLAD in plain torch: a VGG16 encoder, a NetVLAD pool with patch aggregation, WPCA.

The module layout and state-dict keys are the official ones (Hausler et al., CVPR 2021;
the ``patchnetvlad`` package), so the released checkpoints load strictly:

* ``encoder``: torchvision's ``vgg16().features[:-2]``, i.e. conv1_1 to conv5_3 *before*
  its ReLU (and without the last max-pool); stride 16. Keys
  ``encoder.{0,2,5,7,10,12,14,17,19,21,24,26,28}.{weight,bias}``. Built here without
  torchvision, index for index. :data:`.layout.LIGHT_WIDTHS` is the same network, 4x narrower.
* ``pool``: NetVLAD (``pool.centroids`` ``(K, D)``, ``pool.conv.weight`` ``(K, D, 1, 1)``,
  no bias). The encoder's descriptors are L2-normalised, soft-assigned to the K
  clusters by the 1 x 1 conv and a softmax, and their residuals to the centroids are
  summed, weighted by the assignment: over the whole map for the global descriptor,
  over each ``patch_size`` x ``patch_size`` window (``stride`` apart) for the local
  ones. Each is intra-normalised (per cluster), flattened to ``K * D`` and L2-normalised.
* ``WPCA``: ``Sequential(Conv2d(K * D, num_pcs, 1))`` (``WPCA.0.weight``, ``WPCA.0.bias``),
  then L2: PCA whitening fitted on training images' global descriptors.

The official code sums each window over an integral image; the mean over the window
(``F.avg_pool2d``) differs only by a positive factor per window, which the
normalisations remove (REFERENCE §1.2; ``tests/test_fidelity.py`` compares with the
official package). The pool expands the residuals one cluster at a time, so the peak
memory is ``N * D * H * W`` floats per cluster, not ``K`` times that.

The block widths, the conv5_3 grid and the patch centres (:func:`.layout.patch_grid`)
live in :mod:`.layout`, which the plugin reads without importing torch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ssga_descriptor_pnv.layout import VGG16_WIDTHS

_BLOCK_DEPTHS = (2, 2, 3, 3, 3)
"""Convolutions per VGG16 block."""

RANDOM_ALPHA = 10.0
"""Assignment sharpness of a network's random initialisation (k-means initialisation computes its own)."""

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def vgg16_encoder(widths: Sequence[int] = VGG16_WIDTHS) -> nn.Sequential:
    """``vgg16().features[:-2]`` with the given block widths: conv5_3 is the last layer, without its ReLU.

    Weights start as torchvision initialises VGG: Kaiming normal (fan out), zero biases.
    """
    layers: list[nn.Module] = []
    channels = 3
    for block, (width, depth) in enumerate(zip(widths, _BLOCK_DEPTHS)):
        if block:
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        for _ in range(depth):
            conv = nn.Conv2d(channels, width, kernel_size=3, padding=1)
            nn.init.kaiming_normal_(conv.weight, mode="fan_out", nonlinearity="relu")
            nn.init.zeros_(conv.bias)
            layers += [conv, nn.ReLU(inplace=True)]
            channels = width
    return nn.Sequential(*layers[:-1])  # features[:-2] drops conv5_3's ReLU and the final max-pool


class NetVLADPool(nn.Module):
    """NetVLAD (VLAD v1: no assignment bias) with Patch-NetVLAD's patch descriptors."""

    def __init__(self, clusters: int, dim: int, patch_size: int = 5, stride: int = 1) -> None:
        super().__init__()
        self.clusters, self.dim = clusters, dim
        self.patch_size, self.stride = patch_size, stride
        # Before k-means (init_from) or a checkpoint: random unit centroids and the assignment conv
        # NetVLAD derives from centroids (the official torch.rand centroids lie far from every unit
        # descriptor, so all residuals are nearly the same and the features ignore the image).
        centroids = F.normalize(torch.randn(clusters, dim), dim=1)
        self.conv = nn.Conv2d(dim, clusters, kernel_size=1, bias=False)
        self.centroids = nn.Parameter(centroids)
        with torch.no_grad():
            self.conv.weight.copy_(RANDOM_ALPHA * centroids[:, :, None, None])

    def init_from(self, centroids: np.ndarray, descriptors: np.ndarray) -> None:
        """NetVLAD's initialisation from k-means ``centroids`` of L2-normalised ``descriptors`` ``(N, D)``.

        The assignment conv is ``alpha * c / |c|``, with ``alpha`` chosen so that the two
        nearest clusters of a descriptor differ by a factor 100 in the softmax, on average.
        """
        unit = centroids / np.linalg.norm(centroids, axis=1, keepdims=True)
        dots = np.sort(unit @ descriptors.T, axis=0)[::-1]
        alpha = float(-np.log(0.01) / np.mean(dots[0] - dots[1]))
        with torch.no_grad():
            self.centroids.copy_(torch.from_numpy(centroids))
            self.conv.weight.copy_(torch.from_numpy(alpha * unit)[:, :, None, None])

    def forward(self, x: torch.Tensor, local: bool = True) -> tuple[torch.Tensor | None, torch.Tensor]:
        """``(local, global)`` VLADs of the feature maps ``x`` ``(N, D, H, W)``.

        Returns:
            ``local``: ``(N, P, K * D)``, patches row by row (``None`` if not ``local``);
            ``global``: ``(N, K * D)``. Both intra-normalised, then L2-normalised.
        """
        d = x.shape[1]
        x = F.normalize(x, p=2, dim=1)
        assign = F.softmax(self.conv(x), dim=1)  # (N, K, H, W)
        p, s = self.patch_size, self.stride
        glob, patches = [], []
        for k in range(self.clusters):
            residual = (x - self.centroids[k].view(1, d, 1, 1)) * assign[:, k : k + 1]  # (N, D, H, W)
            glob.append(residual.sum(dim=(2, 3)))
            if local:
                patches.append(F.avg_pool2d(residual, kernel_size=p, stride=s).flatten(2))  # (N, D, P)
        vlad_global = _normalise(torch.stack(glob, dim=1))  # (N, K, D) -> (N, K * D)
        if not local:
            return None, vlad_global
        vlad_local = _normalise(torch.stack(patches, dim=1).permute(0, 3, 1, 2))  # (N, P, K, D) -> (N, P, K * D)
        return vlad_local, vlad_global


def _normalise(vlad: torch.Tensor) -> torch.Tensor:
    """Intra-normalisation (per cluster, the second-last axis's rows), flatten, L2."""
    vlad = F.normalize(vlad, p=2, dim=-1)
    return F.normalize(vlad.flatten(-2), p=2, dim=-1)


class PatchNetVLAD(nn.Module):
    """``encoder`` -> ``pool`` -> ``WPCA``, under the official key names.

    Args:
        widths: the encoder's five block widths (:data:`.layout.VGG16_WIDTHS` or :data:`.layout.LIGHT_WIDTHS`).
        clusters: K, NetVLAD's number of clusters (the released models: read it from the file).
        num_pcs: WPCA output dimension (the local and global descriptors' length).
    """

    def __init__(
        self,
        widths: Sequence[int] = VGG16_WIDTHS,
        clusters: int = 16,
        num_pcs: int = 512,
        patch_size: int = 5,
        stride: int = 1,
    ) -> None:
        super().__init__()
        dim = widths[-1]
        self.encoder = vgg16_encoder(widths)
        self.pool = NetVLADPool(clusters, dim, patch_size, stride)
        self.WPCA = nn.Sequential(nn.Conv2d(clusters * dim, num_pcs, kernel_size=1))  # the official key name
        nn.init.zeros_(self.WPCA[0].bias)  # a random projection until fitted (a random bias would be shared by every feature)

    @property
    def num_pcs(self) -> int:
        return self.WPCA[0].out_channels

    def wpca(self, vlad: torch.Tensor) -> torch.Tensor:
        """The WPCA layer on ``(..., K * D)`` VLADs: a 1 x 1 conv is a linear map; then L2."""
        conv = self.WPCA[0]
        return F.normalize(F.linear(vlad, conv.weight.flatten(1), conv.bias), p=2, dim=-1)

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(local (N, P, num_pcs), global (N, num_pcs))`` of normalised images ``(N, 3, H, W)``."""
        vlad_local, vlad_global = self.pool(self.encoder(images))
        assert vlad_local is not None
        return self.wpca(vlad_local), self.wpca(vlad_global)

    def global_vlad(self, images: torch.Tensor) -> torch.Tensor:
        """``(N, K * D)`` whole-image NetVLAD before WPCA (what training compares)."""
        return self.pool(self.encoder(images), local=False)[1]


def preprocess(rgb: np.ndarray, size: int | None) -> torch.Tensor:
    """``(1, 3, S, S)`` float32: RGB uint8 ``(H, W, 3)`` resized to ``size`` x ``size`` (bilinear,
    antialiased when shrinking; ``None``: kept), scaled to [0, 1], ImageNet mean/std normalised."""
    x = torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float().div_(255.0)
    if size is not None and x.shape[-2:] != (size, size):
        x = F.interpolate(x, size=(size, size), mode="bilinear", align_corners=False, antialias=True)
    mean = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
    std = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)
    return (x - mean) / std
