"""The contact element on a `QuadricSurface`: g, 𝒩 = ∂g/∂u, ℳ = ∂²g/∂u² with the nodal
normals' derivatives (issue 35, item 3).

The frozen pairing [§4.2]: each contactor's centre c, spacing h, radius R, support nodes and
sheet normal e3 (its `Patch`) are held fixed. Everything else moves with the unknowns
u = [x^c, x^t...]: the support nodes' positions (through y_i = (x_i - c)/h and the weights
W(|x_i - c|/R)), and their nodal normals n_i, which are functions of the positions of their
rings (the angle-weighted corner normals, `mls.quadric.normal_jets`), through the normal rows
of the fit and the sheet taper τ(n_i·e3). So the element's target nodes are the support and
its rings.

The chain. In spacings, the gap is φ(q, θ) = λ|∇u(y*)| with q = (x^c - c)/h, and θ solves
E(θ, u) = (A(u) + ρI) θ - r(u) = 0 (`mls.quadric.fit`). With p = (q, θ):

    φ_p, φ_pp   the closest point's problem F(z, p) = (y - q + λ∇u, u) = 0, z = (y, λ), by the
                implicit function theorem and one adjoint μ = F_z⁻ᵀ Φ_z of Φ = λ|∇u|:
                φ_pp = Zᵀ (Φ'' - μᵀF'') Z, Z = [z_p; I] (second derivatives by jets, `mls.jet`)
    θ_u = -(A + ρI)⁻¹ E_u
    𝒩 = h (φ_q ∂q/∂u + φ_θ θ_u)
    ℳ = h (J_pᵀ φ_pp J_p + φ_θ·θ_uu),   φ_θ·θ_uu = -aᵀE_uu - X - Xᵀ,  X = Γ θ_u

with a = (A + ρI)⁻¹ φ_θ and Γ_j = aᵀ ∂A/∂u_j. Each support node i adds to E a term e_i(x_i, n_i)
(its rows of the fit) and to A a term A_i(x_i, n_i); their derivatives in (x_i, n_i) come from
jets of 6 variables, and reach the ring's positions through ∂n_i/∂x_ring and ∂²n_i/∂x_ring².
A rigid target's element is the contactor's block: 𝒩 = φ_q, ℳ = φ_qq / h.

This is the reference implementation, in numpy (a loop over elements for the assembly of each
one's dense blocks); tests/test_quadric_element.py checks it by Taylor remainders falling as
h² (h³ for the gap's second-order expansion).
"""
from __future__ import annotations

import numpy as np

from ..mls import quadric as Q
from ..mls.jet import Jet
from ..mls.jet import dot as _dot


def closest_point_jets(q, y, lam, theta):
    """φ (e,), φ_p (e, 13) and φ_pp (e, 13, 13), p = (q, θ), at the converged closest point
    (y, λ) of q on θ's quadric (the implicit function theorem on F(z, p) = 0)."""
    e = len(q)
    var = Jet.variables(np.concatenate([y, lam[:, None], q, theta], axis=1), 17)
    yj, lj, qj, tj = var[0:3], var[3], var[4:7], var[7:17]
    b = Q.basis(yj)
    G = Q.basis_gradient(yj)
    g = [_dot(G[d], tj) for d in range(3)]
    F = [yj[d] - qj[d] + lj * g[d] for d in range(3)] + [_dot(b, tj)]
    Phi = lj * (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt()
    Fg = np.stack([f.g for f in F], axis=1)  # (e, 4, 17)
    Fz, Fp = Fg[:, :, :4].copy(), Fg[:, :, 4:]
    singular = ~(np.abs(np.linalg.det(Fz)) > 1e-300)  # no closest point to differentiate
    Fz[singular] = np.eye(4)
    zp = -np.linalg.solve(Fz, Fp)  # (e, 4, 13)
    mu = np.linalg.solve(np.swapaxes(Fz, 1, 2), Phi.g[:, :4, None])[..., 0]  # (e, 4)
    L = Phi.H - np.einsum("ek,ekij->eij", mu, np.stack([f.H for f in F], axis=1))
    Z = np.concatenate([zp, np.broadcast_to(np.eye(13), (e, 13, 13))], axis=1)  # (e, 17, 13)
    phi_p = Phi.g[:, 4:] + np.einsum("ek,ekp->ep", Phi.g[:, :4], zp)
    phi_pp = np.einsum("eia,eij,ejb->eab", Z, L, Z)
    phi_p[singular], phi_pp[singular] = np.nan, np.nan
    return Phi.v, phi_p, phi_pp


def node_terms(x, n, c, e3, h, R, theta, a, beta):
    """For support nodes (e, K) at x, n: jets over (x_i, n_i) (6 variables) of their rows of the
    fit, e_i = ω_i (b (b·θ) + β Gᵀ(Gθ - n_i)), and of A_i a = ω_i (b (b·a) + β Gᵀ(G a)),
    ω_i = W(|x_i - c|/R) τ(n_i·e3). Returns (∂e_i (e, K, 10, 6), ∂(A_i a) (e, K, 10, 6),
    T_i = a·e_i's gradient (e, K, 6) and Hessian (e, K, 6, 6))."""
    shape = x.shape[:2]
    var = Jet.variables(np.concatenate([x, n], axis=-1), 6)
    xj, nj = var[:3], var[3:]
    cc, hh = c[:, None, :], h[:, None]
    y = [(xj[d] - cc[..., d]) * (1.0 / hh) for d in range(3)]
    w, wg, wh = Q.weights(x, cc, R[:, None])
    g6 = np.zeros((*shape, 6))
    g6[..., :3] = wg
    h6 = np.zeros((*shape, 6, 6))
    h6[..., :3, :3] = wh
    W = Jet.lift(w, g6, h6)
    cosj = _dot(nj, [e3[:, None, d] for d in range(3)])
    tau, d1, d2 = Q.sheet_taper(cosj.v)
    taper = Jet(tau, cosj.g * d1[..., None],
                cosj.H * d1[..., None, None] + d2[..., None, None] * cosj.g[..., :, None]
                * cosj.g[..., None, :])
    omega = W * taper
    b = Q.basis(y)
    G = Q.basis_gradient(y)
    th = [theta[:, None, k] for k in range(Q.NTERMS)]
    aa = [a[:, None, k] for k in range(Q.NTERMS)]
    u = _dot(b, th)
    ua = _dot(b, aa)
    resid = [_dot(G[d], th) - nj[d] for d in range(3)]
    ga = [_dot(G[d], aa) for d in range(3)]
    e_rows = [omega * (b[k] * u + beta * _dot([G[d][k] for d in range(3)], resid))
              for k in range(Q.NTERMS)]
    Aa = [omega * (b[k] * ua + beta * _dot([G[d][k] for d in range(3)], ga))
          for k in range(Q.NTERMS)]
    T = _dot(e_rows, aa)
    de = np.stack([r.g for r in e_rows], axis=-2)
    dAa = np.stack([r.g for r in Aa], axis=-2)
    return de, dAa, T.g, T.H


def quadric_elements(surface, points, patch, rows, second=True, rigid_target=False):
    """The elements of contactors `rows` on a QuadricSurface with their frozen pairing `patch`
    (`QuadricSurface.project(..., keep_patch=True).patch`): (gap (e,), nodes (e, K) -1 padded,
    N (e, 3(K+1)), M (e, 3(K+1), 3(K+1)) or None); a rigid target's: nodes (e, 0), N (e, 3),
    M (e, 3, 3). NaN where the fit or the closest point cannot be solved."""
    rows = np.asarray(rows, dtype=np.int64)
    p = patch.take(rows)
    x_c = np.asarray(points, dtype=np.float64)[rows]
    e = len(rows)
    if e == 0:
        width = 0 if rigid_target else 1
        return (np.zeros(0), np.zeros((0, 0 if rigid_target else width), np.int64),
                np.zeros((0, 3)), np.zeros((0, 3, 3)) if second else None)
    theta, _, _, A = surface.fit_patch(p, rcond=False, matrix=True)
    c, h, R, e3 = p.origin, p.spacing, p.radius, p.axes[:, 2]
    q = (x_c - c) / h[:, None]
    with np.errstate(all="ignore"):
        y, lam, ok = Q.closest_point(q, np.where(np.isfinite(theta), theta, 0.0))
        phi, phi_p, phi_pp = closest_point_jets(q, y, lam, np.where(np.isfinite(theta), theta,
                                                                   0.0))
    bad = ~ok | ~np.isfinite(theta).all(axis=1)
    gap = h * phi
    if rigid_target:
        N = phi_p[:, :3].copy()
        M = phi_pp[:, :3, :3] / h[:, None, None] if second else None
        gap[bad], N[bad] = np.nan, np.nan
        if M is not None:
            M[bad] = np.nan
        return gap, np.zeros((e, 0), np.int64), N, M
    index = np.asarray(p.index)
    live = index >= 0
    ids = np.maximum(index, 0)
    xs, ns = surface.nodes[ids], surface.normals[ids]
    a = np.linalg.solve(A, phi_p[:, 3:, None])[..., 0]
    de, dAa, Tg, TH = node_terms(xs, ns, c, e3, h, R, np.nan_to_num(theta), a, surface.beta)
    # the support's nodes' normals and their rings' derivatives, once per distinct node
    used = np.unique(index[live])
    ring, _, Jn, Hn = Q.normal_jets(surface.nodes, surface.corners, surface.corner_ptr, used,
                                    surface.sign)
    where = {int(v): k for k, v in enumerate(used)}
    elements = []
    for i in range(e):
        elements.append(_one(i, index[i], live[i], where, ring, Jn, Hn, A[i], de[i], dAa[i],
                             Tg[i], TH[i], phi_p[i], phi_pp[i], h[i], second))
    K = max(len(t[0]) for t in elements)
    nodes = np.full((e, K), -1, np.int64)
    N = np.zeros((e, 3 * (K + 1)))
    M = np.zeros((e, 3 * (K + 1), 3 * (K + 1))) if second else None
    for i, (tn, Ni, Mi) in enumerate(elements):
        k = len(tn)
        nodes[i, :k] = tn
        N[i, :3 * (k + 1)] = Ni
        if second:
            M[i, :3 * (k + 1), :3 * (k + 1)] = Mi
    gap[bad], N[bad] = np.nan, np.nan
    if M is not None:
        M[bad] = np.nan
    return gap, nodes, N, M


def _one(i, index, live, where, ring, Jn, Hn, A, de, dAa, Tg, TH, phi_p, phi_pp, h, second):
    """One element's (target nodes, 𝒩, ℳ): the chain of the module's docstring."""
    if not live.any():  # no support (not an answered contactor): no element (NaN)
        return (np.zeros(0, np.int64), np.full(3, np.nan),
                np.full((3, 3), np.nan) if second else None)
    support = index[live]
    rows = [where[int(v)] for v in support]
    targets = np.unique(np.concatenate([ring[r][ring[r] >= 0] for r in rows]))
    slot = {int(v): k for k, v in enumerate(targets)}
    nu = 3 * (len(targets) + 1)
    E_u = np.zeros((Q.NTERMS, nu))
    Gam = np.zeros((nu, Q.NTERMS))
    maps = []
    for j, r in enumerate(np.flatnonzero(live)):
        k = rows[j]
        rn = ring[k][ring[k] >= 0]
        cols = (3 * (1 + np.array([slot[int(v)] for v in rn]))[:, None] + np.arange(3)).ravel()
        P = len(cols)
        Jmap = np.zeros((6, P))
        Jmap[:3, :3] = np.eye(3)  # the ring's first node is the node itself
        Jmap[3:] = Jn[k][:, :P]
        E_u[:, cols] += de[r] @ Jmap
        Gam[cols] += (dAa[r] @ Jmap).T
        maps.append((r, k, cols, P, Jmap))
    theta_u = -np.linalg.solve(A, E_u)
    Jp = np.zeros((13, nu))
    Jp[:3, :3] = np.eye(3) / h
    Jp[3:] = theta_u
    N = h * (phi_p @ Jp)
    if not second:
        return targets, N, None
    M = Jp.T @ phi_pp @ Jp
    X = Gam @ theta_u
    M -= X + X.T
    for r, k, cols, P, Jmap in maps:  # -aᵀ E_uu, node by node over its ring
        Hr = Jmap.T @ TH[r] @ Jmap + np.einsum("c,cij->ij", Tg[r][3:], Hn[k][:, :P, :P])
        M[np.ix_(cols, cols)] -= Hr
    return targets, N, h * M
