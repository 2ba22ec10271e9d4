"""A study of the patch test (issue 37; docs/patch_test.md), not the library's element: a
diffuse element whose force reaches the target through its facets. The gap and normal are
the diffuse surface's, the target's nodal forces go through the shape functions of the facet
the contactor faces, as node-to-facet's and a mortar method's do.

The diffuse element's own transfer is the gradient of its gap, R = p 𝒩 [45]: on the target
its nodes' forces are p ∂g/∂X_j, through the diffuse shape functions, which neither
interpolate the nodes nor integrate to their tributary areas. Here

    R = p 𝒲,   𝒲 = [ν ; -N_b(ξ) ν ...],   p = min(0, λ + ε g)

with g and ν the diffuse gap [32] and normal [29] at the contactor, and N_b(ξ) the shape
functions (linear triangle, bilinear quadrilateral) of facet f's corners b at the point
x_f = x^c - t ν where the line from the contactor along the normal meets the facet:
Σ_b N_b(ξ) X_b + t ν = x^c. The forces balance exactly (Σ_b N_b = 1, and the contactor's
force and the facet's act along one line, x^c - x_f ∥ ν: no moment). What it measured
(`patch_test.solve(..., transfer=True)`, benchmarks/patch_test.py): exact on matching meshes,
near node-to-facet one pass, but two-pass stalls at 1-5% (the constraints are still the
diffuse gaps, which non-uniform states of both faces satisfy), so it is not the answer.

R is not the gradient of an energy: its tangent K = ∂R/∂u = ε 𝒲 𝒩ᵀ + p ∂𝒲/∂u is exact but
not symmetric (tests/test_patch_test.py: Taylor), where
    ∂ν/∂u = ℳ[:3, :] (the contactor's rows of the diffuse ℳ [53]),
    ∂(ξ, t)/∂u = -J⁻¹ ∂G/∂u,  G = Σ_b N_b(ξ) X_b + t ν - x^c,  J = [X_,ξ1  X_,ξ2  ν],
    ∂G/∂u = -I on x^c, N_b I on corner b, t ∂ν/∂u,
    ∂𝒲_b/∂u = -ν ⊗ Σ_β N_b,β ∂ξ_β/∂u - N_b ∂ν/∂u.
The unknowns of an element are its diffuse element's (x^c, then its support nodes) followed
by the facet's corners that are not support nodes.
"""
from __future__ import annotations

import numpy as np

#: Newton iterations for the line's point on a bilinear facet (quadratic from its centre).
QUAD_ITERATIONS = 30


def _shape(kind: np.ndarray, xi: np.ndarray):
    """(e, 4) shape functions and (e, 4, 2) their ξ-derivatives of each facet at ξ (e, 2):
    linear triangles (corners 0, 1, 2; N_3 = 0), bilinear quadrilaterals."""
    a, b = xi[:, 0], xi[:, 1]
    tri = kind == 3
    N = np.stack([np.where(tri, 1 - a - b, (1 - a) * (1 - b)), np.where(tri, a, a * (1 - b)),
                  np.where(tri, b, a * b), np.where(tri, 0.0, (1 - a) * b)], axis=1)
    one, zero = np.ones_like(a), np.zeros_like(a)
    dN = np.stack([np.stack([np.where(tri, -one, -(1 - b)), np.where(tri, -one, -(1 - a))], 1),
                   np.stack([np.where(tri, one, 1 - b), np.where(tri, zero, -a)], 1),
                   np.stack([np.where(tri, zero, b), np.where(tri, one, a)], 1),
                   np.stack([np.where(tri, zero, -b), np.where(tri, zero, 1 - a)], 1)], axis=1)
    return N, dN


def line_point(X: np.ndarray, kind: np.ndarray, x: np.ndarray, nu: np.ndarray):
    """(ξ (e, 2), t (e,)) where the line x - t ν meets each facet X (e, 4, 3) (its surface
    extended past its edges: ξ may leave the facet), by Newton (exact in one step on a
    triangle); NaN where the line is parallel to the facet."""
    e = len(x)
    xi = np.where((kind == 3)[:, None], 1.0 / 3.0, 0.5) * np.ones((e, 2))
    t = np.zeros(e)
    for _ in range(QUAD_ITERATIONS):
        N, dN = _shape(kind, xi)
        G = np.einsum("eb,ebc->ec", N, X) + t[:, None] * nu - x
        J = np.stack([np.einsum("eb,ebc->ec", dN[:, :, 0], X),
                      np.einsum("eb,ebc->ec", dN[:, :, 1], X), nu], axis=2)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(J, -G[..., None])[..., 0]
        xi, t = xi + step[:, :2], t + step[:, 2]
        if not (np.abs(step) > 1e-15 * (1 + np.abs(np.concatenate([xi, t[:, None]], 1)))).any():
            break
    return xi, t


def facet_transfer(nodes, corners, kind, x, support, N, M, facet, second: bool = True):
    """The elements of `facet_transfer`'s module docstring from diffuse elements.

    Parameters
    ----------
    nodes : (n, 3) float          the target's nodes (current positions)
    corners : (F, 4) int          its facets' corners (-1 past a triangle's third)
    kind : (F,) int               3 or 4
    x : (e, 3) float              the contactors
    support : (e, K) int          each diffuse element's support nodes (-1 padded)
    N, M : (e, 3(K+1)) and (e, 3(K+1), 3(K+1)) float
        the diffuse elements' 𝒩 and ℳ (M may be None with `second` False)
    facet : (e,) int              the facet each contactor's force goes through

    Returns
    -------
    unknowns : (e, K') int        the elements' target nodes: the support, then the facet's
                                  corners not in it (-1 padded)
    W : (e, 3(K'+1)) float        𝒲
    Nu : (e, 3(K'+1)) float       𝒩 on those unknowns
    dW : (e, 3(K'+1), 3(K'+1)) float or None    ∂𝒲/∂u (with `second`)
    """
    nodes = np.asarray(nodes, np.float64)
    x = np.asarray(x, np.float64)
    support = np.asarray(support, np.int64)
    e, K = support.shape
    C = np.asarray(corners, np.int64)[facet]                       # (e, 4)
    k = np.asarray(kind, np.int64)[facet]
    real = np.arange(4)[None] < k[:, None]
    # each corner's place among the unknowns: its support column, or a new one after them
    same = (support[:, :, None] == C[:, None, :]) & real[:, None, :] & (support[:, :, None] >= 0)
    found = same.any(axis=1)
    new = real & ~found
    extra = np.cumsum(new, axis=1) - 1
    width = K + int(new.sum(axis=1).max(initial=0))
    place = np.where(found, np.argmax(same, axis=1), K + extra)    # (e, 4): target node slot
    place = np.where(real, place, -1)
    unknowns = np.full((e, width), -1, np.int64)
    unknowns[:, :K] = support
    rows_e = np.repeat(np.arange(e), 4).reshape(e, 4)
    unknowns[rows_e[new], place[new]] = C[new]
    w = 3 * (width + 1)
    Nu = np.zeros((e, w))
    Nu[:, :3 * (K + 1)] = N
    nu = N[:, :3]  # ∂g/∂x^c: the unit normal, and ℳ[:3] its derivative
    X = nodes[np.maximum(C, 0)] * real[..., None]
    xi, t = line_point(X, k, x, nu)
    Nb, dNb = _shape(k, xi)
    W = np.zeros((e, w))
    W[:, :3] = nu
    col = 3 * (1 + place)                                          # (e, 4) first DOF column
    for b in range(4):
        on = real[:, b]
        for c in range(3):
            np.add.at(W, (np.flatnonzero(on), col[on, b] + c), -Nb[on, b] * nu[on, c])
    if not second:
        return unknowns, W, Nu, None
    dnu = np.zeros((e, 3, w))
    dnu[:, :, :3 * (K + 1)] = M[:, :3, :]
    # ∂G/∂u (e, 3, w): -I on x^c, N_b I on corner b, t ∂ν/∂u
    dG = t[:, None, None] * dnu
    dG[:, :, :3] -= np.eye(3)
    for b in range(4):
        on = np.flatnonzero(real[:, b])
        for c in range(3):
            np.add.at(dG, (on, c, col[on, b] + c), Nb[on, b])
    J = np.stack([np.einsum("eb,ebc->ec", dNb[:, :, 0], X),
                  np.einsum("eb,ebc->ec", dNb[:, :, 1], X), nu], axis=2)
    dxt = -np.linalg.solve(J, dG)                                  # (e, 3, w): ξ1, ξ2, t
    dW = np.zeros((e, w, w))
    dW[:, :3, :] = dnu
    for b in range(4):
        on = np.flatnonzero(real[:, b])
        dN = np.einsum("eb,ebw->ew", dNb[on, b, :], dxt[on, :2, :])   # ∂N_b/∂u (., w)
        block = -(nu[on, :, None] * dN[:, None, :] + Nb[on, b, None, None] * dnu[on])
        for c in range(3):
            np.add.at(dW, (on, col[on, b] + c), block[:, c, :])
    return unknowns, W, Nu, dW
