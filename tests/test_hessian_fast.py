"""ℳ at compiled speed (issue 33, item 1): the fast ℳ kernel (register-tiled product of the
factors, the node blocks' rotations as two 3x3 products) against the kernel it replaced
(`_element.elements(..., reference=True)`: rank-one row updates, quadruple sums), and the
tangent whose ℳ is built and added at once (`Hessians.tangent`, `_element.tangent_elements`)
against the numpy path with the reference ℳ (tests/test_tangent_compiled.py's
`reference_tangent`).

Curved targets: a sphere (DiffuseSurface) and a filleted box from gmsh (the default
PatchedSurface: diffuse patches on the flats, the fillets and the corners)."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from diffsurf_cli import contact
from diffsurf_cli.element import _element, blocks
from test_tangent_compiled import (  # noqa: F401
    REL,
    _cases,
    _dofs,
    _same,
    _sphere_scene,
    fillet_box,
    reference_tangent,
    sphere,
)


@pytest.fixture
def reference(monkeypatch):
    """Every diffuse ℳ built by the reference kernel while it is active."""
    def use():
        monkeypatch.setattr(_element, "elements",
                            functools.partial(_element.elements, reference=True))
    return use


@pytest.mark.parametrize("scene", ["sphere", "fillet_box"])
def test_hessian_is_the_reference_kernels(scene, request, monkeypatch, reference):
    """ℳ of every element, whole and built on demand, equals the reference kernel's to
    round-off (1e-13 of the largest entry), NaN-free."""
    surf, points = request.getfixturevalue(scene)
    c = contact(surf, points)
    assert len(c) > 50 and isinstance(c.M, np.ndarray)
    M = np.asarray(c.M)
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 0)
    lazy = np.asarray(contact(surf, points).M)
    reference()
    ref = np.asarray(contact(surf, points).M)
    assert np.isfinite(ref).all() and np.abs(ref).max() > 0
    scale = np.abs(ref).max()
    assert np.abs(M - ref).max() <= REL * scale
    np.testing.assert_array_equal(lazy, M)  # on demand: the same numbers


@pytest.mark.parametrize("scene", ["sphere", "fillet_box"])
def test_fused_tangent_is_the_reference(scene, request, monkeypatch, reference):
    """ℳ on demand: on a DiffuseSurface the tangent builds each ℳ and adds it at once
    (`Hessians.tangent`), equal to the numpy sum of the reference kernel's ℳ to round-off,
    with per-contactor penalties, multipliers (inactive elements), DOFs absent; on the
    filleted box too (its parts' ℳ, summed as before)."""
    surf, points = request.getfixturevalue(scene)
    rng = np.random.default_rng(12)
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 0)
    monkeypatch.setattr(blocks, "TANGENT_BATCH", 20_000)  # several calls of the kernel
    c = contact(surf, points, near=0.05)
    assert isinstance(c.M, blocks.Hessians)
    if scene == "sphere":
        assert c.M.tangent is not None
    reference()
    ref_c = contact(surf, points, near=0.05)
    m, n = len(points), c.n_target
    for holes in (False, True):
        cd, td = _dofs(m, n, rng, holes)
        for penalty, lam in _cases(c, rng):
            _same(c.tangent(penalty, cd, td, multipliers=lam),
                  reference_tangent(ref_c, penalty, cd, td, multipliers=lam))


def test_fused_tangent_without_elements_and_failed(monkeypatch):
    """The fused kernel's edges: no element (an empty sum) and a row it cannot take (a node
    past the target: refused with one line, nothing summed silently)."""
    surf, points = _sphere_scene()
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 0)
    c = contact(surf, points)
    m, n = len(points), c.n_target
    cd, td = np.arange(3 * m).reshape(m, 3), 3 * m + np.arange(3 * n).reshape(n, 3)
    K = c.tangent(1.0, cd, td)
    assert K.nnz and np.isfinite(K.data).all()
    none = contact(surf, points * 2.0)
    assert len(none) == 0 and none.tangent(1.0, cd, td).nnz == 0
    e, K1 = 3, c.nodes.shape[1]
    bad = np.full((e, K1), -1, np.int64)
    bad[:, 0] = n + 5
    z = np.zeros((e, 3))
    with pytest.raises(ValueError, match="beyond"):
        _element.tangent_elements(surf.nodes, z, z, np.zeros((e, 3, 3)), np.ones(e), z, bad,
                                  surf.basis, surf.weight, np.zeros((e, K1 + 1), np.int64),
                                  np.zeros((e, 3 * (K1 + 1))), np.ones(e), np.ones(e),
                                  np.zeros((0, 3)), np.zeros((0, 3, 3)),
                                  np.zeros((1, 3), np.int64), np.zeros(2, np.int64),
                                  np.zeros(1, np.int32), np.zeros(1, np.int32),
                                  np.zeros((1, 3), np.int64), np.zeros(1))
