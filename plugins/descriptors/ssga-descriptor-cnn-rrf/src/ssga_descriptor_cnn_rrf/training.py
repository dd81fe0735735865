"""Crops, augmentation, the training loop and the cache keys of the CNN-RRF classifier.

Everything random is drawn from one seeded ``numpy`` generator (crop boxes, rotations,
colour changes, batch order) and from torch's generator seeded once per training
(initialisation, dropout), so a training is repeatable on one machine and the same
draws are made on the CPU and on a GPU.
"""

from __future__ import annotations

import hashlib
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ssga_descriptor_cnn_rrf.vgg import VGG, normalise

CODE_VERSION = "cnn-rrf-1"
"""Part of every cache key: bump it when a change here would train a different classifier from the same input."""

Box = tuple[int, int, int, int]
"""``(x0, y0, x1, y1)``: a crop's pixel rows ``y0:y1`` and columns ``x0:x1`` (half-open)."""


def expand_box(box: Sequence[float], shape: tuple[int, int], margin: float, min_side: float) -> Box:
    """The crop that describes a region: its box, ``margin`` of its side larger on every side.

    ``box`` is ``[u0, v0, u1, v1]`` in pixel-centre coordinates, inclusive (as
    :class:`ssga_core.Regions` holds them). Each side becomes at least ``min_side`` px and
    at most the image's; a crop that would leave the image is shifted back inside (not
    cut), so every crop keeps its size. A box with a NaN gives the whole image.
    """
    h, w = shape
    u0, v0, u1, v1 = (float(b) for b in box)
    if not all(math.isfinite(b) for b in (u0, v0, u1, v1)):
        return 0, 0, w, h

    def side(lo: float, hi: float, limit: int) -> tuple[int, int]:
        # Pixel i spans [i, i + 1): the box spans [lo, hi + 1), its centre is (lo + hi + 1) / 2.
        size = min(max(round((hi - lo + 1.0) * (1.0 + 2.0 * margin)), round(min_side), 1), limit)
        first = min(max(math.floor((lo + hi + 1.0 - size) / 2.0 + 0.5), 0), limit - size)
        return first, first + size

    x0, x1 = side(u0, u1, w)
    y0, y1 = side(v0, v1, h)
    return x0, y0, x1, y1


def crop_batch(image: torch.Tensor, boxes: Sequence[Box], size: int) -> torch.Tensor:
    """``(len(boxes), 3, size, size)`` float crops in [0, 1] of a ``(3, H, W)`` uint8 image, each resized to a square.

    Bilinear with antialiasing, so a crop larger than ``size`` is averaged down rather
    than point-sampled; the aspect ratio is not kept (as torchvision's RandomResizedCrop).
    """
    crops = [image[None, :, y0:y1, x0:x1].float().div_(255.0) for x0, y0, x1, y1 in boxes]
    return torch.cat([F.interpolate(c, size=(size, size), mode="bilinear", align_corners=False, antialias=True) for c in crops])


@dataclass(frozen=True)
class Augmentation:
    """How a training sample is drawn from one training image (see the README).

    A fraction ``region_crops`` of the samples are *region-like* crops: a box of
    ``region_area`` of the image (log-uniform), aspect ratio 1/2 to 2, expanded by
    ``margin`` and at least ``min_side`` px as :func:`expand_box` expands a region's box,
    because the descriptor classifies region crops too. The others are *image-like*:
    ``image_area`` of the image, aspect ratio 3/4 to 4/3 (a random resized crop). Every
    sample is then rotated by up to ``rotation`` degrees (reflected borders) and its
    brightness, contrast and saturation are each scaled by a factor in ``1 +- colour``.
    No horizontal flips: a mirrored view shows another place.
    """

    size: int
    region_crops: float = 0.5
    region_area: tuple[float, float] = (0.01, 0.25)
    image_area: tuple[float, float] = (0.4, 1.0)
    rotation: float = 10.0
    colour: float = 0.3
    margin: float = 0.1
    min_side: float = 16.0

    def box(self, shape: tuple[int, int], rng: np.random.Generator) -> Box:
        h, w = shape
        region = rng.random() < self.region_crops
        lo, hi = self.region_area if region else self.image_area
        area = math.exp(rng.uniform(math.log(lo), math.log(hi))) * h * w
        ratio = math.exp(rng.uniform(math.log(0.5), math.log(2.0)) if region else rng.uniform(math.log(0.75), math.log(4 / 3)))
        bw = min(math.sqrt(area * ratio), w)
        bh = min(math.sqrt(area / ratio), h)
        u0 = rng.uniform(0.0, w - bw)
        v0 = rng.uniform(0.0, h - bh)
        if region:
            return expand_box((u0, v0, u0 + bw - 1.0, v0 + bh - 1.0), shape, self.margin, self.min_side)
        x0, y0 = int(u0), int(v0)
        return x0, y0, min(w, x0 + max(1, round(bw))), min(h, y0 + max(1, round(bh)))

    def batch(self, images: Sequence[torch.Tensor], picks: np.ndarray, rng: np.random.Generator) -> torch.Tensor:
        """Normalised ``(len(picks), 3, size, size)`` training inputs, one augmented crop of ``images[i]`` per pick."""
        x = torch.cat([crop_batch(images[i], [self.box(tuple(images[i].shape[1:]), rng)], self.size) for i in picks])
        n = len(picks)
        angle = np.deg2rad(rng.uniform(-self.rotation, self.rotation, n))
        gains = rng.uniform(1.0 - self.colour, 1.0 + self.colour, (3, n)).astype(np.float32)
        device = x.device
        if self.rotation > 0:
            cos, sin = np.cos(angle), np.sin(angle)
            theta = torch.tensor(
                np.stack([np.stack([cos, -sin, 0 * cos], 1), np.stack([sin, cos, 0 * cos], 1)], 1),
                dtype=torch.float32,
                device=device,
            )
            grid = F.affine_grid(theta, list(x.shape), align_corners=False)
            x = F.grid_sample(x, grid, mode="bilinear", padding_mode="reflection", align_corners=False)
        if self.colour > 0:
            brightness, contrast, saturation = (torch.from_numpy(g).to(device).view(n, 1, 1, 1) for g in gains)
            x = x * brightness
            mean = x.mean(dim=(1, 2, 3), keepdim=True)
            x = (x - mean) * contrast + mean
            grey = 0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3]
            x = (grey + (x - grey) * saturation).clamp_(0.0, 1.0)
        return normalise(x).contiguous(memory_format=torch.channels_last)


@dataclass(frozen=True)
class TrainingResult:
    steps: int
    seconds: float
    accuracy: float
    """Top-1 accuracy on the training images themselves (whole, not augmented), after training."""
    loss: float
    """Mean training loss over the last tenth of the steps (augmented samples)."""


def balanced_picks(labels: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` image indices, classes drawn in shuffled rounds (each class once per round), an image of the class at random.

    With one view per class (the paper's setting) this is plain shuffled epochs; a class
    with several views is not seen more often than one with a single view.
    """
    classes = np.unique(labels)
    members = [np.flatnonzero(labels == c) for c in classes]
    rounds = -(-count // len(classes))
    order = np.concatenate([rng.permutation(len(classes)) for _ in range(rounds)])[:count]
    return np.array([members[c][rng.integers(len(members[c]))] for c in order], dtype=np.intp)


def train(
    net: VGG,
    images: Sequence[torch.Tensor],
    targets: np.ndarray,
    augmentation: Augmentation,
    *,
    steps: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    label_smoothing: float,
    seed: int,
    log: Callable[[str], None] | None = None,
) -> TrainingResult:
    """Train ``net`` (on its device) to classify ``images`` (``(3, H, W)`` uint8 tensors) as ``targets``.

    AdamW, ``steps`` steps of ``batch_size`` augmented samples, the learning rate
    warmed up linearly over the first 5 % of the steps and then decayed to zero on a
    cosine. ``log`` gets about ten progress lines.
    """
    device = next(net.parameters()).device
    rng = np.random.default_rng(seed)
    picks = balanced_picks(targets, steps * batch_size, rng).reshape(steps, batch_size)
    y_all = torch.as_tensor(targets, dtype=torch.long, device=device)
    optimiser = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    warmup = max(1, steps // 20)

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        return 0.5 * (1.0 + math.cos(math.pi * (step - warmup) / max(1, steps - warmup)))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, factor)
    start = time.perf_counter()
    tail = max(1, steps // 10)
    losses: list[float] = []
    correct = seen = 0
    net.train()
    for step in range(steps):
        x = augmentation.batch(images, picks[step], rng)
        y = y_all[torch.as_tensor(picks[step], device=device)]
        logits = net(x)
        loss = F.cross_entropy(logits, y, label_smoothing=label_smoothing)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        schedule.step()
        losses.append(float(loss.detach()))
        correct += int((logits.argmax(1) == y).sum())
        seen += len(y)
        if log is not None and ((step + 1) % tail == 0 or step + 1 == steps):
            log(
                f"step {step + 1}/{steps}: loss {np.mean(losses[-tail:]):.3f}, "
                f"accuracy on augmented samples {correct / max(seen, 1):.2f}, {time.perf_counter() - start:.0f} s"
            )
            correct = seen = 0
    accuracy = evaluate(net, images, targets, augmentation.size)
    return TrainingResult(
        steps, time.perf_counter() - start, accuracy, float(np.mean(losses[-tail:])) if losses else float("nan")
    )


@torch.no_grad()
def evaluate(net: VGG, images: Sequence[torch.Tensor], targets: np.ndarray, size: int, batch: int = 64) -> float:
    """Top-1 accuracy of ``net`` (in eval mode) on the whole ``images``."""
    net.eval()
    hits = 0
    for s in range(0, len(images), batch):
        x = torch.cat([crop_batch(im, [(0, 0, im.shape[2], im.shape[1])], size) for im in images[s : s + batch]])
        predicted = net(normalise(x).contiguous(memory_format=torch.channels_last)).argmax(1).cpu().numpy()
        hits += int((predicted == targets[s : s + batch]).sum())
    return hits / max(1, len(images))


def training_key(images: Sequence[np.ndarray], labels: Sequence[int], config_json: str, start_digest: str) -> str:
    """The cache key of a training: the images' shapes and bytes, the labels, the config and the starting weights."""
    h = hashlib.blake2b(digest_size=20)
    for part in (CODE_VERSION, config_json, start_digest, str(len(images))):
        h.update(part.encode())
        h.update(b"\0")
    for image, label in zip(images, labels):
        h.update(np.int64(label).tobytes())
        h.update(str(image.shape).encode())
        h.update(np.ascontiguousarray(image).tobytes())
    return h.hexdigest()


@lru_cache(maxsize=8)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    h = hashlib.blake2b(digest_size=20)
    with open(path, "rb") as f:
        while chunk := f.read(1 << 22):
            h.update(chunk)
    return h.hexdigest()


def file_digest(path: Path) -> str:
    """Hash of a file's content (remembered per path, size and modification time: a VGG16 file is 528 MB)."""
    stat = path.stat()
    return _file_digest(str(path.resolve()), stat.st_size, stat.st_mtime_ns)


def stderr_log(prefix: str) -> Callable[[str], None]:
    def log(message: str) -> None:
        print(f"{prefix}: {message}", file=sys.stderr, flush=True)

    return log
