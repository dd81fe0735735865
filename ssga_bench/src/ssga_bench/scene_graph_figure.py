"""A picture of one image's scene graph: what a parser made of it, as the GCN sees it.

Drawn with OpenCV over the image, enlarged to at least ``DRAW_SIDE`` pixels so that
a 256 x 256 view stays readable:

* each region tinted by its colour (one colour per category or class name where the
  parser gives them, so all chairs match; otherwise one per region), with its outline;
  pixels in no region are grey;
* each region's box, in its colour;
* each node at its region's centroid, numbered as in the graph (node ``k + 1`` is
  region ``k``), with its class name (and score) where the parser names its regions
  (its category id where it gives only those), and the edges between parts as lines
  between the nodes;
* below the image, a legend: the whole-image node (node 0, the frame drawn around the
  image, joined to every part) and the counts.
"""

from __future__ import annotations

import math
import zlib

import cv2
import numpy as np

from ssga_bench.figures import class_colour
from ssga_core.data import Regions, SceneGraph

DRAW_SIDE = 512
"""Images whose longer side is shorter are drawn enlarged by a whole factor to at least this."""
NODE_SPACING = 64
"""Pixels between neighbouring nodes (the square root of the area per region) that numbers and markers need."""
MAX_ENLARGE = 8
MAX_SIDE = 4096
"""No enlargement makes a side longer than this (a large photo with thousands of regions is drawn at its size)."""
TINT = 0.45
"""Opacity of a region's colour over the image."""
EDGE_OPACITY = 0.6
WHOLE_IMAGE_COLOUR = (255, 255, 255)
NO_REGION_SHADE = 0.55
"""Brightness of the grey that pixels in no region are drawn in."""
FONT = cv2.FONT_HERSHEY_SIMPLEX


def node_spacing(shape: tuple[int, int], parts: int) -> float:
    """The typical distance in pixels between neighbouring part nodes of an image of ``(height, width)``."""
    return math.sqrt(shape[0] * shape[1] / max(parts, 1))


def drawing_scale(shape: tuple[int, int], parts: int) -> int:
    """The whole factor an image of ``(height, width)`` with ``parts`` regions is enlarged by for drawing: to at least
    ``DRAW_SIDE`` and to ``NODE_SPACING`` between nodes, within ``MAX_ENLARGE`` and ``MAX_SIDE``."""
    wanted = max(math.ceil(DRAW_SIDE / max(shape)), math.ceil(NODE_SPACING / node_spacing(shape, parts)))
    return max(1, min(wanted, MAX_ENLARGE, MAX_SIDE // max(shape)))


def region_colours(regions: Regions) -> np.ndarray:
    """``(K, 3)`` uint8 RGB: one colour per category (or class name) where the parser gives them, else per region."""
    if regions.categories is not None:
        keys = [int(c) for c in regions.categories]
    elif regions.names is not None:
        # A stable hash: a class keeps its colour across images and runs.
        keys = [zlib.crc32(name.encode()) for name in regions.names]
    else:
        keys = list(range(len(regions)))
    return np.array([class_colour(k) for k in keys], dtype=np.uint8).reshape(-1, 3)


def node_centres(regions: Regions) -> np.ndarray:
    """``(K, 2)`` where each part node is drawn: its pixels' centroid, or its box's centre if it has no pixel."""
    centres = regions.centroids().astype(np.float64)
    box_centres = (regions.boxes[:, :2] + regions.boxes[:, 2:]) / 2.0
    empty = ~np.isfinite(centres).all(axis=1)
    centres[empty] = box_centres[empty]
    return centres


def region_label(regions: Regions, k: int) -> str | None:
    """A region's caption: its class name and score, or its category id; None when the parser gives neither."""
    if regions.names is not None:
        text = regions.names[k]
    elif regions.categories is not None:
        text = f"category {int(regions.categories[k])}"
    else:
        return None
    if regions.scores is not None:
        text += f" {float(regions.scores[k]):.2f}"
    return text


class _Pen:
    """Sizes of lines and text: those of a 512 px drawing, grown with a larger canvas while the nodes leave room."""

    def __init__(self, width: int, spacing: float) -> None:
        grow = max(1.0, min(width / DRAW_SIDE, spacing / NODE_SPACING))
        self.line = max(1, round(grow))
        self.font = 0.42 * grow
        self.text = max(1, round(grow))
        self.node = max(3, round(4 * grow))
        self.line_height = cv2.getTextSize("Ag", FONT, self.font, self.text)[0][1] * 2

    def write(self, canvas: np.ndarray, text: str, at: tuple[int, int], colour: tuple[int, int, int], *, halo: bool = True) -> None:
        """Text with a dark halo, readable on any background."""
        if halo:
            cv2.putText(canvas, text, at, FONT, self.font, (0, 0, 0), self.text + 2, cv2.LINE_AA)
        cv2.putText(canvas, text, at, FONT, self.font, colour, self.text, cv2.LINE_AA)

    def tag(self, canvas: np.ndarray, text: str, corner: tuple[int, int], fill: tuple[int, int, int], taken: list[tuple[int, int, int, int]]) -> None:
        """Text on a filled box of ``fill`` near ``corner`` (its top-left), inside the canvas and clear of the boxes in
        ``taken`` where a nearby row allows (overlapping detections would stack their captions); adds its own box."""
        (tw, th), base = cv2.getTextSize(text, FONT, self.font, self.text)
        pad = self.line
        bw, bh = tw + 2 * pad, th + base + 2 * pad
        h, w = canvas.shape[:2]
        x = int(np.clip(corner[0], 0, max(0, w - bw)))

        def box_at(y: int) -> tuple[int, int, int, int]:
            y = int(np.clip(y, 0, max(0, h - bh)))
            return x, y, x + bw, y + bh

        def clear(b: tuple[int, int, int, int]) -> bool:
            return all(b[2] <= t[0] or t[2] <= b[0] or b[3] <= t[1] or t[3] <= b[1] for t in taken)

        tries = [box_at(corner[1] + step * bh) for step in (0, 1, -1, 2, -2, 3, -3)]
        x0, y0, x1, y1 = next((b for b in tries if clear(b)), tries[0])
        taken.append((x0, y0, x1, y1))
        cv2.rectangle(canvas, (x0, y0), (x1, y1), fill, -1)
        ink = (0, 0, 0) if sum(fill) > 382 else (255, 255, 255)
        cv2.putText(canvas, text, (x0 + pad, y0 + pad + th), FONT, self.font, ink, self.text, cv2.LINE_AA)

    def wrap(self, text: str, width: int) -> list[str]:
        """``text`` broken at spaces into lines no wider than ``width`` pixels (a longer word keeps its own line)."""
        lines: list[str] = []
        for word in text.split():
            joined = f"{lines[-1]} {word}" if lines else word
            if lines and cv2.getTextSize(joined, FONT, self.font, self.text)[0][0] <= width:
                lines[-1] = joined
            else:
                lines.append(word)
        return lines

    def whole_image_marker(self, canvas: np.ndarray, centre: tuple[int, int]) -> None:
        """Node 0's marker: a ring around a dot, in the whole-image colour."""
        cv2.circle(canvas, centre, self.node + 2 * self.line, (0, 0, 0), self.line + 2, cv2.LINE_AA)
        cv2.circle(canvas, centre, self.node + 2 * self.line, WHOLE_IMAGE_COLOUR, self.line, cv2.LINE_AA)
        cv2.circle(canvas, centre, max(1, self.node // 2), WHOLE_IMAGE_COLOUR, -1, cv2.LINE_AA)


def legend_lines(regions: Regions, graph: SceneGraph, title: str) -> list[str]:
    """The legend's text: what node 0 is, then the counts (and ``title``, e.g. the parser)."""
    parts = len(regions)
    whole = SceneGraph.WHOLE_IMAGE
    to_whole = int(np.any(graph.edges == whole, axis=1).sum())
    between = len(graph.edges) - to_whole
    head = f"{title}: " if title else ""
    weights = f"; part weight 1/{parts}" if parts else ""
    return [
        f"node {whole} = the whole image (the frame), joined to {to_whole} of {parts} parts; weight 1",
        f"{head}{parts} regions, {between} edges between them{weights}",
    ]


def draw_scene_graph(rgb: np.ndarray, regions: Regions, graph: SceneGraph, *, title: str = "") -> np.ndarray:
    """The picture of ``graph`` over ``rgb`` (RGB uint8, ``(H, W, 3)``), as described in the module docstring.

    Args:
        regions: the parts, ``regions.labels`` of the image's shape; node ``k + 1`` of
            ``graph`` is region ``k``.
        title: a caption for the legend (the parser, its preset).

    Returns:
        RGB uint8 of width ``W * s`` and height ``H * s`` plus the legend, where ``s`` is
        :func:`drawing_scale`. Nodes too close for their numbers (thousands of regions
        in a large photo) are drawn without them.
    """
    h, w = rgb.shape[:2]
    if graph.num_parts != len(regions):
        raise ValueError(f"the graph has {graph.num_parts} parts, the regions {len(regions)}")
    s = drawing_scale((h, w), len(regions))
    big_w, big_h = w * s, h * s
    image = cv2.resize(rgb, (big_w, big_h), interpolation=cv2.INTER_LINEAR) if s > 1 else rgb.copy()
    labels = np.repeat(np.repeat(regions.labels, s, axis=0), s, axis=1)
    colours = region_colours(regions)
    spacing = node_spacing((big_h, big_w), len(regions))
    pen = _Pen(big_w, spacing)
    # Numbers of nodes closer than this would overprint each other; the JSON has them all.
    numbered = spacing >= 0.75 * NODE_SPACING

    grey = cv2.cvtColor(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.COLOR_GRAY2RGB)
    canvas = (grey * NO_REGION_SHADE).astype(np.uint8)
    inside = labels >= 0
    if inside.any():
        tint = colours[labels[inside]].astype(np.float32)
        canvas[inside] = np.clip((1 - TINT) * image[inside] + TINT * tint, 0, 255).astype(np.uint8)
        # Outlines: a pixel whose right or lower neighbour is another region.
        outline = np.zeros(labels.shape, dtype=bool)
        outline[:, :-1] |= labels[:, :-1] != labels[:, 1:]
        outline[:-1, :] |= labels[:-1, :] != labels[1:, :]
        outline &= inside
        canvas[outline] = (0.4 * canvas[outline] + 0.6 * 255).astype(np.uint8)

    def px(u: float, v: float) -> tuple[int, int]:
        # Pixel centre (u, v) of the image to the centre of its s x s block on the canvas.
        return round((u + 0.5) * s - 0.5), round((v + 0.5) * s - 0.5)

    boxes = regions.boxes
    for k in range(len(regions)):
        if np.isfinite(boxes[k]).all():
            u0, v0, u1, v1 = (float(b) for b in boxes[k])
            # A box holds whole pixels: from its first pixel's block to the end of its last one's.
            top_left, bottom_right = (round(u0 * s), round(v0 * s)), (round((u1 + 1) * s) - 1, round((v1 + 1) * s) - 1)
            cv2.rectangle(canvas, top_left, bottom_right, tuple(int(c) for c in colours[k]), pen.line)

    centres = node_centres(regions)
    drawable = np.isfinite(centres).all(axis=1)
    layer = canvas.copy()
    for i, j in graph.edges:
        if SceneGraph.WHOLE_IMAGE in (i, j) or not (drawable[i - 1] and drawable[j - 1]):
            continue  # node 0 is joined to every part: its edges are said in the legend, not drawn
        a, b = px(*centres[i - 1]), px(*centres[j - 1])
        cv2.line(layer, a, b, (0, 0, 0), pen.line + 1, cv2.LINE_AA)
        cv2.line(layer, a, b, (255, 255, 255), pen.line, cv2.LINE_AA)
    canvas = cv2.addWeighted(layer, EDGE_OPACITY, canvas, 1 - EDGE_OPACITY, 0)

    taken: list[tuple[int, int, int, int]] = []
    for k in np.flatnonzero(drawable):
        centre = px(*centres[k])
        colour = tuple(int(c) for c in colours[k])
        cv2.circle(canvas, centre, pen.node, colour, -1, cv2.LINE_AA)
        cv2.circle(canvas, centre, pen.node, (0, 0, 0), pen.line, cv2.LINE_AA)
        caption = region_label(regions, k)
        corner = (centre[0] + pen.node + pen.line, centre[1] - pen.node)
        if caption is None and numbered:
            pen.write(canvas, str(k + 1), (corner[0], centre[1] - pen.line), (255, 255, 255))
        elif caption is not None:
            pen.tag(canvas, f"{k + 1} {caption}", corner, colour, taken)
    # Node 0's box is the whole image: a frame, matched by the legend's marker.
    cv2.rectangle(canvas, (0, 0), (big_w - 1, big_h - 1), WHOLE_IMAGE_COLOUR, pen.line)
    marker_x = pen.node + 3 * pen.line + 2
    text_x = 2 * marker_x + pen.line
    lines = [part for line in legend_lines(regions, graph, title) for part in pen.wrap(line, big_w - text_x - pen.line)]
    legend = np.full((pen.line_height * len(lines) + pen.line_height // 2, big_w, 3), 32, dtype=np.uint8)
    pen.whole_image_marker(legend, (marker_x, pen.line_height // 2 + pen.line_height // 4))
    for n, line in enumerate(lines):
        pen.write(legend, line, (text_x, pen.line_height * (n + 1)), (235, 235, 235), halo=False)
    return np.concatenate([canvas, legend], axis=0)
