"""The three folder layouts, read into one list of frames: files, and a pose checked as read.

* ``captures``: ``captures.jsonl``, one line per image (this package's own format).
* ``scannet``: ScanNet's exported frames, ``color/N.jpg``, ``depth/N.png`` (16-bit
  millimetres), ``pose/N.txt`` (``4 x 4`` camera-to-world, OpenCV's camera; rows of
  ``-inf`` where tracking was lost), ``intrinsic/intrinsic_color.txt`` and
  ``intrinsic/intrinsic_depth.txt``.
* ``tum``: a TUM RGB-D sequence, ``rgb.txt`` and ``depth.txt`` (``timestamp file``),
  ``groundtruth.txt`` (``timestamp tx ty tz qx qy qz qw``, the colour camera's optical
  centre in the motion-capture world), depth PNGs of 5000 per metre. Colour and depth are
  paired as TUM's ``associate.py`` pairs them (closest first, each used once, within
  :data:`TOLERANCE_S`), and each pair takes the nearest valid ground-truth row within it.

A pose problem found while reading stays with its frame (:attr:`Frame.bad`), for the
workspace to refuse or skip (:mod:`.checks`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from ssga_core import InputError, Pose
from ssga_bench import read_jsonl
from ssga_workspace_folder.checks import BadFrame, finite_array, image_header, rigid_transform
from ssga_workspace_folder.images import Intrinsics
from ssga_workspace_folder.poses import parse_row, quaternion_transform

Layout = Literal["auto", "captures", "scannet", "tum"]

TOLERANCE_S = 0.02
"""Colour, depth and ground truth are associated within this many seconds (TUM's ``associate.py``)."""

SCANNET_DEPTH_SCALE = 1000.0
TUM_DEPTH_SCALE = 5000.0
TUM_FOCAL_PX = 525.0
"""TUM's default intrinsics (fx = fy = 525, centred, at 640 x 480), to which its depth is registered."""

LABELS = {"captures": "captures.jsonl", "scannet": "ScanNet frames", "tum": "TUM RGB-D"}


@dataclass(frozen=True, eq=False)
class Frame:
    """One capture as its layout names it, before its images are checked."""

    where: str
    """How errors name it: ``captures.jsonl:7``, ``frame 120``, ``rgb.txt:57``."""
    rgb: Path | None
    pose: Pose | np.ndarray | None = None
    """A level :class:`Pose`, or a ``4 x 4`` camera-to-world transform (OpenCV's camera)."""
    levelled: bool = True
    """Whether a transform is in ssga's world already (a Habitat state) or in the file's, to be levelled."""
    depth: Path | None = None
    semantic: Path | None = None
    instance: Path | None = None
    bad: BadFrame | None = None


@dataclass
class Folder:
    """A folder's frames and what its layout says about its cameras."""

    layout: str
    frames: list[Frame]
    colour: Intrinsics | None = None
    """Colour intrinsics at the stored size (None: from ``hfov_deg``, centred)."""
    depth: Intrinsics | None = None
    """Depth intrinsics at the stored depth size (None: the colour's, scaled)."""
    depth_scale: float = 1000.0
    sequence: bool = False
    """A recorded sequence: frames with invalid poses are always skipped, never refused."""
    dropped: list[tuple[str, BadFrame]] = field(default_factory=list)
    """Frames left out while reading (no depth or pose within the tolerance)."""
    notes: list[str] = field(default_factory=list)
    """Said in the summary line (ground-truth rows passed over)."""

    @property
    def label(self) -> str:
        return LABELS[self.layout]


def detect(root: Path, layout: Layout, captures: str) -> str:
    """The layout of the folder ``root`` (as configured, or from the files there).

    Raises:
        InputError: ``auto`` and no layout's files are there.
    """
    if layout != "auto":
        return layout
    if (root / captures).is_file():
        return "captures"
    if (root / "color").is_dir() and (root / "pose").is_dir():
        return "scannet"
    if (root / "rgb.txt").is_file() and (root / "groundtruth.txt").is_file():
        return "tum"
    raise InputError(
        f"{root}: no {captures}, no ScanNet frames (color/, depth/, pose/, intrinsic/) and no TUM RGB-D sequence "
        "(rgb.txt, depth.txt, groundtruth.txt); set workspace.layout or add the files"
    )


def required_files(root: Path, layout: str, captures: str) -> list[tuple[str, Path]]:
    """``(field, path)`` of the files a layout cannot open without."""
    if layout == "captures":
        return [("captures", root / captures)]
    if layout == "scannet":
        return [("layout", root / p) for p in ("color", "depth", "pose", "intrinsic/intrinsic_color.txt", "intrinsic/intrinsic_depth.txt")]
    return [("layout", root / p) for p in ("rgb.txt", "depth.txt", "groundtruth.txt")]


def read_folder(root: Path, layout: str, *, captures: str = "captures.jsonl", yaw_in_degrees: bool = False) -> Folder:
    """The frames of ``root`` in ``layout`` (not ``auto``: :func:`detect` first)."""
    for _, path in required_files(root, layout, captures):
        if not path.exists():
            raise InputError(f"{path}: no such file or folder ({LABELS[layout]} layout)")
    if layout == "captures":
        return read_captures(root / captures, root, yaw_in_degrees)
    if layout == "scannet":
        return read_scannet(root)
    return read_tum(root)


# --- captures.jsonl ------------------------------------------------------------------------------


def read_captures(path: Path, root: Path, yaw_in_degrees: bool) -> Folder:
    lines = path.read_text(encoding="utf-8").splitlines() if path.is_file() else []
    numbers = [n for n, line in enumerate(lines, 1) if line.strip()]
    frames = [_capture(row, root, f"{path}:{n}", yaw_in_degrees) for n, row in zip(numbers, read_jsonl(path), strict=True)]
    return Folder("captures", frames)


def _capture(row: object, root: Path, where: str, yaw_in_degrees: bool) -> Frame:
    if not isinstance(row, dict):
        return Frame(where, None, bad=BadFrame("line", "unreadable line", f"expected a JSON object, got {type(row).__name__}"))
    files: dict[str, Path] = {}
    for key in ("rgb", "depth", "semantic", "instance"):
        value = row.get(key)
        if value is not None and not isinstance(value, str):
            return Frame(where, None, bad=BadFrame(key, "unreadable line", f"expected a file name, got {value!r}"))
        if value:
            files[key] = root / value
    try:
        kind, pose = parse_row(row, yaw_in_degrees)
    except BadFrame as bad:
        return Frame(where, files.get("rgb"), bad=bad)
    bad = None
    if "rgb" not in files:
        bad = BadFrame("rgb", "no image", "no image named")
    else:
        missing = next((k for k, p in files.items() if not p.is_file()), None)
        if missing:
            bad = BadFrame(missing, "missing file", f"image {files[missing]} does not exist")
    return Frame(where, files.pop("rgb", None), pose, kind != "matrix", bad=bad, **files)


# --- ScanNet --------------------------------------------------------------------------------------

_NUMBERED = re.compile(r"\d+")


def read_scannet(root: Path) -> Folder:
    colours = sorted(
        (p for p in (root / "color").iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png") and _NUMBERED.fullmatch(p.stem)),
        key=lambda p: int(p.stem),
    )
    if not colours:
        raise InputError(f"{root / 'color'}: no numbered colour images (0.jpg, 1.jpg, ...)")
    frames = []
    for colour in colours:
        n = colour.stem
        where, depth, pose_file = f"frame {n}", root / "depth" / f"{n}.png", root / "pose" / f"{n}.txt"
        try:
            pose = scannet_pose(pose_file)
            bad = None if depth.is_file() else BadFrame("depth", "missing file", f"{depth} does not exist")
        except BadFrame as exc:
            pose, bad = None, exc
        frames.append(Frame(where, colour, pose, levelled=False, depth=depth, bad=bad))
    def intrinsics(name: str, example: Path) -> Intrinsics:
        path = root / "intrinsic" / name
        try:
            header = image_header(example, name)
        except BadFrame as bad:
            raise InputError(f"{example}: {bad.detail}") from None
        return Intrinsics.from_matrix(_matrix(path), header.width, header.height, str(path))

    first_depth = next((f.depth for f in frames if f.depth is not None and f.depth.is_file()), None)
    if first_depth is None:
        raise InputError(f"{root / 'depth'}: no depth image for any frame")
    return Folder(
        "scannet",
        frames,
        colour=intrinsics("intrinsic_color.txt", colours[0]),
        depth=intrinsics("intrinsic_depth.txt", first_depth),
        depth_scale=SCANNET_DEPTH_SCALE,
        sequence=True,
    )


def _matrix(path: Path) -> np.ndarray:
    try:
        rows = [[float(v) for v in line.split()] for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
        return np.array(rows, dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a matrix of numbers ({exc})") from None


def scannet_pose(path: Path) -> np.ndarray:
    """A ScanNet ``pose/N.txt``: a rigid ``4 x 4`` camera-to-world, or a :class:`BadFrame`
    (missing, unreadable, ``-inf`` where tracking was lost, the identity placeholder)."""
    if not path.is_file():
        raise BadFrame("pose", "missing file", f"{path} does not exist")
    try:
        rows = [[float(v) for v in line.split()] for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, ValueError) as exc:
        raise BadFrame("pose", "unreadable pose", f"{path}: not a 4 x 4 matrix of numbers ({exc})") from None
    if len(rows) != 4 or any(len(r) != 4 for r in rows):
        raise BadFrame("pose", "unreadable pose", f"{path}: expected 4 rows of 4 numbers")
    matrix = finite_array(rows, "pose", (4, 4))
    if np.array_equal(matrix, np.eye(4)):
        raise BadFrame("pose", "identity placeholder", f"{path} is the identity, written where no pose was known")
    return rigid_transform(matrix, "pose")


# --- TUM RGB-D ------------------------------------------------------------------------------------


def _stamped(path: Path) -> list[tuple[int, float, list[str]]]:
    """``(line number, timestamp, the rest)`` of each data line of a TUM list file."""
    out = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.replace(",", " ").split()
        try:
            stamp = float(fields[0])
        except ValueError:
            raise InputError(f"{path}:{n}: expected a timestamp first, got {fields[0]!r}") from None
        if not np.isfinite(stamp):
            raise InputError(f"{path}:{n}: timestamp {stamp} is not a finite number")
        out.append((n, stamp, fields[1:]))
    return out


def associate(first: np.ndarray, second: np.ndarray, tolerance: float = TOLERANCE_S) -> dict[int, int]:
    """Index pairs ``{i: j}`` of timestamps less than ``tolerance`` apart, closest first, each
    used once (TUM's ``associate.py``, without its offset)."""
    order = np.argsort(second)
    sorted_second = second[order]
    candidates = []
    for i, t in enumerate(first):
        lo, hi = np.searchsorted(sorted_second, (t - tolerance, t + tolerance))
        candidates += [(abs(t - sorted_second[k]), i, int(order[k])) for k in range(lo, hi) if abs(t - sorted_second[k]) < tolerance]
    pairs: dict[int, int] = {}
    used: set[int] = set()
    for _, i, j in sorted(candidates):
        if i not in pairs and j not in used:
            pairs[i] = j
            used.add(j)
    return pairs


def read_tum(root: Path) -> Folder:
    rgb_list, depth_list = root / "rgb.txt", root / "depth.txt"
    rgb, depth = _stamped(rgb_list), _stamped(depth_list)
    for path, rows in ((rgb_list, rgb), (depth_list, depth)):
        short = next((n for n, _, rest in rows if not rest), None)
        if short is not None:
            raise InputError(f"{path}:{short}: expected 'timestamp file'")
    truth_file = root / "groundtruth.txt"
    stamps, poses, invalid = [], [], []
    for n, stamp, rest in _stamped(truth_file):
        try:
            values = finite_array([_number(v) for v in rest], "pose", (7,))
            poses.append(quaternion_transform(values[:3], values[3:], "pose"))
            stamps.append(stamp)
        except BadFrame as bad:
            invalid.append(f"line {n}: {bad.kind}")
    folder = Folder("tum", [], depth_scale=TUM_DEPTH_SCALE, sequence=True)
    if invalid:
        shown = ", ".join(invalid[:3]) + (", ..." if len(invalid) > 3 else "")
        folder.notes.append(f"{truth_file.name}: {len(invalid)} invalid rows passed over ({shown})")
    pairs = associate(np.array([s for _, s, _ in rgb]), np.array([s for _, s, _ in depth]))
    order = np.argsort(np.array(stamps))
    truth = np.array(stamps)[order]
    for i, (n, stamp, rest) in enumerate(rgb):
        where = f"{rgb_list.name}:{n}"
        if i not in pairs:
            folder.dropped.append((where, BadFrame("depth", "no depth within 0.02 s", f"no depth image within {TOLERANCE_S} s of {stamp}")))
            continue
        nearest = _nearest(truth, stamp)
        if nearest is None:
            folder.dropped.append((where, BadFrame("pose", "no valid pose within 0.02 s", f"no valid ground-truth row within {TOLERANCE_S} s of {stamp}")))
            continue
        folder.frames.append(Frame(where, root / rest[0], poses[int(order[nearest])], levelled=False, depth=root / depth[pairs[i]][2][0]))
    return folder


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise BadFrame("pose", "unreadable pose", f"{text!r} is not a number") from None


def _nearest(stamps: np.ndarray, t: float) -> int | None:
    """The index of the timestamp nearest ``t`` in the sorted ``stamps``, if within the tolerance."""
    if not stamps.size:
        return None
    k = int(np.searchsorted(stamps, t))
    best = min((j for j in (k - 1, k) if 0 <= j < len(stamps)), key=lambda j: abs(stamps[j] - t))
    return best if abs(stamps[best] - t) < TOLERANCE_S else None


def tum_intrinsics(width: int, height: int) -> Intrinsics:
    """TUM's default intrinsics scaled to the stored size (640 x 480)."""
    return Intrinsics(TUM_FOCAL_PX, TUM_FOCAL_PX, 319.5, 239.5, 640, 480).scaled(width, height)

