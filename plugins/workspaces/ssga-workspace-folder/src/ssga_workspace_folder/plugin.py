"""Captured images with poses, run through the same benchmark protocol.

The folder holds a ``captures.jsonl`` (one line per image), ScanNet's exported frames or a
TUM RGB-D sequence (:mod:`.layouts`), and, if someone drew one, a ``floorplan.json``
(:meth:`ssga_bench.workspace.FloorPlan.to_json`); without it the floor plan is derived
from the captures' poses and depth (:mod:`ssga_bench.seen_floor`). Every capture is checked before
the workspace opens (:mod:`.workspace`, :mod:`.checks`). See this package's README for
the formats.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from ssga_core import Data, InputError, SsgaError, StageConfig, WorkspaceSource, hookimpl
from ssga_bench import read_jsonl
from ssga_workspace_folder.layouts import Layout, detect, required_files
from ssga_workspace_folder.workspace import DEFAULT_FLOOR_PLAN, FolderWorkspace, open_folder

AXIS_NAMES = ("x", "y", "z", "-x", "-y", "-z")


class FolderConfig(StageConfig):
    path: Path = Field(description="The folder holding the captures (and a floor plan, if one was drawn).")
    layout: Layout = Field(
        default="auto",
        description="What the folder holds: 'captures' (captures.jsonl), 'scannet' (color/, depth/, pose/, intrinsic/), 'tum' "
        "(rgb.txt, depth.txt, groundtruth.txt); 'auto': whichever of these files are there, in that order.",
    )
    captures: str = Field(default="captures.jsonl", description="The captures file, relative to `path` (layout 'captures').")
    skip_bad_frames: bool = Field(
        default=False,
        description="Leave out a capture that fails a check (its pose, its images' size, bit depth or depth range) and say how "
        "many were left out and why, instead of refusing the folder. A sequence's frames with invalid poses are always left out.",
    )
    floor_plan: str = Field(
        default=DEFAULT_FLOOR_PLAN,
        description="A hand-drawn floor plan, relative to `path`. The default file is used when it is there, else a plan is "
        "derived from the captures; another name must exist.",
    )
    derive_floor_plan: bool = Field(
        default=True, description="Without the floor-plan file, derive one from the captures' poses and depth; false requires the file."
    )
    hfov_deg: float | None = Field(
        default=None,
        gt=0.0,
        lt=180.0,
        description="Horizontal field of view of the colour camera, degrees (square pixels, centred). None: 90 for "
        "captures.jsonl, ScanNet's intrinsic_color.txt, TUM's 525 px focal length at 640 x 480.",
    )
    intrinsics: tuple[float, float, float, float] | None = Field(
        default=None,
        description="The colour camera's fx, fy, cx, cy in pixels at the images' stored size, where they are not square and "
        "centred (images are resampled to a camera that is); wins over hfov_deg and the layout's own.",
    )
    yaw_in_degrees: bool = Field(default=False, description="Read `yaw` in degrees instead of radians.")
    up_axis: Literal["auto", "x", "y", "z", "-x", "-y", "-z"] | tuple[float, float, float] = Field(
        default="auto",
        description="Up in the frame of the 6-DoF poses (camera_to_world rows, ScanNet, TUM): an axis ('z', '-y'), or the "
        "floor's normal [x, y, z]. 'auto': 'z' for captures.jsonl (ssga's world); for a sequence, found from the depth's "
        "level surfaces (the cameras' mean up without depth). The world is turned so that up is +z; a line says what was found.",
    )
    floor_height: float | None = Field(
        default=None,
        description="Where the floor is along up_axis in the 6-DoF poses' frame, metres. None: 0 for captures.jsonl with up z; "
        "else found from the depth (the lowest level surface below the cameras), 0 without depth.",
    )
    depth_scale: float | None = Field(
        default=None,
        gt=0.0,
        description="Units per metre of the 16-bit depth PNGs. None: the layout's (1000, millimetres; TUM 5000).",
    )
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

    @field_validator("up_axis", mode="before")
    @classmethod
    def _an_axis_or_a_direction(cls, value: object) -> object:
        if value == "auto" or value in AXIS_NAMES:
            return value
        if isinstance(value, (list, tuple)) and len(value) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            if all(math.isfinite(v) for v in value) and math.hypot(*value) > 1e-9:
                return tuple(float(v) for v in value)
        raise ValueError(f"expected 'auto', one of {', '.join(AXIS_NAMES)}, or a non-zero [x, y, z] vector; got {value!r}")

    @field_validator("intrinsics")
    @classmethod
    def _positive_focal_lengths(cls, value: tuple[float, float, float, float] | None) -> object:
        if value is not None and not (all(math.isfinite(v) for v in value) and value[0] > 0 and value[1] > 0):
            raise ValueError(f"expected finite [fx, fy, cx, cy] with fx, fy > 0; got {list(value)}")
        return value


class FolderWorkspaceSource(WorkspaceSource):
    """Views that were captured rather than rendered: the protocol selects among them."""

    name = "folder"
    fits_protocol = True  # a user's scan or captures: the protocol is fitted to them where it does not fit (protocol.fit)
    Config = FolderConfig
    produces = frozenset({Data.RGB, Data.DEPTH, Data.SEMANTIC})

    @classmethod
    def carries(cls, config: StageConfig) -> frozenset[Data]:
        """RGB, and depth or semantic ids where every capture names such an image (read from the captures file); a
        sequence (ScanNet, TUM) carries RGB and depth."""
        assert isinstance(config, FolderConfig)
        try:
            layout = detect(config.path, config.layout, config.captures)
        except InputError:
            return cls.produces  # validation reports what is missing, as opening the workspace would
        if layout != "captures":
            return frozenset({Data.RGB, Data.DEPTH})
        try:
            rows = list(read_jsonl(config.path / config.captures))  # read_jsonl is lazy: its errors come while reading
        except SsgaError:
            return cls.produces
        rows = [row for row in rows if isinstance(row, dict)]
        extra = {data for data, key in ((Data.DEPTH, "depth"), (Data.SEMANTIC, "semantic")) if rows and all(row.get(key) for row in rows)}
        return frozenset({Data.RGB, *extra})

    @classmethod
    def missing(cls, config: StageConfig) -> list[str]:
        """The folder, its layout's files, and a floor plan or captures to derive one from."""
        assert isinstance(config, FolderConfig)
        root = config.path
        if not root.is_dir():
            return [f"path: no such folder {root}"]
        try:
            layout = detect(root, config.layout, config.captures)
        except InputError:
            layout = "captures"  # nothing there: say what the default layout lacks
        problems, rows = [], []
        if layout == "captures":
            captures = root / config.captures
            try:
                rows = list(read_jsonl(captures))
            except SsgaError as exc:
                problems.append(f"captures: {exc}")
            else:
                if not rows:
                    problems.append(f"captures: {captures} has no captures")
        else:
            problems += [f"{key}: no {path} ({layout} layout)" for key, path in required_files(root, layout, config.captures) if not path.exists()]
            rows = [None] if not problems else []
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
        return open_folder(self.config)  # type: ignore[arg-type]


@hookimpl
def ssga_register_workspaces() -> list[type[WorkspaceSource]]:
    return [FolderWorkspaceSource]
