"""The tangent summed in compiled code (issue 33, item 1; `element._assembly`) against the
numpy path it replaced (kept here as the reference: each element's dense block formed in
numpy, summed by scipy's COO -> CSR), and `Contact.blocks` (item 2) against both.

Scenes: a sphere (DiffuseSurface) and a filleted box read from gmsh (the default
PatchedSurface: diffuse patches and the facets), with per-contactor penalties, inactive
elements (multipliers that cancel the penalty force), target DOFs absent (-1) or negative,
multipliers, Gauss-Newton, ℳ built on demand, DOFs shared or numbered out of node order, a
rigid target with friction, and empty contacts."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from diffsurf_cli import Coulomb, contact
from diffsurf_cli.element import blocks
from diffsurf_cli.element.element import Contact, _SparseSum, assemble
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.testing.shapes import Sphere

REL = 1e-13  # round-off: the compiled sum adds the same numbers in another order


def reference_tangent(c, penalty, contactor_dofs, target_dofs=None, n_dofs=None, *,
                      gauss_newton=False, multipliers=None):
    """The numpy path `Contact.tangent` had before issue 33: dense (width x width) blocks
    eps 𝒩𝒩ᵀ + p ℳ (+ the multipliers' and friction's terms) per element, then scipy's COO
    sum of duplicates (`_SparseSum`), `blocks.TANGENT_BATCH` entries at a time."""
    size = c._size(n_dofs, contactor_dofs, target_dofs)
    if c.M is None and not gauss_newton:
        raise ValueError("the tangent needs ℳ")
    dofs = c.dofs(contactor_dofs, target_dofs)
    eps, p, lam = c._normal(penalty, multipliers)
    eps = np.where(p < 0, eps, 0.0)
    dT = (c._tangential(penalty, curvature=not gauss_newton, multipliers=multipliers)[1]
          if c.friction is not None else None)
    total = _SparseSum((size, size))
    width = dofs.shape[1]
    step = max(1, blocks.TANGENT_BATCH // (width * width))
    for lo in range(0, len(c), step):  # a batch of elements at once (bounded memory)
        hi = min(lo + step, len(c))
        N, d = c.N[lo:hi], dofs[lo:hi]
        vals = eps[lo:hi, None, None] * N[:, :, None] * N[:, None, :]
        if not gauss_newton:
            M = c.M[lo:hi]
            vals += p[lo:hi, None, None] * M
            if lam is not None:  # ∂(λ·ν)/∂u = ℳ[:3]ᵀ λ, where active
                grad = np.einsum("eij,ei->ej", M[:, :3, :], lam[lo:hi])
                vals += (eps[lo:hi] > 0)[:, None, None] * N[:, :, None] * grad[:, None, :]
        if dT is not None:
            vals[:, :3, :3] += dT[lo:hi]
        rows = np.broadcast_to(d[:, :, None], vals.shape)
        cols = np.broadcast_to(d[:, None, :], vals.shape)
        keep = (rows >= 0) & (cols >= 0)
        total.add(rows[keep], cols[keep], vals[keep])
    return total.result()


def _same(K, ref):
    """K equals the reference to round-off, entry by entry, and is canonical CSR (its
    pattern may hold more explicit zeros: the inactive elements' blocks, which the
    reference's sums of parts drop)."""
    assert isinstance(K, sp.csr_matrix) and K.shape == ref.shape
    assert K.has_canonical_format
    scale = max(abs(ref).max(), 1e-300) if ref.nnz else 1.0
    diff = abs(K - ref)
    assert (diff.max() if diff.nnz else 0.0) <= REL * scale
    assert K.nnz >= ref.nnz


def _sphere_scene():
    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(10)
    surf = DiffuseSurface(nodes, [faces])
    on = shape.sample_near(300, 0.0, rng=3)
    depth = np.random.default_rng(4).uniform(-0.03, 0.04, len(on))  # some open
    points = on - depth[:, None] * shape.closest(on)[1]
    return surf, points


@pytest.fixture(scope="module")
def sphere():
    return _sphere_scene()


@pytest.fixture(scope="module")
def fillet_box(tmp_path_factory):
    """A filleted box from gmsh as the default PatchedSurface, contactors within 0.02 of
    its surface (inside and out: elements where they penetrate)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import surface_from_file
    from diffsurf_cli.testing import gmsh_scenes
    from diffsurf_cli.testing.feature_scenes import _box_sdf

    hi = np.array([2.0, 1.0, 1.0])
    path = gmsh_scenes.fillet_box(tmp_path_factory.mktemp("tangent") / "f.msh", *hi,
                                  fillet=0.25, size=0.12)
    _, surf = surface_from_file(str(path))
    points = np.random.default_rng(5).uniform(-0.05, hi + 0.05, (40000, 3))
    sdf = _box_sdf(points, np.full(3, 0.25), hi - 0.25) - 0.25
    return surf, points[np.abs(sdf) < 0.02][:600]


def _dofs(m, n, rng, holes=True):
    """Contactor DOFs 0..3m-1 and target DOFs after them, shuffled by node; with `holes`,
    some of either set to -1 or another negative number (no DOF)."""
    cd = np.arange(3 * m).reshape(m, 3)
    td = 3 * m + rng.permutation(n)[:, None] * 3 + np.arange(3)
    if holes:
        cd[rng.random((m, 3)) < 0.1] = -1
        td[rng.random((n, 3)) < 0.1] = -1
        td[rng.random((n, 3)) < 0.05] = -7
    return cd, td


def _cases(c, rng):
    """(penalty, multipliers) cases: a scalar, one per contactor, and multipliers (some 0),
    within the contact's `near` (0.05): the open contactors' elements of which λ + ε g >= 0
    are inactive (p = 0)."""
    m = len(c.status)
    per = rng.uniform(0.5, 3.0, m)
    lam = -rng.uniform(0.0, 0.02, m)
    lam[::3] = 0.0
    return [(2.0, None), (per, None), (per, lam)]


@pytest.mark.parametrize("scene", ["sphere", "fillet_box"])
def test_compiled_tangent_is_the_numpy_one(scene, request, monkeypatch):
    surf, points = request.getfixturevalue(scene)
    rng = np.random.default_rng(6)
    near = 0.05
    c = contact(surf, points, near=near)
    assert len(c) > 50
    m, n = len(points), c.n_target
    for holes in (False, True):
        cd, td = _dofs(m, n, rng, holes)
        for penalty, lam in _cases(c, rng):
            assert lam is None or Contact.reach(penalty, lam) < near
            for gn in (False, True):
                for target in (td, None):
                    K = c.tangent(penalty, cd, target, gauss_newton=gn, multipliers=lam)
                    ref = reference_tangent(c, penalty, cd, target, gauss_newton=gn,
                                            multipliers=lam)
                    _same(K, ref)
    # some elements inactive in the last case: their pattern stays, with zeros
    penalty, lam = _cases(c, rng)[2]
    assert (c._normal(penalty, lam)[1] == 0).any()
    # ℳ built on demand, several chunks
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 1000)
    monkeypatch.setattr(blocks, "TANGENT_BATCH", 5000)
    lazy = contact(surf, points, near=near)
    assert isinstance(lazy.M, blocks.Hessians)
    cd, td = _dofs(m, n, rng)
    _same(lazy.tangent(penalty, cd, td, multipliers=lam),
          reference_tangent(c, penalty, cd, td, multipliers=lam))


def test_compiled_tangent_with_shared_and_interleaved_dofs(sphere):
    """DOFs numbered by component (all x, then all y, then z: rows not in node order) and
    DOFs shared by a contactor and a target node (self-contact): the sum is still the
    reference's, canonical."""
    surf, points = sphere
    c = contact(surf, points)
    m, n = len(points), c.n_target
    rng = np.random.default_rng(7)
    total = m + n
    order = rng.permutation(total)
    by_component = (order[:, None] + np.arange(3)[None, :] * total)
    cd, td = by_component[:m], by_component[m:]
    _same(c.tangent(1.5, cd, td), reference_tangent(c, 1.5, cd, td))
    # contactor k shares its DOFs with the target node of its element's first support node
    cd, td = _dofs(m, n, rng, holes=False)
    first = c.nodes[:, 0]
    cd = cd.copy()
    cd[c.contactor[:20]] = td[first[:20]]
    _same(c.tangent(1.5, cd, td, n_dofs=3 * (m + n)),
          reference_tangent(c, 1.5, cd, td, n_dofs=3 * (m + n)))


def test_compiled_tangent_rigid_with_friction_and_empty():
    """A rigid target with friction (its ∂T/∂x on the contactor's block), and contacts
    without elements: empty matrices of the asked size."""
    shape = Sphere(radius=10.0)
    nodes, faces = shape.mesh(12)
    surf = DiffuseSurface(nodes, [faces])
    rng = np.random.default_rng(8)
    d = np.column_stack([rng.uniform(-0.4, 0.4, (40, 2)), np.ones(40)])
    x0 = d / np.linalg.norm(d, axis=1, keepdims=True) * 9.95
    friction = Coulomb(0.3)
    c0 = contact(surf, x0, rigid_target=True, friction=friction)
    dofs = np.arange(120).reshape(40, 3)
    c0.residual(1e3, dofs)
    c = contact(surf, x0 + [0.02, 0.01, 0.0], rigid_target=True, friction=friction,
                history=c0.history)
    for gn in (False, True):
        _same(c.tangent(1e3, dofs, gauss_newton=gn),
              reference_tangent(c, 1e3, dofs, gauss_newton=gn))
    assert (c.tractions(1e3).tangential != 0).any()
    outside = contact(surf, x0 * 1.1)
    assert len(outside) == 0
    K = outside.tangent(1.0, dofs, 1000 + np.arange(3 * len(nodes)).reshape(-1, 3))
    assert K.shape == (1000 + 3 * len(nodes),) * 2 and K.nnz == 0
    none = contact(surf, np.zeros((0, 3)))
    K = none.tangent(1.0, np.zeros((0, 3), int), n_dofs=5)
    assert K.shape == (5, 5) and K.nnz == 0


def test_assemble_is_the_sum_of_chunks(sphere):
    """`assemble` (two passes: the pattern, then the chunks) equals one contact's tangent
    and residual, whatever the chunk."""
    surf, points = sphere
    m = len(points)
    c = contact(surf, points)
    cd, td = _dofs(m, c.n_target, np.random.default_rng(9))
    ref = c.tangent(2.0, cd, td)
    for chunk in (1, 37, 1000):
        R, K, status = assemble(surf, points, 2.0, cd, td, chunk=chunk)
        _same(K, ref)
        np.testing.assert_allclose(R, c.residual(2.0, cd, td), rtol=0, atol=1e-15)
        np.testing.assert_array_equal(status, c.status)


@pytest.mark.parametrize("gauss_newton", [False, True])
def test_blocks_sum_to_tangent_and_residual(sphere, gauss_newton):
    """Item 2: `Contact.blocks` yields each element's dense K and R blocks with their DOFs;
    scattered by the caller (dropping DOFs -1), they sum to `tangent` and `residual`."""
    surf, points = sphere
    m = len(points)
    c = contact(surf, points, near=0.05)
    rng = np.random.default_rng(10)
    cd, td = _dofs(m, c.n_target, rng)
    penalty, lam = _cases(c, rng)[2]
    size = c._size(None, cd, td)
    K = sp.csr_matrix((size, size))
    R = np.zeros(size)
    seen = []
    for elements, dofs, Kb, Rb in c.blocks(penalty, cd, td, chunk=29,
                                           gauss_newton=gauss_newton, multipliers=lam):
        w = dofs.shape[1]
        assert Kb.shape == (len(elements), w, w) and Rb.shape == (len(elements), w)
        seen.append(elements)
        rows = np.broadcast_to(dofs[:, :, None], Kb.shape)
        cols = np.broadcast_to(dofs[:, None, :], Kb.shape)
        keep = (rows >= 0) & (cols >= 0)
        K = K + sp.coo_matrix((Kb[keep], (rows[keep], cols[keep])), shape=(size, size))
        np.add.at(R, dofs[dofs >= 0], Rb[dofs >= 0])
    np.testing.assert_array_equal(np.concatenate(seen), np.arange(len(c)))
    ref = c.tangent(penalty, cd, td, gauss_newton=gauss_newton, multipliers=lam)
    assert abs(K - ref).max() <= REL * abs(ref).max()
    np.testing.assert_allclose(R, c.residual(penalty, cd, td, multipliers=lam), rtol=0,
                               atol=1e-14 * np.abs(R).max())
    with pytest.raises(ValueError, match="chunk"):
        next(c.blocks(penalty, cd, td, chunk=0))


def test_tangent_and_assemble_memory_is_about_the_matrix(monkeypatch):
    """The Done-when's memory (issue 33): the peak of `Contact.tangent` and `assemble`
    (tracemalloc) within 1.3x the bytes of the CSR they return, ℳ's chunk held small
    (`blocks.TANGENT_BATCH`); the numpy blocks and scipy sums it replaced peaked at 3.2x
    here."""
    import tracemalloc

    monkeypatch.setattr(blocks, "TANGENT_BATCH", 100_000)
    shape = Sphere(radius=10.0)
    nodes, faces = shape.mesh(16)
    surf = DiffuseSurface(nodes, [faces])
    rng = np.random.default_rng(11)
    u = rng.standard_normal((4000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * (10.0 - rng.uniform(0.0, 0.25 * 0.7, (4000, 1)))
    m, n = len(points), len(nodes)
    cd, td = np.arange(3 * m).reshape(m, 3), 3 * m + np.arange(3 * n).reshape(n, 3)
    c = contact(surf, points)
    assert len(c) == m
    # assemble in chunks small enough that each chunk's ℳ would be built whole (before
    # `blocks.always_on_demand`: 2.4x K at 256, 3.7x at 512, the chunk's ℳ held whole)
    for run in (lambda: c.tangent(1.0, cd, td), lambda: assemble(surf, points, 1.0, cd, td)[1],
                lambda: assemble(surf, points, 1.0, cd, td, chunk=256)[1],
                lambda: assemble(surf, points, 1.0, cd, td, chunk=512)[1]):
        tracemalloc.start()
        K = run()
        top = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert top <= 1.3 * (K.data.nbytes + K.indices.nbytes + K.indptr.nbytes)


def reference_pattern(ids, id_dofs, n_dofs, order):
    """`_assembly.pattern` the obvious way: the node graph as BᵀB of the element-node
    incidence B (scipy), each node row sorted by its columns' rank in `order`, expanded to
    DOFs node by node."""
    nv = (id_dofs >= 0).sum(axis=1)
    valid = (ids >= 0) & (nv[np.where(ids >= 0, ids, 0)] > 0)
    rows = np.nonzero(valid)[0]
    B = sp.csr_matrix((np.ones(len(rows)), (rows, ids[valid])),
                      shape=(len(ids), len(id_dofs)))
    G = (B.T @ B).tocsr()
    rank = np.empty(len(id_dofs), np.int64)
    rank[order] = np.arange(len(order))
    pat_col = np.concatenate([sorted(G.indices[G.indptr[a]:G.indptr[a + 1]],
                                     key=lambda b: rank[b]) for a in range(len(id_dofs))]
                             + [np.zeros(0, np.int64)]).astype(np.int32)
    pat_off = np.zeros(len(pat_col), np.int32)
    segment = []
    for a in range(len(id_dofs)):
        cols = pat_col[G.indptr[a]:G.indptr[a + 1]]
        pat_off[G.indptr[a]:G.indptr[a + 1]] = np.concatenate([[0], np.cumsum(nv[cols])[:-1]])
        segment.append(np.concatenate([id_dofs[b][id_dofs[b] >= 0] for b in cols]
                                      + [np.zeros(0, np.int64)]))
    dof_rows = [[] for _ in range(n_dofs)]
    where = np.full(id_dofs.shape, -1, np.int64)
    for a in range(len(id_dofs)):
        for k in range(3):
            r = id_dofs[a, k]
            if r >= 0 and len(segment[a]):
                where[a, k] = sum(len(s) for s in dof_rows[r])
                dof_rows[r].append(segment[a])
    row = [np.concatenate(s + [np.zeros(0, np.int64)]) for s in dof_rows]
    indptr = np.concatenate([[0], np.cumsum([len(x) for x in row])]).astype(np.int64)
    base = np.where(where >= 0, indptr[np.clip(id_dofs, 0, None)] + where, -1)
    canonical = all(np.all(np.diff(x) > 0) for x in row)
    return (indptr, np.concatenate(row), base, G.indptr.astype(np.int64), pat_col, pat_off,
            canonical)


@pytest.mark.parametrize("scene", ["sphere", "fillet_box"])
def test_pattern_is_the_reference_one(scene, request):
    """The symbolic pass (`_assembly.pattern`: CSR rows, the node rows and their offsets,
    `canonical`) equals `reference_pattern` element for element, with DOF holes and with
    DOFs numbered by component and shared (non-canonical rows)."""
    from diffsurf_cli.element import _assembly
    from diffsurf_cli.element.element import _node_dofs, _node_ids

    surf, points = request.getfixturevalue(scene)
    c = contact(surf, points)
    m, n = len(points), c.n_target
    rng = np.random.default_rng(11)
    holes = _dofs(m, n, rng)
    shared_cd, shared_td = _dofs(m, n, rng, holes=False)
    shared_cd[c.contactor[:20]] = shared_td[c.nodes[:20, 0]]
    total = m + n
    by_component = rng.permutation(total)[:, None] + np.arange(3)[None, :] * total
    ids = _node_ids(c, 0, m)
    for cd, td in (holes, (shared_cd, shared_td), (by_component[:m], by_component[m:])):
        id_dofs = _node_dofs(cd, td, m, n)
        valid = np.where(id_dofs >= 0, id_dofs, np.iinfo(np.int64).max)
        order = np.argsort(valid.min(axis=1), kind="stable").astype(np.int64)
        got = _assembly.pattern(ids, id_dofs, 3 * total, order, np.empty(0, np.int32))
        want = reference_pattern(ids, id_dofs, 3 * total, order)
        for g, r in zip(got[:-1], want[:-1]):
            np.testing.assert_array_equal(g, r)
        assert got[-1] == want[-1]
    assert not got[-1]  # the rows by component are out of node order


@pytest.mark.parametrize("scene", ["sphere", "fillet_box"])
def test_residual_scatter_is_add_at(scene, request):
    """`element._scatter_add` (the residual's sum in compiled code) gives np.add.at's
    numbers over `Contact.dofs`, bitwise (the same additions in the same order), with DOFs
    absent or negative, shared and out of node order, no target DOFs, and no elements."""
    from diffsurf_cli.element.element import _scatter_add

    surf, points = request.getfixturevalue(scene)
    rng = np.random.default_rng(11)
    c = contact(surf, points, near=0.05)
    m, n = len(points), c.n_target
    assert len(c) > 50
    cd, td = _dofs(m, n, rng)
    shared = td.copy()
    shared[1::2] = shared[::2][:len(shared[1::2])]  # two nodes on one DOF
    vals = rng.standard_normal(c.N.shape)
    for target in (td, shared, None):
        size = c._size(None, cd, target)
        ref = np.zeros(size)
        dofs = c.dofs(cd, target)
        np.add.at(ref, dofs[dofs >= 0], vals[dofs >= 0])
        out = np.zeros(size)
        _scatter_add(out, c, cd, target, vals)
        assert np.array_equal(out, ref)
    with pytest.raises(ValueError, match="contactor_dofs"):
        _scatter_add(np.zeros(10), c, cd[:-1], td, vals)
    with pytest.raises(ValueError, match="target_dofs"):
        _scatter_add(np.zeros(10), c, cd, td[:-1], vals)
    none = contact(surf, points[:0])
    out = np.zeros(3)
    _scatter_add(out, none, np.zeros((0, 3), np.int64), None, none.N)
    assert not out.any()


def test_contact_arrays_are_the_widest_elements_own(sphere):
    """`contact`'s nodes, 𝒩 (and ℳ whole) are arrays of their own, as wide as the widest
    element: not views of arrays as wide as the pairing's support (nodes of zero weight
    included, twice as wide or more), which every chunk's elements were copied into."""
    surf, points = sphere
    for second in (True, False):
        c = contact(surf, points, second=second)
        widest = int((c.nodes >= 0).sum(axis=1).max())
        assert c.nodes.shape[1] == widest and c.N.shape[1] == 3 * (widest + 1)
        for a in (c.nodes, c.N) + ((c.M,) if second else ()):
            assert a.flags.c_contiguous and a.flags.owndata
