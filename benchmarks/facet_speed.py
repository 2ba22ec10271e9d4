"""The faceted method's speed against libigl's signed distance, in one run (issue 10, item 6).

The same points (default 200,000, at radius 1 ± 0.05 around a unit sphere meshed with 1692
nodes, `Sphere().mesh(13)` from diffsurf_cli/testing/shapes.py) are projected by

- `FacetSurface.project` (diffsurf's compiled engine, the surface built beforehand);
- `igl.signed_distance` with the pseudonormal sign. libigl builds its AABB tree and
  pseudonormals inside every call: that fixed cost is measured by a call with one point and
  also shown subtracted (negligible at 3380 triangles, a second at `--resolution 200`);
- the former numpy implementation (tests/reference_facet.py, facets around the 12 nearest
  nodes), on the first `--old` points only, for scale (tests/ on the path: PYTHONPATH=tests).

Each figure is the best of `--repeat` runs, the two fast methods alternating: CPU time per
point (process time, all threads) and throughput (points per second of wall time). The ratio
diffsurf / libigl is printed, never asserted; the gaps are compared as a check.

    PYTHONPATH=tests python benchmarks/facet_speed.py [--points N] [--repeat R] [--resolution N]
        [--old N]     # --old 0: without the numpy reference, no PYTHONPATH needed
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from functools import partial

import numpy as np

from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.testing.shapes import Sphere


def _oracle():
    """tests/reference_facet.py's ReferenceFacets: the slow reference lives with the tests."""
    try:
        from reference_facet import ReferenceFacets
    except ImportError:
        sys.exit("--old times tests/reference_facet.py: run with PYTHONPATH=tests (or --old 0)")
    return ReferenceFacets


def timed(fn):
    cpu, wall = time.process_time(), time.perf_counter()
    out = fn()
    return time.process_time() - cpu, time.perf_counter() - wall, out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=200_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--resolution", type=int, default=13,
                        help="Sphere().mesh(N): 13 gives 1692 nodes, 200 gives 400,002")
    parser.add_argument("--old", type=int, default=2000,
                        help="points given to the former numpy implementation (0: skip)")
    args = parser.parse_args(argv)
    try:
        import igl
    except ImportError:
        igl = None

    nodes, faces = Sphere(radius=1.0).mesh(args.resolution)
    rng = np.random.default_rng(5)
    u = rng.standard_normal((args.points, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * rng.uniform(0.95, 1.05, args.points)[:, None]
    n = len(points)
    print(f"{n:,} points at radius 1 ± 0.05 around a unit sphere of {len(nodes):,} nodes, "
          f"{len(faces):,} triangles (Sphere().mesh({args.resolution})); "
          f"{os.cpu_count()} cores; best of {args.repeat}")

    build_cpu, build_wall, surface = timed(lambda: FacetSurface(nodes, [faces]))
    surface.project(points[:64])  # warm-up
    f64 = np.ascontiguousarray(faces, dtype=np.int64)
    best = {"diffsurf": [np.inf, np.inf], "libigl": [np.inf, np.inf],
            "libigl, 1 point": [np.inf, np.inf]}
    result = igl_out = None
    for _ in range(args.repeat):
        cpu, wall, result = timed(lambda: surface.project(points))
        best["diffsurf"] = [min(best["diffsurf"][0], cpu), min(best["diffsurf"][1], wall)]
        if igl is not None:
            kind = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
            cpu, wall, igl_out = timed(
                partial(igl.signed_distance, points, nodes, f64, sign_type=kind))
            best["libigl"] = [min(best["libigl"][0], cpu), min(best["libigl"][1], wall)]
            cpu, wall, _ = timed(
                partial(igl.signed_distance, points[:1], nodes, f64, sign_type=kind))
            best["libigl, 1 point"] = [min(best["libigl, 1 point"][0], cpu),
                                       min(best["libigl, 1 point"][1], wall)]

    rows = [("FacetSurface.project (diffsurf)", n, *best["diffsurf"])]
    if igl is not None:
        rows.append(("igl.signed_distance, pseudonormal", n, *best["libigl"]))
        fixed = best["libigl, 1 point"]
        rows.append(("  the same less its tree (1-point call)", n, best["libigl"][0] - fixed[0],
                     best["libigl"][1] - fixed[1]))
    if args.old:
        ReferenceFacets = _oracle()
        m = min(args.old, n)
        old = ReferenceFacets(nodes, [faces], candidates=12)
        cpu, wall, _ = timed(lambda: old.project(points[:m], chunk=256))
        rows.append((f"former numpy FacetSurface ({m:,} points)", m, cpu, wall))
    print(f"\n{'method':44s} {'CPU µs/point':>13s} {'points/s (wall)':>16s}")
    for name, m, cpu, wall in rows:
        print(f"{name:44s} {1e6 * cpu / m:13.3f} {m / wall:16,.0f}")
    print(f"(diffsurf's surface built in {build_cpu:.3f} s CPU, {build_wall:.3f} s wall, "
          f"not in the figures)")
    if igl is not None:
        d_cpu, d_wall = best["diffsurf"]
        l_cpu, l_wall = best["libigl"]
        print(f"\nthroughput ratio diffsurf / libigl pseudonormal: {l_wall / d_wall:.2f} "
              f"(target ≥ 0.5); CPU-time ratio: {l_cpu / d_cpu:.2f}; against libigl less "
              f"its tree: {(l_wall - fixed[1]) / d_wall:.2f} and {(l_cpu - fixed[0]) / d_cpu:.2f}")
        s, _, closest, _ = igl_out
        print(f"max |gap - igl's signed distance| = {np.abs(result.gap - s).max():.2e}; "
              f"max |proximal point - igl's| = "
              f"{np.abs(result.proximal_point - closest).max():.2e}; signs differ on "
              f"{int((np.sign(result.gap) != np.sign(s)).sum())} points")
    else:
        print("\nlibigl not installed (pip install libigl): no comparison")
    if args.old:
        print(f"speed-up over the former numpy implementation (CPU per point): "
              f"{(rows[-1][2] / rows[-1][1]) / (best['diffsurf'][0] / n):,.0f}x")


if __name__ == "__main__":
    main()
