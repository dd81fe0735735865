"""Any descriptor's features for a set of images, in hloc's HDF5 layout (``ssga extract``).

The layout is hloc's ``extract_features`` output, which VPR-methods-evaluation's
``--save_descriptors`` and many matching tools read: one group per image, named by
the image's path relative to the images' common folder, holding

* ``keypoints``: ``(N, 2)`` float32 pixel positions, x then y (at 256 x 256);
* ``descriptors``: ``(D, N)`` float32, one column per keypoint (hloc's transposed order);
* ``image_size``: ``(2,)`` int, width then height of the image as it was described.

A local descriptor (dense SIFT, Patch-NetVLAD) writes its local features; a region
descriptor (a CNN) writes its whole-image feature as one descriptor at the image centre.
Images are described as they are at 256 x 256; other sizes are resized first, and the
file's ``resized_from`` attribute of that group records the original ``(W, H)``.
The file is written whole or not at all, and replaces only a file ``ssga extract`` wrote
(one whose ``descriptor`` and ``config`` attributes it set): anything else at ``--out`` is
refused before any image is described.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ssga_bench.execution import Executor, SerialExecutor
from ssga_bench.io import atomic_write_bytes, exists, image_size, path_errors, read_rgb
from ssga_bench.tasks import chunks, span
from ssga_core.config import ResolvedStage
from ssga_core.data import View
from ssga_core.errors import InputError
from ssga_core.geometry import Camera, Pose
from ssga_core.stages import Descriptor, LocalDescriptor, RegionDescriptor

SIZE = 256
"""Side the descriptors are made for (the paper's and Patch-NetVLAD's 144-patch input)."""


def image_names(paths: Sequence[Path]) -> list[str]:
    """Each image's group name: its path relative to the images' deepest common folder, with '/'."""
    absolute = [p.resolve() for p in paths]
    root = Path(os.path.commonpath([p.parent for p in absolute]))
    names = [p.relative_to(root).as_posix() for p in absolute]
    refuse_repeats(names, paths, lambda name, earlier: f"given twice (as {earlier} too); each image once")
    return names


def refuse_repeats(keys: Sequence[str], paths: Sequence[Path], why: Callable[[str, Path], str]) -> None:
    """Each of ``keys`` (one per path) once: else an InputError ``{path}: {why(key, earlier path)}`` for the first repeat."""
    seen: dict[str, Path] = {}
    for key, path in zip(keys, paths):
        if key in seen:
            raise InputError(f"{path}: {why(key, seen[key])}")
        seen[key] = path


def load_image(path: Path) -> tuple[View, tuple[int, int] | None]:
    """The image as a 256 x 256 view (a 90 degree pinhole at the origin), and its original (W, H) if resized."""
    size = image_size(path)
    # Read reduced, but with the shorter side still at least 256 (a large JPEG is never decoded whole).
    enough = None if size is None else max(SIZE, math.ceil(SIZE * max(size) / max(1, min(size))))
    rgb, reduced_from = read_rgb(path, enough)  # OpenCV reads PNG, JPEG and the rest alike
    h, w = rgb.shape[:2]
    resized = reduced_from
    if (h, w) != (SIZE, SIZE):
        rgb = cv2.resize(rgb, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
        resized = reduced_from or (w, h)
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(SIZE, SIZE)), resized


def features_many(descriptor: Descriptor, views: Sequence[View]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(keypoints (N, 2), descriptors (D, N))`` of each view; a local descriptor takes them as one batch."""
    if isinstance(descriptor, LocalDescriptor):
        return [
            (local.positions.astype(np.float32), np.ascontiguousarray(local.descriptors.T, dtype=np.float32))
            for local in descriptor.extract_many(views)
        ]
    if isinstance(descriptor, RegionDescriptor):
        centre = np.array([[(SIZE - 1) / 2.0, (SIZE - 1) / 2.0]], dtype=np.float32)
        return [(centre, descriptor.describe(view, None)[0].astype(np.float32).reshape(-1, 1)) for view in views]
    raise InputError(f"descriptor {descriptor.name!r} is neither a local nor a region descriptor; it cannot be extracted")


@dataclass(frozen=True)
class ExtractJob:
    """A chunk of images for :func:`extract_chunk` (a task: it runs on any executor's worker)."""

    descriptor: ResolvedStage
    paths: tuple[str, ...]
    """As the user gave them (errors name them so), relative to ``folder``."""
    folder: str = "."

    def what(self) -> str:
        return span("image", self.paths)


def extract_chunk(job: ExtractJob) -> list[tuple[np.ndarray, np.ndarray, tuple[int, int] | None]]:
    """Each image's keypoints, descriptors and original size if it was resized."""
    from ssga_bench.tasks import in_folder, opened_stage

    with in_folder(job.folder):
        loaded = [load_image(Path(p)) for p in job.paths]
    described = features_many(opened_stage(job.descriptor), [view for view, _ in loaded])
    return [(keypoints, descriptors, resized) for (keypoints, descriptors), (_, resized) in zip(described, loaded)]


def extract_features(
    images: Sequence[str | Path],
    descriptor: ResolvedStage,
    out: str | Path,
    *,
    progress: Callable[[str, int, int], None] | None = None,
    executor: Executor | None = None,
    batch: int = 16,
) -> dict[str, tuple[int, int]]:
    """Describe every image and write ``out`` (HDF5, hloc's layout); returns the resized images' original sizes.

    Every image is read before anything is written, so a broken one stops the run with
    its name and leaves no file behind.

    Args:
        descriptor: the resolved descriptor; each worker builds it once.
        executor: describes the images in chunks of ``batch`` on its workers (default:
            in this process).
    """
    with path_errors():
        return _extract_features(images, descriptor, Path(out), progress=progress, executor=executor, batch=batch)


def written_by_extract(path: Path) -> bool:
    """Whether ``path`` is an HDF5 file ``ssga extract`` wrote (its ``descriptor`` and ``config`` attributes)."""
    import h5py

    try:
        with h5py.File(path, "r") as h5:
            return isinstance(h5.attrs.get("descriptor"), str) and isinstance(h5.attrs.get("config"), str)
    except (OSError, ValueError):
        return False


def _extract_features(
    images: Sequence[str | Path], descriptor: ResolvedStage, out: Path, *, progress: Callable[[str, int, int], None] | None, executor: Executor | None, batch: int
) -> dict[str, tuple[int, int]]:
    import h5py  # the only user of HDF5: imported here so `ssga` starts without it

    paths = [Path(p) for p in images]
    if not paths:
        raise InputError("ssga extract: no image given")
    if exists(out) and (out.is_dir() or not written_by_extract(out)):
        what = "a folder" if out.is_dir() else "not written by ssga extract, which would replace it"
        raise InputError(f"{out}: {what}; it replaces only the files it wrote: choose another --out (nothing was changed)")
    names = image_names(paths)
    jobs = [ExtractJob(descriptor, tuple(map(str, chunk)), os.getcwd()) for chunk in chunks(paths, batch)]
    buffer = io.BytesIO()
    resized_from: dict[str, tuple[int, int]] = {}
    with h5py.File(buffer, "w") as h5, ExitStack() as stack:
        executor = executor or stack.enter_context(SerialExecutor())
        h5.attrs["descriptor"] = descriptor.name
        h5.attrs["config"] = descriptor.config.model_dump_json()
        caveat = descriptor.cls.caveat(descriptor.config)
        if caveat:
            h5.attrs["caveat"] = caveat
        described = (item for chunk in executor.map(extract_chunk, jobs, describe=ExtractJob.what) for item in chunk)
        for n, (name, (keypoints, descriptors, resized)) in enumerate(zip(names, described), 1):
            group = h5.create_group(name)
            group.create_dataset("keypoints", data=keypoints)
            group.create_dataset("descriptors", data=descriptors)
            group.create_dataset("image_size", data=np.array([SIZE, SIZE], dtype=np.int64))
            if resized is not None:
                group.attrs["resized_from"] = np.array(resized, dtype=np.int64)
                resized_from[name] = resized
            if progress:
                progress("extract", n, len(paths))
    atomic_write_bytes(out, buffer.getvalue())
    return resized_from
