"""From what a file says about a camera to ssga's :class:`~ssga_core.Pose`, every value checked.

Two kinds of pose reach a workspace:

* **Level poses** (``x, y, yaw[, height]`` in ssga's world): a position on the floor plane
  and a heading, as :mod:`ssga_core.geometry` defines them.
* **6-DoF poses**: a ``4 x 4`` camera-to-world transform with OpenCV's camera (``x``
  right, ``y`` down, ``z`` forward), from a ``camera_to_world`` row, a Habitat sensor state
  (any rotation, converted from Habitat's ``y``-up world and ``-z``-looking camera), a
  ScanNet pose file or a TUM ground-truth row. Once the world is levelled (``z`` up, floor
  at ``z = 0``; :mod:`.levelling`), :func:`level_pose` keeps the camera's position and
  height, and as heading the direction of its optical axis projected on the floor plane.
  A pitched or rolled camera keeps its image: the protocol classes it by where it stands
  and where it looks.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ssga_core import Pose
from ssga_workspace_folder.checks import (
    MIN_HEADING_SINE,
    BadFrame,
    check_height,
    check_position,
    finite_array,
    finite_number,
    quaternion_matrix,
    rigid_transform,
    unit_quaternion,
)

HABITAT_TO_SSGA = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""Habitat's world (``y`` up) to ssga's (``z`` up): ``x = x_h``, ``y = -z_h``, ``z = y_h``."""

GL_TO_CV = np.diag([1.0, -1.0, -1.0])
"""Habitat's (OpenGL's) camera, ``y`` up and looking down ``-z``, to OpenCV's."""

POSE_KEYS = "x, y, yaw[, height]; a camera_to_world 4 x 4; or a Habitat sensor state (position, rotation)"


def parse_row(row: dict[str, Any], yaw_in_degrees: bool) -> tuple[str, Pose | np.ndarray]:
    """The pose of one ``captures.jsonl`` row: ``("level", Pose)``, ``("habitat", T)`` with ``T``
    already in ssga's world, or ``("matrix", T)`` in the file's world (levelled later).

    Raises:
        BadFrame: a missing, unreadable, non-finite, non-rigid or out-of-range value, naming its field.
    """
    if "camera_to_world" in row:
        matrix = rigid_transform(finite_array(row["camera_to_world"], "camera_to_world", (4, 4)), "camera_to_world")
        check_position(matrix[:3, 3], "camera_to_world")
        return "matrix", matrix
    if "position" in row or "rotation" in row:
        if "position" not in row or "rotation" not in row:
            raise BadFrame("pose", "unreadable pose", f"a Habitat sensor state needs position and rotation, got {sorted(row)}")
        position = finite_array(row["position"], "position", (3,))
        check_position(position, "position")
        w, x, y, z = unit_quaternion(finite_array(row["rotation"], "rotation", (4,)), "rotation")
        return "habitat", habitat_transform(position, quaternion_matrix(w, x, y, z))
    missing = [k for k in ("x", "y", "yaw") if k not in row]
    if missing:
        raise BadFrame("pose", "unreadable pose", f"no {', '.join(missing)}: expected {POSE_KEYS}; got {sorted(row)}")
    x, y = finite_number(row["x"], "x"), finite_number(row["y"], "y")
    check_position(np.array([x, y]), "x, y")
    yaw = finite_number(row["yaw"], "yaw")
    turn = 360.0 if yaw_in_degrees else 2.0 * math.pi
    if abs(yaw) > turn + 1e-9:
        hint = "" if yaw_in_degrees else "; set yaw_in_degrees = true if the file gives degrees"
        raise BadFrame("yaw", "yaw out of range", f"{yaw:g} is more than a turn ({'360' if yaw_in_degrees else '2 pi'}){hint}")
    height = finite_number(row.get("height", 1.5), "height")
    check_height(height, "height")
    return "level", Pose(x, y, math.radians(yaw) if yaw_in_degrees else yaw, height)


def habitat_transform(position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """A Habitat sensor state (position in its ``y``-up world, camera-to-world rotation of its
    ``-z``-looking camera) as a ``4 x 4`` OpenCV camera-to-world transform in ssga's world."""
    out = np.eye(4)
    out[:3, :3] = HABITAT_TO_SSGA @ rotation @ GL_TO_CV
    out[:3, 3] = HABITAT_TO_SSGA @ position
    return out


def quaternion_transform(translation: np.ndarray, q_xyzw: np.ndarray, name: str) -> np.ndarray:
    """A translation and a unit quaternion ``(qx, qy, qz, qw)`` (TUM's order) as a ``4 x 4`` transform."""
    qx, qy, qz, qw = unit_quaternion(q_xyzw, name)
    out = np.eye(4)
    out[:3, :3] = quaternion_matrix(qw, qx, qy, qz)
    out[:3, 3] = translation
    return out


def level_pose(world_from_camera: np.ndarray, name: str) -> Pose:
    """The level :class:`Pose` of a 6-DoF camera in a levelled world: its position, its height
    above the floor and the heading of its optical axis on the floor plane.

    Raises:
        BadFrame: the optical axis within 10 degrees of vertical (no heading), or the camera
            at or below the floor, or out of range.
    """
    optical = world_from_camera[:3, 2]
    horizontal = math.hypot(float(optical[0]), float(optical[1]))
    if horizontal < MIN_HEADING_SINE:
        tilt = math.degrees(math.asin(min(1.0, horizontal)))
        side = "down" if optical[2] < 0 else "up"
        raise BadFrame(name, "optical axis vertical", f"the camera looks straight {side} ({tilt:.1f} deg from vertical): no heading on the floor")
    x, y, height = (float(v) for v in world_from_camera[:3, 3])
    check_position(np.array([x, y]), name)
    check_height(height, name)
    return Pose(x, y, math.atan2(float(optical[1]), float(optical[0])), height)


def tilt_deg(world_from_camera: np.ndarray) -> float:
    """How far the camera's down (its ``y`` axis) is from the world's down: pitch and roll together."""
    return math.degrees(math.acos(float(np.clip(-world_from_camera[2, 1], -1.0, 1.0))))
