"""One image rendered from a moved camera by any synthesizer, to look at (``ssga synthesize``).

The paper's Fig. 3 for a user's own image: the source, the synthetic view, and where
the synthesis had nothing to draw. Writes, into the output folder,

* ``synthetic.png``: the synthetic view;
* ``depth.png``: its depth, 16-bit millimetres (0: unknown: holes, and filled holes);
* ``holes.png``: 255 where no source point landed (what was filled or left black);
* ``side-by-side.png``: source | synthetic | synthetic with the holes in magenta;
* ``synthesis.json``: says ``ssga synthesize`` wrote the folder, before the pictures: a rerun
  replaces them, and a folder holding such pictures that ssga did not write is refused
  (:mod:`ssga_bench.ownership`).

The camera is a pinhole of ``hfov_deg`` at the origin looking along +x; the target is
``forward`` metres ahead, ``left`` metres to the left, turned ``yaw_deg`` to the left.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from ssga_bench.io import WORKING_SIDE, depth_from_png16, depth_to_png16, fit_channel, path_errors, read_png, read_rgb, write_png
from ssga_bench.ownership import SYNTHESIS, check_folder, claim_folder
from ssga_core.data import View
from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose
from ssga_core.stages import Synthesizer

HOLE_COLOUR = np.array([255, 0, 255], dtype=np.uint8)


def parse_move(text: str) -> tuple[float, float, float]:
    """``FORWARD,LEFT,YAW_DEG`` (metres, metres, degrees)."""
    try:
        forward, left, yaw = (float(x) for x in text.split(","))
    except ValueError:
        raise InputError(f"--move {text!r}: expected FORWARD,LEFT,YAW_DEG, e.g. 0.5,0,20") from None
    if not all(math.isfinite(v) for v in (forward, left, yaw)):
        raise InputError(f"--move {text!r}: expected finite numbers")
    return forward, left, yaw


def read_depth(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """Metric depth from a 16-bit PNG (millimetres) or a ``.npy`` (metres), of the image's size."""
    if path.suffix == ".npy":
        try:
            depth = np.load(path).astype(np.float32)
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    else:
        raw = read_png(path, color=False)
        if raw.dtype != np.uint16:
            raise InputError(f"{path}: expected a 16-bit PNG of millimetres, got {raw.dtype}")
        depth = depth_from_png16(raw)
    if depth.shape != shape:
        raise InputError(f"{path}: depth of shape {depth.shape}, expected the image's {shape}")
    return depth


def synthesize_image(
    synthesizer: Synthesizer,
    image: str | Path,
    move: tuple[float, float, float],
    out: str | Path,
    *,
    depth: str | Path | None = None,
    hfov_deg: float = 90.0,
    max_side: int | None = WORKING_SIDE,
) -> tuple[int, int] | None:
    """Render ``image`` from the moved camera into ``out``; the image's own ``(width, height)`` if it
    was read reduced to ``max_side`` (its depth with it, by nearest samples), else ``None``.
    ``out`` may not hold a picture of these names that ``ssga synthesize`` did not write."""
    with path_errors():
        return _synthesize_image(synthesizer, image, move, Path(out), depth=depth, hfov_deg=hfov_deg, max_side=max_side)


def _synthesize_image(
    synthesizer: Synthesizer, image: str | Path, move: tuple[float, float, float], out: Path, *, depth: str | Path | None, hfov_deg: float, max_side: int | None
) -> tuple[int, int] | None:
    check_folder(out, SYNTHESIS)  # said at once, before any work
    rgb, resized_from = read_rgb(image, max_side)
    h, w = rgb.shape[:2]
    view = View(
        rgb=np.ascontiguousarray(rgb),
        pose=Pose(0.0, 0.0, 0.0),
        camera=Camera(width=w, height=h, hfov_deg=hfov_deg),
        depth=None if depth is None else fit_channel(read_depth(Path(depth), (resized_from[1], resized_from[0]) if resized_from else (h, w)), (h, w)),
    )
    forward, left, yaw = move
    synthesis = synthesizer.synthesize(view, Pose(forward, left, math.radians(yaw)))
    synthetic = synthesis.view
    drawn = np.zeros((h, w), dtype=bool)
    uv = synthesis.target_uv[synthesis.visible]
    cols, rows = np.rint(uv[:, 0]).astype(np.intp), np.rint(uv[:, 1]).astype(np.intp)
    inside = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    drawn[rows[inside], cols[inside]] = True
    # A landing point draws its neighbours too (splats, footprints): count a pixel of known depth as drawn.
    if synthetic.depth is not None:
        drawn |= synthetic.depth > 0
    holes = ~drawn
    marked = synthetic.rgb.copy()
    marked[holes] = HOLE_COLOUR
    claim_folder(out, SYNTHESIS)  # the marker first: the pictures after it are ssga's
    write_png(out / "synthetic.png", synthetic.rgb)
    write_png(out / "depth.png", depth_to_png16(synthetic.depth if synthetic.depth is not None else np.zeros((h, w), np.float32)))
    write_png(out / "holes.png", holes.astype(np.uint8) * 255)
    gap = np.full((h, 4, 3), 255, dtype=np.uint8)
    write_png(out / "side-by-side.png", cv2.hconcat([rgb, gap, synthetic.rgb, gap, marked]))
    return resized_from
