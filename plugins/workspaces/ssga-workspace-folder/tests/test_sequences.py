"""RGB-D sequences with 6-DoF poses: ScanNet's exported frames and TUM RGB-D, made from
views of a procedural home rendered with pitch and roll, in a world moved by a random
rigid transform. Read back, every frame stands within 5 cm of where it was rendered and
looks within 3 degrees of where it looked, invalid pose rows are skipped in one line,
and warnings are errors throughout."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from ssga_workspace_folder.layouts import associate
from ssga_workspace_folder.plugin import FolderConfig, FolderWorkspaceSource

from ssga_core import Camera, Data, InputError, Pose
from ssga_bench import ProtocolConfig, build_dataset, depth_to_png16, write_png

pytestmark = pytest.mark.filterwarnings("error")

FRAMES = 36


@dataclass(frozen=True)
class Tilted(Pose):
    """A pose the renderer sees pitched and rolled: ``rotation()`` is the whole camera-to-world rotation."""

    turn: tuple[float, ...] = ()

    def rotation(self) -> np.ndarray:
        return np.array(self.turn).reshape(3, 3)


def open_folder(root, **kw):
    return FolderWorkspaceSource(FolderConfig(path=root, **kw)).open()


def rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_xyzw(r):
    w = math.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    if w > 1e-3:
        return [(r[2, 1] - r[1, 2]) / (4 * w), (r[0, 2] - r[2, 0]) / (4 * w), (r[1, 0] - r[0, 1]) / (4 * w), w]
    k = int(np.argmax(np.diag(r)))
    i, j = (k + 1) % 3, (k + 2) % 3
    s = math.sqrt(1.0 + r[k, k] - r[i, i] - r[j, j]) * 2.0
    q = [0.0, 0.0, 0.0, (r[j, i] - r[i, j]) / s]
    q[k], q[i], q[j] = s / 4.0, (r[i, k] + r[k, i]) / s, (r[j, k] + r[k, j]) / s
    return q


@pytest.fixture(scope="module")
def home():
    generator = pytest.importorskip("ssga_workspace_procedural.generator")  # a real renderer for real depth
    return generator.generate_home(generator.HomeConfig(seed=3, rooms=2, width=8.0, depth=6.0))


def renderer(home, camera):
    from ssga_workspace_procedural.workspace import ProceduralWorkspace

    return ProceduralWorkspace(home, camera)


@pytest.fixture(scope="module")
def truth(home):
    """``FRAMES`` camera-to-world transforms in ssga's world (z up, floor at 0), pitched and rolled up to 12 degrees."""
    rng = np.random.default_rng(7)
    free = home.floor_plan.free.buffer(-0.3)
    import shapely

    out = []
    while len(out) < FRAMES:
        x, y = rng.uniform(0.0, 8.0), rng.uniform(0.0, 6.0)
        if not free.contains(shapely.Point(x, y)):
            continue
        level = Pose(float(x), float(y), float(rng.uniform(-math.pi, math.pi)), float(rng.uniform(1.2, 1.7)))
        t = np.eye(4)
        t[:3, :3] = level.rotation() @ rot_x(math.radians(rng.uniform(-12, 12))) @ rot_z(math.radians(rng.uniform(-12, 12)))
        t[:3, 3] = level.position
        out.append(t)
    return out


def render(home, camera, transform):
    pose = Tilted(float(transform[0, 3]), float(transform[1, 3]), 0.0, float(transform[2, 3]), turn=tuple(transform[:3, :3].ravel()))
    return renderer(home, camera).render(pose)


def heading(transform):
    return math.atan2(transform[1, 2], transform[0, 2])


def planar_fit(found, true):
    """Rotation angle and translation taking ``true`` (n, 2) closest to ``found``, and the residuals."""
    cf, ct = found.mean(0), true.mean(0)
    u, _, vt = np.linalg.svd((true - ct).T @ (found - cf))
    r = vt.T @ u.T
    moved = (true - ct) @ r.T + cf
    return math.atan2(r[1, 0], r[0, 0]), np.linalg.norm(found - moved, axis=1)


def check_against_truth(ws, truth, kept, floor_seen=True):
    """Every kept frame within 5 cm and 3 degrees of the truth (up to one rigid motion of the floor plane)."""
    found = np.array([[p.x, p.y] for p in ws.captures])
    true = np.array([truth[k][:2, 3] for k in kept])
    angle, residuals = planar_fit(found, true)
    assert residuals.max() < 0.05, residuals.max()
    turns = [math.remainder(p.yaw - heading(truth[k]) - angle, 2 * math.pi) for p, k in zip(ws.captures, kept, strict=True)]
    assert max(abs(math.degrees(t)) for t in turns) < 3.0
    if floor_seen:
        heights = np.array([p.height - truth[k][2, 3] for p, k in zip(ws.captures, kept, strict=True)])
        assert np.abs(heights).max() < 0.05, heights


# --- ScanNet -----------------------------------------------------------------------------------

COLOUR_RENDER = Camera(width=104, height=80, hfov_deg=70.0)
CROP = (5, 2)  # columns and rows cut from the left and the top: the principal point is off centre
COLOUR_SIZE = (96, 72)
DEPTH_CAMERA = Camera(width=64, height=48, hfov_deg=76.0)
INVALID_SCANNET = {4: "-inf", 9: "-inf", 17: "-inf", 12: "identity", 20: "scaled"}


def intrinsic_file(path, fx, fy, cx, cy):
    path.write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in [[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]]) + "\n")


@pytest.fixture(scope="module")
def scannet(home, truth, tmp_path_factory):
    """ScanNet's exported frames: JPEG colour whose principal point is off centre, 16-bit depth
    of another size and field of view, 4 x 4 poses in a world turned about z and moved (the
    floor at z = 0.8), five invalid pose files."""
    root = tmp_path_factory.mktemp("scannet")
    for sub in ("color", "depth", "pose", "intrinsic"):
        (root / sub).mkdir()
    move = np.eye(4)
    move[:3, :3] = rot_z(1.1)
    move[:3, 3] = (3.0, -7.0, 0.8)
    for k, t in enumerate(truth):
        colour = render(home, COLOUR_RENDER, t).rgb[CROP[1] : CROP[1] + COLOUR_SIZE[1], CROP[0] : CROP[0] + COLOUR_SIZE[0]]
        cv2.imwrite(str(root / "color" / f"{k}.jpg"), cv2.cvtColor(colour, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
        write_png(root / "depth" / f"{k}.png", depth_to_png16(render(home, DEPTH_CAMERA, t).depth))
        pose = move @ t
        if INVALID_SCANNET.get(k) == "-inf":
            pose = np.full((4, 4), -np.inf)
        elif INVALID_SCANNET.get(k) == "identity":
            pose = np.eye(4)
        elif INVALID_SCANNET.get(k) == "scaled":
            pose[:3, :3] *= 1.2
        (root / "pose" / f"{k}.txt").write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in pose) + "\n")
    f = COLOUR_RENDER.focal_px
    cx, cy = COLOUR_RENDER.principal_point
    intrinsic_file(root / "intrinsic" / "intrinsic_color.txt", f, f, cx - CROP[0], cy - CROP[1])
    intrinsic_file(root / "intrinsic" / "intrinsic_depth.txt", DEPTH_CAMERA.focal_px, DEPTH_CAMERA.focal_px, *DEPTH_CAMERA.principal_point)
    return root


def test_scannet_frames_are_read_levelled_and_resampled_to_the_colour_camera(home, truth, scannet, capsys):
    ws = open_folder(scannet)
    err = capsys.readouterr().err
    (skipped,) = [line for line in err.splitlines() if "skipped" in line]
    assert skipped == (
        f"{scannet} (ScanNet frames): skipped 5 of {FRAMES} frames: 3 pose not finite (frame 4, frame 9, frame 17); "
        "1 identity placeholder (frame 12); 1 pose not rigid (frame 20)"
    )
    found = r"up found from the depth's level surfaces \(\d+% of those seen\): \(-?0\.00\d, -?0\.00\d, 1\.000\), 0\.[0-2] deg from the poses' \+z axis"
    assert re.search(found + r"; floor found at 0\.(79|80)\d m and moved to z = 0", err), err
    kept = [k for k in range(FRAMES) if k not in INVALID_SCANNET]
    assert len(ws.captures) == len(kept)
    check_against_truth(ws, truth, kept)
    # The colour camera (square pixels, centred) keeps the colour's focal length; depth is resampled onto it.
    assert ws.camera == Camera(width=96, height=72, hfov_deg=ws.camera.hfov_deg)
    assert ws.camera.focal_px == pytest.approx(COLOUR_RENDER.focal_px)
    for index in (0, 10):
        view, k = ws.load(index), kept[index]
        expected = render(home, ws.camera, truth[k])
        both = (view.depth > 0) & (expected.depth > 0)
        assert both.mean() > 0.9
        assert np.median(np.abs(view.depth[both] - expected.depth[both])) < 0.02
        shifted = np.abs(view.rgb.astype(int) - expected.rgb.astype(int)).mean()
        unshifted = np.abs(cv2.imread(str(scannet / "color" / f"{k}.jpg"))[..., ::-1].astype(int) - expected.rgb.astype(int)).mean()
        assert shifted < 0.6 * unshifted, (shifted, unshifted)
    assert FolderWorkspaceSource.carries(FolderConfig(path=scannet)) == {Data.RGB, Data.DEPTH}
    assert "(no depth" not in err and "floor plan derived from 31 capture poses and 31 depth images" in err


def test_a_scannet_sequence_runs_through_the_protocol(scannet, tmp_path):
    ws = open_folder(scannet)
    ds = build_dataset(ws, tmp_path / "ds", source={"name": "folder"}, protocol=ProtocolConfig(cells=1, test_per_class=1, seed=1), fit=True)
    assert ds.split("train")


def test_a_bad_depth_frame_in_a_sequence_is_refused_or_skipped(scannet, tmp_path, capsys):
    root = tmp_path / "scannet"
    for sub in ("color", "pose", "intrinsic"):
        (root / sub).mkdir(parents=True)
        for path in (scannet / sub).iterdir():
            (root / sub / path.name).symlink_to(path)
    (root / "depth").mkdir()
    for path in (scannet / "depth").iterdir():
        (root / "depth" / path.name).symlink_to(path)
    (root / "depth" / "7.png").unlink()
    write_png(root / "depth" / "7.png", np.full((48, 64), 200, np.uint8))  # 8-bit
    (root / "depth" / "8.png").unlink()
    write_png(root / "depth" / "8.png", np.full((24, 32), 2000, np.uint16))  # another size
    with pytest.raises(InputError, match=r"scannet \(ScanNet frames\): frame 7: depth: .*7.png is 8-bit grey; expected a 16-bit PNG"):
        open_folder(root)
    ws = open_folder(root, skip_bad_frames=True)
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "skipped" in line]
    assert "skipped 7 of 36 frames: 3 pose not finite" in line and "1 depth not 16-bit (frame 7)" in line and "1 depth of another size (frame 8)" in line
    assert len(ws.captures) == FRAMES - 7


# --- TUM RGB-D ----------------------------------------------------------------------------------

TUM_CAMERA = Camera(width=128, height=96, hfov_deg=math.degrees(2 * math.atan(320 / 525)))  # TUM's 525 px at 640 x 480
START = 1305031102.175304
INVALID_TUM = {5: "nan", 8: "zero quaternion"}
NO_DEPTH = 13


@pytest.fixture(scope="module")
def tum(home, truth, tmp_path_factory):
    """A TUM RGB-D sequence at 30 Hz in a world turned every which way (up known), depth of 5000
    per metre 4 ms after each image, ground truth 3 ms after, two invalid ground-truth rows,
    one image without depth."""
    root = tmp_path_factory.mktemp("tum")
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    move = np.eye(4)
    move[:3, :3] = random_rotation(np.random.default_rng(11))
    move[:3, 3] = (0.4, 2.0, -1.3)
    rgb_lines, depth_lines, truth_lines = ["# color images", "# timestamp filename"], ["# depth maps"], ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    for k, t in enumerate(truth):
        stamp = START + k / 30.0
        view = render(home, TUM_CAMERA, t)
        write_png(root / "rgb" / f"{stamp:.6f}.png", view.rgb)
        rgb_lines.append(f"{stamp:.6f} rgb/{stamp:.6f}.png")
        if k != NO_DEPTH:
            mm = np.clip(np.rint(view.depth * 5000.0), 0, 65535).astype(np.uint16)
            write_png(root / "depth" / f"{stamp + 0.004:.6f}.png", mm)
            depth_lines.append(f"{stamp + 0.004:.6f} depth/{stamp + 0.004:.6f}.png")
        pose = move @ t
        values = [*pose[:3, 3], *quaternion_xyzw(pose[:3, :3])]
        if INVALID_TUM.get(k) == "nan":
            values[0] = float("nan")
        elif INVALID_TUM.get(k) == "zero quaternion":
            values[3:] = [0.0, 0.0, 0.0, 0.0]
        truth_lines.append(f"{stamp + 0.003:.4f} " + " ".join(f"{v:.6f}" for v in values))
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines), ("groundtruth.txt", truth_lines)):
        (root / name).write_text("\n".join(lines) + "\n")
    up = move[:3, :3] @ np.array([0.0, 0.0, 1.0])
    return root, up, float(up @ move[:3, 3])  # the floor (z = 0) is up . t along up


@pytest.mark.parametrize("up", ["given", "auto", "given with the floor"])
def test_a_tum_sequence_is_associated_levelled_and_read(home, truth, tum, up, capsys):
    root, true_up, floor = tum
    given = {"up_axis": [float(v) for v in true_up]} if up.startswith("given") else {}
    ws = open_folder(root, **given, **({"floor_height": floor} if up == "given with the floor" else {}))
    err = capsys.readouterr().err
    (skipped,) = [line for line in err.splitlines() if "skipped" in line]
    assert skipped == (
        f"{root} (TUM RGB-D): skipped 3 of {FRAMES} frames: 2 no valid pose within 0.02 s (rgb.txt:8, rgb.txt:11); "
        "1 no depth within 0.02 s (rgb.txt:16); groundtruth.txt: 2 invalid rows passed over (line 8: pose not finite, line 11: pose not rigid)"
    )
    assert ("up given as" if up.startswith("given") else "up found from the depth's level surfaces") in err
    said = re.search(r"floor (given|found) at (-?[\d.]+) m and moved to z = 0", err)
    assert said and said[1] == ("given" if up == "given with the floor" else "found") and abs(float(said[2]) - floor) < 0.01, err
    kept = [k for k in range(FRAMES) if k not in INVALID_TUM and k != NO_DEPTH]
    check_against_truth(ws, truth, kept)
    assert ws.camera.hfov_deg == pytest.approx(TUM_CAMERA.hfov_deg)
    view = ws.load(0)
    expected = render(home, TUM_CAMERA, truth[0])
    np.testing.assert_allclose(view.depth, expected.depth, atol=2e-4)  # 5000 per metre: 0.2 mm steps
    np.testing.assert_array_equal(view.rgb, expected.rgb)


def test_timestamps_are_associated_as_tums_associate_does():
    rgb = np.array([0.0, 0.033, 0.066, 0.1])
    depth = np.array([0.01, 0.03, 0.031, 0.2])
    # Closest first, each used once, within 0.02 s: 0.033-0.031, then 0.0-0.01; 0.066 and 0.1 have none left near.
    assert associate(rgb, depth) == {1: 2, 0: 0}


# --- layouts -------------------------------------------------------------------------------------


def test_the_layout_is_detected_or_named(scannet, tum, tmp_path):
    root, _, _ = tum
    assert FolderWorkspaceSource.carries(FolderConfig(path=root)) == {Data.RGB, Data.DEPTH}
    with pytest.raises(InputError, match=r"no captures.jsonl, no ScanNet frames .* and no TUM RGB-D sequence .*; set workspace.layout"):
        open_folder(tmp_path)
    with pytest.raises(InputError, match=r"rgb.txt: no such file or folder \(TUM RGB-D layout\)"):
        open_folder(scannet, layout="tum")
    (tmp_path / "rgb.txt").write_text("")
    (tmp_path / "groundtruth.txt").write_text("")
    problems = FolderWorkspaceSource.missing(FolderConfig(path=tmp_path))
    assert problems == [f"layout: no {tmp_path / 'depth.txt'} (tum layout)", f"floor_plan: no {tmp_path / 'floorplan.json'}, and no captures to derive one from"]


def test_captures_jsonl_takes_6dof_poses(home, truth, tmp_path):
    """camera_to_world rows (ssga's world) and pitched Habitat sensor states, level poses alike."""
    (tmp_path / "images").mkdir()
    rows = []
    for k, t in enumerate(truth[:6]):
        view = render(home, Camera(width=64, height=48, hfov_deg=90.0), t)
        write_png(tmp_path / "images" / f"{k}.png", view.rgb)
        write_png(tmp_path / "images" / f"{k}-d.png", depth_to_png16(view.depth))
        row = {"rgb": f"images/{k}.png", "depth": f"images/{k}-d.png"}
        if k % 2:
            row["camera_to_world"] = t.tolist()
        else:  # Habitat: y up, x_h = x, y_h = z, z_h = -y; its camera looks down -z with y up
            to_habitat = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])
            r = to_habitat @ t[:3, :3] @ np.diag([1.0, -1.0, -1.0])
            x, y, z, w = quaternion_xyzw(r)
            row |= {"position": (to_habitat @ t[:3, 3]).tolist(), "rotation": [w, x, y, z]}
        rows.append(row)
    (tmp_path / "captures.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    ws = open_folder(tmp_path, hfov_deg=90.0)
    for p, t in zip(ws.captures, truth[:6], strict=True):
        assert (p.x, p.y, p.height) == pytest.approx(tuple(t[:3, 3]), abs=1e-6)
        assert p.yaw == pytest.approx(heading(t), abs=1e-6)
    # Rows levelled with another up cannot stand beside rows already level.
    with pytest.raises(InputError, match=r"captures.jsonl:1: an x, y, yaw or Habitat pose, already level, among camera_to_world rows"):
        open_folder(tmp_path, up_axis="-y")
    # A level Habitat state gives what Pose.from_habitat gives.
    row = {"rgb": "images/0.png", "position": [1.0, 1.5, -2.0], "rotation": [math.cos(0.3), 0.0, math.sin(0.3), 0.0]}
    (tmp_path / "captures.jsonl").write_text(json.dumps(row) + "\n")
    (p,) = open_folder(tmp_path).captures
    expected = Pose.from_habitat(np.array(row["position"]), np.array(row["rotation"]))
    assert (p.x, p.y, p.yaw, p.height) == pytest.approx((expected.x, expected.y, expected.yaw, expected.height))
