"""Diffuse frames R^d [§3]: the axes the local approximation X3 = f(X1, X2) is written in.

A frame is stored as a (3, 3) rotation whose rows are e1, e2, e3; coordinates in it are
X = axes @ (x - origin). 'global' is the paper's least-squares mean plane of all target nodes;
'local' is a weighted PCA of each reference point's neighbourhood (computed per contactor by
the compiled engine, `_engine.pyx`), for targets that one plane
cannot parametrise (closed or strongly curved). Either way +e3 points out of the target, as
given by the orientation of its facets.
"""
from __future__ import annotations

import numpy as np

from .. import tol
from ..nodes import row_norms

FRAMES = ("auto", "global", "local")
# the frame's thresholds live in tol.py (AUTO_MAX_SLOPE_DEG, FOLD_*, COLLINEAR_SPREAD); their
# names stay importable from here
AUTO_MAX_SLOPE_DEG = tol.AUTO_MAX_SLOPE_DEG
FOLD_SLOPE_DEG = tol.FOLD_SLOPE_DEG
FOLD_MIN_RISE = tol.FOLD_MIN_RISE
FOLD_NEIGHBOURS = tol.FOLD_NEIGHBOURS


#: columns of a facet block -> its corners: linear and quadratic triangles (3, 6, 7 nodes) and
#: quads (4, 8, 9 nodes) list their corners first, then mid-side (and centre) nodes.
CORNERS = {3: 3, 6: 3, 7: 3, 4: 4, 8: 4, 9: 4}


def corner_faces(cells) -> list[np.ndarray]:
    """Corner connectivity of surface cells: (f, 3) for triangles, (f, 4) for quads.

    `cells` is a list of ``(cell_type, connectivity)``; higher-order cells (triangle6, quad8,
    quad9, ...) list their corners first, so the first 3 or 4 columns are the facet.
    """
    return [facet_corners(f) for f in cell_faces(cells)]


def cell_faces(cells) -> list[np.ndarray]:
    """Full connectivity of surface cells, mid-side nodes included: (f, 3|6|7) for triangles,
    (f, 4|8|9) for quads. Given as `faces` to DiffuseSurface, mid-side nodes get the normal
    of their cells (with corners only they would have none, and the sheet test drops them)."""
    out = []
    for kind, conn in cells:
        conn = np.asarray(conn, dtype=np.int64)
        if not (kind.startswith("triangle") or kind.startswith("quad")):
            raise ValueError(f"not a surface cell type: {kind!r}")
        if conn.ndim != 2 or conn.shape[1] not in CORNERS or (
                CORNERS[conn.shape[1]] == 3) != kind.startswith("triangle"):
            raise ValueError(f"{kind} cells of {conn.shape[-1]} nodes are not supported")
        out.append(conn)
    return out


def facet_corners(f: np.ndarray) -> np.ndarray:
    """The corner columns of a facet block (3 for triangles, 4 for quads, any order)."""
    f = np.asarray(f, dtype=np.int64)
    if f.ndim != 2 or f.shape[1] not in CORNERS:
        raise ValueError(f"facets of {f.shape[-1]} nodes: expected 3, 6, 7 (triangles) or "
                         f"4, 8, 9 (quads)")
    return f[:, :CORNERS[f.shape[1]]]


#: higher-order facets as linear sub-facets over all their nodes (same orientation): the
#: 4-split of triangle6 and quad9, the fan of triangle7 around its centre, quad8's corner
#: triangles around its inner quad
_SUB_FACETS = {
    6: [[0, 3, 5], [3, 1, 4], [5, 4, 2], [3, 4, 5]],
    7: [[0, 3, 6], [3, 1, 6], [1, 4, 6], [4, 2, 6], [2, 5, 6], [5, 0, 6]],
    8: [[0, 4, 7], [4, 1, 5], [5, 2, 6], [6, 3, 7], [4, 5, 6, 7]],
    9: [[0, 4, 8, 7], [4, 1, 5, 8], [8, 5, 2, 6], [7, 8, 6, 3]],
}


def linear_facets(faces: list[np.ndarray]) -> list[np.ndarray]:
    """Facet blocks with higher-order facets split into linear sub-facets over all their nodes:
    removing a node then removes only the sub-facets around it, and the other nodes of its
    cells keep a normal (leave-one-out in `tune`)."""
    out = []
    for f in faces:
        f = np.asarray(f, dtype=np.int64)
        if f.ndim == 2 and f.shape[1] in _SUB_FACETS:
            for sub in _SUB_FACETS[f.shape[1]]:
                out.append(f[:, sub])
        else:
            out.append(f)
    return out


def facet_area_vectors(points: np.ndarray, faces: list[np.ndarray]) -> np.ndarray:
    """Area-weighted normal of each facet, (f, 3): |v| = area, direction by the right-hand rule.

    A quad's vector is half the cross product of its diagonals (exact for planar quads, the
    mean normal for warped ones). Higher-order facets count by their corners (the flat facet).
    One compiled pass a block (`facet._setup.area_vectors`: numpy's ``0.5 * np.cross(b - a,
    c - a)``, bit for bit), no (f, 3) temporaries per corner and edge.
    """
    from ..facet import _setup

    blocks = [facet_corners(f) for f in faces]
    out = np.empty((sum(len(f) for f in blocks), 3))
    if len(out):
        points = np.ascontiguousarray(points, dtype=np.float64)
        start = 0
        for f in blocks:
            _setup.area_vectors(points, f, out[start:start + len(f)])
            start += len(f)
    return out


def node_normals(points: np.ndarray, faces: list[np.ndarray]) -> np.ndarray:
    """Unit area-weighted normals at the nodes, (n, 3); zero rows for nodes in no facet.

    Every node of a facet block gets the facet's vector, mid-side and centre nodes of
    higher-order facets (6 to 9 columns) as well as corners.

    The areas are computed on the points scaled by a power of two (exact) to unit size: an
    area's squared norm goes as the fourth power of the size and would otherwise under- or
    overflow for meshes in units far from 1 (1e-80, 1e80).

    The sums: one compiled pass a block (`facet._setup.add_facet_rows`), column by column,
    facet by facet from zero: the order `np.add.at` took them in, so the same sums bit for
    bit (tests/reference_frame.py), without add.at's per-element cost.
    """
    from ..facet import _setup

    normals = np.zeros(np.shape(points))  # C order: the compiled sums write into it
    if len(points):
        centre = points.mean(axis=0)
        size = np.abs(points - centre).max()
        points = np.ldexp(points - centre, -int(np.frexp(size)[1])) if size > 0 else points
    areas = facet_area_vectors(points, faces)
    start = 0
    for f in faces:
        _setup.add_facet_rows(normals, np.asarray(f, dtype=np.int64),
                              areas[start:start + len(f)])
        start += len(f)
    norm = row_norms(normals)[:, None]
    return np.divide(normals, norm, out=np.zeros_like(normals), where=norm > 0)


def _right_handed(e1, e3):
    e1 = e1 - np.sum(e1 * e3, axis=-1, keepdims=True) * e3
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(e3, e1)
    return np.stack([e1, e2, e3], axis=-2)


def mean_plane(nodes: np.ndarray, normals: np.ndarray | None = None):
    """The paper's diffuse frame: least-squares mean plane of the target nodes [§3].

    Parameters
    ----------
    nodes : (n, 3) float
    normals : (n, 3) float, optional
        Node normals; +e3 is turned to agree with their sum (out of the target).

    Returns
    -------
    origin : (3,) float
    axes : (3, 3) float
        Rows e1, e2, e3; e3 is the plane's normal.
    """
    origin = nodes.mean(axis=0)
    _, _, vt = np.linalg.svd(nodes - origin, full_matrices=False)
    e1, e3 = vt[0], vt[2]
    if normals is not None and np.dot(normals.sum(axis=0), e3) < 0:
        e3 = -e3
    return origin, _right_handed(e1, e3)


def pca_normals(nodes: np.ndarray, count: int = FOLD_NEIGHBOURS + 1) -> np.ndarray:
    """Unsigned unit normals (n, 3) of the least-squares plane through each node's `count`
    nearest nodes (itself included): normals for nodes no facet orients. NaN rows where the
    nearest nodes lie on a line (spread across it below `tol.COLLINEAR_SPREAD` of the spread
    along it), which fixes no plane."""
    k = min(count, len(nodes))
    from scipy.spatial import cKDTree  # only for faceless targets: keep CLI start-up light

    _, idx = cKDTree(nodes).query(nodes, k=k)
    near = nodes[idx.reshape(len(nodes), k)]
    d = near - near.mean(axis=1, keepdims=True)
    vals, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))  # ascending
    flat = ~(vals[:, 1] > tol.COLLINEAR_SPREAD * vals[:, 2])
    return np.where(flat[:, None], np.nan, vecs[:, :, 0])


def steep_nodes(nodes: np.ndarray, origin: np.ndarray, axes: np.ndarray,
                spacing: np.ndarray) -> np.ndarray:
    """Nodes where the target folds over a fixed frame, seen from chords (`FOLD_SLOPE_DEG`).

    A node is steep when the chord to one of its `FOLD_NEIGHBOURS` nearest nodes in plan rises
    more than `FOLD_MIN_RISE` spacings and more than `FOLD_SLOPE_DEG` from the plane: a wall,
    or the other sheet of a closed target under this one. (Normals are judged per point, in
    `DiffuseSurface._solve`; chords catch folds without normals, or between sheets whose
    normals are parallel.)

    Parameters
    ----------
    nodes : (n, 3) float
    origin : (3,) float
    axes : (3, 3) float
        The frame; rows e1, e2, e3.
    spacing : (n,) float
        Node spacing at each node.

    Returns
    -------
    steep : (n,) bool
    """
    local = (nodes - origin) @ axes.T
    k = min(FOLD_NEIGHBOURS + 1, len(nodes))
    from scipy.spatial import cKDTree  # only over a global frame: keep CLI start-up light

    dist, idx = cKDTree(local[:, :2]).query(local[:, :2], k=k)
    dist, idx = dist.reshape(len(nodes), k), idx.reshape(len(nodes), k)
    rise = np.abs(local[idx, 2] - local[:, 2:3])
    chord = ((rise * np.cos(np.radians(FOLD_SLOPE_DEG)) > dist * np.sin(np.radians(FOLD_SLOPE_DEG)))
             & (rise > FOLD_MIN_RISE * spacing[:, None]))
    return chord.any(axis=1)


def is_height_field(axes: np.ndarray, area_vectors: np.ndarray) -> bool:
    """Whether every facet faces +e3 of `axes` within `AUTO_MAX_SLOPE_DEG`.

    Facets of zero area (degenerate, with no direction) are left out; each vector is scaled by
    its largest component before it is normalised, so that tiny or huge areas do not under-
    or overflow. (Columns at a time: the largest component and the norm are numpy's
    ``abs(v).max(axis=1)`` and ``norm(v, axis=1)``, the same values.)
    """
    least = least_facing(axes, area_vectors)
    return least is not None and bool(least > np.cos(np.radians(AUTO_MAX_SLOPE_DEG)))


def least_facing(axes: np.ndarray, area_vectors: np.ndarray):
    """`is_height_field`'s least cosine between a facet's unit normal and +e3 of `axes`
    (facets of zero area left out; None where none is left)."""
    a = np.asarray(area_vectors, dtype=np.float64)
    if not len(a):
        return None
    top = np.maximum(np.maximum(np.abs(a[:, 0]), np.abs(a[:, 1])), np.abs(a[:, 2]))
    live = top > 0
    v = a / top[:, None] if live.all() else a[live] / top[live, None]
    if len(v) == 0:
        return None
    n = v / row_norms(v)[:, None]
    return np.min(n @ axes[2])
