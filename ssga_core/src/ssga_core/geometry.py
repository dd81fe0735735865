"""Cameras and poses: the one place where ssga's geometric conventions live.

Conventions (tested in ``tests/core/test_geometry.py``):

* **World frame.** Right-handed, metres, ``z`` up; the floor is the plane ``z = 0``.
  A robot pose lives on the floor plane: ``(x, y)`` position, ``yaw`` the heading in
  radians, counter-clockwise from ``+x`` (``yaw = pi/2`` looks along ``+y``), and the
  camera's ``height`` above the floor. Cameras are level (no pitch, no roll), as
  Habitat's agent sensors are.
* **Camera frame.** OpenCV's: ``x`` right, ``y`` down, ``z`` forward along the optical
  axis. Depth is *planar* ``z`` in this frame (as Habitat's depth sensor gives), not
  the length of the ray.
* **Pixels.** ``(u, v) = (column, row)``; pixel centres sit at integer coordinates,
  so the image spans ``[-0.5, W - 0.5]``. The principal point is the image centre
  ``((W - 1) / 2, (H - 1) / 2)`` and pixels are square, ``fx = fy = (W / 2) /
  tan(hfov / 2)``. With Habitat's defaults (hfov 90 deg, 256 x 256) that is
  ``f = 128`` px and ``c = 127.5``, which is Habitat's GL projection (``K = I`` in
  normalised device coordinates) expressed in pixels.
* **Habitat's frame** is ``y`` up with the agent looking down ``-z`` at identity
  rotation; :meth:`Pose.from_habitat` converts (``x_h = x``, ``y_h = z``,
  ``z_h = -y``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ssga_core.errors import InputError


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with square pixels and a centred principal point."""

    width: int = 256
    height: int = 256
    hfov_deg: float = 90.0

    def __post_init__(self) -> None:
        if self.width <= 0 or self.height <= 0:
            raise InputError(f"Camera: width and height must be positive, got {self.width}x{self.height}")
        if not 0.0 < self.hfov_deg < 180.0:
            raise InputError(f"Camera: hfov_deg must be in (0, 180), got {self.hfov_deg}")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels (``fx = fy``)."""
        return (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def principal_point(self) -> tuple[float, float]:
        return ((self.width - 1) / 2.0, (self.height - 1) / 2.0)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``, the shape of this camera's images."""
        return (self.height, self.width)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - the standard name for intrinsics
        f = self.focal_px
        cx, cy = self.principal_point
        return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])

    def pixel_grid(self) -> np.ndarray:
        """``(H, W, 2)`` float32 array of every pixel centre's ``(u, v)``."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float32)
        return np.stack([u, v], axis=-1)

    def unproject(self, depth: np.ndarray, uv: np.ndarray | None = None) -> np.ndarray:
        """Camera-frame points for planar depths.

        Args:
            depth: ``(H, W)`` depths for every pixel (``uv`` omitted), or ``(N,)``
                depths for the pixels ``uv``.
            uv: optional ``(N, 2)`` pixel coordinates.

        Returns:
            ``(..., 3)`` points ``(x, y, z)`` with ``z = depth``.
        """
        if uv is None:
            uv = self.pixel_grid()
        f = self.focal_px
        cx, cy = self.principal_point
        z = np.asarray(depth, dtype=np.float32)
        x = (uv[..., 0] - cx) / f * z
        y = (uv[..., 1] - cy) / f * z
        return np.stack([x, y, z], axis=-1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates ``(N, 2)`` and depths ``(N,)`` of camera-frame points ``(N, 3)``.

        Points at or behind the camera (``z <= 0``) get NaN coordinates.
        """
        points = np.asarray(points, dtype=np.float32)
        z = points[..., 2]
        f = self.focal_px
        cx, cy = self.principal_point
        with np.errstate(divide="ignore", invalid="ignore"):
            safe_z = np.where(z > 0, z, np.nan)
            u = points[..., 0] / safe_z * f + cx
            v = points[..., 1] / safe_z * f + cy
        return np.stack([u, v], axis=-1), z

    def contains(self, uv: np.ndarray) -> np.ndarray:
        """Whether pixel coordinates fall inside the image (NaN never does)."""
        u, v = uv[..., 0], uv[..., 1]
        return (u > -0.5) & (u < self.width - 0.5) & (v > -0.5) & (v < self.height - 0.5)


@dataclass(frozen=True)
class Pose:
    """A level camera on the floor plane: position, heading and height."""

    x: float
    y: float
    yaw: float
    height: float = 1.5

    @property
    def forward(self) -> np.ndarray:
        """Unit viewing direction in the world frame (on the floor plane)."""
        return np.array([math.cos(self.yaw), math.sin(self.yaw), 0.0])

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.height])

    def rotation(self) -> np.ndarray:
        """``R_world<-camera``: its columns are the camera's x, y, z axes in the world."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[s, 0.0, c], [-c, 0.0, s], [0.0, -1.0, 0.0]])

    def world_from_camera(self) -> np.ndarray:
        """4 x 4 transform taking camera-frame points to the world frame."""
        T = np.eye(4)
        T[:3, :3] = self.rotation()
        T[:3, 3] = self.position
        return T

    def camera_from_world(self) -> np.ndarray:
        """4 x 4 transform taking world points into this camera's frame."""
        T = np.eye(4)
        R = self.rotation()
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ self.position
        return T

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` camera-frame points in world coordinates."""
        return np.asarray(points) @ self.rotation().T + self.position

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` world points in this camera's frame."""
        return (np.asarray(points) - self.position) @ self.rotation()

    def relative_to(self, source: Pose) -> np.ndarray:
        """4 x 4 ``T_self<-source``: takes points from ``source``'s camera frame into this one's."""
        return self.camera_from_world() @ source.world_from_camera()

    @classmethod
    def from_habitat(cls, position: np.ndarray, rotation_wxyz: np.ndarray) -> Pose:
        """Pose from a Habitat sensor state (y-up world; the camera looks down ``-z``).

        Args:
            position: the sensor's ``(x, y, z)`` in Habitat's world (``y`` is height).
            rotation_wxyz: the sensor's rotation quaternion ``(w, x, y, z)``; it must
                be a turn about the vertical axis, as an agent's is.
        """
        w, qx, qy, qz = (float(a) for a in rotation_wxyz)
        if abs(qx) > 1e-4 or abs(qz) > 1e-4:
            raise InputError(
                f"Pose.from_habitat: rotation {tuple(rotation_wxyz)} is not a turn about the vertical axis"
            )
        theta = 2.0 * math.atan2(qy, w)  # turn about +y_h, counter-clockwise seen from above
        px, py, pz = (float(a) for a in position)
        # Habitat's identity heading looks along -z_h, which is ssga's +y (yaw = pi/2).
        yaw = math.remainder(theta + math.pi / 2.0, 2.0 * math.pi)
        return cls(x=px, y=-pz, yaw=yaw, height=py)
