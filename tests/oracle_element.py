"""The slow, obvious contact elements: the oracles of the production ones (tests only).

Every derivative comes from `jet` (exact forward-mode differentiation over all 3(n+1) + 2
unknowns [X̄, u]); ∂α/∂u, which the paper omits, is `jet.solve`. This was diffsurf's
production element until the compiled `diffsurf_cli.element._element` replaced it (15-20 ms a
contactor); the tests compare the two to 1e-10 and run the Taylor tests on both. The jet
node-to-facet element (`facet_element`) is the oracle of `diffsurf_cli.element.facet`.

Written once, generically: a surface point x(X, u) with in-plane parameters X and unit normal
ν(X, u); the proximal point X̄(u) is stationary for D = ½‖x^c - x‖² [30]; the gap is
G(X̄, u) = (x^c - x)·ν [32]. Because ∂G/∂X = 0 at X̄,

    𝒩 = ∂G/∂u,    ℳ = ∂²G/∂u² + ∂²G/∂u∂X · ∂X̄/∂u,  ∂X̄/∂u = -(∂²D/∂X²)⁻¹ ∂²D/∂X∂u.
"""
from __future__ import annotations

import numpy as np

import reference_steps
from jet import Jet, stack


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


def dot3(a: Jet, b: Jet) -> Jet:
    return (a * b).sum(-1)


def _unit(v: Jet) -> Jet:
    return v / dot3(v, v).sqrt()


def solve(A: Jet, b: Jet) -> Jet:
    """x = A⁻¹ b with exact first and second derivatives (as `jet.solve`), A equilibrated:
    with D = diag(A)^-½, A⁻¹ = D (D A D)⁻¹ D, so the inverse's round-off follows the
    condition of D A D, not of A (a cubic basis' columns differ by decades: on a thin
    support, `jet.solve`'s plain inverse lost 2.6e-9 of 𝒩 against a 40-digit reference where
    the compiled Cholesky, scaling-invariant, lost 7e-11).

    From A x = b: ∂x = A⁻¹(∂b - ∂A x) and ∂²x = A⁻¹(∂²b - ∂²A x - ∂A ∂x - (∂A ∂x)ᵀ).
    """
    d = 1.0 / np.sqrt(np.diag(A.val))
    A0inv = d[:, None] * np.linalg.inv(d[:, None] * A.val * d[None, :]) * d[None, :]
    x = A0inv @ b.val
    dAx = np.einsum("ijp,j->ip", A.grad, x)
    dx = A0inv @ (b.grad - dAx)
    dAdx = np.einsum("ijp,jq->ipq", A.grad, dx)
    rhs = b.hess - np.einsum("ijpq,j->ipq", A.hess, x) - dAdx - np.swapaxes(dAdx, -1, -2)
    ddx = np.einsum("ij,jpq->ipq", A0inv, rhs)
    return Jet(x, dx, ddx)


def diffuse_element(surface, contactor, index, origin, axes, radius, proximal_point,
                    second=True):
    """Gap, support nodes (u's order), 𝒩 and ℳ of the diffuse element of one contactor [§4],
    on the frozen pairing (origin, axes, radius, support index; -1 padding allowed); only
    nodes with positive weight enter u."""
    index = np.asarray(index)
    index = index[index >= 0]
    A = axes / radius
    b = -A @ origin
    # drop the nodes whose weight is zero: they do not move the fit
    loc = surface.nodes[index] @ A.T + b
    c0 = A @ contactor + b
    q0 = (loc[:, 0] - c0[0]) ** 2 + (loc[:, 1] - c0[1]) ** 2
    index = index[reference_steps.weight(surface.weight, q0)[0] > 0]
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
    w = q.apply(*reference_steps.weight(surface.weight, q.val, 2))
    P = stack(reference_steps.terms(surface.basis, s, t), axis=-1)  # (n, k) [20]
    wP = P * Jet(w.val[:, None], w.grad[:, None], w.hess[:, None])
    Pi = Jet(P.val[:, None, :], P.grad[:, None, :], P.hess[:, None, :])
    wPi = Jet(wP.val[:, :, None], wP.grad[:, :, None], wP.hess[:, :, None])
    Amat = (wPi * Pi).sum(0)  # Pᵀ W P [17]
    # α = α0 + A⁻¹ Pᵀ W (Z - P α0), α0 the fit's value: the right-hand side in residual
    # form, so ∂b - ∂A α is not the difference of two large sums (Pᵀ W Z and Pᵀ W P α cancel
    # to the residual's size where the fit nearly interpolates)
    alpha0 = np.linalg.solve(Amat.val, (wP.val * z.val[:, None]).sum(0))
    resid = z - (P * alpha0).sum(-1)
    rvec = (wP * Jet(resid.val[:, None], resid.grad[:, None], resid.hess[:, None])).sum(0)
    alpha = solve(Amat, rvec) + alpha0
    sb, tb = X[0] - cs, X[1] - ct
    f, fs, ft = (dot3(stack(reference_steps.terms(surface.basis, sb, tb, i, j), -1), alpha)
                 for i, j in ((0, 0), (1, 0), (0, 1)))
    xd = stack([X[0], X[1], f])
    one = Jet.constant(1.0, v.nvars)
    nu = _unit(stack([-fs, -ft, one]))  # [29]
    d = c - xd
    G = dot3(d, nu)  # [32], in units of R
    D = 0.5 * dot3(d, d)
    N, M = _implicit(G, D, 2, 1.0, second)
    # G is measured in the scaled frame X = axes (x - o) / R, a rotation scaled by 1/R, so
    # g = R G and every derivative of g with respect to u is R times that of G.
    return radius * G.val, index, radius * N, (radius * M if second else None)


def diffuse_elements(surface, points, patch, proximal_point, rows, second=True):
    """`diffuse_element` over `rows`, in the layout of
    `diffsurf_cli.element.diffuse.diffuse_elements` (nodes -1 padded, N and M zero padded)."""
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    out = [diffuse_element(surface, points[i], patch.index[i], patch.origin[i],
                           patch.axes[i], patch.radius[i], proximal_point[i], second)
           for i in rows]
    K = max((len(o[1]) for o in out), default=0)
    size = 3 * (K + 1)
    gap = np.array([o[0] for o in out], dtype=np.float64)
    nodes = np.full((len(rows), K), -1, dtype=np.int64)
    N = np.zeros((len(rows), size))
    M = np.zeros((len(rows), size, size)) if second else None
    for e, (_, ix, Ne, Me) in enumerate(out):
        nodes[e, :len(ix)] = ix
        N[e, :len(Ne)] = Ne
        if second:
            M[e, :len(Ne), :len(Ne)] = Me
    return gap, nodes, N, M


def _cross(a: Jet, b: Jet) -> Jet:
    return stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def facet_element(corners: np.ndarray, contactor: np.ndarray, xi: np.ndarray, side: float,
                  sign: float = 1.0, second: bool = True):
    """Gap, 𝒩 and ℳ of the node-to-facet element [§2], [7]-[10], by jets (the oracle of
    `diffsurf_cli.element.facet.facet_element`).

    Parameters
    ----------
    corners : (3, 3) or (4, 3) float
        The facet's nodes (linear triangle or bilinear quad).
    contactor : (3,) float
    xi : (2,) float
        Facet parameters of the closest point x^m [1].
    side : float
        +1 or -1: the side of the facet the contactor is on (used at edges and vertices, where
        the gap is the signed distance to x^m).
    sign : float
        -1 to reverse the facet orientation.

    Returns
    -------
    gap, N (3(p+1),), M (3(p+1), 3(p+1)) or None, with u = [x^c, x^1..x^p] [5].
    """
    from diffsurf_cli.facet.surface import free_parameters

    kind = len(corners)
    where = free_parameters(xi, kind)
    nfree = {"interior": 2, "a": 1, "b": 1, "hypotenuse": 1, "vertex": 0}[where]
    params = {"interior": xi, "a": xi[:1], "b": xi[1:], "hypotenuse": xi[:1],
              "vertex": xi[:0]}[where]
    coords = np.vstack([contactor, corners])
    v, pts = _unknowns(nfree, params, coords)
    m = v.nvars
    const = [Jet.constant(x, m) for x in xi]
    if where == "interior":
        a, b = v[0], v[1]
    elif where == "a":
        a, b = v[0], const[1]
    elif where == "b":
        a, b = const[0], v[0]
    elif where == "hypotenuse":
        a, b = v[0], 1.0 - v[0]
    else:
        a, b = const
    xc, x = pts[0], pts[1:]
    if kind == 3:
        N = [1.0 - a - b, a, b]
    else:
        N = [(1.0 - a) * (1.0 - b), a * (1.0 - b), a * b, (1.0 - a) * b]
    xm = N[0] * x[0]
    for j in range(1, kind):
        xm = xm + N[j] * x[j]
    d = xc - xm
    D = 0.5 * dot3(d, d)
    if where == "interior":
        if kind == 3:
            ta, tb = x[1] - x[0], x[2] - x[0]
        else:
            ta = (1.0 - b) * (x[1] - x[0]) + b * (x[2] - x[3])
            tb = (1.0 - a) * (x[3] - x[0]) + a * (x[2] - x[1])
        G = dot3(d, _unit(_cross(ta, tb))) * sign  # [2]
    else:
        G = dot3(d, d).sqrt() * side  # distance to an edge or vertex, signed by the side
    Nvec, M = _implicit(G, D, nfree, 1.0, second)
    return float(G.val), Nvec, M


def cell_element(shape: np.ndarray, nodes: np.ndarray, contactor: np.ndarray, xi: np.ndarray,
                 orient: np.ndarray, second: bool = True):
    """Gap, 𝒩 and ℳ of the node-to-cell element on a second-order cell, by jets (the oracle
    of `diffsurf_cli.element.cell.cell_elements`).

    shape : (9, n) float, W: the cell's monomial coefficients are W X (X its n nodes), over
    `patches.surface.CELL_MONOMIALS`; nodes (n, 3); contactor (3,); xi (2,) the closest
    point's parameters (inside the cell); orient (3,): the side ν faces.

    Returns gap, N (3(n+1),), M (3(n+1), 3(n+1)) or None, with u = [x^c, X_1..X_n].
    """
    from diffsurf_cli.patches.surface import CELL_MONOMIALS

    coords = np.vstack([contactor, nodes])
    v, pts = _unknowns(2, xi, coords)
    a, b = v[0], v[1]
    xc, X = pts[0], pts[1:]
    pa, pb = [1.0, a, a * a], [1.0, b, b * b]
    da, db = [0.0, 1.0, 2.0 * a], [0.0, 1.0, 2.0 * b]

    def combine(terms):  # Σ_m term_m Σ_k W_mk X_k, skipping zero terms
        out = None
        for m, t in enumerate(terms):
            if isinstance(t, float) and t == 0.0:
                continue
            for k in range(len(nodes)):
                if shape[m, k] != 0.0:
                    add = (t * shape[m, k]) * X[k]
                    out = add if out is None else out + add
        return out

    x = combine([pa[i] * pb[j] for i, j in CELL_MONOMIALS])
    ta = combine([da[i] * pb[j] for i, j in CELL_MONOMIALS])
    tb = combine([pa[i] * db[j] for i, j in CELL_MONOMIALS])
    d = xc - x
    D = 0.5 * dot3(d, d)
    nu = _unit(_cross(ta, tb))
    sign = 1.0 if float(np.dot(nu.val, orient)) >= 0 else -1.0
    G = dot3(d, nu) * sign  # [32]
    Nvec, M = _implicit(G, D, 2, 1.0, second)
    return float(G.val), Nvec, M
