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
