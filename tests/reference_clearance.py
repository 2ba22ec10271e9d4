"""The oracles of `patches.clearance`: its two bounds as they were before issue 36 (numpy; the
foreign clearance a cKDTree query of the 32 nearest centroids of every facet, with (F, 32)
tables), kept verbatim to check the package's against (tests/test_clearance_fast.py). Not part
of the package."""
from __future__ import annotations

import numpy as np

#: Features are sampled along their edges at this fraction of the median facet edge: each
#: sample stands for the piece of edge within half a step of it.
SAMPLE_EDGES = 0.25


def feature_clearance(corner: np.ndarray, kind: np.ndarray, edge_class: np.ndarray,
                      features: tuple, edge_eps: float) -> np.ndarray:
    """(F,) lower bound of the distance from each facet to the features (inf: no feature).

    Parameters
    ----------
    corner : (F, 4, 3) float
        Corner coordinates of each facet (a triangle's 4th unused).
    kind : (F,) int
        3 or 4 corners.
    edge_class : (F, 4) int
        Class of each local edge (edge j from corner j to corner j + 1).
    features : tuple of int
        The classes that are features.
    edge_eps : float
        The facets' parametric tolerance (`tol.EDGE_EPS`): a point that close to an edge, in
        the facet's parameters, is on it; the bound is lowered by that band.
    """
    from scipy.spatial import cKDTree

    F = len(kind)
    nxt = np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)
    start, end = corner, corner[np.arange(F)[:, None], nxt]
    real = np.arange(4)[None] < kind[:, None]
    length = np.where(real, np.linalg.norm(end - start, axis=2), 0.0)
    longest = float(length.max()) if F else 0.0
    feature = real & np.isin(edge_class, features)
    if not feature.any():
        return np.full(F, np.inf)
    step = SAMPLE_EDGES * float(np.median(length[real]))
    a, b = start[feature], end[feature]
    pieces = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / step), 1).astype(np.int64)
    piece = np.repeat(np.arange(len(a)), pieces)
    frac = (np.arange(len(piece)) - np.repeat(np.cumsum(pieces) - pieces, pieces) + 0.5) \
        / pieces[piece]
    samples = a[piece] + frac[:, None] * (b[piece] - a[piece])
    half = 0.5 * float((np.linalg.norm(b - a, axis=1) / pieces).max())  # a piece's half
    centroid = np.where(real[..., None], corner, 0.0).sum(axis=1) / kind[:, None]
    reach = np.where(real, np.linalg.norm(corner - centroid[:, None], axis=2), 0.0).max(axis=1)
    nearest = cKDTree(samples).query(centroid)[0]
    size = float(np.ptp(corner[real], axis=0).max())
    margin = 1e-9 * size + 8.0 * edge_eps * longest  # round-off, the edges' parametric band
    return np.maximum(nearest - half - reach - margin, 0.0)


#: Nearest facets (by centroid) examined for each facet's foreign clearance; those beyond are
#: bounded together by the K-th's distance.
FOREIGN_NEIGHBOURS = 32


def foreign_clearance(corner: np.ndarray, kind: np.ndarray, label: np.ndarray,
                      ring_ptr: np.ndarray, ring: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """(F,) lower bound, for each facet f, of dist(y, g) - bound[g] over the points y of f and
    the facets g of a patch that is not one of f's candidates (ring_ptr, ring: the patches
    of f's vertex ring): how near another patch's smooth surface (within bound[g] of its
    facets, the guard's bound) can come to f (see the package's version)."""
    from scipy.spatial import cKDTree

    F = len(kind)
    real = np.arange(4)[None] < kind[:, None]
    centroid = np.where(real[..., None], corner, 0.0).sum(axis=1) / kind[:, None]
    reach = np.where(real, np.linalg.norm(corner - centroid[:, None], axis=2), 0.0).max(axis=1)
    npatches = int(label.max()) + 1
    owner = np.repeat(np.arange(F), np.diff(ring_ptr))
    own = np.sort(owner * np.int64(npatches) + ring)
    k = min(FOREIGN_NEIGHBOURS, F)
    dist, near = cKDTree(centroid).query(centroid, k=k)
    dist, near = dist.reshape(F, k), near.reshape(F, k)
    key = np.arange(F)[:, None] * np.int64(npatches) + label[near]
    at = np.minimum(np.searchsorted(own, key), len(own) - 1)
    foreign = own[at] != key
    lower = dist - reach[:, None] - reach[near] - bound[near]
    out = np.where(foreign, lower, np.inf).min(axis=1)
    if k < F:  # every facet past the K-th nearest centroid
        out = np.minimum(out, dist[:, -1] - reach - reach.max() - bound.max())
    size = float(np.ptp(corner[real], axis=0).max()) if F else 0.0
    return out - 1e-9 * size
