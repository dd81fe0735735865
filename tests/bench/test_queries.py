"""Per-query predictions (written and read back) and pictures of sample queries."""

from __future__ import annotations

import numpy as np
import pytest

from ssga_core.geometry import Pose
from ssga_core.testing import make_view
from ssga_bench.io import read_png
from ssga_bench.protocol import Sample
from ssga_bench.queries import GREEN, RED, draw_queries, load_predictions, pick_queries, save_predictions


def _tests(n):
    pose = [Pose(float(q), -1.0, 0.5) for q in range(n)]
    return [Sample(f"test-{q:03d}", "test", q % 4, 7, q % 4, pose[q], vo=40.0 + q, vo_landmark=10.0, level=1 + q % 3) for q in range(n)]


def test_predictions_round_trip(tmp_path):
    tests = _tests(3)
    truth = np.array([2, 0, 3])
    scores = np.array([[0.1, 0.2, 0.6, 0.1], [0.2, 0.3, 0.3, 0.2], [0.4, 0.3, 0.2, 0.1]])
    path = tmp_path / "predictions.jsonl"
    extra, groups = {"heading_gap": np.array([5.0, 70.0, 10.0])}, {"near": np.array([True, False, True])}
    save_predictions(path, tests, {"v": scores, "E": scores[:, ::-1]}, truth, k=2, extra=extra, groups=groups, ensemble="E")
    records = load_predictions(path)
    assert [r["id"] for r in records] == ["test-000", "test-001", "test-002"]
    first, second, third = records
    assert first["pose"] == {"x": 0.0, "y": -1.0, "yaw": 0.5} and first["level"] == 1
    assert first["vo"] == 40.0 and first["vo_landmark"] == 10.0
    assert first["groups"] == ["near"] and second["groups"] == [] and second["heading_gap"] == 70.0
    assert first["truth"] == 2 and first["rows"]["v"] == {"top": [2, 1], "scores": [0.6, 0.2], "rank": 1}
    assert second["rows"]["v"]["top"] == [1, 2] and second["rows"]["v"]["rank"] == 3  # ties: the lower class first
    assert third["rows"]["v"]["rank"] == 4 and third["rows"]["E"] == {"top": [3, 2], "scores": [0.4, 0.3], "rank": 1, "ensemble": True}
    assert not list(tmp_path.glob(".*.tmp"))  # written atomically


def test_pick_queries_is_seeded_and_balanced():
    correct = np.arange(100) % 4 == 0  # 25 right, 75 wrong
    picked = pick_queries(correct, 10, seed=1)
    assert len(set(picked)) == 10 and correct[picked].sum() == 5
    assert picked.tolist() == pick_queries(correct, 10, seed=1).tolist()
    few_right = np.arange(100) < 3
    assert few_right[pick_queries(few_right, 10)].sum() == 3  # too few right ones: the rest are wrong
    assert len(pick_queries(correct[:4], 10)) == 4


class _Views:
    def __init__(self):
        self.loaded = []

    def view(self, sample):
        self.loaded.append(sample.id)
        return make_view(seed=sample.place, size=64)


def test_draw_queries_writes_framed_pictures(tmp_path):
    tests = _tests(12)
    truth = np.array([s.place for s in tests])
    scores = np.eye(4)[truth] + 0.01
    scores[:6] = np.eye(4)[(truth[:6] + 1) % 4]  # the first six are wrong
    class_views = {c: Sample(f"class-{c}", "target", c, 7, c, Pose(0.0, 0.0, 0.0)) for c in range(4)}
    views = _Views()
    paths = draw_queries(tmp_path / "queries", views, tests, scores, truth, class_views, n=6)
    assert len(paths) == 6 and all(p.exists() for p in paths)
    assert sum("-wrong-" in p.name for p in paths) == 3 and sum("-right-" in p.name for p in paths) == 3
    for p in paths:
        picture = read_png(p, color=True)
        frame = tuple(picture[24, 1])  # the query tile's frame, below its caption
        assert frame == (GREEN if "-right-" in p.name else RED)
    assert len(set(views.loaded)) == len(views.loaded)  # each class view loaded once


@pytest.mark.parametrize("n", [0, 1])
def test_draw_few_queries(tmp_path, n):
    tests = _tests(2)
    truth = np.array([0, 1])
    class_views = {c: tests[0] for c in range(4)}
    assert len(draw_queries(tmp_path, _Views(), tests, np.eye(4)[truth], truth, class_views, n=n)) == n
