"""The experiment runner, end to end with stand-in stages."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ssga_bench.config import TrainingConfig, validate_experiment
from ssga_bench.dataset import build_dataset
from ssga_bench.experiment import Timings, Views, run_experiment, training_cells
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.testing import WallWorkspaceSource


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    return build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=2, seed=4))


def experiment(stand_in_registry, **training):
    return validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
            "variants": ["PDS", "PD", "SD"],
            "fuser": {"name": "rrf"},
            "training": {"epochs": 3, "hidden": 16, **training},
        },
        stand_in_registry,
    )


@pytest.fixture
def stand_in_registry(ssga_plugin_set):
    from ssga_bench import testing
    from ssga_core.testing import stages

    ssga_plugin_set.load_entry_points()  # the installed fusers
    ssga_plugin_set.register(stages, "stand-ins")
    ssga_plugin_set.register(testing, "stand-in-workspaces")
    return ssga_plugin_set.registry()


def test_training_poses_cover_every_class_with_jittered_copies(dataset):
    config = TrainingConfig(synthetic_per_class=3, jitter_m=0.2, jitter_deg=4)
    cells = training_cells(dataset, config, Views(dataset, Timings()))
    reals = {s.place: s for s in dataset.split("train")}
    assert [c.real_class for c in cells] == list(reals)
    viewpoint = {s.place: s.pose for s in dataset.split("train") + dataset.split("target")}
    for cell in cells:
        assert cell.real.pose == reals[cell.real_class].pose
        # Every class of the cell: the real one gets 2 jittered copies, the others their viewpoint and 2 copies.
        first = cell.real_class - cell.real_class % 12
        assert sorted(cell.poses) == list(range(first, first + 12))
        for place, poses in cell.poses.items():
            assert len(poses) == (2 if place == cell.real_class else 3)
            v = viewpoint[place]
            if place != cell.real_class:
                assert poses[0] == v
            for pose in poses:
                assert math.hypot(pose.x - v.x, pose.y - v.y) <= 0.2 + 1e-9
                assert abs(math.remainder(pose.yaw - v.yaw, 2 * math.pi)) <= math.radians(4) + 1e-9


def test_runs_fuses_reports_and_resumes(tmp_path, dataset, stand_in_registry, monkeypatch):
    exp = experiment(stand_in_registry)
    report, timings = run_experiment(exp, dataset, tmp_path)
    for name in ("report.md", "results.csv", "results.png", "timings.json"):
        assert (tmp_path / name).exists()
    assert set(report.variants) == {"PC-ST (PDS)", "PC-ST (PD)", "PC (SD)"}
    assert (tmp_path / "variants" / "PC-ST_PDS" / "gcn.pt").exists()
    scores = np.load(tmp_path / "variants" / "PC-ST_PDS" / "scores.npy")
    assert scores.shape == (len(dataset.split("test")), dataset.num_classes)
    np.testing.assert_allclose(scores.sum(axis=1), 1.0, rtol=1e-5)
    assert {"parse", "describe", "synthesize", "train", "evaluate"} <= set(timings.seconds)

    # A second run trains nothing; a changed training config retrains.
    def no_training(*args, **kwargs):
        raise AssertionError("trained again")

    monkeypatch.setattr("ssga_bench.experiment.train_gcn", no_training)
    again, _ = run_experiment(exp, dataset, tmp_path)
    assert again.markdown() == report.markdown()
    with pytest.raises(AssertionError, match="trained again"):
        run_experiment(experiment(stand_in_registry, seed=1), dataset, tmp_path)


def test_the_feature_cache_parses_each_real_view_once(tmp_path, dataset, stand_in_registry, monkeypatch):
    from ssga_core.testing.stages import StripesParser

    parsed = []
    original = StripesParser._parse
    monkeypatch.setattr(StripesParser, "_parse", lambda self, view: parsed.append(view.synthetic) or original(self, view))
    run_experiment(experiment(stand_in_registry), dataset, tmp_path)
    # PDS and PD both parse every real view (tests and the training views); the cache makes it once each.
    assert len(parsed) == len(dataset.split("test")) + len(dataset.split("train"))
    assert not any(parsed)  # neither parses a synthetic view


def test_variants_without_s_train_every_class_of_a_cell_on_its_real_graph(tmp_path, dataset, stand_in_registry, monkeypatch):
    seen = {}

    def recording(graphs, labels, num_classes, config, progress=None):
        seen[len(seen)] = (list(graphs), list(labels))
        from ssga_bench.gcn import train_gcn

        return train_gcn(graphs, labels, num_classes, config)

    monkeypatch.setattr("ssga_bench.experiment.train_gcn", recording)
    exp = experiment(stand_in_registry)
    run_experiment(exp, dataset, tmp_path)
    graphs, labels = seen[1]  # PD, the second variant
    assert sorted(labels) == list(range(dataset.num_classes))
    assert len({id(g) for g in graphs}) == len(dataset.split("train"))  # one real graph per cell, repeated
    exp = experiment(stand_in_registry, real_for_every_class=False)
    run_experiment(exp, dataset, tmp_path / "real-only")
    assert sorted(seen[4][1]) == sorted(s.place for s in dataset.split("train"))
