"""``ssga parse``: any parser's scene graph of a user's images, drawn, with its regions as a label PNG and JSON."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from ssga_bench.io import ids_from_png16, ids_to_png16
from ssga_bench.scene_graph_figure import TINT, drawing_scale, region_colours
from ssga_bench.testing import plugin_with
from ssga_core import Parser, Regions, StageConfig, View, resolve_stage
from ssga_core.cli import app_with_plugin_commands
from ssga_core.graph import assemble
from ssga_core.testing import make_view

app = app_with_plugin_commands()
runner = CliRunner()


def write_rgb(path, rgb):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def read(path, flags=cv2.IMREAD_UNCHANGED):
    image = cv2.imread(str(path), flags)
    assert image is not None, path
    return image


def parse(*args):
    return runner.invoke(app, ["parse", *map(str, args)])


def one_line_error(result, *fragments, problems=0):
    """Exit 1 with one line (a config error: its header, then one line per problem), naming each fragment."""
    assert result.exit_code == 1, result.output
    assert "Traceback" not in result.output and result.stdout == ""
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 + problems and lines[0].startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, (fragment, result.stderr)


@pytest.fixture
def wall(tmp_path):
    """make_view's painted wall as a plain image file."""
    view = make_view(seed=3)
    write_rgb(tmp_path / "wall.png", view.rgb)
    return view


def test_slico_writes_labels_that_round_trip_and_the_core_graph(tmp_path, wall, ssga_installed_registry):
    out = tmp_path / "out"
    result = parse(tmp_path / "wall.png", "--parser", "slico", "--preset", "coarse", "--out", out)
    assert result.exit_code == 0, result.output

    plain = View(rgb=wall.rgb, pose=wall.pose, camera=wall.camera)
    slico = resolve_stage("parser", {"name": "slico", "preset": "coarse"}, ssga_installed_registry)
    expected = slico.create().parse(plain)
    labels = read(out / "wall.labels.png")
    assert labels.dtype == np.uint16 and labels.min() >= 1  # SLICO leaves no pixel out of a region
    np.testing.assert_array_equal(ids_from_png16(labels), expected.labels)

    record = json.loads((out / "wall.regions.json").read_text())
    assert record["parser"]["name"] == "slico" and record["parser"]["preset"] == "coarse"
    assert record["parser"]["config"] == slico.config.model_dump(mode="json")
    assert record["parser"]["config"]["n_segments"] == slico.cls.presets["coarse"]["n_segments"]
    assert "caveat" not in record["parser"] and record["channels"] == ["rgb"]
    regions = record["regions"]
    assert len(regions) == len(expected) == labels.max()
    assert [r["node"] for r in regions] == list(range(1, len(expected) + 1))
    assert [r["area"] for r in regions] == np.bincount(expected.labels.ravel()).tolist()
    np.testing.assert_allclose([r["box"] for r in regions], expected.boxes)
    np.testing.assert_allclose([r["centroid"] for r in regions], expected.centroids(), atol=0.01)
    assert {r["name"] for r in regions} == {None} and {r["score"] for r in regions} == {None}
    graph = assemble(plain.camera, expected.boxes, np.zeros((1 + len(expected), 1), np.float32))
    assert record["edges"] == graph.edges.tolist()
    assert [r["weight"] for r in regions] == pytest.approx(graph.weights[1:].tolist())

    between = sum(0 not in edge for edge in record["edges"])
    assert result.stdout.strip() == f"{out / 'wall.graph.png'}: {tmp_path / 'wall.png'}: {len(expected)} regions, {between} edges between them"
    picture = read(out / "wall.graph.png")
    scale = drawing_scale((256, 256), len(expected))
    assert scale >= 2 and picture.shape[1] == 256 * scale and 256 * scale < picture.shape[0] < 256 * scale + 128


class Detections(Parser):
    """Overlapping boxes with names, scores and categories, on any image: two chairs and a table; the caveat of
    a stage on random weights."""

    name = "test-detections"
    Config = StageConfig
    presets = {"all": {}}

    @classmethod
    def caveat(cls, config):
        return "random weights"

    def _parse(self, view):
        h, w = view.camera.shape
        labels = np.full((h, w), -1, np.int32)
        labels[20:80, 20:80] = 0
        labels[20:80, 224:254] = 1
        labels[150:230, 60:200] = 2
        # The table's box reaches above its mask, to 16 px from the left chair's.
        boxes = np.array([[20, 20, 79, 79], [224, 20, 253, 79], [60, 95, 199, 229]], np.float32)
        return Regions(
            labels=labels,
            boxes=boxes,
            categories=np.array([19, 19, 15], np.int32),
            names=("chair", "chair", "table"),
            scores=np.array([0.9, 0.6, 0.75], np.float32),
        )


@pytest.fixture
def detections(monkeypatch, ssga_plugin_set, stand_ins):
    ssga_plugin_set.register(plugin_with(Detections), "detections")
    registry = ssga_plugin_set.registry()
    monkeypatch.setattr("ssga_core.plugins.default_registry", lambda: registry)


def test_names_scores_and_categories_reach_the_json_and_the_picture(tmp_path, detections):
    grey = np.full((256, 256, 3), 120, np.uint8)
    write_rgb(tmp_path / "room.png", grey)
    out = tmp_path / "out"
    result = parse(tmp_path / "room.png", "--parser", "test-detections", "-o", "preset=all", "--out", out)
    assert result.exit_code == 0, result.output
    assert result.stdout.strip().endswith("3 regions, 1 edges between them [random weights]")

    record = json.loads((out / "room.regions.json").read_text())
    assert record["parser"]["caveat"] == "random weights" and record["parser"]["preset"] == "all"
    regions = record["regions"]
    assert [(r["name"], r["score"], r["category"]) for r in regions] == [("chair", 0.9, 19), ("chair", 0.6, 19), ("table", 0.75, 15)]
    assert regions[2]["box"] == [60, 95, 199, 229] and regions[2]["area"] == 80 * 140
    # Node 0 to every part; the left chair's box is 16 px from the table's, the right one's 25 px (over 20).
    assert record["edges"] == [[0, 1], [0, 2], [0, 3], [1, 3]]
    assert read(out / "room.labels.png")[0, 0] == 0  # no region

    picture = cv2.cvtColor(read(out / "room.graph.png", cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    s = drawing_scale((256, 256), 3)

    def at(u, v):
        return picture[v * s, u * s].astype(int)

    colours = region_colours(Detections().parse(View(rgb=grey, pose=make_view().pose, camera=make_view().camera)))
    tinted = np.rint((1 - TINT) * 120 + TINT * colours.astype(float)).astype(int)
    # Inside each region, away from outlines, boxes, nodes and captions: the image under the region's tint;
    # both chairs in one colour (one category), the table in another; no region is grey.
    assert np.abs(at(30, 70) - tinted[0]).max() <= 2 and np.abs(at(230, 70) - tinted[1]).max() <= 2
    assert (at(30, 70) == at(230, 70)).all() and not (at(30, 70) == at(70, 220)).all()
    assert np.abs(at(70, 220) - tinted[2]).max() <= 2
    no_region = at(128, 110)
    assert no_region[0] == no_region[1] == no_region[2] < 120


def test_semantic_ids_are_read_from_a_workspace_folder(tmp_path):
    view = make_view(seed=2)
    image = tmp_path / "ws" / "rgb" / "view-0001.png"
    write_rgb(image, view.rgb)
    for channel in ("semantic", "instance"):
        (tmp_path / "ws" / channel).mkdir()
        cv2.imwrite(str(tmp_path / "ws" / channel / "view-0001.png"), ids_to_png16(getattr(view, channel), channel))
    out = tmp_path / "out"
    result = parse(image, "--parser", "semantic", "-o", "min_region_px=0", "--out", out)
    assert result.exit_code == 0, result.output
    assert "(read with semantic, instance)" in result.stdout
    record = json.loads((out / "view-0001.regions.json").read_text())
    visible = np.unique(view.instance[view.instance >= 0])  # rectangles may hide each other
    assert [r["category"] for r in record["regions"]] == visible.tolist()
    assert [r["area"] for r in record["regions"]] == [int((view.instance == i).sum()) for i in visible]
    assert record["channels"] == ["rgb", "semantic", "instance"]
    labels = ids_from_png16(read(out / "view-0001.labels.png"))
    np.testing.assert_array_equal(labels >= 0, view.instance >= 0)

    result = parse(image, "--parser", "semantic", "--rgb-only", "--out", tmp_path / "plain")
    one_line_error(result, str(image), "needs semantic", "without --rgb-only")


def test_a_synthetic_view_keeps_its_holes_out_of_the_regions(tmp_path, wall):
    folder = tmp_path / "synthesis"
    write_rgb(folder / "synthetic.png", wall.rgb)
    depth = np.full((256, 256), 3000, np.uint16)
    depth[:, 200:] = 0  # a hole, as `ssga synthesize` writes it
    cv2.imwrite(str(folder / "depth.png"), depth)
    result = parse(folder / "synthetic.png", "--parser", "slico", "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    record = json.loads((tmp_path / "out" / "synthetic.regions.json").read_text())
    assert record["synthetic"] is True and record["channels"] == ["rgb", "depth"]
    labels = read(tmp_path / "out" / "synthetic.labels.png")
    assert (labels[:, 200:] == 0).all() and (labels[:, :190] > 0).mean() > 0.95


def test_several_images_keep_their_folders_and_never_replace_an_input(tmp_path, wall):
    write_rgb(tmp_path / "a" / "x.png", wall.rgb)
    write_rgb(tmp_path / "b" / "x.png", wall.rgb[::-1].copy())
    out = tmp_path / "out"
    result = parse(tmp_path / "a" / "x.png", tmp_path / "b" / "x.png", "--parser", "slico", "--out", out)
    assert result.exit_code == 0, result.output
    assert len(result.stdout.strip().splitlines()) == 2
    assert (out / "a" / "x.graph.png").is_file() and (out / "b" / "x.labels.png").is_file()
    assert not np.array_equal(read(out / "a" / "x.labels.png"), read(out / "b" / "x.labels.png"))

    # Parsing a folder's images into itself twice: the second run would replace the first's picture, an input now.
    first = tmp_path / "c"
    write_rgb(first / "x.png", wall.rgb)
    assert parse(first / "x.png", "--parser", "slico", "--out", first).exit_code == 0
    before = (first / "x.graph.png").read_bytes()
    result = parse(first / "x.png", first / "x.graph.png", "--parser", "slico", "--out", first)
    one_line_error(result, f"{first / 'x.graph.png'}: is an input")
    assert (first / "x.graph.png").read_bytes() == before and not (first / "x.graph.graph.png").exists()

    write_rgb(tmp_path / "a" / "x.jpg", wall.rgb)
    result = parse(tmp_path / "a" / "x.png", tmp_path / "a" / "x.jpg", "--parser", "slico", "--out", tmp_path / "out2")
    one_line_error(result, "x.jpg", "same x.* files")
    assert not (tmp_path / "out2").exists()


def test_bad_input_is_one_line_and_writes_nothing(tmp_path, wall):
    out = tmp_path / "out"
    base = [tmp_path / "wall.png"]
    one_line_error(parse(tmp_path / "missing.png", "--parser", "slico", "--out", out), "missing.png: no such file")
    (tmp_path / "broken.png").write_bytes(b"\x89PNG not really")
    one_line_error(parse(*base, tmp_path / "broken.png", "--parser", "slico", "--out", out), "broken.png: not a readable image")
    one_line_error(parse(*base, "--parser", "nope", "--out", out), "no parser named 'nope'", problems=1)
    one_line_error(parse(*base, "--parser", "slico", "-o", "n_segments=0", "--out", out), "parser.n_segments", problems=1)
    one_line_error(parse(*base, "--parser", "slico", "-o", "n_segments", "--out", out), "expected key=value")
    one_line_error(parse(*base, "--parser", "slico", "--preset", "huge", "--out", out), "no preset 'huge'", "coarse", problems=1)
    one_line_error(parse(*base, "--parser", "slico", "--preset", "fine", "-o", "preset=coarse", "--out", out), "expected one preset")
    one_line_error(parse(*base, "--parser", "semantic", "--out", out), "wall.png", "needs semantic", "semantic/ and instance/")
    assert not out.exists()
    (tmp_path / "file").write_text("in the way")
    one_line_error(parse(*base, "--parser", "slico", "--out", tmp_path / "file"), "file", "a file")
