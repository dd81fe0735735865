"""A small vocabulary on disk for the detic tests (the LVIS files are not shipped), and one torch thread."""

from __future__ import annotations

import numpy as np
import pytest
from ssga_bench.testing import one_torch_thread as torch_at_one_thread

CLASSES = 40


@pytest.fixture(scope="session")
def vocabulary_dir(tmp_path_factory):
    """``vocab.npy`` (40 random CLIP-like embeddings, float16 as Detic's LVIS file) and ``names.txt``."""
    folder = tmp_path_factory.mktemp("vocabulary")
    rng = np.random.default_rng(0)
    np.save(folder / "vocab.npy", rng.normal(size=(CLASSES, 512)).astype(np.float16))
    (folder / "names.txt").write_text("\n".join(f"thing {k}" for k in range(CLASSES)) + "\n")
    return folder


@pytest.fixture(scope="session")
def vocabulary(vocabulary_dir) -> dict[str, str]:
    """The config fields naming the test vocabulary."""
    return {"vocabulary": str(vocabulary_dir / "vocab.npy"), "class_names": str(vocabulary_dir / "names.txt")}


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """With the other core busy, two torch threads wait on each other (2-3x slower): one thread, as the runner's workers."""
    with torch_at_one_thread():
        yield
