"""What an exact faceted foot costs even when its answer is known (issue 31, item 1): the nodes
of the facets' hierarchy a search must visit to prove that no facet is nearer than the true
closest one, by the points' distance to the target in node spacings h.

Issue 31 asks the default path to take the guard's faceted foot from the facets around the
support nodes, the hierarchy only where that neighbourhood cannot hold the closest facet, and
to cost at most 1.2x one `DiffuseSurface` with points within ±5% of unit icospheres. At 655k
nodes those points lie up to 11 h off the surface (82% beyond 2 h). A local answer is exact
only with a proof that nothing else is nearer; this script measures what the cheapest proof
by the hierarchy costs, seeded with the exact answer itself (the best any local search can
hand it): a traversal pruned at the true distance, from the root (`top-down`) or from the
leaf holding the answer up (`bottom-up`), with the engine's axis-aligned boxes and with
tighter oriented bounds (a cylinder along each node's mean facet normal, intersected with its
box). Pure Python over the engine's own hierarchy (`facet._engine.build_hierarchy`); counts,
not times.

    python benchmarks/facet_search_visits.py [--levels 4 6 8] [--points 300]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np


def cloud(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * rng.uniform(0.95, 1.05, (n, 1))


class Tree:
    """The engine's hierarchy of a triangle mesh, with each node's slot range, parent and an
    oriented cylinder bound."""

    def __init__(self, V, F):
        from diffsurf_cli.facet import _engine

        tri = V[F]
        fbox = np.ascontiguousarray(np.concatenate([tri.min(1), tri.max(1)], 1))
        order, self.box, self.link = _engine.build_hierarchy(
            fbox, np.ascontiguousarray(tri.mean(1)))
        self.order = order
        N = len(self.box)
        self.lo, self.hi = np.zeros(N, int), np.zeros(N, int)
        self.parent = -np.ones(N, int)
        for n in range(N - 1, -1, -1):  # children after parents: fill bottom-up
            if self.link[n, 1] > 0:
                self.lo[n], self.hi[n] = self.link[n, 0], self.link[n, 0] + self.link[n, 1]
            else:
                a, b = n + 1, self.link[n, 0]
                self.lo[n], self.hi[n] = min(self.lo[a], self.lo[b]), max(self.hi[a], self.hi[b])
                self.parent[a] = self.parent[b] = n
        T = tri[order]
        area = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        csum = np.concatenate([np.zeros((1, 3)), np.cumsum(area, 0)])
        self.C, self.n = np.zeros((N, 3)), np.zeros((N, 3))
        self.rho, self.thick = np.zeros(N), np.zeros(N)
        for k in range(N):
            nv = csum[self.hi[k]] - csum[self.lo[k]]
            nv /= np.linalg.norm(nv) + 1e-300
            P = T[self.lo[k]:self.hi[k]].reshape(-1, 3)
            c = 0.5 * (P.min(0) + P.max(0))
            z = (P - c) @ nv
            c = c + 0.5 * (z.min() + z.max()) * nv
            z = (P - c) @ nv
            self.C[k], self.n[k] = c, nv
            self.rho[k] = np.linalg.norm((P - c) - np.outer(z, nv), axis=1).max()
            self.thick[k] = np.abs(z).max()
        self.leaf_of = np.empty(len(order), int)
        for k in np.flatnonzero(self.link[:, 1] > 0):
            self.leaf_of[self.link[k, 0]:self.link[k, 0] + self.link[k, 1]] = k
        self.slot_of = np.empty(len(order), int)
        self.slot_of[order] = np.arange(len(order))

    def bound(self, k, x, oriented: bool) -> float:
        lo, hi = self.box[k, :3], self.box[k, 3:]
        d = np.maximum(np.maximum(lo - x, x - hi), 0.0)
        b = float(np.sqrt(d @ d))
        if oriented:
            r = x - self.C[k]
            z = r @ self.n[k]
            lat = np.sqrt(max(r @ r - z * z, 0.0))
            b = max(b, float(np.hypot(max(lat - self.rho[k], 0.0),
                                      max(abs(z) - self.thick[k], 0.0))))
        return b

    def below(self, start, x, d0, oriented):
        """(visits, leaves) of a pruned descent from `start` at distance d0."""
        stack, visits, leaves = [start], 0, 0
        while stack:
            k = stack.pop()
            visits += 1
            if self.bound(k, x, oriented) >= d0:
                continue
            if self.link[k, 1] > 0:
                leaves += 1
                continue
            stack += [k + 1, self.link[k, 0]]
        return visits, leaves

    def bottom_up(self, x, d0, facet, oriented):
        k = self.leaf_of[self.slot_of[facet]]
        visits, leaves = 0, 1
        while self.parent[k] >= 0:
            p = self.parent[k]
            v, lv = self.below(self.link[p, 0] if k == p + 1 else p + 1, x, d0, oriented)
            visits, leaves, k = visits + v, leaves + lv, p
        return visits, leaves


def main(argv=None):
    import trimesh

    from diffsurf_cli.facet.surface import FacetSurface

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--levels", type=int, nargs="+", default=[4, 6, 8])
    ap.add_argument("--points", type=int, default=300)
    args = ap.parse_args(argv)
    print("hierarchy nodes visited / leaves reached (4 facets each) to prove the closest facet,"
          " the search bounded by the true distance from the start; points within ±5% of "
          "unit icospheres, by distance to the surface in node spacings h")
    bands = ((0, 0.5), (0.5, 2), (2, 5), (5, 20))
    for level in args.levels:
        mesh = trimesh.creation.icosphere(subdivisions=level)
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
        tree = Tree(V, F)
        pts = cloud(100_000)[:args.points]
        facets = FacetSurface(np.ascontiguousarray(V), np.ascontiguousarray(F))
        ans = facets.project(pts)
        d, f = np.abs(ans.gap) * (1 + 1e-12), ans.facet
        h = float(np.median(facets.node_spacing))
        rows = {}
        walks = (("top-down, boxes", False, False), ("top-down, oriented", False, True),
                 ("bottom-up, boxes", True, False), ("bottom-up, oriented", True, True))
        for name, up, oriented in walks:
            rows[name] = np.array([tree.bottom_up(x, d0, g, oriented) if up
                                   else tree.below(0, x, d0, oriented)
                                   for x, d0, g in zip(pts, d, f)])
        print(f"\n{len(V):,} nodes ({len(F):,} facets), h = {h:.4f}")
        print(f"{'':>22}" + "".join(f"{f'{a}-{b} h':>14}" for a, b in bands))
        share = [np.mean((d / h >= a) & (d / h < b)) for a, b in bands]
        print(f"{'share of points':>22}" + "".join(f"{s:>14.0%}" for s in share))
        for name, r in rows.items():
            cells = []
            for a, b in bands:
                s = (d / h >= a) & (d / h < b)
                cells.append(f"{r[s, 0].mean():.0f} / {r[s, 1].mean():.1f}" if s.any() else "-")
            print(f"{name:>22}" + "".join(f"{c:>14}" for c in cells), flush=True)


if __name__ == "__main__":
    sys.exit(main())
