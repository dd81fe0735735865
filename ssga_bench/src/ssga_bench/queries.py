"""Per-query results: every test view's predictions in a file, and pictures of a few queries.

The tables say how often a row is right; these say on which views and how it is wrong.
``predictions.jsonl`` has one line per test view (read it back with
:func:`load_predictions`); :func:`draw_queries` draws a fixed, seeded sample of correct
and wrong queries (as VPR-methods-evaluation's ``--num_preds_to_save`` does): the query,
its true class's training view and the top three predicted classes' views, framed green
where the class is right and red where it is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from ssga_core.data import View
from ssga_bench.evaluation import truth_ranks
from ssga_bench.io import make_folder, read_jsonl, write_jsonl, write_png
from ssga_bench.protocol import Sample


def top_k(scores: np.ndarray, k: int) -> np.ndarray:
    """``(Q, k)`` best classes per query, ties broken by class index as :func:`truth_ranks` does."""
    return np.argsort(-np.asarray(scores), axis=-1, kind="stable")[:, :k]


def prediction_records(
    tests: Sequence[Sample],
    rows: Mapping[str, np.ndarray],
    truth: np.ndarray,
    k: int = 5,
    groups: Mapping[str, np.ndarray] | None = None,
    extra: Mapping[str, Sequence[Any]] | None = None,
    ensemble: str | None = None,
) -> list[dict[str, Any]]:
    """One record per test view; see :func:`save_predictions`."""
    truth = np.asarray(truth)
    groups, extra = dict(groups or {}), dict(extra or {})
    if ensemble is not None and ensemble not in rows:
        raise ValueError(f"the ensemble row {ensemble!r} is not among the rows")
    ranked = {label: (top_k(s, k), truth_ranks(s, truth), np.asarray(s)) for label, s in rows.items()}
    records = []
    for q, sample in enumerate(tests):
        predictions = {
            label: {
                "top": best[q].tolist(),
                "scores": [round(float(s[q, c]), 6) for c in best[q]],
                "rank": int(rank[q]),
                **({"ensemble": True} if label == ensemble else {}),
            }
            for label, (best, rank, s) in ranked.items()
        }
        records.append(
            {
                "id": sample.id,
                "pose": {"x": sample.pose.x, "y": sample.pose.y, "yaw": sample.pose.yaw},
                "level": sample.level,
                "vo": sample.vo,
                "vo_landmark": sample.vo_landmark,
                "groups": [g for g, mask in groups.items() if mask[q]],
                "truth": int(truth[q]),
                **{key: _plain(values[q]) for key, values in extra.items()},
                "rows": predictions,
            }
        )
    return records


def _plain(value: Any) -> Any:
    """A numpy scalar as the Python value JSON can hold."""
    return value.item() if isinstance(value, np.generic) else value


def save_predictions(
    path: str | Path,
    tests: Sequence[Sample],
    rows: Mapping[str, np.ndarray],
    truth: np.ndarray,
    k: int = 5,
    extra: Mapping[str, Sequence[Any]] | None = None,
    *,
    groups: Mapping[str, np.ndarray] | None = None,
    ensemble: str | None = None,
) -> None:
    """Write one JSON line per test view, atomically.

    Each line: ``id``, ``pose`` (x, y, yaw), ``level``, ``vo``, ``vo_landmark``, ``groups``
    (the names of the ``groups`` masks the view is in, e.g. ``["near"]``), ``truth`` (its
    class), any ``extra`` per-view values under their own keys, and ``rows``: per row label
    (each variant, the ensemble, the other fusions and references) the ``top`` ``k``
    classes, their ``scores`` and the ``rank`` of the true class; the ensemble row's entry
    also has ``"ensemble": true``.

    Args:
        tests: the test views, in the order of the scores' rows.
        rows: ``(Q, C)`` scores per row label.
        ensemble: the label of the run's ensemble row, one of ``rows``.
    """
    write_jsonl(path, prediction_records(tests, rows, truth, k, groups, extra, ensemble))


def load_predictions(path: str | Path) -> list[dict[str, Any]]:
    return list(read_jsonl(path))


class ViewSource(Protocol):
    """What :func:`draw_queries` needs of a dataset (:class:`ssga_bench.dataset.Dataset` has it)."""

    def view(self, sample: Sample) -> View: ...


GREEN, RED, GREY = (40, 170, 60), (210, 40, 40), (128, 128, 128)
TILE = 160
"""Height of each image in a picture, pixels."""


def pick_queries(correct: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """A fixed sample of ``n`` query indices, half wrong and half correct where there are enough of each."""
    rng = np.random.default_rng(seed)
    wrong, right = np.flatnonzero(~correct), np.flatnonzero(correct)
    n = min(n, len(correct))
    take_wrong = min(len(wrong), max(n - len(right), (n + 1) // 2))  # mistakes first: they say more
    picked = [rng.choice(wrong, take_wrong, replace=False), rng.choice(right, n - take_wrong, replace=False)]
    return np.sort(np.concatenate(picked)).astype(int)


def _tile(rgb: np.ndarray, caption: str, frame: tuple[int, int, int]) -> np.ndarray:
    """The image scaled to :data:`TILE` pixels high, framed in ``frame`` colour, with a caption above."""
    h, w = rgb.shape[:2]
    image = cv2.resize(rgb, (max(1, round(w * TILE / h)), TILE), interpolation=cv2.INTER_AREA)
    image = cv2.copyMakeBorder(image, 4, 4, 4, 4, cv2.BORDER_CONSTANT, value=frame)
    strip = np.full((22, image.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, caption, (4, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([strip, image])


def _row(tiles: list[np.ndarray]) -> np.ndarray:
    gap = np.full((tiles[0].shape[0], 6, 3), 255, np.uint8)
    return np.hstack([part for t in tiles for part in (t, gap)][:-1])


def draw_queries(
    folder: str | Path,
    dataset: ViewSource,
    tests: Sequence[Sample],
    scores: np.ndarray,
    truth: np.ndarray,
    class_views: Mapping[int, Sample],
    n: int = 10,
    seed: int = 0,
) -> list[Path]:
    """Draw ``n`` sample queries of one row's ``(Q, C)`` scores as PNGs in ``folder``; returns their paths.

    Each picture: the query (green if its top class is right, red if not), its true
    class's view, then the top three classes' views with their index and score, each
    green if it is the true class and red if not. ``class_views`` gives the view that
    stands for each class (the cell's real training view for its real class, the
    synthesis target's render for the others). Files are ``<nn>-<right|wrong>-<id>.png``.
    """
    truth, scores = np.asarray(truth), np.asarray(scores)
    best = top_k(scores, 3)
    correct = best[:, 0] == truth
    folder = make_folder(folder)
    images: dict[str, np.ndarray] = {}  # the same class views recur from query to query

    def rgb(sample: Sample) -> np.ndarray:
        if sample.id not in images:
            images[sample.id] = dataset.view(sample).rgb
        return images[sample.id]

    paths = []
    for i, q in enumerate(pick_queries(correct, n, seed)):
        test, t = tests[q], int(truth[q])
        tiles = [
            _tile(rgb(test), f"query {test.id} L{test.level}", GREEN if correct[q] else RED),
            _tile(rgb(class_views[t]), f"true class {t}", GREY),
        ]
        tiles += [
            _tile(rgb(class_views[int(c)]), f"#{r} class {c}: {scores[q, c]:.3f}", GREEN if c == t else RED)
            for r, c in enumerate(best[q], 1)
        ]
        path = folder / f"{i:02d}-{'right' if correct[q] else 'wrong'}-{test.id}.png"
        write_png(path, _row(tiles))
        paths.append(path)
    return paths
