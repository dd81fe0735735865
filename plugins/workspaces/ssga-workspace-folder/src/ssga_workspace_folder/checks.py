"""What is checked of every capture before a workspace opens, and how a bad one is reported.

A capture is refused with a one-line :class:`~ssga_core.InputError` naming it (the line of
``captures.jsonl``, or the sequence's frame) and the field at fault, or, where the config
asks to skip bad frames (and, in a sequence, always for an invalid pose), left out and
counted in one summary line. Nothing is guessed, and no numpy or OpenCV warning is ever
the only sign of a problem: every value is checked before it is computed with.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ssga_core import InputError

MAX_COORDINATE = 10_000.0
"""Positions farther than this from the origin (metres) are out of range: millimetres, or garbage."""

MAX_HEIGHT = 20.0
"""A camera higher than this above the floor (metres) is out of range; at or below the floor too."""

UNIT_TOLERANCE = 1e-2
"""How far a quaternion's norm may be from 1, and a rotation matrix from orthonormal (poses
written with 4-6 decimals are within it; a scale or a shear is not)."""

MIN_HEADING_SINE = math.sin(math.radians(10.0))
"""An optical axis within 10 degrees of vertical has no heading on the floor plane."""

DEPTH_MEDIAN_RANGE = (0.25, 15.0)
"""The median known depth of a capture (metres) must lie here: a median of 0.002 m is depth
read in the wrong units (centimetres, or metres stored as integers), one of 40 m depth
read with the wrong scale. Indoor RGB-D sensors see 0.2 to 10 m. A scale off by less than
these bounds allow (TUM's 5000 per metre read as millimetres) is not caught here."""

SIZE_TOLERANCE = 0.01
"""Depth of another size than its image must have the same aspect ratio within this share."""


POSE_KINDS = frozenset(
    {
        "unreadable pose",
        "pose not finite",
        "pose not rigid",
        "identity placeholder",
        "position out of range",
        "height out of range",
        "yaw out of range",
        "optical axis vertical",
    }
)
"""The problems of a pose itself: a recorded sequence skips such frames (tracking lost), never refuses them."""


class BadFrame(Exception):
    """A capture that cannot be used: which field, what kind of problem (for the summary), and why."""

    def __init__(self, field_name: str, kind: str, detail: str) -> None:
        super().__init__(f"{field_name}: {detail}")
        self.field = field_name
        self.kind = kind
        self.detail = detail

    @property
    def is_pose(self) -> bool:
        return self.kind in POSE_KINDS


@dataclass
class Skips:
    """Frames left out, by kind of problem, for one summary line."""

    source: str
    total: int = 0
    by_kind: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))
    prefix: str = ""
    """Put before a frame's name in an error (the folder, where the name is a sequence's ``frame 12``)."""

    def add(self, where: str, bad: BadFrame) -> None:
        self.by_kind[bad.kind].append(where)

    def handle(self, where: str, bad: BadFrame, *, skip: bool) -> None:
        """Record ``bad`` if ``skip``, else raise the one-line error naming ``where`` and the field."""
        if not skip:
            raise InputError(f"{self.prefix}{where}: {bad}") from None
        self.add(where, bad)

    @property
    def count(self) -> int:
        return sum(len(v) for v in self.by_kind.values())

    def summary(self) -> str | None:
        """``None`` if nothing was skipped, else one line: how many of how many, and why."""
        if not self.count:
            return None
        parts = []
        for kind, names in sorted(self.by_kind.items(), key=lambda kv: (-len(kv[1]), kv[0])):
            shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
            parts.append(f"{len(names)} {kind} ({shown})")
        return f"{self.source}: skipped {self.count} of {self.total} frames: " + "; ".join(parts)


# --- numbers ---------------------------------------------------------------------------------


def finite_number(value: object, name: str) -> float:
    """``value`` as a finite float, or a :class:`BadFrame` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise BadFrame(name, "unreadable pose", f"expected a number, got {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise BadFrame(name, "unreadable pose", f"expected a number, got {value!r}") from None
    if not math.isfinite(number):
        raise BadFrame(name, "pose not finite", f"{number} is not a finite number")
    return number


def finite_array(value: object, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``value`` as a float64 array of ``shape`` with finite entries, or a :class:`BadFrame`."""
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadFrame(name, "unreadable pose", f"expected {_shape_words(shape)} numbers, got {value!r}") from None
    if array.shape != shape:
        raise BadFrame(name, "unreadable pose", f"expected {_shape_words(shape)} numbers, got shape {array.shape}")
    if not np.isfinite(array).all():
        bad = array[~np.isfinite(array)][0]
        raise BadFrame(name, "pose not finite", f"holds {bad} (not a finite number)")
    return array


def _shape_words(shape: tuple[int, ...]) -> str:
    return " x ".join(str(s) for s in shape)


def check_position(position: np.ndarray, name: str) -> None:
    if np.abs(position).max() > MAX_COORDINATE:
        raise BadFrame(name, "position out of range", f"{_fmt(position)} is more than {MAX_COORDINATE:g} m from the origin (millimetres?)")


def check_height(height: float, name: str) -> None:
    if not 0.0 < height <= MAX_HEIGHT:
        where = "at or below the floor" if height <= 0 else f"more than {MAX_HEIGHT:g} m above the floor"
        raise BadFrame(name, "height out of range", f"the camera is {height:.3f} m high, {where} (floor at z = 0)")


def _fmt(values: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in np.ravel(values)) + ")"


# --- rotations -------------------------------------------------------------------------------


def unit_quaternion(q: np.ndarray, name: str) -> np.ndarray:
    """``q`` normalised, or a :class:`BadFrame` if it is far from unit length (a placeholder of zeros, a scale)."""
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise BadFrame(name, "pose not rigid", f"{_fmt(q)} is not a unit quaternion (norm {norm:.4g})")
    return q / norm


def quaternion_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of the unit quaternion ``w + xi + yj + zk``."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rigid_transform(matrix: np.ndarray, name: str) -> np.ndarray:
    """A ``4 x 4`` camera-to-world transform checked to be rigid (finite already), its rotation re-orthonormalised."""
    if not np.allclose(matrix[3], (0.0, 0.0, 0.0, 1.0), atol=1e-6):
        raise BadFrame(name, "pose not rigid", f"last row is {_fmt(matrix[3])}, not (0, 0, 0, 1)")
    rotation = matrix[:3, :3]
    error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    if error > UNIT_TOLERANCE:
        raise BadFrame(name, "pose not rigid", f"its 3 x 3 part is not a rotation (R^T R differs from I by {error:.3g}: a scale or a shear)")
    if np.linalg.det(rotation) < 0:
        raise BadFrame(name, "pose not rigid", "its 3 x 3 part is a reflection (determinant -1), not a rotation")
    u, _, vt = np.linalg.svd(rotation)
    out = matrix.copy()
    out[:3, :3] = u @ vt
    return out


# --- images ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImageHeader:
    """What an image file says about itself before it is decoded."""

    width: int
    height: int
    bits: int | None
    """Bits per channel of a single-channel image (8 or 16); None for colour or float arrays."""
    kind: str
    """``"grey"``, ``"colour"`` or ``"float"`` (a ``.npy`` of floats)."""

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


_GREY_MODES = {"L": 8, "I;16": 16, "I;16B": 16, "I;16L": 16, "I;16N": 16, "I": 32, "1": 1, "F": 32}


def image_header(path: Path, name: str) -> ImageHeader:
    """Size and bit depth from the file's header (``.npy``: its array header), nothing decoded."""
    if path.suffix == ".npy":
        try:
            array = np.load(path, mmap_mode="r")
        except (OSError, ValueError) as exc:
            raise BadFrame(name, "unreadable file", f"{path}: not a readable .npy array ({exc})") from None
        if array.ndim != 2:
            raise BadFrame(name, "depth of the wrong kind", f"{path}: expected a 2-D array, got shape {array.shape}")
        kind = "float" if array.dtype.kind == "f" else "grey"
        return ImageHeader(array.shape[1], array.shape[0], None if kind == "float" else array.dtype.itemsize * 8, kind)
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as image:
            mode, (width, height) = image.mode, image.size
    except FileNotFoundError:
        raise BadFrame(name, "missing file", f"{path} does not exist") from None
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise BadFrame(name, "unreadable file", f"{path}: not a readable image ({type(exc).__name__})") from None
    if mode in _GREY_MODES:
        return ImageHeader(width, height, _GREY_MODES[mode], "grey")
    return ImageHeader(width, height, None, "colour")


def check_depth_header(header: ImageHeader, path: Path, rgb_size: tuple[int, int] | None, name: str = "depth") -> None:
    """A depth file of the right kind: a 16-bit PNG or a float ``.npy``; and, given the image's
    size (``None`` where intrinsics map one onto the other), the same aspect ratio."""
    if path.suffix == ".npy":
        if header.kind != "float":
            raise BadFrame(name, "depth of the wrong kind", f"{path}: an integer .npy array; expected float metres")
    elif header.kind != "grey" or header.bits != 16:
        what = f"{header.bits}-bit grey" if header.kind == "grey" else "colour"
        raise BadFrame(name, "depth not 16-bit", f"{path} is {what}; expected a 16-bit PNG of depth (0 = unknown)")
    if rgb_size is not None and header.size != rgb_size:
        aspect, wanted = header.width / header.height, rgb_size[0] / rgb_size[1]
        if abs(aspect / wanted - 1.0) > SIZE_TOLERANCE:
            raise BadFrame(
                name,
                "depth of another size",
                f"{path} is {header.width} x {header.height}, its image {rgb_size[0]} x {rgb_size[1]} (another aspect ratio: not the same view)",
            )


def check_depth_values(depth: np.ndarray, path: Path, units: str, name: str = "depth") -> None:
    """Depth in metres whose known values (finite, > 0) are plausible; ``units`` says how it was read."""
    if depth.dtype.kind == "f" and (depth < 0).any():
        raise BadFrame(name, "depth out of range", f"{path} holds negative depths (as low as {float(np.nanmin(depth)):.3g} m)")
    known = depth[np.isfinite(depth) & (depth > 0)]
    if not known.size:
        return  # nothing seen: no depth, which is allowed
    median = float(np.median(known))
    low, high = DEPTH_MEDIAN_RANGE
    if not low <= median <= high:
        raise BadFrame(
            name,
            "depth out of range",
            f"{path}: median depth {median:.4g} m read as {units}, outside the plausible {low:g}-{high:g} m (other units or scale?)",
        )
