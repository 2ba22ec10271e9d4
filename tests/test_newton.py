"""A Newton solve in miniature of the paper's example (§5): contactor nodes tied by linear
springs (stiffness k_s) to prescribed positions, pressed into the rigid faceted half cylinder of
sample_meshes/cylinder.msh and slid around it.

Unknowns: the contactor positions x (the target is rigid). Total energy
Π(x) = Σ ½ k_s |x_i - y_i|² + Σ ε g_i²/2 over the closed contacts; Newton:
(k_s I + K_cc) Δx = -(k_s (x - y) + R_c), R_c and K_cc the contactor block of the assembled
residual and tangent of `contact(...)`, recomputed every iteration.

What is exact, and so converges quadratically:
- node-to-facet: the pairing (facet) is searched again each iteration (it is locally constant);
- diffuse, global frame: pairing searched again each iteration (support set and R are locally
  constant in x^c, the frame is the one mean plane);
- diffuse, local (PCA) frames: the frame of each contactor depends smoothly on where it is, and
  the element holds it fixed (the paper's decision, docs/element.md), so the pairing is frozen
  within the Newton loop of a step (searched at the step's start) and Newton is exact on that
  function.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import io
from diffsurf_cli.element.element import contact
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import corner_faces
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import CELLS, PatchedSurface
from samples import CYLINDER

AXIS = np.array([32.5, 30.0])  # the cylinder's axis (along z), radius 10 mm
RADIUS = 10.0
#: Contactor row along z, away from the planes z = 0, 2.5, 5 of the facets' edges.
ZS = np.array([0.6, 1.25, 3.75, 4.4])
DEPTH = 0.5  # mm inside the exact cylinder
KS = 1.0
PENALTY = 30.0 * KS
FORCE = KS * DEPTH  # force scale of one contactor


def _target():
    tgt = io.read_target(CYLINDER)
    nodes = tgt.points[tgt.nodes]
    faces = [np.searchsorted(tgt.nodes, f) for f in corner_faces(tgt.cells)]
    return nodes, faces


def prescribed(theta_deg):
    """The row's prescribed positions: DEPTH inside the exact cylinder, at angle θ."""
    t = np.radians(theta_deg)
    r = RADIUS - DEPTH
    one = np.ones_like(ZS)
    return np.column_stack([AXIS[0] + r * np.cos(t) * one, AXIS[1] + r * np.sin(t) * one, ZS])


def newton(surf, y, x0, freeze=False, tol=1e-11, maxit=30, rigid=False):
    """Solve k_s (x - y) + R_c(x) = 0; returns x, residual norms, the last Contact. `rigid`:
    the rigid target's element (else the full one's contactor block)."""
    n = len(y)
    dofs = np.arange(3 * n).reshape(n, 3)
    x = x0.copy()
    history, pairing = [], None
    for _ in range(maxit):
        c = contact(surf, x, pairing=pairing, rigid_target=rigid)
        if freeze and pairing is None:
            pairing = c.projection.patch
        R = c.residual(PENALTY, dofs)  # the target is fixed: no target DOFs
        K = c.tangent(PENALTY, dofs).toarray()
        r = KS * (x - y).ravel() + R
        history.append(float(np.linalg.norm(r)))
        if history[-1] <= tol * FORCE:
            break
        x = x + np.linalg.solve(KS * np.eye(3 * n) + K, -r).reshape(n, 3)
    return x, np.array(history), c


def check_quadratic(history, label):
    """Quadratic convergence near the solution.

    - r_{k+1} <= C r_k² (C = 10 / FORCE) once r_k is below 0.1 FORCE;
    - where three residuals in that region are above round-off, the order estimated from the
      last three, log(r_{k+1}/r_k) / log(r_k/r_{k-1}), is >= 1.8.
    """
    floor = 1e-12 * FORCE
    near = np.flatnonzero(history <= 0.1 * FORCE)
    assert len(near), f"{label}: never got near the solution: {history}"
    for k in near[:-1]:
        if history[k + 1] > floor:
            assert history[k + 1] <= 10.0 / FORCE * history[k] ** 2, f"{label}: {history}"
    tail = [k for k in near if history[k] > floor]
    if len(tail) >= 3:
        r0, r1, r2 = history[tail[-3:]]
        order = np.log(r2 / r1) / np.log(r1 / r0)
        assert order >= 1.8, f"{label}: order {order:.2f}: {history}"
    return len(tail)


def _cells(nodes, faces):
    """The facets curved through their corner normals (`element.cell`) answering everywhere:
    a PatchedSurface whose one patch carries no diffuse surface (as test_cells.py)."""
    surf = PatchedSurface(nodes, faces, feature_angle=None)
    surf.surfaces = [None]
    surf._pass = None
    return surf


SCHEMES = {
    "facet": (lambda n, f: FacetSurface(n, f), False),
    "diffuse-global": (lambda n, f: DiffuseSurface(n, f, frame="global"), False),
    "diffuse-local-frozen": (lambda n, f: DiffuseSurface(n, f), True),
}


@pytest.mark.parametrize("scheme", list(SCHEMES))
def test_newton_slide_converges_quadratically(scheme):
    make, freeze = SCHEMES[scheme]
    nodes, faces = _target()
    surf = make(nodes, faces)
    if scheme.startswith("diffuse"):
        assert surf.frame == ("global" if scheme == "diffuse-global" else "local")
    x = prescribed(255.0)
    orders_checked = 0
    forces = []
    for theta in np.arange(255.0, 286.0, 3.75):  # 3 facets of 11.25°, 9 positions
        y = prescribed(theta)
        x, history, c = newton(surf, y, x, freeze=freeze)
        label = f"{scheme} θ={theta}"
        assert history[-1] <= 1e-11 * FORCE, f"{label}: no convergence: {history}"
        assert len(history) - 1 <= 8, f"{label}: {len(history) - 1} iterations: {history}"
        orders_checked += check_quadratic(history, label) >= 3
        # every contactor is in contact, pushed back out to a small penetration
        gap = c.projection.gap
        assert np.all(c.projection.status == 2), label
        assert np.all((gap < 0) & (gap > -2 * DEPTH * KS / PENALTY)), (label, gap)
        # equilibrium: the contact force balances the springs
        force = -c.residual(PENALTY, np.arange(3 * len(y)).reshape(-1, 3))
        assert np.allclose(force.reshape(-1, 3), KS * (x - y), atol=1e-10)
        t = np.radians(theta)
        forces.append(force.reshape(-1, 3).sum(0) @ np.array([np.cos(t), np.sin(t), 0.0]))
    forces = np.array(forces)
    # the force pushes the row back out of the cylinder (radially outwards), about k_s DEPTH each
    assert np.all(forces > 0)
    assert np.allclose(forces, len(ZS) * KS * DEPTH * PENALTY / (KS + PENALTY), rtol=0.1)
    if scheme.startswith("diffuse"):
        # the surface is curved: Newton takes several iterations, and the order was measured
        assert orders_checked >= 3, scheme


def test_facet_newton_is_exact_in_one_step_on_a_facet():
    """Planar facet and rigid target: g is affine in x^c, Π is quadratic, one Newton step."""
    nodes, faces = _target()
    surf = FacetSurface(nodes, faces)
    y = prescribed(264.0)  # inside the facet 258.75°..270°
    x, history, _ = newton(surf, y, y)
    assert len(history) == 2 and history[-1] <= 1e-11 * FORCE, history


@pytest.mark.slow
def test_diffuse_smooth_force_facet_jumps():
    """Sliding across a facet edge (θ = 270°), the facet force's direction jumps (when the
    contactors cross the bisector of the two facets, a little after the edge because the force
    holds them back); the diffuse force turns smoothly with θ."""
    nodes, faces = _target()
    thetas = np.arange(268.0, 272.01, 0.25)
    jumps = {}
    for name, surf in (("facet", FacetSurface(nodes, faces)),
                       ("diffuse", DiffuseSurface(nodes, faces, frame="global"))):
        tangential = []
        x = prescribed(thetas[0])
        for theta in thetas:
            y = prescribed(theta)
            x, history, c = newton(surf, y, x)
            assert history[-1] <= 1e-11 * FORCE, (name, theta, history)
            f = -c.residual(PENALTY, np.arange(3 * len(y)).reshape(-1, 3))
            t = np.radians(theta)
            tangential.append(f.reshape(-1, 3).sum(0) @ np.array([-np.sin(t), np.cos(t), 0.0]))
        jumps[name] = np.abs(np.diff(tangential)).max()
    total = len(ZS) * KS * DEPTH * PENALTY / (KS + PENALTY)
    # facet: the normal turns by 11.25° at once, the tangential force jumps by about
    # 2 sin(5.6°) ≈ 0.2 of the total; diffuse: it changes by a fraction of a percent per step
    assert jumps["facet"] > 0.1 * total, jumps
    assert jumps["diffuse"] < 0.01 * total, jumps


def test_rigid_cells_newton_converges_quadratically_and_turns_smoothly():
    """The node-to-cell element (`element.cell`) of the rigid target, on the cylinder's
    facets curved through their corner normals (the cells answer every contactor): sliding
    across the facet edge at θ = 270° in steps small enough to keep contact, Newton
    converges quadratically at every position (its exact tangent), and the force turns with
    θ where the facets' jumps by a fifth of itself (test_diffuse_smooth_force_facet_jumps)."""
    nodes, faces = _target()
    surf = _cells(nodes, faces)
    thetas = np.arange(266.0, 274.01, 0.5)
    x = prescribed(thetas[0])
    x, _, _ = newton(surf, x, x, rigid=True)
    tangential, orders = [], 0
    for theta in thetas:
        y = prescribed(theta)
        force = np.zeros(3)
        for i in range(len(y)):  # the contactors are independent: one residual history each
            x[i:i + 1], history, c = newton(surf, y[i:i + 1], x[i:i + 1], rigid=True)
            label = f"cells θ={theta} z={ZS[i]}"
            assert (c.projection.source == CELLS).all(), label
            assert history[-1] <= 1e-11 * FORCE and len(history) - 1 <= 6, (label, history)
            # quadratic: r_{k+1} <= C r_k² near the solution (check_quadratic's bound; its
            # three-point order estimate does not apply: the stiff normal (ε) and soft
            # tangential (k_s) errors converge with constants 30x apart, so the last three
            # residuals mix two quadratic sequences)
            near = np.flatnonzero(history <= 0.1 * FORCE)
            for k in near[:-1]:
                if history[k + 1] > 1e-12 * FORCE:
                    assert history[k + 1] <= 10.0 / FORCE * history[k] ** 2, (label, history)
                    orders += 1
            force -= c.residual(PENALTY, np.arange(3).reshape(1, 3))
        t = np.radians(theta)
        tangential.append(force @ np.array([-np.sin(t), np.cos(t), 0.0]))
    assert orders >= 2 * len(thetas), orders  # two quadratic steps checked a position
    total = len(ZS) * KS * DEPTH * PENALTY / (KS + PENALTY)
    assert np.abs(np.diff(tangential)).max() < 0.01 * total, tangential
