"""The heading prior: a view's heading modulo 90 from its straight lines, the room's frame, the
prior, and the driver applying it to every row alike."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ssga_bench import heading
from ssga_bench.heading import HomeFrame, apply_prior, heading_mod_90, heading_prior, home_frame
from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose

CAMERA = Camera(width=256, height=256, hfov_deg=90.0)


def room_picture(pose: Pose, room_turn_deg: float, camera: Camera = CAMERA) -> np.ndarray:
    """A grey picture of a room's straight edges as ``pose`` sees them: a 8 x 6 m box turned by
    ``room_turn_deg``, its floor and ceiling edges (2.6 m) and floor planks every 0.5 m."""
    import cv2

    turn = math.radians(room_turn_deg)
    axis_a, axis_b = np.array([math.cos(turn), math.sin(turn)]), np.array([-math.sin(turn), math.cos(turn)])
    centre = np.array([pose.x, pose.y]) + 0.5 * axis_a

    def at(a: float, b: float, z: float) -> np.ndarray:
        xy = centre + a * axis_a + b * axis_b
        return np.array([xy[0], xy[1], z])

    segments = []
    corners = [(-4, -3), (4, -3), (4, 3), (-4, 3)]
    for z in (0.0, 2.6):
        segments += [(at(*corners[i], z), at(*corners[(i + 1) % 4], z)) for i in range(4)]
    segments += [(at(a, -3, 0.0), at(a, 3, 0.0)) for a in np.arange(-3.5, 4.0, 0.5)]
    image = np.full((camera.height, camera.width, 3), 160, np.uint8)
    for start, end in segments:
        points = pose.to_camera(np.linspace(start, end, 400))
        uv, z = camera.project(points)
        visible = z > 0.2
        runs = np.split(np.arange(len(z)), np.flatnonzero(np.diff(visible.astype(int))) + 1)
        for run in runs:
            if visible[run[0]] and len(run) > 1:
                cv2.polylines(image, [np.round(uv[run]).astype(np.int32)], False, (40, 40, 40), 2, cv2.LINE_AA)
    return image


@pytest.mark.parametrize("yaw_deg, turn_deg", [(0.0, 0.0), (17.0, 0.0), (44.0, 10.0), (200.0, 33.0), (-75.0, 5.0)])
def test_the_heading_modulo_90_is_read_from_a_rooms_lines(yaw_deg, turn_deg):
    pose = Pose(x=0.3, y=-0.2, yaw=math.radians(yaw_deg), height=1.5)
    estimate = heading_mod_90(room_picture(pose, turn_deg), CAMERA)
    assert estimate is not None
    expected = (yaw_deg - turn_deg) % 90.0
    assert abs((estimate - expected + 45.0) % 90.0 - 45.0) < 1.0


def test_a_picture_without_straight_lines_reads_no_heading_and_a_wrong_shape_is_refused():
    assert heading_mod_90(np.full((256, 256, 3), 120, np.uint8), CAMERA) is None
    with pytest.raises(InputError, match="256x256x3"):
        heading_mod_90(np.zeros((100, 256, 3), np.uint8), CAMERA)


def test_the_rooms_frame_comes_from_views_of_known_heading_and_needs_them_to_agree():
    yaws = np.radians([0.0, 30.0, 120.0, 275.0])
    frame = home_frame([(math.degrees(y) + 12.0) % 90.0 for y in yaws], yaws)
    assert frame is not None and frame.offset_deg == pytest.approx(12.0) and frame.views == 4 and frame.agreement == pytest.approx(1.0)
    # Across the fold: offsets of 89 and 1 degree agree on 0.
    frame = home_frame([89.0, 1.0], [0.0, 0.0])
    assert frame is not None and min(frame.offset_deg, 90.0 - frame.offset_deg) == pytest.approx(0.0, abs=1e-6)
    assert home_frame([10.0, None], [0.0, 0.0]) is None  # one view is no frame
    assert home_frame([0.0, 22.5, 45.0, 67.5], [0.0] * 4) is None  # spread round the circle: no room directions


def test_the_prior_keeps_a_class_and_its_two_neighbours_apart():
    headings = np.arange(12) * 30.0  # one cell's 12 classes
    frame = HomeFrame(offset_deg=12.0, agreement=1.0, views=4)
    # A view at heading 62 degrees (class 2) in a room turned so that its estimate reads 62 + 12.
    prior = heading_prior([(62.0 + 12.0) % 90.0, None], frame, headings, window_deg=15.0, sigma_deg=2.0, mix=0.05)
    assert prior.shape == (2, 12)
    np.testing.assert_allclose(prior.sum(axis=1), 1.0)
    best = set(np.flatnonzero(prior[0] > 0.2))
    assert best == {2, 5, 8, 11}  # 62 degrees modulo 90: the class and those 90, 180 and 270 degrees on
    assert prior[0, 1] < 0.01 and prior[0, 3] < 0.01 and prior[0, 1] >= 0.05 / 12  # neighbours lowered, never ruled out
    np.testing.assert_allclose(prior[1], 1.0 / 12)  # no estimate: uniform


def test_the_prior_multiplies_scores_keeping_each_views_order_when_they_are_not_probabilities():
    prior = np.array([[0.5, 0.25, 0.25], [1 / 3, 1 / 3, 1 / 3]])
    np.testing.assert_allclose(apply_prior(np.array([[0.2, 0.4, 0.4], [0.1, 0.2, 0.7]]), prior), [[0.1, 0.1, 0.1], [0.1 / 3, 0.2 / 3, 0.7 / 3]])
    signed = apply_prior(np.array([[-1.0, 2.0, 0.5], [3.0, 2.0, 1.0]]), prior)
    assert signed.min() >= 0.0
    assert list(np.argsort(-signed[1])) == [0, 1, 2]  # a uniform prior keeps the order
    with pytest.raises(InputError, match="shape"):
        apply_prior(np.zeros((2, 4)), prior)


def test_the_run_applies_the_prior_to_every_row_and_records_it(tmp_path, monkeypatch, stand_ins):
    from ssga_bench.config import validate_experiment
    from ssga_bench.dataset_build import build_dataset
    from ssga_bench.evaluation import truth_ranks
    from ssga_bench.experiment import run_experiment
    from ssga_bench.protocol import ProtocolConfig
    from ssga_bench.testing import WallWorkspaceSource

    registry = stand_ins  # the stand-in stages and workspace, and the installed fusers (stacking)
    dataset = build_dataset(
        WallWorkspaceSource().open(), tmp_path / "ds", source={"name": "test-wall"}, protocol=ProtocolConfig(cells=2, test_per_class=2, val_per_class=2, seed=4)
    )
    config = {
        "workspace": {"name": "test-wall"},
        "stages": {"parser": {"name": "test-stripes"}, "descriptor": {"name": "test-patch-colour"}, "synthesizer": {"name": "test-shift"}},
        "variants": ["PD", "SD"],
        "protocol": {"val_per_class": 2},
        "training": {"classifier": "graph-match"},
        "fuser": {"name": "stacking"},
        "prior": {"heading": "manhattan"},
    }
    out = tmp_path / "out"
    # The stand-in wall draws no straight edges: no frame, and the run says so and scores as it is.
    plain, _ = run_experiment(validate_experiment(config, registry), dataset, out)
    assert plain.notes and "No heading prior" in plain.notes[0] and not (out / "heading.json").exists()
    assert "No heading prior" in (out / "report.md").read_text()
    raw = {label: np.load(out / "variants" / folder / "scores.npy") for label, folder in (("PC-ST (PD)", "PC-ST_PD"), ("PC (SD)", "PC_SD"))}
    truth = np.array([s.place for s in dataset.split("test")])
    for label, scores in raw.items():
        np.testing.assert_array_equal(plain.true_ranks[label], truth_ranks(scores, truth))

    # A room that reads: every view's estimate its true heading plus a room turned by 12 degrees.
    monkeypatch.setattr(heading, "view_heading", lambda view: (math.degrees(view.pose.yaw) + 12.0) % 90.0)
    report, _ = run_experiment(validate_experiment(config, registry), dataset, out)
    record = json.loads((out / "heading.json").read_text())
    assert record["frame_deg"] == pytest.approx(12.0, abs=1e-3) and record["real_views_read"] == len(dataset.split("train"))
    assert record["validation_views_within_2_deg"] == record["validation_views_read"] == len(dataset.split("val"))
    assert set(record["estimates"]) == {s.id for split in ("train", "test", "val") for s in dataset.split(split)}
    assert "heading prior" in report.notes[0] and "heading prior" in (out / "report.md").read_text()
    headings = np.array([next(s.orientation for s in dataset.plan.samples if s.place == c) * 30.0 for c in range(dataset.num_classes)])
    prior = heading_prior([record["estimates"][s.id] for s in dataset.split("test")], HomeFrame(12.0, 1.0, 2), headings, 15.0, 2.0, 0.05)
    for label, scores in raw.items():  # the variants' stored scores are the raw ones; the report's carry the prior
        np.testing.assert_array_equal(report.true_ranks[label], truth_ranks(apply_prior(scores, prior), truth))
    nearest = next(label for label in report.rows if label.startswith("nearest neighbour"))
    assert report.rows[nearest].stats["all"]["mrr"].value >= plain.rows[nearest].stats["all"]["mrr"].value
    # The prior knows each class's heading modulo 90: with the truth's headings, every row's Top-1 rises or holds.
    for label in raw:
        assert report.rows[label].stats["all"]["top1"].value >= plain.rows[label].stats["all"]["top1"].value

    # Turned off again, the run leaves no stale record.
    config["prior"] = {"heading": "none"}
    again, _ = run_experiment(validate_experiment(config, registry), dataset, out)
    assert not again.notes and not (out / "heading.json").exists()
