"""One torch thread for these tests: with the other core busy, two threads wait on each other (2-3x slower)."""

from __future__ import annotations

import pytest
from ssga_bench.testing import one_torch_thread as torch_at_one_thread


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """With the other core busy, two torch threads wait on each other (2-3x slower): one thread, as the runner's workers."""
    with torch_at_one_thread():
        yield
