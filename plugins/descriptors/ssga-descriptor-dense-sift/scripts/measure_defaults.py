"""Measure the dense-SIFT / bag-of-words defaults: is a region's node feature stable across views?

Protocol. Each *place* is a pair of 256 x 256 views of the same surface: view A, and
view B, the same content under a random similarity warp (shift up to 20 % of the view,
scale 0.85-1.15, rotation up to 8 degrees), a gain/bias change and pixel noise. The
warp is known, so every feature of B is assigned to the 4 x 4 grid cell of A it shows.
Nodes are the whole image and the 16 cells (parts with fewer than 2 features in A or
B are left out). The dictionary is fitted on the A views, as the pipeline fits it on
the training views.

Scores (higher is better, 1 is perfect), mean over 3 draws of the B warps:

* ``part``: mean reciprocal rank of a part's counterpart in B among all parts of all
  B views (Euclidean distance between node features);
* ``part@img``: the same, among the parts of its own B view only (spatial detail);
* ``image``: mean reciprocal rank of the place's B whole-image node among all B views.

Two sets of places: ``natural``, crops of scikit-image's sample photographs (needs
scikit-image), and ``walls``, :func:`ssga_core.testing.make_view` walls (flat
colour rectangles on a gradient). Run from the repository root::

    .venv/bin/python plugins/descriptors/ssga-descriptor-dense-sift/scripts/measure_defaults.py
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np
from ssga_descriptor_dense_sift.plugin import DenseSift, DenseSiftConfig

from ssga_core import Camera, Pose, View
from ssga_bench import BagOfWords, BoWConfig
from ssga_core.testing import make_view

SIZE = 256
CELLS = 4


@dataclass
class Place:
    a: np.ndarray  # (256, 256, 3) uint8
    b: np.ndarray
    b_to_a: np.ndarray  # (2, 3) affine: B pixel -> A pixel


def _similarity(centre: tuple[float, float], scale: float, angle_deg: float, shift: tuple[float, float]) -> np.ndarray:
    m = cv2.getRotationMatrix2D(centre, angle_deg, scale)
    m[:, 2] += shift
    return m


def _compose(m2: np.ndarray, m1: np.ndarray) -> np.ndarray:
    """``m2 @ m1`` for 2 x 3 affine maps."""
    a = np.vstack([m1, [0, 0, 1]])
    b = np.vstack([m2, [0, 0, 1]])
    return (b @ a)[:2]


def make_place(source: np.ndarray, window: tuple[float, float, float], rng: np.random.Generator) -> Place:
    """A: the square ``window`` (u0, v0, side) of ``source`` resized to 256; B: A's content warped, re-lit and noisy."""
    u0, v0, side = window
    s = SIZE / side
    src_to_a = np.array([[s, 0, -u0 * s], [0, s, -v0 * s]], dtype=np.float64)
    c = (SIZE / 2 - 0.5, SIZE / 2 - 0.5)
    a_to_b = _similarity(c, rng.uniform(0.85, 1.15), rng.uniform(-8, 8), tuple(rng.uniform(-0.2, 0.2, 2) * SIZE))
    src_to_b = _compose(a_to_b, src_to_a)
    flags = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    a = cv2.warpAffine(source, src_to_a, (SIZE, SIZE), flags=flags, borderMode=cv2.BORDER_REFLECT101)
    b = cv2.warpAffine(source, src_to_b, (SIZE, SIZE), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT101)
    b = b.astype(np.float32) * rng.uniform(0.7, 1.3) + rng.uniform(-25, 25) + rng.normal(0, 4, b.shape)
    return Place(a=a, b=np.clip(b, 0, 255).astype(np.uint8), b_to_a=cv2.invertAffineTransform(a_to_b))


def natural_sources() -> Iterator[np.ndarray]:
    import skimage.data as data

    names = ["astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field", "immunohistochemistry", "brick", "grass",
             "gravel", "camera", "retina", "moon", "coins", "horse", "colorwheel"]
    for name in names:
        img = getattr(data, name)()
        img = img.astype(np.uint8) if img.dtype == bool or img.max() > 1 else (img * 255).astype(np.uint8)
        yield np.repeat(img[..., None], 3, axis=2) if img.ndim == 2 else img[..., :3]
    left, _, _ = data.stereo_motorcycle()
    yield left


def places(kind: str, seed: int) -> list[Place]:
    rng = np.random.default_rng(seed)
    out = []
    if kind == "walls":
        for s in range(36):
            out.append(make_place(make_view(seed=100 + s).rgb, (0.0, 0.0, float(SIZE)), rng))
        return out
    for img in natural_sources():
        h, w = img.shape[:2]
        side = 0.55 * min(h, w)
        n = 3 if min(h, w) >= 500 else 2
        for i in range(n):
            # Windows spread along the longer side; deterministic so the A views do not change with the seed.
            t = (i + 0.5) / n
            out.append(make_place(img, ((w - side) * t, (h - side) * (1 - t), side), rng))
    return out


def _view(rgb: np.ndarray) -> View:
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(width=SIZE, height=SIZE))


def _cells(uv: np.ndarray) -> np.ndarray:
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] < SIZE - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < SIZE - 0.5)
    cell = (np.floor((uv[:, 1] + 0.5) * CELLS / SIZE) * CELLS + np.floor((uv[:, 0] + 0.5) * CELLS / SIZE)).astype(int)
    return np.where(inside, cell, -1)


def _mrr(query: np.ndarray, gallery: np.ndarray, truth: np.ndarray) -> float:
    d = ((query[:, None, :] - gallery[None, :, :]) ** 2).sum(-1)
    rank = (d < d[np.arange(len(query)), truth][:, None]).sum(1) + 1
    return float((1.0 / rank).mean())


def evaluate(extract: DenseSift, bow_config: BoWConfig, place_sets: list[list[Place]]) -> dict[str, float]:
    """Fit on the A views of the first set (A views are the same in every set), score every set."""
    feats_a = [extract.extract(_view(p.a)) for p in place_sets[0]]
    t = time.perf_counter()
    bow = BagOfWords(bow_config).fit(np.concatenate([f.descriptors for f in feats_a]))
    fit_s = time.perf_counter() - t
    scores: dict[str, list[float]] = {"part": [], "part@img": [], "image": []}
    for ps in place_sets:
        na, nb, owner = [], [], []
        whole_a, whole_b = [], []
        for i, (p, fa) in enumerate(zip(ps, feats_a, strict=True)):
            fb = extract.extract(_view(p.b))
            cell_a = _cells(fa.positions)
            uv = fb.positions @ p.b_to_a[:, :2].T + p.b_to_a[:, 2]
            cell_b = _cells(uv)
            members_a = [np.arange(len(fa))] + [np.flatnonzero(cell_a == c) for c in range(CELLS * CELLS)]
            members_b = [np.arange(len(fb))] + [np.flatnonzero(cell_b == c) for c in range(CELLS * CELLS)]
            pa = bow.pool(bow.encode(fa.descriptors), members_a)
            pb = bow.pool(bow.encode(fb.descriptors), members_b)
            whole_a.append(pa[0])
            whole_b.append(pb[0])
            for c in range(CELLS * CELLS):
                if len(members_a[c + 1]) >= 2 and len(members_b[c + 1]) >= 2:
                    na.append(pa[c + 1])
                    nb.append(pb[c + 1])
                    owner.append(i)
        na, nb, owner = np.array(na), np.array(nb), np.array(owner)
        truth = np.arange(len(na))
        scores["part"].append(_mrr(na, nb, truth))
        within = []
        for i in np.unique(owner):
            sel = np.flatnonzero(owner == i)
            within.append(_mrr(na[sel], nb[sel], np.arange(len(sel))) * len(sel))
        scores["part@img"].append(sum(within) / len(na))
        scores["image"].append(_mrr(np.array(whole_a), np.array(whole_b), np.arange(len(whole_a))))
    out = {k: float(np.mean(v)) for k, v in scores.items()}
    out["part_sd"] = float(np.std(scores["part"]))
    out["fit_s"] = fit_s
    return out


SWEEPS: list[tuple[str, dict, dict]] = [
    ("default", {}, {}),
    ("root_sift=True", {"root_sift": True}, {}),
    ("root_sift=False", {"root_sift": False}, {}),
    *[(f"similarity={m}", {}, {"similarity": m}) for m in ("nbnn", "centroid")],
    *[(f"prototypes={m}", {}, {"prototypes": m}) for m in (1, 4, 16, 32, 64, 256)],
    *[(f"top_n={n}", {}, {"top_n": n}) for n in (1, 3, 10, 30, None)],
    *[(f"rr_offset={c}", {}, {"rr_offset": c}) for c in (0.0, 1.0, 5.0, 60.0)],
    *[(f"norm={n}", {}, {"norm": n}) for n in ("l2", "l1", "none")],
    *[(f"k={k}", {}, {"k": k}) for k in (50, 100, 200)],
    *[(f"keypoint_size={s}", {"keypoint_size": s}, {}) for s in (8.0, 12.0, 16.0, 21.0, 24.0, 28.0, 32.0, 48.0)],
    *[(f"layout={x}", {"layout": x}, {}) for x in ("pnv", "uniform")],
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", nargs="+", default=["natural", "walls"])
    parser.add_argument("--draws", type=int, default=3)
    parser.add_argument("--only", nargs="*", default=None, help="sweep names to run (default: all)")
    parser.add_argument("--base", default="{}", help='JSON overrides of the defaults, e.g. {"root_sift": true, "bow": {"k": 50}}')
    args = parser.parse_args()
    base = DenseSiftConfig.model_validate(json.loads(args.base))
    for kind in args.sets:
        place_sets = [places(kind, seed) for seed in range(args.draws)]
        print(f"\n## {kind}: {len(place_sets[0])} places, {args.draws} draws of B")
        print("| setting | part (sd over draws) | part@img | image | fit s |\n|---|---|---|---|---|")
        for name, sift_changes, bow_changes in SWEEPS:
            if args.only and name not in args.only:
                continue
            bow = base.bow.model_copy(update=bow_changes)
            extract = DenseSift(base.model_copy(update={**sift_changes, "bow": bow}))
            r = evaluate(extract, BoWConfig.model_validate(bow.model_dump()), place_sets)
            print(f"| {name} | {r['part']:.3f} ({r['part_sd']:.3f}) | {r['part@img']:.3f} | {r['image']:.3f} | {r['fit_s']:.2f} |", flush=True)


if __name__ == "__main__":
    main()
