"""Shared scenes for the mesh workspace tests."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ssga_core import Camera
from ssga_workspace_mesh.scenes import box_room


@pytest.fixture(scope="session")
def room() -> trimesh.Scene:
    return box_room()


@pytest.fixture(scope="session")
def camera() -> Camera:
    return Camera(width=256, height=256, hfov_deg=90.0)


@pytest.fixture(scope="session")
def pattern() -> np.ndarray:
    """A 256 x 256 texture that shows any flip, mirror or shift: a colour ramp plus a corner marker."""
    v, u = np.mgrid[0:256, 0:256]
    image = np.stack([u, v, (u + 2 * v) % 256], axis=-1).astype(np.uint8)
    image[:40, :60] = (255, 255, 255)  # top-left marker
    return image
