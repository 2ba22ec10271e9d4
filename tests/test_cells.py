"""A target's curved cells answer where the facets would (issue 19; `patches._pass.cells_answer`,
`Projection.source` `CELLS`): its second-order cells, or its first-order facets curved through
their corner normals (`patches.surface.cell_coefficients`).

- the compiled closest point on the cells is that of a slow, obvious reference: every cell
  sampled on a fine grid of its parameters, the nearest sample (a gmsh sphere of second order,
  and a first-order sphere, whose patches carry no diffuse surface, so that the cells answer
  everywhere);
- its gap, normal and curvatures are the sphere's to the cells' own accuracy; the first-order
  facets' curved edges are the same from both of their facets;
- on a second-order box with fillets about one cell wide, where the guard and narrow patches
  send points to the mesh's own answer, the cells answer them far closer to the CAD than the
  flat facets, with fewer wrong signs;
- the contact element there is the cell's (`element.cell`: the projection's gap, full and
  rigid target, its pairing frozen; on a first-order target's curved facets, the
  node-to-facet one for a deformable target), no contactor is dropped, `smooth` places its
  vertices on the cells, and a flat first-order target has no cells.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from diffsurf_cli.patches.surface import CELL_MONOMIALS, CELLS, FACETS, PatchedSurface
from diffsurf_cli.projection import GUARD, PENETRATION
from diffsurf_cli.testing.shapes import Sphere, Torus


def _read(path):
    from diffsurf_cli.targets import read_surface

    _, nodes, faces = read_surface(str(path))
    return nodes, faces


@pytest.fixture(scope="module", params=["triangle6", "triangle7"])
def sphere_cells(tmp_path_factory, request):
    """A unit gmsh sphere of triangle6 cells (or triangle7: each with its centre node, the
    cell's point at (1/3, 1/3) put on the sphere), as a PatchedSurface whose one patch
    carries no diffuse surface: the mesh's own answer (its cells, else its facets)
    everywhere."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.sphere_surface(tmp_path_factory.mktemp("cells") / "s.msh", size=0.35,
                                      order=2)
    nodes, faces = _read(path)
    if request.param == "triangle7":
        (tri6,) = faces
        at = np.array([-1, -1, -1, 4, 4, 4]) / 9          # tri6's shape functions at the centre
        centre = np.einsum("k,fkj->fj", at, nodes[tri6])
        centre /= np.linalg.norm(centre, axis=1, keepdims=True)
        faces = [np.column_stack([tri6, len(nodes) + np.arange(len(tri6))])]
        nodes = np.concatenate([nodes, centre])
    surf = PatchedSurface(nodes, faces, feature_angle=None)
    surf.surfaces = [None]
    surf._pass = None
    points = Sphere().sample_near(3000, 0.1, rng=3)
    return surf, nodes, faces, points


def _cell_samples(nodes, faces, n):
    """Every second-order cell's points on an n x n grid of its parameters (the slow, obvious
    reference: its shape functions evaluated directly), and the grid's largest step."""
    from diffsurf_cli.patches.surface import CELL_NODES

    out, step = [], 0.0
    for f in faces:
        k = f.shape[1]
        u = np.linspace(0.0, 1.0, n)
        a, b = (g.ravel() for g in np.meshgrid(u, u))
        if k in (6, 7):
            a, b = a[a + b <= 1], b[a + b <= 1]
        if k == 7:  # the textbook's: the quadratics and the bubble 27 λ1λ2λ3
            l1, l2, l3 = 1 - a - b, a, b
            bub = l1 * l2 * l3
            shape = np.stack([l1 * (2 * l1 - 1) + 3 * bub, l2 * (2 * l2 - 1) + 3 * bub,
                              l3 * (2 * l3 - 1) + 3 * bub, 4 * l1 * l2 - 12 * bub,
                              4 * l2 * l3 - 12 * bub, 4 * l3 * l1 - 12 * bub, 27 * bub], 1)
        else:
            V = np.array([[x ** i * y ** j for i, j in CELL_MONOMIALS[:k]]
                          for x, y in CELL_NODES[k]])
            shape = np.stack([a ** i * b ** j for i, j in CELL_MONOMIALS[:k]], 1) @ \
                np.linalg.inv(V)
        pts = np.einsum("sk,fkj->fsj", shape, nodes[f])
        out.append(pts.reshape(-1, 3))
        grid = pts.reshape(len(f), -1, 3)
        step = max(step, float(np.max(np.linalg.norm(np.diff(grid, axis=1), axis=2))))
    return np.concatenate(out), step


def test_cells_answer_the_closest_point_of_a_sampled_reference(sphere_cells):
    surf, nodes, faces, points = sphere_cells
    p = surf.project(points)
    cells = p.source == CELLS
    assert cells.mean() > 0.97, np.unique(p.source, return_counts=True)
    assert (p.status[cells] <= PENETRATION).all()
    samples, step = _cell_samples(nodes, faces, 61)
    brute, _ = cKDTree(samples).query(points[cells])
    dist = np.abs(p.gap[cells])
    # the compiled answer is a true minimum on a cell: no sample is nearer, and the nearest
    # sample is within the grid's step of it
    assert (dist <= brute + 1e-12).all()
    assert (brute - dist).max() < 0.5 * step
    # its proximal point is on the cells, its gap the signed distance to it along the normal
    on, _ = cKDTree(samples).query(p.proximal_point[cells])
    assert on.max() < step
    np.testing.assert_allclose(points[cells] - p.proximal_point[cells],
                               p.gap[cells, None] * p.normal[cells], atol=1e-12)


def test_cells_answer_as_the_sphere_does(sphere_cells):
    surf, _, _, points = sphere_cells
    p = surf.project(points)
    cells = p.source == CELLS
    exact = np.linalg.norm(points, axis=1) - 1.0
    facets = np.abs(p.facet_gap - exact)[cells]
    err = np.abs(p.gap - exact)[cells]
    assert np.sqrt(np.mean(err ** 2)) < 0.1 * np.sqrt(np.mean(facets ** 2))
    assert (np.sign(p.gap[cells]) == np.sign(exact[cells])).mean() > 0.99
    radial = points[cells] / np.linalg.norm(points[cells], axis=1, keepdims=True)
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", p.normal[cells], radial),
                                        -1, 1))).max() < 3.0
    # convex: both principal curvatures near the sphere's 1 (the cells' own curvature)
    np.testing.assert_allclose(np.median(p.curvature[cells], axis=0), 1.0, rtol=0.1)
    assert (p.curvature[cells] > 0).all()


@pytest.fixture(scope="module")
def fillet_box(tmp_path_factory):
    """A second-order box with fillets about one cell wide (CAD faces as tags) and contactors
    within 0.3 cells of it, with their exact gaps."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import surface_from_file
    from diffsurf_cli.testing import gmsh_scenes
    from diffsurf_cli.testing.feature_scenes import _box_sdf

    size, fillet, hi = 0.3, 0.15, np.array([2.0, 1.0, 1.0])
    path = gmsh_scenes.fillet_box(tmp_path_factory.mktemp("cells") / "f.msh", *hi,
                                  fillet=fillet, size=size, order=2)
    _, surf = surface_from_file(str(path))
    points = np.random.default_rng(2).uniform(-0.1, hi + 0.1, (60000, 3))
    exact = _box_sdf(points, np.full(3, fillet), hi - fillet) - fillet
    near = np.abs(exact) < 0.3 * size
    return path, surf, points[near][:8000], exact[near][:8000]


def test_cells_answer_where_the_facets_would_on_a_second_order_part(fillet_box):
    path, surf, points, exact = fillet_box
    p = surf.project(points)
    cells = p.source == CELLS
    assert cells.sum() > 50 and (p.reason[cells] == GUARD).sum() > 20
    err = np.abs(p.gap - exact)
    flat = np.abs(p.facet_gap - exact)
    assert np.sqrt(np.mean(err[cells] ** 2)) < 0.1 * np.sqrt(np.mean(flat[cells] ** 2))
    wrong = np.sign(p.gap) != np.sign(exact)
    assert wrong[cells].sum() < 0.2 * (np.sign(p.facet_gap) != np.sign(exact))[cells].sum()
    # the gap departs from the facets' by no more than the guard's envelope
    assert (np.abs(p.gap - p.facet_gap)[cells] <= surf.gap_bound[p.facet[cells]]).all()


def test_element_and_smooth_on_cells(fillet_box, monkeypatch):
    from diffsurf_cli.element import blocks
    from diffsurf_cli.element.element import contact
    from diffsurf_cli.smooth import refine, smooth

    path, surf, points, exact = fillet_box
    p = surf.project(points)
    cells = p.source == CELLS
    closed = cells & (p.status == PENETRATION)
    assert closed.sum() > 20
    for rigid in (False, True):
        c = contact(surf, points, rigid_target=rigid)
        # the element there is the cell's (node-to-cell): its gap is the projection's
        assert (c.projection.source[cells] == CELLS).all()
        np.testing.assert_allclose(c.projection.gap[cells], p.gap[cells], rtol=0, atol=1e-12)
        on = np.isin(c.contactor, np.flatnonzero(closed))
        np.testing.assert_array_equal(c.contactor[on], np.flatnonzero(closed))
        np.testing.assert_allclose(c.gap[on], p.gap[closed], rtol=0, atol=1e-12)
        np.testing.assert_allclose(c.N[on, :3], p.normal[closed], rtol=0, atol=1e-12)
        every = c.projection.status == PENETRATION
        assert np.array_equal(np.unique(c.contactor), np.flatnonzero(every))
    # full element: u = [x^c, the six nodes of the answering cell], and the pairing holds
    # that cell: the frozen pairing gives the same elements
    c_full = contact(surf, points)
    cell = c_full.pairing.facet[closed]
    assert (cell >= 0).all() and (surf.has_cell[cell] == 1).all()
    tri6 = np.concatenate(surf.faces)[cell]
    k = np.searchsorted(c_full.contactor, np.flatnonzero(closed))
    np.testing.assert_array_equal(np.sort(c_full.nodes[k][:, :6], axis=1), np.sort(tri6, axis=1))
    again = contact(surf, points, pairing=c_full.pairing)
    np.testing.assert_array_equal(again.contactor, c_full.contactor)
    np.testing.assert_allclose(again.gap, c_full.gap, rtol=0, atol=1e-12)
    np.testing.assert_allclose(again.N, c_full.N, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(again.M)[k], np.asarray(c_full.M)[k], rtol=0,
                               atol=1e-8 * np.abs(np.asarray(c_full.M)[k]).max())
    # a pairing naming no second-order cell where a cell answered is refused
    bad = c_full.pairing.take(np.arange(len(points)))
    bad.facet[np.flatnonzero(closed)[0]] = -1
    with pytest.raises(ValueError, match="cells this surface does not have"):
        contact(surf, points, pairing=bad)
    # beyond HESSIAN_BYTES, ℳ is built on demand: the same numbers
    monkeypatch.setattr(blocks, "HESSIAN_BYTES", 1000)
    lazy = contact(surf, points)
    assert isinstance(lazy.M, blocks.Hessians)
    np.testing.assert_array_equal(lazy.M[k], np.asarray(c_full.M)[k])
    # smooth: a vertex the cells answer is placed on them (not left on the flat facets)
    corners = [f[:, :3] for f in surf.faces]
    out = smooth(surf, corners, levels=1)
    used = np.unique(np.concatenate([f.ravel() for f in corners]))
    remap = np.full(len(surf.nodes), -1)
    remap[used] = np.arange(len(used))
    vertices, _ = refine(surf.nodes[used], [remap[f] for f in corners], 1)
    res = surf.project(vertices)
    on_cells = res.source == CELLS
    assert on_cells.sum() > 10
    assert (out.point_data["placed"][on_cells] == 1).all()
    np.testing.assert_array_equal(out.vertices[on_cells], res.proximal_point[on_cells])


def test_a_flat_first_order_target_has_no_cells():
    """A box's facets are flat: no curved cell, the facets answer as exactly as before."""
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0)).subdivide().subdivide()
    surf = PatchedSurface(np.asarray(box.vertices), [np.asarray(box.faces)])
    assert not surf.has_cell.any() and surf.cell_coef.shape == (1, 9, 3)
    # nor with one patch over the whole box: its edges are creases of the mesh all the same
    whole = PatchedSurface(np.asarray(box.vertices), [np.asarray(box.faces)], feature_angle=None)
    assert not whole.has_cell.any()
    points = np.random.default_rng(4).uniform(-1.2, 1.2, (2000, 3))
    assert not (surf.project(points).source == CELLS).any()


@pytest.fixture(scope="module", params=["sphere triangles", "torus quads"])
def curved_facets(request):
    """A first-order target whose one patch carries no diffuse surface (its facets curved
    through their corner normals answer everywhere), contactors near it and their exact
    gaps."""
    if request.param == "sphere triangles":
        shape = Sphere()
        nodes, faces = shape.mesh(4)
    else:
        shape = Torus(1.0, 0.4)
        nodes, faces = shape.mesh_quads(24)  # dihedral angles below 40°: no crease
    surf = PatchedSurface(nodes, [faces], feature_angle=None)
    surf.surfaces = [None]
    surf._pass = None
    points = shape.sample_near(3000, 0.05, rng=5)
    return surf, points, shape.closest(points)[2]


def test_first_order_facets_are_curved_through_their_normals(curved_facets):
    from diffsurf_cli.patches.surface import hermite_midsides

    surf, points, exact = curved_facets
    assert surf.has_cell.all()
    k = int(surf.kind[0])
    mid = hermite_midsides(surf)[:, :k]
    # one edge's mid-side node is the same from both of its facets (conforming cells)
    corners = surf.corners[:, :k]
    ends = np.sort(np.stack([corners, np.roll(corners, -1, axis=1)], axis=2),
                   axis=2).reshape(-1, 2)
    _, first, inverse = np.unique(ends, axis=0, return_index=True, return_inverse=True)
    np.testing.assert_allclose(mid.reshape(-1, 3), mid.reshape(-1, 3)[first][inverse.ravel()],
                               atol=1e-14)
    # the answers are the closest points on those cells (the sampled reference) ...
    p = surf.project(points)
    cells = p.source == CELLS
    assert cells.mean() > 0.97
    nodes = np.concatenate([surf.nodes, mid.reshape(-1, 3)])
    second = np.concatenate([corners, len(surf.nodes) + np.arange(k * len(mid)).reshape(-1, k)],
                            axis=1)
    samples, step = _cell_samples(nodes, [second], 41)
    brute, _ = cKDTree(samples).query(points[cells])
    dist = np.abs(p.gap[cells])
    assert (dist <= brute + 1e-12).all() and (brute - dist).max() < 0.5 * step
    # ... and far nearer the exact shape than the flat facets
    rms = np.sqrt(np.mean((p.gap - exact)[cells] ** 2))
    assert rms < 0.25 * np.sqrt(np.mean((p.facet_gap - exact)[cells] ** 2))


def test_cell_element_derivatives_through_the_target(fillet_box):
    """R and K of the node-to-cell element are derivatives in the target's own numbering:
    the contactor and the cell's GLOBAL nodes move (`PatchedSurface.moved`: its cells follow),
    the pairing (the cell) frozen; and, with a rigid target, the contactor alone."""
    from diffsurf_cli.element.element import contact
    from test_contact_api import _check_rigid_derivatives
    from test_element import _taylor

    path, surf, points, exact = fillet_box
    p = surf.project(points)
    curved = np.abs(p.curvature).max(axis=1) > 2.0    # on a fillet's cells (radius 0.15)
    deep = np.flatnonzero((p.source == CELLS) & curved & (p.gap < -0.02))[:3]
    assert len(deep) == 3
    rng = np.random.default_rng(8)
    c = contact(surf, points[deep])
    assert len(c) == 3 and (c.projection.source == CELLS).all()
    for k in range(len(c)):
        ids = c.nodes[k][c.nodes[k] >= 0]
        size = 3 * (len(ids) + 1)
        assert len(ids) == 6 and not c.N[k, size:].any()
        pair = c.pairing.take([k])

        def evaluate(v, ids=ids, pair=pair, size=size):
            moved = surf.nodes.copy()
            moved[ids] = v[3:].reshape(-1, 3)
            c2 = contact(surf.moved(moved), v[None, :3], pairing=pair)
            if len(c2) != 1:
                return None
            assert np.array_equal(c2.nodes[0][:len(ids)], ids)
            return c2.gap[0], c2.N[0, :size]

        u = np.concatenate([points[deep[k]], surf.nodes[ids].ravel()])
        _taylor(evaluate, u, c.gap[k], c.N[k, :size], c.M[k][:size, :size], 0.3, rng,
                f"cell element {k}")
    _check_rigid_derivatives(surf, points[deep], rng, "rigid cells")


def test_curved_first_order_facets_in_the_element(curved_facets):
    """A first-order facet curved through its normals: the rigid target's element is the
    cell's (the projection's gap); a deformable target's is the node-to-facet one."""
    from diffsurf_cli.element.element import contact

    surf, points, exact = curved_facets
    p = surf.project(points)
    cells = p.source == CELLS
    closed = cells & (p.status == PENETRATION)
    assert closed.sum() > 100
    rigid = contact(surf, points, rigid_target=True)
    assert (rigid.projection.source[cells] == CELLS).all()
    on = np.isin(rigid.contactor, np.flatnonzero(closed))
    np.testing.assert_allclose(rigid.gap[on], p.gap[closed], rtol=0, atol=1e-12)
    full = contact(surf, points)
    assert (full.projection.source[cells] == FACETS).all()
    np.testing.assert_allclose(full.projection.gap[cells], p.facet_gap[cells], rtol=0,
                               atol=1e-12)
    assert full.nodes.shape[1] == 4 and (full.pairing.facet[cells] == p.facet[cells]).all()


def test_a_cell_minimum_farther_than_the_foot_cell_is_not_an_answer(tmp_path):
    """A cells answer is no farther from x than the foot's own cell over the faceted foot:
    a nearer point of the cells exists there, so a farther interior minimum is not the
    closest point (`_pass.cells_answer`). On a first-order fillet box, points deep inside
    near its fillets, about one cell wide, meet such minima: without the check some answers
    here are farther (this test fails)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.element import cell
    from diffsurf_cli.targets import surface_from_file
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", 2.0, 1.0, 1.0, fillet=0.15, size=0.3,
                                  order=1)
    _, surf = surface_from_file(str(path))
    assert (surf.kind == 3).all()
    points = np.random.default_rng(0).uniform([-0.2, -0.1, -0.1], [2.2, 1.1, 1.1],
                                              (60000, 3))
    p = surf.project(points)
    on = np.flatnonzero((p.source == CELLS) & (surf.has_cell[np.maximum(p.facet, 0)] == 1))
    assert len(on) > 300
    f0 = p.facet[on]
    foot = points[on] - p.facet_gap[on, None] * p.facet_normal[on]
    c = surf.nodes[surf.corners[f0, :3]]  # f0's corners: its cell's (0, 0), (1, 0), (0, 1)
    e = np.stack([c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]], axis=2)
    ab = np.linalg.solve(np.einsum("nki,nkj->nij", e, e),
                         np.einsum("nki,nk->ni", e, foot - c[:, 0])[..., None])[..., 0]
    over = cell.evaluate(surf.cell_coef[f0], ab)[0]  # f0's cell over the faceted foot
    limit = np.linalg.norm(points[on] - over, axis=1)
    assert (np.abs(p.gap[on]) <= (1 + 1e-9) * limit + 1e-12).all()


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_chunked_assemble_with_cells_is_the_one_shot_assembly(fillet_box, rigid):
    """`assemble` in chunks of contactors is `contact`'s one-shot assembly where patches,
    facets and curved cells answer together."""
    from test_patch_element import check_chunked_assemble

    path, surf, points, exact = fillet_box
    p = surf.project(points)
    pick = np.concatenate([np.flatnonzero(p.source == CELLS)[:40],
                           np.flatnonzero(p.source >= 0)[:40]])
    c = check_chunked_assemble(surf, points[pick], rigid, np.random.default_rng(12))
    assert (c.projection.source[c.contactor] == CELLS).sum() >= 10
