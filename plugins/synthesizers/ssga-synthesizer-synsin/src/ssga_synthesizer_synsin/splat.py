"""A differentiable z-buffered point splatter in plain torch: SynSin's renderer without pytorch3d.

SynSin (Wiles et al., CVPR 2020, ``models/layers/z_buffer_layers.py``) rasterises its
point cloud with pytorch3d's ``rasterize_points`` and composites it with
``compositing.alpha_composite``. This module does the same with sorts and scatters:

1. **Candidates.** Every point at target position ``(u, v)`` (pixels; centres at
   integers) is a candidate for each pixel whose centre lies within ``radius`` of it
   (found among the pixels around its nearest one that can be that close: 9 for a
   radius of 1.5 px, 69 for 4 px). Points behind the camera (``z <= near``), non-finite or masked out draw
   nothing.
2. **Z-buffer.** The candidates are sorted by pixel, and within a pixel by depth (one
   sort of a 64-bit key: the pixel's index above the depth's float32 bits, which order
   like the depths for positive floats); each keeps its rank in its pixel's list, and only the ``points_per_pixel`` nearest (K) stay, as pytorch3d keeps
   the K nearest points per pixel.
3. **Soft radius.** A candidate at squared distance ``d2`` from the pixel centre has
   ``alpha = (1 - sqrt(clamp(d2 / r^2, 1e-3, 1)))^tau``: about 0.97 at the centre, 0 at
   the radius. Distances are measured in normalised device units (``2 / W`` per pixel),
   as SynSin's ``dist / radius^rad_pow``; with ``rad_pow = 2`` the units cancel.
4. **Alpha compositing**, front to back: the k-th point of a pixel weighs
   ``alpha_k * prod_{j<k} (1 - alpha_j)``. The products are a segmented cumulative sum
   of ``log(1 - alpha)`` (finite: alpha never exceeds 1 - sqrt(1e-3)), so the whole
   composite is a handful of vectorised operations, and gradients reach the features
   (through the weighted sums) and the depths (through each point's position, hence its
   distances and alphas), as through pytorch3d's.

The output features are the composite ``sum_k w_k f_k``; pixels no point reaches are
zero (SynSin's ``default_feature`` is commented out of its forward). Besides the
features it returns the coverage ``sum_k w_k`` (``1 - prod (1 - alpha)``), the depth of
each pixel's front-most candidate (0 where none) and, per point, the depth of the
nearest point on its own nearest pixel, from which the caller tells visible points.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

ALPHA_FLOOR = 1e-3
"""SynSin's clamp of ``d2 / r^2`` from below: the largest alpha is ``1 - sqrt(1e-3)`` (0.968)."""


class Splat(NamedTuple):
    """What :func:`splat` renders for ``B`` images of ``H x W`` pixels from ``N`` points each."""

    features: torch.Tensor
    """``(B, C, H, W)`` alpha-composited features."""
    coverage: torch.Tensor
    """``(B, 1, H, W)`` the sum of the compositing weights, ``1 - prod (1 - alpha)``: 0 where no point reaches."""
    depth: torch.Tensor
    """``(B, H, W)`` depth of the front-most point within the radius of each pixel, 0 where none (no gradient)."""
    nearest: torch.Tensor
    """``(B, N)`` for each point, the smallest depth of the points whose nearest pixel is its own (inf if it draws
    nothing); a point is on the front-most surface at its pixel when its depth is close to this (no gradient)."""


def splat(
    uv: torch.Tensor,
    z: torch.Tensor,
    features: torch.Tensor,
    size: tuple[int, int],
    *,
    radius: float,
    points_per_pixel: int,
    tau: float = 1.0,
    rad_pow: float = 2.0,
    mask: torch.Tensor | None = None,
    near: float = 1e-3,
) -> Splat:
    """Render points with features into ``size = (H, W)`` images, z-buffered and alpha-composited.

    Args:
        uv: ``(B, N, 2)`` pixel positions ``(u, v)`` of the points in the target image.
        z: ``(B, N)`` their depths in the target camera.
        features: ``(B, N, C)`` what each point carries.
        radius: the splat's radius in pixels (SynSin's ``--radius``, 4 by default).
        points_per_pixel: K, how many of the nearest points each pixel composites.
        tau: the alpha profile's exponent (SynSin's ``--tau``).
        rad_pow: the exponent of the radius that the squared distance is divided by
            (SynSin's ``--rad_pow``; 2: the squared distance over the squared radius).
        mask: optional ``(B, N)`` bool, the points that draw.
        near: points at or nearer than this depth draw nothing.
    """
    if uv.ndim != 3 or uv.shape[-1] != 2 or z.shape != uv.shape[:2] or features.shape[:2] != uv.shape[:2]:
        raise ValueError(
            f"splat: expected uv (B, N, 2), z (B, N), features (B, N, C); got {tuple(uv.shape)}, {tuple(z.shape)}, {tuple(features.shape)}"
        )
    if radius <= 0 or points_per_pixel < 1:
        raise ValueError(f"splat: radius must be positive and points_per_pixel at least 1, got {radius} and {points_per_pixel}")
    b, n, c = features.shape
    h, w = size
    device = uv.device
    valid = torch.isfinite(uv).all(-1) & torch.isfinite(z) & (z > near)
    if mask is not None:
        valid = valid & mask
    u = torch.where(valid, uv[..., 0], torch.zeros((), device=device))
    v = torch.where(valid, uv[..., 1], torch.zeros((), device=device))
    zz = torch.where(valid, z, torch.ones((), device=device))

    # 1. Candidates: the pixels around each point's nearest one that can lie within the radius
    # (a point is at most half a pixel from its nearest pixel's centre in each axis).
    reach = math.ceil(radius + 0.5) - 1
    steps = torch.arange(-reach, reach + 1, device=device)
    dy, dx = torch.meshgrid(steps, steps, indexing="ij")
    near_x, near_y = (dx.abs() - 0.5).clamp_min(0), (dy.abs() - 0.5).clamp_min(0)
    reachable = near_x**2 + near_y**2 < radius * radius
    dx, dy = dx[reachable], dy[reachable]
    offsets = dx.numel()
    with torch.no_grad():
        fu, fv = u.detach(), v.detach()
        cu, cv = torch.round(fu).long(), torch.round(fv).long()
        px = cu[..., None] + dx  # (B, N, O)
        py = cv[..., None] + dy
        inside = (px >= 0) & (px < w) & (py >= 0) & (py < h) & valid[..., None]
        inside &= (px - fu[..., None]) ** 2 + (py - fv[..., None]) ** 2 < radius * radius
        flat = torch.nonzero(inside.view(-1)).squeeze(1)
        point = torch.div(flat, offsets, rounding_mode="floor")  # index into the (B * N) points
        cand_x, cand_y = px.view(-1)[flat], py.view(-1)[flat]
        pixel = (torch.div(point, n, rounding_mode="floor") * h + cand_y) * w + cand_x  # flat index into (B, H, W)
        # 2. One sort by pixel, then depth: the key packs the pixel above the depth's float32 bits
        # (positive floats order like their bit patterns), 31 bits for the depth, the rest for the pixel.
        depth_bits = zz.reshape(-1)[point].float().contiguous().view(torch.int32).long()
        order = torch.sort((pixel << 31) | depth_bits).indices
        pixel_s = pixel[order]
        m = pixel_s.numel()
        index = torch.arange(m, device=device)
        first = torch.ones(m, dtype=torch.bool, device=device)
        first[1:] = pixel_s[1:] != pixel_s[:-1]
        start = torch.cummax(torch.where(first, index, torch.zeros_like(index)), 0).values if m else index
        keep = (index - start) < points_per_pixel  # rank within the pixel's list: the K nearest stay
        if not bool(keep.all()):
            order, pixel_s, first = order[keep], pixel_s[keep], first[keep]
            m = pixel_s.numel()
            index = torch.arange(m, device=device)
            start = torch.cummax(torch.where(first, index, torch.zeros_like(index)), 0).values if m else index
        point_s = point[order]
        cand_x, cand_y = cand_x[order].to(u.dtype), cand_y[order].to(v.dtype)
    # squared distances again, now with gradients to the points' positions
    d2 = (cand_x - u.reshape(-1)[point_s]) ** 2 + (cand_y - v.reshape(-1)[point_s]) ** 2
    # 3. Soft radius, in normalised device units as SynSin's (2 / W per pixel).
    ndc = 2.0 / w
    r_ndc = radius * ndc
    dist = d2 * (ndc * ndc) / (r_ndc**rad_pow)
    alpha = (1.0 - dist.clamp(ALPHA_FLOOR, 1.0).sqrt()) ** tau
    # 4. Front-to-back compositing: transmittance by a segmented exclusive cumulative sum of log(1 - alpha).
    # (in float64: over ~10^6 entries a float32 running sum loses the few digits each pixel needs)
    log_t = torch.log1p(-alpha).double()
    total = torch.cumsum(log_t, 0)
    before = total - log_t  # the sum over every earlier entry
    transmittance = torch.exp(before - before[start]).to(alpha.dtype) if m else alpha
    weight = alpha * transmittance
    out = torch.zeros(b * h * w, c, dtype=features.dtype, device=device)
    out = out.index_add(0, pixel_s, weight[:, None] * features.reshape(b * n, c)[point_s])
    coverage = torch.zeros(b * h * w, dtype=weight.dtype, device=device).index_add(0, pixel_s, weight)
    with torch.no_grad():
        front = torch.zeros(b * h * w, dtype=z.dtype, device=device)
        front[pixel_s[first]] = zz.reshape(-1)[point_s[first]]
        # Each point's own (nearest) pixel and the nearest depth drawn there by a point of that pixel.
        own = (torch.arange(b, device=device)[:, None] * h + cv.clamp(0, h - 1)) * w + cu.clamp(0, w - 1)
        on_image = valid & (cu >= 0) & (cu < w) & (cv >= 0) & (cv < h)
        zbuf = torch.full((b * h * w,), math.inf, dtype=z.dtype, device=device)
        zbuf = zbuf.scatter_reduce(0, own[on_image], zz[on_image], reduce="amin")
        nearest = torch.where(on_image, zbuf[own.clamp(0, b * h * w - 1)], torch.full_like(zz, math.inf))
    return Splat(
        features=out.view(b, h, w, c).permute(0, 3, 1, 2),
        coverage=coverage.view(b, 1, h, w),
        depth=front.view(b, h, w),
        nearest=nearest,
    )
