"""What a second-order target's cells bring and cost the projection (issue 19,
`_pass.cells_answer`), on battery rows (`benchmarks/real_parts.py`'s names, its cached points
and references: run it first), with the cells and without them (the same surface, its
`has_cell` cleared): the facets' RMS error away from sharp edges over diffsurf's (the
battery's ratio), diffsurf's wrong signs (the facets' in brackets), and the CPU per point
of `PatchedSurface.project`, best of 5, and its ratio. Run with OMP_NUM_THREADS=1 for one
thread.

    OMP_NUM_THREADS=1 python benchmarks/cells_cost.py gmsh.Solid_56.o2-tags gmsh.Block.o2-tags
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import parts
import real_parts as rp
from diffsurf_cli.patches.surface import CELLS
from diffsurf_cli.targets import surface_from_file


def cost(name: str, count: int, repeat: int = 5) -> None:
    man = parts.Manifest.load(parts.OUT / "manifest.json")
    row = next((r for r in man.rows if r.name == name), None)
    if row is None:
        raise SystemExit(f"{name}: no such row in the battery")
    ref, _, _ = rp.reference(row, count)
    target = str(parts.OUT / row.target)
    _, cells = surface_from_file(target, zone=row.zone)
    _, plain = surface_from_file(target, zone=row.zone)
    plain.has_cell = np.zeros_like(plain.has_cell)
    plain._pass = None
    best = {}
    for label, surf in (("cells", cells), ("none", plain)):
        surf.project(ref.points[:100])  # build the pass
        times = []
        for _ in range(repeat):
            t = time.process_time()
            surf.project(ref.points)
            times.append(time.process_time() - t)
        best[label] = min(times) / len(ref.points) * 1e6
    facets = cells.facet_surface().project(ref.points).gap
    away = ~ref.near
    firm = np.abs(ref.gap) > rp.SIGN_FLOOR * ref.diag

    def rms(gap):
        return float(np.sqrt(np.nanmean((gap[away] - ref.gap[away]) ** 2)))

    def ratio(gap):  # none where the reference is the facets themselves (STLs, decks)
        return f"{rms(facets) / rms(gap):.2f}" if row.reference else "-"

    def wrong(gap):
        return int(np.sum(firm & (np.sign(gap) != np.sign(ref.gap))))

    with_cells, without = cells.project(ref.points), plain.project(ref.points)
    print(f"{name}: RMS ratio {ratio(with_cells.gap)} with the cells "
          f"({int(np.sum(with_cells.source == CELLS))} of {len(ref.points)} answered by them), "
          f"{ratio(without.gap)} without; wrong signs {wrong(with_cells.gap)} "
          f"and {wrong(without.gap)} (facets {wrong(facets)}); CPU {best['cells']:.2f} µs a "
          f"point, {best['none']:.2f} without: {best['cells'] / best['none']:.3f}x")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--points", type=int, default=20000)
    args = ap.parse_args()
    for name in args.rows:
        cost(name, args.points)
