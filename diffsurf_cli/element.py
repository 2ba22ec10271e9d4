"""The contact element: gap, 𝒩 = ∂g/∂u and ℳ = ∂²g/∂u², residual and tangent [§4.2-4.3], [§2].

Unknowns of one element are u = [x^c, x^1, ..., x^n] [22] (3(n+1) numbers): the contactor and
the nodes its gap depends on (the support of its local approximation for the diffuse element,
the facet's nodes for node-to-facet). With the penalty method [3], the residual and tangent are
R = ε g 𝒩 [45] and K = ε (g ℳ + 𝒩 𝒩ᵀ) [54], the gradient and Hessian of ε g²/2.

Both elements are written once, generically: a surface point x(X, u) with in-plane parameters X
and unit normal ν(X, u); the proximal point X̄(u) is stationary for D = ½‖x^c - x‖² ([30], or
the facet's closest point [1]); the gap is G(X̄, u) with G = (x^c - x)·ν [32]. Then, because
∂G/∂X = 0 at X̄ (x^c - x^d is parallel to ν and ⊥ τ_k),

    𝒩 = ∂G/∂u                                   (the paper's [42]-[44]: no ∂X̄ needed)
    ℳ = ∂²G/∂u² + ∂²G/∂u∂X · ∂X̄/∂u,  ∂X̄/∂u = -(∂²D/∂X²)⁻¹ ∂²D/∂X∂u   (implicit function theorem)

which gathers the paper's 𝒮_l, 𝒯_l, 𝒰 and 𝒟_τ terms [48]-[53]. Every derivative comes from
`jet` (exact forward-mode differentiation); ∂α/∂u, which the paper omits, is `jet.solve`.
The frame, the support set and the radius R are held fixed, as in the paper.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from . import basis as _basis
from . import weight as _weight
from .jet import Jet, solve, stack


@dataclass
class Element:
    """One contact element.

    contactor : int          index of the contactor x^c
    nodes : (n,) int         target node indices in u = [x^c, x^nodes[0], ...] order
    gap : float              g [32]
    N : (3(n+1),) float      ∂g/∂u (the paper's 𝒩 [42])
    M : (3(n+1), 3(n+1)) float or None   ∂²g/∂u² (the paper's ℳ [53]), when asked for
    """

    contactor: int
    nodes: np.ndarray
    gap: float
    N: np.ndarray
    M: np.ndarray | None

    def residual(self, penalty: float) -> np.ndarray:
        """R = ε g 𝒩 [45]."""
        return penalty * self.gap * self.N

    def tangent(self, penalty: float) -> np.ndarray:
        """K = ε (g ℳ + 𝒩 𝒩ᵀ) [54]."""
        return penalty * (self.gap * self.M + np.outer(self.N, self.N))


def _unknowns(nparams: int, params, coords: np.ndarray):
    """Jet variables [X (nparams), u (3 per point)] and the points of u as (p, 3) jets."""
    v = Jet.variables(np.concatenate([np.ravel(params), coords.ravel()]))
    m = v.nvars
    pts = Jet(coords.copy(), v.grad[nparams:].reshape(len(coords), 3, m),
              np.zeros((len(coords), 3, m, m)))
    return v, pts


def _linear(pts: Jet, A: np.ndarray, b: np.ndarray) -> Jet:
    """A @ p + b for each point of `pts` (p, 3): an affine map of the unknowns."""
    return Jet(pts.val @ A.T + b, np.einsum("ij,pjm->pim", A, pts.grad),
               np.zeros(pts.val.shape + pts.hess.shape[-2:]))


def _implicit(G: Jet, D: Jet, nparams: int, scale: float, second: bool):
    """𝒩 and ℳ from the gap G and the distance D, both functions of [X, u]."""
    k = nparams
    N = scale * G.grad[k:]
    if not second:
        return N, None
    M = G.hess[k:, k:]
    if k:
        Xu = -np.linalg.solve(D.hess[:k, :k], D.hess[:k, k:])  # ∂X̄/∂u from ∂D/∂X = 0 [30]
        M = M + G.hess[k:, :k] @ Xu
    M = scale * 0.5 * (M + M.T)
    return N, M


def _unit(v: Jet) -> Jet:
    return v / dot3(v, v).sqrt()


def dot3(a: Jet, b: Jet) -> Jet:
    return (a * b).sum(-1)


def diffuse_element(surface, contactor: np.ndarray, index: np.ndarray, origin: np.ndarray,
                    axes: np.ndarray, radius: float, proximal_point: np.ndarray,
                    second: bool = True):
    """Gap, 𝒩 and ℳ of the diffuse element of one contactor [§4].

    Parameters
    ----------
    surface : DiffuseSurface
        Provides the target nodes, the basis and the weight.
    contactor : (3,) float
    index : (K,) int
        Support node indices (-1 padding allowed); only nodes with positive weight enter u.
    origin : (3,) float
    axes : (3, 3) float
    radius : float
        The frozen pairing (frame R^d and R).
    proximal_point : (3,) float
        x^d from the projection (it fixes the stationary X̄).
    second : bool
        Compute ℳ too (the tangent needs it; the residual does not).

    Returns
    -------
    gap : float
    nodes : (n,) int   the support nodes in u's order
    N : (3(n+1),) float
    M : (3(n+1), 3(n+1)) float or None
    """
    index = np.asarray(index)
    index = index[index >= 0]
    A = axes / radius
    b = -A @ origin
    # drop the nodes whose weight is zero: they do not move the fit
    loc = surface.nodes[index] @ A.T + b
    c0 = A @ contactor + b
    q0 = (loc[:, 0] - c0[0]) ** 2 + (loc[:, 1] - c0[1]) ** 2
    index = index[_weight.evaluate(surface.weight, q0)[0] > 0]
    Xbar = (A @ proximal_point + b)[:2]
    coords = np.vstack([contactor, surface.nodes[index]])
    v, pts = _unknowns(2, Xbar, coords)
    local = _linear(pts, A, b)  # X = axes (x - o) / R for x^c and every support node
    X = v[:2]
    c = local[0]
    nodes = local[1:]
    # basis and weights centred at the contactor's in-plane position [14], [15]
    cs, ct = c[0], c[1]
    s = nodes[:, 0] - cs
    t = nodes[:, 1] - ct
    z = nodes[:, 2]
    q = s * s + t * t
    w = q.apply(*_weight.evaluate(surface.weight, q.val, 2))
    P = stack(_basis.terms(surface.basis, s, t), axis=-1)  # (n, k) [20]
    wP = P * Jet(w.val[:, None], w.grad[:, None], w.hess[:, None])
    Pi = Jet(P.val[:, None, :], P.grad[:, None, :], P.hess[:, None, :])
    wPi = Jet(wP.val[:, :, None], wP.grad[:, :, None], wP.hess[:, :, None])
    Amat = (wPi * Pi).sum(0)  # Pᵀ W P [17]
    bvec = (wP * Jet(z.val[:, None], z.grad[:, None], z.hess[:, None])).sum(0)  # Pᵀ W Z
    alpha = solve(Amat, bvec)
    sb, tb = X[0] - cs, X[1] - ct
    f, fs, ft = (dot3(stack(_basis.terms(surface.basis, sb, tb, i, j), -1), alpha)
                 for i, j in ((0, 0), (1, 0), (0, 1)))
    xd = stack([X[0], X[1], f])
    one = Jet.constant(1.0, v.nvars)
    nu = _unit(stack([-fs, -ft, one]))  # [29]
    d = c - xd
    G = dot3(d, nu)  # [32], in units of R
    D = 0.5 * dot3(d, d)
    N, M = _implicit(G, D, 2, 1.0, second)
    # X = axes (x - o) / R: G and its u-derivatives are in units of R per unit of u... the map
    # is linear with factor 1/R, so g = R G and ∂g/∂u = R ∂G/∂u.
    return radius * G.val, index, radius * N, (radius * M if second else None)
