"""A folder of captures made from the stand-in wall workspace, run through the protocol."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
import shapely
from ssga_workspace_folder.plugin import FolderConfig, FolderWorkspaceSource

from ssga_core import InputError, Pose
from ssga_bench import ProtocolConfig, build_dataset, depth_to_png16, write_json, write_png


def open_folder(root, **kw):
    return FolderWorkspaceSource(FolderConfig(path=root, **kw)).open()


def test_is_installed(ssga_installed_registry):
    assert ssga_installed_registry.entry("workspace", "folder").plugin.distribution == "ssga-workspace-folder"


def test_the_protocol_selects_training_and_test_views_among_captures(make_folder, tmp_path):
    rows = make_folder(tmp_path / "scene")
    ws = open_folder(tmp_path / "scene")
    assert (ws.camera.width, ws.camera.height, ws.camera.focal_px) == (256, 256, pytest.approx(128.0))
    ds = build_dataset(ws, tmp_path / "ds", source={"name": "folder"}, protocol=ProtocolConfig(cells=3, test_per_class=2, seed=1))
    train, tests, targets = ds.split("train"), ds.split("test"), ds.split("target")
    assert len(train) == 3 and len(targets) == 33
    assert tests and all(s.source is not None for s in train + tests)
    assert {s.source for s in train}.isdisjoint({s.source for s in tests})
    # A selected view is the capture itself, pose and pixels.
    s = tests[0]
    assert (s.pose.x, s.pose.y) == pytest.approx((rows[s.source]["x"], rows[s.source]["y"]))
    np.testing.assert_array_equal(ds.view(s).rgb, ws.load(s.source).rgb)
    assert ds.view(s).depth is not None and ds.view(s).semantic is None
    with pytest.raises(InputError, match="no image of view"):
        ds.view(targets[0])


def test_habitat_poses_and_degrees(make_folder, tmp_path):
    make_folder(tmp_path, n=1)
    row = {"rgb": "images/0000.png", "position": [1.0, 1.5, -2.0], "rotation": [1.0, 0.0, 0.0, 0.0]}
    (tmp_path / "captures.jsonl").write_text(json.dumps(row) + "\n" + json.dumps({"rgb": "images/0000.png", "x": 0, "y": 0, "yaw": 90}) + "\n")
    ws = open_folder(tmp_path, yaw_in_degrees=True)
    assert ws.captures[0] == Pose(1.0, 2.0, math.pi / 2, 1.5)
    assert ws.captures[1].yaw == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ({"rgb": "images/missing.png", "x": 0, "y": 0, "yaw": 0}, r"captures.jsonl:2: rgb: image .*missing.png does not exist"),
        ({"rgb": "images/0000.png", "x": 0, "yaw": 0}, r"captures.jsonl:2: pose: no y: expected x, y, yaw"),
        ({"x": 0, "y": 0, "yaw": 0}, r"captures.jsonl:2: rgb: no image named"),
    ],
)
def test_bad_capture_lines_name_the_line(make_folder, tmp_path, line, message):
    make_folder(tmp_path, n=1)
    with (tmp_path / "captures.jsonl").open("a") as f:
        f.write(json.dumps(line) + "\n")
    with pytest.raises(InputError, match=message):
        open_folder(tmp_path)


def test_a_pose_outside_the_plan_is_named(make_folder, tmp_path):
    make_folder(tmp_path, n=30)
    with (tmp_path / "captures.jsonl").open("a") as f:
        f.write(json.dumps({"rgb": "images/0000.png", "x": 40.0, "y": 0.0, "yaw": 0.0}) + "\n")
    ws = open_folder(tmp_path)
    with pytest.raises(InputError, match=r"capture 30 at \(40.00, 0.00\) stands outside the floor plan's free floor"):
        build_dataset(ws, tmp_path / "ds", source={"name": "folder"}, protocol=ProtocolConfig(cells=1))


def test_broken_files_are_named(make_folder, tmp_path):
    make_folder(tmp_path, n=2)
    ws = open_folder(tmp_path)
    (tmp_path / "images" / "0001.png").write_bytes(b"broken")
    with pytest.raises(InputError, match=r"captures.jsonl:2: .*0001.png: not a readable image"):
        ws.load(1)  # broken after the workspace opened
    with pytest.raises(InputError, match=r"captures.jsonl:2: rgb: .*0001.png: not a readable image"):
        open_folder(tmp_path)  # broken before: refused when it opens
    (tmp_path / "images" / "0001.png").write_bytes((tmp_path / "images" / "0000.png").read_bytes())
    (tmp_path / "floorplan.json").write_text('{"free": 3}')
    with pytest.raises(InputError, match=r"floorplan.json: .free. must be a list of polygons"):
        open_folder(tmp_path)
    with pytest.raises(InputError, match="no such folder"):
        open_folder(tmp_path / "nope")


def test_a_relative_folder_follows_the_config_file_in_every_command(make_folder, tmp_path, monkeypatch):
    """`path = "caps"` in cfgdir/exp.toml means cfgdir/caps for `config validate`, `workspace build` and `run` alike."""
    from typer.testing import CliRunner

    from ssga_core.cli import app_with_plugin_commands

    make_folder(tmp_path / "cfgdir" / "caps", n=300)
    (tmp_path / "cfgdir" / "exp.toml").write_text(
        'variants = ["PD"]\noutput = "out"\n[workspace]\nname = "folder"\npath = "caps"\n'
        "[protocol]\ncells = 2\ntest_per_class = 1\nseed = 1\n"
        '[stages]\nparser = { name = "slico" }\ndescriptor = { name = "dense-sift" }\n[training]\nepochs = 2\n'
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    app, runner = app_with_plugin_commands(), CliRunner()
    config = str(tmp_path / "cfgdir" / "exp.toml")
    for args in (["config", "validate", config], ["workspace", "build", "--config", config], ["run", config]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, (args, result.output)
    built = json.loads(next((elsewhere / "runs" / "workspaces").glob("*/dataset.json")).read_text())
    assert built["source"]["path"] == str(tmp_path / "cfgdir" / "caps")
    assert (elsewhere / "out" / "report.md").exists()  # `output` is relative to where ssga runs


def test_captures_without_depth_refuse_a_depth_warp_before_anything_runs(make_folder, tmp_path, ssga_installed_registry):
    """RGB-only captures: `config validate` names the variant and what it lacks; RGB-only variants pass."""
    from ssga_core import ConfigError, Data
    from ssga_bench import validate_experiment

    rows = make_folder(tmp_path / "caps", n=40)
    assert FolderWorkspaceSource.carries(FolderConfig(path=tmp_path / "caps")) == {Data.RGB, Data.DEPTH}
    (tmp_path / "caps" / "captures.jsonl").write_text("".join(json.dumps({k: v for k, v in r.items() if k != "depth"}) + "\n" for r in rows))
    assert FolderWorkspaceSource.carries(FolderConfig(path=tmp_path / "caps")) == {Data.RGB}
    config = {
        "workspace": {"name": "folder", "path": str(tmp_path / "caps")},
        "stages": {"parser": {"name": "slico"}, "descriptor": {"name": "dense-sift"}, "synthesizer": {"name": "depth-warp"}},
    }
    with pytest.raises(ConfigError, match=r"variants\[0\].*depth"):
        validate_experiment({**config, "variants": ["SD", "PD"]}, ssga_installed_registry)
    assert [v.label for v in validate_experiment({**config, "variants": ["PD", "D"]}, ssga_installed_registry).variants] == ["SIFT-SL (PD)", "SIFT (D)"]


# --- floor plans derived from the captures -------------------------------------------------


@pytest.fixture(scope="module")
def room_captures(tmp_path_factory):
    """A folder of 60 captures (RGB and depth) rendered in the mesh workspace's box room (8 x 6 m,
    two crates), without a floor plan; and the plan the mesh itself gives, to compare with."""
    scenes = pytest.importorskip("ssga_workspace_mesh.scenes")  # a real renderer for real depth
    from ssga_workspace_mesh.floorplan import floor_plan_from_mesh
    from ssga_workspace_mesh.renderer import MeshRenderer

    from ssga_core import Camera

    root = tmp_path_factory.mktemp("room")
    room = scenes.box_room()
    truth = floor_plan_from_mesh(room)
    renderer = MeshRenderer(room, Camera(width=96, height=96))
    rng = np.random.default_rng(0)
    rows = []
    (root / "images").mkdir()
    while len(rows) < 60:
        x, y = rng.uniform(-3.7, 3.7), rng.uniform(-2.7, 2.7)
        if not truth.can_stand(x, y):
            continue
        k = len(rows)
        view = renderer.render(Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi))))
        write_png(root / "images" / f"{k:04d}.png", view.rgb)
        write_png(root / "images" / f"{k:04d}-depth.png", depth_to_png16(view.depth))
        rows.append({"rgb": f"images/{k:04d}.png", "depth": f"images/{k:04d}-depth.png", "x": x, "y": y, "yaw": view.pose.yaw})
    (root / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return root, truth, rows


def test_without_a_floor_plan_one_is_derived_from_poses_and_depth(room_captures, tmp_path, capsys):
    root, truth, rows = room_captures
    ws = open_folder(root)
    assert "no floorplan.json; floor plan derived from 60 capture poses and 60 depth images" in capsys.readouterr().err
    plan = ws.floor_plan
    overlap = plan.free.intersection(truth.free).area
    assert overlap > 0.8 * truth.free.area, "most of the free floor is found"
    assert plan.free.difference(truth.free.buffer(0.15)).area < 0.05 * truth.free.area, "little is free that is not"
    for x, y in ((4.05, 0.0), (-4.05, 1.0), (0.0, 3.05), (1.0, -3.05)):  # the walls
        assert plan.occluders.distance(shapely.Point(x, y)) < 0.15, (x, y)
    assert not plan.occluders.covers(shapely.Point(0.0, 0.0))
    for (x, y), (dx, dy, _) in pytest.importorskip("ssga_workspace_mesh.scenes").CRATES.values():  # seen at camera height, and not to be stood in
        crate = shapely.box(x - dx / 2, y - dy / 2, x + dx / 2, y + dy / 2)
        assert plan.occluders.intersection(crate.buffer(0.1)).area > 0.05
        assert not plan.can_stand(x, y)
    assert all(plan.free.buffer(0.1).covers(shapely.Point(r["x"], r["y"])) for r in rows)
    ds = build_dataset(ws, tmp_path / "ds", source={"name": "folder"}, protocol=ProtocolConfig(cells=2, test_per_class=1, seed=1))
    assert len(ds.split("train")) == 2


def test_captures_without_depth_give_the_floor_the_cameras_swept(room_captures, tmp_path, capsys):
    root, _, rows = room_captures
    (tmp_path / "images").symlink_to(root / "images")
    (tmp_path / "captures.jsonl").write_text("".join(json.dumps({k: v for k, v in r.items() if k != "depth"}) + "\n" for r in rows))
    plan = open_folder(tmp_path, robot_radius=0.4).floor_plan
    assert "(no depth: no occluders)" in capsys.readouterr().err
    assert plan.occluders.is_empty
    # A disc around each capture, and a band along each step of less than a metre to the next.
    xy = [(r["x"], r["y"]) for r in rows]
    steps = [shapely.LineString(pair) for pair in itertools.pairwise(xy) if math.dist(*pair) < 1.0]
    swept = shapely.union_all([shapely.Point(p).buffer(0.4) for p in xy] + [s.buffer(0.4) for s in steps])
    assert steps and plan.free.symmetric_difference(swept).area < 0.02 * swept.area


def test_a_hand_drawn_floor_plan_wins(room_captures, tmp_path, capsys):
    root, _, _ = room_captures
    (tmp_path / "images").symlink_to(root / "images")
    (tmp_path / "captures.jsonl").write_text((root / "captures.jsonl").read_text())
    write_json(tmp_path / "floorplan.json", {"free": [[[-4, -3], [4, -3], [4, 3], [-4, 3]]]})
    plan = open_folder(tmp_path).floor_plan
    assert plan.free.area == pytest.approx(48.0) and plan.occluders.is_empty
    assert "derived" not in capsys.readouterr().err


def test_config_validate_names_what_is_missing_before_anything_runs(make_folder, tmp_path, ssga_installed_registry):
    from ssga_core import ConfigError
    from ssga_bench import validate_experiment

    (tmp_path / "empty").mkdir()
    base = {"variants": ["D"], "stages": {"descriptor": {"name": "dense-sift"}}}
    with pytest.raises(ConfigError) as raised:
        validate_experiment({**base, "workspace": {"name": "folder", "path": str(tmp_path / "empty")}}, ssga_installed_registry)
    problems = str(raised.value)
    assert "workspace.captures: " in problems and "captures.jsonl: no such file" in problems
    assert "workspace.floor_plan: no " in problems and "floorplan.json, and no captures to derive one from" in problems
    make_folder(tmp_path / "caps", n=3)
    (tmp_path / "caps" / "floorplan.json").unlink()
    workspace = {"name": "folder", "path": str(tmp_path / "caps")}
    validate_experiment({**base, "workspace": workspace}, ssga_installed_registry)  # derived from the captures: fine
    with pytest.raises(ConfigError, match=r"workspace.floor_plan: no .*floorplan.json; draw one, or set derive_floor_plan = true"):
        validate_experiment({**base, "workspace": {**workspace, "derive_floor_plan": False}}, ssga_installed_registry)
    with pytest.raises(ConfigError, match=r"workspace.floor_plan: no .*plan.json \(named in the config; leave floor_plan out"):
        validate_experiment({**base, "workspace": {**workspace, "floor_plan": "plan.json"}}, ssga_installed_registry)
    with pytest.raises(ConfigError, match=r"workspace.path: no such folder"):
        validate_experiment({**base, "workspace": {"name": "folder", "path": str(tmp_path / "nowhere")}}, ssga_installed_registry)


def test_large_captures_are_read_reduced_with_their_depth(make_folder, tmp_path, capsys):
    import cv2

    rows = make_folder(tmp_path, n=3)
    view = open_folder(tmp_path, max_side=None).load(0)
    for row in rows:  # each capture 4x larger, as a high-resolution camera takes them
        for key in ("rgb", "depth"):
            image = cv2.imread(str(tmp_path / row[key]), cv2.IMREAD_UNCHANGED)
            cv2.imwrite(str(tmp_path / row[key]), cv2.resize(image, None, fx=4, fy=4, interpolation=cv2.INTER_NEAREST))
    big = open_folder(tmp_path, max_side=view.camera.width)
    assert "read reduced to" in capsys.readouterr().err
    reduced = big.load(0)
    assert big.camera == view.camera and reduced.rgb.shape == view.rgb.shape and reduced.depth.shape == view.depth.shape
    np.testing.assert_allclose(reduced.depth, view.depth)  # nearest samples of a 4x nearest upscale: the same depths
    assert np.abs(reduced.rgb.astype(int) - view.rgb.astype(int)).mean() < 2.0
