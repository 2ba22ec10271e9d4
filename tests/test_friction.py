"""Coulomb friction on a rigid target (issue 23, `diffsurf_cli.element.friction`): the
tangent against the residual's Taylor expansion in stick and in slip, full slip on a flat
target, the stick-slip transition, objectivity, and the history's round trip."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import Coulomb, FacetSurface, History, contact
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import CELLS, PatchedSurface
from diffsurf_cli.testing.shapes import Sphere

EPS = 1.0e3          # the normal penalty
R = 10.0             # the sphere's radius


def _sphere(kind="diffuse"):
    nodes, faces = Sphere(radius=R).mesh(12)
    if kind == "cells":  # its facets curved through their corner normals answer everywhere
        surf = PatchedSurface(nodes, [faces], feature_angle=None)
        surf.surfaces, surf._pass = [None], None
        return surf
    cls = DiffuseSurface if kind == "diffuse" else FacetSurface
    return cls(nodes, [faces])


def _plane(kind="diffuse"):
    """A flat square target z = 0, 21 x 21 nodes over [-10, 10]², triangles."""
    g = np.linspace(-10.0, 10.0, 21)
    X, Y = np.meshgrid(g, g, indexing="ij")
    nodes = np.column_stack([X.ravel(), Y.ravel(), np.zeros(X.size)])
    idx = np.arange(X.size).reshape(21, 21)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), \
        idx[:-1, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    cls = DiffuseSurface if kind == "diffuse" else FacetSurface
    return cls(nodes, [faces])


def _caps(m, rng, depth=0.05):
    """m contactors `depth` inside the sphere, around its top."""
    d = np.column_stack([rng.uniform(-0.4, 0.4, (m, 2)), np.ones(m)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (R - depth)


def _state(surface, x, friction, history):
    c = contact(surface, x, rigid_target=True, friction=friction, history=history)
    dofs = np.arange(3 * len(x)).reshape(-1, 3)
    return c, c.residual(EPS, dofs, n_dofs=3 * len(x)), c.tangent(EPS, dofs, n_dofs=3 * len(x))


def _slid(x0, k, slide, target):
    """x0 slid k times by `slide` along the target: along (2, 1, 0) on the plane, by the
    rotation of that arc about the sphere's centre (the depth stays)."""
    if target == "plane":
        return x0 + k * slide * np.array([1.0, 0.5, 0.0])
    a = k * slide / R
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    return x0 @ rot.T


def _history_after(surface, x0, slide, target, friction, steps=2):
    """The history after `steps` converged states: x0 slid 0, 1, ... times."""
    h = None
    for k in range(steps):
        c, _, _ = _state(surface, _slid(x0, k, slide, target), friction, h)
        h = c.history
    return h


@pytest.mark.parametrize("kind,target", [("diffuse", "sphere"), ("diffuse", "plane"),
                                         ("facet", "sphere"), ("facet", "plane"),
                                         ("cells", "sphere")])
@pytest.mark.parametrize("mu,slide", [(0.5, 1e-4), (20.0, 0.05), (0.2, 0.02), (0.05, 0.3)])
def test_tangent_is_the_residuals_derivative(kind, target, mu, slide):
    """R(x + h d) − R(x) − h K d falls as h² (stick for the small slides, slip for the large
    one), on a curved and a flat target, diffuse, faceted and on curved cells (the
    node-to-cell element, `element.cell`); and friction's own part of K is its part of R's
    central difference to 1e-6."""
    rng = np.random.default_rng(4)
    surface = _sphere(kind) if target == "sphere" else _plane(kind)
    x0 = _caps(12, rng) if target == "sphere" else np.column_stack(
        [rng.uniform(-3, 3, (12, 2)), np.full(12, -0.05)])
    friction = Coulomb(mu, penalty_t=2.0 * EPS)
    h = _history_after(surface, x0, slide, target, friction)
    x = _slid(x0, 2, slide, target)
    c, r0, K = _state(surface, x, friction, h)
    assert len(c) == 12
    if kind == "cells":
        assert (c.projection.source == CELLS).all()
    stick = c.tractions(EPS).stick
    if mu > 0.4:
        assert stick.all()
    elif slide > 0.1:
        assert not stick.any()
    assert np.abs(c.tractions(EPS).tangential).max() > 0
    d = rng.normal(size=x.shape)
    rem = []
    steps = [1e-3, 5e-4, 2.5e-4]
    for t in steps:
        _, r, _ = _state(surface, x + t * d, friction, h)
        rem.append(np.linalg.norm(r - r0 - t * (K @ d.ravel())))
    # second order, or round-off where R is linear in x (stick on a flat facet)
    floor = 1e-8 * steps[-1] * np.linalg.norm(K @ d.ravel())
    order = np.log2(rem[0] / rem[1]), np.log2(rem[1] / rem[2])
    assert min(order) > 1.8 or max(rem) < floor, (rem, order, floor)
    # friction's own part: (K − K0) d against the central difference of R − R0, where the
    # curvature terms of the trial (ν·a H, ν (H a)ᵀ) weigh more than in all of K
    _, r0_free, K0 = _state(surface, x, None, None)
    assert abs(K - K0).max() > 1e-3 * abs(K0).max()
    step = 1e-6
    (_, rp, _), (_, rm, _) = (_state(surface, x + t * d, friction, h) for t in (step, -step))
    (_, rp0, _), (_, rm0, _) = (_state(surface, x + t * d, None, None) for t in (step, -step))
    exact = (K - K0) @ d.ravel()
    central = ((rp - rp0) - (rm - rm0)) / (2 * step)
    assert np.linalg.norm(central - exact) <= 1e-6 * np.linalg.norm(exact)


def test_full_slip_on_a_flat_target_is_coulomb():
    """A block of contactors slid far on a flat target slips everywhere: |F_T| = μ |F_N| to
    round-off, F_T along −(the slide) in the plane."""
    surface = _plane()
    rng = np.random.default_rng(1)
    x0 = np.column_stack([rng.uniform(-3, 3, (50, 2)), rng.uniform(-0.1, -0.01, 50)])
    friction = Coulomb(0.3)
    slide = np.array([0.6, -0.8, 0.0])
    h = None
    for k in range(2):
        c = contact(surface, x0 + k * slide, rigid_target=True, friction=friction, history=h)
        c.residual(EPS, np.arange(150).reshape(50, 3))
        h = c.history
    c = contact(surface, x0 + 2 * slide, rigid_target=True, friction=friction, history=h)
    t = c.tractions(EPS)
    assert len(c) == 50 and not t.stick.any()
    size = np.linalg.norm(t.tangential, axis=1)
    np.testing.assert_allclose(size, 0.3 * t.normal, rtol=1e-12)
    np.testing.assert_allclose(t.normal, EPS * np.abs(x0[:, 2]), rtol=1e-12)
    np.testing.assert_allclose(t.tangential / size[:, None],
                               np.broadcast_to(-slide, (50, 3)), atol=1e-12)


def test_stick_then_slip():
    """One contactor pushed along a flat target in small steps: the tangential force grows as
    ε_T times the displacement while it sticks, then stays at μ ε |g| as it slips."""
    surface = _plane()
    mu, eps_t, depth = 0.2, 4.0 * EPS, 0.05
    friction = Coulomb(mu, penalty_t=eps_t)
    limit = mu * EPS * depth
    du = 0.1 * limit / eps_t
    h, forces, sticks = None, [], []
    for k in range(25):
        x = np.array([[0.3 + k * du, 0.2, -depth]])
        c = contact(surface, x, rigid_target=True, friction=friction, history=h)
        t = c.tractions(EPS)
        forces.append(t.tangential[0, 0])
        sticks.append(t.stick[0])
        h = c.history
    forces, sticks = -np.array(forces), np.array(sticks)
    u = du * np.arange(25)
    assert sticks[:10].all() and not sticks[11:].any()
    np.testing.assert_allclose(forces[:10], eps_t * u[:10], rtol=1e-9, atol=1e-12 * limit)
    np.testing.assert_allclose(forces[11:], limit, rtol=1e-12)


def test_objectivity():
    """A rigid rotation of the whole scene (target, contactors, history) rotates the
    tractions."""
    rng = np.random.default_rng(2)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    nodes, faces = Sphere(radius=R).mesh(12)
    friction = Coulomb(0.2, penalty_t=EPS)
    x0 = _caps(20, rng)
    shift = np.array([0.01, 0.02, 0.0])
    out = []
    for rot in (np.eye(3), Q):
        surface = DiffuseSurface(nodes @ rot.T, [faces])
        h = None
        for k in range(3):
            c = contact(surface, (x0 + k * shift) @ rot.T, rigid_target=True,
                        friction=friction, history=h)
            t = c.tractions(EPS)
            h = c.history
        out.append(t)
    a, b = out
    assert np.abs(a.tangential).max() > 1e-3 * a.normal.max()
    np.testing.assert_array_equal(a.stick, b.stick)
    np.testing.assert_allclose(b.normal, a.normal, rtol=1e-8)
    np.testing.assert_allclose(b.tangential, a.tangential @ Q.T,
                               atol=1e-8 * np.abs(a.tangential).max())


def test_history_round_trips(tmp_path):
    """Stopping a slide, saving the history, and restarting from the file gives the same
    forces, bit for bit."""
    surface = _sphere()
    rng = np.random.default_rng(3)
    x0 = _caps(30, rng)
    friction = Coulomb(0.1)
    shift = np.array([0.02, -0.01, 0.0])

    def slide(h, ks):
        forces = []
        for k in ks:
            c = contact(surface, x0 + k * shift, rigid_target=True, friction=friction,
                        history=h)
            forces.append(c.tractions(EPS).tangential)
            h = c.history
        return forces, h

    whole, _ = slide(None, range(6))
    first, h = slide(None, range(3))
    np.savez(tmp_path / "h.npz", proximal_point=h.proximal_point, traction=h.traction)
    saved = np.load(tmp_path / "h.npz")
    rest, _ = slide(History(saved["proximal_point"], saved["traction"]), range(3, 6))
    for a, b in zip(whole, first + rest):
        np.testing.assert_array_equal(a, b)
    assert np.abs(whole[-1]).max() > 0


def test_friction_refuses_what_it_cannot_do():
    surface = _sphere()
    x = _caps(3, np.random.default_rng(0))
    rigid_history = contact(surface, x, rigid_target=True, friction=Coulomb(0.2))
    rigid_history.residual(EPS, np.arange(9).reshape(3, 3))
    with pytest.raises(ValueError, match=r"history: taken on a rigid target \(no nodes\)"):
        contact(surface, x, friction=Coulomb(0.2), history=rigid_history.history)
    with pytest.raises(ValueError, match="friction=Coulomb"):
        contact(surface, x, rigid_target=True,
                history=History(np.zeros((3, 3)), np.zeros((3, 3))))
    with pytest.raises(ValueError, match=r"history.proximal_point: expected shape \(3, 3\)"):
        contact(surface, x, rigid_target=True, friction=Coulomb(0.2),
                history=History(np.zeros((2, 3)), np.zeros((3, 3))))
    with pytest.raises(ValueError, match="mu"):
        Coulomb(-1.0)
    c = contact(surface, x, rigid_target=True, friction=Coulomb(0.2))
    with pytest.raises(ValueError, match="penalty"):
        _ = c.history
    c = contact(surface, x, rigid_target=True, friction=Coulomb(0.2, penalty_t=np.ones(2)))
    with pytest.raises(ValueError, match=r"^Coulomb.penalty_t: expected a number or one per "
                                         r"contactor \(3,\), got shape \(2,\)$"):
        c.residual(EPS, np.arange(9).reshape(3, 3))


def test_a_patched_target_slides_as_its_patch():
    """On a PatchedSurface (what `surface_from_file` builds), friction acts on each contactor
    through what answered it, and the tangent is still the residual's derivative."""
    from diffsurf_cli import surface_from_file
    from samples import CYLINDER

    _, surface = surface_from_file(CYLINDER)
    assert type(surface).__name__ == "PatchedSurface"
    t = np.radians(np.linspace(255, 285, 7))
    r = 10.0 - np.linspace(0.02, 0.08, 7)  # limits μ ε |g| from 6 to 24
    x0 = np.column_stack([32.5 + r * np.cos(t), 30 + r * np.sin(t), np.full(7, 2.0)])
    friction, h = Coulomb(0.3, penalty_t=5 * EPS), None
    for k in range(3):  # 0.001 a step along the axis: ε_T times it, 5 a step
        c, _, _ = _state(surface, x0 + [0.0, 0.0, 0.001 * k], friction, h)
        h = c.history
    x = x0 + [0.0, 0.0, 0.003]
    c, r0, K = _state(surface, x, friction, h)
    stick = c.tractions(EPS).stick
    assert len(c) == 7 and stick.any() and not stick.all(), stick
    d = np.random.default_rng(5).normal(size=x.shape)
    rem = [np.linalg.norm(_state(surface, x + s * d, friction, h)[1] - r0 - s * (K @ d.ravel()))
           for s in (1e-4, 5e-5)]
    assert np.log2(rem[0] / rem[1]) > 1.8, rem
