"""The node-to-facet contact element [§2]: gap, 𝒩 = ∂g/∂u [7] and ℳ = ∂²g/∂u² [9]-[10].

Unknowns u = [x^c, x^1, ..., x^p] [5] (p = 3 for a linear triangle, 4 for a bilinear quad).
The closest point x^m = Σ_j N_j(ξ) x_j [1] has facet parameters ξ = ξ0 + E θ: θ the free
ones (two inside the facet, one on an edge, none at a vertex). With d = x^c - x^m:

- inside, g = sign d·m/|m|, m = t_a × t_b the facet's normal vector, t_α = Σ_j N_j,α x_j [2];
- on an edge or at a vertex, g = side |d| (the signed distance to that point).

θ is stationary for D = ½ d·d, so 𝒩 = ∂g/∂u at fixed θ and
ℳ = ∂²g/∂u² - ∂²g/∂u∂θ (∂²D/∂θ²)⁻¹ ∂²D/∂θ∂u (implicit function theorem). Every derivative is
written out by the chain rule through d and m, whose first and second derivatives in (θ, u)
are explicit (d is linear in u, m bilinear in the nodes, both polynomial in ξ). The jet
element it replaced is its oracle in tests/oracle_element.py.
"""
from __future__ import annotations

import numpy as np

#: Free facet parameters at each kind of closest point (`facet.surface.free_parameters`):
#: ξ = ξ0 + E θ.
_FREE = {"interior": np.eye(2), "a": np.array([[1.0], [0.0]]), "b": np.array([[0.0], [1.0]]),
         "hypotenuse": np.array([[1.0], [-1.0]]), "vertex": np.zeros((2, 0))}


def _shape(kind: int, a: float, b: float):
    """Shape functions N (p,), their derivatives N,α (p, 2) and N,αβ (p, 2, 2) at (a, b)."""
    if kind == 3:
        N = np.array([1.0 - a - b, a, b])
        dN = np.array([[-1.0, -1.0], [1.0, 0.0], [0.0, 1.0]])
        return N, dN, np.zeros((3, 2, 2))
    N = np.array([(1 - a) * (1 - b), a * (1 - b), a * b, (1 - a) * b])
    dN = np.array([[-(1 - b), -(1 - a)], [1 - b, -a], [b, a], [-b, 1 - a]])
    ddN = np.zeros((4, 2, 2))
    ddN[:, 0, 1] = ddN[:, 1, 0] = [1.0, -1.0, 1.0, -1.0]
    return N, dN, ddN


def facet_element(corners: np.ndarray, contactor: np.ndarray, xi: np.ndarray, side: float,
                  sign: float = 1.0, second: bool = True):
    """Gap, 𝒩 and ℳ of the node-to-facet element [§2], [7]-[10].

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
    second : bool
        Compute ℳ too.

    Returns
    -------
    gap, N (3(p+1),), M (3(p+1), 3(p+1)) or None, with u = [x^c, x^1..x^p] [5].
    """
    from ..facet.surface import free_parameters

    corners = np.asarray(corners, dtype=np.float64)
    xc = np.asarray(contactor, dtype=np.float64)
    kind = len(corners)
    where = free_parameters(xi, kind)
    E = _FREE[where]
    f = E.shape[1]
    N, dN, ddN = _shape(kind, float(xi[0]), float(xi[1]))
    nz = f + 3 * (kind + 1)
    eye = np.eye(3)
    d = xc - N @ corners
    # d's derivatives in z = (θ, x^c, x^1..x^p): Jd (3, nz), Hd (3, nz, nz)
    dNt = dN @ E                       # ∂N_j/∂θ (p, f)
    ddNt = np.einsum("ak,jab,bl->jkl", E, ddN, E)
    Jd = np.zeros((3, nz))
    Jd[:, :f] = -corners.T @ dNt
    Jd[:, f:f + 3] = eye
    for j in range(kind):
        Jd[:, f + 3 + 3 * j:f + 6 + 3 * j] = -N[j] * eye
    Hd = np.zeros((3, nz, nz))
    if f:
        Hd[:, :f, :f] = -np.einsum("jkl,ji->ikl", ddNt, corners)
        for j in range(kind):
            cols = slice(f + 3 + 3 * j, f + 6 + 3 * j)
            block = -np.einsum("k,ic->ikc", dNt[j], eye)  # ∂²d_i/∂θ_k∂x_jc
            Hd[:, :f, cols] = block
            Hd[:, cols, :f] = np.swapaxes(block, 1, 2)
    if where == "interior":
        g, Gz, Gzz = _plane_gap(corners, d, Jd, Hd, dN, ddN, E, f, nz, sign, second)
    else:
        rho = np.sqrt(d @ d)
        n = d / rho
        g = side * rho
        Gz = side * (n @ Jd)
        Gzz = (side * (Jd.T @ (eye - np.outer(n, n)) @ Jd / rho + np.einsum("i,ikl->kl", n, Hd))
               if second else None)
    Nvec = Gz[f:]
    if not second:
        return float(g), Nvec, None
    M = Gzz[f:, f:]
    if f:
        Dzz = Jd.T @ Jd + np.einsum("i,ikl->kl", d, Hd)
        theta_u = -np.linalg.solve(Dzz[:f, :f], Dzz[:f, f:])  # ∂θ/∂u from ∂D/∂θ = 0 [1]
        M = M + Gzz[f:, :f] @ theta_u
    return float(g), Nvec, 0.5 * (M + M.T)


def _plane_gap(corners, d, Jd, Hd, dN, ddN, E, f, nz, sign, second):
    """g = sign d·m/|m| inside the facet [2], with its derivatives in z (Gz, Gzz)."""
    kind = len(corners)
    eye = np.eye(3)
    # t_α = Σ_j N_j,α x_j: Jt (α, 3, nz), Ht (α, 3, nz, nz) (t is linear in ξ and in x)
    t = dN.T @ corners                 # (2, 3)
    Jt = np.zeros((2, 3, nz))
    Ht = np.zeros((2, 3, nz, nz))
    ddNt = np.einsum("jab,bk->jak", ddN, E)  # ∂N_j,α/∂θ_k (p, 2, f)
    Jt[:, :, :f] = np.einsum("jak,ji->aik", ddNt, corners)
    for j in range(kind):
        cols = slice(f + 3 + 3 * j, f + 6 + 3 * j)
        Jt[:, :, cols] = dN[j][:, None, None] * eye
        if f:
            block = np.einsum("ak,ic->aikc", ddNt[j], eye)
            Ht[:, :, :f, cols] = block
            Ht[:, :, cols, :f] = np.swapaxes(block, 2, 3)
    m = np.cross(t[0], t[1])
    Jm = np.cross(Jt[0], t[1][:, None], axis=0) + np.cross(t[0][:, None], Jt[1], axis=0)
    mu = np.sqrt(m @ m)
    nu = m / mu
    g = d @ nu
    Hd_ = nu                           # ∂H/∂d
    Hm_ = (d - g * nu) / mu            # ∂H/∂m
    Gz = sign * (Hd_ @ Jd + Hm_ @ Jm)
    if not second:
        return sign * g, Gz, None
    Hm = (np.cross(Ht[0], t[1][:, None, None], axis=0)
          + np.cross(t[0][:, None, None], Ht[1], axis=0))
    cross = np.cross(Jt[0][:, :, None], Jt[1][:, None, :], axis=0)
    Hm = Hm + cross + np.swapaxes(cross, 1, 2)
    Hdm = (eye - np.outer(nu, nu)) / mu
    Hmm = (-(np.outer(d, nu) + np.outer(nu, d)) - g * eye + 3.0 * g * np.outer(nu, nu)) / mu**2
    Gzz = (Jd.T @ Hdm @ Jm + Jm.T @ Hdm @ Jd + Jm.T @ Hmm @ Jm
           + np.einsum("i,ikl->kl", Hd_, Hd) + np.einsum("i,ikl->kl", Hm_, Hm))
    return sign * g, Gz, sign * Gzz
