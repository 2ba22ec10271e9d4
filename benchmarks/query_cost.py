"""The cost of a query (issue 31): the default surface (`build_surface`: patches, the guard's
faceted foot, what `diffsurf project` builds) against one `DiffuseSurface`, the facets alone
(`FacetSurface`) and libigl's pseudonormal `signed_distance`, per point, in one run.

Targets: unit trimesh icospheres (subdivisions 4, 6, 8: 2.5k, 41k, 655k nodes). Points:
`--points` (100k) uniform in direction, radius uniform in [0.95, 1.05] (within ±5%), the same
cloud for every target and variant. CPU time (time.process_time), one thread
(OMP_NUM_THREADS=1 is set before the compiled modules load), best of `--repeat` calls, each
surface built (and its lazy tables made by a first call on 10 points) before timing; libigl
builds its AABB tree inside every call, as its API does.

Printed per target: µs a point of each variant; the ratios the issue asks of the default
(<= 1.2 x one surface at every size, <= libigl at 2.5k nodes) and of one surface's growth
(655k / 2.5k <= 1.5); and, to show where the default's extra cost lies, the facets' cost
split by the points' distance to the target in node spacings h (near: |d| < 2 h; far: the
rest): an exact closest-facet search visits the leaves of its hierarchy within about
sqrt(2 d h) of the foot, so its cost grows with d / h where the diffuse projection's (a
support of a few spacings around the proximal point) does not.

    python benchmarks/query_cost.py [--levels 4 6 8] [--points 100000] [--repeat 3]

Results: benchmarks/results/query_cost.txt.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from common import best_cpu


def cloud(n: int, seed: int = 0) -> np.ndarray:
    """n points within ±5% of the unit sphere, uniform in direction."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(0.95, 1.05, (n, 1))


def measure(level: int, points: np.ndarray, repeat: int) -> dict:
    """CPU µs a point of each variant on the icosphere of `level` subdivisions."""
    import trimesh

    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.mls.surface import DiffuseSurface
    from diffsurf_cli.targets import build_surface

    mesh = trimesh.creation.icosphere(subdivisions=level)
    nodes = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    default, one, facets = build_surface(nodes, faces), DiffuseSurface(nodes, faces), \
        FacetSurface(nodes, faces)
    for s in (default, one, facets):
        s.project(points[:10])
    us = 1e6 / len(points)
    row = {"nodes": len(nodes),
           "default": best_cpu(lambda: default.project(points), repeat) * us,
           "one": best_cpu(lambda: one.project(points), repeat) * us,
           "facets": best_cpu(lambda: facets.project(points), repeat) * us}
    h = float(np.median(facets.node_spacing))
    near = np.abs(np.linalg.norm(points, axis=1) - 1.0) < 2 * h
    row["near share"] = near.mean()
    for name, rows in (("facets near", points[near]), ("facets far", points[~near])):
        row[name] = (best_cpu(lambda r=rows: facets.project(r), repeat) * 1e6 / len(rows)
                     if len(rows) else np.nan)
    try:
        import igl
    except ImportError:
        row["libigl"] = np.nan
    else:
        sign = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
        row["libigl"] = best_cpu(lambda: igl.signed_distance(points, nodes, faces,
                                                             sign_type=sign), repeat) * us
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", type=int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    points = cloud(args.points)
    print(f"{len(points):,} points within ±5% of a unit icosphere, one thread, CPU µs a "
          f"point (best of {args.repeat})")
    print(f"{'nodes':>9} {'default':>8} {'one':>7} {'facets':>7} {'libigl':>7} "
          f"{'def/one':>8} {'def/igl':>8} {'one/first':>9} {'facets near':>13} "
          f"{'facets far':>12}")
    first = None
    for level in args.levels:
        r = measure(level, points, args.repeat)
        first = r["one"] if first is None else first
        print(f"{r['nodes']:>9,} {r['default']:>8.2f} {r['one']:>7.2f} {r['facets']:>7.2f} "
              f"{r['libigl']:>7.2f} {r['default'] / r['one']:>8.2f} "
              f"{r['default'] / r['libigl']:>8.2f} {r['one'] / first:>9.2f} "
              f"{r['facets near']:>6.2f} ({r['near share']:>4.0%}) "
              f"{r['facets far']:>5.2f} ({1 - r['near share']:>4.0%})", flush=True)


if __name__ == "__main__":
    main()
