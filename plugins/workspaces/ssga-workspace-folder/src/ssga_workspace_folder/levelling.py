"""Which way is up in a sequence's world, and where its floor is: ssga's world is ``z`` up
with the floor at ``z = 0`` (:mod:`ssga_core.geometry`); a sequence's poses come in
whatever frame its tracker or motion-capture system chose.

* **Up** is given (``up_axis = "z"``, ``"-y"``, or a vector in the poses' frame), or found
  (``"auto"``) in two steps: a first guess from the cameras, which are held roughly upright
  (the mean of their up directions, ``-y`` in OpenCV's camera), then refined on the
  surfaces the depth saw: the area-weighted principal axis of the surface normals within
  45, then 20, then 10 degrees of the guess. Floors, tabletops, seats and ceilings are
  level to a fraction of a degree; walls, 90 degrees away, never enter the cones while
  the guess is within 45 degrees. Without depth, the guess stands, and the line printed
  says so.
* **The turn** is the smallest rotation taking up to ``+z`` (a world already ``z`` up is not
  turned about the vertical), as the mesh workspace levels a scan.
* **The floor** is the lowest level, below the cameras, holding at least
  :data:`FLOOR_SHARE` of the upward-facing surface of the busiest such level (2 cm levels,
  summed over 10 cm, so that a noisy floor does not split): it passes over depth noise
  under the floor and over tabletops above it. Without depth, or with no upward surface
  below the cameras, the floor is left where the poses' frame puts ``0``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ssga_core import InputError
from ssga_bench import lowest_level, rotation_to_z
from ssga_workspace_folder.images import Intrinsics

AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}

CONES_DEG = (45.0, 20.0, 10.0)
"""Normals within these angles of the current estimate refine it, in turn."""

FLOOR_SHARE = 0.25
"""The floor: the lowest level below the cameras with this share of the busiest level's upward area."""

UPWARD_DEG = 10.0
"""A surface faces up if its normal is within this angle of up."""

SURFACE_COLUMNS = 64
"""Depth maps are sampled on a grid about this many columns wide to find surfaces."""


def up_vector(value: str | Sequence[float]) -> np.ndarray | None:
    """``"x"``, ``"-y"``, a vector, as a unit vector; ``"auto"``: None."""
    if isinstance(value, str):
        if value == "auto":
            return None
        sign = -1.0 if value.startswith("-") else 1.0
        return sign * np.array(AXES[value.lstrip("+-")])
    vector = np.asarray(value, dtype=np.float64)
    return vector / np.linalg.norm(vector)


@dataclass(frozen=True)
class Levelling:
    """How a sequence's world was levelled."""

    up: np.ndarray
    """Unit up vector in the poses' frame."""
    how: str
    """``"given"``, ``"found from depth"``, ``"from the cameras"``."""
    floor: float | None
    """Height of the floor after the turn (None: not found, left at 0)."""
    share: float = 0.0
    """Share of the surface seen that faces along up (found from depth)."""
    floor_given: bool = False
    """Whether the floor's height was given (the config's, or captures.jsonl's z = 0) rather than found."""

    @property
    def rotation(self) -> np.ndarray:
        return rotation_to_z(self.up)

    @property
    def transform(self) -> np.ndarray:
        """``4 x 4``: the turn, then the shift putting the floor at ``z = 0``."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[2, 3] = -(self.floor or 0.0)
        return out

    def describe(self) -> str:
        x, y, z = (float(v) for v in self.up)
        k = int(np.argmax(np.abs(self.up)))
        axis = f"{'-' if self.up[k] < 0 else '+'}{'xyz'[k]}"
        off = math.degrees(math.acos(min(1.0, abs(float(self.up[k])))))
        what = {
            "given": f"up given as ({x:.3f}, {y:.3f}, {z:.3f})",
            "found from depth": f"up found from the depth's level surfaces ({100 * self.share:.0f}% of those seen): ({x:.3f}, {y:.3f}, {z:.3f})",
            "from the cameras": f"up taken from the cameras' mean up, no depth to refine it: ({x:.3f}, {y:.3f}, {z:.3f})",
        }[self.how]
        if self.floor is None:
            floor = "floor not seen in the depth: heights as the poses give them"
        else:
            floor = f"floor {'given' if self.floor_given else 'found'} at {self.floor:.3f} m and moved to z = 0"
        return f"{what}, {off:.1f} deg from the poses' {axis} axis; {floor}"


@dataclass(frozen=True)
class Surfaces:
    """Small surface patches one depth map saw, in its camera's frame."""

    points: np.ndarray
    normals: np.ndarray
    """Unit normals, facing the camera."""
    areas: np.ndarray


def surfaces(depth: np.ndarray, intrinsics: Intrinsics) -> Surfaces:
    """Patches between neighbouring samples of a depth map (metres, 0: unknown) that lie on
    one surface (the fourth corner where the other three put it, within 5% of its depth)."""
    step = max(1, intrinsics.width // SURFACE_COLUMNS)
    d = depth[::step, ::step].astype(np.float64)
    v, u = np.mgrid[0 : depth.shape[0] : step, 0 : depth.shape[1] : step].astype(np.float64)
    p = np.stack([(u - intrinsics.cx) / intrinsics.fx * d, (v - intrinsics.cy) / intrinsics.fy * d, d], axis=-1)
    p00, p01, p10, p11 = p[:-1, :-1], p[:-1, 1:], p[1:, :-1], p[1:, 1:]
    z = np.stack([d[:-1, :-1], d[:-1, 1:], d[1:, :-1], d[1:, 1:]])
    known = (np.isfinite(z) & (z > 0)).all(axis=0)
    flat = np.linalg.norm(p11 - (p01 + p10 - p00), axis=-1) <= 0.05 * np.where(known, z[0], 0.0)
    keep = known & flat
    cross = np.cross(p01 - p00, p10 - p00)[keep]
    areas = np.linalg.norm(cross, axis=-1)
    good = areas > 0
    normals = cross[good] / areas[good, None]
    centres = ((p00 + p11) / 2.0)[keep][good]
    normals *= np.where(np.sum(normals * centres, axis=-1) > 0, -1.0, 1.0)[:, None]  # towards the camera
    return Surfaces(centres, normals, areas[good])


def cameras_up(transforms: Sequence[np.ndarray]) -> np.ndarray:
    """The mean of the cameras' up directions (``-y`` in OpenCV's camera) in the poses' frame, unit length.

    Raises:
        InputError: the cameras agree on no up (mean shorter than 0.3: held every which way).
    """
    mean = -np.mean([t[:3, 1] for t in transforms], axis=0)
    norm = float(np.linalg.norm(mean))
    if norm < 0.3:
        raise InputError(f"the cameras' up directions agree on no up (mean length {norm:.2f}); give up_axis")
    return mean / norm


def find_up(transforms: Sequence[np.ndarray], seen: Sequence[Surfaces]) -> tuple[np.ndarray, float]:
    """Up refined on the surfaces ``seen`` from the camera ``transforms`` (one each; see the
    module docstring), and the share of the surface area along it; from the cameras alone
    (share 0) if too little surface is level."""
    up = cameras_up(transforms)
    if not seen:
        return up, 0.0
    normals = np.concatenate([s.normals @ t[:3, :3].T for s, t in zip(seen, transforms, strict=True)])
    areas = np.concatenate([s.areas for s in seen])
    if not areas.size:
        return up, 0.0
    guess = up
    for cone in CONES_DEG:
        near = np.abs(normals @ up) >= math.cos(math.radians(cone))
        if areas[near].sum() < 0.02 * areas.sum():
            return guess, 0.0
        n, w = normals[near], areas[near]
        _, vectors = np.linalg.eigh((n * w[:, None]).T @ n)
        up = vectors[:, -1] if vectors[:, -1] @ guess > 0 else -vectors[:, -1]
    share = float(areas[np.abs(normals @ up) >= math.cos(math.radians(CONES_DEG[-1]))].sum() / areas.sum())
    return up, share


def find_floor(rotation: np.ndarray, transforms: Sequence[np.ndarray], seen: Sequence[Surfaces], camera_heights: np.ndarray) -> float | None:
    """Height, after ``rotation``, of the floor the surfaces ``seen`` show below the cameras (see the module docstring)."""
    if not seen:
        return None
    heights, weights = [], []
    for s, t in zip(seen, transforms, strict=True):
        r = rotation @ t[:3, :3]
        upward = (s.normals @ r.T)[:, 2] >= math.cos(math.radians(UPWARD_DEG))
        heights.append((s.points[upward] @ r.T + rotation @ t[:3, 3])[:, 2])
        weights.append(s.areas[upward])
    z, w = np.concatenate(heights), np.concatenate(weights)
    below = z < float(np.median(camera_heights)) - 0.2
    z, w = z[below], w[below]
    if not z.size:
        return None
    return lowest_level(z, w, FLOOR_SHARE)
