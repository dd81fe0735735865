"""Opening a folder: its frames read, checked, levelled, and its floor plan drawn or derived.

:func:`open_folder` does, in order, for every frame of the folder's layout (:mod:`.layouts`):

1. the problems found while reading it (a pose that is not finite, not rigid, a placeholder;
   a file that is not there);
2. its files' headers: the colour image of the size most captures have, depth a 16-bit PNG
   (or float ``.npy``) of the image's aspect ratio (or, in ScanNet, of the depth intrinsics'
   size);
3. its pose, levelled (:mod:`.levelling`) and made level (:func:`.poses.level_pose`): a
   heading, a height above the floor;
4. its depth's values (a plausible range in metres), read once, and what it saw gathered
   for a derived floor plan.

A problem refuses the folder with a one-line error naming the frame and the field, or,
with ``skip_bad_frames`` (and always for an invalid pose in a recorded sequence), leaves
the frame out; a line then says how many were left out and why (:class:`.checks.Skips`).
"""

from __future__ import annotations

import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ssga_core import Camera, InputError, Pose, View
from ssga_bench import FloorPlan, ids_from_png16, read_json, read_png, read_rgb
from ssga_workspace_folder.checks import BadFrame, Skips, check_depth_header, image_header
from ssga_bench import FloorEvidence
from ssga_workspace_folder.images import Intrinsics, read_depth, resample
from ssga_workspace_folder.layouts import Folder, Frame, detect, read_folder, tum_intrinsics
from ssga_workspace_folder.levelling import Levelling, find_floor, find_up, rotation_to_z, surfaces, up_vector
from ssga_workspace_folder.poses import level_pose

if TYPE_CHECKING:
    from ssga_workspace_folder.plugin import FolderConfig

DEFAULT_FLOOR_PLAN = "floorplan.json"
"""Looked for in the folder; when it is not there the floor plan is derived. A plan the
config names explicitly must be there."""

DEFAULT_HFOV_DEG = 90.0
"""The field of view of captures.jsonl's images when the config gives neither hfov_deg nor intrinsics."""

LEVELLING_SAMPLE = 48
"""Depth maps (spread over the sequence) that up and the floor are found from."""


@dataclass(frozen=True)
class Capture:
    """A frame that passed every check: where it stands, its files, how to read them."""

    pose: Pose
    rgb: Path
    depth: Path | None = None
    semantic: Path | None = None
    instance: Path | None = None
    where: str = ""
    transform: np.ndarray = field(default_factory=lambda: np.eye(4), compare=False)
    """``4 x 4`` camera-to-world in the levelled world (pitch and roll kept), OpenCV's camera."""


@dataclass(frozen=True)
class Pixels:
    """How a folder's images are read onto the workspace's camera (see :mod:`.images`)."""

    camera: Camera
    colour: Intrinsics
    """Colour intrinsics at the stored size."""
    depth: Intrinsics | None = None
    """Depth intrinsics at the stored depth size; None: the colour's, scaled."""
    depth_scale: float = 1000.0
    max_side: int | None = None

    @property
    def target(self) -> Intrinsics:
        return Intrinsics.of(self.camera)

    def rgb(self, path: Path) -> np.ndarray:
        rgb, _ = read_rgb(path, self.max_side)
        h, w = rgb.shape[:2]
        if (w, h) != (self.camera.width, self.camera.height):
            raise InputError(f"{path}: the image is {w} x {h} now, the workspace's {self.camera.width} x {self.camera.height}")
        return resample(rgb, self.colour.scaled(w, h), self.target, nearest=False)

    def depth_of(self, capture: Capture) -> np.ndarray | None:
        """A capture's planar depth in metres (``0``: unknown) on the workspace camera's grid, checked.

        Raises:
            BadFrame: unreadable, of the wrong kind or an implausible range.
        """
        if capture.depth is None:
            return None
        depth = read_depth(capture.depth, self.depth_scale)
        h, w = depth.shape
        return resample(depth, (self.depth or self.colour).scaled(w, h), self.target, nearest=True)

    def ids(self, path: Path) -> np.ndarray:
        """Semantic or instance ids (``-1``: unknown; stored ``+ 1`` in a PNG or ``.npy``) on the workspace camera's grid."""
        if path.suffix == ".npy":
            try:
                stored = np.load(path)
            except (OSError, ValueError) as exc:
                raise InputError(f"{path}: not a readable .npy array ({exc})") from None
        else:
            stored = read_png(path, color=False)
        h, w = stored.shape[:2]
        return ids_from_png16(resample(stored, self.colour.scaled(w, h), self.target, nearest=True))


class FolderWorkspace:
    """A :class:`ssga_bench.workspace.CapturedWorkspace` over the captures of one folder."""

    def __init__(self, name: str, pixels: Pixels, floor_plan: FloorPlan, captures: list[Capture]) -> None:
        self.name, self.pixels, self.camera, self.floor_plan = name, pixels, pixels.camera, floor_plan
        self._captures = captures
        self.captures = [c.pose for c in captures]

    def load(self, index: int) -> View:
        c = self._captures[index]
        try:
            semantic, instance = (None if p is None else self.pixels.ids(p) for p in (c.semantic, c.instance))
            rgb = self.pixels.rgb(c.rgb)
            return View(rgb=rgb, pose=c.pose, camera=self.camera, depth=self.pixels.depth_of(c), semantic=semantic, instance=instance)
        except BadFrame as bad:
            raise InputError(f"{c.where}: {bad}") from None
        except InputError as exc:
            raise InputError(f"{c.where}: {exc}") from None


def open_folder(config: FolderConfig) -> FolderWorkspace:
    """Read, check and level the folder ``config`` names (see the module docstring)."""
    root = config.path
    if not root.is_dir():
        raise InputError(f"{root}: no such folder (workspace.path)")
    layout = detect(root, config.layout, config.captures)
    folder = read_folder(root, layout, captures=config.captures, yaw_in_degrees=config.yaw_in_degrees)
    source = str(root / config.captures) if layout == "captures" else f"{root} ({folder.label})"
    if not folder.frames and not folder.dropped:
        raise InputError(f"{source}: no captures")
    skips = Skips(source, total=len(folder.frames) + len(folder.dropped), prefix="" if layout == "captures" else f"{source}: ")
    for where, bad in folder.dropped:
        skips.add(where, bad)

    def refuse_or_skip(frame: Frame, bad: BadFrame) -> None:
        skips.handle(frame.where, bad, skip=config.skip_bad_frames or (folder.sequence and bad.is_pose))

    frames = []
    for frame in folder.frames:
        if frame.bad is not None:
            refuse_or_skip(frame, frame.bad)
        else:
            frames.append(frame)
    frames = _checked_headers(frames, folder, refuse_or_skip)
    if not frames:
        raise InputError(f"{source}: no usable captures; {skips.summary()}")

    colour = _colour_intrinsics(config, folder, image_header(frames[0].rgb, "rgb").size)
    first, original = read_rgb(frames[0].rgb, config.max_side)
    camera = colour.scaled(first.shape[1], first.shape[0]).camera()
    pixels = Pixels(camera, colour, folder.depth, config.depth_scale or folder.depth_scale, config.max_side)
    if original:
        print(f"{root}: captures of {original[0]} x {original[1]} read reduced to {camera.width} x {camera.height} (workspace.max_side)", file=sys.stderr)

    levelling = _levelling(config, folder, frames, pixels, source)
    if levelling is not None and not (levelling.how == "given" and levelling.floor == 0.0 and np.allclose(levelling.up, (0, 0, 1))):
        print(f"{source}: {levelling.describe()}", file=sys.stderr)  # said where the world was turned, moved or found
    candidates = []
    for frame in frames:
        try:
            candidates.append(_capture(frame, levelling))
        except BadFrame as bad:
            refuse_or_skip(frame, bad)

    plan_path = root / config.floor_plan
    derive = not plan_path.is_file() and config.derive_floor_plan and config.floor_plan == DEFAULT_FLOOR_PLAN
    evidence = None
    if derive and candidates:
        heights = float(np.median([c.pose.height for c, _ in candidates]))
        evidence = FloorEvidence(camera, heights, max_depth=config.max_depth, source=source)
    captures: list[Capture] = []
    for capture, frame in candidates:
        try:
            depth = pixels.depth_of(capture)
        except BadFrame as bad:
            refuse_or_skip(frame, bad)
            continue
        if evidence is not None:
            evidence.add(len(captures), capture.transform, capture.pose.height, depth)
        captures.append(capture)
    line = "; ".join(filter(None, [skips.summary(), *folder.notes]))
    if line:
        print(line, file=sys.stderr)
    if not captures:
        raise InputError(f"{source}: no usable captures; {skips.summary()}")

    if evidence is None:
        floor_plan = FloorPlan.from_json(read_json(plan_path), str(plan_path))  # a hand-drawn plan wins
    else:
        derived = evidence.plan(
            [c.pose for c in captures], resolution=config.plan_resolution, robot_radius=config.robot_radius, clearance=config.clearance
        )
        # Said before anything runs, so a plan that looks wrong is seen before a build uses it.
        print(f"{root}: no {config.floor_plan}; {derived.describe()}", file=sys.stderr)
        floor_plan = derived.plan
    return FolderWorkspace(root.resolve().name, pixels, floor_plan, captures)


def _checked_headers(frames: list[Frame], folder: Folder, refuse_or_skip) -> list[Frame]:
    """The frames whose colour is of the size most have and whose depth is of the right kind and size."""
    headers = {}
    for frame in frames:
        try:
            assert frame.rgb is not None
            headers[id(frame)] = image_header(frame.rgb, "rgb")
        except BadFrame as bad:
            refuse_or_skip(frame, bad)
    sizes = Counter(h.size for h in headers.values())
    usual = sizes.most_common(1)[0][0] if sizes else None
    depth_size = None if folder.depth is None else (folder.depth.width, folder.depth.height)
    kept = []
    for frame in frames:
        header = headers.get(id(frame))
        if header is None:
            continue
        try:
            if header.size != usual:
                others = sum(n for s, n in sizes.items() if s == usual)
                raise BadFrame("rgb", "image of another size", f"{frame.rgb} is {header.width} x {header.height}, the other {others} captures' {usual[0]} x {usual[1]}")
            if frame.depth is not None:
                depth = image_header(frame.depth, "depth")
                check_depth_header(depth, frame.depth, usual if depth_size is None else None)
                if depth_size is not None and depth.size != depth_size:
                    raise BadFrame(
                        "depth", "depth of another size", f"{frame.depth} is {depth.width} x {depth.height}, the depth intrinsics' {depth_size[0]} x {depth_size[1]}"
                    )
        except BadFrame as bad:
            refuse_or_skip(frame, bad)
            continue
        kept.append(frame)
    return kept


def _colour_intrinsics(config: FolderConfig, folder: Folder, size: tuple[int, int]) -> Intrinsics:
    """The colour images' intrinsics at their stored size: the config's, else the layout's, else a centred camera of ``hfov_deg``."""
    width, height = size
    if config.intrinsics is not None:
        fx, fy, cx, cy = config.intrinsics
        return Intrinsics(fx, fy, cx, cy, width, height)
    if config.hfov_deg is not None or folder.layout == "captures":
        return Intrinsics.of(Camera(width=width, height=height, hfov_deg=config.hfov_deg or DEFAULT_HFOV_DEG))
    if folder.colour is not None:
        return folder.colour.scaled(width, height)
    return tum_intrinsics(width, height)


def _levelling(config: FolderConfig, folder: Folder, frames: list[Frame], pixels: Pixels, source: str) -> Levelling | None:
    """How the frames' 6-DoF poses are levelled; None if none has one in the file's frame."""
    six = [f for f in frames if isinstance(f.pose, np.ndarray) and not f.levelled]
    if not six:
        return None
    up = up_vector(config.up_axis)
    if up is None and folder.layout == "captures":
        up = np.array([0.0, 0.0, 1.0])  # captures.jsonl's camera_to_world rows are in ssga's world
    z_up = up is not None and np.allclose(up, (0.0, 0.0, 1.0))
    if folder.layout == "captures" and not z_up and len(six) < len(frames):
        level = next(f.where for f in frames if f not in six)
        raise InputError(
            f"{level}: an x, y, yaw or Habitat pose, already level, among camera_to_world rows levelled with up_axis = {config.up_axis!r}; give one kind"
        )
    floor_given = config.floor_height is not None or (folder.layout == "captures" and z_up)
    seen: list = []
    transforms: list[np.ndarray] = []
    if up is None or not floor_given:
        for k in np.unique(np.linspace(0, len(six) - 1, min(len(six), LEVELLING_SAMPLE)).round().astype(int)):
            frame = six[k]
            try:
                depth = None if frame.depth is None else read_depth(frame.depth, pixels.depth_scale)
            except BadFrame:
                continue  # refused or skipped, naming it, when every depth is read
            transforms.append(frame.pose)  # type: ignore[arg-type]
            if depth is not None:
                h, w = depth.shape
                seen.append(surfaces(depth, (pixels.depth or pixels.colour).scaled(w, h)))
            else:
                seen.append(None)
    how = "given"
    share = 0.0
    if up is None:
        with_depth = [(t, s) for t, s in zip(transforms, seen, strict=True) if s is not None]
        try:
            if with_depth:
                up, share = find_up([t for t, _ in with_depth], [s for _, s in with_depth])
            else:
                up, share = find_up(transforms or [f.pose for f in six], [])  # type: ignore[misc]
        except InputError as exc:
            raise InputError(f"{source}: {exc}") from None
        how = "found from depth" if share > 0 else "from the cameras"
    rotation = rotation_to_z(up)
    if config.floor_height is not None:
        floor: float | None = config.floor_height
    elif floor_given:
        floor = 0.0
    else:
        pairs = [(t, s) for t, s in zip(transforms, seen, strict=True) if s is not None]
        heights = np.array([(rotation @ f.pose[:3, 3])[2] for f in six])  # type: ignore[index]
        floor = find_floor(rotation, [t for t, _ in pairs], [s for _, s in pairs], heights) if pairs else None
    return Levelling(up=up, how=how, floor=floor, share=share, floor_given=floor_given)


def _capture(frame: Frame, levelling: Levelling | None) -> tuple[Capture, Frame]:
    """A frame with its level pose (BadFrame: no heading, out of range)."""
    if isinstance(frame.pose, Pose):
        pose, transform = frame.pose, frame.pose.world_from_camera()
    else:
        assert frame.pose is not None
        transform = frame.pose if frame.levelled or levelling is None else levelling.transform @ frame.pose
        pose = level_pose(transform, "pose")
    assert frame.rgb is not None
    return Capture(pose, frame.rgb, frame.depth, frame.semantic, frame.instance, frame.where, transform), frame
