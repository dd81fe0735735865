"""The example plugin's own tests, written as any plugin author would, with ssga's fixtures."""

from __future__ import annotations

import numpy as np
from ssga_parser_grid.plugin import GridConfig, GridParser

from ssga_core.testing import check_parser, check_parser_in_all_orders, make_view


def test_is_installed_and_registered(ssga_installed_registry):
    entry = ssga_installed_registry.entry("parser", "grid")
    assert entry.cls is GridParser
    assert entry.plugin.distribution == "ssga-parser-grid"


def test_meets_the_parser_contract():
    check_parser(GridParser(GridConfig(rows=3, cols=5)), make_view(seed=1))


def test_cells_are_the_grid():
    regions = GridParser(GridConfig(rows=2, cols=4)).parse(make_view(seed=0))
    assert len(regions) == 8
    # 256 px split in 4 columns of 64 px: region 1 is row 0, column 1.
    np.testing.assert_array_equal(regions.boxes[1], [64, 0, 127, 127])


def test_runs_in_every_order():
    check_parser_in_all_orders(GridParser())
