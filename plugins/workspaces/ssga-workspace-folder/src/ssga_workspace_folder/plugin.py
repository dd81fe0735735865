"""Captured images with poses, run through the same benchmark protocol.

The folder holds a ``captures.jsonl`` (one line per image) and, if someone drew one, a
``floorplan.json`` (:meth:`ssga_bench.workspace.FloorPlan.to_json`); without it the
floor plan is derived from the captures' poses and depth (:mod:`.floorplan`). See this
package's README for the format.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from ssga_core import Camera, Data, InputError, Pose, SsgaError, StageConfig, View, WorkspaceSource, hookimpl
from ssga_bench import depth_from_png16, fit_channel, ids_from_png16, read_json, read_jsonl, read_png, read_rgb
from ssga_bench import FloorPlan
from ssga_workspace_folder.floorplan import floor_plan_from_captures


DEFAULT_FLOOR_PLAN = "floorplan.json"
"""Looked for in the folder; when it is not there the floor plan is derived. A plan the
config names explicitly must be there."""


class FolderConfig(StageConfig):
    path: Path = Field(description="The folder holding the captures (and a floor plan, if one was drawn).")
    captures: str = Field(default="captures.jsonl", description="The captures file, relative to `path`.")
    floor_plan: str = Field(
        default=DEFAULT_FLOOR_PLAN,
        description="A hand-drawn floor plan, relative to `path`. The default file is used when it is there, else a plan is "
        "derived from the captures; another name must exist.",
    )
    derive_floor_plan: bool = Field(
        default=True, description="Without the floor-plan file, derive one from the captures' poses and depth; false requires the file."
    )
    hfov_deg: float = Field(default=90.0, gt=0.0, lt=180.0, description="Horizontal field of view of the camera, degrees.")
    yaw_in_degrees: bool = Field(default=False, description="Read `yaw` in degrees instead of radians.")
    max_side: int | None = Field(
        default=1024,
        ge=16,
        le=16384,
        description="Captures whose longest side is larger are read reduced to it (a JPEG decoded reduced, never whole), "
        "their depth and ids with them by nearest samples; None: as captured.",
    )
    plan_resolution: float = Field(default=0.1, ge=0.02, le=1.0, description="Derived floor plan: its grid, metres.")
    robot_radius: float = Field(
        default=0.3, gt=0.0, le=5.0, description="Derived floor plan: how far around each capture (and the path between) the floor is free, metres."
    )
    clearance: float = Field(default=0.25, ge=0.0, le=5.0, description="Derived floor plan: how far from a seen obstacle a camera may stand, metres.")
    max_depth: float = Field(default=6.0, gt=0.0, le=100.0, description="Derived floor plan: depth beyond this is not used, metres.")


@dataclass(frozen=True)
class Capture:
    pose: Pose
    rgb: Path
    depth: Path | None = None
    semantic: Path | None = None
    instance: Path | None = None


def parse_capture(row: dict[str, Any], root: Path, where: str, yaw_in_degrees: bool) -> Capture:
    """One line of ``captures.jsonl``: files relative to the folder, and an ssga or a Habitat pose."""
    try:
        if "position" in row:
            pose = Pose.from_habitat(np.asarray(row["position"], float), np.asarray(row["rotation"], float))
        else:
            yaw = float(row["yaw"])
            pose = Pose(float(row["x"]), float(row["y"]), math.radians(yaw) if yaw_in_degrees else yaw, float(row.get("height", 1.5)))
        files = {k: root / row[k] for k in ("rgb", "depth", "semantic", "instance") if row.get(k)}
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"{where}: expected rgb and a pose (x, y, yaw[, height]) or a Habitat sensor state (position, rotation), "
            f"got {sorted(row)} ({type(exc).__name__}: {exc})"
        ) from None
    if "rgb" not in files:
        raise InputError(f"{where}: no rgb image named")
    for name, path in files.items():
        if not path.is_file():
            raise InputError(f"{where}: {name} image {path} does not exist")
    return Capture(pose=pose, **files)


class FolderWorkspace:
    """A :class:`ssga_bench.workspace.CapturedWorkspace` over the captures of one folder."""

    def __init__(self, name: str, camera: Camera, floor_plan: FloorPlan, captures: list[Capture], max_side: int | None = None) -> None:
        self.name, self.camera, self.floor_plan = name, camera, floor_plan
        self._captures = captures
        self.captures = [c.pose for c in captures]
        self.max_side = max_side

    def load(self, index: int) -> View:
        c = self._captures[index]
        semantic, instance = _single(c.semantic), _single(c.instance)
        try:
            rgb, _ = read_rgb(c.rgb, self.max_side)
            shape = rgb.shape[:2]
            return View(
                rgb=rgb,
                pose=c.pose,
                camera=self.camera,
                depth=_fitted(depth_of(c), shape),
                semantic=None if semantic is None else fit_channel(ids_from_png16(semantic), shape),
                instance=None if instance is None else fit_channel(ids_from_png16(instance), shape),
            )
        except InputError as exc:
            raise InputError(f"{c.rgb}: {exc}") from None


def _fitted(depth: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    return None if depth is None else fit_channel(depth, shape)


def depth_of(capture: Capture) -> np.ndarray | None:
    """A capture's planar depth in metres (``0``: unknown), or None if it has none."""
    depth = _single(capture.depth)
    if depth is None:
        return None
    return depth.astype(np.float32) if depth.dtype.kind == "f" else depth_from_png16(depth)


def _single(path: Path | None) -> np.ndarray | None:
    """A depth map or id map: 16-bit PNG, or ``.npy`` (depth in metres)."""
    if path is None:
        return None
    if path.suffix == ".npy":
        try:
            return np.load(path)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    return read_png(path, color=False)


class FolderWorkspaceSource(WorkspaceSource):
    """Views that were captured rather than rendered: the protocol selects among them."""

    name = "folder"
    fits_protocol = True  # a user's scan or captures: the protocol is fitted to them where it does not fit (protocol.fit)
    Config = FolderConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    @classmethod
    def carries(cls, config: StageConfig) -> frozenset[Data]:
        """RGB, and depth or semantic ids where every capture names such an image (read from the captures file)."""
        assert isinstance(config, FolderConfig)
        try:
            rows = list(read_jsonl(config.path / config.captures))  # read_jsonl is lazy: its errors come while reading
        except SsgaError:
            return cls.produces  # validation reports the file (missing), as opening the workspace would
        rows = [row for row in rows if isinstance(row, dict)]
        extra = {data for data, key in ((Data.DEPTH, "depth"), (Data.SEMANTIC, "semantic")) if rows and all(row.get(key) for row in rows)}
        return frozenset({Data.RGB, *extra})

    @classmethod
    def missing(cls, config: StageConfig) -> list[str]:
        """The folder, the captures file, and a floor plan or captures to derive one from."""
        assert isinstance(config, FolderConfig)
        root = config.path
        if not root.is_dir():
            return [f"path: no such folder {root}"]
        problems, rows = [], []
        captures = root / config.captures
        try:
            rows = list(read_jsonl(captures))
        except SsgaError as exc:
            problems.append(f"captures: {exc}")
        else:
            if not rows:
                problems.append(f"captures: {captures} has no captures")
        plan = root / config.floor_plan
        if not plan.is_file():
            if not config.derive_floor_plan:
                problems.append(f"floor_plan: no {plan}; draw one, or set derive_floor_plan = true to derive it from the captures")
            elif config.floor_plan != DEFAULT_FLOOR_PLAN:
                problems.append(f"floor_plan: no {plan} (named in the config; leave floor_plan out to derive one from the captures)")
            elif not rows:
                problems.append(f"floor_plan: no {plan}, and no captures to derive one from")
        return problems

    def open(self) -> FolderWorkspace:
        config: FolderConfig = self.config  # type: ignore[assignment]
        root = config.path
        if not root.is_dir():
            raise InputError(f"{root}: no such folder (workspace.path)")
        captures_path = root / config.captures
        captures = [
            parse_capture(row, root, f"{captures_path}:{n}", config.yaw_in_degrees) for n, row in enumerate(read_jsonl(captures_path), 1)
        ]
        if not captures:
            raise InputError(f"{captures_path}: no captures")
        first, original = read_rgb(captures[0].rgb, config.max_side)
        camera = Camera(width=first.shape[1], height=first.shape[0], hfov_deg=config.hfov_deg)
        if original:
            print(f"{root}: captures of {original[0]} x {original[1]} read reduced to {camera.width} x {camera.height} (workspace.max_side)", file=sys.stderr)
        plan_path = root / config.floor_plan
        if plan_path.is_file() or not config.derive_floor_plan or config.floor_plan != DEFAULT_FLOOR_PLAN:
            floor_plan = FloorPlan.from_json(read_json(plan_path), str(plan_path))  # a hand-drawn plan wins
        else:
            derived = floor_plan_from_captures(
                [c.pose for c in captures],
                camera,
                (_fitted(depth_of(c), first.shape[:2]) for c in captures),
                resolution=config.plan_resolution,
                robot_radius=config.robot_radius,
                clearance=config.clearance,
                max_depth=config.max_depth,
                source=str(captures_path),
            )
            # Said before anything runs, so a plan that looks wrong is seen before a build uses it.
            print(f"{root}: no {config.floor_plan}; {derived.describe()}", file=sys.stderr)
            floor_plan = derived.plan
        return FolderWorkspace(root.resolve().name, camera, floor_plan, captures, config.max_side)


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [FolderWorkspaceSource]
