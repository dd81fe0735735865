"""Every capture of captures.jsonl checked before the workspace opens, never guessed: a bad
one is refused in one line naming its line and field, or skipped and counted where the
config asks; warnings are errors here, so no numpy or OpenCV warning is the only sign."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import ValidationError
from ssga_workspace_folder.plugin import FolderConfig, FolderWorkspaceSource

from ssga_core import InputError
from ssga_bench import ProtocolConfig, build_dataset, depth_to_png16, write_png

pytestmark = pytest.mark.filterwarnings("error")

NAN, INF = float("nan"), float("inf")


def open_folder(root, **kw):
    return FolderWorkspaceSource(FolderConfig(path=root, **kw)).open()
RIGID = [[0.0, 0.0, 1.0, 0.5], [-1.0, 0.0, 0.0, 0.5], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]]


def append(root, *rows):
    with (root / "captures.jsonl").open("a") as f:
        for row in rows:
            f.write(json.dumps(row) + "\n")  # NaN and Infinity as JSON writes them (json.loads reads them back)


@pytest.mark.parametrize(
    ("pose", "message"),
    [
        ({"x": NAN, "y": 0, "yaw": 0}, r"captures.jsonl:3: x: nan is not a finite number"),
        ({"x": 0, "y": 0, "yaw": INF}, r"captures.jsonl:3: yaw: inf is not a finite number"),
        ({"x": 0, "y": 0, "yaw": 0, "height": NAN}, r"captures.jsonl:3: height: nan is not a finite number"),
        ({"x": 0, "y": 0, "yaw": 0, "height": -0.2}, r"captures.jsonl:3: height: the camera is -0.200 m high, at or below the floor"),
        ({"x": 0, "y": 0, "yaw": 0, "height": 1500}, r"captures.jsonl:3: height: .* more than 20 m above the floor"),
        ({"x": 2500.0e3, "y": 0, "yaw": 0}, r"captures.jsonl:3: x, y: \(2.5e\+06, 0\) is more than 10000 m from the origin \(millimetres\?\)"),
        ({"x": 0, "y": 0, "yaw": 90}, r"captures.jsonl:3: yaw: 90 is more than a turn \(2 pi\); set yaw_in_degrees = true"),
        ({"x": 0, "y": 0, "yaw": "north"}, r"captures.jsonl:3: yaw: expected a number, got 'north'"),
        ({"position": [0, NAN, 0], "rotation": [1, 0, 0, 0]}, r"captures.jsonl:3: position: holds nan \(not a finite number\)"),
        ({"position": [0, 1.5, 0], "rotation": [2, 0, 0, 0]}, r"captures.jsonl:3: rotation: .* is not a unit quaternion \(norm 2\)"),
        ({"position": [0, 1.5, 0], "rotation": [1, 0]}, r"captures.jsonl:3: rotation: expected 4 numbers, got shape \(2,\)"),
        ({"camera_to_world": [[NAN] * 4] * 4}, r"captures.jsonl:3: camera_to_world: holds nan"),
        ({"camera_to_world": [[2 * v for v in r[:3]] + r[3:] for r in RIGID[:3]] + [RIGID[3]]}, r"camera_to_world: its 3 x 3 part is not a rotation"),
        ({"camera_to_world": [r[:3] + [r[3]] for r in RIGID[:2]] + [[0, 1, 0, 1.5], RIGID[3]]}, r"camera_to_world: its 3 x 3 part is a reflection"),
        ({"camera_to_world": RIGID[:3] + [[0, 0, 1, 1]]}, r"camera_to_world: last row is \(0, 0, 1, 1\), not \(0, 0, 0, 1\)"),
        ({"camera_to_world": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1.5], [0, 0, 0, 1]]}, r"captures.jsonl:3: pose: the camera looks straight up"),
    ],
)
def test_a_bad_pose_is_refused_naming_its_line_and_field(make_folder, tmp_path, pose, message):
    make_folder(tmp_path, n=2)
    append(tmp_path, {"rgb": "images/0000.png", **pose})
    with pytest.raises(InputError, match=message) as raised:
        open_folder(tmp_path)
    assert "\n" not in str(raised.value)


def test_degrees_are_read_as_degrees_when_asked(make_folder, tmp_path):
    make_folder(tmp_path, n=1)
    append(tmp_path, {"rgb": "images/0000.png", "x": 0, "y": 0, "yaw": -270})
    assert open_folder(tmp_path, yaw_in_degrees=True).captures[1].yaw == pytest.approx(math.radians(-270))
    append(tmp_path, {"rgb": "images/0000.png", "x": 0, "y": 0, "yaw": 400})
    with pytest.raises(InputError, match=r"captures.jsonl:3: yaw: 400 is more than a turn \(360\)$"):
        open_folder(tmp_path, yaw_in_degrees=True)


def _depth(root, name, image):
    write_png(root / "images" / name, image)
    return f"images/{name}"


def test_depth_of_the_wrong_bit_depth_size_or_units_is_refused(make_folder, tmp_path):
    rows = make_folder(tmp_path, n=2)
    view = open_folder(tmp_path).load(0)
    mm = depth_to_png16(view.depth)
    cases = [
        # An 8-bit PNG where the README says 16-bit millimetres (read as 0-255 mm before).
        (_depth(tmp_path, "d8.png", np.clip(mm // 20, 0, 255).astype(np.uint8)), r"depth: .*d8.png is 8-bit grey; expected a 16-bit PNG"),
        (_depth(tmp_path, "rgb.png", view.rgb), r"depth: .*rgb.png is colour; expected a 16-bit PNG"),
        (_depth(tmp_path, "wide.png", mm[:128]), r"depth: .*wide.png is 256 x 128, its image 256 x 256 \(another aspect ratio"),
        # Metres stored as integers: a median of a few millimetres.
        (_depth(tmp_path, "metres.png", np.rint(view.depth).astype(np.uint16)), r"depth: .*metres.png: median depth 0.00\d+ m read as 1000 per metre, outside"),
    ]
    np.save(tmp_path / "images" / "mm.npy", view.depth * 1000.0)
    cases.append(("images/mm.npy", r"depth: .*mm.npy: median depth \d+ m read as metres, outside the plausible 0.25-15 m"))
    np.save(tmp_path / "images" / "int.npy", mm)
    cases.append(("images/int.npy", r"depth: .*int.npy: an integer .npy array; expected float metres"))
    for depth, message in cases:
        lines = [rows[0], {**rows[1], "depth": depth}]
        (tmp_path / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
        with pytest.raises(InputError, match=r"captures.jsonl:2: " + message):
            open_folder(tmp_path)
    # Half the size, same aspect ratio: fine, read at the image's size.
    lines = [rows[0], {**rows[1], "depth": _depth(tmp_path, "half.png", mm[::2, ::2])}]
    (tmp_path / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    assert open_folder(tmp_path).load(1).depth.shape == (256, 256)


def test_a_colour_image_of_another_size_is_refused(make_folder, tmp_path):
    rows = make_folder(tmp_path, n=4)
    write_png(tmp_path / "images" / "small.png", np.zeros((128, 128, 3), np.uint8))
    rows[2] = {**rows[2], "rgb": "images/small.png"}
    (tmp_path / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(InputError, match=r"captures.jsonl:3: rgb: .*small.png is 128 x 128, the other 3 captures' 256 x 256$"):
        open_folder(tmp_path)


def test_bad_frames_are_skipped_with_one_line_when_asked(make_folder, tmp_path, capsys):
    rows = make_folder(tmp_path, n=40)
    write_png(tmp_path / "images" / "small.png", np.zeros((128, 128, 3), np.uint8))
    write_png(tmp_path / "images" / "d8.png", np.full((256, 256), 100, np.uint8))
    rows[3] = {**rows[3], "x": NAN}
    rows[5] = {**rows[5], "yaw": NAN}
    rows[7] = {**rows[7], "rgb": "images/small.png"}
    rows[9] = {**rows[9], "depth": "images/d8.png"}
    (tmp_path / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.raises(InputError, match=r"captures.jsonl:4: x: nan is not a finite number"):
        open_folder(tmp_path)
    ws = open_folder(tmp_path, skip_bad_frames=True)
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "skipped" in line]
    captures = tmp_path / "captures.jsonl"
    assert line == (
        f"{captures}: skipped 4 of 40 frames: 2 pose not finite ({captures}:4, {captures}:6); "
        f"1 depth not 16-bit ({captures}:10); 1 image of another size ({captures}:8)"
    )
    assert len(ws.captures) == 36
    kept = [r for k, r in enumerate(rows) if k not in (3, 5, 7, 9)]
    assert [(p.x, p.y) for p in ws.captures] == [(r["x"], r["y"]) for r in kept]
    # The build that once printed numpy's "invalid value encountered in cast" and lost the capture in silence.
    ds = build_dataset(ws, tmp_path / "ds", source={"name": "folder"}, protocol=ProtocolConfig(cells=1, test_per_class=1, seed=1))
    assert ds.split("train")


def test_up_axis_is_an_axis_or_a_vector():
    assert FolderConfig(path=".", up_axis="-y").up_axis == "-y"
    assert FolderConfig(path=".", up_axis=[0, 0, 2]).up_axis == (0.0, 0.0, 2.0)
    for wrong in ("up", [0, 0, 0], [0, 1]):
        with pytest.raises(ValidationError, match="expected 'auto', one of x, y, z"):
            FolderConfig(path=".", up_axis=wrong)
