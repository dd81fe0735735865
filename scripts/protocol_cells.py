#!/usr/bin/env python
"""How many location cells the protocol finds in small furnished rooms, before and after
canonical viewpoints could stand nearer than half ``viewpoint_distance``.

For each room size, ``--rooms`` rectangular rooms (``ssga_workspace_mesh.scenes.furnished_room``:
desks, shelves and cabinets against random walls, a chair in the middle, the room's corner at a
random offset from the cell grid), each floor plan derived from the mesh as the mesh workspace
does, then counted at the protocol's defaults with ``--cell-size`` (1 m) and 12 headings:

* ``grid``: cells of the grid over the plan; ``free``: those whose centroid is free floor;
* ``before``: cells every heading of which has a canonical viewpoint under the rule at
  ``OLD_COMMIT`` (1, 0.75, 1.25, 0.5 or 1.5 times ``viewpoint_distance`` behind the centroid),
  read from git;
* ``after``: the same under the current rule (:data:`ssga_bench.protocol.VIEWPOINT_STEPS`),
  and ``full``: those of them whose viewpoints all stand at least half the distance back.

    .venv/bin/python scripts/protocol_cells.py --rooms 10
"""

from __future__ import annotations

import argparse

import numpy as np
from ssga_workspace_mesh.floorplan import floor_plan_from_mesh
from ssga_workspace_mesh.scenes import furnished_room

from ssga_core import Camera
from ssga_bench.protocol import FULL_REACH, Protocol, ProtocolConfig

from history import module_at

OLD_COMMIT = "0e535dc"
"""The last commit whose canonical viewpoints stood at 0.5 to 1.5 times ``viewpoint_distance``."""
ROOMS = (((3.0, 4.0), 4), ((3.5, 4.4), 5), ((4.0, 5.0), 5), ((5.0, 8.0), 6))
"""Room sizes (m) and pieces of furniture: 12, 15.4 (the office of the issue that asked for this), 20 and 40 m^2."""


def old_protocol_class() -> type:
    return module_at(OLD_COMMIT, "ssga_bench/src/ssga_bench/protocol.py", "old_protocol").Protocol


def count(size: tuple[float, float], pieces: int, seed: int, cell_size: float, old: type) -> dict[str, int]:
    area = round(size[0] * size[1])
    corner = tuple(np.random.default_rng([area, seed]).uniform(0.0, cell_size, 2))
    plan = floor_plan_from_mesh(furnished_room(size, seed=seed, corner=corner, pieces=pieces))
    camera, config = Camera(), ProtocolConfig(cell_size=cell_size)
    new = Protocol(plan, camera, config)
    before = old(plan, camera, config)
    free = new.free_cells()
    headings = range(config.orientations)
    reach = {cell: new.canonical_viewpoints(cell, 1.5) for cell in free}
    after = [cell for cell, views in reach.items() if all(v is not None for v in views)]
    return {
        "grid": len(new.centroids),
        "free": len(free),
        "before": sum(all(before.canonical_viewpoint(cell, o, 1.5) is not None for o in headings) for cell in free),
        "after": len(after),
        "full": sum(min(step for _, step in reach[cell]) >= FULL_REACH for cell in after),  # type: ignore[misc]
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rooms", type=int, default=10, help="rooms per floor area (seeds 0..N-1)")
    parser.add_argument("--cell-size", type=float, default=1.0)
    args = parser.parse_args()
    old = old_protocol_class()
    print(f"cells of {args.cell_size:g} m seen from all 12 headings, {args.rooms} rooms per area: mean [min, max]")
    print("| area | room | grid | free centroid | before | after | after, all at >= half the distance |")
    print("|---|---|---|---|---|---|---|")
    for size, pieces in ROOMS:
        rows = [count(size, pieces, seed, args.cell_size, old) for seed in range(args.rooms)]
        cell = {k: f"{np.mean([r[k] for r in rows]):.1f} [{min(r[k] for r in rows)}, {max(r[k] for r in rows)}]" for k in rows[0]}
        print(f"| {size[0] * size[1]:g} m^2 | {size[0]:g} x {size[1]:g} m | {cell['grid']} | {cell['free']} | {cell['before']} | {cell['after']} | {cell['full']} |")


if __name__ == "__main__":
    main()
