"""The compiled diffuse element (diffsurf_cli.element.diffuse) against its jet oracle.

tests/oracle_element.py differentiates the same function by forward-mode jets over every
unknown; the compiled engine uses structured analytic derivatives (adjoints, node-local
blocks, the implicit function theorem on [30]). They must agree to 1e-10, relative
(|Δg| / R, ‖Δ𝒩‖ / ‖𝒩‖, ‖Δℳ‖ / ‖ℳ‖), on every scene of test_element.py plus a torus and a
saddle in local frames, for every basis and weight, with and without ℳ. The Taylor tests of
test_element.py check the compiled element against finite differences of the projection.
"""
from __future__ import annotations

import numpy as np
import pytest

import oracle_element
from diffsurf_cli.element.diffuse import diffuse_elements
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import PENETRATION, Patch
from diffsurf_cli.testing.element_scenes import ALL_SCENES, pairing
from test_element import BASES, SLOW_BASES, WEIGHTS

AGREE = 1e-10


def diffuse_element(surface, contactor, index, origin, axes, radius, proximal_point):
    """The diffuse element of one contactor, as `diffuse_elements` of one row: (gap, nodes,
    N, M) with the padding removed."""
    patch = Patch(np.reshape(origin, (1, 3)), np.reshape(axes, (1, 3, 3)),
                  np.reshape(float(radius), (1,)), np.full(1, np.nan), np.reshape(index, (1, -1)),
                  np.full(1, -1, dtype=np.int8), np.full(1, np.nan))
    gap, nodes, N, M = diffuse_elements(surface, np.reshape(contactor, (1, 3)), patch,
                                        np.reshape(proximal_point, (1, 3)), [0])
    return float(gap[0]), nodes[0], N[0], M[0]


@pytest.mark.parametrize("scene", list(ALL_SCENES))
@pytest.mark.parametrize("weight", WEIGHTS)
@pytest.mark.parametrize("basis", SLOW_BASES)
def test_compiled_agrees_with_jet(scene, basis, weight):
    surf, points, proj, rows = pairing(scene, basis, weight)
    args = (surf, points, proj.patch, proj.proximal_point, rows)
    g0, nodes0, N0, M0 = oracle_element.diffuse_elements(*args)
    g1, nodes1, N1, M1 = diffuse_elements(*args)
    g2, nodes2, N2, M2 = diffuse_elements(*args, second=False)
    assert M2 is None
    assert np.array_equal(nodes1, nodes0) and np.array_equal(nodes2, nodes0)
    R = proj.patch.radius[rows]
    assert np.all(np.isfinite(g1))
    for g, N in ((g1, N1), (g2, N2)):
        assert np.all(np.abs(g - g0) / R <= AGREE), (g - g0) / R
        dN = np.linalg.norm(N - N0, axis=1) / np.linalg.norm(N0, axis=1)
        assert np.all(dN <= AGREE), dN
    dM = np.linalg.norm(M1 - M0, axis=(1, 2)) / np.linalg.norm(M0, axis=(1, 2))
    assert np.all(dM <= AGREE), dM
    # exactly symmetric, and the same 𝒩 whether ℳ is asked for or not
    assert np.array_equal(M1, np.swapaxes(M1, 1, 2))
    assert np.array_equal(N1, N2) and np.array_equal(g1, g2)


@pytest.mark.parametrize("weight", WEIGHTS)
def test_compiled_agrees_with_jet_knn(weight):
    """k-nearest supports (R from the farthest of the k) and duplicated target nodes."""
    nodes, faces, points, extra = ALL_SCENES["torus"]()
    nodes = np.vstack([nodes, nodes[:40]])  # copies: each position enters a support once
    surf = DiffuseSurface(nodes, faces, basis="quadratic", weight=weight, support="knn",
                          k=14, **extra)
    proj = surf.project(points, keep_patch=True)
    rows = np.flatnonzero(proj.status == PENETRATION)
    assert len(rows) >= 2
    args = (surf, points, proj.patch, proj.proximal_point, rows)
    g0, nodes0, N0, M0 = oracle_element.diffuse_elements(*args)
    g1, nodes1, N1, M1 = diffuse_elements(*args)
    assert np.array_equal(nodes1, nodes0)
    assert np.all(np.abs(g1 - g0) / proj.patch.radius[rows] <= AGREE)
    assert np.all(np.linalg.norm(N1 - N0, axis=1) <= AGREE * np.linalg.norm(N0, axis=1))
    assert np.all(np.linalg.norm(M1 - M0, axis=(1, 2))
                  <= AGREE * np.linalg.norm(M0, axis=(1, 2)))


def test_batch_layout():
    """Rows of different support sizes in one call: -1 / zero padding, each row as if alone
    (the per-thread scratch keeps nothing from the previous element), in any order."""
    surf, points, proj, rows = pairing("sphere", "quadratic", "wendland")
    # a third contactor whose support is cut to fewer nodes: a narrower element in the batch
    patch = proj.patch
    index = np.full((len(points) + 1, patch.index.shape[1]), -1)
    index[:-1] = patch.index
    alive = np.flatnonzero(patch.index[rows[0]] >= 0)
    index[-1, :len(alive) - 4] = patch.index[rows[0], alive[:-4]]
    patch = Patch(*(np.concatenate([a, a[rows[0]][None]]) for a in
                    (patch.origin, patch.axes, patch.radius, patch.spacing)), index)
    points = np.vstack([points, points[rows[0]]])
    proximal = np.vstack([proj.proximal_point, proj.proximal_point[rows[0]]])
    rows = np.concatenate([rows, [len(points) - 1]])
    g, nodes, N, M = diffuse_elements(surf, points, patch, proximal, rows)
    count = (nodes >= 0).sum(axis=1)
    assert nodes.shape[1] == count.max() and count.min() < count.max()
    for e, i in enumerate(rows):
        n = count[e]
        assert np.all(nodes[e, n:] == -1) and np.all(nodes[e, :n] >= 0)
        size = 3 * (n + 1)
        assert not N[e, size:].any() and not M[e, size:].any() and not M[e, :, size:].any()
        alone = diffuse_elements(surf, points, patch, proximal, [i])
        assert alone[0][0] == g[e]
        assert np.array_equal(alone[2][0], N[e, :size])
        assert np.array_equal(alone[3][0], M[e, :size, :size])
        # one contactor's element, alone, is the same computation
        g1, nodes1, N1, M1 = diffuse_element(surf, points[i], patch.index[i], patch.origin[i],
                                             patch.axes[i], patch.radius[i], proximal[i])
        assert g1 == g[e] and np.array_equal(nodes1, nodes[e, :n])
        assert np.array_equal(N1, N[e, :size]) and np.array_equal(M1, M[e, :size, :size])
    back = diffuse_elements(surf, points, patch, proximal, rows[::-1])
    assert np.array_equal(back[0], g[::-1]) and np.array_equal(back[2], N[::-1])
    assert np.array_equal(back[3], M[::-1])


def test_trouble_is_nan():
    """A support too small for the basis, or a NaN contactor, gives NaN on that element only
    (its padding still zero), never an exception or a plausible number."""
    surf, points, proj, rows = pairing("sphere", "quadratic", "wendland")
    patch = proj.patch
    index = patch.index.copy()
    alive = np.flatnonzero(index[rows[0]] >= 0)
    index[rows[0], alive[4:]] = -1  # 4 nodes for 6 basis terms
    points = points.copy()
    points[rows[1]] = np.nan
    cut = Patch(patch.origin, patch.axes, patch.radius, patch.spacing, index)
    g, nodes, N, M = diffuse_elements(surf, points, cut, proj.proximal_point, rows)
    good = diffuse_elements(surf, points, patch, proj.proximal_point, rows[2:])
    assert np.isnan(g[:2]).all() and np.array_equal(g[2:], good[0])
    n0 = (nodes[0] >= 0).sum()
    assert n0 <= 4
    assert np.isnan(N[0, :3 * (n0 + 1)]).all() and not N[0, 3 * (n0 + 1):].any()
    assert np.isnan(M[0, :3 * (n0 + 1), :3 * (n0 + 1)]).all()
    assert not M[0, 3 * (n0 + 1):].any() and not M[0, :, 3 * (n0 + 1):].any()
    assert np.isnan(N[1]).any()


def test_empty_and_bad_rows():
    surf, points, proj, rows = pairing("sphere", "linear", "wendland")
    g, nodes, N, M = diffuse_elements(surf, points, proj.patch, proj.proximal_point, [])
    assert g.shape == (0,) and nodes.shape == (0, 0) and N.shape == (0, 3)
    assert M.shape == (0, 3, 3)
    with pytest.raises(IndexError):
        diffuse_elements(surf, points, proj.patch, proj.proximal_point, [len(points)])
    with pytest.raises(ValueError):
        diffuse_elements(surf, points[:-1], proj.patch, proj.proximal_point, rows)


def test_bases_cover_the_engine():
    """The compiled basis tables are the Python ones (mls/basis.py): every basis is tested."""
    from diffsurf_cli.mls import basis as _basis

    assert set(BASES) == set(_basis.BASES)


@pytest.mark.parametrize("kind", [3, 4], ids=["triangles", "quads"])
def test_facet_element_agrees_with_jet(kind):
    """The analytic node-to-facet element (element.facet) against its jet oracle, at interior,
    edge and vertex closest points, both sides, with and without ℳ."""
    from diffsurf_cli.element.facet import facet_element
    from diffsurf_cli.facet.surface import FacetSurface, free_parameters
    from test_element import QUAD_CASES, TRI_CASES, _facet_scene, _point_at

    nodes, faces, spacing = _facet_scene(kind)
    surf = FacetSurface(nodes, [faces])
    cases = TRI_CASES if kind == 3 else QUAD_CASES
    seen = set()
    for facet in (3, len(faces) // 2):
        ids = faces[facet]
        for ab, _ in cases:
            for depth in (-0.2, 0.15):
                xc = _point_at(nodes[ids], ab, depth * spacing)
                proj = surf.project_with(xc[None], [facet])
                xi = proj.param[0]
                seen.add(free_parameters(xi, kind))
                side = 1.0 if np.dot(xc - proj.proximal_point[0], proj.normal[0]) >= 0 else -1.0
                args = (nodes[ids], xc, xi, side, surf.sign)
                g0, N0, M0 = oracle_element.facet_element(*args)
                g1, N1, M1 = facet_element(*args)
                g2, N2, M2 = facet_element(*args, second=False)
                assert M2 is None and g2 == g1 and np.array_equal(N2, N1)
                assert abs(g1 - g0) <= AGREE * spacing
                assert np.linalg.norm(N1 - N0) <= AGREE * np.linalg.norm(N0)
                assert np.linalg.norm(M1 - M0) <= AGREE * np.linalg.norm(M0)
                assert np.array_equal(M1, M1.T)
    assert seen == {w for _, w in cases}


def test_gap_and_support_match_the_projection():
    """Over a cloud (a 1692-node sphere, 1000 contactors inside it, every basis and weight):
    the element's g is the projection's g, and its nodes are the projection's support of
    positive weight (Projection.support)."""
    from diffsurf_cli.testing.shapes import Sphere

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(13)
    rng = np.random.default_rng(7)
    u = rng.standard_normal((1000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * (1.0 - rng.uniform(0.0, 0.3, 1000) * shape.spacing(13))[:, None]
    for basis in BASES:
        for weight in WEIGHTS:
            surf = DiffuseSurface(nodes, [faces], basis=basis, weight=weight)
            proj = surf.project(points, keep_patch=True)
            rows = np.flatnonzero(proj.status == PENETRATION)
            assert len(rows) > 800
            g, ids, _, _ = diffuse_elements(surf, points, proj.patch, proj.proximal_point, rows,
                                            second=False)
            assert np.array_equal((ids >= 0).sum(axis=1), proj.support[rows])
            assert np.all(np.abs(g - proj.gap[rows]) <= 1e-13 * proj.patch.radius[rows])


def test_facet_elements_batch_is_each_row_alone_at_any_thread_count():
    """The compiled node-to-facet batch: each row is the one-element answer (bitwise), the
    same on 1 and 2 threads; a degenerate facet (collinear corners) gives a NaN row, and
    `contact` turns it into a 'failed' contactor, not an element."""
    from diffsurf_cli.element import _element
    from diffsurf_cli.element.facet import facet_element, facet_elements
    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.testing.shapes import Sphere

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(6)
    surf = FacetSurface(nodes, [faces])
    rng = np.random.default_rng(3)
    u = rng.standard_normal((3000, 3))
    points = u / np.linalg.norm(u, axis=1, keepdims=True) * rng.uniform(0.9, 1.0, (3000, 1))
    proj = surf.project(points)
    corners = surf.facets[proj.facet]
    side = np.where(np.einsum("ij,ij->i", points - proj.proximal_point, proj.normal) >= 0,
                    1.0, -1.0)
    gap, N, M = facet_elements(nodes, corners, points, proj.param, side)
    np.testing.assert_allclose(gap, proj.gap, rtol=0, atol=1e-15)  # the projection's gap
    for i in rng.choice(len(points), 40, replace=False):
        g1, N1, M1 = facet_element(nodes[corners[i, :3]], points[i], proj.param[i], side[i])
        assert g1 == gap[i] and np.array_equal(N1, N[i, :12]) and np.array_equal(M1, M[i, :12, :12])
        assert not N[i, 12:].any() and not M[i, 12:].any()
    for threads in (1, 2):
        m_ = len(points)
        g, n, m = np.empty(m_), np.zeros((m_, 15)), np.zeros((m_, 15, 15))
        _element.facet_elements(nodes, corners, points, np.ascontiguousarray(proj.param), side,
                                1.0, g, n, m, threads)
        assert np.array_equal(g, gap) and np.array_equal(n, N) and np.array_equal(m, M)
    flat = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    g, n, _ = facet_elements(flat, [[0, 1, 2, -1]], [[0.5, 0.3, 0.2]], [[0.3, 0.3]], [1.0])
    assert np.isnan(g[0]) and np.isnan(n[0, :12]).all()
