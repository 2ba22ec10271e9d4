"""The rigid-target element's speed against the projection, in one run (issue 12, speed).

A unit sphere meshed with 1692 nodes (`Sphere().mesh(13)` from diffsurf_cli/testing/shapes.py,
the "1.6k-node sphere"), 20,000 contactors penetrating 0 to 0.3 node spacings (random
directions). Measured:

- `DiffuseSurface.project(points)` (the compiled projection engine);
- `RigidTarget.evaluate(points)`: gap, normal = ∂g/∂x^c and the 3x3 Hessian ∂²g/∂x^c²
  (`second=True`), and without the Hessian (`second=False`);
- the RigidTarget's build (node fits and grid), once per surface, timed apart.

Each figure is the best of `--repeat` runs, alternating: CPU time per contactor (process time,
all threads). The ratio rigid / projection is printed, never asserted (target: at most 3).
`--beta` lists, for several blending radii β, the gap error against the exact sphere (max and
RMS, in node spacings, over the same contactors) next to the cost: the measurement behind
`rigid.BLEND_SPACINGS`.

    python benchmarks/rigid_speed.py [--points N] [--repeat R] [--resolution N] [--beta]
"""
from __future__ import annotations

import argparse
import time
from functools import partial

import numpy as np

from diffsurf_cli.element.rigid import RigidTarget
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.testing.shapes import Sphere


def cpu(fn):
    start = time.process_time()
    out = fn()
    return time.process_time() - start, out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--resolution", type=int, default=13,
                        help="Sphere().mesh(N): 13 gives 1692 nodes")
    parser.add_argument("--beta", action="store_true",
                        help="accuracy and cost for several blending radii β")
    args = parser.parse_args(argv)

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(args.resolution)
    h = shape.spacing(args.resolution)
    rng = np.random.default_rng(7)
    u = rng.standard_normal((args.points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * (1.0 - rng.uniform(0.0, 0.3 * h, args.points))[:, None]
    exact = np.linalg.norm(points, axis=1) - 1.0

    surface = DiffuseSurface(nodes, [faces])
    surface.project(points[:10])  # the engine's grids, built on first use
    build, rigid = cpu(lambda: RigidTarget(surface))
    rigid.evaluate(points[:10])
    n = len(points)
    best = {"project": np.inf, "rigid": np.inf, "rigid-first": np.inf}
    for _ in range(args.repeat):
        t, proj = cpu(lambda: surface.project(points))
        best["project"] = min(best["project"], t / n)
        t, res = cpu(lambda: rigid.evaluate(points))
        best["rigid"] = min(best["rigid"], t / n)
        t, _ = cpu(lambda: rigid.evaluate(points, second=False))
        best["rigid-first"] = min(best["rigid-first"], t / n)
    print(f"sphere: {len(nodes)} nodes, {n} contactors penetrating 0..0.3 spacings, "
          f"best of {args.repeat} (CPU time, all threads)")
    print(f"  RigidTarget build          {build * 1e3:8.1f} ms (once per surface)")
    for key, label in (("project", "DiffuseSurface.project"),
                       ("rigid", "RigidTarget.evaluate"),
                       ("rigid-first", "  ... second=False")):
        print(f"  {label:26s} {best[key] * 1e6:8.2f} µs/contactor")
    print(f"  ratio rigid / projection   {best['rigid'] / best['project']:8.2f} "
          f"(without the Hessian {best['rigid-first'] / best['project']:.2f}; target <= 3)")
    for name, gap, status in (("projection", proj.gap, proj.status),
                              ("rigid", res.gap, res.status)):
        err = np.abs(gap - exact) / h
        print(f"  {name:10s} gap error / h: max {np.nanmax(err):.2e}, "
              f"rms {np.sqrt(np.nanmean(err**2)):.2e}; statuses {np.bincount(status, minlength=5)}")
    if args.beta:
        print("  beta  build ms  µs/contactor  max err/h  rms err/h")
        for beta in (1.25, 1.5, 1.75, 2.0, 2.5):
            b, rt = cpu(partial(RigidTarget, surface, beta=beta))
            t = min(cpu(partial(rt.evaluate, points))[0] for _ in range(3)) / n
            r = rt.evaluate(points)
            err = np.abs(r.gap - exact) / h
            print(f"  {beta:4.2f} {b * 1e3:9.1f} {t * 1e6:13.2f} {np.nanmax(err):10.2e} "
                  f"{np.sqrt(np.nanmean(err**2)):10.2e}")


if __name__ == "__main__":
    main()
