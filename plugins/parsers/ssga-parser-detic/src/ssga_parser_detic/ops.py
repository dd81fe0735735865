"""The detector's box operations in plain torch (``torchvision.ops`` is not available here).

Each reproduces what detectron2 computes at inference, so a released checkpoint sees the
inputs it was trained with:

* :func:`roi_align`: torchvision's ``roi_align`` as detectron2's ``ROIAlignV2`` calls it
  (``aligned=True``: box corners shifted by half a pixel; ``sampling_ratio=0``: each bin
  averages ``ceil(bin size)`` x ``ceil(bin size)`` bilinear samples, per box);
* :func:`assign_levels` and :func:`pool_levels`: ``ROIPooler``'s choice of FPN level by
  box size (FPN paper eq. 1, canonical 224 px at level 4);
* :func:`nms` and :func:`batched_nms`: greedy NMS by decreasing score, boxes of different
  classes never suppressing each other (torchvision's ``batched_nms``);
* :func:`apply_deltas`: ``Box2BoxTransform.apply_deltas``;
* :func:`paste_masks`: ``paste_masks_in_image`` (each ``M x M`` mask resampled into its
  box with ``grid_sample``, then thresholded);
* :func:`resized_shape` and :func:`resize_rgb`: the test-time resizes (PIL bilinear).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

SCALE_CLAMP = math.log(1000.0 / 16)
"""``Box2BoxTransform``'s limit on predicted log-scale changes (detectron2's default)."""

CANONICAL_BOX_SIZE, CANONICAL_LEVEL = 224, 4
"""``ROIPooler``'s defaults: a 224 px box pools from level 4 (stride 16)."""

_SAMPLES_PER_CHUNK = 1 << 24
"""Bilinear samples (times channels) drawn at once by :func:`roi_align`: bounds its memory to ~64 MB."""


def roi_align(
    features: torch.Tensor,
    rois: torch.Tensor,
    output_size: int,
    spatial_scale: float,
    sampling_ratio: int = 0,
    aligned: bool = True,
) -> torch.Tensor:
    """Average of bilinear samples in each of ``output_size`` x ``output_size`` bins of each box.

    Args:
        features: ``(N, C, H, W)``.
        rois: ``(R, 5)``: batch index, then ``x0, y0, x1, y1`` in image coordinates (pixel
            ``i`` spans ``[i, i + 1)``), scaled to the map by ``spatial_scale``.
        sampling_ratio: samples per bin side; ``0``: ``ceil(bin size)`` per box and side.
        aligned: shift the scaled corners by -0.5 so samples sit on pixel centres
            (detectron2's ROIAlignV2); ``False``: the legacy op, boxes at least 1 x 1.

    Returns:
        ``(R, C, output_size, output_size)``. A sample further than one pixel outside the
        map counts as zero; one within a pixel of the border takes the border's value.
    """
    r = len(rois)
    c = features.shape[1]
    # Filled channel-major, as grid_sample returns its samples, and transposed once at the end.
    out = features.new_zeros((c, r, output_size, output_size))
    if r == 0:
        return out.transpose(0, 1)
    rois = rois.to(features.dtype)
    offset = 0.5 if aligned else 0.0
    start = rois[:, 1:3] * spatial_scale - offset  # (R, 2): x, y
    size = (rois[:, 3:5] * spatial_scale - offset) - start
    if not aligned:
        size = size.clamp(min=1.0)
    bin_size = size / output_size
    if sampling_ratio > 0:
        grid = torch.full_like(size, sampling_ratio, dtype=torch.long)
    else:
        grid = torch.ceil(size / output_size).long()
    keys = torch.cat([rois[:, :1].long(), grid], dim=1)
    for key in torch.unique(keys, dim=0):
        batch, gx, gy = (int(v) for v in key)
        if gx <= 0 or gy <= 0:  # an empty box: no sample, the bins stay zero as in the reference op
            continue
        members = torch.nonzero((keys == key).all(dim=1)).squeeze(1)
        chunk = max(1, _SAMPLES_PER_CHUNK // (c * output_size * output_size * gx * gy))
        for part in members.split(chunk):
            out[:, part] = _sample_bins(features[batch], start[part], bin_size[part], output_size, gx, gy)
    return out.transpose(0, 1).contiguous()


def _sample_bins(fmap: torch.Tensor, start: torch.Tensor, bin_size: torch.Tensor, bins: int, gx: int, gy: int) -> torch.Tensor:
    """``(C, m, bins, bins)`` for boxes sharing a sample grid of ``gy`` x ``gx`` per bin, on one ``(C, H, W)`` map."""
    c, h, w = fmap.shape
    m = len(start)

    def positions(axis: int, per_bin: int) -> torch.Tensor:  # (m, bins * per_bin), bin-major
        step = bin_size[:, axis, None, None]
        sub = (torch.arange(per_bin, device=fmap.device, dtype=fmap.dtype) + 0.5)[None, None, :]
        pos = start[:, axis, None, None] + torch.arange(bins, device=fmap.device, dtype=fmap.dtype)[None, :, None] * step + sub * step / per_bin
        return pos.reshape(m, bins * per_bin)

    xs, ys = positions(0, gx), positions(1, gy)
    ny, nx = ys.shape[1], xs.shape[1]
    gxy = torch.stack(torch.broadcast_tensors(((2.0 * xs + 1.0) / w - 1.0)[:, None, :], ((2.0 * ys + 1.0) / h - 1.0)[:, :, None]), dim=-1)
    # The reference clamps a sample within one pixel outside the map to the border (grid_sample's
    # "border" padding) and zeroes one further out.
    sampled = F.grid_sample(fmap[None], gxy.reshape(1, m * ny, nx, 2), mode="bilinear", padding_mode="border", align_corners=False)
    outside = ~(((ys >= -1.0) & (ys <= h))[:, :, None] & ((xs >= -1.0) & (xs <= w))[:, None, :])
    if outside.any():
        sampled = sampled * ~outside.reshape(1, 1, m * ny, nx)
    # Each bin's samples are a gy x gx block that never straddles two boxes (ny = bins * gy).
    pooled = F.avg_pool2d(sampled, kernel_size=(gy, gx), stride=(gy, gx))  # (1, C, m * bins, bins)
    return pooled.reshape(c, m, bins, bins)


def assign_levels(boxes: torch.Tensor, min_level: int, max_level: int) -> torch.Tensor:
    """Index (from ``min_level``) of the FPN level each ``(R, 4)`` box pools from, by its size."""
    sizes = torch.sqrt((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1]))
    levels = torch.floor(CANONICAL_LEVEL + torch.log2(sizes / CANONICAL_BOX_SIZE + 1e-8))
    return levels.clamp(min=min_level, max=max_level).long() - min_level


def pool_levels(features: list[torch.Tensor], boxes: torch.Tensor, strides: list[int], output_size: int) -> torch.Tensor:
    """ROIAlignV2 features ``(R, C, output_size, output_size)`` of one image's boxes, each from its level."""
    min_level, max_level = int(math.log2(strides[0])), int(math.log2(strides[-1]))
    out = features[0].new_zeros((len(boxes), features[0].shape[1], output_size, output_size))
    if not len(boxes):
        return out
    levels = assign_levels(boxes, min_level, max_level)
    rois = torch.cat([boxes.new_zeros((len(boxes), 1)), boxes], dim=1)
    for level, (fmap, stride) in enumerate(zip(features, strides, strict=True)):
        members = torch.nonzero(levels == level).squeeze(1)
        if len(members):
            out[members] = roi_align(fmap, rois[members], output_size, 1.0 / stride)
    return out


def nms(boxes: torch.Tensor, scores: torch.Tensor, iou_threshold: float) -> torch.Tensor:
    """Indices of the boxes greedy NMS keeps, by decreasing score.

    A box is dropped when its IoU with a kept, higher-scoring box exceeds the threshold.
    IoU as torchvision computes it, in float32: areas ``(x1 - x0) * (y1 - y0)``, no +1.
    """
    if not len(boxes):
        return torch.zeros(0, dtype=torch.long, device=boxes.device)
    b = boxes.detach().float().cpu().numpy()
    order = np.argsort(-scores.detach().float().cpu().numpy(), kind="stable")
    x0, y0, x1, y1 = (np.ascontiguousarray(b[order, k]) for k in range(4))
    areas = (x1 - x0) * (y1 - y0)
    suppressed = np.zeros(len(order), dtype=bool)
    keep = []
    for i in range(len(order)):
        if suppressed[i]:
            continue
        keep.append(i)
        rest = slice(i + 1, None)
        inter = np.clip(np.minimum(x1[i], x1[rest]) - np.maximum(x0[i], x0[rest]), 0, None) * np.clip(
            np.minimum(y1[i], y1[rest]) - np.maximum(y0[i], y0[rest]), 0, None
        )
        with np.errstate(invalid="ignore", divide="ignore"):  # two empty boxes: 0 / 0, never above the threshold
            suppressed[rest] |= inter / (areas[i] + areas[rest] - inter) > iou_threshold
    return torch.from_numpy(order[keep]).to(boxes.device)


def batched_nms(boxes: torch.Tensor, scores: torch.Tensor, classes: torch.Tensor, iou_threshold: float) -> torch.Tensor:
    """:func:`nms` within each class; the kept indices of all classes by decreasing score.

    torchvision's small-input path offsets each class's boxes far apart instead, which
    gives the same result except where the offset costs float32 precision.
    """
    kept = [members[nms(boxes[members], scores[members], iou_threshold)] for members in _groups(classes)]
    if not kept:
        return torch.zeros(0, dtype=torch.long, device=boxes.device)
    keep = torch.cat(kept)
    return keep[torch.argsort(scores[keep], descending=True, stable=True)]


def _groups(classes: torch.Tensor) -> list[torch.Tensor]:
    order = torch.argsort(classes, stable=True)
    _, counts = torch.unique_consecutive(classes[order], return_counts=True)
    return list(order.split(counts.tolist()))


def apply_deltas(deltas: torch.Tensor, boxes: torch.Tensor, weights: tuple[float, float, float, float]) -> torch.Tensor:
    """Boxes ``(R, 4)`` moved by R-CNN deltas ``(R, 4)`` (dx, dy, dw, dh, each divided by its weight)."""
    deltas, boxes = deltas.float(), boxes.float()
    widths, heights = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    cx, cy = boxes[:, 0] + 0.5 * widths, boxes[:, 1] + 0.5 * heights
    wx, wy, ww, wh = weights
    dx, dy = deltas[:, 0] / wx, deltas[:, 1] / wy
    dw, dh = (deltas[:, 2] / ww).clamp(max=SCALE_CLAMP), (deltas[:, 3] / wh).clamp(max=SCALE_CLAMP)
    px, py = dx * widths + cx, dy * heights + cy
    pw, ph = torch.exp(dw) * widths, torch.exp(dh) * heights
    return torch.stack([px - 0.5 * pw, py - 0.5 * ph, px + 0.5 * pw, py + 0.5 * ph], dim=1)


def clip_boxes(boxes: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Boxes clamped into an image of ``(height, width)``."""
    h, w = shape
    return torch.stack([boxes[:, 0].clamp(0, w), boxes[:, 1].clamp(0, h), boxes[:, 2].clamp(0, w), boxes[:, 3].clamp(0, h)], dim=1)


def paste_masks(masks: torch.Tensor, boxes: torch.Tensor, shape: tuple[int, int], threshold: float = 0.5) -> torch.Tensor:
    """``(N, H, W)`` bool: each ``(M, M)`` soft mask resampled into its box, ``>= threshold``.

    A pixel takes the mask's bilinear value at its centre, the mask's ``M x M`` cells
    spanning the box; outside the box the value falls below one half within one pixel, so
    only the box's neighbourhood is sampled (as detectron2 does on the CPU).
    """
    h, w = shape
    out = torch.zeros((len(masks), h, w), dtype=torch.bool, device=masks.device)
    for k, (mask, box) in enumerate(zip(masks.float(), boxes.float(), strict=True)):
        x0, y0, x1, y1 = (float(v) for v in box)
        c0, r0 = max(math.floor(x0) - 1, 0), max(math.floor(y0) - 1, 0)
        c1, r1 = min(math.ceil(x1) + 1, w), min(math.ceil(y1) + 1, h)
        if c1 <= c0 or r1 <= r0 or x1 <= x0 or y1 <= y0:
            continue
        gx = (torch.arange(c0, c1, device=masks.device, dtype=torch.float32) + 0.5 - x0) / (x1 - x0) * 2 - 1
        gy = (torch.arange(r0, r1, device=masks.device, dtype=torch.float32) + 0.5 - y0) / (y1 - y0) * 2 - 1
        grid = torch.stack(torch.broadcast_tensors(gx[None, :], gy[:, None]), dim=-1)[None]
        pasted = F.grid_sample(mask[None, None], grid, mode="bilinear", padding_mode="zeros", align_corners=False)[0, 0]
        out[k, r0:r1, c0:c1] = pasted >= threshold
    return out


def resized_shape(shape: tuple[int, int], resize: str, size: int, max_size: int) -> tuple[int, int]:
    """``(height, width)`` the network sees for an image of ``shape``.

    ``"max-size"``: Detic's ``EfficientDetResizeCrop`` at test time (scale 1): the longer
    side becomes ``size``, sides truncated to integers, nothing to crop.
    ``"shortest-edge"``: detectron2's ``ResizeShortestEdge`` as its ``DefaultPredictor``
    (Detic's demo) uses it: the shorter side becomes ``size`` unless the longer would
    exceed ``max_size``; sides rounded.
    """
    h, w = shape
    if resize == "max-size":
        scale = min(size / h, size / w)
        return int(h * scale), int(w * scale)
    scale = size / min(h, w)
    nh, nw = (size, scale * w) if h < w else (scale * h, size)
    if max(nh, nw) > max_size:
        shrink = max_size / max(nh, nw)
        nh, nw = nh * shrink, nw * shrink
    return int(nh + 0.5), int(nw + 0.5)


def resize_rgb(rgb: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A uint8 RGB image resized to ``(height, width)`` with PIL's bilinear filter, as both resizes do."""
    from PIL import Image

    if rgb.shape[:2] == tuple(shape):
        return rgb
    return np.asarray(Image.fromarray(rgb).resize((shape[1], shape[0]), Image.BILINEAR))
