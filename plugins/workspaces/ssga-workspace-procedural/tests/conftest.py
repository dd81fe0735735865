"""Homes shared by the tests: generating one takes a fraction of a second, but many tests look at the same ones."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import pytest

from ssga_workspace_procedural import Home, HomeConfig, generate_home


@cache
def _home(seed: int, rooms: int = 4, density: float = 1.0) -> Home:
    return generate_home(HomeConfig(seed=seed, rooms=rooms, furniture_density=density))


VARIED = [(s, 3 + s, 1.0 + 0.3 * s) for s in range(4)]
"""(seed, rooms, furniture density) of the homes the property tests run on."""


@pytest.fixture(scope="session")
def home_for() -> Callable[..., Home]:
    """``home_for(seed, rooms=4, density=1.0)``: a generated home, cached for the session."""
    return _home


@pytest.fixture(scope="session")
def home() -> Home:
    """The default home (seed 0)."""
    return _home(0)


@pytest.fixture(scope="session", params=VARIED, ids=[f"seed{s}-{r}rooms" for s, r, _ in VARIED])
def varied_home(request: pytest.FixtureRequest) -> Home:
    """Homes of 3 to 6 rooms and increasing furniture density."""
    return _home(*request.param)
