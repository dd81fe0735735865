"""Bird's-eye visibility: what a camera sees on the floor plan, and how much two views share.

A view's *visibility polygon* is the part of the floor plane inside its horizontal
field of view that a ray from the camera reaches before hitting an occluder (walls,
tall furniture), up to a maximum range. It is built by casting rays in numpy against
the occluders' edges, which is fast enough to test tens of thousands of candidate
poses.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from shapely.geometry.base import BaseGeometry

from ssga_core.geometry import Pose


def occluder_segments(occluders: BaseGeometry) -> np.ndarray:
    """``(S, 4)`` segments ``[x0, y0, x1, y1]`` of every ring of the occluder polygons."""
    rings = []
    for poly in getattr(occluders, "geoms", [occluders]):
        if poly.is_empty or poly.geom_type != "Polygon":
            continue
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            rings.append(np.concatenate([xy[:-1], xy[1:]], axis=1))
    return np.concatenate(rings) if rings else np.zeros((0, 4))


def cast_rays(origins: np.ndarray, yaws: np.ndarray, hfov_deg: float, segments: np.ndarray, max_range: float, rays: int) -> np.ndarray:
    """Free distance along ``rays`` rays spread over the field of view of each camera.

    Args:
        origins: ``(B, 2)`` camera positions; yaws: ``(B,)`` headings.
        segments: ``(S, 4)`` occluder edges (:func:`occluder_segments`).

    Returns:
        ``(B, rays)`` distance to the first occluder along each ray, at most ``max_range``;
        ray ``r`` points at ``yaw - hfov/2 + r * hfov / (rays - 1)``.
    """
    origins = np.asarray(origins, dtype=np.float64).reshape(-1, 2)
    angles = ray_angles(np.asarray(yaws, dtype=np.float64).reshape(-1), hfov_deg, rays)  # (B, R)
    if len(segments) == 0:
        return np.full(angles.shape, float(max_range))
    dx, dy = np.cos(angles)[..., None], np.sin(angles)[..., None]  # (B, R, 1)
    ax = (segments[:, 0][None] - origins[:, 0:1])[:, None, :]  # (B, 1, S)
    ay = (segments[:, 1][None] - origins[:, 1:2])[:, None, :]
    ex, ey = segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1]  # (S,)
    denom = dx * ey - dy * ex  # cross(ray, edge)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * ey - ay * ex) / denom  # distance along the ray
        s = (ax * dy - ay * dx) / denom  # position along the edge, 0..1
    hit = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
    return np.minimum(np.where(hit, t, np.inf).min(axis=-1), max_range)


def ray_angles(yaws: np.ndarray, hfov_deg: float, rays: int) -> np.ndarray:
    half = math.radians(hfov_deg) / 2.0
    return yaws[:, None] + np.linspace(-half, half, rays)[None, :]


def sees(origins: np.ndarray, yaws: np.ndarray, distances: np.ndarray, hfov_deg: float, points: np.ndarray) -> np.ndarray:
    """``(B, P)``: whether each camera's visibility cone contains each point.

    A point is in the cone if it lies within the horizontal field of view and no
    farther than the free distance of the ray nearest to its direction.
    """
    rays = distances.shape[1]
    rel = points[None, :, :] - origins[:, None, :]  # (B, P, 2)
    dist = np.hypot(rel[..., 0], rel[..., 1])
    off = np.angle(np.exp(1j * (np.arctan2(rel[..., 1], rel[..., 0]) - yaws[:, None])))  # wrapped to (-pi, pi]
    half = math.radians(hfov_deg) / 2.0
    idx = np.clip(np.rint((off + half) / (2 * half) * (rays - 1)).astype(int), 0, rays - 1)
    free = np.take_along_axis(distances, idx, axis=1)
    return (np.abs(off) <= half) & (dist <= free) & (dist > 1e-9)


def visibility_polygon(pose: Pose, hfov_deg: float, distances: np.ndarray) -> shapely.Polygon:
    """The floor area seen from ``pose``, from its ray distances (one row of :func:`cast_rays`)."""
    angles = ray_angles(np.array([pose.yaw]), hfov_deg, len(distances))[0]
    origin = np.array([pose.x, pose.y])
    ends = origin + distances[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    poly = shapely.Polygon(np.concatenate([origin[None], ends]))
    return poly if poly.is_valid else poly.buffer(0)


def view_overlap(a: BaseGeometry, b: BaseGeometry) -> float:
    """View-overlap rate VO in percent: intersection over union of two visibility polygons.

    The paper defines VO from "the area of the intersection" of the two views'
    visibility areas without naming the denominator; the union makes VO symmetric and
    100 only for views that see exactly the same floor.
    """
    union = shapely.union(a, b).area
    return 0.0 if union <= 0 else 100.0 * shapely.intersection(a, b).area / union
