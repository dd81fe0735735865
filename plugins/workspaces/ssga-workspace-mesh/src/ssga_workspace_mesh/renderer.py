"""Ray-casting renderer: RGB, planar depth and semantic/instance ids of a textured triangle mesh.

One ray per pixel centre, built from :class:`ssga_core.Camera` and
:class:`ssga_core.Pose` so that the pinhole model, the pixel-centre convention and
the camera frame are the core's, not a second copy of them. Embree finds the first
hit; colour, depth and ids are gathers from per-face arrays (:mod:`.meshdata`). A
scene with label surfaces (HM3D's semantic mesh) takes its ids from a second cast of
the same rays against them.

The camera-frame ray of pixel ``(u, v)`` is ``((u - cx) / f, (v - cy) / f, 1)``:
its ``z`` is 1, so Embree's hit distance ``t`` *is* the planar depth (Habitat's
depth), with no division by the ray length.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Iterable, Mapping
from concurrent.futures import ProcessPoolExecutor

import cv2
import numpy as np
import trimesh

from ssga_bench import single_threaded_children
from ssga_core import View
from ssga_core import Camera, Pose
from ssga_workspace_mesh.atlas import TextureAtlas
from ssga_workspace_mesh.meshdata import UNANNOTATED, FlatMesh, LabelMesh, RayCaster, flatten_labels, flatten_scene

LIGHT = np.array([0.35, 0.55, 0.76], dtype=np.float32) / np.linalg.norm([0.35, 0.55, 0.76])
"""Direction *towards* the light: from above and oblique to both floor axes, so walls facing
+x, -x, +y and -y, the floor and the ceiling all get different brightness."""

AMBIENT = 0.35
"""Brightness of a surface facing straight away from the light."""

MIN_POSES_PER_WORKER = 50
"""Below this many poses per worker, :meth:`MeshRenderer.render_many` does not start processes."""


class MeshRenderer:
    """Renders :class:`~ssga_core.View` s of a triangle mesh scene from level camera poses.

    Args:
        scene: the scene, already in ssga's world frame (z up, metres, floor at z = 0);
            node transforms are applied.
        camera: intrinsics of every view.
        ids: geometry name -> ``(semantic_id, instance_id)``; geometries not in it use
            their ``metadata["semantic_id"]`` / ``["instance_id"]``, else ``-1`` and
            their index in the scene; per-face ids in a geometry's metadata win.
            If the scene has label surfaces (:data:`~.meshdata.LABEL_SURFACE`), ids come
            from them instead: a pixel whose ray meets none is unannotated
            (semantic ``-1``, instance :data:`~.meshdata.UNANNOTATED`).
        shading: darken surfaces by their angle to a fixed light, so that flat-coloured
            walls at different angles stay distinguishable; off, RGB is the plain albedo.
    """

    def __init__(
        self,
        scene: trimesh.Scene | trimesh.Trimesh,
        camera: Camera,
        *,
        ids: Mapping[str, tuple[int, int]] | None = None,
        shading: bool = True,
    ) -> None:
        self._setup(flatten_scene(scene, ids), flatten_labels(scene), camera, shading)

    def _setup(self, mesh: FlatMesh, labels: LabelMesh | None, camera: Camera, shading: bool) -> None:
        self.camera = camera
        self.shading = shading
        self._mesh = mesh
        self._caster = RayCaster(self._mesh.vertices, self._mesh.faces)
        self._labels = labels
        self._label_caster = RayCaster(labels.vertices, labels.faces) if labels is not None else None
        ones = np.ones(self.camera.shape, dtype=np.float32)
        rays = self.camera.unproject(ones).reshape(-1, 3).astype(np.float32)
        self._rays_camera = tuple(np.ascontiguousarray(rays[:, i]) for i in range(3))
        # Most meshes are coloured per face or per material: then one gather replaces
        # interpolation. From a contiguous copy: np.take copies a strided view whole first
        # (13 ms a view at 728k faces, against 1.2 ms).
        corners = self._mesh.corner_rgb
        self._face_rgb = np.ascontiguousarray(corners[:, 0]) if bool(np.all(corners == corners[:, :1])) else None
        self._atlas = TextureAtlas.pack(self._mesh.textures) if self._mesh.textures else None

    @property
    def num_triangles(self) -> int:
        return self._mesh.num_faces

    def render(self, pose: Pose) -> View:
        """The view from ``pose``: RGB, planar depth (0 where no hit), semantic and instance ids (-1 where no hit)."""
        h, w = self.camera.shape
        directions = self._world_directions(pose)
        origins = np.empty_like(directions)
        origins[:] = pose.position
        face, t, bary = self._caster.first_hit(origins, directions)
        idx = np.flatnonzero(face >= 0)
        f, b = face[idx], bary[idx]
        mesh = self._mesh

        depth = np.zeros(h * w, dtype=np.float32)
        depth[idx] = t[idx]
        semantic = np.full(h * w, -1, dtype=np.int32)
        instance = np.full(h * w, -1, dtype=np.int32)
        if self._labels is None:
            semantic[idx] = np.take(mesh.semantic, f)
            instance[idx] = np.take(mesh.instance, f)
        else:
            self._label(semantic, instance, idx, origins[idx], directions[idx])

        if self._face_rgb is not None:
            color = np.take(self._face_rgb, f, axis=0)
        else:
            color = _interpolate(b, np.take(mesh.corner_rgb, f, axis=0))
        if self._atlas is not None:
            _apply_textures(color, mesh, self._atlas, f, b)
        if self.shading:
            color *= _shade(np.take(mesh.normals, f, axis=0), directions[idx])[:, None]
        rgb = np.zeros((h * w, 3), dtype=np.uint8)
        rgb[idx] = np.clip(color * 255.0 + 0.5, 0.0, 255.0).astype(np.uint8)
        return View(
            rgb=rgb.reshape(h, w, 3),
            pose=pose,
            camera=self.camera,
            depth=depth.reshape(h, w),
            semantic=semantic.reshape(h, w),
            instance=instance.reshape(h, w),
        )

    def _label(self, semantic: np.ndarray, instance: np.ndarray, idx: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> None:
        """Ids of the pixels ``idx`` (in place) from the first label surface along their rays."""
        assert self._labels is not None and self._label_caster is not None
        face, _, _ = self._label_caster.first_hit(origins, directions)
        hit = face >= 0
        semantic[idx] = -1
        instance[idx] = UNANNOTATED
        semantic[idx[hit]] = np.take(self._labels.semantic, face[hit])
        instance[idx[hit]] = np.take(self._labels.instance, face[hit])

    def render_many(self, poses: Iterable[Pose], workers: int = 1) -> list[View]:
        """Views from every pose, in order; ``workers > 1`` renders in that many processes.

        Processes, not threads: Embree releases the GIL while it casts rays, but the
        numpy half of a view holds it, and two threads handing the GIL back and forth
        ran anywhere from 0.75x to 1.9x one thread. Workers are spawned (forking after
        Embree has started its threads is unsafe), pinned to one BLAS/OpenMP/OpenCV
        thread each, and rebuild the scene from the flat arrays; start-up takes about
        1.3 s, so batches shorter than :data:`MIN_POSES_PER_WORKER` per worker are
        rendered here instead.
        """
        poses = list(poses)
        if workers <= 1 or len(poses) < MIN_POSES_PER_WORKER * workers:
            return [self.render(p) for p in poses]
        context = multiprocessing.get_context("spawn")
        chunk = max(1, len(poses) // (8 * workers))
        # Workers start on the first submissions, so the environment stays set throughout.
        with single_threaded_children(), ProcessPoolExecutor(workers, context, _init_worker, (self,)) as pool:
            return list(pool.map(_render_in_worker, poses, chunksize=chunk))

    # An Embree scene cannot be pickled: a worker gets the flat mesh and builds its own.
    def __getstate__(self) -> dict[str, object]:
        return {"camera": self.camera, "shading": self.shading, "mesh": self._mesh, "labels": self._labels}

    def __setstate__(self, state: dict[str, object]) -> None:
        self._setup(state["mesh"], state["labels"], state["camera"], state["shading"])  # type: ignore[arg-type]

    def _world_directions(self, pose: Pose) -> np.ndarray:
        """``(H*W, 3)`` world ray directions (camera ``z`` component 1) of every pixel centre."""
        r = pose.rotation()
        x, y, z = self._rays_camera
        out = np.empty((len(x), 3), dtype=np.float32)
        # Written out rather than ``d @ r.T``: no BLAS thread pool, no (N, 3) temporaries.
        for i in range(3):
            out[:, i] = x * np.float32(r[i, 0]) + y * np.float32(r[i, 1]) + z * np.float32(r[i, 2])
        return out


def _interpolate(bary: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of ``(N, 3, C)`` corner values with ``(N, 3)`` weights."""
    return np.einsum("nk,nkc->nc", bary, corners)


def _apply_textures(color: np.ndarray, mesh: FlatMesh, atlas: TextureAtlas, faces: np.ndarray, bary: np.ndarray) -> None:
    """Multiply ``color`` (``(N, 3)``, in place) by the texture of each textured hit."""
    tex = np.take(mesh.texture, faces)
    textured = np.flatnonzero(tex >= 0)
    if len(textured) == 0:
        return
    if len(textured) < len(tex):
        faces, bary, tex = faces[textured], bary[textured], tex[textured]
    uv = _interpolate(bary, np.take(mesh.corner_uv, faces, axis=0))
    samples = atlas.sample(tex, uv)
    if len(textured) < len(color):
        color[textured] *= samples
    else:
        color *= samples


def _shade(normals: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Per-hit brightness in ``[AMBIENT, 1]``: two-sided, wrapped Lambert.

    The normal is turned towards the camera, so a surface's brightness does not depend
    on its winding. Wrapped (``(1 + n.l) / 2``) rather than clamped (``max(n.l, 0)``)
    Lambert, so that surfaces facing away from the light still differ from one another.
    """
    facing = np.einsum("ij,ij->i", normals, directions) > 0
    cos = np.einsum("ij,j->i", normals, LIGHT)
    cos = np.where(facing, -cos, cos)
    return AMBIENT + (1.0 - AMBIENT) * 0.5 * (1.0 + cos)




_worker_renderer: MeshRenderer | None = None


def _init_worker(renderer: MeshRenderer) -> None:
    global _worker_renderer  # noqa: PLW0603 - one renderer per worker process, set once
    cv2.setNumThreads(1)
    _worker_renderer = renderer


def _render_in_worker(pose: Pose) -> View:
    assert _worker_renderer is not None, "worker used before _init_worker"
    return _worker_renderer.render(pose)
