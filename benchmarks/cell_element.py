"""The node-to-cell element (`diffsurf_cli/element/cell.py`) against the node-to-facet one, in
one run, on the same contactors.

A gmsh sphere of triangle6 cells (radius 1, `--size`) as a PatchedSurface whose one patch
carries no diffuse surface, so that its curved cells answer every contactor (`source` -3, as
the guard's rejections and narrow patches do on a real part); `--points` contactors within
0.05 of the sphere (about half penetrating). Timed, CPU time (`time.process_time`, all
threads), best of `--repeat`, every engine built before:

- the projection `PatchedSurface.project(points)`;
- `contact(cells, points)`: the node-to-cell element of each penetrating contactor (g, 𝒩, ℳ;
  u = [x^c, 6 nodes]), with second=False, and with a rigid target;
- `contact(cells, points, pairing=...)`: the same elements on a frozen pairing (each
  contactor's cell kept from a first call: Newton on it, no search);
- the same four on the sphere's corner facets (`contact(facets, ...)`, node-to-facet,
  u = [x^c, 3 corners]).

Printed: `contact()`'s CPU (its projection included: the patched pass for the cells, the
facet engine for the facets) per element, and the ratio node-to-cell / node-to-facet; never
asserted. Needs gmsh.

    python benchmarks/cell_element.py [--points N] [--size H] [--repeat R]
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from diffsurf_cli.element.element import contact
from diffsurf_cli.patches.surface import CELLS, PatchedSurface
from diffsurf_cli.targets import read_surface
from diffsurf_cli.testing import gmsh_scenes
from diffsurf_cli.testing.shapes import Sphere
from patch_element import best  # CPU time, best of `repeat`


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--size", type=float, default=0.1)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = gmsh_scenes.sphere_surface(Path(tmp) / "s.msh", size=args.size, order=2)
        _, nodes, faces = read_surface(str(path))
    cells = PatchedSurface(nodes, faces, feature_angle=None)
    cells.surfaces = [None]
    cells._pass = None
    facets = cells.facet_surface()
    points = Sphere().sample_near(args.points, 0.05, rng=3)
    t, proj = best(lambda: cells.project(points), args.repeat)
    facets.project(points[:10])
    assert (proj.source == CELLS).mean() > 0.99
    print(f"triangle6 sphere of {len(nodes)} nodes, {args.points} contactors, best of "
          f"{args.repeat}; the curved cells answer {100 * (proj.source == CELLS).mean():.2f}%")
    print(f"  projection {1e6 * t / args.points:8.2f} µs CPU per contactor")
    print(f"  {'':28s} {'node-to-cell':>14s} {'node-to-facet':>14s} {'ratio':>7s}")
    paired = contact(cells, points).pairing, contact(facets, points).pairing
    for label, kw in (("contact (g, N, M)", {}), ("contact, N only", {"second": False}),
                      ("contact, rigid target", {"rigid_target": True}),
                      ("contact, frozen pairing", {"pairing": paired})):
        ck, fk = kw, kw
        if "pairing" in kw:
            ck, fk = {"pairing": paired[0]}, {"pairing": paired[1]}
        tc, c = best(lambda ck=ck: contact(cells, points, **ck), args.repeat)
        tf, f = best(lambda fk=fk: contact(facets, points, **fk), args.repeat)
        if c.M is not None:
            np.asarray(c.M[:1])  # a Hessians builds on demand: count one block only
        print(f"  {label:28s} {1e6 * tc / len(c):11.2f} µs {1e6 * tf / len(f):11.2f} µs "
              f"{tc / len(c) / (tf / len(f)):7.2f}   ({len(c)} / {len(f)} elements)")


if __name__ == "__main__":
    main()
