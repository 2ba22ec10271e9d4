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
from ..nodes import SharedNodes, row_norms
from ..projection import (
    FAILED,
    Projection,
    as_faces,
    as_moved_nodes,
    as_points,
    as_target_nodes,
    bounds,
    warn_inside_out,
)
from . import _engine, _setup

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
    shared : SharedNodes, optional
        The node identity and spacing of these nodes, measured by the caller (a
        `PatchedSurface`, for its facets and its surfaces alike); ignored for other nodes.
    """

    def __init__(self, nodes, faces, *, flip=False, check_winding=True, shared=None):
        self.nodes = as_target_nodes(nodes)
        faces = [f for f in as_faces(faces, len(self.nodes), (3, 4)) if f.size]
        if not faces:
            raise ValueError("the facet method needs surface cells (triangles or quads)")
        # coincident nodes (a zone boundary) are one node for the edges and vertices; a
        # caller's own `SharedNodes` of these nodes (PatchedSurface's) is not measured again
        shared = SharedNodes.of(self.nodes, shared)
        if check_winding and not flip:  # a closed target wound inside out: say so
            warn_inside_out(self.nodes, faces, shared.first)
        # one table of facets, triangles padded with -1 in the 4th corner
        self.facets = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in faces])
        self.flip = bool(flip)
        self.sign = -1.0 if flip else 1.0
        #: made by `moved`: a deformable target's positions (not a fixed, rigid one)
        self.deformed = False
        self._geometry(shared)

    def _geometry(self, shared=None) -> None:
        """Node spacing and the search's tables, from the nodes' positions."""
        shared = SharedNodes.of(self.nodes, shared)
        if len(shared.distinct) < 3:
            raise ValueError("the target has fewer than 3 distinct nodes")
        first = shared.first
        self.node_spacing = shared.spacing
        if not self.node_spacing.min() > tol.SPACING_MIN:
            raise ValueError(f"the target's node spacing is down to {self.node_spacing.min():.3g}, "
                             f"below the supported {tol.SPACING_MIN:.0e}: rescale the mesh")
        # the index tables int32 as the search reads them (`_engine.index_tables`)
        self._tables = _engine.index_tables(_tables(self.nodes, first, self.facets, self.sign,
                                                    tol.CONTACT * self.node_spacing))
        self._engine = None

    def moved(self, nodes) -> FacetSurface:
        """The same facets with their nodes at new positions (a deformable target): facet
        numbers, hence a pairing (`projection.facet`), stay valid."""
        nodes = as_moved_nodes(nodes, self.nodes)
        new = copy.copy(self)
        new.nodes = nodes
        new.deformed = True
        new._geometry()
        return new

    def __getstate__(self):
        # the compiled engine's view does not pickle; it is rebuilt on first use
        state = self.__dict__.copy()
        state["_engine"] = None
        return state

    def facet_surface(self) -> FacetSurface:
        """The target's facets: this surface itself (every surface's `facet_surface`)."""
        return self

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
        the facet and its parameters ξ at the proximal point; ``facet_gap`` is the gap (the
        facets' own answer, as a PatchedSurface's).
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
        return Projection(points, gap, normal, prox, status, support, iterations,
                          np.where(failed, np.nan, 1.0), curvature, reason, facet=facet,
                          param=param, facet_gap=gap)


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
    lo, hi = bounds(nodes[used])  # x.min(axis=0), x.max(axis=0), column by column
    centre = 0.5 * (lo + hi)
    X = nodes - centre
    # the farthest used node: its squared distance (x² + y²) + z², numpy's row sum
    Xu = X[used]
    radius = float(np.sqrt(((Xu[:, 0] ** 2 + Xu[:, 1] ** 2) + Xu[:, 2] ** 2).max()))
    del Xu
    # each facet's box and centroid (a triangle's 4th corner repeats its first), then its
    # (F, 4, 3) corners in hierarchy order: compiled passes over the facets, no table of
    # corners in their own order
    X = np.ascontiguousarray(X)
    facets = np.ascontiguousarray(facets, dtype=np.int64)
    order, box, link = _engine.build_hierarchy(*_setup.facet_boxes(X, facets))
    slot = np.empty(F, dtype=np.int64)
    slot[order] = np.arange(F)
    corner = _setup.facet_corners(X, facets, order)
    # each slot's corner count and its corners' node identity (-1 past a triangle's third)
    kind, fnode = _setup.ordered_nodes(facets, np.ascontiguousarray(canon, dtype=np.int64),
                                       order)
    # vertex pseudonormals (angle-weighted corner normals) and triangle normals; quads'
    # normals vary over the facet and are evaluated where needed
    vnormal = np.zeros((n, 3))
    fnormal = np.empty((F, 3))
    _engine.corner_normals(corner, kind, fnode, vnormal, fnormal)
    # edges: local edge j runs from corner j to corner j + 1; the same pair of nodes is one
    # edge, edges numbered by their (smaller, larger) node (a counting sort, linear)
    fedge, edge_ptr, edge_inc = _setup.facet_edges(fnode, np.ascontiguousarray(kind), n)
    # each hierarchy node's oriented bound: the search prunes by it as well as by its box
    cyl = _engine.oriented_bounds(corner, np.ascontiguousarray(kind, dtype=np.int8), link)
    return {"corner": corner, "kind": kind, "fnormal": fnormal, "fnode": fnode,
            "fedge": fedge, "edge_ptr": edge_ptr, "edge_inc": edge_inc,
            "vnormal": np.ascontiguousarray(_unit(vnormal)), "box": box, "link": link, "cyl": cyl,
            "ctol": np.ascontiguousarray(ctol, dtype=np.float64), "original": order,
            "slot": slot, "centre": np.ascontiguousarray(centre), "radius": max(radius, tol.TINY),
            "sign": float(sign), "quad_iterations": tol.QUAD_ITERATIONS,
            "quad_step": tol.QUAD_STEP, "edge_eps": tol.EDGE_EPS, "far": tol.FAR_RADII,
            "proxy": tol.PROXY_RADII}


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of v (n, 3) scaled to unit length; zero rows (degenerate) stay zero. (The norms
    column by column: `nodes.row_norms`, np.linalg.norm's values.)"""
    norm = row_norms(v)[:, None]
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
