"""The oracle of the curved-cell tables (issue 36): today's (0f0e242) pure-numpy
`cell_coefficients`, `hermite_midsides` and `_crease_normals` of `diffsurf_cli.patches.surface`,
copied verbatim before they were compiled (`patches._cells`); `tests/test_cells_fast.py`
compares the package's tables with these, bit for bit. Not part of the package."""
from __future__ import annotations

import copy

import numpy as np

from diffsurf_cli.patches import segment as _segment
from diffsurf_cli.patches.surface import (
    CELL_NODES,
    PatchedSurface,
    cell_shape,
    corner_normals,
)


def _next_corner(kind: np.ndarray) -> np.ndarray:
    """(F, 4) the corner at the end of each facet edge: edge j runs from corner j to this."""
    return np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)


def _regions(F: int, joined: np.ndarray) -> np.ndarray:
    """(F,) the connected groups of F facets joined across the edges `joined` (e, 2): the
    two facets of each."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a, b = joined.T
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(F, F))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def cell_coefficients(surf: PatchedSurface):
    """The curved cells of a target, for the pass's `cells_answer`: x(a, b) = sum_k a^i b^j
    coef[f, k] over `CELL_MONOMIALS`, a cell's own shape functions in the parameters of its
    corner facet (`cell_shape` times its nodes).

    A second-order cell (triangle6, triangle7, quad8, quad9) is its own nodes'. A first-order
    facet is curved through its corners' normals (`corner_normal`, its smooth region's): each edge
    x0 -> x1 gets the mid-side node of the cubic Hermite curve whose end tangents are the
    edge's projection on each end's tangent plane, (x0 + x1) / 2 + (T0 - T1) / 8 with
    |T| = the edge's length (a circular arc of chord L and turn φ: L φ / 8 off the chord,
    its sag, to O(φ³)); one edge's mid-side node is the same from both of its facets within
    a smooth region (conforming there). A facet whose edges are all straight so (a flat
    face) has no cell: its facets answer, as exactly.

    Returns
    -------
    has_cell : (F,) int8       1 where facet f has a curved cell
    coef : (F, 9, 3) float     zero past a cell's monomials; (1, 9, 3) zeros where the
                               target has no curved cell
    """
    F = len(surf.corners)
    has = np.zeros(F, np.int8)
    coef = np.zeros((F, 9, 3))
    first_order = any(f.shape[1] in (3, 4) for f in surf.faces)
    mid = hermite_midsides(surf) if first_order else None                   # (F, 4, 3)
    start = 0
    for f in surf.faces:
        rows = slice(start, start + len(f))
        k = f.shape[1]
        if k in CELL_NODES:                     # a second-order cell: its own nodes
            pts = surf.nodes[f]
        else:                                   # a first-order facet, curved by its normals
            corner = surf.nodes[f]
            off = mid[rows, :k] - 0.5 * (corner + np.roll(corner, -1, axis=1))
            curved = (np.linalg.norm(off, axis=2)
                      > 1e-9 * surf.edge_length[rows, :k]).any(axis=1)
            pts = np.concatenate([corner, mid[rows, :k]], axis=1)
            k = 2 * k
            sel = np.flatnonzero(curved)
            pts, rows = pts[sel], np.arange(start, start + len(f))[sel]
        coef[rows] = np.einsum("mk,fkj->fmj", cell_shape(k), pts)
        has[rows] = 1
        start += len(f)
    if not has.any():
        return has, np.zeros((1, 9, 3))
    return has, coef


def hermite_midsides(surf: PatchedSurface) -> np.ndarray:
    """(F, 4, 3) the mid-side node of each facet edge's cubic Hermite curve through its ends
    with the ends' corner normals (`cell_coefficients`); an edge whose end normal lies along
    it (a degenerate normal) keeps its straight tangent there."""
    F = len(surf.corners)
    nxt = _next_corner(surf.kind)
    x0 = surf.nodes[np.maximum(surf.corners, 0)]
    x1 = x0[np.arange(F)[:, None], nxt]
    n0 = _crease_normals(surf)
    n1 = n0[np.arange(F)[:, None], nxt]
    edge = x1 - x0
    length = np.linalg.norm(edge, axis=2, keepdims=True)

    def tangent(n):  # the edge on the plane normal to n, as long as the edge
        t = edge - np.einsum("fkj,fkj->fk", edge, n)[..., None] * n
        norm = np.linalg.norm(t, axis=2, keepdims=True)
        keep = norm > 1e-12 * length
        return np.where(keep, t * np.divide(length, norm, out=np.ones_like(norm), where=keep),
                        edge)

    return 0.5 * (x0 + x1) + (tangent(n0) - tangent(n1)) / 8


def _crease_normals(surf: PatchedSurface) -> np.ndarray:
    """(F, 4, 3) the corner normals the curved facets follow: the smooth regions' own
    (`corner_normal`), split also at every edge sharper than the default feature angle
    (`segment.FEATURE_ANGLE_DEG`; inside one CAD face, none) when the surface was built with
    a wider one (180, None: one patch over a box). A box's edge is a crease of its mesh
    whatever its patches: its faces stay flat."""
    limit = _segment.FEATURE_ANGLE_DEG
    if surf.feature_angle is not None and surf.feature_angle <= limit:
        return surf.corner_normal
    a, b = surf.edge_facets.T
    cos = np.einsum("ij,ij->i", surf.facet_normal[a], surf.facet_normal[b])
    crease = cos < np.cos(np.radians(limit))
    if surf.smooth_tags:
        crease &= surf.tags[a] != surf.tags[b]
    split = copy.copy(surf)
    split.smooth_region = _regions(len(surf.corners), surf.edge_facets[~crease])
    return corner_normals(split)[0]
