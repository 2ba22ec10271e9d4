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

from ..mls import basis as _basis
from . import _element


def _inputs(surface, points, patch, proximal_point, rows):
    """The kernel's per-row inputs of the contactors `rows` (`diffuse_elements`): rows,
    x^c, x^d, frame origin and axes (turned where a strip's reduced basis is fitted),
    radius, support index, and the rows' groups by basis [(reduced index, positions)]."""
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
    # a strip's reduced basis [basis.REDUCED]: its monomials in (a, b), the frame's (s, t)
    # turned by the pairing's direction, i.e. the basis in the frame turned about e3
    reduced = np.full(e, -1, dtype=np.int64)
    if getattr(patch, "reduced", None) is not None:
        reduced = np.asarray(patch.reduced, dtype=np.int64).reshape(-1)[rows]
        theta = np.asarray(patch.direction, dtype=np.float64).reshape(-1)[rows]
        theta = np.where(np.isfinite(theta) & (reduced >= 0), theta, 0.0)
        c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
        axes = axes.copy()
        axes[:, 0], axes[:, 1] = c * axes[:, 0] + s * axes[:, 1], c * axes[:, 1] - s * axes[:, 0]
    groups = [(r, np.flatnonzero(reduced == r)) for r in np.unique(reduced)]
    return rows, xc, xd, origin, axes, radius, index, groups


def _basis_of(surface, r):
    """The basis of group r (-1: the surface's own; else its reduced basis r)."""
    return surface.basis if r < 0 else _basis.REDUCED[surface.basis][r]


def diffuse_elements(surface, points, patch, proximal_point, rows, second: bool = True, *,
                     width: int | None = None, out: np.ndarray | None = None):
    """Gap, 𝒩 and ℳ of the diffuse element of the contactors `rows`.

    Parameters
    ----------
    surface : DiffuseSurface
        The target (nodes, basis, weight).
    points : (m, 3) float
        Contactors x^c.
    patch : Patch
        The frozen pairing of the m contactors (``Projection.patch``: frame origin and axes,
        radius R, support index; where the projection fitted a reduced basis, a strip's,
        ``patch.reduced`` and ``patch.direction``: that basis is fitted in the frame turned by
        that angle about e3, held fixed as the frame is).
    proximal_point : (m, 3) float
        x^d of each contactor from the projection with that pairing (it fixes X̄ [30]).
    rows : (e,) int
        The contactors to build elements for (indices into points and the patch's rows).
    second : bool
        Compute ℳ too (the tangent needs it; the residual does not).
    width : int, optional
        K, the support nodes to pad to (at least the widest of these rows'; by default, that
        widest).
    out : (e, 3(K+1), 3(K+1)) float, optional
        C-contiguous; ℳ is written there (and returned) instead of into a new array, when
        these rows need one basis only (the usual case; else ℳ is copied into it).

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
    rows, xc, xd, origin, axes, radius, index, groups = _inputs(surface, points, patch,
                                                                 proximal_point, rows)
    e = len(rows)
    kept = np.empty_like(index)
    count = np.empty(e, dtype=np.int64)
    if len(groups) == 1:  # one basis (the usual case): no copies of the rows
        _element.supports(surface.nodes, xc, origin, axes, radius, index,
                          _basis_of(surface, groups[0][0]), surface.weight, kept, count)
    for r, g in (groups if len(groups) > 1 else ()):
        sub_kept, sub_count = np.empty_like(index[g]), np.empty(len(g), dtype=np.int64)
        _element.supports(surface.nodes, xc[g], origin[g], axes[g], radius[g], index[g],
                          _basis_of(surface, r), surface.weight, sub_kept, sub_count)
        kept[g], count[g] = sub_kept, sub_count
    K = int(count.max(initial=0))
    if width is not None:
        if width < K:
            raise ValueError(f"width {width} is narrower than these rows' widest support {K}")
        kept = np.pad(kept[:, :K], ((0, 0), (0, width - K)), constant_values=-1)
        K = width
    nodes = np.ascontiguousarray(kept[:, :K])
    size = 3 * (K + 1)
    gap = np.empty(e)
    N = np.empty((e, size))
    M = np.empty((e, size, size) if second else (0, size, size))
    if out is not None and second:
        if out.shape != M.shape or out.dtype != np.float64 or not out.flags.c_contiguous:
            raise ValueError(f"out must be a C-contiguous float64 array of shape {M.shape}")
        M = out
    if len(groups) == 1:  # one basis (the usual case): the kernel writes the answer itself
        _element.elements(surface.nodes, xc, origin, axes, radius, xd, nodes, count,
                          _basis_of(surface, groups[0][0]), surface.weight, gap, N, M)
        return gap, nodes, N, (M if second else None)
    for r, g in groups:
        sub = (np.empty(len(g)), np.empty((len(g), size)),
               np.empty((len(g), size, size) if second else (0, size, size)))
        _element.elements(surface.nodes, xc[g], origin[g], axes[g], radius[g], xd[g],
                          np.ascontiguousarray(nodes[g]), count[g], _basis_of(surface, r),
                          surface.weight, *sub)
        gap[g], N[g] = sub[0], sub[1]
        if second:
            M[g] = sub[2]
    return gap, nodes, N, (M if second else None)


def diffuse_tangent(surface, points, patch, proximal_point, rows, nodes, ids, N, eps, p,
                    lam, dT, places) -> None:
    """Adds the tangent blocks eps 𝒩𝒩ᵀ + p ℳ (+ the multipliers' λ (e, 3) and friction's
    ∂T/∂x (e, 3, 3) terms, or None) of the diffuse elements of contactors `rows` into a CSR
    pattern's values (`places`: `_assembly.pattern`'s base, pat_ptr, pat_col, pat_off, the
    DOFs of its node ids, and the values), each ℳ built and added at once in compiled code
    (`_element.tangent_elements`): the numbers `diffuse_elements` gives ℳ, never a batch of
    them in memory. nodes (e, K) are the elements' support nodes (`diffuse_elements`'
    answer for these rows, the Contact's), ids (e, K+1) their node ids in the pattern, N
    (e, 3(K+1)) their 𝒩; arguments otherwise as `diffuse_elements`."""
    rows, xc, xd, origin, axes, radius, _, groups = _inputs(surface, points, patch,
                                                             proximal_point, rows)
    nodes = np.ascontiguousarray(nodes, dtype=np.int64)
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    N = np.ascontiguousarray(N, dtype=np.float64)
    eps = np.ascontiguousarray(eps, dtype=np.float64)
    p = np.ascontiguousarray(p, dtype=np.float64)
    lam = np.zeros((0, 3)) if lam is None else np.ascontiguousarray(lam, dtype=np.float64)
    dT = np.zeros((0, 3, 3)) if dT is None else np.ascontiguousarray(dT, dtype=np.float64)
    for r, g in groups:
        whole = len(groups) == 1

        def part(a, g=g, whole=whole):
            return a if whole or not len(a) else np.ascontiguousarray(a[g])

        _element.tangent_elements(surface.nodes, part(xc), part(origin), part(axes),
                                  part(radius), part(xd), part(nodes), _basis_of(surface, r),
                                  surface.weight, part(ids), part(N), part(eps), part(p),
                                  part(lam), part(dT), *places)
