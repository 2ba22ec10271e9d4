"""The diffuse contact element of many contactors at once [§4.2-4.3], in the compiled engine.

`diffuse_elements` hands one batch of contactors and their frozen pairing (frame, support,
radius: `Patch`) to `_element.pyx`, which computes the gap g [32], 𝒩 = ∂g/∂u [42]-[44] and
ℳ = ∂²g/∂u² [53] of each, in parallel, with structured analytic derivatives (see its
docstring). The unknowns of element e are u = [x^c, x^nodes[e, 0], x^nodes[e, 1], ...]: the
contactor, then its support nodes of positive weight (nodes of zero weight do not move the
fit and are left out), padded with -1 to the widest support of the batch.
"""
from __future__ import annotations

import numpy as np

from . import _element


def diffuse_elements(surface, points, patch, proximal_point, rows, second: bool = True):
    """Gap, 𝒩 and ℳ of the diffuse element of the contactors `rows`.

    Parameters
    ----------
    surface : DiffuseSurface
        The target (nodes, basis, weight).
    points : (m, 3) float
        Contactors x^c.
    patch : Patch
        The frozen pairing of the m contactors (``Projection.patch``: frame origin and axes,
        radius R, support index).
    proximal_point : (m, 3) float
        x^d of each contactor from the projection with that pairing (it fixes X̄ [30]).
    rows : (e,) int
        The contactors to build elements for (indices into points and the patch's rows).
    second : bool
        Compute ℳ too (the tangent needs it; the residual does not).

    Returns
    -------
    gap : (e,) float
        g [32]; NaN where the fit or the proximal point's system is singular (then N and M
        are NaN on that element's block).
    nodes : (e, K) int64
        Support nodes in u's order, -1 padded; K the largest support among these rows.
    N : (e, 3(K+1)) float
        𝒩 = ∂g/∂u; entries of padding nodes are exactly 0.
    M : (e, 3(K+1), 3(K+1)) float or None
        ℳ = ∂²g/∂u², symmetric; rows and columns of padding nodes exactly 0.
    """
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    points = np.asarray(points, dtype=np.float64)
    proximal_point = np.asarray(proximal_point, dtype=np.float64)
    m = len(points)
    index = np.asarray(patch.index).reshape(len(patch.radius), -1)
    if points.shape != (m, 3) or proximal_point.shape != (m, 3) or len(index) != m:
        raise ValueError(f"points {points.shape}, proximal_point {proximal_point.shape} and "
                         f"the patch ({len(index)} rows) must have m rows of 3")
    if len(rows) and (rows.min() < -m or rows.max() >= m):
        raise IndexError(f"rows must index the {m} contactors")
    if getattr(surface, "recentre", False):
        raise ValueError("the contact element is defined on the contactor's own local "
                         "approximation: use it without re-centring")

    def take(a, shape):
        return np.ascontiguousarray(np.asarray(a, dtype=np.float64)[rows].reshape(shape))

    e = len(rows)
    xc = take(points, (e, 3))
    xd = take(proximal_point, (e, 3))
    origin = take(patch.origin, (e, 3))
    axes = take(patch.axes, (e, 3, 3))
    radius = take(patch.radius, (e,))
    index = np.ascontiguousarray(index[rows], dtype=np.int64)
    kept = np.empty_like(index)
    count = np.empty(e, dtype=np.int64)
    _element.supports(surface.nodes, xc, origin, axes, radius, index, surface.basis,
                      surface.weight, kept, count)
    K = int(count.max(initial=0))
    nodes = np.ascontiguousarray(kept[:, :K])
    size = 3 * (K + 1)
    gap = np.empty(e)
    N = np.empty((e, size))
    M = np.empty((e, size, size) if second else (0, size, size))
    _element.elements(surface.nodes, xc, origin, axes, radius, xd, nodes, count,
                      surface.basis, surface.weight, gap, N, M)
    return gap, nodes, N, (M if second else None)
