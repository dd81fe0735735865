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
The file is written whole or not at all.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np

from ssga_bench.io import atomic_write_bytes, read_png
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
    seen: dict[str, Path] = {}
    for name, path in zip(names, paths):
        if name in seen:
            raise InputError(f"{path}: given twice (as {seen[name]} too); each image once")
        seen[name] = path
    return names


def load_image(path: Path) -> tuple[View, tuple[int, int] | None]:
    """The image as a 256 x 256 view (a 90 degree pinhole at the origin), and its original (W, H) if resized."""
    rgb = read_png(path, color=True)  # OpenCV reads PNG, JPEG and the rest alike
    h, w = rgb.shape[:2]
    resized = None
    if (h, w) != (SIZE, SIZE):
        rgb = cv2.resize(rgb, (SIZE, SIZE), interpolation=cv2.INTER_AREA)
        resized = (w, h)
    return View(rgb=np.ascontiguousarray(rgb), pose=Pose(0.0, 0.0, 0.0), camera=Camera(SIZE, SIZE)), resized


def features(descriptor: Descriptor, view: View) -> tuple[np.ndarray, np.ndarray]:
    """``(keypoints (N, 2), descriptors (D, N))`` of one view."""
    if isinstance(descriptor, LocalDescriptor):
        local = descriptor.extract(view)
        return local.positions.astype(np.float32), np.ascontiguousarray(local.descriptors.T, dtype=np.float32)
    if isinstance(descriptor, RegionDescriptor):
        whole = descriptor.describe(view, None)[0]
        centre = np.array([[(SIZE - 1) / 2.0, (SIZE - 1) / 2.0]], dtype=np.float32)
        return centre, whole.astype(np.float32).reshape(-1, 1)
    raise InputError(f"descriptor {descriptor.name!r} is neither a local nor a region descriptor; it cannot be extracted")


def extract_features(
    images: Sequence[str | Path],
    descriptor: Descriptor,
    out: str | Path,
    *,
    progress: Callable[[str, int, int], None] | None = None,
) -> dict[str, tuple[int, int]]:
    """Describe every image and write ``out`` (HDF5, hloc's layout); returns the resized images' original sizes.

    Every image is read before anything is written, so a broken one stops the run with
    its name and leaves no file behind.
    """
    import h5py  # the only user of HDF5: imported here so `ssga` starts without it

    paths = [Path(p) for p in images]
    if not paths:
        raise InputError("ssga extract: no image given")
    names = image_names(paths)
    buffer = io.BytesIO()
    resized_from: dict[str, tuple[int, int]] = {}
    with h5py.File(buffer, "w") as h5:
        h5.attrs["descriptor"] = descriptor.name
        h5.attrs["config"] = descriptor.config.model_dump_json()
        caveat = type(descriptor).caveat(descriptor.config)
        if caveat:
            h5.attrs["caveat"] = caveat
        for n, (path, name) in enumerate(zip(paths, names), 1):
            view, resized = load_image(path)
            keypoints, descriptors = features(descriptor, view)
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
