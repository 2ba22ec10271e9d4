"""The augmented Lagrangian in the API (issue 33, item 3): `Contact.residual` / `tangent` with
`multipliers=`, `Contact.multipliers` (Uzawa after Alart-Curnier) and `contact(near=)`.

The issue's test (one contactor under a load of 1 on a flat rigid target, penalty 10: the
penalty alone leaves a penetration of 0.1, the augmentations drive it below 1e-8); Taylor
tests (remainder falling as h²) of the residual and the tangent with multipliers on a curved
deformable target, a curved rigid one and with friction on a rigid one; the update rule; and
the refusals."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli import Contact, Coulomb, DiffuseSurface, contact
from diffsurf_cli.testing.shapes import Plane, Sphere

R = 10.0      # the sphere's radius
EPS = 1.0e3   # the penalty of the Taylor tests


def _plane():
    """A flat square target z = 0, 21 x 21 nodes over [-10, 10]², triangles."""
    nodes, faces = Plane(size=10.0).mesh(20)
    return DiffuseSurface(nodes, [faces])


def _sphere():
    nodes, faces = Sphere(radius=R).mesh(12)
    return DiffuseSurface(nodes, [faces])


def _caps(m, rng, lo=-0.05, hi=0.02):
    """m contactors around the sphere's top, from `lo` (inside) to `hi` (outside) of it."""
    d = np.column_stack([rng.uniform(-0.4, 0.4, (m, 2)), np.ones(m)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d * (R + rng.uniform(lo, hi, m))[:, None]


def test_one_contactor_on_a_flat_rigid_target_reaches_round_off():
    """The issue's case: a load of 1, a penalty of 10; the penalty alone leaves a penetration
    of 0.1; after <= 10 augmentations it is below 1e-8, the force still the load."""
    surface, eps, load = _plane(), 10.0, 1.0
    x = np.array([[0.3, 0.2, -0.01]])
    dofs = np.array([[-1, -1, 0]])  # the contactor moves along z (frictionless: x, y free)
    lam = np.zeros(1)
    penetration = []
    for _ in range(10):
        for _ in range(20):  # Newton: R(x) = F, with F = (0, 0, -load)
            c = contact(surface, x, rigid_target=True, near=Contact.reach(eps, lam))
            r = c.residual(eps, dofs, n_dofs=1, multipliers=lam)[0] + load
            if abs(r) <= 1e-12:
                break
            x[0, 2] -= r / c.tangent(eps, dofs, n_dofs=1, multipliers=lam)[0, 0]
        assert abs(r) <= 1e-12
        penetration.append(-c.projection.gap[0])
        assert c.tractions(eps, lam).normal[0] == pytest.approx(load, rel=1e-12)
        if penetration[-1] <= 1e-8:
            break
        lam = c.multipliers(eps, lam)
    assert penetration[0] == pytest.approx(0.1, rel=1e-9)  # the penalty alone
    assert len(penetration) <= 10 and abs(penetration[-1]) <= 1e-8, penetration
    assert lam[0] == pytest.approx(-load, rel=1e-9)


def _taylor(residual, K, d, steps=(1e-4, 5e-5, 2.5e-5)):
    """Orders of the remainder |R(h d) − R(0) − h K d| over halving h."""
    r0 = residual(0.0)
    rem = [np.linalg.norm(residual(h) - r0 - h * (K @ d)) for h in steps]
    return [np.log2(rem[k] / rem[k + 1]) for k in range(len(rem) - 1)], rem


def _multipliers(m, rng):
    """Multipliers that keep some open contactors (g up to 0.02) active and leave others
    inactive within `near` (λ + ε g >= 0: their element adds nothing): λ in (-40, 0), with
    ε g in (-50, 20)."""
    lam = -rng.uniform(0.0, 40.0, m)
    lam[::3] = 0.0  # no multiplier: open ones within `near` are inactive
    return lam


def test_taylor_deformable_curved_target():
    """The full element on a moving sphere (frozen pairing): R with multipliers and its
    tangent K = ε 𝒩𝒩ᵀ + p ℳ over the active elements, on contactor and target DOFs."""
    rng = np.random.default_rng(3)
    surface = _sphere()
    x = _caps(16, rng)
    pairing = contact(surface, x, second=False).pairing
    lam = _multipliers(len(x), rng)
    near = Contact.reach(EPS, lam)
    n = len(surface.nodes)
    cd = np.arange(3 * len(x)).reshape(-1, 3)
    td = 3 * len(x) + np.arange(3 * n).reshape(-1, 3)
    c = contact(surface, x, pairing=pairing, near=near)
    p = np.minimum(lam[c.contactor] + EPS * c.gap, 0)
    # the scene has what it is for: active open elements and inactive ones
    assert ((c.gap > 0) & (p < 0)).any() and ((c.gap > 0) & (p == 0)).any(), (c.gap, p)
    assert not (c.gap > 0).all()
    K = c.tangent(EPS, cd, td, multipliers=lam)
    d = rng.normal(size=3 * (len(x) + n))

    def residual(h):
        moved = surface.moved(surface.nodes + h * d[3 * len(x):].reshape(-1, 3))
        ch = contact(moved, x + h * d[:3 * len(x)].reshape(-1, 3), pairing=pairing, near=near)
        return ch.residual(EPS, cd, td, n_dofs=K.shape[0], multipliers=lam)

    order, rem = _taylor(residual, K, d)
    assert min(order) > 1.8, (order, rem)


def test_taylor_rigid_curved_target():
    rng = np.random.default_rng(5)
    surface = _sphere()
    x = _caps(16, rng)
    lam = _multipliers(len(x), rng)
    near = Contact.reach(EPS, lam)
    cd = np.arange(3 * len(x)).reshape(-1, 3)
    c = contact(surface, x, rigid_target=True, near=near)
    p = np.minimum(lam[c.contactor] + EPS * c.gap, 0)
    assert ((c.gap > 0) & (p < 0)).any() and ((c.gap > 0) & (p == 0)).any(), (c.gap, p)
    K = c.tangent(EPS, cd, multipliers=lam)
    d = rng.normal(size=3 * len(x))

    def residual(h):
        ch = contact(surface, x + h * d.reshape(-1, 3), rigid_target=True, near=near)
        return ch.residual(EPS, cd, n_dofs=K.shape[0], multipliers=lam)

    order, rem = _taylor(residual, K, d)
    assert min(order) > 1.8, (order, rem)


@pytest.mark.parametrize("mu,slide", [(20.0, 1e-4), (0.2, 0.05)])
def test_taylor_friction_rigid_target(mu, slide):
    """Multiplier vectors λ (m, 3) with friction: the cone's radius μ |p| with p = min(0, λ·ν
    + ε g), the trial from λ; stick (large μ) and slip."""
    rng = np.random.default_rng(7)
    surface = _sphere()
    x0 = _caps(12, rng, -0.05, -0.01)
    friction = Coulomb(mu, penalty_t=2.0 * EPS)
    cd = np.arange(3 * len(x0)).reshape(-1, 3)
    c0 = contact(surface, x0, rigid_target=True, friction=friction)
    lam = c0.multipliers(EPS)   # the penalty's first augmentation: p ν (no history yet)
    assert (lam != 0).all()
    c0.residual(EPS, cd, multipliers=lam)
    h = c0.history
    # slid along the sphere, the multipliers given a tangential part
    a = slide / R
    rot = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    x = x0 @ rot.T
    lam = lam + rng.normal(scale=1.0, size=lam.shape)
    near = Contact.reach(EPS, lam)
    c = contact(surface, x, rigid_target=True, friction=friction, history=h, near=near)
    stick = c.tractions(EPS, lam).stick
    assert stick.all() if mu > 1 else not stick.any(), stick
    t = c.tractions(EPS, lam)
    assert np.abs(t.tangential).max() > 0
    # slip: on Coulomb's cone with the augmented normal force
    if mu < 1:
        assert np.allclose(np.linalg.norm(t.tangential, axis=1), mu * t.normal, rtol=1e-12)
    K = c.tangent(EPS, cd, multipliers=lam)
    assert abs(K - K.T).max() > 0 if mu < 1 else True
    d = rng.normal(size=3 * len(x))

    def residual(s):
        ch = contact(surface, x + s * d.reshape(-1, 3), rigid_target=True, friction=friction,
                     history=h, near=near)
        return ch.residual(EPS, cd, n_dofs=K.shape[0], multipliers=lam)

    order, rem = _taylor(residual, K, d)
    assert min(order) > 1.8, (order, rem)


def test_update_is_uzawa_and_the_penalty_is_unchanged():
    rng = np.random.default_rng(11)
    surface = _sphere()
    x = _caps(20, rng)
    cd = np.arange(3 * len(x)).reshape(-1, 3)
    lam = -rng.uniform(0.0, 40.0, len(x))
    c = contact(surface, x, rigid_target=True, near=Contact.reach(EPS, lam))
    new = c.multipliers(EPS, lam)
    g = c.projection.gap
    answered = np.isfinite(g)
    assert answered.all()
    np.testing.assert_allclose(new, np.minimum(lam + EPS * g, 0.0), rtol=1e-14, atol=0)
    # without multipliers the residual and tangent are the penalty's, whatever `near`
    plain = contact(surface, x, rigid_target=True)
    assert len(c) > len(plain)
    np.testing.assert_array_equal(c.residual(EPS, cd), plain.residual(EPS, cd))
    assert abs(c.tangent(EPS, cd) - plain.tangent(EPS, cd)).max() == 0
    np.testing.assert_array_equal(plain.residual(EPS, cd, multipliers=np.zeros(len(x))),
                                  plain.residual(EPS, cd))
    np.testing.assert_array_equal(plain.multipliers(EPS)[plain.contactor],
                                  EPS * plain.gap)


def test_refusals():
    rng = np.random.default_rng(13)
    surface = _sphere()
    x = _caps(10, rng)
    cd = np.arange(3 * len(x)).reshape(-1, 3)
    c = contact(surface, x, rigid_target=True)
    lam = np.full(len(x), -40.0)
    # an open contactor that carries a force but was given no element: refused, not dropped
    with pytest.raises(ValueError, match="near=Contact.reach"):
        c.residual(EPS, cd, multipliers=lam)
    with pytest.raises(ValueError, match="one per contactor"):
        c.residual(EPS, cd, multipliers=lam[:3])
    with pytest.raises(ValueError, match="<= 0"):
        c.tangent(EPS, cd, multipliers=-lam)
    with pytest.raises(ValueError, match="finite"):
        c.multipliers(EPS, np.full(len(x), np.nan))
    with pytest.raises(ValueError, match="near"):
        contact(surface, x, rigid_target=True, near=-1.0)
    f = contact(surface, x, rigid_target=True, friction=Coulomb(0.3))
    with pytest.raises(ValueError, match=r"traction vector"):
        f.residual(EPS, cd, multipliers=lam)


@pytest.mark.parametrize("rigid", [False, True])
def test_assemble_takes_the_multipliers_chunk_by_chunk(rigid):
    """`assemble(..., multipliers=)` sums, chunk by chunk (each with the `near` its own
    multipliers need), what one `Contact` with the whole cloud's `near` gives: the extra
    elements the wider `near` builds are inactive (p = 0) and add nothing."""
    from diffsurf_cli import assemble

    rng = np.random.default_rng(5)
    surface = _sphere()
    x = _caps(40, rng)
    lam = _multipliers(len(x), rng)
    n = len(surface.nodes)
    cd = np.arange(3 * len(x)).reshape(-1, 3)
    td = None if rigid else 3 * len(x) + np.arange(3 * n).reshape(-1, 3)
    c = contact(surface, x, rigid_target=rigid, near=Contact.reach(EPS, lam))
    R0 = c.residual(EPS, cd, td, multipliers=lam)
    K0 = c.tangent(EPS, cd, td, multipliers=lam)
    R, K, status = assemble(surface, x, EPS, cd, td, rigid_target=rigid, chunk=7,
                            n_dofs=len(R0), multipliers=lam)
    assert np.abs(R0).max() > 0 and abs(K0).max() > 0
    np.testing.assert_allclose(R, R0, rtol=1e-12, atol=1e-12 * np.abs(R0).max())
    np.testing.assert_allclose(K.toarray(), K0.toarray(), rtol=1e-12,
                               atol=1e-12 * abs(K0).max())
    np.testing.assert_array_equal(status, c.status)
    # without `multipliers`, assemble is the penalty's: the open contactors' forces are gone
    R1, _, _ = assemble(surface, x, EPS, cd, td, rigid_target=rigid, chunk=7, n_dofs=len(R0))
    assert not np.allclose(R1, R0)
    with pytest.raises(ValueError, match="multipliers"):
        assemble(surface, x, EPS, cd, td, rigid_target=rigid, multipliers=lam[:-1])
