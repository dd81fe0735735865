"""Captured images with poses and a floor plan, run through the same benchmark protocol.

The folder holds a ``captures.jsonl`` (one line per image) and a ``floorplan.json``
(:meth:`ssga_bench.workspace.FloorPlan.to_json`); see this package's README for the format.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from ssga_core import Camera, Data, InputError, Pose, SsgaError, StageConfig, View, WorkspaceSource, hookimpl
from ssga_bench import depth_from_png16, ids_from_png16, read_json, read_jsonl, read_png
from ssga_bench import FloorPlan


class FolderConfig(StageConfig):
    path: Path = Field(description="The folder holding the captures and the floor plan.")
    captures: str = Field(default="captures.jsonl", description="The captures file, relative to `path`.")
    floor_plan: str = Field(default="floorplan.json", description="The floor-plan file, relative to `path`.")
    hfov_deg: float = Field(default=90.0, gt=0.0, lt=180.0, description="Horizontal field of view of the camera, degrees.")
    yaw_in_degrees: bool = Field(default=False, description="Read `yaw` in degrees instead of radians.")


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

    def __init__(self, name: str, camera: Camera, floor_plan: FloorPlan, captures: list[Capture]) -> None:
        self.name, self.camera, self.floor_plan = name, camera, floor_plan
        self._captures = captures
        self.captures = [c.pose for c in captures]

    def load(self, index: int) -> View:
        c = self._captures[index]
        depth = _single(c.depth)
        semantic, instance = _single(c.semantic), _single(c.instance)
        try:
            return View(
                rgb=read_png(c.rgb, color=True),
                pose=c.pose,
                camera=self.camera,
                depth=None if depth is None else (depth.astype(np.float32) if depth.dtype.kind == "f" else depth_from_png16(depth)),
                semantic=None if semantic is None else ids_from_png16(semantic),
                instance=None if instance is None else ids_from_png16(instance),
            )
        except InputError as exc:
            raise InputError(f"{c.rgb}: {exc}") from None


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
    Config = FolderConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    @classmethod
    def carries(cls, config: StageConfig) -> frozenset[Data]:
        """RGB, and depth or semantic ids where every capture names such an image (read from the captures file)."""
        assert isinstance(config, FolderConfig)
        try:
            rows = read_jsonl(config.path / config.captures)
        except SsgaError:
            return cls.produces  # opening the workspace reports the file
        rows = [row for row in rows if isinstance(row, dict)]
        extra = {data for data, key in ((Data.DEPTH, "depth"), (Data.SEMANTIC, "semantic")) if rows and all(row.get(key) for row in rows)}
        return frozenset({Data.RGB, *extra})

    def open(self) -> FolderWorkspace:
        root = self.config.path
        if not root.is_dir():
            raise InputError(f"{root}: no such folder (workspace.path)")
        plan_path = root / self.config.floor_plan
        floor_plan = FloorPlan.from_json(read_json(plan_path), str(plan_path))
        captures_path = root / self.config.captures
        captures = [
            parse_capture(row, root, f"{captures_path}:{n}", self.config.yaw_in_degrees)
            for n, row in enumerate(read_jsonl(captures_path), 1)
        ]
        if not captures:
            raise InputError(f"{captures_path}: no captures")
        first = read_png(captures[0].rgb, color=True)
        camera = Camera(width=first.shape[1], height=first.shape[0], hfov_deg=self.config.hfov_deg)
        return FolderWorkspace(root.resolve().name, camera, floor_plan, captures)


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [FolderWorkspaceSource]
