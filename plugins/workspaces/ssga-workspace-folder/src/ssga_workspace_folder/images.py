"""A capture's pixels as ssga's camera sees them: colour, and depth in metres on the colour's grid.

ssga's :class:`~ssga_core.Camera` has square pixels and its principal point at the image's
centre. A sequence's cameras rarely do (ScanNet's colour camera: ``fx = 1170``, ``fy =
1167``, ``cx = 646.3`` on a 1296 x 968 image), and its depth may come from another camera
model and size (ScanNet's 640 x 480 depth, ``fx = 572``): both are resampled onto the
workspace's camera through their intrinsics (:func:`resample`: an affine map, since
colour and depth share the pose), colour bilinearly, depth by nearest samples (never a
blend of two surfaces).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ssga_core import Camera, InputError
from ssga_workspace_folder.checks import BadFrame, check_depth_values

SAME_PIXEL = 0.05
"""Intrinsics whose mapping moves no pixel by more than this (pixels) need no resampling."""


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole camera's intrinsics at an image size (pixel centres at integer coordinates)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def of(cls, camera: Camera) -> Intrinsics:
        cx, cy = camera.principal_point
        return cls(camera.focal_px, camera.focal_px, cx, cy, camera.width, camera.height)

    @classmethod
    def from_matrix(cls, k: np.ndarray, width: int, height: int, source: str) -> Intrinsics:
        """From a ``3 x 3`` (or ``4 x 4``) matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        k = np.asarray(k, dtype=np.float64)
        if k.shape not in ((3, 3), (4, 4)) or not np.isfinite(k).all():
            raise InputError(f"{source}: expected a 3 x 3 or 4 x 4 matrix of finite numbers, got shape {k.shape}")
        fx, fy, cx, cy = float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
        if not (fx > 0 and fy > 0 and 0 <= cx <= width and 0 <= cy <= height):
            raise InputError(f"{source}: fx = {fx:g}, fy = {fy:g}, cx = {cx:g}, cy = {cy:g} do not fit a {width} x {height} image")
        return cls(fx, fy, cx, cy, width, height)

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width / 2.0 / self.fx))

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same camera's intrinsics for the image resized to ``width x height``."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5, width, height)

    def camera(self) -> Camera:
        """ssga's camera of this image size with this horizontal focal length (square pixels, centred)."""
        return Camera(width=self.width, height=self.height, hfov_deg=self.hfov_deg)


def resample(image: np.ndarray, source: Intrinsics, target: Intrinsics, *, nearest: bool) -> np.ndarray:
    """``image`` (taken with ``source``) as ``target`` would see it from the same pose; outside it: 0
    (unknown) for ``nearest`` samples (depth, ids), the nearest edge pixel for colour (no black seam)."""
    import cv2

    a, c = source.fx / target.fx, source.fy / target.fy
    b, d = source.cx - a * target.cx, source.cy - c * target.cy
    if (source.width, source.height) == (target.width, target.height):
        corners = np.array([[0.0, 0.0], [target.width - 1.0, target.height - 1.0]])
        moved = np.abs(corners * (a, c) + (b, d) - corners).max()
        if moved <= SAME_PIXEL:
            return image
    flags = (cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR) | cv2.WARP_INVERSE_MAP
    return cv2.warpAffine(image, np.array([[a, 0.0, b], [0.0, c, d]]), (target.width, target.height), flags=flags, borderMode=cv2.BORDER_CONSTANT if nearest else cv2.BORDER_REPLICATE, borderValue=0)


def read_depth(path: Path, scale: float, name: str = "depth") -> np.ndarray:
    """Depth in metres (``0``: unknown) from a 16-bit PNG of ``scale`` units per metre, or a
    float ``.npy`` in metres (non-finite: unknown), its values checked for plausibility.

    Raises:
        BadFrame: unreadable, of the wrong kind, negative, or an implausible range.
    """
    if path.suffix == ".npy":
        try:
            raw = np.load(path)
        except (OSError, ValueError) as exc:
            raise BadFrame(name, "unreadable file", f"{path}: not a readable .npy array ({exc})") from None
        if raw.ndim != 2 or raw.dtype.kind != "f":
            raise BadFrame(name, "depth of the wrong kind", f"{path}: expected a 2-D float array in metres, got {raw.dtype} {raw.shape}")
        depth = np.where(np.isfinite(raw), raw, 0.0).astype(np.float32)
        check_depth_values(raw, path, "metres", name)
        return depth
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise BadFrame(name, "unreadable file", f"{path}: not a readable image")
    if raw.ndim != 2 or raw.dtype != np.uint16:
        bits = raw.dtype.itemsize * 8
        raise BadFrame(name, "depth not 16-bit", f"{path} is a {bits}-bit image of shape {raw.shape}; expected a 16-bit PNG of depth (0 = unknown)")
    depth = raw.astype(np.float32) / np.float32(scale)
    check_depth_values(depth, path, f"{scale:g} per metre", name)
    return depth
