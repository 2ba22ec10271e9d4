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

import copy

import numpy as np

from .. import tol
from ..projection import (
    FAILED,
    Projection,
    as_faces,
    as_moved_nodes,
    as_points,
    as_target_nodes,
    warn_inside_out,
)
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
    check_winding : bool
        Warn (`projection.InsideOutWarning`, naming flip=True) where the facets hold a closed
        surface wound inside out; not with `flip` (`DiffuseSurface`).
    """

    def __init__(self, nodes, faces, *, flip=False, check_winding=True):
        self.nodes = as_target_nodes(nodes)
        faces = [f for f in as_faces(faces, len(self.nodes), (3, 4)) if f.size]
        if not faces:
            raise ValueError("the facet method needs surface cells (triangles or quads)")
        if check_winding and not flip:  # a closed target wound inside out: say so
            warn_inside_out(self.nodes, faces, _merge(self.nodes)[0])
        # one table of facets, triangles padded with -1 in the 4th corner
        self.facets = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in faces])
        self.flip = bool(flip)
        self.sign = -1.0 if flip else 1.0
        self._geometry()

    def _geometry(self) -> None:
        """Node spacing and the search's tables, from the nodes' positions."""
        # coincident nodes (a zone boundary) are one node for the edges and vertices
        first, distinct, group = _merge(self.nodes)
        if len(distinct) < 3:
            raise ValueError("the target has fewer than 3 distinct nodes")
        self.node_spacing = _spacing(self.nodes[distinct])[group]
        if not self.node_spacing.min() > tol.SPACING_MIN:
            raise ValueError(f"the target's node spacing is down to {self.node_spacing.min():.3g}, "
                             f"below the supported {tol.SPACING_MIN:.0e}: rescale the mesh")
        self._tables = _tables(self.nodes, first, self.facets, self.sign,
                               tol.CONTACT * self.node_spacing)
        self._engine = None

    def moved(self, nodes) -> FacetSurface:
        """The same facets with their nodes at new positions (a deformable target): facet
        numbers, hence a pairing (`projection.facet`), stay valid."""
        nodes = as_moved_nodes(nodes, self.nodes)
        new = copy.copy(self)
        new.nodes = nodes
        new._geometry()
        return new

    def __getstate__(self):
        # the compiled engine's view does not pickle; it is rebuilt on first use
        state = self.__dict__.copy()
        state["_engine"] = None
        return state

    @property
    def engine(self) -> _engine.FacetTables:
        """The compiled search's view of the facet tables, built on first use."""
        if self._engine is None:
            self._engine = _engine.FacetTables(self._tables)
        return self._engine

    def _order_keys(self, points) -> np.ndarray:
        """A spatial key of each point (m,): its Morton code over the target's box, for taking
        contactors in an order where neighbours follow each other."""
        return _morton(np.asarray(points, dtype=np.float64), self._tables)

    def project(self, points, *, progress=None, **_) -> Projection:
        """Closest point on the facets [1], gap [2] and normal of each contactor.

        Parameters
        ----------
        points : (m, 3) float
        progress : callable, optional
            Called as ``progress(0)`` when the work starts, then ``progress(done)`` after
            each chunk of `CHUNK` contactors.

        Returns
        -------
        Projection, with also ``facet`` (m,) int (-1 where failed) and ``param`` (m, 2) float,
        the facet and its parameters ξ at the proximal point.
        """
        return self._project(points, None, progress)

    def project_with(self, points, facet) -> Projection:
        """Closest point on one given facet per contactor (a frozen pairing); -1: failed."""
        points = as_points(points)
        facet = np.asarray(facet, dtype=np.int64).reshape(-1)
        if len(facet) != len(points):
            raise ValueError(f"the pairing is for {len(facet)} contactors, got {len(points)}")
        if facet.max(initial=-1) >= len(self.facets) or facet.min(initial=-1) < -1:
            raise ValueError("the pairing does not match the contactors and the target facets")
        return self._project(points, facet, None)

    def _project(self, points, given, progress) -> Projection:
        points = np.ascontiguousarray(as_points(points))
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
        order = _spatial_order(points, self._tables)
        if progress is not None:
            progress(0)  # the work starts: what came before was setup
        for lo in range(0, m, CHUNK):
            hi = min(lo + CHUNK, m)
            _engine.project(self.engine, points, gap, normal, prox, status, reason, facet,
                            param, support, iterations, order[lo:hi], given)
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

    def contact(self, points, *, rigid_target: bool = False, pairing=None,
                second: bool = True):
        """The contact element of every closed contact (`element.contact`, the
        `projection.Surface` protocol): the node-to-facet element [§2]."""
        from ..element.element import facet_contact

        return facet_contact(self, points, rigid_target=rigid_target, pairing=pairing,
                    second=second)

def _merge(nodes: np.ndarray):
    """Exact duplicates: (first (n,) the first node at each node's position, distinct (d,) the
    first of each position, group (n,) each node's position in `distinct`)."""
    order = np.lexsort(nodes.T[::-1])  # stable: a position's first node comes first
    s = nodes[order]
    new = np.ones(len(nodes), bool)
    new[1:] = np.any(s[1:] != s[:-1], axis=1)
    distinct = order[new]
    group = np.empty(len(nodes), dtype=np.int64)
    group[order] = np.cumsum(new) - 1
    return distinct[group], distinct, group


def _spacing(nodes: np.ndarray) -> np.ndarray:
    """Local node spacing: mean distance of each node to its `tol.SPACING_NEIGHBOURS` (4)
    nearest (as the diffuse surface's), a function of the geometry only."""
    from scipy.spatial import cKDTree

    k = min(tol.SPACING_NEIGHBOURS + 1, len(nodes))
    dist, _ = cKDTree(nodes).query(nodes, k=k, workers=-1)
    return dist[:, 1:].mean(axis=1)


def _spatial_order(points: np.ndarray, tables: dict) -> np.ndarray:
    """Contactors in Morton (Z-curve) order over the target's box, 10 bits a coordinate: the
    engine then takes nearby contactors together, and their searches share the cache."""
    if len(points) < 2048:
        return np.arange(len(points), dtype=np.int64)
    return np.argsort(_morton(points, tables), kind="stable").astype(np.int64)


def _morton(points: np.ndarray, tables: dict) -> np.ndarray:
    """Morton code (m,) of each point over the target's box, 10 bits a coordinate."""
    r = tables["radius"]
    q = (points - (tables["centre"] - 1.25 * r)) * (1023 / (2.5 * r))
    q = np.clip(np.nan_to_num(q), 0, 1023).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for axis in range(3):
        x = q[:, axis]
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        x = (x | (x << np.uint64(2))) & np.uint64(0x09249249)
        code |= x << np.uint64(axis)
    return code


def _tables(nodes, canon, facets, sign, ctol) -> dict:
    """The arrays the engine searches: facets in hierarchy order ('slots'), coordinates
    relative to the target's centre, edge and vertex pseudonormals."""
    n, F = len(nodes), len(facets)
    used = np.zeros(n, bool)
    used[facets[facets >= 0]] = True
    lo, hi = nodes[used].min(axis=0), nodes[used].max(axis=0)
    centre = 0.5 * (lo + hi)
    X = nodes - centre
    radius = float(np.sqrt((X[used] ** 2).sum(axis=1).max()))
    kind = np.where(facets[:, 3] < 0, 3, 4).astype(np.int64)
    corner = X[np.where(facets >= 0, facets, facets[:, :1])]  # (F, 4, 3); a triangle repeats a
    centroid = corner.mean(axis=1)
    order, box, link = _engine.build_hierarchy(
        np.ascontiguousarray(np.concatenate([corner.min(axis=1), corner.max(axis=1)], axis=1)),
        np.ascontiguousarray(centroid))
    slot = np.empty(F, dtype=np.int64)
    slot[order] = np.arange(F)
    corner = np.ascontiguousarray(corner[order])
    kind, facets = kind[order], facets[order]
    fnode = np.ascontiguousarray(np.where(facets >= 0, canon[np.maximum(facets, 0)], -1))
    # vertex pseudonormals (angle-weighted corner normals) and triangle normals; quads'
    # normals vary over the facet and are evaluated where needed
    vnormal = np.zeros((n, 3))
    fnormal = np.empty((F, 3))
    _engine.corner_normals(corner, kind, fnode, vnormal, fnormal)
    # edges: local edge j runs from corner j to corner j + 1; the same pair of nodes is one edge
    tri = (kind == 3)[:, None]
    b = np.where(tri, fnode[:, [1, 2, 0, 0]], fnode[:, [1, 2, 3, 0]])
    real = np.arange(4)[None, :] < kind[:, None]
    key = (np.minimum(fnode, b) * n + np.maximum(fnode, b))[real]
    inc = (4 * np.arange(F)[:, None] + np.arange(4)[None, :])[real]
    by_edge = np.argsort(key, kind="stable")
    new = np.ones(len(key), bool)
    new[1:] = key[by_edge][1:] != key[by_edge][:-1]
    edge = np.empty(len(key), dtype=np.int64)
    edge[by_edge] = np.cumsum(new) - 1
    fedge = np.full((F, 4), -1, dtype=np.int64)
    fedge[real] = edge
    edge_ptr = np.append(np.flatnonzero(new), len(key)).astype(np.int64)
    return {"corner": corner, "kind": kind, "fnormal": fnormal, "fnode": fnode,
            "fedge": fedge, "edge_ptr": edge_ptr,
            "edge_inc": np.ascontiguousarray(inc[by_edge], dtype=np.int64),
            "vnormal": np.ascontiguousarray(_unit(vnormal)), "box": box, "link": link,
            "ctol": np.ascontiguousarray(ctol, dtype=np.float64), "original": order,
            "slot": slot, "centre": np.ascontiguousarray(centre), "radius": max(radius, tol.TINY),
            "sign": float(sign), "quad_iterations": tol.QUAD_ITERATIONS,
            "quad_step": tol.QUAD_STEP, "edge_eps": tol.EDGE_EPS, "far": tol.FAR_RADII,
            "proxy": tol.PROXY_RADII}


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of v scaled to unit length; zero rows (degenerate) stay zero."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, v / norm, 0.0)


def free_parameters(xi, kind, eps=tol.EDGE_EPS) -> str:
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
