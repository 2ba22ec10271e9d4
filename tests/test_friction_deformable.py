"""Coulomb friction on a deformable target (issue 33, item 2; `element.friction`): the full
element's tangent against the residual's Taylor expansion over the contactors' and the target
nodes' DOFs, in stick and in slip, on curved and flat targets (diffuse, faceted, the default
patched surface), with and without an augmented Lagrangian's multipliers; forces balanced;
full slip on Coulomb's cone; the rigid target's law where the target does not move;
objectivity; the history's round trip; and what is refused."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import Contact, Coulomb, FacetSurface, History, build_surface, contact
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.testing.shapes import Plane, Sphere

EPS = 1.0e3          # the normal penalty
R = 10.0             # the sphere's radius


def _target(kind, shape):
    if shape == "sphere":
        nodes, faces = Sphere(radius=R).mesh(12)
    else:  # a flat square z = 0, 21 x 21 nodes over [-10, 10]², triangles
        nodes, faces = Plane(size=10.0).mesh(20)
    if kind == "patched":  # the default surface (`diffsurf project`'s): patches and guard
        return build_surface(nodes, [faces])
    return (DiffuseSurface if kind == "diffuse" else FacetSurface)(nodes, [faces])


class Scene:
    """m contactors pressed into a target whose nodes move and deform from step to step, slid
    along it; the global DOFs: contactors first, then the target's nodes."""

    def __init__(self, kind, shape, m=12, seed=4):
        self.base = _target(kind, shape)
        self.shape = shape
        self.nodes = np.asarray(self.base.nodes, dtype=np.float64)
        rng = np.random.default_rng(seed)
        if shape == "sphere":
            d = np.column_stack([rng.uniform(-0.4, 0.4, (m, 2)), np.ones(m)])
            self.x0 = d / np.linalg.norm(d, axis=1, keepdims=True) * (R - 0.05)
        else:
            self.x0 = np.column_stack([rng.uniform(-3, 3, (m, 2)), np.full(m, -0.05)])
        n = len(self.nodes)
        self.cd = np.arange(3 * m).reshape(m, 3)
        self.td = 3 * m + np.arange(3 * n).reshape(n, 3)
        self.size = 3 * (m + n)

    def target(self, k, extra=0.0):
        """The target's nodes at step k: translated and deformed a little each step."""
        return (self.nodes + k * np.array([0.003, -0.002, 0.0]) + k * 1e-3 * np.sin(self.nodes)
                + extra)

    def contactors(self, k, slide):
        if self.shape == "plane":
            return self.x0 + k * slide * np.array([1.0, 0.5, 0.0])
        a = k * slide / R
        rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0],
                        [-np.sin(a), 0.0, np.cos(a)]])
        return self.x0 @ rot.T

    def state(self, X, x, friction, history, pairing=None, multipliers=None, near=0.0):
        c = contact(self.base.moved(X), x, friction=friction, history=history,
                    pairing=pairing, near=near)
        r = c.residual(EPS, self.cd, self.td, self.size, multipliers=multipliers)
        return c, r

    def history(self, friction, slide, steps=2):
        h = None
        for k in range(steps):
            c, _ = self.state(self.target(k), self.contactors(k, slide), friction, h)
            h = c.history
        return h


def _taylor(residual, r0, K, du, steps=(1e-3, 5e-4, 2.5e-4)):
    rem = [np.linalg.norm(residual(s) - r0 - s * (K @ du)) for s in steps]
    return [np.log2(rem[i] / rem[i + 1]) for i in range(len(rem) - 1)], rem


@pytest.mark.parametrize("kind,shape", [("diffuse", "sphere"), ("diffuse", "plane"),
                                        ("facet", "sphere"), ("facet", "plane"),
                                        ("patched", "sphere")])
@pytest.mark.parametrize("mu,slide", [(20.0, 1e-4), (0.2, 0.02)])
def test_tangent_is_the_residuals_derivative(kind, shape, mu, slide):
    """Over the contactors' and the target nodes' DOFs (frozen pairing, the target moved and
    deformed): R(u + h d) − R(u) − h K d falls as h², in stick (large μ) and slip; friction's
    own part of K against central differences to 1e-6; the forces balance."""
    s = Scene(kind, shape)
    friction = Coulomb(mu, penalty_t=2.0 * EPS)
    h = s.history(friction, slide)
    X, x = s.target(2), s.contactors(2, slide)
    c, r0 = s.state(X, x, friction, h)
    K = c.tangent(EPS, s.cd, s.td, s.size)
    assert len(c) == 12 and c.anchor is not None
    if kind == "patched":
        assert isinstance(s.base, PatchedSurface)
    t = c.tractions(EPS)
    assert t.stick.all() if mu > 1 else not t.stick.any(), t.stick
    assert np.abs(t.tangential).max() > 0
    # the forces on contactors and target nodes balance (Σ R = 0 per direction)
    assert np.abs(r0.reshape(-1, 3).sum(axis=0)).max() <= 1e-12 * np.abs(r0).max()
    rng = np.random.default_rng(5)
    dx, dX = rng.normal(size=x.shape), rng.normal(size=X.shape)
    du = np.concatenate([dx.ravel(), dX.ravel()])

    def residual(step, fr=friction, hist=h):
        return s.state(X + step * dX, x + step * dx, fr, hist, c.pairing)[1]

    order, rem = _taylor(residual, r0, K, du)
    floor = 1e-9 * np.linalg.norm(K @ du)  # stick on a flat target: R is linear in u
    assert min(order) > 1.8 or max(rem) < floor, (order, rem)
    # friction's own part against the central difference of its part of R
    K0 = contact(s.base.moved(X), x, pairing=c.pairing).tangent(EPS, s.cd, s.td, s.size)
    exact = (K - K0) @ du
    assert np.linalg.norm(exact) > 1e-3 * np.linalg.norm(K0 @ du)
    step = 1e-6

    def own(sign):
        free = s.state(X + sign * step * dX, x + sign * step * dx, None, None, c.pairing)[1]
        return residual(sign * step) - free

    central = (own(1) - own(-1)) / (2 * step)
    assert np.linalg.norm(central - exact) <= 1e-6 * np.linalg.norm(exact)


def test_full_slip_on_a_flat_target_is_coulomb_and_the_target_takes_the_reaction():
    """Contactors slid far on a flat deformable target slip everywhere: |F_T| = μ F_N to
    round-off, against the slide; the target's nodes take −F_T each, so the forces balance."""
    s = Scene("diffuse", "plane", m=50, seed=1)
    s.x0[:, 2] = np.random.default_rng(1).uniform(-0.1, -0.01, 50)
    friction = Coulomb(0.3)
    h = s.history(friction, 0.6)
    c, r = s.state(s.target(2), s.contactors(2, 0.6), friction, h)
    t = c.tractions(EPS)
    assert len(c) == 50 and not t.stick.any()
    size = np.linalg.norm(t.tangential, axis=1)
    np.testing.assert_allclose(size, 0.3 * t.normal, rtol=1e-12)
    assert (np.einsum("mi,i->m", t.tangential, [1.0, 0.5, 0.0]) < 0).all()
    on_contactors = r[:s.cd.size].reshape(-1, 3)
    on_target = r[s.cd.size:].reshape(-1, 3)
    np.testing.assert_allclose(on_target.sum(axis=0), -on_contactors.sum(axis=0),
                               atol=1e-10 * np.abs(on_contactors).sum())
    assert np.linalg.norm(on_target.sum(axis=0)[:2]) > 0.1 * 0.3 * t.normal.sum()


def test_on_a_target_that_does_not_move_it_is_the_rigid_targets_law():
    """Node-to-facet on a fixed flat target: the deformable element's tractions, step after
    step, are the rigid target's (the history point rides on nodes that stay)."""
    nodes = Scene("facet", "plane").nodes
    out = []
    for rigid in (True, False):
        s = Scene("facet", "plane", m=20, seed=3)
        friction, h, forces = Coulomb(0.2, penalty_t=3 * EPS), None, []
        for k in range(5):
            x = s.contactors(k, 0.004)
            c = contact(s.base.moved(nodes), x, friction=friction, history=h,
                        rigid_target=rigid) if not rigid else \
                contact(s.base, x, friction=friction, history=h, rigid_target=True)
            forces.append(c.tractions(EPS).tangential)
            h = c.history
        out.append(forces)
    assert np.abs(out[0][-1]).max() > 0
    for a, b in zip(*out):
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-10 * np.abs(out[0][-1]).max())


def test_objectivity():
    """A rigid rotation of the whole scene (target, contactors, history) rotates the
    tractions."""
    rng = np.random.default_rng(2)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    out = []
    for rot in (np.eye(3), Q):
        s = Scene("diffuse", "sphere", m=20, seed=6)
        s.base = DiffuseSurface(s.nodes @ rot.T, [Sphere(radius=R).mesh(12)[1]])
        friction, h = Coulomb(0.2, penalty_t=EPS), None
        for k in range(3):
            c = contact(s.base.moved(s.target(k) @ rot.T), s.contactors(k, 0.01) @ rot.T,
                        friction=friction, history=h)
            t = c.tractions(EPS)
            h = c.history
        out.append(t)
    a, b = out
    assert np.abs(a.tangential).max() > 1e-3 * a.normal.max()
    np.testing.assert_array_equal(a.stick, b.stick)
    np.testing.assert_allclose(b.tangential, a.tangential @ Q.T,
                               atol=1e-8 * np.abs(a.tangential).max())


def test_history_round_trips(tmp_path):
    """Saving a deformable target's history (its nodes, weights and positions too) and
    restarting from the file gives the same forces, bit for bit."""
    s = Scene("diffuse", "sphere", m=30, seed=3)
    friction = Coulomb(0.1)

    def slide(h, ks):
        forces = []
        for k in ks:
            c, _ = s.state(s.target(k), s.contactors(k, 0.02), friction, h)
            forces.append(c.tractions(EPS).tangential)
            h = c.history
        return forces, h

    whole, _ = slide(None, range(5))
    first, h = slide(None, range(2))
    assert h.anchored and (h.nodes >= 0).any()
    np.savez(tmp_path / "h.npz", **vars(h))
    rest, _ = slide(History(**np.load(tmp_path / "h.npz")), range(2, 5))
    for a, b in zip(whole, first + rest):
        np.testing.assert_array_equal(a, b)
    assert np.abs(whole[-1]).max() > 0


@pytest.mark.parametrize("mu,slide", [(20.0, 1e-4), (0.2, 0.05)])
def test_augmented_lagrangian_with_friction(mu, slide):
    """Multiplier vectors λ (m, 3) on a deformable target: the cone's radius μ |p| with
    p = min(0, λ·ν + ε g), the trial from λ; Taylor over all DOFs in stick and slip."""
    s = Scene("diffuse", "sphere")
    friction = Coulomb(mu, penalty_t=2.0 * EPS)
    c0, _ = s.state(s.target(0), s.contactors(0, slide), friction, None)
    lam = c0.multipliers(EPS)
    c0.residual(EPS, s.cd, s.td, s.size, multipliers=lam)
    h = c0.history
    lam = lam + np.random.default_rng(7).normal(scale=1.0, size=lam.shape)
    near = Contact.reach(EPS, lam)
    X, x = s.target(1), s.contactors(1, slide)
    c, r0 = s.state(X, x, friction, h, multipliers=lam, near=near)
    t = c.tractions(EPS, lam)
    assert t.stick.all() if mu > 1 else not t.stick.any(), t.stick
    if mu < 1:
        np.testing.assert_allclose(np.linalg.norm(t.tangential, axis=1), mu * t.normal,
                                   rtol=1e-12)
    K = c.tangent(EPS, s.cd, s.td, s.size, multipliers=lam)
    rng = np.random.default_rng(8)
    dx, dX = rng.normal(size=x.shape), rng.normal(size=X.shape)

    def residual(step):
        return s.state(X + step * dX, x + step * dx, friction, h, c.pairing, lam, near)[1]

    order, rem = _taylor(residual, r0, K, np.concatenate([dx.ravel(), dX.ravel()]))
    assert min(order) > 1.8, (order, rem)
    nxt = c.multipliers(EPS, lam)
    assert nxt.shape == (len(x), 3) and np.abs(nxt).max() > 0


def test_blocks_sum_to_the_tangent_and_the_residual():
    """`Contact.blocks` with friction on a deformable target: its wider blocks (the history
    point's nodes too) summed at their DOFs are `tangent` and `residual`."""
    s = Scene("diffuse", "sphere")
    friction = Coulomb(0.2, penalty_t=2.0 * EPS)
    h = s.history(friction, 0.02)
    c, r = s.state(s.target(2), s.contactors(2, 0.02), friction, h)
    K = c.tangent(EPS, s.cd, s.td, s.size).toarray()
    Kb, Rb = np.zeros_like(K), np.zeros_like(r)
    for _, dofs, Ke, Re in c.blocks(EPS, s.cd, s.td, chunk=5):
        for e in range(len(dofs)):
            keep = dofs[e] >= 0
            Kb[np.ix_(dofs[e][keep], dofs[e][keep])] += Ke[e][np.ix_(keep, keep)]
            Rb[dofs[e][keep]] += Re[e][keep]
    np.testing.assert_allclose(Kb, K, rtol=0, atol=1e-12 * np.abs(K).max())
    np.testing.assert_allclose(Rb, r, rtol=0, atol=1e-12 * np.abs(r).max())


def test_zero_contactors_and_refusals():
    s = Scene("diffuse", "sphere")
    friction = Coulomb(0.2)
    c = contact(s.base, np.zeros((0, 3)), friction=friction)
    assert c.residual(EPS, np.zeros((0, 3), int), s.td).shape == (s.td.max() + 1,)
    assert c.tangent(EPS, np.zeros((0, 3), int), s.td).nnz == 0
    assert c.history.nodes.shape[0] == 0
    x = s.contactors(0, 0.0)
    rigid = contact(s.base, x, rigid_target=True, friction=friction)
    rigid.residual(EPS, s.cd)
    with pytest.raises(ValueError, match=r"history: taken on a rigid target \(no nodes\)"):
        contact(s.base, x, friction=friction, history=rigid.history)
    h = s.history(friction, 0.02)
    with pytest.raises(ValueError, match=r"nodes, weights and positions go together"):
        contact(s.base, x, friction=friction,
                history=History(h.proximal_point, h.traction, h.nodes, h.weights))
    with pytest.raises(ValueError, match=r"history.weights: expected shape"):
        contact(s.base, x, friction=friction,
                history=History(h.proximal_point, h.traction, h.nodes, h.weights[:, :2],
                                h.positions))
    with pytest.raises(ValueError, match=r"moved target.*no reaction"):
        contact(s.base.moved(s.target(1)), x, rigid_target=True, friction=friction)
