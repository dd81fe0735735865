"""Pictures of a dataset: a bird's-eye plan with cells and cameras, a contact sheet of views,
and the scene graphs a parser makes of a few of them.

Drawn with OpenCV, which ssga already depends on, so no plotting stack is needed.
"""

from __future__ import annotations

import colorsys
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
import shapely

from ssga_core.errors import InputError
from ssga_core.data import Regions, View
from ssga_core.geometry import Pose
from ssga_bench.dataset import Dataset
from ssga_bench.io import write_png
from ssga_bench.protocol import Sample

LEVEL_COLOURS = {1: (46, 160, 67), 2: (230, 150, 20), 3: (210, 50, 50)}  # RGB: green, orange, red
PSEUDO_COLOUR = (140, 60, 200)  # RGB: purple


def class_colour(place: int) -> tuple[int, int, int]:
    # Spread hues by a golden-ratio step so neighbouring classes differ.
    h = (place * 0.618034) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.75, 0.9)
    return int(r * 255), int(g * 255), int(b * 255)


def birdseye(
    dataset: Dataset, colour_by: str = "class", px_per_m: float = 60.0, frustum_m: float = 0.45, pseudo: Sequence[Pose] = ()
) -> np.ndarray:
    """RGB image of the floor plan: free floor, occluders, the cell grid (selected cells outlined and
    numbered), test cameras with their frusta coloured by class or level, training views (filled
    triangles), synthesis targets (outlined) and ``pseudo`` views (purple dots, a tick for the heading)."""
    plan = dataset.floor_plan
    xmin, ymin, xmax, ymax = plan.bounds
    margin = 0.5
    w = int(math.ceil((xmax - xmin + 2 * margin) * px_per_m))
    h = int(math.ceil((ymax - ymin + 2 * margin) * px_per_m))
    img = np.full((h, w, 3), 255, np.uint8)

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.stack([(xy[:, 0] - xmin + margin) * px_per_m, (ymax + margin - xy[:, 1]) * px_per_m], axis=1).round().astype(np.int32)

    def fill(geom: shapely.geometry.base.BaseGeometry, colour: tuple[int, int, int]) -> None:
        for poly in getattr(geom, "geoms", [geom]):
            if poly.geom_type != "Polygon" or poly.is_empty:
                continue
            cv2.fillPoly(img, [px(np.asarray(poly.exterior.coords))], colour)
            for hole in poly.interiors:
                cv2.fillPoly(img, [px(np.asarray(hole.coords))], (255, 255, 255))

    fill(plan.free, (236, 240, 244))
    fill(plan.occluders, (70, 70, 78))
    grid = dataset.plan.grid
    for cell in range(grid.nx * grid.ny):
        x0, y0, x1, y1 = grid.box(cell)
        a, b = px([[x0, y1], [x1, y0]])
        cv2.rectangle(img, tuple(a), tuple(b), (200, 200, 210), 1)
    for rank, cell in enumerate(dataset.plan.cells):
        x0, y0, x1, y1 = grid.box(cell)
        a, b = px([[x0, y1], [x1, y0]])
        cv2.rectangle(img, tuple(a), tuple(b), (40, 90, 200), 2)
        cv2.putText(img, str(rank), (int(a[0]) + 4, int(a[1]) + 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 90, 200), 1, cv2.LINE_AA)

    hfov = math.radians(dataset.camera.hfov_deg)

    def frustum(s: Sample, scale: float) -> np.ndarray:
        p = np.array([s.pose.x, s.pose.y])
        ends = [p + scale * frustum_m * np.array([math.cos(s.pose.yaw + a), math.sin(s.pose.yaw + a)]) for a in (-hfov / 2, hfov / 2)]
        return px([p, *ends])

    for pose in pseudo:
        a, b = px([[pose.x, pose.y], [pose.x + 0.15 * math.cos(pose.yaw), pose.y + 0.15 * math.sin(pose.yaw)]])
        cv2.line(img, tuple(a), tuple(b), PSEUDO_COLOUR, 1, cv2.LINE_AA)
        cv2.circle(img, tuple(a), 2, PSEUDO_COLOUR, -1, cv2.LINE_AA)
    for s in dataset.split("test"):
        colour = LEVEL_COLOURS[s.level] if colour_by == "level" else class_colour(s.place)
        cv2.polylines(img, [frustum(s, 0.6)], True, colour, 1, cv2.LINE_AA)
    for s in dataset.split("target"):
        cv2.polylines(img, [frustum(s, 1.0)], True, class_colour(s.place), 2, cv2.LINE_AA)
    for s in dataset.split("train"):
        tri = frustum(s, 1.0)
        cv2.fillPoly(img, [tri], class_colour(s.place), cv2.LINE_AA)
        cv2.polylines(img, [tri], True, (0, 0, 0), 2, cv2.LINE_AA)
    return img


def contact_sheet(dataset: Dataset, per_level: int = 4, thumb: int = 128) -> np.ndarray:
    """Rows of thumbnails: each cell's real training view, then test views of L1, L2 and L3."""
    rows: list[tuple[str, list[Sample]]] = [("train", dataset.split("train"))]
    tests = dataset.split("test")
    rng = np.random.default_rng(0)
    for level in (1, 2, 3):
        pool = [s for s in tests if s.level == level]
        pick = rng.choice(len(pool), size=min(per_level * 3, len(pool)), replace=False) if pool else []
        rows.append((f"L{level}", [pool[i] for i in sorted(pick)]))
    cols = max(len(r[1]) for r in rows) or 1
    label_w, pad = 56, 4
    sheet = np.full((len(rows) * (thumb + pad) + pad, label_w + cols * (thumb + pad) + pad, 3), 255, np.uint8)
    for r, (name, samples) in enumerate(rows):
        y = pad + r * (thumb + pad)
        cv2.putText(sheet, name, (6, y + thumb // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        for c, s in enumerate(samples):
            x = label_w + pad + c * (thumb + pad)
            sheet[y : y + thumb, x : x + thumb] = cv2.resize(dataset.view(s).rgb, (thumb, thumb), interpolation=cv2.INTER_AREA)
            caption = f"c{s.place}" + (f" {s.vo:.0f}%" if s.vo is not None else "")
            cv2.putText(sheet, caption, (x + 3, y + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 2, cv2.LINE_AA)
            cv2.putText(sheet, caption, (x + 3, y + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return sheet


def draw_workspace(*, dataset: Dataset, colour_by: str = "class", out: Path | None = None) -> tuple[Path, Path]:
    """Write the bird's-eye plan and the contact sheet of a dataset; returns their paths.

    Args:
        colour_by: colour test cameras by ``"class"`` or ``"level"``.
        out: folder for the pictures [default: the dataset folder].
    """
    if colour_by not in ("class", "level"):
        raise InputError(f"--by {colour_by!r}: expected 'class' or 'level'")
    out = out or dataset.root
    plan_png, sheet_png = out / f"birdseye-by-{colour_by}.png", out / "contact-sheet.png"
    write_png(plan_png, birdseye(dataset, colour_by=colour_by))
    write_png(sheet_png, contact_sheet(dataset))
    return plan_png, sheet_png


def scene_graph_pictures(dataset: Dataset, regions_of: Callable[[Sample, View], Regions | None], samples: Sequence[Sample], out: Path, title: str) -> list[Path]:
    """Each sample view's scene graph from the regions ``regions_of`` gives it (skipped where
    it gives none), drawn into ``out/<id>.png`` as ``ssga parse`` draws it."""
    from ssga_bench.parse import scene_graph
    from ssga_bench.scene_graph_figure import draw_scene_graph

    paths = []
    for sample in samples:
        view = dataset.view(sample)
        regions = regions_of(sample, view)
        if regions is None:
            continue
        path = out / f"{sample.id}.png"
        write_png(path, draw_scene_graph(view.rgb, regions, scene_graph(view, regions), title=title))
        paths.append(path)
    return paths
