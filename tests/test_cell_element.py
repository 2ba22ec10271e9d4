"""The node-to-cell element (`diffsurf_cli.element.cell`): the contact element on a target's
curved cell, where the cells answer the projection (issue 19).

- 𝒩 and ℳ are the jet oracle's (tests/oracle_element.py `cell_element`: exact forward-mode
  derivatives, ∂ξ̄/∂u by the implicit function theorem) to round-off, on random triangle6,
  triangle7, quad8 and quad9 cells, contactors on both sides, either orientation; the cells'
  shape functions are the textbooks';
- they are derivatives: Taylor remainders fall as h² and h³ when the contactor and the cell's
  nodes move (the closest point re-solved on the moved cell), and, for a rigid target, when
  the contactor alone moves; the rigid element is the full one's x^c block;
- the rigid ℳ = ∂ν/∂x^c is the closed form where the cell is its shape exactly (a flat
  cell, a parabola's vertex).

Contactors stay within a fraction of the cells' radius of curvature: past its centre the
closest point is no longer a strict minimum (A = G - g H singular), and no element is.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli.element import cell
from diffsurf_cli.patches._pass import frozen_cells
from diffsurf_cli.patches.surface import CELL_MONOMIALS, CELL_NODES, cell_shape
from oracle_element import cell_element
from test_element import _taylor

UP = np.array([0.0, 0.0, 1.0])


def _textbook(k, a, b):
    """(s, k) the shape functions of a cell of k nodes (`CELL_NODES` order) at (a, b), as
    the textbooks write them: barycentric for triangle6 and triangle7 (its bubble 27 λ1λ2λ3),
    serendipity for quad8, tensor Lagrange for quad9."""
    if k in (6, 7):
        l1, l2, l3 = 1 - a - b, a, b
        bub = l1 * l2 * l3 if k == 7 else 0 * a
        N = [l1 * (2 * l1 - 1) + 3 * bub, l2 * (2 * l2 - 1) + 3 * bub,
             l3 * (2 * l3 - 1) + 3 * bub, 4 * l1 * l2 - 12 * bub, 4 * l2 * l3 - 12 * bub,
             4 * l3 * l1 - 12 * bub]
        return np.stack(N + [27 * bub] if k == 7 else N, axis=1)
    pts = np.array(CELL_NODES[k], float)
    if k == 9:
        def lagrange(t, at):
            return {0.0: 2 * (t - .5) * (t - 1), 0.5: -4 * t * (t - 1), 1.0: 2 * t * (t - .5)}[at]
        return np.stack([lagrange(a, x) * lagrange(b, y) for x, y in pts], axis=1)
    xi, eta = 2 * a - 1, 2 * b - 1
    out = []
    for x, y in 2 * pts - 1:
        if x and y:
            out.append(0.25 * (1 + xi * x) * (1 + eta * y) * (xi * x + eta * y - 1))
        elif x == 0:
            out.append(0.5 * (1 - xi ** 2) * (1 + eta * y))
        else:
            out.append(0.5 * (1 + xi * x) * (1 - eta ** 2))
    return np.stack(out, axis=1)


@pytest.mark.parametrize("k", [6, 7, 8, 9])
def test_cell_shape_functions_are_the_textbook_ones(k):
    """`cell_shape`'s monomial coefficients give the textbook shape functions everywhere in
    the cell (triangle7: the quadratics and its cubic bubble)."""
    a, b = np.random.default_rng(k).uniform(0, 1, (2, 200))
    if k in (6, 7):
        a, b = a[a + b <= 1], b[a + b <= 1]
    mono = np.stack([a ** i * b ** j for i, j in CELL_MONOMIALS], axis=1)
    np.testing.assert_allclose(mono @ cell_shape(k), _textbook(k, a, b), rtol=0, atol=1e-13)


def _cell(k, rng, bend=0.15):
    """A curved cell of k nodes over the unit triangle or square, its nodes jittered."""
    X = np.column_stack([np.array(CELL_NODES[k], float), bend * rng.standard_normal(k)])
    return X + 0.03 * rng.standard_normal(X.shape)


def _solve(W, X, xc):
    """The closest point of xc on the cell of nodes X, as a frozen pairing finds it."""
    coef = (W @ X)[None]
    xi, ok = frozen_cells(coef, np.asarray(xc)[None])
    return coef, xi, bool(ok[0])


@pytest.mark.parametrize("k", [6, 7, 8, 9])
@pytest.mark.parametrize("side", [0.12, -0.1])
@pytest.mark.parametrize("orient", [1.0, -1.0])
def test_node_to_cell_element_is_the_jet_oracle(k, side, orient):
    rng = np.random.default_rng(k + 10 * int(side > 0) + 100 * int(orient > 0))
    W = cell_shape(k)
    for _ in range(4):
        X = _cell(k, rng)
        xc = np.array([*rng.uniform(0.15, 0.4, 2), side])
        coef, xi, ok = _solve(W, X, xc)
        a, b = xi[0]
        assert ok and min(a, b) > 0 and (a + b < 1 if k in (6, 7) else max(a, b) < 1)
        g, N, M = cell.cell_elements(coef, xc[None], xi, orient * UP[None], W[None])
        g0, N0, M0 = cell_element(W, X, xc, xi[0], orient * UP)
        scale = np.abs(M0).max()
        assert g[0] == pytest.approx(g0, abs=1e-14)
        np.testing.assert_allclose(N[0], N0, rtol=0, atol=1e-13)
        np.testing.assert_allclose(M[0], M0, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(M[0], M[0].T, rtol=0, atol=1e-14 * scale)
        # the rigid target's element is the full one's contactor block
        gr, Nr, Mr = cell.cell_elements(coef, xc[None], xi, orient * UP[None])
        assert gr[0] == g[0]
        np.testing.assert_allclose(Nr[0], N[0, :3], rtol=0, atol=1e-15)
        np.testing.assert_allclose(Mr[0], M[0, :3, :3], rtol=0, atol=1e-13 * scale)
        # and second=False gives the same gap and 𝒩 without ℳ
        g2, N2, M2 = cell.cell_elements(coef, xc[None], xi, orient * UP[None], W[None], False)
        assert M2 is None and g2[0] == g[0] and np.array_equal(N2, N)


@pytest.mark.parametrize("k", [6, 7, 8, 9])
def test_node_to_cell_element_derivatives(k):
    """Taylor: the contactor and the cell's nodes move, the closest point is re-solved on the
    moved cell (full element); the contactor alone (rigid target)."""
    rng = np.random.default_rng(40 + k)
    W = cell_shape(k)
    X = _cell(k, rng)
    xc = np.array([0.35, 0.3, -0.2])
    coef, xi, ok = _solve(W, X, xc)
    assert ok
    g, N, M = cell.cell_elements(coef, xc[None], xi, UP[None], W[None])

    def full(u):
        c2, x2, ok2 = _solve(W, u[3:].reshape(k, 3), u[:3])
        if not ok2:
            return None
        g2, N2, _ = cell.cell_elements(c2, u[None, :3], x2, UP[None], W[None], False)
        return g2[0], N2[0]

    u = np.concatenate([xc, X.ravel()])
    _taylor(full, u, g[0], N[0], M[0], 1.0, rng, f"cell{k}/full")

    gr, Nr, Mr = cell.cell_elements(coef, xc[None], xi, UP[None])

    def rigid(x):
        c2, x2, ok2 = _solve(W, X, x)
        g2, N2, _ = cell.cell_elements(c2, x[None], x2, UP[None], None, False)
        return (g2[0], N2[0]) if ok2 else None

    _taylor(rigid, xc, gr[0], Nr[0], Mr[0], 1.0, rng, f"cell{k}/rigid")


def test_rigid_cell_element_in_closed_form():
    """Where the cell is its shape exactly: a flat quad9 (𝒩 = e_z, ℳ = 0) and the parabola
    z = c a² (a cylinder's section to second order), at its vertex: ν = e_z, the surface bends
    towards ν (H = 2c), so ℳ = -Y G⁻¹ H (G - g H)⁻¹ Yᵀ = -2c / (1 - 2c g) along e_x, 0 along
    the straight direction and ν."""
    W = cell_shape(9)
    P = np.array(CELL_NODES[9], float)
    flat = np.column_stack([2.0 * P, np.zeros(9)])
    xc = np.array([0.7, 1.1, -0.3])
    coef, xi, ok = _solve(W, flat, xc)
    g, N, M = cell.cell_elements(coef, xc[None], xi, UP[None])
    assert ok and g[0] == pytest.approx(-0.3, abs=1e-15)
    np.testing.assert_allclose(N[0], UP, atol=1e-15)
    np.testing.assert_allclose(M[0], 0.0, atol=1e-14)
    c = 0.4
    shifted = P - 0.5                       # a in [-0.5, 0.5]: the parabola's vertex inside
    para = np.column_stack([shifted, c * shifted[:, 0] ** 2])
    for gap in (0.3, -0.2):
        xc = np.array([0.0, 0.1, gap])
        coef, xi, ok = _solve(W, para, xc)
        g, N, M = cell.cell_elements(coef, xc[None], xi, UP[None])
        assert ok and xi[0, 0] == pytest.approx(0.5, abs=1e-12)
        assert g[0] == pytest.approx(gap, abs=1e-14)
        # the curvature of z = c a² at its vertex is 2c, its centre above (towards +z)
        expected = np.zeros((3, 3))
        expected[0, 0] = -2 * c / (1 - 2 * c * gap)
        np.testing.assert_allclose(M[0], expected, atol=1e-13)


def test_a_contactor_at_the_centre_of_curvature_gets_nan_not_an_exception():
    """At the parabola's centre of curvature (g = 1 / 2c) A = G - g H is singular: that
    row's ℳ is NaN (its contactor then fails, `element.cell._elements`), the others'
    are computed, and nothing raises."""
    W = cell_shape(9)
    P = np.array(CELL_NODES[9], float) - 0.5
    c = 0.4
    para = np.column_stack([P, c * P[:, 0] ** 2])
    coef = np.repeat((W @ para)[None], 2, axis=0)
    xc = np.array([[0.0, 0.1, 1 / (2 * c)], [0.0, 0.1, 0.3]])
    xi = np.full((2, 2), 0.5)
    for shape in (None, np.repeat(W[None], 2, axis=0)):
        g, N, M = cell.cell_elements(coef, xc, xi, np.repeat(UP[None], 2, axis=0), shape)
        assert np.isfinite(g).all() and np.isfinite(N).all()
        assert not np.isfinite(M[0]).all() and np.isfinite(M[1]).all()
