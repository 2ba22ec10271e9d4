"""The full diffuse element of many contactors as padded arrays [§4.2-4.3].

This version loops over the jet-based `element.diffuse_element` (exact, slow: the oracle); the
compiled element has the same signature and replaces it.
"""
from __future__ import annotations

import numpy as np


def diffuse_elements(surface, points, patch, proximal_point, rows, second=True):
    """Gap, 𝒩 [42]-[44] and ℳ [53] of the diffuse element of the contactors `rows`.

    Parameters
    ----------
    surface : DiffuseSurface
    points : (m, 3) float             the contactors x^c
    patch : Patch                     their frozen pairing (m rows: frame, support, radius)
    proximal_point : (m, 3) float     x^d of each contactor (from the projection)
    rows : (e,) int                   the contactors that get an element
    second : bool                     compute ℳ too

    Returns
    -------
    gap : (e,) float
    nodes : (e, K) int                support nodes in u = [x^c, x^nodes...] order, -1 padded
    N : (e, 3(K+1)) float             ∂g/∂u, exactly zero on the padding
    M : (e, 3(K+1), 3(K+1)) float or None
    """
    from .element import diffuse_element

    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    parts = [diffuse_element(surface, points[i], patch.index[i], patch.origin[i],
                             patch.axes[i], patch.radius[i], proximal_point[i], second)
             for i in rows]
    e = len(rows)
    K = max((len(p[1]) for p in parts), default=0)
    gap = np.empty(e)
    nodes = np.full((e, K), -1, dtype=np.int64)
    N = np.zeros((e, 3 * (K + 1)))
    M = np.zeros((e, 3 * (K + 1), 3 * (K + 1))) if second else None
    for k, (g, idx, n, mm) in enumerate(parts):
        size = 3 * (len(idx) + 1)
        gap[k] = g
        nodes[k, :len(idx)] = idx
        N[k, :size] = n
        if second:
            M[k, :size, :size] = mm
    return gap, nodes, N, M
