"""The contact element as an API for FE codes (issue 12, item 4): `contact(...)` returns a
`Contact` of per-element arrays and per-contactor statuses; `residual` / `tangent` assemble them
at a caller's DOF map (-1: no DOF) with a per-contactor penalty; `assemble` does it chunk by
chunk. Each assembly is checked against an obvious loop over the elements; the rigid-target
mode's R and K against the energy Σ ε g²/2 by a Taylor test.
"""
from __future__ import annotations

import types

import numpy as np
import pytest

import diffsurf_cli
from diffsurf_cli.element.element import Contact, assemble, contact
from diffsurf_cli.element.rigid import RigidTarget
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import FAILED, OPEN, OUTSIDE, PENETRATION, REASONS
from diffsurf_cli.testing.shapes import Saddle, Sphere
from test_element import _taylor

METHODS = ("diffuse", "facet", "facet-rigid")


def _saddle():
    """An open saddle, with contactors that penetrate, are open, lie beyond its edge and are
    not numbers."""
    shape = Saddle(a=0.5, size=1.0)
    nodes, faces = shape.mesh(10)
    on = shape.sample_near(10, 0.0, rng=3, margin=0.35)
    _, normal, _ = shape.closest(on)
    points = np.vstack([on - 0.04 * normal, on[:4] + 0.05 * normal[:4],
                        [[2.2, 0.1, 0.0], [0.0, -2.0, 0.1], [np.nan, 0.0, 0.0]]])
    return nodes, faces, points[np.random.default_rng(4).permutation(len(points))]


def _surface(method, nodes, faces):
    if method == "diffuse":
        return DiffuseSurface(nodes, [faces], frame="global")
    return FacetSurface(nodes, [faces])


def _contact(method, surf, points, **kw):
    return contact(surf, points, rigid_target=method.endswith("rigid"), **kw)


def _dof_maps(rng, m, n, fixed=True):
    """A scattered DOF map of m contactors and n target nodes (with unused DOFs between), and
    with `fixed` some DOFs removed (-1): one coordinate of a few nodes, every DOF of others."""
    total = 3 * (m + n) + 11
    perm = rng.permutation(total)[:3 * (m + n)]
    cd, td = perm[:3 * m].reshape(m, 3).copy(), perm[3 * m:].reshape(n, 3).copy()
    if fixed:
        cd[rng.choice(m, 3, replace=False), rng.integers(0, 3, 3)] = -1
        td[rng.choice(n, n // 3, replace=False)] = -1
        td[rng.choice(n, n // 5, replace=False), 2] = -1
    return cd, td, total


def _loop(c: Contact, penalty, cd, td, size):
    """R and K by the obvious loop over the elements (Element records), dense."""
    R, K = np.zeros(size), np.zeros((size, size))
    for e in c:
        eps = penalty[e.contactor]
        dof = np.concatenate([cd[e.contactor], td[e.nodes].ravel()])
        keep = dof >= 0
        R[dof[keep]] += (eps * e.gap * e.N)[keep]
        K[np.ix_(dof[keep], dof[keep])] += e.tangent(eps)[np.ix_(keep, keep)]
    return R, K


@pytest.mark.parametrize("method", METHODS)
def test_dof_map_and_penalty_assembly_is_the_loop(method):
    nodes, faces, points = _saddle()
    surf = _surface(method, nodes, faces)
    c = _contact(method, surf, points)
    m, n = len(points), len(nodes)
    assert 6 <= len(c) < m
    rng = np.random.default_rng(9)
    penalty = rng.uniform(1.0, 50.0, m)
    cd, td, size = _dof_maps(rng, m, n)
    R = c.residual(penalty, cd, td, size)
    K = c.tangent(penalty, cd, td, size)
    assert R.shape == (size,) and K.shape == (size, size) and K.format == "csr"
    R_ref, K_ref = _loop(c, penalty, cd, td, size)
    assert np.abs(R_ref).max() > 0 and np.abs(K_ref).max() > 0
    np.testing.assert_allclose(R, R_ref, rtol=0, atol=1e-13 * np.abs(R_ref).max())
    np.testing.assert_allclose(K.toarray(), K_ref, rtol=0, atol=1e-13 * np.abs(K_ref).max())
    assert abs(K - K.T).max() <= 1e-13 * abs(K).max()
    assert c.energy(penalty) == pytest.approx(
        sum(0.5 * penalty[e.contactor] * e.gap ** 2 for e in c), rel=1e-14)
    # fixed DOFs carry nothing, unused DOFs neither
    dropped = np.setdiff1d(np.arange(size), np.concatenate([cd[cd >= 0], td[td >= 0]]))
    assert not R[dropped].any() and not K[dropped].count_nonzero()
    assert not K[:, dropped].count_nonzero()


@pytest.mark.parametrize("method", METHODS)
def test_gauss_newton_tangent_is_the_loop_of_penalty_N_Nt(method):
    """`tangent(..., gauss_newton=True)`: Σ ε 𝒩 𝒩ᵀ, the loop's, positive semi-definite, and
    the same from a contact built without ℳ (second=False); the full tangent minus it is
    Σ ε g ℳ."""
    nodes, faces, points = _saddle()
    surf = _surface(method, nodes, faces)
    c = _contact(method, surf, points)
    m, n = len(points), len(nodes)
    rng = np.random.default_rng(19)
    penalty = rng.uniform(1.0, 50.0, m)
    cd, td, size = _dof_maps(rng, m, n)
    if method == "facet-rigid":
        td = None
    G = c.tangent(penalty, cd, td, size, gauss_newton=True).toarray()
    ref = np.zeros((size, size))
    for e in c:
        dof = np.concatenate([cd[e.contactor]] + ([] if td is None else [td[e.nodes].ravel()]))
        keep = dof >= 0
        ref[np.ix_(dof[keep], dof[keep])] += e.tangent(penalty[e.contactor],
                                                       gauss_newton=True)[np.ix_(keep, keep)]
        np.testing.assert_allclose(e.tangent(2.0) - e.tangent(2.0, gauss_newton=True),
                                   2.0 * e.gap * e.M, rtol=0, atol=1e-12)
    assert np.abs(ref).max() > 0
    np.testing.assert_allclose(G, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    assert np.linalg.eigvalsh(G).min() >= -1e-12 * np.abs(G).max()
    light = _contact(method, surf, points, second=False)
    assert light.M is None
    np.testing.assert_allclose(light.tangent(penalty, cd, td, size, gauss_newton=True).toarray(),
                               G, rtol=0, atol=1e-13 * np.abs(G).max())


@pytest.mark.parametrize("method", METHODS)
def test_fixed_dofs_are_the_free_rows_of_the_full_assembly(method):
    """-1 drops exactly the row and column of that DOF: the assembly with some DOFs fixed is
    the free rows and columns of the assembly with none fixed."""
    nodes, faces, points = _saddle()
    surf = _surface(method, nodes, faces)
    c = _contact(method, surf, points)
    m, n = len(points), len(nodes)
    rng = np.random.default_rng(10)
    cd, td, size = _dof_maps(rng, m, n, fixed=False)
    R_all, K_all = c.residual(7.0, cd, td, size), c.tangent(7.0, cd, td, size).toarray()
    cf, tf = cd.copy(), td.copy()
    cf[rng.random(cf.shape) < 0.2] = -1
    tf[rng.random(tf.shape) < 0.4] = -1
    R, K = c.residual(7.0, cf, tf, size), c.tangent(7.0, cf, tf, size).toarray()
    free = np.concatenate([cf[cf >= 0], tf[tf >= 0]])
    mask = np.zeros(size, bool)
    mask[free] = True
    np.testing.assert_array_equal(R[mask], R_all[mask])
    assert not R[~mask].any()
    np.testing.assert_allclose(K[np.ix_(mask, mask)], K_all[np.ix_(mask, mask)], rtol=0,
                               atol=1e-14 * np.abs(K_all).max())
    assert not K[~mask].any() and not K[:, ~mask].any()
    # no target DOFs at all: the same as every target DOF fixed; n_dofs defaults to max + 1
    none = np.full_like(td, -1)
    np.testing.assert_array_equal(c.residual(7.0, cd, None, size), c.residual(7.0, cd, none, size))
    assert len(c.residual(7.0, cd, td)) == max(cd.max(), td.max()) + 1


def test_bad_dof_maps_and_penalties_are_refused():
    nodes, faces, points = _saddle()
    c = contact(FacetSurface(nodes, [faces]), points)
    m, n = len(points), len(nodes)
    cd = np.arange(3 * m).reshape(m, 3)
    td = 3 * m + np.arange(3 * n).reshape(n, 3)
    with pytest.raises(ValueError, match="contactor_dofs"):
        c.residual(1.0, cd[:-1], td)
    with pytest.raises(ValueError, match="target_dofs"):
        c.tangent(1.0, cd, td[:-1])
    with pytest.raises(ValueError, match="penalty"):
        c.residual(np.ones(m - 1), cd, td)
    with pytest.raises(ValueError, match="n_dofs"):
        c.residual(1.0, cd, td, n_dofs=3 * (m + n) - 1)
    light = contact(FacetSurface(nodes, [faces]), points, second=False)
    assert light.M is None
    with pytest.raises(ValueError, match="second=True"):
        light.tangent(1.0, cd, td)


@pytest.mark.parametrize("method", METHODS)
def test_statuses_say_why_a_contactor_has_no_element(method):
    nodes, faces, points = _saddle()
    surf = _surface(method, nodes, faces)
    c = _contact(method, surf, points)
    m = len(points)
    assert c.status.shape == c.reason.shape == (m,)
    np.testing.assert_array_equal(c.contactor, np.flatnonzero(c.status == PENETRATION))
    assert (c.gap < 0).all()
    bad = np.flatnonzero(np.isnan(points).any(axis=1))
    assert c.status[bad] == FAILED and REASONS[c.reason[bad[0]]] == "bad-point"
    beyond = np.flatnonzero(np.abs(points[:, :2]).max(axis=1) > 1.5)
    assert len(beyond) == 2
    if method == "diffuse":
        assert (c.status[beyond] == OUTSIDE).all() and (c.reason[beyond] > 0).all()
    assert (c.status == OPEN).sum() >= 4
    # the contactors without an element get nothing assembled
    cd = np.arange(3 * m).reshape(m, 3)
    R = c.residual(3.0, cd, None, 3 * m)
    K = c.tangent(3.0, cd, None, 3 * m)
    for i in np.flatnonzero(c.status != PENETRATION):
        assert not R[3 * i:3 * i + 3].any() and not K[3 * i:3 * i + 3].count_nonzero()


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_element_records_are_the_arrays_without_padding(method):
    nodes, faces, points = _saddle()
    c = _contact(method, _surface(method, nodes, faces), points)
    e_, K = c.nodes.shape
    assert c.N.shape == (e_, 3 * (K + 1)) and c.M.shape == (e_, 3 * (K + 1), 3 * (K + 1))
    pad = np.repeat(np.concatenate([np.zeros((e_, 1), bool), c.nodes < 0], axis=1), 3, axis=1)
    assert not c.N[pad].any() and not c.M[pad[:, :, None] | pad[:, None, :]].any()
    assert len(c.elements) == len(c) == e_
    for k, e in enumerate(c):
        n = (c.nodes[k] >= 0).sum()
        assert e.contactor == c.contactor[k] and e.gap == c.gap[k]
        np.testing.assert_array_equal(e.nodes, c.nodes[k, :n])
        np.testing.assert_array_equal(e.N, c.N[k, :3 * (n + 1)])
        np.testing.assert_array_equal(e.M, c.M[k, :3 * (n + 1), :3 * (n + 1)])


def test_facet_rigid_target_is_the_contactor_block():
    nodes, faces, points = _saddle()
    surf = FacetSurface(nodes, [faces])
    full = contact(surf, points)
    rigid = contact(surf, points, rigid_target=True)
    assert rigid.rigid_target and rigid.nodes.shape == (len(full), 0)
    np.testing.assert_array_equal(rigid.contactor, full.contactor)
    np.testing.assert_array_equal(rigid.gap, full.gap)
    np.testing.assert_array_equal(rigid.N, full.N[:, :3])
    np.testing.assert_array_equal(rigid.M, full.M[:, :3, :3])


@pytest.mark.parametrize("method", METHODS)
def test_chunked_assemble_is_the_one_shot_assembly(method):
    nodes, faces, points = _saddle()
    surf = _surface(method, nodes, faces)
    rigid = method.endswith("rigid")
    m, n = len(points), len(nodes)
    rng = np.random.default_rng(12)
    penalty = rng.uniform(1.0, 5.0, m)
    cd, td, size = _dof_maps(rng, m, n)
    c = _contact(method, surf, points)
    R1, K1 = c.residual(penalty, cd, td, size), c.tangent(penalty, cd, td, size)
    for pairing in (None, c.projection.facet if method != "diffuse" else c.projection.patch):
        R, K, status = assemble(surf, points, penalty, cd, td, n_dofs=size, rigid_target=rigid,
                                pairing=pairing, chunk=4)
        np.testing.assert_array_equal(status, c.status)
        np.testing.assert_allclose(R, R1, rtol=0, atol=1e-14 * np.abs(R1).max())
        assert abs(K - K1).max() <= 1e-14 * abs(K1).max() and K.shape == (size, size)
    # the public name
    assert diffsurf_cli.assemble is assemble and diffsurf_cli.contact is contact


# --------------------------------------------------------------------------------------------
# rigid target: R and K are the gradient and Hessian of Σ ε g²/2 in the contactors
# --------------------------------------------------------------------------------------------


def _taylor_energy(energy_and_residual, x, E0, R, K, scale, rng, label):
    """Along a random d: |E(x+hd) - E - h R·d| falls as h², |... - ½h² dᵀKd| as h³, and
    central differences of E and R match R·d and K d."""
    d = rng.standard_normal(x.size)
    hs = scale * 10.0 ** -np.arange(2.0, 6.01, 0.5)
    r1, r2, fd1, fd2 = [], [], [], []
    Rd, Kd = R @ d, K @ d
    for h in hs:
        (Ep, Rp), (Em, Rm) = energy_and_residual(x + h * d), energy_and_residual(x - h * d)
        r1.append(abs(Ep - E0 - h * Rd))
        r2.append(abs(Ep - E0 - h * Rd - 0.5 * h * h * d @ Kd))
        fd1.append(abs((Ep - Em) / (2 * h) - Rd) / abs(Rd))
        fd2.append(np.linalg.norm((Rp - Rm) / (2 * h) - Kd) / np.linalg.norm(Kd))
    r1, r2 = np.array(r1), np.array(r2)
    floor = 1e3 * np.finfo(float).eps * max(abs(E0), 1e-300)
    msg = f"{label}: r1={r1}, r2={r2}, fd1={min(fd1):.1e}, fd2={min(fd2):.1e}"
    k1 = r1 > floor
    k2 = r2 > floor
    assert k1.sum() >= 3, msg
    assert np.polyfit(np.log(hs[k1]), np.log(r1[k1]), 1)[0] >= 1.7, msg
    if k2.sum() >= 3:
        assert np.polyfit(np.log(hs[k2]), np.log(r2[k2]), 1)[0] >= 2.7, msg
    else:  # E is exactly quadratic along d (flat facets): the remainder is round-off at every h
        assert r2.max() <= floor, msg
    assert min(fd1) <= 1e-6 and min(fd2) <= 1e-6, msg


def _check_rigid_derivatives(surf, points, rng, label, **kw):
    m = len(points)
    penalty = rng.uniform(1.0, 10.0, m)
    cd = np.arange(3 * m).reshape(m, 3)
    c = contact(surf, points, rigid_target=True, **kw)
    assert len(c) >= 3 and c.nodes.shape == (len(c), 0) and c.N.shape == (len(c), 3)
    R, K = c.residual(penalty, cd), c.tangent(penalty, cd)
    assert R.shape == (3 * m,) and K.shape == (3 * m, 3 * m)

    def energy_and_residual(x):
        c2 = contact(surf, x.reshape(m, 3), rigid_target=True, **kw)
        assert np.array_equal(c2.status, c.status), label
        return c2.energy(penalty), c2.residual(penalty, cd, None, 3 * m)

    _taylor_energy(energy_and_residual, points.ravel(), c.energy(penalty), R, K.toarray(),
                   0.1, rng, label)


def test_facet_rigid_target_derivatives():
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(4)
    on = shape.sample_near(8, 0.0, rng=5)
    surf = FacetSurface(nodes, [faces])
    points = on * 0.97
    pairing = surf.project(points).facet  # a node-to-facet element freezes its facet
    _check_rigid_derivatives(surf, points, np.random.default_rng(6), "facet", pairing=pairing)


class _UnitSphere:
    """A stand-in for element.rigid's kernel (`RigidTarget`, answering as `RigidResult`): the
    exact signed distance to the unit sphere, its gradient ν = x/|x| and Hessian
    (I - ν νᵀ)/|x|; NaN rows fail."""

    surfaces: list = []

    @classmethod
    def for_surface(cls, surface):
        cls.surfaces.append(surface)
        return cls()

    def evaluate(self, points, *, second=True):
        r = np.linalg.norm(points, axis=1)
        normal = points / r[:, None]
        gap = r - 1.0
        hessian = (np.eye(3) - normal[:, :, None] * normal[:, None, :]) / r[:, None, None]
        bad = ~np.isfinite(r)
        status = np.where(bad, FAILED, np.where(gap < 0, PENETRATION, OPEN)).astype(np.int8)
        return types.SimpleNamespace(gap=gap, normal=normal, proximal_point=normal,
                                     hessian=hessian if second else None,
                                     curvature=np.ones((len(r), 2)), status=status,
                                     reason=np.where(bad, 1, 0).astype(np.int8),
                                     iterations=np.zeros(len(r), np.int64))


@pytest.fixture
def fake_rigid(monkeypatch):
    import diffsurf_cli.element.element as element

    _UnitSphere.surfaces = []
    monkeypatch.setattr(element, "RigidTarget", _UnitSphere)
    return _UnitSphere


def test_rigid_target_assembly_with_a_stand_in_kernel(fake_rigid):
    """The rigid-target path of contact/assemble: the kernel's normal and Hessian are N and M
    of the penetrating contactors, its statuses are the contactors'; R and K are the
    derivatives of the energy; no pairing is taken."""
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(3)
    surf = DiffuseSurface(nodes, [faces])
    on = shape.sample_near(12, 0.0, rng=7)
    points = np.vstack([on * 0.95, on[:3] * 1.1, [[np.nan, 0, 0]]])
    c = contact(surf, points, rigid_target=True)
    assert fake_rigid.surfaces == [surf]
    np.testing.assert_array_equal(c.contactor, np.arange(12))
    np.testing.assert_allclose(c.N, on, atol=1e-12)
    np.testing.assert_allclose(c.gap, -0.05, atol=1e-12)
    assert c.status[-1] == FAILED and REASONS[c.reason[-1]] == "bad-point"
    np.testing.assert_array_equal(c.projection.gap[:-1],
                                  np.linalg.norm(points[:-1], axis=1) - 1.0)
    with pytest.raises(ValueError, match="pairing"):
        contact(surf, points, rigid_target=True,
                pairing=surf.project(points, keep_patch=True).patch)
    assert contact(surf, points, rigid_target=True, second=False).M is None
    m = len(points)
    rng = np.random.default_rng(8)
    penalty = rng.uniform(1.0, 5.0, m)
    cd, _, size = _dof_maps(rng, m, 0)
    R1, K1 = c.residual(penalty, cd, None, size), c.tangent(penalty, cd, None, size)
    R_ref, K_ref = _loop(c, penalty, cd, np.zeros((0, 3), np.int64), size)
    np.testing.assert_allclose(R1, R_ref, rtol=0, atol=1e-14 * np.abs(R_ref).max())
    np.testing.assert_allclose(K1.toarray(), K_ref, rtol=0, atol=1e-14 * np.abs(K_ref).max())
    R, K, status = assemble(surf, points, penalty, cd, n_dofs=size, rigid_target=True, chunk=5)
    np.testing.assert_array_equal(status, c.status)
    np.testing.assert_allclose(R, R1, rtol=0, atol=1e-14 * np.abs(R1).max())
    assert abs(K - K1).max() <= 1e-14 * abs(K1).max()
    _check_rigid_derivatives(surf, points[:-1], rng, "stand-in")


@pytest.mark.parametrize("frame", ["auto", "global"])
def test_rigid_target_derivatives(frame):
    """The real rigid-target element (diffsurf_cli.element.rigid): R and K of the assembled
    contactor DOFs are the gradient and Hessian of Σ ε g²/2, with a per-contactor penalty."""
    rng = np.random.default_rng(13)
    if frame == "auto":
        shape = Sphere(center=(0.2, -0.1, 0.3), radius=1.0)
        nodes, faces = shape.mesh(5)
        on = shape.sample_near(6, 0.0, rng=14)
        depth = 0.05
    else:
        shape = Saddle(a=0.5, size=1.0)
        nodes, faces = shape.mesh(10)
        on = shape.sample_near(6, 0.0, rng=15, margin=0.35)
        depth = 0.03
    _, normal, _ = shape.closest(on)
    points = np.vstack([on - depth * normal, on[:2] + depth * normal[:2]])
    surf = DiffuseSurface(nodes, [faces], frame=frame)
    _check_rigid_derivatives(surf, points, rng, f"rigid/{frame}")


def test_sparse_sum_is_scipys_sum_of_duplicates():
    """The accumulator of the chunked assembly against scipy's COO sum, over random parts
    (empty ones, repeated entries within and across parts)."""
    import scipy.sparse as sp

    from diffsurf_cli.element.element import _SparseSum

    rng = np.random.default_rng(0)
    for _ in range(40):
        shape = (int(rng.integers(1, 40)), int(rng.integers(1, 40)))
        total, parts = _SparseSum(shape), []
        for _ in range(int(rng.integers(0, 12))):
            k = int(rng.integers(0, 60))
            part = (rng.integers(0, shape[0], k), rng.integers(0, shape[1], k),
                    rng.standard_normal(k))
            total.add(*part)
            parts.append(part)
        out = total.result()
        rows, cols, vals = (np.concatenate([p[j] for p in parts]) if parts else
                            np.zeros(0, int if j < 2 else float) for j in range(3))
        ref = sp.coo_matrix((vals, (rows, cols)), shape=shape).toarray()
        assert out.shape == shape and out.has_canonical_format
        np.testing.assert_allclose(out.toarray(), ref, rtol=0, atol=1e-14)


def test_an_element_the_kernel_could_not_compute_fails_its_contactor(monkeypatch):
    """The batched element returns NaN where a fit or the proximal point's system is
    singular: that contactor gets no element, status failed, reason ill-conditioned; R and K
    stay finite."""
    import diffsurf_cli.element.element as element

    real = element.diffuse_elements

    def broken(*args, **kw):
        gap, nodes, N, M = real(*args, **kw)
        gap[1] = np.nan
        N[1] = np.nan
        if M is not None:
            M[1] = np.nan
        return gap, nodes, N, M

    nodes, faces, points = _saddle()
    surf = _surface("diffuse", nodes, faces)
    good = contact(surf, points)
    monkeypatch.setattr(element, "diffuse_elements", broken)
    c = contact(surf, points)
    lost = good.contactor[1]
    assert c.status[lost] == FAILED and REASONS[c.reason[lost]] == "ill-conditioned"
    np.testing.assert_array_equal(c.contactor, np.delete(good.contactor, 1))
    np.testing.assert_array_equal(c.gap, np.delete(good.gap, 1))
    m = len(points)
    cd = np.arange(3 * m).reshape(m, 3)
    assert np.isfinite(c.residual(1.0, cd)).all() and np.isfinite(c.tangent(1.0, cd).data).all()


def test_a_patched_surface_of_one_patch_is_its_diffuse_surface():
    """A target of one patch: where its diffuse surface answers (and the guard accepts), the
    elements are its DiffuseSurface's, bit for bit; a pairing is that surface's."""
    from diffsurf_cli.patches.surface import PatchedSurface

    nodes, faces, points = _saddle()
    patched = PatchedSurface(nodes, [faces], feature_angle=None, frame="global")
    assert patched.npatches == 1
    one = patched.surfaces[0]
    a, b = contact(patched, points), contact(one, points)
    # past the saddle's open edges neither answers; elsewhere its diffuse surface does
    np.testing.assert_array_equal(a.projection.source == -2, b.projection.status >= 3)
    np.testing.assert_array_equal(a.contactor, b.contactor)
    np.testing.assert_array_equal(a.N, b.N)
    pair = b.projection.patch
    np.testing.assert_array_equal(contact(patched, points, pairing=pair).N, b.N)
    # a cube's faces are six patches: no single pairing to hold fixed (their elements are
    # tests/test_patch_element.py's)
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4],
                      [1, 5, 7, 3]])
    several = PatchedSurface(cube, [quads], basis="linear", support="knn", k=3)
    assert several.npatches == 6
    with pytest.raises(ValueError, match="one diffuse surface"):
        contact(several, [[0.5, 0.5, 0.9]], pairing=np.zeros(1, np.int64))


def test_rigid_target_answers_far_and_deep_contactors():
    """The rigid surface's blend reaches 1.5 node spacings; a contactor beyond (far out, or
    deeper) starts its search from its faceted foot (issue 21): far ones are open with the
    rigid surface's gap, deep ones get an element whose gap is the exact sphere's to the
    smoothing's accuracy, and whose 𝒩 and ℳ pass the Taylor test there."""
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(8)
    surf = DiffuseSurface(nodes, [faces])
    h = float(np.median(surf.node_spacing))
    on = shape.sample_near(4, 0.0, rng=21)
    _, normal, _ = shape.closest(on)
    points = np.vstack([on + 3 * h * normal, on - 2.5 * h * normal, on - 0.3 * h * normal,
                        on + 40 * normal])
    c = contact(surf, points, rigid_target=True)
    n = len(on)
    assert (c.status[:n] == OPEN).all() and (c.status[3 * n:] == OPEN).all()
    assert (c.reason == REASONS.index("ok")).all()
    exact = np.linalg.norm(points - shape.center, axis=1) - shape.radius
    # the rigid surface's own gap (not the projection's): a sphere to the smoothing's accuracy
    np.testing.assert_allclose(c.projection.gap, exact, rtol=0, atol=0.01 * h)
    np.testing.assert_array_equal(c.contactor, np.arange(n, 3 * n))
    assert len(c.lost) == 0
    rigid = RigidTarget.for_surface(surf)
    rng = np.random.default_rng(8)
    for k in range(len(c)):
        i = c.contactor[k]

        def evaluate(v):
            r = rigid.evaluate(v[None])
            return None if r.status[0] != PENETRATION else (r.gap[0], r.normal[0])

        _taylor(evaluate, points[i].copy(), c.gap[k], c.N[k], c.M[k], h, rng, f"#{i}")


def test_patch_driven_three_spacings_deep_in_one_step_converges():
    """A 5x5 patch of contactors tied by springs to positions 3 node spacings inside a coarse
    sphere (R = 10, spacing R/5.4), in one step: every contactor gets an element at the first
    iteration, in both modes, and Newton converges (the rigid target in a few steps)."""
    shape = Sphere(radius=10.0)
    nodes, faces = shape.mesh(6)
    h = shape.spacing(6)
    a = np.radians(np.linspace(-8, 8, 5))
    A, B = (v.ravel() for v in np.meshgrid(a, a))
    ray = np.stack([np.sin(A), np.sin(B), np.cos(A) * np.cos(B)], 1)
    ray /= np.linalg.norm(ray, axis=1)[:, None]
    y = ray * (10.0 - 3.0 * h)
    m = len(y)
    dofs = np.arange(3 * m).reshape(m, 3)
    ks, eps = 1.0, 30.0
    for surf, rigid, most in ((DiffuseSurface(nodes, [faces]), True, 4),
                              (DiffuseSurface(nodes, [faces]), False, 12),
                              (FacetSurface(nodes, [faces]), True, 4)):
        x, norms = y.copy(), []
        for it in range(30):
            c = contact(surf, x, rigid_target=rigid)
            if it == 0:
                assert len(c) == m, (rigid, np.bincount(c.status))
                np.testing.assert_allclose(c.gap, -3 * h, rtol=0.1)
            r = ks * (x - y).ravel() + c.residual(eps, dofs, n_dofs=3 * m)
            norms.append(np.linalg.norm(r))
            if norms[-1] <= 1e-10 * ks * h:
                break
            K = c.tangent(eps, dofs, n_dofs=3 * m).toarray()
            x = x + np.linalg.solve(ks * np.eye(3 * m) + K, -r).reshape(m, 3)
        assert norms[-1] <= 1e-10 * ks * h and len(norms) - 1 <= most, (type(surf), rigid,
                                                                          norms)
        # pushed back out to the penalty's small penetration
        gap = c.gap
        assert np.all((gap < 0) & (gap > -3 * h * ks / eps)), gap


def test_lost_contactors_are_counted():
    """A contactor that gets no answer but lies inside the target (the facets say so) is
    counted in `Contact.lost`, never taken for open; one outside the target, or not a number,
    is not. The unanswered statuses are set by hand: the rigid target answers all of these."""
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(5)
    surf = DiffuseSurface(nodes, [faces])
    on = shape.sample_near(3, 0.0, rng=2)
    _, normal, _ = shape.closest(on)
    points = np.vstack([on - 0.1 * normal, on + 0.1 * normal, [[np.nan, 0, 0]]])
    proj = surf.project(points)
    proj.status[:] = OUTSIDE  # as if nothing answered
    from diffsurf_cli.element.element import lost_contactors

    np.testing.assert_array_equal(lost_contactors(surf, points, proj), np.arange(3))
    proj.status[:] = FAILED
    np.testing.assert_array_equal(lost_contactors(surf, points, proj), np.arange(3))
    c = contact(surf, points, rigid_target=True)
    assert len(c.lost) == 0 and len(c) == 3


@pytest.mark.parametrize("kind", ["diffuse", "diffuse-global", "facet", "patched"])
def test_moved_target_is_the_target_rebuilt_on_its_new_nodes(kind):
    """`surface.moved(nodes)` (issue 21: a deformable target in one call per iteration): the
    same answers as the surface built again on the moved nodes (a global frame's mean plane
    pinned instead), and a pairing taken before the move applies to it."""
    from diffsurf_cli.patches.surface import PatchedSurface

    shape = Saddle(a=0.5, size=1.0) if kind == "diffuse-global" else Sphere(radius=1.0)
    nodes, faces = shape.mesh(8)
    make = {"diffuse": lambda n: DiffuseSurface(n, [faces]),
            "diffuse-global": lambda n: DiffuseSurface(n, [faces], frame="global"),
            "facet": lambda n: FacetSurface(n, [faces]),
            "patched": lambda n: PatchedSurface(n, [faces])}[kind]
    surf = make(nodes)
    rng = np.random.default_rng(6)
    new = nodes + 0.01 * np.sin(3 * nodes[:, [1, 2, 0]]) + [0.1, 0.0, -0.05]
    on = shape.sample_near(40, 0.0, rng=7, **({"margin": 0.3} if kind == "diffuse-global"
                                               else {}))
    points = on + rng.normal(0, 0.03, on.shape)
    moved, again = surf.moved(new), make(new)
    assert type(moved) is type(surf) and moved.nodes is not surf.nodes
    if kind == "diffuse-global":  # the frame is pinned: the rebuilt one's mean plane moved
        assert np.array_equal(moved.axes, surf.axes) and not np.array_equal(again.axes,
                                                                              surf.axes)
        again.origin, again.axes = surf.origin, surf.axes
        again.steep = moved.steep
        again._engine = None
    a, b = moved.project(points), again.project(points)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_allclose(a.gap, b.gap, rtol=0, atol=1e-13)
    assert np.abs(a.gap - surf.project(points).gap).max() > 1e-3  # it did move
    if kind in ("diffuse", "diffuse-global", "facet"):  # a frozen pairing across the move
        first = contact(surf, points)
        pairing = first.projection.patch if kind != "facet" else first.projection.facet
        c, d = contact(moved, points, pairing=pairing), contact(again, points, pairing=pairing)
        np.testing.assert_array_equal(c.contactor, d.contactor)
        np.testing.assert_allclose(c.N, d.N, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="moved: expected the target's"):
        surf.moved(new[:-1])


@pytest.mark.parametrize("kind", ["diffuse", "facet", "patched"])
def test_hessians_built_on_demand_are_the_whole_arrays(kind, monkeypatch):
    """Beyond `HESSIAN_BYTES` a Contact's ℳ is a `Hessians` built a block at a time (issue
    21: bounded memory): the tangent, the elements and np.asarray(c.M) are the same numbers as
    with ℳ held whole."""
    from diffsurf_cli.element import blocks
    from diffsurf_cli.patches.surface import PatchedSurface

    if kind == "patched":  # a box of 6 patches, with its corners and edges to the facets
        import trimesh

        box = trimesh.creation.box(extents=(1.0, 0.8, 0.6)).subdivide().subdivide()
        nodes, faces = np.asarray(box.vertices), np.asarray(box.faces)
        surf = PatchedSurface(nodes, [faces])
        points = np.random.default_rng(4).uniform([-0.45, -0.35, -0.25], [0.45, 0.35, 0.25],
                                                  (300, 3))
        assert surf.npatches > 1
    else:
        shape = Sphere(radius=1.0)
        nodes, faces = shape.mesh(8)
        surf = DiffuseSurface(nodes, [faces]) if kind == "diffuse" else FacetSurface(nodes,
                                                                                    [faces])
        on = shape.sample_near(150, 0.0, rng=9)
        points = on - 0.05 * shape.closest(on)[1]
    whole = contact(surf, points)
    assert isinstance(whole.M, np.ndarray) and len(whole) > 100
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 1000)
    monkeypatch.setattr(blocks, "TANGENT_BATCH", 4000)  # several blocks
    lazy = contact(surf, points)
    assert isinstance(lazy.M, blocks.Hessians) and lazy.M.shape == whole.M.shape
    np.testing.assert_array_equal(lazy.gap, whole.gap)
    np.testing.assert_array_equal(lazy.N, whole.N)
    np.testing.assert_array_equal(np.asarray(lazy.M), whole.M)
    for k in (0, len(whole) // 2, len(whole) - 1):
        np.testing.assert_array_equal(lazy[k].M, whole[k].M)
    m, n = len(points), len(nodes)
    cd, td = np.arange(3 * m).reshape(m, 3), 3 * m + np.arange(3 * n).reshape(n, 3)
    K1 = lazy.tangent(2.0, cd, td).toarray()
    np.testing.assert_allclose(K1, whole.tangent(2.0, cd, td).toarray(), rtol=0,
                               atol=1e-14 * np.abs(K1).max())


def test_one_pairing_type_on_every_surface_and_a_patched_target():
    """Issue 22's sibling 21, item 3: `Contact.pairing` is a `Pairing` on every surface, and
    `contact(..., pairing=c.pairing)` takes it back, a PatchedSurface of several patches too
    (each contactor to what answered it: its patch's diffuse element or the facets'). At the
    same coordinates the frozen call gives the same elements; on moved contactors and target
    nodes (`surface.moved`) its 𝒩 is the derivative of its gap (central differences)."""
    import trimesh

    from diffsurf_cli.patches.surface import PatchedSurface
    from diffsurf_cli.projection import Pairing

    box = trimesh.creation.box(extents=(1.0, 0.8, 0.6)).subdivide().subdivide()
    nodes, faces = np.asarray(box.vertices), np.asarray(box.faces)
    rng = np.random.default_rng(12)
    points = rng.uniform([-0.48, -0.38, -0.28], [0.48, 0.38, 0.28], (400, 3))
    edge = rng.uniform(-0.25, 0.25, 40)  # just outside a vertical edge: the facets answer
    points = np.vstack([points, np.column_stack([np.full(40, 0.51), np.full(40, 0.41),
                                                 edge])])
    surfaces = {"patched": PatchedSurface(nodes, [faces]),
                "diffuse": DiffuseSurface(nodes, [faces]), "facet": FacetSurface(nodes, [faces])}
    for name, surf in surfaces.items():
        c = contact(surf, points)
        assert isinstance(c.pairing, Pairing) and len(c.pairing.source) == len(points), name
        again = contact(surf, points, pairing=c.pairing)
        np.testing.assert_array_equal(again.contactor, c.contactor, err_msg=name)
        np.testing.assert_allclose(again.gap, c.gap, rtol=0, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(again.N, c.N, rtol=0, atol=1e-10, err_msg=name)
    c = contact(surfaces["patched"], points)
    assert surfaces["patched"].npatches > 1 and len(c) > 50
    assert (c.pairing.source >= 0).any() and (c.pairing.source == -1).any()
    # derivatives on a moving target: contactors and target nodes along d
    d_pts = rng.standard_normal(points.shape)
    d_nodes = rng.standard_normal(nodes.shape)
    h = 1e-7  # a contactor's gap bends sharply (fd at 1e-6 is 1.5e-5 off, at 1e-7 1.5e-7)

    def gaps(t):
        moved = surfaces["patched"].moved(nodes + t * d_nodes)
        return contact(moved, points + t * d_pts, pairing=c.pairing, second=False)

    plus, minus = gaps(h), gaps(-h)
    np.testing.assert_array_equal(plus.contactor, c.contactor)
    np.testing.assert_array_equal(minus.contactor, c.contactor)
    fd = (plus.gap - minus.gap) / (2 * h)
    Nd = np.einsum("ek,ek->e", c.N[:, :3], d_pts[c.contactor])
    for j in range(c.nodes.shape[1]):
        live = c.nodes[:, j] >= 0
        Nd[live] += np.einsum("ek,ek->e", c.N[live, 3 * j + 3:3 * j + 6],
                              d_nodes[c.nodes[live, j]])
    np.testing.assert_allclose(fd, Nd, rtol=0, atol=1e-6 * np.abs(Nd).max())


def test_deep_contactors_on_a_second_order_target():
    """The faceted foot of a deep contactor on a target of second-order cells (triangle6) is
    taken on their corners: every contactor half a radius deep gets an element, and one 5
    radii out is open."""
    shape = Sphere(radius=1.0)
    nodes, tri = shape.mesh(6)
    pts, mids, t6 = list(nodes), {}, []
    for f in tri:
        row = list(f)
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            key = (min(a, b), max(a, b))
            if key not in mids:
                m = 0.5 * (nodes[a] + nodes[b])
                mids[key] = len(pts)
                pts.append(m / np.linalg.norm(m))
            row.append(mids[key])
        t6.append(row)
    surf = DiffuseSurface(np.array(pts), [np.array(t6)])
    on = shape.sample_near(20, 0.0, rng=1)
    normal = shape.closest(on)[1]
    c = contact(surf, np.vstack([on - 0.5 * normal, on + 5 * normal]), rigid_target=True)
    np.testing.assert_array_equal(c.contactor, np.arange(20))
    assert (c.status[20:] == OPEN).all() and len(c.lost) == 0
    np.testing.assert_allclose(c.gap, -0.5, atol=0.01)
