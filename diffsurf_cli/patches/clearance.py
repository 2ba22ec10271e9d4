"""How far each facet is from the features of a patched target: a lower bound of the distance
from any point of facet f to any point of a sharp edge or of an edge between two patches
(`_pass.pyx` classes SHARP and SMOOTH, their vertices included).

The compiled pass (`_pass.pyx`, `on_patch`) uses it to skip the search of a proximal point's
closest point on its own patch's facets where that point cannot be on a feature: if x^d is
closer to a point y of facet f than half of f's clearance, the closest point of x^d on the
patch (no farther than y) is farther from every feature than from x^d, so it lies on none
(the search would find what the test needs: not on a feature edge, 'on the patch').
"""
from __future__ import annotations

import numpy as np

from . import _clearance

#: Features are sampled along their edges at this fraction of the median facet edge: each
#: sample stands for the piece of edge within half a step of it.
SAMPLE_EDGES = 0.25

#: Facets in one block of the numpy passes over the corners (bounds their temporaries).
BLOCK = 1 << 16


def feature_clearance(corner: np.ndarray, kind: np.ndarray, edge_class: np.ndarray,
                      features: tuple, edge_eps: float) -> np.ndarray:
    """(F,) lower bound of the distance from each facet to the features (inf: no feature,
    and no geometry computed). Each centroid's nearest sample of the features: a compiled k-d
    tree query (`_clearance.nearest_distance`, cKDTree's distances bit for bit).

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
    F = len(kind)
    real = np.arange(4)[None] < kind[:, None]
    feature = real & np.isin(edge_class, features)
    if not feature.any():  # a smooth closed target, say: no geometry at all
        return np.full(F, np.inf)
    nxt = np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)
    start, end = corner, corner[np.arange(F)[:, None], nxt]
    length = np.where(real, np.linalg.norm(end - start, axis=2), 0.0)
    longest = float(length.max()) if F else 0.0
    step = SAMPLE_EDGES * float(np.median(length[real]))
    a, b = start[feature], end[feature]
    pieces = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / step), 1).astype(np.int64)
    piece = np.repeat(np.arange(len(a)), pieces)
    frac = (np.arange(len(piece)) - np.repeat(np.cumsum(pieces) - pieces, pieces) + 0.5) \
        / pieces[piece]
    samples = a[piece] + frac[:, None] * (b[piece] - a[piece])
    half = 0.5 * float((np.linalg.norm(b - a, axis=1) / pieces).max())  # a piece's half
    centroid, reach, size = _centroids(corner, kind)
    nearest = _clearance.nearest_distance(np.ascontiguousarray(samples, dtype=np.float64),
                                          centroid, np.empty(F))
    margin = 1e-9 * size + 8.0 * edge_eps * longest  # round-off, the edges' parametric band
    return np.maximum(nearest - half - reach - margin, 0.0)


def _centroids(corner: np.ndarray, kind: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(F, 3) centroids of the facets' corners, (F,) their reach (the farthest corner from the
    centroid), and the size of the target (its corners' box's longest side); in blocks of
    facets (each facet's figures are its own: the same bits as in one pass)."""
    F = len(kind)
    centroid = np.empty((F, 3))
    reach = np.empty(F)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for a in range(0, F, BLOCK):
        b = min(a + BLOCK, F)
        c, n = corner[a:b], kind[a:b]
        real = np.arange(4)[None] < n[:, None]
        centroid[a:b] = np.where(real[..., None], c, 0.0).sum(axis=1) / n[:, None]
        reach[a:b] = np.where(real, np.linalg.norm(c - centroid[a:b, None], axis=2),
                              0.0).max(axis=1)
        pts = c[real]
        lo, hi = np.minimum(lo, pts.min(axis=0)), np.maximum(hi, pts.max(axis=0))
    return centroid, reach, float((hi - lo).max()) if F else 0.0


#: Nearest facets (by centroid) examined for each facet's foreign clearance; those beyond are
#: bounded together by the K-th's distance.
FOREIGN_NEIGHBOURS = 32


def foreign_clearance(corner: np.ndarray, kind: np.ndarray, label: np.ndarray,
                      ring_ptr: np.ndarray, ring: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """(F,) lower bound, for each facet f, of dist(y, g) - bound[g] over the points y of f and
    the facets g of a patch that is not one of f's candidates (ring_ptr, ring: the patches
    of f's vertex ring): how near another patch's smooth surface (within bound[g] of its
    facets, the guard's bound) can come to f.

    The compiled pass (`_pass.pyx`, `foreign_patches`) searches the facets near a contactor x
    for such patches only where this bound is within reach: with x at d0 from its faceted foot
    on f and a diffuse answer at D, another patch's surface can be nearer than D only if some
    g has dist(x, g) - bound[g] < D, hence this clearance < D + d0. Centroid distances less
    both facets' reach about their centroids; beyond the K-th nearest centroid, every facet
    is bounded by the K-th's distance with the largest reach and bound (`_clearance.pyx`:
    one k-d tree query a facet, compiled, no (F, K) table).

    A target of one patch has no foreign patch: +inf everywhere, no tree. The pass never
    searches then (its test `foreign < D + d0` fails), and that search would have found
    nothing (it skips every patch of f's ring, here the only one), so its answers are those
    of the finite bound the K-th centroid would give.
    """
    F = len(kind)
    if F == 0 or int(label.max()) == 0:
        return np.full(F, np.inf)
    centroid, reach, size = _centroids(corner, kind)
    out = np.empty(F)
    _clearance.foreign_bound(
        centroid, reach, np.ascontiguousarray(label, dtype=np.int64),
        np.ascontiguousarray(ring_ptr, dtype=np.int64),
        np.ascontiguousarray(ring, dtype=np.int64),
        np.ascontiguousarray(bound, dtype=np.float64), min(FOREIGN_NEIGHBOURS, F), out)
    out -= 1e-9 * size
    return out
