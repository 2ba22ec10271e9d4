"""The faceted target: closest point on its facets, the node-to-facet baseline of §2.

Facets are linear triangles and bilinear quads (higher-order cells use their corners), with
parameters ξ in the unit triangle or the unit square. The proximal point x^m [1] is the closest
point over the facets around the contactor; the gap is g = (x^c - x^m)·ν [2], with ν the facet
normal there (at an edge or a vertex, ν is the direction x^c - x^m, signed by the facet's side).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .. import tol
from ..mls.surface import (BAD_POINT, CONTACT, FAILED, OK, OPEN, PENETRATION, Projection, _as_points,
                      _blank)

#: Facets touching this many nearest nodes of the contactor are searched.
CANDIDATE_NODES = 12
#: Projected-Newton iterations on a bilinear quad.
QUAD_ITERATIONS = 25


def shape(kind: int, xi: np.ndarray) -> np.ndarray:
    """Shape functions of a 3-node triangle or 4-node bilinear quad at ξ (..., 2) -> (..., kind)."""
    a, b = xi[..., 0], xi[..., 1]
    if kind == 3:
        return np.stack([1 - a - b, a, b], axis=-1)
    return np.stack([(1 - a) * (1 - b), a * (1 - b), a * b, (1 - a) * b], axis=-1)


def _closest_on_triangles(p, a, b, c):
    """Closest point of each triangle (a, b, c) to p, all (..., 3); returns ξ (..., 2).

    Minimises over the unit triangle: the unconstrained solution, else the best of the three
    edges (clamped segment projections) — exact, by enumeration of the faces of the simplex.
    """
    e1, e2, d = b - a, c - a, p - a
    g11, g12, g22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    r1, r2 = (d * e1).sum(-1), (d * e2).sum(-1)
    det = g11 * g22 - g12 * g12
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
        tt = np.clip(((p - q0) * seg).sum(-1) / (seg * seg).sum(-1), 0.0, 1.0)
        xi = s0 + tt[..., None] * (s1 - s0)
        dist = (((q0 + tt[..., None] * seg) - p) ** 2).sum(-1)
        cands.append((dist, xi))
    dists = np.stack([c[0] for c in cands], -1)
    pick = np.argmin(dists, axis=-1)
    edge_xi = np.stack([c[1] for c in cands], -2)
    edge_xi = np.take_along_axis(edge_xi, pick[..., None, None], axis=-2)[..., 0, :]
    return np.where(inside[..., None], best, edge_xi)


def _closest_on_quads(p, x):
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


class FacetSurface:
    """The faceted target itself, projected onto as the node-to-facet element does [§2].

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, 3) or (f, 4) int
        Triangles and quads (corners), indexing `nodes`.
    flip : bool
        Reverse the facet orientation.
    """

    def __init__(self, nodes, faces, *, flip=False):
        self.nodes = _as_points(nodes, "nodes")
        faces = [np.asarray(f, dtype=np.int64) for f in faces]
        if not faces or sum(len(f) for f in faces) == 0:
            raise ValueError("the facet method needs surface cells (triangles or quads)")
        # one table of facets, triangles padded with -1 in the 4th corner
        self.facets = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in faces])
        self.flip = bool(flip)
        self.sign = -1.0 if flip else 1.0
        self.tree = cKDTree(self.nodes)
        n = len(self.nodes)
        # node -> incident facets, as a padded table
        corners = self.facets.ravel()
        owners = np.repeat(np.arange(len(self.facets)), 4)
        keep = corners >= 0
        corners, owners = corners[keep], owners[keep]
        order = np.argsort(corners, kind="stable")
        corners, owners = corners[order], owners[order]
        counts = np.bincount(corners, minlength=n)
        width = max(int(counts.max(initial=1)), 1)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        rank = np.arange(len(corners)) - start[corners]
        self.incident = np.full((n, width), -1, dtype=np.int64)
        self.incident[corners, rank] = owners
        dist, _ = self.tree.query(self.nodes, k=min(5, n))
        self.node_spacing = dist[:, 1:].mean(axis=1)

    def project(self, points, **_) -> Projection:
        """Closest point on the facets [1], gap [2] and facet normal of each contactor."""
        points = _as_points(points)
        m = len(points)
        finite = np.all(np.isfinite(points), axis=1)
        safe = np.where(finite[:, None], points, self.nodes[0])
        k = min(CANDIDATE_NODES, len(self.nodes))
        _, near = self.tree.query(safe, k=k)
        cand = self.incident[near.reshape(m, k)].reshape(m, -1)
        cand = np.sort(cand, axis=1)
        cand[:, 1:][cand[:, 1:] == cand[:, :-1]] = -1  # de-duplicate
        return self._project(points, cand)

    def project_with(self, points, facet: np.ndarray) -> Projection:
        """Closest point on one given facet per contactor (a frozen pairing); -1: failed."""
        points = _as_points(points)
        facet = np.asarray(facet, dtype=np.int64).reshape(-1, 1)
        if len(facet) != len(points) or facet.max(initial=-1) >= len(self.facets):
            raise ValueError("the pairing does not match the contactors and the target facets")
        return self._project(points, facet)

    def _project(self, points: np.ndarray, cand: np.ndarray) -> Projection:
        m = len(points)
        finite = np.all(np.isfinite(points), axis=1) & (cand.max(axis=1) >= 0)
        safe = np.where(finite[:, None], points, self.nodes[0])
        valid = cand >= 0
        fac = self.facets[np.where(valid, cand, 0)]  # (m, C, 4)
        tri = fac[..., 3] < 0
        x = self.nodes[np.where(fac >= 0, fac, fac[..., :1])]  # (m, C, 4, 3)
        p = safe[:, None, :]
        xi_t = _closest_on_triangles(p, x[..., 0, :], x[..., 1, :], x[..., 2, :])
        xi_q = _closest_on_quads(np.broadcast_to(p, x.shape[:-2] + (3,)), x)
        xi = np.where(tri[..., None], xi_t, xi_q)
        Nt = shape(3, xi)
        Nq = shape(4, xi)
        Nfull = np.where(tri[..., None], np.pad(Nt, [(0, 0)] * (Nt.ndim - 1) + [(0, 1)]), Nq)
        pos = np.einsum("mca,mcad->mcd", Nfull, x)
        dist = np.where(valid, ((pos - p) ** 2).sum(-1), np.inf)
        best = np.argmin(dist, axis=1)
        rows = np.arange(m)
        facet = cand[rows, best]
        xi_b = xi[rows, best]
        xm = pos[rows, best]
        corners = x[rows, best]
        area = np.where(tri[rows, best][:, None],
                        np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                        self._quad_normal(corners, xi_b))
        nf = self.sign * area / np.linalg.norm(area, axis=1, keepdims=True)
        d = points - xm
        dn = np.linalg.norm(d, axis=1)
        on_facet = _interior(xi_b, tri[rows, best])
        side = np.where((d * nf).sum(1) >= 0, 1.0, -1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            edge_normal = side[:, None] * d / dn[:, None]
        normal = np.where(on_facet[:, None] | (dn[:, None] == 0), nf, edge_normal)
        gap = (d * normal).sum(1)
        h = self.node_spacing[self.facets[np.maximum(facet, 0), 0]]
        status = np.where(gap > 0, OPEN, PENETRATION).astype(np.int8)
        status[np.abs(gap) <= tol.CONTACT * h] = CONTACT
        status[~finite] = FAILED
        support = np.where(finite, np.where(tri[rows, best], 3, 4), 0)
        res = Projection(points, gap, normal, xm, status, support,
                         np.zeros(m, dtype=np.int64), np.where(finite, 1.0, np.nan),
                         np.zeros((m, 2)),
                         np.where(finite, OK, BAD_POINT).astype(np.int8))
        _blank(res, ~finite)
        res.facet = np.where(finite, facet, -1)
        res.param = xi_b
        return res

    @staticmethod
    def _quad_normal(x, xi):
        a, b = xi[:, 0:1], xi[:, 1:2]
        ta = (1 - b) * (x[:, 1] - x[:, 0]) + b * (x[:, 2] - x[:, 3])
        tb = (1 - a) * (x[:, 3] - x[:, 0]) + a * (x[:, 2] - x[:, 1])
        return np.cross(ta, tb)


def _interior(xi, tri, eps=1e-12):
    a, b = xi[:, 0], xi[:, 1]
    in_tri = (a > eps) & (b > eps) & (a + b < 1 - eps)
    in_quad = (a > eps) & (b > eps) & (a < 1 - eps) & (b < 1 - eps)
    return np.where(tri, in_tri, in_quad)


def free_parameters(xi, kind, eps=1e-12) -> str:
    """Where ξ lies on the facet: 'interior', on an edge where only 'a' or only 'b' is free,
    on a triangle's 'hypotenuse' (a + b = 1, free along it: b = 1 - a), or at a 'vertex'."""
    a, b = xi
    if kind == 3:
        if a > eps and b > eps and a + b < 1 - eps:
            return "interior"
        if a + b >= 1 - eps and a > eps and b > eps:
            return "hypotenuse"
    free_a, free_b = eps < a < 1 - eps, eps < b < 1 - eps
    if free_a and free_b:
        return "interior"
    if free_a:
        return "a"
    if free_b:
        return "b"
    return "vertex"
