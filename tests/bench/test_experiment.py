"""The experiment runner, end to end with stand-in stages."""

from __future__ import annotations

import dataclasses
import json
import math
import re

import numpy as np
import shapely
import pytest

from ssga_bench.config import TrainingConfig, validate_experiment
from ssga_bench.dataset_build import build_dataset
from ssga_bench.experiment import Timings, Views, run_experiment, training_plan
from ssga_bench.training_plan import class_viewpoints, training_cells, training_protocol
from ssga_bench.protocol import Protocol
from ssga_bench.protocol import ProtocolConfig
from ssga_bench.protocol_plan import level_of
from ssga_bench.variant_training import _unused_options
from ssga_bench.testing import WallWorkspaceSource
from ssga_bench.visibility import view_overlap


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    return build_dataset(WallWorkspaceSource().open(), out, source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=2, seed=4))


def experiment(stand_in_registry, variants=("PDS", "PD", "SD"), **training):
    return validate_experiment(
        {
            "workspace": {"name": "test-wall"},
            "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
            "variants": list(variants),
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


def test_canonical_poses_are_each_class_viewpoint_and_jittered_copies(dataset):
    config = TrainingConfig(poses="canonical", sources="own", synthetic_per_class=3, jitter_m=0.2, jitter_deg=4)
    plan = training_plan(dataset, config, Views(dataset, Timings()))
    reals = {s.place: s for s in dataset.split("train")}
    assert [c.real_class for c in plan.cells] == list(reals)
    cells = training_cells(dataset, Views(dataset, Timings()))
    viewpoint = class_viewpoints(training_protocol(dataset, cells), dataset, cells)
    assert all(viewpoint[s.place] == s.pose for s in dataset.split("train"))
    by_place = {}
    for p, group in zip(plan.pseudo, plan.pose_groups):
        by_place.setdefault(p.place, []).append((p, group))
    assert sorted(by_place) == list(range(dataset.num_classes))
    for place, drawn in by_place.items():
        # The real class gets 2 jittered copies, the others their viewpoint and 2 copies, all of one pose group.
        assert len(drawn) == (2 if place in reals else 3)
        assert len({group for _, group in drawn}) == 1
        v = viewpoint[place]
        if place not in reals:
            assert drawn[0][0].pose == v
        for p, _ in drawn:
            assert p.sources == (place // 12,)  # its own cell's real view
            assert math.hypot(p.pose.x - v.x, p.pose.y - v.y) <= 0.2 + 1e-9
            assert abs(math.remainder(p.pose.yaw - v.yaw, 2 * math.pi)) <= math.radians(4) + 1e-9


def test_class_poses_belong_to_their_class_and_take_every_landmark_that_sees_them(dataset):
    config = TrainingConfig(poses="class", sources="seen", synthetic_per_class=2, max_sources=3, min_source_coverage=0.0)
    plan = training_plan(dataset, config, Views(dataset, Timings()))
    protocol = seen_protocol(dataset)
    assert len(set(plan.pose_groups)) == len(plan.pseudo)  # every pose is its own draw
    for p in plan.pseudo:
        cell = protocol.assign(np.array([[p.pose.x, p.pose.y]]), np.array([p.pose.yaw]))[0]
        assert dataset.plan.cells.index(cell) == p.place // 12
        assert protocol.orientation_of(p.pose.yaw) == p.place % 12
        assert p.sources[0] == p.place // 12 and len(set(p.sources)) == len(p.sources) <= 3
    assert any(len(p.sources) > 1 for p in plan.pseudo)


def seen_protocol(dataset):
    """The protocol on the floor the real views saw: what the training plan knows."""
    return training_protocol(dataset, training_cells(dataset, Views(dataset, Timings())))


def _pose_levels(dataset, plan):
    """Each class's pseudo-view levels, measured as the training plan measures them (on the seen floor)."""
    protocol = seen_protocol(dataset)
    cells = training_cells(dataset, Views(dataset, Timings()))
    polygons = protocol.level_reference_polygons(class_viewpoints(protocol, dataset, cells), [s.place for s in dataset.split("train")])
    levels: dict[int, list[int]] = {}
    for p in plan.pseudo:
        vo = view_overlap(protocol.polygon(p.pose), polygons[p.place])
        levels.setdefault(p.place, []).append(level_of(vo, dataset.plan.config.level_bounds))
    return levels


def test_poses_kept_for_the_rare_levels_are_at_them_and_the_classes_keep_their_count(dataset):
    views = Views(dataset, Timings())
    plain = _pose_levels(dataset, training_plan(dataset, TrainingConfig(poses="class", synthetic_per_class=9), views))
    kept_plan = training_plan(dataset, TrainingConfig(poses="class", synthetic_per_class=9, synthetic_per_level=3), views)
    kept = _pose_levels(dataset, kept_plan)
    # A class whose poses the real views never saw gets fewer; the kept slots take none from any class.
    assert sorted(kept) == sorted(plain) and all(len(kept[place]) == len(plain[place]) for place in kept)
    assert sum(len(v) == 9 for v in kept.values()) >= len(kept) // 2
    protocol = seen_protocol(dataset)
    for p in kept_plan.pseudo:  # still poses of their own class
        cell = protocol.assign(np.array([[p.pose.x, p.pose.y]]), np.array([p.pose.yaw]))[0]
        assert dataset.plan.cells.index(cell) == p.place // 12 and protocol.orientation_of(p.pose.yaw) == p.place % 12

    def rare(levels, level):
        return sum(lv.count(level) for lv in levels.values())

    # Drawn as test views are, most poses are at L1; the kept slots raise the rarer levels.
    assert rare(kept, 2) + rare(kept, 3) > rare(plain, 2) + rare(plain, 3)
    assert rare(kept, 3) > rare(plain, 3)


def test_a_level_no_pose_reaches_leaves_its_slots_to_any_pose(dataset):
    # Measured against a far-off speck every pose overlaps nothing (L3): the L2 slots wait, then
    # open, and each class still gets every pose it asked for.
    protocol = Protocol(dataset.floor_plan, dataset.camera, dataset.plan.config)
    speck = shapely.box(-1e3, -1e3, -1e3 + 0.01, -1e3 + 0.01)
    places = range(len(dataset.plan.cells) * 12)
    poses = protocol.class_poses(dataset.plan.cells, 3, 1.2, np.random.default_rng(0), per_level=1, level_polygons={p: speck for p in places})
    assert sorted(poses) == list(places) and all(len(p) == 3 for p in poses.values())


def test_training_reads_only_what_the_robot_has(dataset, monkeypatch):
    """The training plan reads no floor plan, no synthesis target and no view but the real ones."""
    from ssga_bench.dataset import Dataset

    def no_floor_plan(self):
        raise AssertionError("training read the workspace's floor plan")

    view, split = Dataset.view, Dataset.split
    monkeypatch.setattr(Dataset, "floor_plan", property(no_floor_plan))
    monkeypatch.setattr(Dataset, "view", lambda self, s, **kw: view(self, s, **kw) if s.split == "train" else pytest.fail(f"training read {s.id}"))
    monkeypatch.setattr(Dataset, "split", lambda self, name: split(self, name) if name == "train" else pytest.fail(f"training read the {name} split"))
    for poses in ("class", "canonical"):
        plan = training_plan(dataset, TrainingConfig(poses=poses, synthetic_per_class=3, synthetic_per_level=1), Views(dataset, Timings()))
        assert plan.pseudo and {p.place for p in plan.pseudo} <= set(range(dataset.num_classes))


def test_a_run_records_its_pseudo_views_and_none_stands_on_a_test_view(tmp_path, dataset, stand_in_registry):
    run_experiment(experiment(stand_in_registry, variants=("SD",)), dataset, tmp_path)
    records = [json.loads(line) for line in (tmp_path / "pseudo_views.jsonl").read_text().splitlines()]
    reals = {s.id for s in dataset.split("train")}
    assert records and all(set(r) == {"class", "pose", "sources"} and set(r["pose"]) == {"x", "y", "yaw"} for r in records)
    assert all(r["sources"] and set(r["sources"]) <= reals for r in records)
    tests = [json.loads(line) for line in (tmp_path / "predictions.jsonl").read_text().splitlines()]
    for r in records:
        for t in tests:
            if t["truth"] == r["class"]:
                apart = math.hypot(r["pose"]["x"] - t["pose"]["x"], r["pose"]["y"] - t["pose"]["y"])
                turn = abs(math.remainder(r["pose"]["yaw"] - t["pose"]["yaw"], 2 * math.pi))
                assert apart > 0.01 or turn > math.radians(0.5)


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
    # Every row is also scored by its place alone (the class's cell, whatever the heading), which
    # a Top-1 hit always has too.
    cells = dataset.place_cells
    assert cells is not None and all(cells[s.place] == s.cell for s in dataset.plan.samples)
    assert len(set(cells.tolist())) == dataset.num_classes // 12  # twelve headings a cell
    for label in report.variants:
        stats = report.rows[label].stats["all"]
        assert stats["top1"].value <= stats["loc1"].value <= 100
    assert "#### Top-1 of the location" in (tmp_path / "report.md").read_text()

    # A second run trains nothing; a changed training config retrains.
    def no_training(*args, **kwargs):
        raise AssertionError("trained again")

    def no_task(*args, **kwargs):
        raise AssertionError("a task ran again")

    monkeypatch.setattr("ssga_bench.variant_training.train_gcn", no_training)
    # Nor is a real view looked at again, nor a finished variant handed to a worker.
    monkeypatch.setattr("ssga_bench.tasks.describe_views", no_task)
    monkeypatch.setattr("ssga_bench.experiment.prepare_variant", no_task)
    monkeypatch.setattr("ssga_bench.experiment.score_chunk", no_task)
    again, _ = run_experiment(exp, dataset, tmp_path)
    assert again.markdown() == report.markdown()
    assert not (tmp_path / "scoring").exists()  # the scored chunks went once every variant's scores were written
    monkeypatch.undo()
    monkeypatch.setattr("ssga_bench.variant_training.train_gcn", no_training)
    with pytest.raises(AssertionError, match="trained again"):
        run_experiment(experiment(stand_in_registry, seed=1), dataset, tmp_path)


def test_parse_invented_retrains_only_the_orders_whose_parts_it_can_change(tmp_path, dataset, stand_in_registry, monkeypatch):
    def keys(out=tmp_path, **training):
        run_experiment(experiment(stand_in_registry, ("PSD", "SD", "PDS"), **training), dataset, out)
        return {d.name: json.loads((d / "training.json").read_text())["key"] for d in (out / "variants").iterdir()}

    before = keys()
    assert set(before) == {"PC-ST_PSD", "PC_SD", "PC-ST_PDS"}
    # describe_invented changes the orders that describe before S (PDS) and no other; while it is off,
    # every key is what it was before the option existed (the variant_key record without it).
    for option, changed in (("parse_invented", "PC-ST_PSD"), ("describe_invented", "PC-ST_PDS")):
        after = keys(**{option: True})
        assert before[changed] != after[changed], option
        assert {k: v for k, v in before.items() if k != changed} == {k: v for k, v in after.items() if k != changed}, option
    # Off, describe_invented and join_split_parts are left out of every key: the runs made before them resume.
    exp = experiment(stand_in_registry, ("PSD", "SD", "PDS"))
    for rv in exp.variants:
        assert {"describe_invented", "join_split_parts"} <= _unused_options(rv, TrainingConfig()), rv.label
        assert ("describe_invented" in _unused_options(rv, TrainingConfig(describe_invented=True))) != rv.variant.describes_before_synthesis
    # join_split_parts changes only the orders that carry parts through S, and only with a parser of
    # category pieces: with the stand-in's stripes it retrains nothing.
    assert keys(join_split_parts=True) == before
    from ssga_core.testing.stages import StripesParser

    stripes = StripesParser._parse
    monkeypatch.setattr(StripesParser, "regions_are_category_pieces", True)
    monkeypatch.setattr(StripesParser, "_parse", lambda self, view: dataclasses.replace(r := stripes(self, view), categories=np.arange(len(r), dtype=np.int32)))
    joined = keys(tmp_path / "pieces", join_split_parts=True)  # a cache of its own: the parser's output changed
    assert {name for name in before if joined[name] != before[name]} == {"PC-ST_PSD", "PC-ST_PDS"}


def test_a_training_setting_added_since_keeps_the_keys_of_earlier_runs(tmp_path, dataset, stand_in_registry, monkeypatch):
    def keys(out, **training):
        run_experiment(experiment(stand_in_registry, ("PSD", "SD"), classifier="graph-match", **training), dataset, out)
        return {d.name: json.loads((d / "training.json").read_text())["key"] for d in (out / "variants").iterdir()}

    plain = keys(tmp_path / "plain")
    assert TrainingConfig().unkeyed() == {"match_whiten", "match_whiten_parts", "match_whiten_variants", "match_category_penalty", "match_category_min_score"}
    whitened = keys(tmp_path / "whitened", match_whiten=1.0)
    assert set(whitened) == set(plain) and all(whitened[k] != plain[k] for k in plain)
    # The keys of a training section that never had the setting: what runs stored before it were keyed by.
    dump = TrainingConfig.model_dump
    later = TrainingConfig.added_since
    monkeypatch.setattr(TrainingConfig, "model_dump", lambda self, **kw: {k: v for k, v in dump(self, **kw).items() if k not in later})
    assert keys(tmp_path / "before") == plain


def test_parts_matched_within_their_category_retrain_only_the_variants_whose_parser_names_categories(tmp_path, dataset, stand_in_registry, monkeypatch):
    from ssga_bench.variant_training import load_classifier
    from ssga_core.testing.stages import StripesParser

    def run(out, **training):
        run_experiment(experiment(stand_in_registry, ("PSD", "SD", "PDS"), classifier="graph-match", **training), dataset, out)
        folders = {d.name: d for d in (out / "variants").iterdir()}
        return {name: json.loads((d / "training.json").read_text())["key"] for name, d in folders.items()}, folders

    plain, _ = run(tmp_path / "plain")
    assert run(tmp_path / "plain", match_category_penalty=2.0)[0] == plain  # stripes name no category: nothing retrained
    stripes = StripesParser._parse
    monkeypatch.setattr(StripesParser, "names_categories", True)
    monkeypatch.setattr(StripesParser, "_parse", lambda self, view: dataclasses.replace(r := stripes(self, view), categories=np.arange(len(r), dtype=np.int32) % 2))
    named, _ = run(tmp_path / "named")  # a cache of its own: the parser's output changed
    assert named == plain  # off, the setting is in no key
    within, folders = run(tmp_path / "named", match_category_penalty=2.0)
    assert {name for name in named if within[name] != named[name]} == {"PC-ST_PSD", "PC-ST_PDS"}
    for name, folder in folders.items():
        matcher = load_classifier(folder, "graph-match")
        assert (matcher.category_penalty == 2.0) == (name != "PC_SD"), name
        assert ("match_category_penalty" in json.loads((folder / "training.json").read_text())) == (name != "PC_SD"), name
        if name != "PC_SD":
            assert set(np.unique(matcher.categories)) == {-1, 0, 1}, name
    # The score floor is in no key without the penalty, and with it only in the keys the penalty is in.
    assert run(tmp_path / "named", match_category_min_score=0.5)[0] == named
    sure, folders = run(tmp_path / "named", match_category_penalty=2.0, match_category_min_score=0.5)
    assert {name for name in named if sure[name] != within[name]} == {"PC-ST_PSD", "PC-ST_PDS"}
    for name, folder in folders.items():
        assert (load_classifier(folder, "graph-match").category_min_score == 0.5) == (name != "PC_SD"), name
        assert json.loads((folder / "training.json").read_text()).get("match_category_min_score") == (None if name == "PC_SD" else 0.5), name


def test_whitening_only_the_synthesized_views_retrains_only_the_variants_that_describe_them(tmp_path, dataset, stand_in_registry):
    from ssga_bench.matching import GraphMatcher
    from ssga_bench.variant_training import load_classifier

    def run(out, **training):
        run_experiment(experiment(stand_in_registry, ("PSD", "SD", "PDS", "DS"), classifier="graph-match", **training), dataset, out)
        folders = {d.name: d for d in (out / "variants").iterdir()}
        return {name: json.loads((d / "training.json").read_text())["key"] for name, d in folders.items()}, folders

    plain, _ = run(tmp_path / "plain")
    every, _ = run(tmp_path / "every", match_whiten=1.0)
    synthesized, folders = run(tmp_path / "synthesized", match_whiten=1.0, match_whiten_variants="synthesized")
    describe_after_s = {"PC-ST_PSD", "PC_SD"}
    assert set(plain) == set(synthesized) == describe_after_s | {"PC-ST_PDS", "PC_DS"}
    assert {name for name in plain if synthesized[name] != plain[name]} == describe_after_s
    assert all(synthesized[name] != every[name] for name in describe_after_s)
    for name, folder in folders.items():
        matcher = load_classifier(folder, "graph-match")
        assert isinstance(matcher, GraphMatcher)
        assert (matcher.whiten is not None) == (name in describe_after_s), name



def test_carried_parts_are_whitened_in_groups_of_one_real_part_and_the_rest_as_the_whole_images(tmp_path, dataset, stand_in_registry):
    from ssga_bench.variant_training import load_classifier

    run_experiment(
        experiment(stand_in_registry, ("PSD", "SPD"), classifier="graph-match", match_whiten=1.0, match_whiten_parts="carried"), dataset, tmp_path
    )
    carried = load_classifier(tmp_path / "variants" / "PC-ST_PSD", "graph-match")
    groups = carried.part_groups
    assert carried.whiten_parts and groups is not None and len(groups) == len(carried._parts)
    # A group is one real part within one class, seen in the class's real view and its pseudo-views: several graphs each.
    owner = np.repeat(np.arange(len(carried.labels)), np.diff(carried.node_ptr) - 1)
    grouped = groups >= 0
    assert grouped.all()  # the stand-in synthesizer draws nothing of its own: every part is carried
    for g in np.unique(groups):
        members = owner[groups == g]
        assert len(set(carried.labels[members].tolist())) == 1 and len(set(members.tolist())) == len(members)
    assert max(np.bincount(groups)) > 1
    # SPD parses the synthetic views: no part is a real one, so its parts are whitened as the whole images are.
    parsed_after_s = load_classifier(tmp_path / "variants" / "PC-ST_SPD", "graph-match")
    assert parsed_after_s.whiten_parts and parsed_after_s.part_groups is None and parsed_after_s._part_whitening is None


def test_an_interrupted_scoring_resumes_with_the_chunks_it_had_not_scored(tmp_path, dataset, stand_in_registry, monkeypatch):
    from ssga_bench import experiment as runner

    monkeypatch.setattr(runner, "SCORE_CHUNK", 4)  # several chunks of this small dataset's views
    exp = experiment(stand_in_registry)
    whole, _ = run_experiment(exp, dataset, tmp_path / "whole")

    score_chunk, scored = runner.score_chunk, []

    def stops_at_the_third(job):
        if len(scored) == 2:
            raise KeyboardInterrupt
        scored.append(job.ids)
        return score_chunk(job)

    monkeypatch.setattr(runner, "score_chunk", stops_at_the_third)
    with pytest.raises(KeyboardInterrupt):
        run_experiment(exp, dataset, tmp_path / "cut")
    assert len(list((tmp_path / "cut" / "scoring").rglob("*.npz"))) == 2
    assert not (tmp_path / "cut" / "variants" / "PC-ST_PDS" / "scores.npy").exists()

    again = []
    monkeypatch.setattr(runner, "score_chunk", lambda job: again.append(job.ids) or score_chunk(job))
    monkeypatch.setattr("ssga_bench.variant_training.train_gcn", lambda *a, **k: pytest.fail("trained again"))
    resumed, _ = run_experiment(exp, dataset, tmp_path / "cut")
    assert not set(again) & set(scored) and again  # the two scored chunks were not scored again
    assert resumed.markdown() == whole.markdown()
    for name in ("scores.npy", "nn_scores.npy", "val_scores.npy"):
        assert (tmp_path / "cut" / "variants" / "PC_SD" / name).read_bytes() == (tmp_path / "whole" / "variants" / "PC_SD" / name).read_bytes()
    assert not (tmp_path / "cut" / "scoring").exists()


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

    def recording(graphs, labels, num_classes, config, progress=None, groups=None):
        seen[len(seen)] = (list(graphs), list(labels))
        from ssga_bench.gcn import train_gcn

        return train_gcn(graphs, labels, num_classes, config, groups=groups)

    def without_s(runs):
        # PD's training set, whichever order the variants ran in: only real graphs, one per cell, repeated.
        (found,) = [run for run in runs if len({id(g) for g in run[0]}) == len(dataset.split("train"))]
        return found

    monkeypatch.setattr("ssga_bench.variant_training.train_gcn", recording)
    exp = experiment(stand_in_registry)
    run_experiment(exp, dataset, tmp_path)
    graphs, labels = without_s(seen.values())
    assert sorted(labels) == list(range(dataset.num_classes))
    first_run = len(seen)  # the variants and the oracle
    exp = experiment(stand_in_registry, real_for_every_class=False)
    run_experiment(exp, dataset, tmp_path / "real-only")
    _, labels = without_s(list(seen.values())[first_run:])
    assert sorted(labels) == sorted(s.place for s in dataset.split("train"))


def test_the_pseudo_views_graphs_built_in_chunks_are_those_the_pipeline_builds_whole(tmp_path, dataset, stand_in_registry, monkeypatch):
    from ssga_bench import variant_training
    from ssga_core.pipeline import fitting_pseudo_views, training_graphs
    from ssga_core.testing.stages import PatchColour

    # A descriptor that learns in fit (the mean colour of its training views, taken off every
    # node): the chunks must describe with the state the variant's descriptor was fitted to.
    pool = PatchColour._pool

    def fit(self, views, labels=None):
        self.centre = np.mean([v.rgb.mean(axis=(0, 1)) / 255 for v in views], axis=0).astype(np.float32)

    monkeypatch.setattr(PatchColour, "fit", fit)
    monkeypatch.setattr(PatchColour, "state_dict", lambda self: {"centre": self.centre})
    monkeypatch.setattr(PatchColour, "load_state_dict", lambda self, state: setattr(self, "centre", state["centre"]))
    monkeypatch.setattr(PatchColour, "_pool", lambda self, features, members: pool(self, features, members) - self.centre)
    seen, chunks = {}, []
    fit_classifier, build = variant_training._fit_classifier, variant_training.pseudo_graphs

    def recording(graphs, labels, groups, num_classes, training, folder, part_groups=None):
        seen[folder.parent.name, folder.name] = (list(graphs), list(labels), groups.copy())  # variants/ or oracle/
        return fit_classifier(graphs, labels, groups, num_classes, training, folder, part_groups)

    monkeypatch.setattr("ssga_bench.variant_training._fit_classifier", recording)
    monkeypatch.setattr("ssga_bench.experiment.pseudo_graphs", lambda chunk: chunks.append(len(chunk.pseudo)) or build(chunk))
    monkeypatch.setattr("ssga_bench.experiment.PSEUDO_CHUNK", 2)
    exp = experiment(stand_in_registry)
    run_experiment(exp, dataset, tmp_path)

    plan = training_plan(dataset, exp.config.training, Views(dataset, Timings()))
    fitting = fitting_pseudo_views(plan.cells, plan.pseudo)
    # The pseudo-views the descriptors were fitted on are built where they were rendered; the rest, 2 per task.
    assert 0 < len(fitting) < len(plan.pseudo)
    assert sum(chunks) == len(plan.pseudo) - len(fitting) and max(chunks) == 2
    for rv in exp.variants:
        graphs, labels, groups = seen["variants", rv.label.replace(" (", "_").rstrip(")")]
        whole, whole_labels = training_graphs(rv.bind(), plan.cells, plan.pseudo)
        assert labels == whole_labels
        assert len(graphs) == len(whole) == len(groups)
        for got, want in zip(graphs, whole, strict=True):
            np.testing.assert_array_equal(got.features, want.features)
            np.testing.assert_array_equal(got.edges, want.edges)


def test_the_oracle_renders_the_truth_with_an_exact_point_map():
    from ssga_bench.oracle import TrueRender
    from ssga_core import Pose

    workspace = WallWorkspaceSource().open()
    source = workspace.render(Pose(0.0, 0.0, 0.0, workspace.camera_height))
    same = TrueRender(workspace).synthesize(source, source.pose)
    np.testing.assert_allclose(same.target_uv[same.visible], source.camera.pixel_grid()[same.visible], atol=1e-3)
    assert same.visible.mean() > 0.95 and same.view.synthetic
    # 0.3 m to the right of a wall 3 m ahead (the stand-in's flat wall): content moves 128 * 0.3 / 3 px left.
    moved = TrueRender(workspace).synthesize(source, Pose(0.0, -0.3, 0.0, workspace.camera_height))
    shift = moved.target_uv[moved.visible] - source.camera.pixel_grid()[moved.visible]
    np.testing.assert_allclose(shift, np.broadcast_to([-12.8, 0.0], shift.shape), atol=1e-2)
    assert 0.9 < moved.visible.mean() < 0.96  # the strip that left the image
    both = TrueRender(workspace).synthesize_from([source, source], moved.view.pose)
    assert both[0].view is both[1].view  # rendered once for every source


def test_a_descriptor_that_learns_without_a_state_is_refused_by_name():
    from ssga_bench.variant_training import fitted_state
    from ssga_core import PluginError
    from ssga_core.testing.stages import PatchColour

    class Forgetful(PatchColour):
        def fit(self, views, labels=None):
            self.learned = len(views)

    assert fitted_state(PatchColour()) == {}  # learns nothing: nothing to keep
    with pytest.raises(PluginError, match="descriptor 'test-patch-colour' .* learns in fit\\(\\) but its state_dict\\(\\) is empty"):
        fitted_state(Forgetful())


def test_graph_matching_classifies_without_training_a_network(tmp_path, dataset, stand_in_registry, monkeypatch):
    monkeypatch.setattr("ssga_bench.variant_training.train_gcn", lambda *a, **k: pytest.fail("a GCN was trained"))
    exp = experiment(stand_in_registry, classifier="graph-match", match_whole=0.25)
    report, _ = run_experiment(exp, dataset, tmp_path)
    folder = tmp_path / "variants" / "PC-ST_PDS"
    assert (folder / "matcher.npz").exists() and not (folder / "gcn.pt").exists()
    scores = np.load(folder / "scores.npy")
    np.testing.assert_allclose(scores.sum(axis=1), 1.0, rtol=1e-5)
    assert json.loads((folder / "training.json").read_text())["classifier"] == "graph-match"
    assert set(report.variants) == {"PC-ST (PDS)", "PC-ST (PD)", "PC (SD)"}
    again, _ = run_experiment(exp, dataset, tmp_path)  # finished: read back
    assert again.markdown() == report.markdown()


def test_parts_judged_where_drawn_keep_each_pseudo_views_drawn_grid_in_the_matcher(tmp_path, dataset, stand_in_registry):
    exp = experiment(
        stand_in_registry, classifier="graph-match", match_whole=0.0, match_standardise=True, match_drawn=True, match_drawn_prior=2.0, match_burst=0.9
    )
    run_experiment(exp, dataset, tmp_path)
    folder = tmp_path / "variants" / "PC-ST_PDS"
    record = json.loads((folder / "training.json").read_text())
    assert record["match_drawn"] is True and record["match_drawn_prior"] == 2.0
    assert record["match_burst"] == 0.9 and record["match_burst_power"] == 1.0
    state = np.load(folder / "matcher.npz")
    assert float(state["drawn_prior"]) == 2.0
    assert float(state["burst"]) == pytest.approx(0.9) and float(state["burst_power"]) == 1.0
    drawn, real = state["drawn"], len(dataset.split("train"))
    assert drawn.shape == (len(state["labels"]), 16, 16)
    assert (drawn[:real] == 1).all()  # the real views: all of them seen
    assert drawn[real:].min() < 1  # the stand-in synthesizer's sideways moves leave holes
    plain = tmp_path / "plain"
    run_experiment(experiment(stand_in_registry, classifier="graph-match", match_whole=0.0, match_standardise=True), dataset, plain)
    assert not {"drawn", "burst"} & set(np.load(plain / "variants" / "PC-ST_PDS" / "matcher.npz").files)
    assert not np.array_equal(np.load(plain / "variants" / "PC-ST_PDS" / "scores.npy"), np.load(folder / "scores.npy"))


def _with_validation_views(tmp_path, registry, fusion):
    """A wall workspace with validation views, and three graph-matching variants fused as ``fusion`` says."""
    validated = build_dataset(
        WallWorkspaceSource().open(), tmp_path / "ds", source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=2, val_per_class=2, seed=4)
    )
    config = {
        "workspace": {"name": "test-wall"},
        "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
        "variants": ["PDS", "PD", "SD"],
        "protocol": {"val_per_class": 2},
        "training": {"classifier": "graph-match"},
    }
    return validated, validate_experiment({**config, **fusion}, registry)


def _stored_scores(out):
    """The validation and test scores each of :func:`_with_validation_views`'s variants stored under ``out``."""
    folders = {"PC-ST (PDS)": "PC-ST_PDS", "PC-ST (PD)": "PC-ST_PD", "PC (SD)": "PC_SD"}
    return tuple({label: np.load(out / "variants" / f / name) for label, f in folders.items()} for name in ("val_scores.npy", "scores.npy"))


def test_a_fusion_learned_on_validation_is_reported_beside_the_papers(tmp_path, stand_in_registry):
    from ssga_fuser_stacking.plugin import Stacking

    from ssga_bench.evaluation import truth_ranks

    validated, exp = _with_validation_views(tmp_path, stand_in_registry, {"ensemble": {"also": [{"name": "stacking"}]}})
    report, _ = run_experiment(exp, validated, tmp_path / "out")
    row = "Ensemble (STK) of all, learned on validation"
    assert row in report.rows and row in report.markdown()
    assert "Ensemble (RRF)" in report.rows  # the paper's fusion stays the ensemble row
    learned = json.loads((tmp_path / "out" / "fusion.json").read_text())["Ensemble (STK)"]
    assert learned["members"] == ["PC-ST (PDS)", "PC-ST (PD)", "PC (SD)"]

    # The row is the rule fitted on the validation views' scores, fusing the test views'.
    folders = ["PC-ST_PDS", "PC-ST_PD", "PC_SD"]
    val = np.stack([np.load(tmp_path / "out" / "variants" / f / "val_scores.npy") for f in folders])
    test = np.stack([np.load(tmp_path / "out" / "variants" / f / "scores.npy") for f in folders])
    by_hand = Stacking()
    by_hand.fit(val, np.array([s.place for s in validated.split("val")]))
    np.testing.assert_allclose(by_hand.weights, learned["weights"], atol=1e-6)
    truth = np.array([s.place for s in validated.split("test")])
    np.testing.assert_array_equal(report.true_ranks[row], truth_ranks(by_hand.fuse(test), truth))

    # The predictions hold every row of the report, the ensemble's marked, for `ssga compare`.
    records = [json.loads(line) for line in (tmp_path / "out" / "predictions.jsonl").read_text().splitlines()]
    entries = records[0]["rows"]
    assert set(entries) == set(report.rows) - {"random"} - {label for label in report.rows if label.startswith("best single")}
    assert [label for label, entry in entries.items() if entry.get("ensemble")] == ["Ensemble (RRF)"]
    assert [r["rows"][row]["rank"] for r in records] == report.true_ranks[row].tolist()

    # Without the learned rule, a rerun leaves no stale weights behind.
    plain = validate_experiment({**exp.config.model_dump(mode="json", exclude={"ensemble"}), "output": str(tmp_path / "out")}, stand_in_registry)
    again, _ = run_experiment(plain, validated, tmp_path / "out")
    assert row not in again.rows and not (tmp_path / "out" / "fusion.json").exists()


def test_a_learned_ensemble_row_keeps_the_papers_fusion_beside_it_over_all_and_over_the_chosen(tmp_path, stand_in_registry):
    from ssga_fuser_rrf.plugin import ReciprocalRankFusion

    from ssga_bench.evaluation import truth_ranks
    from ssga_bench.fusion import choose_members

    validated, exp = _with_validation_views(tmp_path, stand_in_registry, {"fuser": {"name": "stacking"}, "ensemble": {"also": [{"name": "rrf"}]}})
    report, _ = run_experiment(exp, validated, tmp_path / "out")
    assert report.ensemble == "Ensemble (STK)"
    val, test = _stored_scores(tmp_path / "out")
    rrf = ReciprocalRankFusion()
    members = choose_members(val, np.array([s.place for s in validated.split("val")]), rrf)
    chosen = f"Ensemble (RRF) of {len(members)} chosen on validation: " + ", ".join(members)
    truth = np.array([s.place for s in validated.split("test")])
    for row, fused in ((chosen, rrf.fuse(np.stack([test[m] for m in members]))), ("Ensemble (RRF) of all", rrf.fuse(np.stack(list(test.values()))))):
        assert report.rows[row].kind == "reference"
        np.testing.assert_array_equal(report.true_ranks[row], truth_ranks(fused, truth))
    assert report.rows[chosen].key == "Ensemble (RRF) chosen on validation"  # one row across seeds, whatever each chose


def test_forward_selection_by_level_keeps_the_member_that_holds_up_on_the_few_hard_views():
    """Ten easy (L1) validation views and two hard (L3) ones, the truth class 0 of three: 'easy' ranks
    it first on the easy views and last on the hard ones, 'hard' second and first."""
    from ssga_fuser_rrf.plugin import ReciprocalRankFusion

    from ssga_bench.fusion import choose_members

    levels = np.array([1] * 10 + [3] * 2)
    easy = np.array([[0.9, 0.05, 0.05]] * 10 + [[0.0, 0.9, 0.1]] * 2)
    hard = np.array([[0.4, 0.5, 0.1]] * 10 + [[0.9, 0.05, 0.05]] * 2)
    scores, truth, rrf = {"easy": easy, "hard": hard}, np.zeros(12, int), ReciprocalRankFusion()
    # Over all views 'easy' leads (MRR 0.89 against 0.58) and 'hard' still adds to it (0.92: both hard views move up to second).
    assert choose_members(scores, truth, rrf) == ["easy", "hard"]
    # Each level counting equally, 'hard' leads (0.75 against 0.67) and 'easy' adds nothing (the levels' mean stays 0.75).
    assert choose_members(scores, truth, rrf, levels) == ["hard"]
    # One level is no level at all: the plain choice.
    assert choose_members(scores, truth, rrf, np.ones(12, int)) == ["easy", "hard"]


def test_the_ensemble_chosen_with_each_level_equal_says_so_and_is_what_forward_selection_by_level_chose(tmp_path, stand_in_registry):
    from ssga_fuser_rrf.plugin import ReciprocalRankFusion

    from ssga_bench.evaluation import truth_ranks
    from ssga_bench.fusion import choose_members

    validated, exp = _with_validation_views(tmp_path, stand_in_registry, {"ensemble": {"members": "validation", "selection": "levels"}})
    report, _ = run_experiment(exp, validated, tmp_path / "out")
    val, test = _stored_scores(tmp_path / "out")
    vals = validated.split("val")
    assert len({s.level for s in vals}) > 1  # else the choice by level could not differ from the plain one
    members = choose_members(val, np.array([s.place for s in vals]), ReciprocalRankFusion(), np.array([s.level or 0 for s in vals]))
    assert report.ensemble == f"Ensemble (RRF) of {len(members)} chosen on validation, each level equal: " + ", ".join(members)
    truth = np.array([s.place for s in validated.split("test")])
    fused = ReciprocalRankFusion().fuse(np.stack([test[m] for m in members]))
    np.testing.assert_array_equal(report.true_ranks[report.ensemble], truth_ranks(fused, truth))
    assert report.rows[report.ensemble].key == "Ensemble (RRF) chosen on validation, each level equal"


@pytest.mark.parametrize(
    ("config", "problem"),
    [
        ({"ensemble": {"also": [{"name": "stacking"}]}}, "ensemble.also.0: fuser 'stacking' is learned on the validation views; set protocol.val_per_class > 0"),
        ({"fuser": {"name": "stacking"}}, "fuser: fuser 'stacking' is learned on the validation views"),
        (
            {"fuser": {"name": "stacking"}, "protocol": {"val_per_class": 1}, "ensemble": {"members": "validation"}},
            "ensemble.members: fuser 'stacking' weighs its members itself",
        ),
    ],
)
def test_a_learned_fusion_without_validation_views_is_refused_before_anything_runs(stand_in_registry, config, problem):
    from ssga_core import ConfigError

    with pytest.raises(ConfigError, match=re.escape(problem)):
        validate_experiment({"workspace": {"name": "test-wall"}, "variants": ["SD"], **config}, stand_in_registry)


def test_packaged_weights_on_another_kind_of_workspace_are_flagged_in_the_report(tmp_path, dataset, ssga_plugin_set, monkeypatch):
    from ssga_bench import testing
    from ssga_bench.learned import Learned, LearnedConfig
    from ssga_core.testing import stages
    from ssga_core.testing.stages import PatchColour

    packaged = tmp_path / "weights"
    packaged.mkdir()
    (packaged / "light.pt").write_bytes(b"")

    class TrainedHere(Learned, PatchColour):
        """PatchColour standing in for a learned descriptor that ships weights trained on procedural homes."""

        name = "test-trained-here"
        Config = LearnedConfig
        packaged_weights = packaged
        trained_on = "procedural"

    ssga_plugin_set.load_entry_points()
    trained_here = testing.plugin_with(TrainedHere, hook="ssga_register_descriptors")
    for module, name in ((stages, "stand-ins"), (testing, "stand-in-workspaces"), (trained_here, "trained-here")):
        ssga_plugin_set.register(module, name)
    config = {
        "workspace": {"name": "test-wall"},
        "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-trained-here", "weights": "light.pt"}, "synthesizer": {"name": "test-shift"}},
        "variants": ["SD", "PD"],
        "training": {"classifier": "graph-match"},
    }
    report, _ = run_experiment(validate_experiment(config, ssga_plugin_set.registry()), dataset, tmp_path / "out")
    flagged = {label: row.flags for label, row in report.rows.items() if row.flags}
    assert set(flagged) >= {"PC (SD)", "PC-ST (PD)"}
    assert "descriptor 'test-trained-here' runs the weights trained here on procedural homes (light.pt), not on views like this 'test-wall' workspace's" in report.markdown()
