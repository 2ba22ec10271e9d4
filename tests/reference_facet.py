"""The slow, obvious node-to-facet projection that `diffsurf_cli.facet` is checked against.

Brute force: every contactor against every facet, in numpy (the package's former
implementation): the closest point of a triangle by enumerating the faces of the simplex, of a
bilinear quad by projected Newton on [0, 1]² from its centre. The sign at an edge or a vertex
is the angle-weighted pseudonormal, computed the obvious way for each such contactor: the
facets holding that edge (each one's normal at its own closest point to x^m) or that vertex
(angle x corner normal). `candidates=12` restricts the search to the facets around the 12
nearest nodes, as the package's former numpy `FacetSurface` did (the benchmark's "before").
"""
from __future__ import annotations

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.projection import BAD_POINT, CONTACT, FAILED, OK, OPEN, PENETRATION, Projection

#: Projected-Newton iterations on a bilinear quad.
QUAD_ITERATIONS = 25
#: ξ within this of a bound is on the facet's edge or vertex.
EDGE_EPS = 1e-12


def shape(kind: int, xi: np.ndarray) -> np.ndarray:
    """Shape functions of a 3-node triangle or 4-node bilinear quad at ξ (..., 2) -> (..., kind)."""
    a, b = xi[..., 0], xi[..., 1]
    if kind == 3:
        return np.stack([1 - a - b, a, b], axis=-1)
    return np.stack([(1 - a) * (1 - b), a * (1 - b), a * b, (1 - a) * b], axis=-1)


def closest_on_triangles(p, a, b, c):
    """Closest point of each triangle (a, b, c) to p, all (..., 3); returns ξ (..., 2).

    Minimises over the unit triangle: the unconstrained solution, else the best of the three
    edges (clamped segment projections) — exact, by enumeration of the faces of the simplex.
    """
    e1, e2, d = b - a, c - a, p - a
    g11, g12, g22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    r1, r2 = (d * e1).sum(-1), (d * e2).sum(-1)
    det = g11 * g22 - g12 * g12
    with np.errstate(invalid="ignore", divide="ignore"):
        u = (g22 * r1 - g12 * r2) / det
        v = (g11 * r2 - g12 * r1) / det
    inside = (u >= 0) & (v >= 0) & (u + v <= 1)
    best = np.stack([u, v], axis=-1)
    cands = []
    for s0, s1 in (((0, 0), (1, 0)), ((0, 0), (0, 1)), ((1, 0), (0, 1))):
        s0, s1 = np.array(s0, float), np.array(s1, float)
        q0 = a + s0[0] * e1 + s0[1] * e2
        q1 = a + s1[0] * e1 + s1[1] * e2
        seg = q1 - q0
        with np.errstate(invalid="ignore", divide="ignore"):
            tt = np.clip(((p - q0) * seg).sum(-1) / (seg * seg).sum(-1), 0.0, 1.0)
        tt = np.where(np.isfinite(tt), tt, 0.0)  # a zero-length edge: its end
        xi = s0 + tt[..., None] * (s1 - s0)
        dist = (((q0 + tt[..., None] * seg) - p) ** 2).sum(-1)
        cands.append((dist, xi))
    dists = np.stack([c[0] for c in cands], -1)
    pick = np.argmin(dists, axis=-1)
    edge_xi = np.stack([c[1] for c in cands], -2)
    edge_xi = np.take_along_axis(edge_xi, pick[..., None, None], axis=-2)[..., 0, :]
    return np.where(inside[..., None], best, edge_xi)


def closest_on_quads(p, x):
    """Closest point of bilinear quads x (..., 4, 3) to p (..., 3) by projected Newton on [0,1]²."""
    xi = np.full(p.shape[:-1] + (2,), 0.5)
    for _ in range(QUAD_ITERATIONS):
        a, b = xi[..., 0:1], xi[..., 1:2]
        pos = ((1 - a) * (1 - b)) * x[..., 0, :] + (a * (1 - b)) * x[..., 1, :] \
            + (a * b) * x[..., 2, :] + ((1 - a) * b) * x[..., 3, :]
        ta = (1 - b) * (x[..., 1, :] - x[..., 0, :]) + b * (x[..., 2, :] - x[..., 3, :])
        tb = (1 - a) * (x[..., 3, :] - x[..., 0, :]) + a * (x[..., 2, :] - x[..., 1, :])
        tab = x[..., 0, :] - x[..., 1, :] + x[..., 2, :] - x[..., 3, :]
        r = pos - p
        g = np.stack([(r * ta).sum(-1), (r * tb).sum(-1)], -1)
        h11, h22 = (ta * ta).sum(-1), (tb * tb).sum(-1)
        h12 = (ta * tb).sum(-1) + (r * tab).sum(-1)
        # coordinates on a bound whose gradient pushes outward are held (active set)
        hold = ((xi <= 0) & (g > 0)) | ((xi >= 1) & (g < 0))
        h12 = np.where(hold.any(-1), 0.0, h12)
        h11 = np.where(hold[..., 0], 1.0, h11)
        h22 = np.where(hold[..., 1], 1.0, h22)
        g = np.where(hold, 0.0, g)
        det = h11 * h22 - h12 * h12
        det = np.where(det > 0, det, 1.0)
        step = -np.stack([(h22 * g[..., 0] - h12 * g[..., 1]), (h11 * g[..., 1] - h12 * g[..., 0])],
                         -1) / det[..., None]
        xi = np.clip(xi + step, 0.0, 1.0)
    return xi


def facet_point(x, kind, xi):
    """The point at ξ of a facet with corners x (4, 3) (a triangle uses the first 3)."""
    return shape(kind, xi) @ x[:kind]


def facet_normal(x, kind, xi):
    """Unit normal of a facet at ξ, right-hand rule over its corners (zero if degenerate)."""
    if kind == 3:
        n = np.cross(x[1] - x[0], x[2] - x[0])
    else:
        a, b = xi
        ta = (1 - b) * (x[1] - x[0]) + b * (x[2] - x[3])
        tb = (1 - a) * (x[3] - x[0]) + a * (x[2] - x[1])
        n = np.cross(ta, tb)
    norm = np.linalg.norm(n)
    return n / norm if norm > 0 else np.zeros(3)


def closest_on_facet(p, x, kind):
    """ξ of the closest point of one facet to p."""
    if kind == 3:
        return closest_on_triangles(p, x[0], x[1], x[2])
    return closest_on_quads(p, x)


def spacing(nodes):
    """Mean distance of each node to its 4 nearest distinct others (full distance matrix)."""
    distinct, inverse = np.unique(nodes, axis=0, return_inverse=True)
    d = np.sqrt(((distinct[:, None, :] - distinct[None, :, :]) ** 2).sum(-1))
    d.sort(axis=1)
    k = min(5, len(distinct))
    return d[:, 1:k].mean(axis=1)[inverse.ravel()]


class ReferenceFacets:
    """Brute-force closest point on the facets, gap and pseudonormal sign.

    nodes (n, 3), faces list of (f, 3) / (f, 4) int; `candidates`: None for all facets, k for
    the facets around the k nearest nodes (the former search, not exact).
    """

    def __init__(self, nodes, faces, *, flip=False, candidates=None):
        self.nodes = np.asarray(nodes, dtype=np.float64)
        if isinstance(faces, np.ndarray) and faces.ndim == 2:
            faces = [faces]
        faces = [np.asarray(f, dtype=np.int64) for f in faces if len(f)]
        self.facets = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in faces])
        self.kind = np.where(self.facets[:, 3] < 0, 3, 4)
        self.sign = -1.0 if flip else 1.0
        _, first, inverse = np.unique(self.nodes, axis=0, return_index=True, return_inverse=True)
        self.canon = first[inverse.ravel()]
        self.corner = self.nodes[np.where(self.facets >= 0, self.facets, self.facets[:, :1])]
        self.node_spacing = spacing(self.nodes)
        # who holds each node (facet, corner) and each edge (facets), merged nodes as one
        self.vertex_corners, self.edge_facets = {}, {}
        for g, row in enumerate(self.canon[np.maximum(self.facets, 0)]):
            k = self.kind[g]
            for j in range(k):
                self.vertex_corners.setdefault(row[j], []).append((g, j))
                self.edge_facets.setdefault(frozenset((row[j], row[(j + 1) % k])), []).append(g)
        self.candidates = candidates
        if candidates is not None:
            from scipy.spatial import cKDTree

            self.tree = cKDTree(self.nodes)
            width = max(len(v) for v in self.vertex_corners.values())
            self.incident = np.full((len(self.nodes), width), -1)  # node -> its facets
            for node in range(len(self.nodes)):
                held = [g for g, _ in self.vertex_corners.get(self.canon[node], [])
                        if node in self.facets[g]]
                self.incident[node, :len(held)] = held

    # -- the search ---------------------------------------------------------------------------
    def _closest(self, p, cand):
        """Closest point over facets cand (m, C) (-1: none) to each p (m, 3): (facet, ξ, x^m)."""
        valid = cand >= 0
        c = np.where(valid, cand, 0)
        xt = self.corner[c]  # (m, C, 4, 3)
        tri = self.kind[c] == 3
        P = p[:, None, :]
        xi_t = closest_on_triangles(P, xt[..., 0, :], xt[..., 1, :], xt[..., 2, :])
        xi_q = closest_on_quads(np.broadcast_to(P, xt.shape[:-2] + (3,)), xt)
        xi = np.where(tri[..., None], xi_t, xi_q)
        Nt = np.pad(shape(3, xi), [(0, 0), (0, 0), (0, 1)])
        N = np.where(tri[..., None], Nt, shape(4, xi))
        pos = np.einsum("mca,mcad->mcd", N, xt)
        dist = np.where(valid, ((pos - P) ** 2).sum(-1), np.inf)
        best = np.argmin(dist, axis=1)
        rows = np.arange(len(p))
        return cand[rows, best], xi[rows, best], pos[rows, best]

    def project(self, points, chunk=64) -> Projection:
        points = np.asarray(points, dtype=np.float64)
        m = len(points)
        facet = np.full(m, -1)
        xi = np.full((m, 2), np.nan)
        xm = np.full((m, 3), np.nan)
        ok = np.all(np.isfinite(points), axis=1)
        rows = np.flatnonzero(ok)
        for lo in range(0, len(rows), chunk):
            r = rows[lo:lo + chunk]
            if self.candidates is None:
                cand = np.broadcast_to(np.arange(len(self.facets)), (len(r), len(self.facets)))
            else:  # the facets around the nearest nodes, each once
                k = min(self.candidates, len(self.nodes))
                _, near = self.tree.query(points[r], k=k)
                cand = np.sort(self.incident[near.reshape(len(r), k)].reshape(len(r), -1), axis=1)
                cand[:, 1:][cand[:, 1:] == cand[:, :-1]] = -1
            facet[r], xi[r], xm[r] = self._closest(points[r], cand)
        return self._answer(points, facet, xi, xm)

    def project_with(self, points, given) -> Projection:
        points = np.asarray(points, dtype=np.float64)
        given = np.asarray(given, dtype=np.int64)
        m = len(points)
        facet = np.full(m, -1)
        xi = np.full((m, 2), np.nan)
        xm = np.full((m, 3), np.nan)
        for i in range(m):
            f = given[i]
            if f < 0 or not np.all(np.isfinite(points[i])):
                continue
            k = self.kind[f]
            xi[i] = closest_on_facet(points[i], self.corner[f], k)
            xm[i] = facet_point(self.corner[f], k, xi[i])
            facet[i] = f
        return self._answer(points, facet, xi, xm)

    # -- the sign -----------------------------------------------------------------------------
    def pseudonormal(self, f, xi, xm):
        """Pseudonormal at x^m on facet f at ξ (facet orientation), where: 'interior', 'edge'
        or 'vertex', and the nodes of that feature."""
        k = self.kind[f]
        a, b = xi
        e = EDGE_EPS
        if k == 3:
            corner_at = {(0, 0): 0, (1, 0): 1, (0, 1): 2}
            on = [b <= e, a + b >= 1 - e, a <= e]  # edges 0-1, 1-2, 2-0
            near = (round(a), round(b))
            at_vertex = (a <= e and b <= e) or a >= 1 - e or b >= 1 - e
        else:
            corner_at = {(0, 0): 0, (1, 0): 1, (1, 1): 2, (0, 1): 3}
            on = [b <= e, a >= 1 - e, b >= 1 - e, a <= e]  # edges 0-1, 1-2, 2-3, 3-0
            near = (round(a), round(b))
            at_vertex = (a <= e or a >= 1 - e) and (b <= e or b >= 1 - e)
        corners = self.canon[self.facets[f, :k]]
        if at_vertex:
            node = corners[corner_at[near]]
            n = np.zeros(3)
            for g, j in self.vertex_corners[node]:
                kg = self.kind[g]
                x = self.corner[g]
                e1, e2 = x[(j + 1) % kg] - x[j], x[(j - 1) % kg] - x[j]
                c = np.cross(e1, e2)
                if np.linalg.norm(c) > 0:
                    angle = np.arctan2(np.linalg.norm(c), e1 @ e2)
                    n += angle * c / np.linalg.norm(c)
            return n, "vertex", [node]
        if not any(on):
            return facet_normal(self.corner[f], k, xi), "interior", corners
        j = int(np.flatnonzero(on)[0])
        n = np.zeros(3)
        for g in self.edge_facets[frozenset((corners[j], corners[(j + 1) % k]))]:
            kg = self.kind[g]
            xg = closest_on_facet(xm, self.corner[g], kg)
            n += facet_normal(self.corner[g], kg, xg)
        return n, "edge", [corners[j], corners[(j + 1) % k]]

    def _answer(self, points, facet, xi, xm) -> Projection:
        m = len(points)
        gap = np.full(m, np.nan)
        normal = np.full((m, 3), np.nan)
        status = np.full(m, FAILED, dtype=np.int8)
        reason = np.full(m, BAD_POINT, dtype=np.int8)
        for i in np.flatnonzero(facet >= 0):
            f = facet[i]
            k = self.kind[f]
            d = points[i] - xm[i]
            dist = np.linalg.norm(d)
            nf = facet_normal(self.corner[f], k, xi[i])
            pn, where, feature = self.pseudonormal(f, xi[i], xm[i])
            # spacing at the feature: mean over the facet's corners, the edge's or the vertex
            h = self.node_spacing[feature].mean()
            if where == "interior" and np.any(nf != 0):
                normal[i] = self.sign * nf
                gap[i] = d @ normal[i]
            elif dist <= tol.CONTACT * h:  # on the target at an edge or vertex: pseudonormal
                size = np.linalg.norm(pn)
                normal[i] = self.sign * (pn / size if size > 0 else nf)
                gap[i] = d @ normal[i]
            else:
                s = d @ pn
                if s == 0:
                    s = d @ nf
                s = self.sign * (1.0 if s >= 0 else -1.0)
                normal[i] = s * d / dist
                gap[i] = s * dist
            status[i] = CONTACT if abs(gap[i]) <= tol.CONTACT * h else (
                OPEN if gap[i] > 0 else PENETRATION)
            reason[i] = OK
        failed = status == FAILED
        res = Projection(points, gap, normal, xm, status, np.where(failed, 0, self.kind[facet]),
                         np.zeros(m, dtype=np.int64), np.where(failed, np.nan, 1.0),
                         np.where(failed[:, None], np.nan, np.zeros((m, 2))), reason)
        res.facet = facet
        res.param = xi
        return res
