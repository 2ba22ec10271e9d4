"""The contact element's cost against the projection's, in one run (issue 12, speed).

A unit sphere meshed with 1692 nodes (`Sphere().mesh(13)` from diffsurf_cli/testing/shapes.py,
the default DiffuseSurface: quadratic basis, Wendland weight, local frames) and `--points`
contactors (default 20,000) inside it by 0 to 0.3 node spacings (all penetrating). Timed, CPU
time (`time.process_time`, all threads), best of `--repeat`:

- the projection with the pairing kept: `surface.project(points, keep_patch=True)`;
- the full element (g, 𝒩, ℳ) of every contactor on that pairing:
  `diffuse_elements(surface, points, patch, proximal_point, rows)`, in chunks of `--chunk`
  contactors (ℳ of 20k contactors at once would hold ~1 GB);
- the same with second=False (g and 𝒩 only: what a residual needs), in one call;
- when `diffsurf_cli.element.rigid` exists: `RigidTarget(surface).evaluate(points)` (the
  rigid-target element; its build is timed apart).

Printed: CPU per contactor of each and its ratio to the projection (the issue's targets: full
element <= 20, rigid <= 3), never asserted. `--jet N` also times the former jet element
(tests/oracle_element.py) on N contactors, for scale (tests/ on the path: PYTHONPATH=tests).

    python benchmarks/element_speed.py [--points N] [--repeat R] [--chunk C]
    PYTHONPATH=tests python benchmarks/element_speed.py --jet N

Instructions per element, repeatable where timings are not (compare versions of the kernel):
`--callgrind N` only builds the full elements of N contactors, once, in one call:

    OMP_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/element.cg \
        --collect-atstart=no --toggle-collect='*element_2elements._omp_fn*' \
        "$(python -c 'import sys; print(sys.executable)')" \
        benchmarks/element_speed.py --callgrind 2000

(the instructions of the compiled loop alone; divide the "Collected" count by N; the
interpreter itself, not a pyenv shim, must run under valgrind).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
from diffsurf_cli.element.diffuse import diffuse_elements  # noqa: E402
from diffsurf_cli.mls.surface import DiffuseSurface  # noqa: E402
from diffsurf_cli.projection import PENETRATION  # noqa: E402
from diffsurf_cli.testing.shapes import Sphere  # noqa: E402

try:
    from diffsurf_cli.element.rigid import RigidTarget
except ImportError:  # the rigid-target mode is another branch's work
    RigidTarget = None


def best(fn, repeat):
    """Least CPU time of `repeat` calls of fn, and the last result."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return min(times), out


def scene(points, resolution, rng):
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(resolution)
    spacing = shape.spacing(resolution)
    u = rng.standard_normal((points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    depth = rng.uniform(0.0, 0.3, points) * spacing
    return nodes, faces, u * (1.0 - depth)[:, None]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=13,
                        help="Sphere().mesh(N): 13 gives 1692 nodes")
    parser.add_argument("--chunk", type=int, default=2000,
                        help="contactors per diffuse_elements call")
    parser.add_argument("--basis", default="quadratic")
    parser.add_argument("--jet", type=int, default=0,
                        help="also time the jet element (tests/oracle_element.py) on N points")
    parser.add_argument("--callgrind", type=int, metavar="N",
                        help="only build the full elements of N contactors (for valgrind)")
    args = parser.parse_args(argv)

    count = args.callgrind or args.points
    nodes, faces, points = scene(count, args.resolution, np.random.default_rng(7))
    surface = DiffuseSurface(nodes, [faces], basis=args.basis)
    if args.callgrind:
        proj = surface.project(points, keep_patch=True)
        rows = np.flatnonzero(proj.status == PENETRATION)
        gap = diffuse_elements(surface, points, proj.patch, proj.proximal_point, rows)[0]
        print(f"{len(rows)} elements, {int(np.isfinite(gap).sum())} finite")
        return
    surface.project(points[:10])  # build the engine's grids outside the timings
    t_proj, proj = best(lambda: surface.project(points, keep_patch=True), args.repeat)
    rows = np.flatnonzero(proj.status == PENETRATION)
    m = len(points)

    def elements(second):
        K = 0
        chunk = args.chunk if second else len(rows)  # without ℳ, one call holds little
        for lo in range(0, len(rows), chunk):
            out = diffuse_elements(surface, points, proj.patch, proj.proximal_point,
                                   rows[lo:lo + chunk], second=second)
            K = max(K, out[1].shape[1])
        return K

    t_full, K = best(lambda: elements(True), args.repeat)
    t_first, _ = best(lambda: elements(False), args.repeat)
    support = (proj.patch.index >= 0).sum(axis=1)
    print(f"sphere of {len(nodes)} nodes, {m} contactors ({len(rows)} penetrating), "
          f"{args.basis} basis, support {support.mean():.1f} nodes on average "
          f"(K = {K} after dropping zero weights), best of {args.repeat}")
    per = lambda t, count: 1e6 * t / max(count, 1)  # noqa: E731
    print(f"projection (keep_patch)      {per(t_proj, m):9.2f} µs CPU per contactor")
    print(f"full element (g, N, M)       {per(t_full, len(rows)):9.2f} µs   "
          f"ratio {per(t_full, len(rows)) / per(t_proj, m):6.2f}  (target <= 20)")
    print(f"full element, N only         {per(t_first, len(rows)):9.2f} µs   "
          f"ratio {per(t_first, len(rows)) / per(t_proj, m):6.2f}")
    if RigidTarget is not None:
        t0 = time.process_time()
        rigid = RigidTarget(surface)
        t_build = time.process_time() - t0
        t_rigid, _ = best(lambda: rigid.evaluate(points, second=True), args.repeat)
        print(f"rigid-target element         {per(t_rigid, m):9.2f} µs   "
              f"ratio {per(t_rigid, m) / per(t_proj, m):6.2f}  (target <= 3; "
              f"build {t_build:.3f} s apart)")
    else:
        print("rigid-target element         (diffsurf_cli.element.rigid not available)")
    if args.jet:
        try:
            from oracle_element import diffuse_element
        except ImportError:
            sys.exit("--jet times tests/oracle_element.py: run with PYTHONPATH=tests")
        p = proj.patch
        some = rows[:args.jet]
        t0 = time.process_time()
        for i in some:
            diffuse_element(surface, points[i], p.index[i], p.origin[i], p.axes[i],
                            p.radius[i], proj.proximal_point[i])
        t_jet = time.process_time() - t0
        print(f"jet element (tests/, {len(some)})      {per(t_jet, len(some)):9.2f} µs   "
              f"ratio {per(t_jet, len(some)) / per(t_proj, m):6.0f}")


if __name__ == "__main__":
    main()
