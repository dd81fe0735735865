"""Where every source pixel lands in another pinhole camera, and at what depth.

The geometry, for any pinhole intrinsics ``K`` (OpenCV frame: ``x`` right, ``y`` down,
``z`` forward; planar depth; pixel centres at integers):

* each source pixel ``(u, v)`` with known depth ``z`` is the camera-frame point
  ``X = z K_src^-1 [u, v, 1]^T``;
* in the target camera it is ``X' = R X + t`` (``T_dst<-src = [R | t]``), and it lands at
  ``q = K_dst X' = z H [u, v, 1]^T + K_dst t`` with ``H = K_dst R K_src^-1``:
  ``(u', v') = (q_x / q_z, q_y / q_z)`` at depth ``z' = q_z``.
"""

from __future__ import annotations

import numpy as np

from ssga_core import InputError
from ssga_synthesizer_depth_warp.scratch import _SCRATCH


def _check_intrinsics(name: str, K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or tuple(K[2]) != (0.0, 0.0, 1.0) or K[1, 0] != 0.0 or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"{name}: expected pinhole intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}")
    return K


def reproject(
    depth: np.ndarray,
    K_src: np.ndarray,
    K_dst: np.ndarray,
    T_dst_from_src: np.ndarray,
    max_depth: float = np.inf,
) -> tuple[np.ndarray, np.ndarray]:
    """Where every source pixel lands in the target camera, and at what depth.

    Args:
        depth: ``(H, W)`` planar depths of the source pixels; ``<= 0``, non-finite or
            beyond ``max_depth`` means unknown.
        K_src: ``3 x 3`` intrinsics of the source camera.
        K_dst: ``3 x 3`` intrinsics of the target camera.
        T_dst_from_src: ``4 x 4`` (or ``3 x 4``) rigid transform taking source-camera
            points into the target camera's frame (``Pose.relative_to`` gives it).
        max_depth: source depths beyond this are treated as unknown.

    Returns:
        ``(H, W, 2)`` float32 target positions ``(u', v')`` and ``(H, W)`` float32 target
        depths ``z'``; both NaN where the depth is unknown or ``z' <= 0``.
    """
    u, v, zt, _ = _reproject(depth, K_src, K_dst, T_dst_from_src, max_depth)
    return np.stack([u, v], axis=-1), zt


def _reproject(
    depth: np.ndarray, K_src: np.ndarray, K_dst: np.ndarray, T_dst_from_src: np.ndarray, max_depth: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`reproject` as three ``(H, W)`` arrays ``u', v', z'``, and the source depth (NaN: unknown).

    ``u'``, ``v'`` and the source depth are scratch arrays, overwritten by the next call.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise InputError(f"reproject: expected an (H, W) depth map, got shape {depth.shape}")
    K_src = _check_intrinsics("reproject: K_src", K_src)
    K_dst = _check_intrinsics("reproject: K_dst", K_dst)
    T = np.asarray(T_dst_from_src, dtype=np.float64)
    if T.shape not in {(4, 4), (3, 4)}:
        raise InputError(f"reproject: expected a 4 x 4 transform T_dst_from_src, got shape {T.shape}")
    h, w = depth.shape
    Hm = (K_dst @ T[:3, :3] @ np.linalg.inv(K_src)).astype(np.float32)
    kt = (K_dst @ T[:3, 3]).astype(np.float32)

    # Written with in-place operations and reused scratch arrays: at these sizes fresh
    # temporaries cost more in page faults than the arithmetic does.
    z = _SCRATCH.get("depth", (h, w), np.float32)
    np.copyto(z, depth, casting="unsafe")
    with np.errstate(invalid="ignore"):
        z[~((z > 0) & (z < np.inf) & (z <= max_depth))] = np.nan
    col = np.arange(w, dtype=np.float32)[None, :]
    row = np.arange(h, dtype=np.float32)[:, None]
    qx, qy = _SCRATCH.get("u", (h, w), np.float32), _SCRATCH.get("v", (h, w), np.float32)
    zt = np.empty((h, w), dtype=np.float32)
    # q = z H [u, v, 1] + K_dst t, one row of H at a time; (1, W) + (H, 1) broadcasts to (H, W).
    for i, q in ((2, zt), (0, qx), (1, qy)):
        np.add(Hm[i, 0] * col, Hm[i, 1] * row + Hm[i, 2], out=q)
        q *= z
        q += kt[i]
    with np.errstate(invalid="ignore", divide="ignore"):
        zt[~(zt > 0)] = np.nan  # at or behind the target camera (unknown depths are NaN already)
        qx /= zt
        qy /= zt
    return qx, qy, zt, z
