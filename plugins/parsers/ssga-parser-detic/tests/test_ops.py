"""The detector's box operations against direct reference computations on random inputs.

Each reference is written from the operation's definition, one sample, one pixel or one
box at a time, in float64 Python: slow, obvious, independent of the vectorised code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from ssga_parser_detic.ops import (
    apply_deltas,
    assign_levels,
    batched_nms,
    nms,
    paste_masks,
    pool_levels,
    resized_shape,
    roi_align,
)

# --------------------------------------------------------------------------- ROIAlign


def _bilinear(fmap: np.ndarray, y: float, x: float) -> np.ndarray:
    """One sample of a (C, H, W) map as the ROIAlign kernel takes it (zero beyond a pixel outside, clamped within)."""
    _, h, w = fmap.shape
    if y < -1.0 or y > h or x < -1.0 or x > w:
        return np.zeros(fmap.shape[0])
    y, x = max(y, 0.0), max(x, 0.0)
    y0, x0 = int(y), int(x)
    if y0 >= h - 1:
        y0 = y1 = h - 1
        y = float(y0)
    else:
        y1 = y0 + 1
    if x0 >= w - 1:
        x0 = x1 = w - 1
        x = float(x0)
    else:
        x1 = x0 + 1
    ly, lx = y - y0, x - x0
    return (1 - ly) * (1 - lx) * fmap[:, y0, x0] + (1 - ly) * lx * fmap[:, y0, x1] + ly * (1 - lx) * fmap[:, y1, x0] + ly * lx * fmap[:, y1, x1]


def _roi_align_reference(features, rois, out, scale, sampling_ratio, aligned):
    features = features.double().numpy()
    result = np.zeros((len(rois), features.shape[1], out, out))
    for r, (b, x0, y0, x1, y1) in enumerate(rois.double().tolist()):
        offset = 0.5 if aligned else 0.0
        sx, sy = x0 * scale - offset, y0 * scale - offset
        rw, rh = x1 * scale - offset - sx, y1 * scale - offset - sy
        if not aligned:
            rw, rh = max(rw, 1.0), max(rh, 1.0)
        bw, bh = rw / out, rh / out
        gy = sampling_ratio if sampling_ratio > 0 else math.ceil(rh / out)
        gx = sampling_ratio if sampling_ratio > 0 else math.ceil(rw / out)
        for py in range(out):
            for px in range(out):
                total = np.zeros(features.shape[1])
                for iy in range(gy):
                    for ix in range(gx):
                        y = sy + py * bh + (iy + 0.5) * bh / gy
                        x = sx + px * bw + (ix + 0.5) * bw / gx
                        total += _bilinear(features[int(b)], y, x)
                result[r, :, py, px] = total / max(gy * gx, 1)
    return result


def _random_rois(rng, n: int, image: tuple[int, int], batches: int) -> torch.Tensor:
    """Boxes of every kind: inside, across the border, far outside, thin, tiny, empty."""
    h, w = image
    x0 = rng.uniform(-0.3 * w, 1.1 * w, n)
    y0 = rng.uniform(-0.3 * h, 1.1 * h, n)
    bw = rng.choice([0.0, 0.3, 2.5, 9.0, 0.6 * w, 1.4 * w], n) * rng.uniform(0.5, 1.0, n)
    bh = rng.choice([0.0, 0.4, 3.0, 11.0, 0.7 * h, 1.3 * h], n) * rng.uniform(0.5, 1.0, n)
    batch = rng.integers(0, batches, n)
    return torch.tensor(np.stack([batch, x0, y0, x0 + bw, y0 + bh], axis=1), dtype=torch.float32)


@pytest.mark.parametrize(
    ("scale", "out", "sampling_ratio", "aligned"),
    [(1 / 8, 7, 0, True), (1 / 4, 14, 0, True), (1 / 2, 3, 2, True), (1 / 8, 7, 0, False), (1.0, 2, 0, True)],
)
def test_roi_align_matches_the_per_bin_bilinear_loop(scale, out, sampling_ratio, aligned):
    rng = np.random.default_rng(int(scale * 100) + out + sampling_ratio)
    features = torch.tensor(rng.normal(size=(2, 3, 13, 17)), dtype=torch.float32)
    image = (round(13 / scale), round(17 / scale))
    rois = _random_rois(rng, 40, image, batches=2)
    got = roi_align(features, rois, out, scale, sampling_ratio, aligned)
    want = _roi_align_reference(features, rois, out, scale, sampling_ratio, aligned)
    assert got.shape == (40, 3, out, out)
    np.testing.assert_allclose(got.numpy(), want, atol=2e-5)
    assert (want == 0).all(axis=(1, 2, 3)).any() and not (want == 0).all(), "the boxes should include empty and non-empty ones"


def test_roi_align_of_a_constant_map_inside_is_the_constant():
    features = torch.full((1, 2, 10, 10), 3.0)
    rois = torch.tensor([[0, 8.0, 8.0, 70.0, 60.0]])  # stride 8: well inside the 80 x 80 image
    np.testing.assert_allclose(roi_align(features, rois, 7, 1 / 8).numpy(), 3.0, rtol=1e-6)


def test_roi_align_with_no_box_is_empty():
    assert roi_align(torch.zeros(1, 4, 5, 5), torch.zeros(0, 5), 7, 1.0).shape == (0, 4, 7, 7)


# --------------------------------------------------------------------------- FPN levels


@pytest.mark.parametrize(
    ("side", "level"),
    [(224, 4), (223, 3), (112, 3), (10, 3), (0.0, 3), (447, 4), (448, 5), (5000, 5)],
)
def test_boxes_pool_from_the_level_of_their_size(side, level):
    # floor(4 + log2(sqrt(area) / 224)), clamped to P3..P5 (index from P3).
    box = torch.tensor([[10.0, 20.0, 10.0 + side, 20.0 + side]])
    assert int(assign_levels(box, 3, 5)[0]) == level - 3


def test_each_box_is_aligned_on_its_own_level():
    rng = np.random.default_rng(3)
    strides = [8, 16, 32]
    features = [torch.tensor(rng.normal(size=(1, 2, 96 // s, 128 // s)), dtype=torch.float32) for s in strides]
    x0, y0 = rng.uniform(0, 60, 30), rng.uniform(0, 40, 30)
    side = rng.choice([30.0, 350.0, 900.0], 30) * rng.uniform(0.8, 1.2, 30)
    boxes = torch.tensor(np.stack([x0, y0, x0 + side, y0 + side * 0.8], axis=1), dtype=torch.float32)
    got = pool_levels(features, boxes, strides, 7)
    levels = assign_levels(boxes, 3, 5)
    assert set(levels.tolist()) == {0, 1, 2}
    rois = torch.cat([torch.zeros(30, 1), boxes], dim=1)
    for k in range(30):
        level = int(levels[k])
        want = roi_align(features[level], rois[k : k + 1], 7, 1 / strides[level])
        torch.testing.assert_close(got[k : k + 1], want)


# --------------------------------------------------------------------------- NMS


def _iou(a, b) -> float:
    inter = max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return inter / union if union > 0 else 0.0


def _greedy_reference(boxes, scores, classes, threshold) -> list[int]:
    """Visit boxes by decreasing score; keep one unless a kept box of its class overlaps it by more than the threshold."""
    order = sorted(range(len(scores)), key=lambda i: -scores[i])
    kept: list[int] = []
    for i in order:
        if all(classes[j] != classes[i] or _iou(boxes[i], boxes[j]) <= threshold for j in kept):
            kept.append(i)
    return kept


def _clustered_boxes(rng, n: int):
    """Boxes jittered around a few centres (so many overlap), a third near-copies of others, a few empty."""
    centres = rng.uniform(0, 200, (6, 2))
    c = centres[rng.integers(0, 6, n)] + rng.normal(0, 6, (n, 2))
    size = rng.uniform(20, 60, (n, 2))
    copies = rng.random(n) < 1 / 3
    source = rng.integers(0, n, n)
    c[copies], size[copies] = c[source[copies]] + rng.normal(0, 0.5, (copies.sum(), 2)), size[source[copies]]
    size[rng.random(n) < 0.05] = 0.0
    return np.concatenate([c - size / 2, c + size / 2], axis=1)


@pytest.mark.parametrize("threshold", [0.3, 0.5, 0.9])
def test_nms_matches_the_brute_force_greedy_loop(threshold):
    rng = np.random.default_rng(int(threshold * 10))
    boxes, scores = _clustered_boxes(rng, 300), rng.permutation(300) / 300.0 + 0.001
    got = nms(torch.tensor(boxes, dtype=torch.float32), torch.tensor(scores, dtype=torch.float32), threshold)
    want = _greedy_reference(boxes.tolist(), scores.tolist(), [0] * 300, threshold)
    assert got.tolist() == want
    assert 10 < len(want) < 290, "the test boxes should both overlap and not"


def test_batched_nms_suppresses_only_within_a_class():
    rng = np.random.default_rng(7)
    boxes, scores = _clustered_boxes(rng, 400), rng.permutation(400) / 400.0 + 0.001
    classes = rng.integers(0, 5, 400)
    got = batched_nms(torch.tensor(boxes, dtype=torch.float32), torch.tensor(scores, dtype=torch.float32), torch.tensor(classes), 0.5)
    want = _greedy_reference(boxes.tolist(), scores.tolist(), classes.tolist(), 0.5)
    assert got.tolist() == want
    assert len(want) > len(_greedy_reference(boxes.tolist(), scores.tolist(), [0] * 400, 0.5))


def test_nms_of_nothing_keeps_nothing():
    assert nms(torch.zeros(0, 4), torch.zeros(0), 0.5).tolist() == []
    assert batched_nms(torch.zeros(0, 4), torch.zeros(0), torch.zeros(0, dtype=torch.long), 0.5).tolist() == []


# --------------------------------------------------------------------------- boxes and masks


def test_deltas_move_and_scale_boxes_by_their_weights():
    boxes = torch.tensor([[10.0, 20.0, 50.0, 40.0]])  # 40 x 20, centre (30, 30)
    weights = (10.0, 10.0, 5.0, 5.0)
    np.testing.assert_allclose(apply_deltas(torch.zeros(1, 4), boxes, weights).numpy(), boxes.numpy())
    moved = apply_deltas(torch.tensor([[1.0, -2.0, 5 * math.log(2.0), 0.0]]), boxes, weights)
    # centre + (0.1 * 40, -0.2 * 20), width x 2, height kept
    np.testing.assert_allclose(moved.numpy(), [[34.0 - 40.0, 26.0 - 10.0, 34.0 + 40.0, 26.0 + 10.0]], rtol=1e-6)
    huge = apply_deltas(torch.tensor([[0.0, 0.0, 1e4, 1e4]]), boxes, weights)
    assert torch.isfinite(huge).all() and float(huge[0, 2] - huge[0, 0]) == pytest.approx(40 * 1000 / 16, rel=1e-4)


def _paste_reference(mask: np.ndarray, box, shape) -> np.ndarray:
    """Each pixel centre's bilinear value of the mask stretched over the box (zero beyond its cells), >= 0.5."""
    m = mask.shape[0]
    x0, y0, x1, y1 = box
    out = np.zeros(shape, dtype=bool)
    for r in range(shape[0]):
        for c in range(shape[1]):
            # mask cell coordinates: cell k's centre at k; the box spans [-0.5, m - 0.5]
            u = (c + 0.5 - x0) / (x1 - x0) * m - 0.5
            v = (r + 0.5 - y0) / (y1 - y0) * m - 0.5
            u0, v0 = math.floor(u), math.floor(v)
            value = 0.0
            for vv, wv in ((v0, 1 - (v - v0)), (v0 + 1, v - v0)):
                for uu, wu in ((u0, 1 - (u - u0)), (u0 + 1, u - u0)):
                    if 0 <= vv < m and 0 <= uu < m:
                        value += wv * wu * mask[vv, uu]
            out[r, c] = value >= 0.5
    return out


def test_pasted_masks_match_the_per_pixel_bilinear_reference():
    rng = np.random.default_rng(5)
    shape = (40, 50)
    masks = rng.random((6, 28, 28)).astype(np.float32)
    masks[0] = 1.0  # a full mask covers exactly the pixels whose centres are in its box
    boxes = np.array([[5.3, 7.7, 30.2, 21.4], [-6.0, -3.0, 12.5, 9.5], [40.1, 30.3, 58.0, 47.0], [10.0, 10.0, 10.5, 30.0], [1.2, 2.2, 48.6, 38.9], [20.0, 5.0, 22.7, 6.1]])
    got = paste_masks(torch.tensor(masks), torch.tensor(boxes, dtype=torch.float32), shape).numpy()
    for k in range(6):
        np.testing.assert_array_equal(got[k], _paste_reference(masks[k], boxes[k], shape), err_msg=f"mask {k}")
    centres_in_box = (np.arange(50)[None, :] + 0.5 >= 5.3) & (np.arange(50)[None, :] + 0.5 <= 30.2) & (np.arange(40)[:, None] + 0.5 >= 7.7) & (np.arange(40)[:, None] + 0.5 <= 21.4)
    np.testing.assert_array_equal(got[0], centres_in_box)


# --------------------------------------------------------------------------- test-time resize


@pytest.mark.parametrize(
    ("shape", "resize", "size", "want"),
    [
        ((256, 256), "max-size", 640, (640, 640)),
        ((480, 640), "max-size", 640, (480, 640)),
        ((300, 500), "max-size", 640, (384, 640)),
        ((333, 1000), "max-size", 640, (213, 640)),  # 333 * 0.64 = 213.12, truncated
        ((480, 640), "shortest-edge", 800, (800, 1067)),  # 1066.67, rounded
        ((200, 1000), "shortest-edge", 800, (267, 1333)),  # the longer side capped at 1333
        ((256, 256), "shortest-edge", 800, (800, 800)),
    ],
)
def test_test_time_resizes(shape, resize, size, want):
    assert resized_shape(shape, resize, size, 1333) == want
