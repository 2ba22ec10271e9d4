"""What a second-order target's cells cost the projection (issue 19, `_pass.cells_answer`): CPU
per point of `PatchedSurface.project` on battery rows (`benchmarks/real_parts.py`'s names, its
cached points: run it first), with the cells and without them (the same surface, its
`has_cell` cleared), best of 5, and their ratio. Run with OMP_NUM_THREADS=1 for one thread.

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
    answered = int(np.sum(cells.project(ref.points).source == CELLS))
    print(f"{name}: {best['cells']:.2f} µs a point with the cells ({answered} of "
          f"{len(ref.points)} answered by them), {best['none']:.2f} without: "
          f"{best['cells'] / best['none']:.3f}x")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--points", type=int, default=20000)
    args = ap.parse_args()
    for name in args.rows:
        cost(name, args.points)
