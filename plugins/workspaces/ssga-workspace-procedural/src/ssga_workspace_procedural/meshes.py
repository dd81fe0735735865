"""Mesh primitives: UV-mapped boxes for textured surfaces, coloured parts for furniture.

Textured boxes get their own four vertices per face and a UV map in metres divided by
the texture's repeat size, so textures have a physical scale and run on continuously
from one wall piece to the next. Each face's ``u`` axis points to the right of a viewer
facing it and ``v`` points up (or, on floors, along ``+y``), so photographs are upright
and not mirrored.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import trimesh
from trimesh.visual import ColorVisuals, TextureVisuals
from trimesh.visual.material import SimpleMaterial

from ssga_workspace_procedural.textures import Rgb, Texture

_X, _Y, _Z = np.eye(3)

FACES: dict[str, tuple[np.ndarray, np.ndarray]] = {
    # face: (right, up) with right x up = the outward normal
    "+x": (_Y, _Z),
    "-x": (-_Y, _Z),
    "+y": (-_X, _Z),
    "-y": (_X, _Z),
    "+z": (_X, _Y),
    "-z": (_X, -_Y),
}
"""The six faces of a box and the in-plane axes their texture runs along."""

ALL_FACES: tuple[str, ...] = tuple(FACES)

FRAME_UV = (0.004, 0.004)
"""Where a fitted texture's unfitted faces sample it: the corner, i.e. a poster's frame or a rug's border."""


def _material(texture: Texture) -> SimpleMaterial:
    return SimpleMaterial(image=texture.image, diffuse=(255, 255, 255, 255), ambient=(255, 255, 255, 255), name=texture.name)


def textured_box(
    lo: Sequence[float],
    hi: Sequence[float],
    texture: Texture,
    faces: Iterable[str] = ALL_FACES,
    *,
    fit: str | None = None,
) -> trimesh.Trimesh:
    """A box from corner ``lo`` to ``hi`` with ``faces`` only (the rest left open).

    Args:
        fit: a face on which the texture is stretched once over the whole face (a
            poster's front, a rug's top) instead of repeating at its physical size; the
            other faces then sample :data:`FRAME_UV`.
    """
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    centre, half = (lo_ + hi_) / 2.0, (hi_ - lo_) / 2.0
    sx, sy = texture.size
    verts, uvs, tris = [], [], []
    for name in faces:
        right, up = FACES[name]
        normal = np.cross(right, up)
        corners = [centre + normal * half + right * half * a + up * half * b for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        corners = np.array(corners)
        if fit is None:
            uv = np.stack([corners @ right / sx, corners @ up / sy], axis=1)
        elif name == fit:
            uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        else:
            uv = np.tile(FRAME_UV, (4, 1))
        base = len(verts) * 4
        verts.append(corners)
        uvs.append(uv)
        tris += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    mesh = trimesh.Trimesh(vertices=np.concatenate(verts), faces=np.array(tris, dtype=np.int64), process=False)
    mesh.visual = TextureVisuals(uv=np.concatenate(uvs), material=_material(texture))
    return mesh


def merge_textured(meshes: Sequence[trimesh.Trimesh], texture: Texture) -> trimesh.Trimesh:
    """One mesh (one material) from textured pieces that share ``texture``."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    mesh = trimesh.Trimesh(
        vertices=np.concatenate([m.vertices for m in meshes]),
        faces=np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=False)]),
        process=False,
    )
    mesh.visual = TextureVisuals(uv=np.concatenate([m.visual.uv for m in meshes]), material=_material(texture))
    return mesh


def _rgba(colour: Rgb) -> np.ndarray:
    return np.array([*(round(255 * c) for c in colour), 255], dtype=np.uint8)


def paint(mesh: trimesh.Trimesh, colour: Rgb) -> trimesh.Trimesh:
    """``mesh`` with every face coloured ``colour``."""
    mesh.visual = ColorVisuals(mesh, face_colors=np.tile(_rgba(colour), (len(mesh.faces), 1)))
    return mesh


def block(lo: Sequence[float], hi: Sequence[float], colour: Rgb) -> trimesh.Trimesh:
    """A coloured box from corner ``lo`` to ``hi``."""
    lo_, hi_ = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return paint(
        trimesh.creation.box(extents=hi_ - lo_, transform=trimesh.transformations.translation_matrix((lo_ + hi_) / 2)), colour
    )


def cylinder(
    x: float, y: float, z0: float, z1: float, radius: float, colour: Rgb, *, top_radius: float | None = None
) -> trimesh.Trimesh:
    """A vertical coloured cylinder (a frustum if ``top_radius`` differs), 16 sides."""
    mesh = trimesh.creation.cylinder(radius=radius, height=z1 - z0, sections=16)
    if top_radius is not None:
        top = mesh.vertices[:, 2] > 0
        mesh.vertices[top, :2] *= top_radius / radius
    mesh.apply_translation((x, y, (z0 + z1) / 2.0))
    return paint(mesh, colour)


def blob(centre: Sequence[float], radii: Sequence[float], colour: Rgb, subdivisions: int = 1) -> trimesh.Trimesh:
    """A coloured ellipsoid (foliage, pillows)."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    mesh.apply_scale(np.asarray(radii, dtype=np.float64))
    mesh.apply_translation(np.asarray(centre, dtype=np.float64))
    return paint(mesh, colour)


def assemble(parts: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """One coloured mesh from coloured parts (face colours kept)."""
    return trimesh.util.concatenate(list(parts))


def place(mesh: trimesh.Trimesh, x: float, y: float, quarter_turns: int) -> trimesh.Trimesh:
    """A copy of a model-frame ``mesh`` turned by ``quarter_turns`` x 90 degrees about ``z`` and moved to ``(x, y)``."""
    out = mesh.copy()
    angle = (quarter_turns % 4) * np.pi / 2.0
    T = trimesh.transformations.rotation_matrix(angle, (0, 0, 1))
    T[:3, :3] = np.rint(T[:3, :3])  # exact quarter turns: identical bytes on every platform
    T[:2, 3] = (x, y)
    out.apply_transform(T)
    return out
