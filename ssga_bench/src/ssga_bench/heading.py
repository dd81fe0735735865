"""A heading prior from the room's straight lines (``[prior] heading = "manhattan"``).

Every row of a report confuses a place with its neighbouring heading: a test view 14 degrees
one side of a class boundary looks like one 16 degrees the other side, and on the bench about
15% of the L1 views go to the next heading, the oracle's (true renders) too. Rooms are mostly
built on two perpendicular directions (the Manhattan world), and a level camera sees where
their horizontal lines meet on the horizon: that vanishing point gives the camera's heading
against the room's directions, modulo 90 degrees, to a fraction of a degree when walls, floors
and furniture draw straight edges. Against the class headings (30 degrees apart), heading
modulo 90 keeps a class and its two neighbours apart.

Three steps, all here, nothing learned:

1. :func:`heading_mod_90`: each line segment (OpenCV's LSD) that is not vertical on screen
   meets the horizon row at its vanishing point; its direction on the floor, relative to the
   optical axis, folded modulo 90, votes with its length; the vote's peak is the view's estimate.
2. :func:`home_frame`: the real training views have known headings, so the room's directions
   (the offset of the estimates from the true headings, a circular mean modulo 90) come from
   them; where they disagree (no straight-edged room), there is no frame and no prior.
3. :func:`heading_prior`: for each view and class, how far the view's heading (estimate less
   the frame) lies outside the class's heading window, modulo 90, as a Gaussian of ``sigma``,
   mixed with a uniform share ``mix`` so that a wrong estimate lowers the true class without
   ruling it out.

The prior multiplies every row's scores alike (variants, nearest neighbour, oracles; the
fused rows fuse the members' multiplied scores), so the report's comparisons stay like for
like. It reads nothing of the test views but their own pictures (the validation views' known
headings only say, in the run's note, how often the estimate is right on this scene).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ssga_bench.io import warn, write_json
from ssga_bench.timings import Timings
from ssga_core.data import View
from ssga_core.errors import InputError
from ssga_core.geometry import Camera
from ssga_core.pipeline import Progress

if TYPE_CHECKING:
    from ssga_bench.config import PriorConfig
    from ssga_bench.dataset import Dataset
    from ssga_bench.variant_training import VariantResult

MIN_LENGTH_PX = 12.0
"""Shorter segments are mostly texture (grain, brick joints): they vote for any heading."""
MAX_SLOPE_DEG = 75.0
"""Steeper segments on screen are the room's verticals, which meet the horizon nowhere useful."""
HORIZON_MARGIN_PX = 8.0
"""A segment this near the horizon row (an edge at the camera's own height) lies almost along it:
where it meets the horizon is ill-conditioned."""
VOTE_SIGMA_DEG = 1.5
"""Each segment's vote is spread this wide, so near-parallel edges add up."""
HEADING_RECORD = "heading.json"
"""The run folder's record of its heading prior: the settings, the room's frame, every view's estimate."""
WITHIN_DEG = 2.0
"""A validation view's estimate this near its true heading (modulo 90) counts as read right, in the run's note."""
MIN_FRAME_AGREEMENT = 0.5
"""The real views' offsets must agree this well (mean resultant length of the angles times 4)
for the room to have a frame."""


def heading_mod_90(rgb: np.ndarray, camera: Camera) -> float | None:
    """The camera's heading against the room's directions, degrees in ``[0, 90)``, or None
    where the picture has no straight horizontal edge to read it by.

    The value is the bearing (clockwise from the optical axis, folded modulo 90) of the
    horizontal floor direction whose lines the view sees converge; a room whose directions lie
    at world heading ``t`` (modulo 90) is seen by a camera of yaw ``psi`` at ``psi - t``.
    """
    import cv2  # here: the core's listing of plugins stays light

    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[:2] != camera.shape:
        raise InputError(f"heading: expected an RGB image of {camera.shape[0]}x{camera.shape[1]}x3, got {rgb.shape}")
    grey = cv2.cvtColor(np.ascontiguousarray(rgb, dtype=np.uint8), cv2.COLOR_RGB2GRAY)
    found = cv2.createLineSegmentDetector().detect(grey)[0]
    if found is None:
        return None
    x1, y1, x2, y2 = found.reshape(-1, 4).astype(np.float64).T
    cx, cy = camera.principal_point
    length = np.hypot(x2 - x1, y2 - y1)
    slope = np.degrees(np.arctan2(np.abs(y2 - y1), np.abs(x2 - x1)))
    keep = (length >= MIN_LENGTH_PX) & (slope < MAX_SLOPE_DEG) & (np.abs((y1 + y2) / 2 - cy) > HORIZON_MARGIN_PX)
    if not keep.any():
        return None
    ones = np.ones(int(keep.sum()))
    lines = np.cross(np.stack([x1[keep], y1[keep], ones], 1), np.stack([x2[keep], y2[keep], ones], 1))
    vanishing = np.cross(lines, np.array([0.0, 1.0, -cy]))  # each line's meeting with the horizon row, homogeneous
    # The direction through that point, in the camera's x-z plane: its bearing right of the axis.
    bearing = np.degrees(np.arctan2((vanishing[:, 0] - cx * vanishing[:, 2]) / camera.focal_px, vanishing[:, 2])) % 90.0
    bins = np.arange(0.0, 90.0, 0.25)
    apart = (bins[:, None] - bearing[None, :] + 45.0) % 90.0 - 45.0
    votes = (length[keep][None, :] * np.exp(-0.5 * (apart / VOTE_SIGMA_DEG) ** 2)).sum(axis=1)
    return float(bins[int(votes.argmax())])


def view_heading(view: View) -> float | None:
    """:func:`heading_mod_90` of a view's picture."""
    return heading_mod_90(view.rgb, view.camera)


@dataclass(frozen=True)
class HomeFrame:
    """The room's directions: world heading ``offset`` (degrees, modulo 90) of its lines."""

    offset_deg: float
    agreement: float
    """The real views' mean resultant length (1: every view gives the same offset)."""
    views: int
    """Real views that gave an estimate."""


def home_frame(estimates: Sequence[float | None], yaws: Sequence[float]) -> HomeFrame | None:
    """The room's directions from views of known heading (``yaws``, radians), or None where
    fewer than two give an estimate or they disagree (:data:`MIN_FRAME_AGREEMENT`)."""
    offsets = np.array([(e - math.degrees(y)) % 90.0 for e, y in zip(estimates, yaws, strict=True) if e is not None])
    if len(offsets) < 2:
        return None
    angle = np.radians(offsets * 4.0)  # period 90 degrees -> a full circle
    c, s = float(np.cos(angle).mean()), float(np.sin(angle).mean())
    agreement = math.hypot(c, s)
    if agreement < MIN_FRAME_AGREEMENT:
        return None
    return HomeFrame(offset_deg=(math.degrees(math.atan2(s, c)) / 4.0) % 90.0, agreement=agreement, views=len(offsets))


def _apart_mod_90(a_deg: Any, b_deg: Any) -> Any:
    """How far apart two headings are, modulo 90 degrees (numbers or arrays)."""
    return abs((a_deg - b_deg + 45.0) % 90.0 - 45.0)


def heading_prior(
    estimates: Sequence[float | None], frame: HomeFrame, class_headings_deg: np.ndarray, window_deg: float, sigma_deg: float, mix: float
) -> np.ndarray:
    """``(views, classes)`` probabilities: how well each view's heading fits each class's.

    A class covers headings within ``window_deg`` of its heading; a view's heading is its
    estimate less the frame's offset, known modulo 90. A view without an estimate gets a
    uniform row.
    """
    num_classes = len(class_headings_deg)
    centre = np.asarray(class_headings_deg, dtype=np.float64) % 90.0
    out = np.full((len(estimates), num_classes), 1.0 / num_classes)
    for n, estimate in enumerate(estimates):
        if estimate is None:
            continue
        heading = (estimate - frame.offset_deg) % 90.0
        outside = np.maximum(_apart_mod_90(heading, centre) - window_deg, 0.0)
        fit = np.exp(-0.5 * (outside / sigma_deg) ** 2)
        out[n] = (1.0 - mix) * fit / fit.sum() + mix / num_classes
    return out


def apply_prior(scores: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """A row's scores times the prior. Scores in ``[0, 1]`` (probabilities, cosines of
    non-negative features) are multiplied as they are; others are first shifted per view to
    start at 0, which keeps each view's order of classes."""
    if scores.size == 0:  # no validation split
        return scores
    if scores.shape != prior.shape:
        raise InputError(f"heading prior: scores of shape {scores.shape} against a prior of {prior.shape}")
    if len(scores) and (scores.min() < 0.0 or scores.max() > 1.0):
        scores = scores - scores.min(axis=1, keepdims=True)
    return scores * prior


@dataclass(frozen=True)
class HeadingPrior:
    """A run's heading prior (:func:`dataset_heading_prior`): its rows for the test and
    validation views, the line the report carries and what ``heading.json`` records."""

    test: np.ndarray
    val: np.ndarray
    note: str
    record: dict[str, Any]

    def applied(self, result: VariantResult) -> VariantResult:
        """A variant's (or oracle's) scores with the prior: test, nearest neighbour and validation."""
        return dataclasses.replace(
            result, test=apply_prior(result.test, self.test), nearest=apply_prior(result.nearest, self.test), val=apply_prior(result.val, self.val)
        )

    def applied_to_all(self, results: Mapping[str, VariantResult]) -> dict[str, VariantResult]:
        return {label: self.applied(result) for label, result in results.items()}


def dataset_heading_prior(dataset: Dataset, config: PriorConfig, progress: Callable[[int, int], None] | None = None) -> HeadingPrior | None:
    """The heading prior of ``dataset``'s test and validation views, or None where its real views
    give the room no frame (the run then says :func:`no_frame_note`)."""
    real, tests, vals = dataset.split("train"), dataset.split("test"), dataset.split("val")
    views = [*real, *tests, *vals]
    estimates: list[float | None] = []
    for n, sample in enumerate(views):
        estimates.append(view_heading(dataset.view(sample, channels=())))
        if progress:
            progress(n + 1, len(views))
    on_real, on_test, on_val = estimates[: len(real)], estimates[len(real) : len(real) + len(tests)], estimates[len(real) + len(tests) :]
    frame = home_frame(on_real, [s.pose.yaw for s in real])
    if frame is None:
        return None
    orientations = dataset.plan.config.orientations
    headings = np.zeros(dataset.num_classes)
    for s in dataset.plan.samples:
        headings[s.place] = s.orientation * 360.0 / orientations
    window = 180.0 / orientations

    def prior(on: list[float | None]) -> np.ndarray:
        return heading_prior(on, frame, headings, window, config.sigma_deg, config.mix)

    read = sum(e is not None for e in on_test)
    # How far to trust it on this scene, told on the validation views' known headings (never the test views').
    val_errors = [_apart_mod_90(e - frame.offset_deg, math.degrees(s.pose.yaw)) for s, e in zip(vals, on_val, strict=True) if e is not None]
    within = sum(error <= WITHIN_DEG for error in val_errors)
    record: dict[str, Any] = {
        "heading": config.heading,
        "sigma_deg": config.sigma_deg,
        "mix": config.mix,
        "validation_views_read": len(val_errors),
        f"validation_views_within_{WITHIN_DEG:g}_deg": within,
        "frame_deg": round(frame.offset_deg, 3),
        "frame_agreement": round(frame.agreement, 4),
        "real_views_read": frame.views,
        "estimates": {s.id: e for s, e in zip(views, estimates, strict=True)},
    }
    note = (
        f"Every row's scores carry the heading prior (`[prior] heading = \"manhattan\"`, sigma {config.sigma_deg:g} deg, mix {config.mix:g}): "
        f"the room's directions at {frame.offset_deg:.1f} deg (mod 90) from {frame.views} of {len(real)} real views "
        f"(agreement {frame.agreement:.2f}); {read} of {len(tests)} test views read a heading (one that reads none gets a uniform prior)"
        + (f"; {within} of the {len(val_errors)} validation views that read one are within {WITHIN_DEG:g} deg of their true heading (mod 90)." if val_errors else ".")
    )
    return HeadingPrior(test=prior(on_test), val=prior(on_val), note=note, record=record)


def no_frame_note(dataset: Dataset) -> str:
    return (
        f"No heading prior: `[prior] heading = \"manhattan\"` was asked, but the {len(dataset.split('train'))} real views of "
        f"{dataset.name} do not agree on the room's directions (straight horizontal edges too few or not square); scores as they are."
    )


def with_heading_prior(
    config: PriorConfig,
    dataset: Dataset,
    out: Path,
    results: Mapping[str, VariantResult],
    oracle_results: Mapping[str, VariantResult],
    timings: Timings,
    progress: Progress | None = None,
) -> tuple[dict[str, VariantResult], dict[str, VariantResult], list[str]]:
    """A run's variant and oracle results with the prior ``config`` asks for, and the notes its
    report carries; writes ``out/heading.json`` (and removes a stale one when there is no prior)."""
    (out / HEADING_RECORD).unlink(missing_ok=True)
    if config.heading == "none":
        return dict(results), dict(oracle_results), []
    with timings.phase("heading prior"), timings.wall_phase("heading prior"):
        prior = dataset_heading_prior(dataset, config, (lambda d, n: progress("heading prior", d, n)) if progress else None)
    if prior is None:
        note = no_frame_note(dataset)
        warn(note)
        return dict(results), dict(oracle_results), [note]
    write_json(out / HEADING_RECORD, prior.record)
    return prior.applied_to_all(results), prior.applied_to_all(oracle_results), [prior.note]
