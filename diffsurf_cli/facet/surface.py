"""The faceted target: closest point on its facets, the node-to-facet baseline of §2.

Facets are linear triangles and bilinear quads (higher-order cells use their corners), with
parameters ξ in the unit triangle or the unit square. The proximal point x^m [1] is the
closest point over all the facets (exact on triangles; projected Newton on a bilinear quad);
the gap is g = (x^c - x^m)·ν [2], with ν the facet normal inside a facet, and at an edge or a
vertex the direction x^c - x^m signed by the angle-weighted pseudonormal there (libigl's
'pseudonormal' sign: the right side on closed, consistently oriented meshes, whichever facet
of the edge or vertex is picked). The search and the gap are compiled (`_engine.pyx`).
"""
from __future__ import annotations

import numpy as np

from .. import tol
from ..mls.surface import FAILED, Projection, _as_points
from . import _engine

#: Contactors per call of the engine: `project` reports progress after each.
CHUNK = 65536


class FacetSurface:
    """The faceted target itself, projected onto as the node-to-facet element does [§2].

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, 3) or (f, 4) int, or one such array
        Triangles and quads (corners), indexing `nodes`.
    flip : bool
        Reverse the facet orientation.
    """

    def __init__(self, nodes, faces, *, flip=False):
        self.nodes = _as_points(nodes, "nodes")
        if not np.all(np.isfinite(self.nodes)):
            raise ValueError("target nodes contain NaN or inf")
        top = np.abs(self.nodes).max(initial=0.0)
        if not top < tol.COORDINATE_MAX:
            raise ValueError(f"target coordinates reach {top:.3g}, beyond the supported "
                             f"{tol.COORDINATE_MAX:.0e}: rescale the mesh")
        if isinstance(faces, np.ndarray) and faces.ndim == 2:
            faces = [faces]  # one block of facets
        faces = [np.asarray(f, dtype=np.int64) for f in faces]
        faces = [f for f in faces if f.size]
        if not faces:
            raise ValueError("the facet method needs surface cells (triangles or quads)")
        n = len(self.nodes)
        for f in faces:
            if f.ndim != 2 or f.shape[1] not in (3, 4):
                raise ValueError(f"facets must have 3 or 4 corners, got shape {f.shape}")
            if f.min() < 0 or f.max() >= n:
                raise ValueError(f"facet corners must index the {n} nodes")
        # one table of facets, triangles padded with -1 in the 4th corner
        self.facets = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in faces])
        self.flip = bool(flip)
        self.sign = -1.0 if flip else 1.0
        # coincident nodes (a zone boundary) are one node for the edges and vertices
        _, first, inverse = np.unique(self.nodes, axis=0, return_index=True, return_inverse=True)
        if len(first) < 3:
            raise ValueError("the target has fewer than 3 distinct nodes")
        self.node_spacing = _spacing(self.nodes[first])[inverse.ravel()]
        if not self.node_spacing.min() > tol.SPACING_MIN:
            raise ValueError(f"the target's node spacing is down to {self.node_spacing.min():.3g}, "
                             f"below the supported {tol.SPACING_MIN:.0e}: rescale the mesh")
        self._tables = _tables(self.nodes, first[inverse.ravel()], self.facets, self.sign,
                               tol.CONTACT * self.node_spacing[self.facets[:, 0]])

    def project(self, points, *, progress=None, **_) -> Projection:
        """Closest point on the facets [1], gap [2] and normal of each contactor.

        Parameters
        ----------
        points : (m, 3) float
        progress : callable, optional
            Called as ``progress(done)`` after each chunk of `CHUNK` contactors.

        Returns
        -------
        Projection, with also ``facet`` (m,) int (-1 where failed) and ``param`` (m, 2) float,
        the facet and its parameters ξ at the proximal point.
        """
        return self._project(points, None, progress)

    def project_with(self, points, facet) -> Projection:
        """Closest point on one given facet per contactor (a frozen pairing); -1: failed."""
        points = _as_points(points)
        facet = np.asarray(facet, dtype=np.int64).reshape(-1)
        if len(facet) != len(points) or facet.max(initial=-1) >= len(self.facets) \
                or facet.min(initial=-1) < -1:
            raise ValueError("the pairing does not match the contactors and the target facets")
        return self._project(points, facet, None)

    def _project(self, points, given, progress) -> Projection:
        points = np.ascontiguousarray(_as_points(points))
        m = len(points)
        gap = np.empty(m)
        normal = np.empty((m, 3))
        prox = np.empty((m, 3))
        status = np.empty(m, dtype=np.int8)
        reason = np.empty(m, dtype=np.int8)
        facet = np.empty(m, dtype=np.int64)
        param = np.empty((m, 2))
        support = np.empty(m, dtype=np.int64)
        iterations = np.empty(m, dtype=np.int64)
        for lo in range(0, m, CHUNK):
            hi = min(lo + CHUNK, m)
            _engine.project(self._tables, points[lo:hi], gap[lo:hi], normal[lo:hi],
                            prox[lo:hi], status[lo:hi], reason[lo:hi], facet[lo:hi],
                            param[lo:hi], support[lo:hi], iterations[lo:hi],
                            None if given is None else given[lo:hi])
            if progress is not None:
                progress(hi)
        failed = status == FAILED
        curvature = np.zeros((m, 2))  # flat facets (a quad's twist is not reported)
        curvature[failed] = np.nan
        res = Projection(points, gap, normal, prox, status, support, iterations,
                         np.where(failed, np.nan, 1.0), curvature, reason)
        res.facet = facet
        res.param = param
        return res


def _spacing(nodes: np.ndarray) -> np.ndarray:
    """Local node spacing: mean distance of each node to its 4 nearest (as the diffuse
    surface's), a function of the geometry only."""
    from scipy.spatial import cKDTree

    k = min(5, len(nodes))
    dist, _ = cKDTree(nodes).query(nodes, k=k)
    return dist[:, 1:].mean(axis=1)


def _tables(nodes, canon, facets, sign, ctol) -> dict:
    """The arrays the engine searches: facets in hierarchy order ('slots'), coordinates
    relative to the target's centre, edge and vertex pseudonormals."""
    used = np.unique(facets[facets >= 0])
    lo, hi = nodes[used].min(axis=0), nodes[used].max(axis=0)
    centre = 0.5 * (lo + hi)
    X = nodes - centre
    radius = float(np.sqrt((X[used] ** 2).sum(axis=1).max()))
    kind = np.where(facets[:, 3] < 0, 3, 4).astype(np.int64)
    corner = X[np.where(facets >= 0, facets, facets[:, :1])]  # (F, 4, 3); a triangle repeats a
    fbox = np.concatenate([corner.min(axis=1), corner.max(axis=1)], axis=1)
    centroid = corner.mean(axis=1)
    order, box, link = _engine.build_hierarchy(np.ascontiguousarray(fbox),
                                               np.ascontiguousarray(centroid))
    F = len(facets)
    slot = np.empty(F, dtype=np.int64)
    slot[order] = np.arange(F)
    corner, kind, facets = corner[order], kind[order], facets[order]
    fnode = np.where(facets >= 0, canon[np.maximum(facets, 0)], -1)
    # triangle normals; quads' vary over the facet and are evaluated where needed
    fnormal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
    fnormal = _unit(np.where((kind == 3)[:, None], fnormal, 0.0))
    # edges: local edge j runs from corner j to corner j + 1; the same pair of nodes is one edge
    j = np.arange(4)
    nxt = np.where(j[None, :] + 1 < kind[:, None], j[None, :] + 1, 0)
    a, b = fnode, np.take_along_axis(fnode, nxt, axis=1)
    real = j[None, :] < kind[:, None]
    key = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=-1)[real]
    _, edge = np.unique(key, axis=0, return_inverse=True)
    edge = edge.ravel()
    fedge = np.full((F, 4), -1, dtype=np.int64)
    fedge[real] = edge
    inc = (4 * np.arange(F)[:, None] + j[None, :])[real]
    by_edge = np.argsort(edge, kind="stable")
    edge_ptr = np.concatenate([[0], np.cumsum(np.bincount(edge, minlength=edge.max() + 1))])
    # vertex pseudonormals: Σ over the corners at a node of angle x unit corner normal
    prv = np.where(j[None, :] > 0, j[None, :] - 1, kind[:, None] - 1)
    here = corner
    e1 = np.take_along_axis(corner, nxt[..., None], axis=1) - here
    e2 = np.take_along_axis(corner, prv[..., None], axis=1) - here
    cr = np.cross(e1, e2)
    angle = np.arctan2(np.linalg.norm(cr, axis=-1), (e1 * e2).sum(-1))
    vnormal = np.zeros_like(nodes)
    np.add.at(vnormal, fnode[real], (angle[..., None] * _unit(cr))[real])
    vnormal = _unit(vnormal)
    return {"corner": np.ascontiguousarray(corner), "kind": kind,
            "fnormal": np.ascontiguousarray(fnormal), "fnode": np.ascontiguousarray(fnode),
            "fedge": fedge, "edge_ptr": edge_ptr.astype(np.int64),
            "edge_inc": np.ascontiguousarray(inc[by_edge], dtype=np.int64),
            "vnormal": np.ascontiguousarray(vnormal), "box": box, "link": link,
            "ctol": np.ascontiguousarray(ctol[order], dtype=np.float64), "original": order,
            "slot": slot, "centre": np.ascontiguousarray(centre), "radius": max(radius, 1e-300),
            "sign": float(sign)}


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of v scaled to unit length; zero rows (degenerate) stay zero."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, v / norm, 0.0)


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
