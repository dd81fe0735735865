"""How close is a synthetic view to the true render at its pose? The masks and scores every synthesis figure uses.

* :func:`seen_mask`: the target pixels whose true surface a source view saw: the pixel,
  moved into the source camera with the true render's depth, lands on the source's own
  depth there (within :data:`TOLERANCE`). It does not depend on the synthesizer, so
  synthesizers are compared on the same pixels; a seen pixel a synthesis left empty
  counts (as black). The content a synthesis can hope to get right.
* :class:`QualityTally`: PSNR of the pooled mean squared error and SSIM (scikit-image's
  ``structural_similarity``: Gaussian window, sigma 1.5, per colour channel) averaged
  over the masked pixels of every pair added. For a mask, the synthetic image takes the
  true render's pixels outside it, so that an SSIM window straddling the mask's edge
  judges only the masked pixels.

Used by ``scripts/synthesis_quality.py`` (a benchmark dataset's cells) and the learned
synthesizers' held-out figures (``python -m ssga_synthesizer_synsin.evaluate``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from ssga_core import Pose, View

TOLERANCE = 0.02
"""Relative depth margin of "the same surface", as the synthesizers use it."""


def move(depth: np.ndarray, view: View, to: Pose) -> tuple[np.ndarray, np.ndarray]:
    """Where the pixels of ``view``, at ``depth``, land in the same camera at ``to``.

    Returns:
        ``(H, W, 2)`` uv and ``(H, W)`` depth in that camera (NaN where unknown).
    """
    T = to.relative_to(view.pose)
    points = view.camera.unproject(depth) @ T[:3, :3].T.astype(np.float32) + T[:3, 3].astype(np.float32)
    uv, z = view.camera.project(points)
    known = depth > 0
    return np.where(known[..., None], uv, np.nan), np.where(known, z, np.nan)


def on_surface(uv: np.ndarray, z: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Whether points at pixel ``uv`` and depth ``z`` lie on the surface that ``depth`` shows there.

    ``depth`` is read at the nearest pixel and, bilinearly, as inverse depth (exact on
    planes, so a floor seen at a grazing angle still matches); either within
    :data:`TOLERANCE` counts.
    """
    h, w = depth.shape
    with np.errstate(invalid="ignore"):
        inside = (uv[..., 0] > -0.5) & (uv[..., 0] < w - 0.5) & (uv[..., 1] > -0.5) & (uv[..., 1] < h - 0.5) & (z > 0)
    u = np.where(inside, uv[..., 0], 0).astype(np.float32)
    v = np.where(inside, uv[..., 1], 0).astype(np.float32)
    nearest = depth[np.rint(v).astype(int), np.rint(u).astype(int)]
    with np.errstate(divide="ignore"):
        inverse = np.where(depth > 0, 1.0 / depth, 0.0).astype(np.float32)
    bilinear = cv2.remap(inverse, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    with np.errstate(invalid="ignore", divide="ignore"):
        return inside & ((np.abs(nearest - z) <= TOLERANCE * z) | (np.abs(1.0 / bilinear - z) <= TOLERANCE * z))


def seen_mask(truth: View, sources: Iterable[View]) -> np.ndarray:
    """``(H, W)`` bool: the target pixels of ``truth`` whose true surface one of ``sources`` saw (all carry true depth)."""
    seen = np.zeros(truth.camera.shape, dtype=bool)
    for source in sources:
        seen |= on_surface(*move(truth.depth, truth, source.pose), source.depth)
    return seen


@dataclass
class QualityTally:
    """PSNR and SSIM of one mask, pooled over pairs."""

    pixels: int = 0
    squared_error: float = 0.0
    ssim_sum: float = 0.0

    def add(self, synthetic: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> None:
        from skimage.metrics import structural_similarity

        if not mask.any():
            return
        diff = synthetic[mask].astype(np.float64) - truth[mask]
        self.squared_error += float((diff**2).mean(axis=-1).sum())
        pasted = np.where(mask[..., None], synthetic, truth)  # only masked pixels differ
        _, smap = structural_similarity(
            pasted, truth, channel_axis=-1, data_range=255, gaussian_weights=True, sigma=1.5,
            use_sample_covariance=False, full=True,
        )  # fmt: skip
        self.ssim_sum += float(smap.mean(axis=-1)[mask].sum())
        self.pixels += int(mask.sum())

    @property
    def psnr(self) -> float:
        """In dB; NaN for no pixels, infinite for no error."""
        if not self.pixels:
            return float("nan")
        return float(10 * np.log10(255.0**2 * self.pixels / self.squared_error)) if self.squared_error else float("inf")

    @property
    def ssim(self) -> float:
        return self.ssim_sum / self.pixels if self.pixels else float("nan")
