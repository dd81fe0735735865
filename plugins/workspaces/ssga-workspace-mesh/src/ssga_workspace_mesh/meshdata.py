"""A trimesh scene flattened into the per-face arrays a ray caster needs, and the ray caster.

A scene graph is convenient to build and to load, but a renderer wants one triangle
soup in world coordinates: a hit gives a face index, and every per-pixel quantity
(colour, texture coordinates, normal, semantic and instance id) is then a gather
from a per-face array. :func:`flatten_scene` does that once, so rendering a view
is a handful of vectorised numpy operations around one call into Embree.

Ids are per geometry, or per face where a geometry's metadata lists them
(:data:`FACE_SEMANTIC`, :data:`FACE_INSTANCE`). A scene may also hold label surfaces
(:data:`LABEL_SURFACE`: HM3D's semantic mesh), which :func:`flatten_labels` keeps apart:
they give the ids of what a ray hits without being seen themselves.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass

import numpy as np
import trimesh
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from trimesh.visual.material import PBRMaterial, SimpleMaterial

from ssga_core import InputError

Ids = Mapping[str, tuple[int, int]]
"""Geometry name -> ``(semantic_id, instance_id)``."""

NO_TEXTURE = -1

LABEL_SURFACE = "label_surface"
"""``geometry.metadata`` key: true on a surface that carries ids and is never seen in RGB or
depth (HM3D's semantic mesh, :mod:`.hm3d`). Where a scene has such surfaces, each view's
semantic and instance ids are those of the first label surface its rays meet."""

UNANNOTATED = 0
"""Instance id where label surfaces exist but none is hit, or where no object claims the
surface hit (HM3D's object 0, "unknown"); its semantic id is ``-1``."""

FACE_SEMANTIC = "face_semantic_id"
FACE_INSTANCE = "face_instance_id"
"""``geometry.metadata`` keys: ``(F,)`` ids of each face, which win over the geometry's own."""


@dataclass(frozen=True, eq=False)
class FlatMesh:
    """Every triangle of a scene in world coordinates, with what a renderer looks up per face.

    Attributes:
        vertices: ``(V, 3)`` float32 world positions.
        faces: ``(F, 3)`` int32 vertex indices.
        normals: ``(F, 3)`` float32 unit face normals (zero for degenerate faces),
            oriented as the file's winding says (flipped back under mirroring transforms).
        corner_rgb: ``(F, 3, 3)`` float32 base colour in ``[0, 1]`` at each corner:
            vertex or face colours, or the material's colour (times glTF's COLOR_0 where a
            file has both; multiplied with the texture).
        corner_uv: ``(F, 3, 2)`` float32 texture coordinates, trimesh's convention
            (``v`` up, origin at the image's bottom-left); zeros where untextured.
        texture: ``(F,)`` int32 index into ``textures``, ``-1`` for none.
        textures: ``(H, W, 3)`` uint8 images.
        semantic: ``(F,)`` int32 semantic id of each face.
        instance: ``(F,)`` int32 instance id of each face.
    """

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    corner_rgb: np.ndarray
    corner_uv: np.ndarray
    texture: np.ndarray
    textures: tuple[np.ndarray, ...]
    semantic: np.ndarray
    instance: np.ndarray

    @property
    def num_faces(self) -> int:
        return len(self.faces)


def geometry_ids(scene: trimesh.Scene, ids: Ids | None = None) -> dict[str, tuple[int, int]]:
    """``(semantic_id, instance_id)`` of every geometry of ``scene``.

    ``ids`` wins; then the geometry's ``metadata["semantic_id"]`` / ``["instance_id"]``;
    else ``-1`` (unknown category) and the geometry's index in the scene, so that
    distinct objects still get distinct instances.
    """
    ids = ids or {}
    out: dict[str, tuple[int, int]] = {}
    for index, (name, geom) in enumerate(scene.geometry.items()):
        if name in ids:
            sem, inst = ids[name]
        else:
            meta = getattr(geom, "metadata", None) or {}
            sem, inst = meta.get("semantic_id", -1), meta.get("instance_id", index)
        out[name] = (int(sem), int(inst))
    return out


def as_scene(mesh: trimesh.Scene | trimesh.Trimesh) -> trimesh.Scene:
    return mesh if isinstance(mesh, trimesh.Scene) else trimesh.Scene(mesh)


def flatten_scene(mesh: trimesh.Scene | trimesh.Trimesh, ids: Ids | None = None) -> FlatMesh:
    """Flatten every visible triangle mesh of ``mesh`` (node transforms applied) into a :class:`FlatMesh`.

    Non-triangle geometry (paths, point clouds) is skipped: it has no surface to hit;
    so are label surfaces (:data:`LABEL_SURFACE`, see :func:`flatten_labels`).
    """
    scene = as_scene(mesh)
    per_geometry = geometry_ids(scene, ids)
    textures: list[np.ndarray] = []
    texture_of: dict[int, int] = {}  # id(PIL image) -> index, so shared materials are stored once
    parts: list[tuple[np.ndarray, ...]] = []
    offset = 0
    for name, geom, vertices, faces, mirrored in _triangle_meshes(scene, labels=False):
        normals = _face_normals(vertices, faces)
        if mirrored:  # a mirror flips the winding, not the surface
            normals = -normals
        rgb, uv, tex = _appearance(geom, faces, textures, texture_of)
        sem, inst = _face_ids(name, geom, per_geometry[name])
        parts.append(
            (
                vertices.astype(np.float32),
                (faces + offset).astype(np.int32),
                normals.astype(np.float32),
                rgb,
                uv,
                np.full(len(faces), tex, dtype=np.int32),
                sem,
                inst,
            )
        )
        offset += len(vertices)
    if not parts:
        raise InputError("mesh: the scene has no triangles to render")
    columns = [np.concatenate(c) for c in zip(*parts, strict=True)]
    vertices, faces, normals, rgb, uv, tex, sem, inst = columns
    return FlatMesh(vertices, faces, normals, rgb, uv, tex, tuple(textures), sem, inst)


@dataclass(frozen=True, eq=False)
class LabelMesh:
    """The label surfaces of a scene (:data:`LABEL_SURFACE`) in world coordinates, with each face's ids.

    Attributes:
        vertices: ``(V, 3)`` float32 world positions.
        faces: ``(F, 3)`` int32 vertex indices.
        semantic: ``(F,)`` int32 semantic id of each face.
        instance: ``(F,)`` int32 instance id of each face.
    """

    vertices: np.ndarray
    faces: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray


def flatten_labels(mesh: trimesh.Scene | trimesh.Trimesh) -> LabelMesh | None:
    """The label surfaces of ``mesh`` flattened like :func:`flatten_scene`'s; None if it has none."""
    scene = as_scene(mesh)
    per_geometry = geometry_ids(scene)
    parts = []
    offset = 0
    for name, geom, vertices, faces, _ in _triangle_meshes(scene, labels=True):
        sem, inst = _face_ids(name, geom, per_geometry[name])
        parts.append((vertices.astype(np.float32), (faces + offset).astype(np.int32), sem, inst))
        offset += len(vertices)
    if not parts:
        return None
    return LabelMesh(*(np.concatenate(c) for c in zip(*parts, strict=True)))


def _triangle_meshes(scene: trimesh.Scene, *, labels: bool) -> Iterator[tuple[str, trimesh.Trimesh, np.ndarray, np.ndarray, bool]]:
    """Each instance of a triangle mesh that is (``labels``) or is not a label surface: its
    name, the geometry, world vertices ``(V, 3)`` float64, faces ``(F, 3)`` int64, and
    whether its transform mirrors."""
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geom = scene.geometry.get(name)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        if bool(geom.metadata.get(LABEL_SURFACE, False)) != labels:
            continue
        vertices = trimesh.transform_points(np.asarray(geom.vertices, dtype=np.float64), transform)
        yield name, geom, vertices, np.asarray(geom.faces, dtype=np.int64), bool(np.linalg.det(transform[:3, :3]) < 0)


def _face_ids(name: str, geom: trimesh.Trimesh, ids: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(F,)`` semantic and instance ids of a geometry's faces: its per-face ids where it has them."""
    n = len(geom.faces)
    out = []
    for key, default in ((FACE_SEMANTIC, ids[0]), (FACE_INSTANCE, ids[1])):
        per_face = geom.metadata.get(key)
        if per_face is not None and len(per_face) != n:
            raise InputError(f"mesh: geometry {name!r} has {len(per_face)} {key} values for its {n} faces")
        out.append(np.asarray(per_face, dtype=np.int32) if per_face is not None else np.full(n, default, dtype=np.int32))
    return out[0], out[1]


def _face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _rgb01(color: object) -> np.ndarray:
    """An RGB(A) colour as float ``[0, 1]`` RGB (trimesh stores uint8, glTF factors may be float)."""
    rgba = trimesh.visual.color.to_rgba(np.asarray(color))
    return rgba[..., :3].astype(np.float32) / 255.0


def _appearance(
    geom: trimesh.Trimesh, faces: np.ndarray, textures: list[np.ndarray], texture_of: dict[int, int]
) -> tuple[np.ndarray, np.ndarray, int]:
    """Corner colours ``(F, 3, 3)``, corner uvs ``(F, 3, 2)`` and texture index of one geometry."""
    n = len(faces)
    uv = np.zeros((n, 3, 2), dtype=np.float32)
    visual = geom.visual
    if isinstance(visual, trimesh.visual.TextureVisuals):
        material = visual.material
        if isinstance(material, PBRMaterial):
            # glTF: the base colour is texture x baseColorFactor.
            image = material.baseColorTexture
            factor = _rgb01(material.baseColorFactor) if material.baseColorFactor is not None else np.ones(3, np.float32)
        elif isinstance(material, SimpleMaterial):
            # trimesh fills an unset diffuse with grey, so, as trimesh does, a texture
            # replaces the diffuse colour rather than being darkened by it.
            image = material.image
            factor = np.ones(3, np.float32) if image is not None else _rgb01(material.diffuse)
        else:
            image, factor = None, _rgb01(getattr(material, "main_color", trimesh.visual.color.DEFAULT_COLOR))
        colours = _vertex_attribute_rgb01(visual, len(geom.vertices))
        if colours is not None:  # glTF: and x COLOR_0, which trimesh keeps aside when there is a material
            rgb = (colours[faces] * factor).astype(np.float32)
        else:
            rgb = np.broadcast_to(factor, (n, 3, 3)).astype(np.float32)
        if image is None or visual.uv is None or len(visual.uv) < len(geom.vertices):
            return rgb, uv, NO_TEXTURE
        uv[:] = np.asarray(visual.uv, dtype=np.float32)[faces]
        key = id(image)
        if key not in texture_of:
            texture_of[key] = len(textures)
            textures.append(np.ascontiguousarray(np.asarray(image.convert("RGB"), dtype=np.uint8)))
        return rgb, uv, texture_of[key]
    if visual.kind == "vertex":
        rgb = _rgb01(visual.vertex_colors)[faces]
    else:  # face colours, or trimesh's default grey when the mesh has none
        rgb = np.repeat(_rgb01(visual.face_colors)[:, None, :], 3, axis=1)
    return rgb.astype(np.float32), uv, NO_TEXTURE


def _vertex_attribute_rgb01(visual: trimesh.visual.TextureVisuals, num_vertices: int) -> np.ndarray | None:
    """``(V, 3)`` float ``[0, 1]`` RGB of glTF's COLOR_0 as trimesh keeps it beside a material
    (as stored: float, normalised 8- or 16-bit), or None without one."""
    raw = (getattr(visual, "vertex_attributes", None) or {}).get("color")
    if raw is None or len(raw) != num_vertices:
        return None
    raw = np.asarray(raw)
    if raw.ndim != 2 or raw.shape[1] < 3:
        return None
    if raw.dtype.kind == "f":
        return np.clip(raw[:, :3], 0.0, 1.0).astype(np.float32)
    scale = 65535.0 if raw.dtype.itemsize == 2 else 255.0
    return (raw[:, :3] / scale).astype(np.float32)


class RayCaster:
    """First-hit ray queries against a triangle soup, calling Embree directly.

    trimesh's ``ray_pyembree`` wrapper adds per-call bookkeeping and returns only
    face indices; asking Embree for the hit distance and barycentrics directly is
    what keeps a 256 x 256 view at a few milliseconds.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self._scene = rtcore_scene.EmbreeScene()
        # Embree keeps pointers into these buffers; hold them for the scene's lifetime.
        self._vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self._faces = np.ascontiguousarray(faces, dtype=np.int32)
        TriangleMesh(self._scene, self._vertices, self._faces)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Face index (``-1`` for a miss), distance ``t`` in units of each direction's length, and barycentrics.

        Args:
            origins: ``(N, 3)`` ray origins.
            directions: ``(N, 3)`` ray directions, not necessarily unit length.

        Returns:
            ``face`` ``(N,)`` int32; ``t`` ``(N,)`` float32 (the hit is ``origin + t * direction``);
            ``bary`` ``(N, 3)`` float32 weights of the face's three corners.
        """
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        hit = self._scene.run(origins, directions, output=1)
        face = hit["primID"]
        u, v = hit["u"], hit["v"]
        bary = np.stack([1.0 - u - v, u, v], axis=-1)
        return face, hit["tfar"], bary
