"""The node-to-cell element: the node-to-facet element [§2] on a target's curved cell.

Where a PatchedSurface's curved cells answer a contactor (`patches.surface.CELLS`: its
second-order cells, or its first-order facets curved through their corner normals), its
element is that cell's, so that `contact` gives the gap `project` gives. The cell is
x(ξ) = Σ_m ξ^m c_m over the monomials a^i b^j (i, j ≤ 2) of `patches.surface.CELL_MONOMIALS`
[1]; on a second-order cell c = W X, its nodes X times its shape functions' monomial
coefficients (`patches.surface.cell_shape`), so that x(ξ) = Σ_k N_k(ξ) X_k with
N_k(ξ) = Σ_m ξ^m W_mk.

With r = x^c - x(ξ̄), ξ̄ stationary for D = ½ r·r [30], ν the cell's unit normal and
g = r·ν [32] (r = g ν at ξ̄), the tangent basis y_α = x_,α, G_αβ = y_α·y_β,
H_αβ = ν·x_,αβ and A = G - g H:

    δg = ν·δr_ξ,   δr_ξ = δx^c - Σ_k N_k δX_k                                       [42]

(ν ⊥ y_α, and ν·δν = 0), so 𝒩 = [ν, -N_1 ν, ..., -N_n ν]. Varying it, with
a_α(δ) = y_α·δr_ξ, b_α(δ) = ν·Σ_k N_k,α δX_k, the Weingarten formula
Δν = -y^α (b_α(Δ) + H_αβ Δξ^β) and Δξ = A⁻¹ (a(Δ) + g b(Δ)) (from Δ(r·y_α) = 0):

    ℳ = -aᵀ G⁻¹ H A⁻¹ a - aᵀ A⁻¹ b - bᵀ A⁻¹ a - g bᵀ A⁻¹ b                         [53]

(G⁻¹ H A⁻¹ is symmetric). A rigid target has b = 0 and a = [y_1, y_2]ᵀ: 𝒩 = ν and
ℳ = ∂ν/∂x^c = -Y G⁻¹ H A⁻¹ Yᵀ (a sphere of radius R: (I - ν νᵀ)/(R + g)). A first-order
facet's cell is curved through its corner normals, themselves functions of the nodes: its
element on a deformable target would need their derivatives, so there the node-to-facet
element of the facet stands (`element.patched_contact`). Its oracle is the jet element
`cell_element` of tests/oracle_element.py.
"""
from __future__ import annotations

import numpy as np

from .. import tol
from ..patches._pass import frozen_cells
from ..patches.surface import CELL_MONOMIALS, CELL_NODES, cell_shape
from ..projection import CONTACT, FAILED, ILL_CONDITIONED, NO_CONVERGENCE, OK, OPEN, PENETRATION
from . import blocks

#: The powers i of a and j of b of each monomial (2, 9).
POWERS = np.array(CELL_MONOMIALS).T


def monomials(xi: np.ndarray) -> np.ndarray:
    """(6, e, 9) the monomials a^i b^j at ξ (e, 2) and their derivatives: value, ∂a, ∂b,
    ∂aa, ∂ab, ∂bb."""
    i, j = POWERS
    a, b = np.asarray(xi, dtype=np.float64).T
    pa = np.stack([np.ones_like(a), a, a * a], axis=1)   # (e, 3): 1, a, a²
    pb = np.stack([np.ones_like(b), b, b * b], axis=1)
    da = np.stack([np.zeros_like(a), np.ones_like(a), 2 * a], axis=1)
    db = np.stack([np.zeros_like(b), np.ones_like(b), 2 * b], axis=1)
    two_a, two_b = 2.0 * (i == 2), 2.0 * (j == 2)
    return np.stack([pa[:, i] * pb[:, j], da[:, i] * pb[:, j], pa[:, i] * db[:, j],
                     two_a * pb[:, j], da[:, i] * db[:, j], pa[:, i] * two_b])


def evaluate(coef: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """(6, e, 3) x, x_a, x_b, x_aa, x_ab, x_bb of each cell (coef (e, 9, 3)) at ξ (e, 2)."""
    return np.einsum("kem,emj->kej", monomials(xi), coef)


def cell_elements(coef, points, xi, orient, shape=None, second=True):
    """Gap, 𝒩 and ℳ of the node-to-cell element of each contactor (module docstring).

    Parameters
    ----------
    coef : (e, 9, 3) float
        Each cell's monomial coefficients (`patches.surface.cell_coefficients`).
    points : (e, 3) float
        The contactors x^c.
    xi : (e, 2) float
        Their closest points' parameters ξ̄ on their cells.
    orient : (e, 3) float
        The side the cell's normal faces: ν is x_a × x_b turned to agree with it (its
        facet's normal, reversed on a flipped target).
    shape : (e, 9, n) float, optional
        W: each cell's shape functions' monomial coefficients (coef = W X on its n nodes;
        zero columns pad a narrower cell). None: a rigid target, u = x^c only.
    second : bool
        Compute ℳ too.

    Returns
    -------
    gap (e,), N (e, 3(n+1)) with u = [x^c, X_1..X_n] (3 with a rigid target), and
    M (e, 3(n+1), 3(n+1)) or None.
    """
    coef = np.asarray(coef, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    mono = monomials(xi)
    X = np.einsum("kem,emj->kej", mono, coef)
    y = X[1:3].transpose(1, 0, 2)                                   # (e, 2, 3): y_1, y_2
    n = np.cross(X[1], X[2])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.where(np.einsum("ej,ej->e", n, orient) < 0, -1.0, 1.0)[:, None]
    gap = np.einsum("ej,ej->e", points - X[0], n)
    G = np.einsum("eaj,ebj->eab", y, y)
    H = np.einsum("kej,ej->ek", X[3:6], n)[:, [0, 1, 1, 2]].reshape(-1, 2, 2)
    A = G - gap[:, None, None] * H
    e = len(points)
    if shape is None:                                       # a rigid target: u = x^c
        N = n
    else:
        W = np.asarray(shape, dtype=np.float64)
        Nk = np.einsum("em,emk->ek", mono[0], W)            # N_k(ξ̄)
        k = W.shape[2]
        N = np.concatenate([n, -(Nk[:, :, None] * n[:, None, :]).reshape(e, 3 * k)], axis=1)
    if not second:
        return gap, N, None
    if shape is None:
        a = y                                               # a_α(δ) = y_α·δx^c
    else:
        dN = np.einsum("aem,emk->eak", mono[1:3], W)        # N_k,α(ξ̄)
        a = np.concatenate([y, -(Nk[:, None, :, None] * y[:, :, None, :]).reshape(e, 2, 3 * k)],
                           axis=2)
        b = np.concatenate([np.zeros((e, 2, 3)),
                            (dN[:, :, :, None] * n[:, None, None, :]).reshape(e, 2, 3 * k)],
                           axis=2)
    Ainv = _inverse(A)                    # NaN where singular: a degenerate cell, or x^c
    S = _inverse(G) @ H @ Ainv            # at its centre of curvature; G⁻¹ H A⁻¹ (symmetric)
    if shape is None:
        Q, C = a, S
    else:  # ℳ = -Qᵀ C Q, Q = [a; b], C = [[S, A⁻¹], [A⁻¹, g A⁻¹]]
        Q = np.concatenate([a, b], axis=1)
        C = np.block([[S, Ainv], [Ainv, gap[:, None, None] * Ainv]])
    QT = Q.transpose(0, 2, 1)
    M = -(QT @ C) @ Q
    return gap, N, 0.5 * (M + M.transpose(0, 2, 1))


def _inverse(A: np.ndarray) -> np.ndarray:
    """(e, 2, 2) the inverse of each 2x2 matrix, NaN where it is singular (never raises,
    as np.linalg.inv does for a whole batch over one singular row)."""
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(det != 0, 1.0 / det, np.nan)
    adj = np.stack([A[:, 1, 1], -A[:, 0, 1], -A[:, 1, 0], A[:, 0, 0]], axis=1)
    return (adj * r[:, None]).reshape(-1, 2, 2)


# --- on a PatchedSurface ------------------------------------------------------------------
def node_cells(surface, cells):
    """The second-order cells among `cells`: nodes (e, K) int (-1 padded; K the widest) and
    shape (e, 9, K) float (W: coef = W X), and (e,) bool, True on a cell of its own nodes
    (triangle6, triangle7, quad8, quad9; False on a first-order facet curved through its
    normals)."""
    starts = np.cumsum([0] + [len(f) for f in surface.faces])
    block = np.searchsorted(starts, cells, side="right") - 1
    width = np.array([f.shape[1] for f in surface.faces])[block]
    own = np.isin(width, list(CELL_NODES)) & (cells >= 0)
    K = int(width[own].max(initial=0))
    nodes = np.full((len(cells), K), -1, np.int64)
    shape = np.zeros((len(cells), 9, K))
    for b, f in enumerate(surface.faces):
        k = f.shape[1]
        sel = np.flatnonzero(own & (block == b))
        if not len(sel):
            continue
        nodes[sel, :k] = f[cells[sel] - starts[b]]
        shape[sel, :, :k] = cell_shape(k)
    return nodes, shape, own


def orientation(surface, cells) -> np.ndarray:
    """(e, 3) the side each cell's normal faces: its facet's normal (reversed: flipped)."""
    return (-1.0 if surface.flip else 1.0) * surface.facet_normal[cells]


def _elements(surface, points, rows, cells, xi, rigid_target, second, proj):
    """The part (rows, nodes, gap, N, M) of the penetrating `rows` on their `cells` at ξ;
    an element that cannot be computed (a degenerate cell: NaN) fails, and says so."""
    closed = proj.status[rows] == PENETRATION
    rows, cells, xi = rows[closed], cells[closed], xi[closed]
    if rigid_target:
        nodes, shape = np.zeros((len(rows), 0), np.int64), None
    else:
        nodes, shape, _ = node_cells(surface, cells)
    coef, orient = surface.cell_rows(cells), orientation(surface, cells)

    def build(i, second):
        with np.errstate(divide="ignore", invalid="ignore"):
            return cell_elements(coef[i], points[rows[i]], xi[i], orient[i],
                                 None if shape is None else shape[i], second)

    width = 3 * (nodes.shape[1] + 1)
    lazy = blocks.on_demand(len(rows), width, second)  # ℳ on demand past `HESSIAN_BYTES`
    gap, N, M = build(np.arange(len(rows)), second and not lazy)
    bad = ~np.isfinite(gap) | ~np.isfinite(N).all(axis=1)
    if M is not None:
        bad |= ~np.isfinite(M).all(axis=(1, 2))
    proj.status[rows[bad]], proj.reason[rows[bad]] = FAILED, ILL_CONDITIONED
    ok = np.flatnonzero(~bad)
    if lazy:
        M = blocks.Hessians(lambda idx, out: build(ok[idx], True)[2], len(ok), width)
    elif M is not None:
        M = M[ok]
    return rows[ok], nodes[ok], gap[ok], N[ok], M


def cell_part(surface, points, proj, rows, rigid_target, second):
    """The node-to-cell elements of the `rows` a PatchedSurface's curved cells answered
    (`element.patched_contact`): every one on a rigid target, those on second-order cells
    otherwise.

    Returns taken (r,) bool (the rows the cells keep: the rest get the node-to-facet
    element), cell (r,) int and the part (rows, nodes, gap, N, M) of the penetrating ones."""
    cell, xi = proj.cell[rows], proj.cell_param[rows]     # the pass's answer
    taken = cell >= 0
    if not rigid_target:
        taken &= node_cells(surface, cell)[2]
    part = _elements(surface, points, rows[taken], cell[taken], xi[taken], rigid_target,
                     second, proj)
    return taken, cell, part


def frozen_part(surface, points, rows, cells, proj, second):
    """A frozen pairing's node-to-cell elements: each row's closest point on its paired
    second-order cell (the pass's Newton, `_pass.frozen_cells`: from x^c's projection on its
    corners' plane, past the cell's edges as its polynomial goes); the projection's fields
    of `rows` are set."""
    if len(cells) and not (cells.min() >= 0 and cells.max() < len(surface.corners)
                           and node_cells(surface, cells)[2].all()):
        raise ValueError("the pairing names cells this surface does not have (source -3 "
                         "holds a second-order cell): pass the Contact.pairing of this "
                         "surface (or of one moved from it)")
    coef = surface.cell_rows(cells)
    x = points[rows]
    xi, ok = frozen_cells(coef, x)
    with np.errstate(divide="ignore", invalid="ignore"):
        gap, n, _ = cell_elements(coef, x, xi, orientation(surface, cells), None, False)
    ok &= np.isfinite(gap) & np.isfinite(n).all(axis=1)
    spacing = surface.node_spacing[surface.corners[cells, 0]]
    status = np.where(gap < 0, PENETRATION, OPEN)
    status[np.abs(gap) <= tol.CONTACT * spacing] = CONTACT
    status[~ok] = FAILED
    proj.gap[rows] = np.where(ok, gap, np.nan)
    proj.normal[rows] = np.where(ok[:, None], n, np.nan)
    proj.proximal_point[rows] = np.where(ok[:, None], evaluate(coef, xi)[0], np.nan)
    proj.status[rows] = status
    proj.reason[rows] = np.where(ok, OK, NO_CONVERGENCE)
    return _elements(surface, points, rows, cells, xi, False, second, proj)
