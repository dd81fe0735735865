"""k-means over local descriptors: the bag of words' dictionary (:mod:`ssga_bench.bow`).

Lloyd's iterations from a k-means++ (or random) seeding, in float32 and in blocks of
distances, so that memory stays bounded for any number of descriptors and words.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from ssga_core.errors import InputError

BLOCK = 1 << 22
"""Most distance entries computed at once (16 MiB of float32): bounds memory for any N, k, m."""


def as_descriptor_matrix(name: str, x: np.ndarray, dim: int | None = None) -> np.ndarray:
    """``x`` as a contiguous float32 ``(N, D)`` matrix of finite numbers (``D = dim`` if given), or a one-line error naming ``name``."""
    x = np.asarray(x)
    if x.ndim != 2 or not np.issubdtype(x.dtype, np.number):
        raise InputError(f"{name}: expected an (N, D) array of numbers, got shape {x.shape} of {x.dtype}")
    if dim is not None and x.shape[1] != dim:
        raise InputError(f"{name}: expected {dim}-d descriptors (the dictionary's), got {x.shape[1]}-d")
    x = np.ascontiguousarray(x, dtype=np.float32)
    if not np.isfinite(x).all():
        raise InputError(f"{name}: descriptors contain NaN or infinity")
    return x


def squared_distances(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``(N, K)`` squared Euclidean distances between the rows of ``x`` and of ``y`` (float32, >= 0)."""
    d = (x * x).sum(1)[:, None] - 2.0 * (x @ y.T) + (y * y).sum(1)[None, :]
    return np.maximum(d, 0.0, out=d)


def _assign(x: np.ndarray, x2: np.ndarray, centroids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest centroid of each row and its squared distance (``x2``: the rows' squared norms), in blocks."""
    labels = np.empty(len(x), dtype=np.intp)
    dist = np.empty(len(x), dtype=np.float32)
    c2 = (centroids * centroids).sum(1)
    minus_2c = -2.0 * centroids.T
    step = max(1, BLOCK // len(centroids))
    for s in range(0, len(x), step):
        d = x[s : s + step] @ minus_2c
        d += c2  # + |x|^2 is the same for every centroid: added to the minimum only
        lab = d.argmin(1)
        labels[s : s + step] = lab
        dist[s : s + step] = d[np.arange(len(d)), lab] + x2[s : s + step]
    np.maximum(dist, 0.0, out=dist)
    return labels, dist


def _kmeans_pp(x: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding (Arthur and Vassilvitskii, 2007) on at most ``100 k`` rows of ``x``."""
    if len(x) > 100 * k:
        x = x[rng.choice(len(x), 100 * k, replace=False)]
    x2 = (x * x).sum(1)
    centres = np.empty((k, x.shape[1]), dtype=np.float32)
    centres[0] = x[rng.integers(len(x))]
    closest = np.maximum(x2 - 2.0 * (x @ centres[0]) + x2.dtype.type(centres[0] @ centres[0]), 0.0).astype(np.float64)
    for i in range(1, k):
        total = closest.sum()
        # All remaining rows coincide with a centre: any row will do (a duplicate word).
        j = int(rng.choice(len(x), p=closest / total)) if total > 0 else int(rng.integers(len(x)))
        centres[i] = x[j]
        d = x2 - 2.0 * (x @ centres[i]) + x2[j]
        np.minimum(closest, np.maximum(d, 0.0), out=closest)
    return centres


def kmeans(
    x: np.ndarray,
    k: int,
    *,
    iterations: int = 20,
    init: Literal["k-means++", "random"] = "k-means++",
    tol: float = 1e-3,
    rng: np.random.Generator | int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means on the rows of ``x``.

    Stops after ``iterations`` updates, or once at most a fraction ``tol`` of the rows
    change cluster. An emptied cluster is re-seeded at the row farthest from its
    centroid, so all ``k`` centroids stay in use as long as ``x`` has ``k`` distinct rows.

    Returns:
        ``(k, D)`` float32 centroids and ``(N,)`` labels (each row's nearest centroid).
    """
    x = as_descriptor_matrix("kmeans", x)
    if not 1 <= k <= len(x):
        raise InputError(f"kmeans: k = {k} clusters need at least {k} descriptors, got {len(x)}")
    rng = np.random.default_rng(rng)
    if init == "k-means++":
        centroids = _kmeans_pp(x, k, rng)
    else:
        centroids = x[rng.choice(len(x), k, replace=False)].copy()
    x2 = (x * x).sum(1)
    labels, dist = _assign(x, x2, centroids)
    for _ in range(iterations):
        means, counts = _cluster_means(x, labels, k)
        filled = counts > 0
        centroids[filled] = means[filled]
        empty = np.flatnonzero(~filled)
        if len(empty):
            far = np.argsort(-dist, kind="stable")[: len(empty)]
            centroids[empty] = x[far]
        new_labels, dist = _assign(x, x2, centroids)
        changed = np.count_nonzero(new_labels != labels)
        labels = new_labels
        if changed <= tol * len(x) and not len(empty):
            break
    return centroids, labels


def _cluster_means(x: np.ndarray, labels: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of each cluster's rows (float32; rows of empty clusters undefined) and the cluster sizes."""
    counts = np.bincount(labels, minlength=k)
    ends = np.cumsum(counts)
    grouped = x[np.argsort(labels, kind="stable")]
    means = np.zeros((k, x.shape[1]), dtype=np.float32)
    for c in np.flatnonzero(counts):
        means[c] = grouped[ends[c] - counts[c] : ends[c]].sum(axis=0, dtype=np.float64) / counts[c]
    return means, counts
