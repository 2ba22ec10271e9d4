"""The contact element on a target of several smooth patches (`contact` on a PatchedSurface).

Each contactor's element is that of what answered it in the patched projection: its patch's
diffuse surface (node indices mapped to the target's nodes) or the target's facets. Checked:
the element's gap is the patched projection's (full element), exact on a box's flat faces and
facets (both modes); R and K are derivatives (Taylor, the global node numbering); a
single-facet patch (facets answer) and diffuse patches mix in one Contact; `assemble` chunked
is the one-shot assembly.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")  # the scenes are meshed by gmsh

from diffsurf_cli.element.element import assemble, contact
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import FAILED, OPEN, OUTSIDE, PENETRATION
from diffsurf_cli.targets import read_surface
from diffsurf_cli.testing import feature_scenes as fs
from diffsurf_cli.testing import gmsh_scenes
from test_contact_api import _check_rigid_derivatives, _dof_maps
from test_element import _taylor

LO, HI = np.zeros(3), np.array([2.0, 1.0, 1.0])


def _box_sdf(p):
    return fs._box_sdf(p, LO, HI)


def _patched(path, **opts):
    t, nodes, faces = read_surface(path, None)
    tags = None if t.tags is None else np.concatenate(t.tags)
    return PatchedSurface(nodes, faces, tags=tags, **opts)


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    path = gmsh_scenes.box(tmp_path_factory.mktemp("box") / "b.msh", size=0.25)
    surf = _patched(path)
    assert surf.npatches == 6
    return surf


@pytest.fixture(scope="module")
def fillet(tmp_path_factory):
    sc = fs.fillet_box(tmp_path_factory.mktemp("fillet"), size=0.1)
    t, nodes, faces = read_surface(sc.path, None)
    surf = PatchedSurface(nodes, faces)
    assert surf.npatches == 7  # 6 flat faces, the fillets with their corners
    return sc, surf


def _box_points():
    """Contactors of the box: under its faces, near its edges and corners, inside and out."""
    rng = np.random.default_rng(3)
    faces = []  # penetrating each face, away from its edges
    for axis in range(3):
        for side in (0, 1):
            p = rng.uniform(LO + 0.3, HI - 0.3, (4, 3))
            p[:, axis] = (LO if side == 0 else HI)[axis] + (0.06 if side == 0 else -0.06)
            faces.append(p)
    edges = np.array([[1.0, 0.03, 0.06], [0.7, 0.95, 0.04], [1.97, 0.5, 0.02],  # inside
                      [1.0, -0.05, -0.04], [0.3, 1.04, 1.03]])  # outside: the edge answers
    corners = np.array([[0.04, 0.05, 0.06], [1.95, 0.96, 0.97],  # inside
                        [-0.03, -0.04, -0.05], [2.02, 1.03, 1.01]])  # outside
    return np.vstack(faces + [edges, corners])


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_box_gaps_are_the_projections_and_exact(box, rigid):
    points = _box_points()
    proj = box.project(points)
    assert set(np.unique(proj.source)) >= {-1, 0, 1, 2, 3, 4, 5}  # every face, and the facets
    c = contact(box, points, rigid_target=rigid)
    pen = np.flatnonzero(proj.status == PENETRATION)
    exact = _box_sdf(points)
    if rigid:  # the rigid surface of a flat face is its plane: its gap is exact, where it
        # reaches (deeper contactors are 'outside' there: no element, never a wrong one)
        assert set(c.contactor) <= set(pen) and len(c) >= 0.8 * len(pen)
        assert (c.status[np.setdiff1d(pen, c.contactor)] == OUTSIDE).all()
        assert c.nodes.shape == (len(c), 0) and c.N.shape == (len(c), 3)
    else:
        np.testing.assert_array_equal(c.contactor, pen)
        np.testing.assert_allclose(c.gap, proj.gap[pen], rtol=0, atol=1e-14)
        assert c.nodes.shape[1] > 4  # the diffuse supports, padded to the widest
        assert (c.nodes < len(box.nodes)).all()
    np.testing.assert_allclose(c.gap, exact[c.contactor], rtol=0, atol=1e-13)
    np.testing.assert_allclose(c.projection.gap[c.contactor], c.gap, rtol=0, atol=1e-14)
    # ∂g/∂x^c is the face's outward normal, the unit vector of the exact gradient
    np.testing.assert_allclose(np.linalg.norm(c.N[:, :3], axis=1), 1.0, atol=1e-12)
    # open contactors (outside the box, the facets at its edges and corners) have none
    out = np.flatnonzero(exact > 0)
    assert (c.status[out] == OPEN).all() and not np.isin(out, c.contactor).any()
    np.testing.assert_allclose(c.projection.gap[out], exact[out], rtol=0, atol=1e-13)
    assert (proj.source[out] == -1).any()


def _quad_box(nx=8, ny=4, nz=4):
    """The surface of the box LO..HI as quads of an nx x ny x nz grid, outward; tags: the
    face (0-5), and one quad in the middle of the top face a patch of its own (6)."""
    ticks = [np.linspace(LO[a], HI[a], n + 1) for a, n in enumerate((nx, ny, nz))]
    index = {}
    nodes = []

    def node(i, j, k):
        key = (i, j, k)
        if key not in index:
            index[key] = len(nodes)
            nodes.append([ticks[0][i], ticks[1][j], ticks[2][k]])
        return index[key]

    dims = (nx, ny, nz)
    quads, tags = [], []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for side in (0, 1):
            for i in range(dims[u]):
                for j in range(dims[v]):
                    ids = []
                    for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        key = [0, 0, 0]
                        key[axis] = side * dims[axis]
                        key[u], key[v] = i + du, j + dv
                        ids.append(node(*key))
                    quads.append(ids)
                    tags.append(2 * axis + side)
    nodes, quads, tags = np.array(nodes, float), np.array(quads), np.array(tags)
    # outward: flip the quads whose normal points in
    c = nodes[quads].mean(axis=1)
    n = np.cross(nodes[quads[:, 1]] - nodes[quads[:, 0]], nodes[quads[:, 3]] - nodes[quads[:, 0]])
    inward = np.einsum("ij,ij->i", n, c - 0.5 * (LO + HI)) < 0
    quads[inward] = quads[inward][:, ::-1]
    top = np.flatnonzero(tags == 5)
    middle = top[np.argmin(np.linalg.norm(c[top, :2] - [1.125, 0.625], axis=1))]
    tags[middle] = 6
    return nodes, quads, tags, middle


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_facet_and_patch_elements_merge(rigid):
    """Where a patch has no diffuse surface, the target's facets answer over it (node-to-facet
    elements, 4 corners) next to the faces' diffuse elements, in one Contact. (A one-quad
    patch carries the plane of its quad: `test_one_facet_patch_is_its_plane`; here it is
    taken away, as a patch whose nodes coincide would have none.)"""
    nodes, quads, tags, middle = _quad_box()
    surf = PatchedSurface(nodes, [quads], tags=tags)
    assert surf.npatches == 7 and surf.surfaces[-1].basis == "linear"
    surf.surfaces[-1] = None  # before the first projection builds the pass
    corners = nodes[quads[middle]]
    centre = corners.mean(axis=0)
    points = np.vstack([centre + [0.01, -0.02, -0.04], centre + [-0.03, 0.02, -0.02],
                        [0.5, 0.5, 0.95], [1.5, 0.3, 0.05], [0.05, 0.6, 0.4],
                        [1.2, 0.97, 0.5], centre + [0, 0, 0.05]])
    proj = surf.project(points)
    assert proj.source[:2].tolist() == [-1, -1] and (proj.source[2:6] >= 0).all()
    c = contact(surf, points, rigid_target=rigid)
    np.testing.assert_array_equal(c.contactor, np.arange(6))
    exact = _box_sdf(points[:6])
    np.testing.assert_allclose(c.gap, exact, rtol=0, atol=1e-13)
    if not rigid:
        np.testing.assert_allclose(c.gap, proj.gap[:6], rtol=0, atol=1e-14)
        K = c.nodes.shape[1]
        assert K > 4
        for k in (0, 1):  # the facet's element: its 4 corners, zero padding after them
            assert sorted(c.nodes[k, :4]) == sorted(quads[middle])
            assert (c.nodes[k, 4:] == -1).all() and not c.N[k, 15:].any()
            assert not c.M[k, 15:].any() and not c.M[k, :, 15:].any()
        for k in range(2, 6):  # a face's element: nodes of that face only
            ids = c.nodes[k][c.nodes[k] >= 0]
            axis = int(np.argmin(np.minimum(points[k] - LO, HI - points[k])))
            coord = nodes[ids, axis]
            assert np.ptp(coord) == 0 and coord[0] in (LO[axis], HI[axis])
    assert c.status[6] == OPEN
    if rigid:  # the facets' contactor block and the faces' rigid surfaces, one energy
        _check_rigid_derivatives(surf, points[:6], np.random.default_rng(2), "rigid/quad box")


def test_one_facet_patch_is_its_plane():
    """A patch of one quad has fewer nodes than the quadratic basis: it gets the largest basis
    they determine, the plane of its quad (issue 19, item 4), exact over it, and its contact
    element is the diffuse one on its 4 corners."""
    nodes, quads, tags, middle = _quad_box()
    surf = PatchedSurface(nodes, [quads], tags=tags)
    assert surf.surfaces[-1].basis == "linear" and surf.surfaces[-1].nterms == 3
    centre = nodes[quads[middle]].mean(axis=0)
    points = np.vstack([centre + [0.01, -0.02, -0.04], centre + [-0.03, 0.02, -0.02],
                        centre + [0.05, 0.04, 0.03]])
    proj = surf.project(points)
    assert proj.source.tolist() == [6, 6, 6]
    np.testing.assert_allclose(proj.gap, _box_sdf(points), rtol=0, atol=1e-14)
    c = contact(surf, points)
    np.testing.assert_array_equal(c.contactor, [0, 1])
    for k in (0, 1):
        assert sorted(c.nodes[k][c.nodes[k] >= 0]) == sorted(quads[middle])


def _full_taylor(surf, c, k, rng, label):
    """Taylor check of element k of Contact c (a PatchedSurface's), in the target's own node
    numbering: the contactor and the GLOBAL nodes c.nodes[k] are moved, the pairing frozen;
    the gap is that of the moved patch surface's nodes."""
    i = c.contactor[k]
    ids = c.nodes[k][c.nodes[k] >= 0]
    size = 3 * (len(ids) + 1)
    N, M = c.N[k, :size], c.M[k][:size, :size]
    assert not c.N[k, size:].any()
    p = int(surf.project(c.projection.points[i:i + 1]).source[0])
    sp, glob = surf.surfaces[p], surf.patch_nodes[p]
    pair = sp.project(c.projection.points[i:i + 1], keep_patch=True).patch
    opts = {key: getattr(sp, key) for key in ("basis", "weight", "support", "radius", "k")}
    from diffsurf_cli.element.diffuse import diffuse_elements

    def evaluate(v):
        moved = surf.nodes.copy()
        moved[ids] = v[3:].reshape(-1, 3)
        s2 = DiffuseSurface(moved[glob], sp.faces, frame=sp.frame, flip=surf.flip, **opts)
        p2 = s2.project_with(v[None, :3], pair)
        if p2.status[0] != PENETRATION:
            return None
        g2, ids2, N2, _ = diffuse_elements(s2, v[None, :3], p2.patch, p2.proximal_point, [0],
                                           second=False)
        ids2 = ids2[0][ids2[0] >= 0]
        if not np.array_equal(glob[ids2], ids):  # a support node's weight reached zero
            return None
        return g2[0], N2[0][:size]

    u = np.concatenate([c.projection.points[i], surf.nodes[ids].ravel()])
    g_again, _ = evaluate(u)  # the same element, its nodes mapped to the target's
    assert g_again == pytest.approx(c.gap[k], rel=1e-12, abs=1e-15)
    _taylor(evaluate, u, c.gap[k], N, M, float(pair.spacing[0]), rng, label)


def test_full_element_derivatives_on_box_faces(box):
    """R and K of the full element on a patch are derivatives in the target's node numbering:
    two flat faces of the box."""
    rng = np.random.default_rng(5)
    points = np.array([[1.0, 0.4, 0.94], [0.06, 0.45, 0.55]])
    c = contact(box, points)
    assert len(c) == 2
    for k in range(2):
        _full_taylor(box, c, k, rng, f"box/{k}")


def test_full_element_derivatives_on_a_fillet(fillet):
    """The same on a fillet and a flat face of the fillet box (curved: ℳ's surface terms)."""
    rng = np.random.default_rng(6)
    sc, surf = fillet
    # on the fillet along the x edge at y = z = 0 (axis at y = z = 0.25), and a flat face
    t = np.radians(225.0)
    points = np.array([[1.0, 0.25 + 0.22 * np.cos(t), 0.25 + 0.22 * np.sin(t)],
                       [1.1, 0.5, 0.96]])
    assert sc.region(points).tolist() == ["fillet", "flat"]
    c = contact(surf, points)
    assert len(c) == 2
    np.testing.assert_allclose(c.gap, surf.project(points).gap, rtol=0, atol=1e-14)
    for k in range(2):
        _full_taylor(surf, c, k, rng, f"fillet box/{k}")


def test_rigid_derivatives_on_box_faces(box):
    """The rigid target's R and K: gradient and Hessian of Σ ε g²/2 in the contactors, on the
    box's faces (points away from patch edges)."""
    rng = np.random.default_rng(9)
    points = np.array([[1.0, 0.4, 0.94], [0.06, 0.45, 0.55], [1.3, 0.04, 0.5],
                       [0.5, 0.6, 0.05]])
    _check_rigid_derivatives(box, points, rng, "rigid/box")


def test_rigid_derivatives_on_fillets(fillet):
    """The same on the fillet box's fillets and a face."""
    rng = np.random.default_rng(10)
    sc, surf = fillet
    t = np.radians([200.0, 225.0, 250.0])
    points = np.vstack([np.column_stack([[0.8, 1.0, 1.2], 0.25 + 0.22 * np.cos(t),
                                         0.25 + 0.22 * np.sin(t)]),
                        [[1.1, 0.5, 0.96]]])
    assert (sc.region(points) == ["fillet"] * 3 + ["flat"]).all()
    c = contact(surf, points, rigid_target=True)
    np.testing.assert_array_equal(c.contactor, np.arange(4))
    # the rigid surface is the diffuse one's blend: within the fit's error of the exact gap
    assert np.abs(c.gap - sc.sdf(points)).max() <= 1e-2 * sc.h
    _check_rigid_derivatives(surf, points, rng, "rigid/fillet box")


def test_rigid_target_answers_every_contactor_the_projection_answers(tmp_path):
    """Contactors deep behind a narrow patch (a fillet about one cell wide) have no closest
    point on that patch's rigid surface within its blend's reach, though the patch answers
    their projection: their element is the node-to-facet one (source -1, reason 'ok'), as
    where a patch cannot answer the projection, not none. Before, 43 of these 40,000
    contactors got no element (status 'failed')."""
    from diffsurf_cli.patches.surface import FACETS
    from diffsurf_cli.projection import OK

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", *HI, fillet=0.15, size=0.3, order=1)
    surf = _patched(path)
    points = np.random.default_rng(5).uniform(LO - 0.1, HI + 0.1, (40000, 3))
    p = surf.project(points)
    assert (p.status <= PENETRATION).all()
    c = contact(surf, points, rigid_target=True)
    q = c.projection
    assert (q.status <= PENETRATION).all()
    lost = (p.source >= 0) & (q.source == FACETS) & (q.reason == OK)
    assert lost.sum() >= 20
    f = contact(surf.facet_surface(), points[lost], rigid_target=True)
    np.testing.assert_array_equal(q.gap[lost], f.projection.gap)
    rows = np.flatnonzero(lost)[f.contactor]  # their elements: the facets' contactor blocks
    k = np.searchsorted(c.contactor, rows)
    np.testing.assert_array_equal(c.contactor[k], rows)
    np.testing.assert_array_equal(c.N[k], f.N)
    np.testing.assert_array_equal(c.M[k], f.M)


def check_chunked_assemble(surf, points, rigid, rng):
    """`assemble` in chunks of 7 contactors is `contact`'s one-shot assembly (random
    penalties and DOF maps); returns the Contact."""
    m, n = len(points), len(surf.nodes)
    penalty = rng.uniform(1.0, 5.0, m)
    cd, td, size = _dof_maps(rng, m, n)
    td = None if rigid else td
    c = contact(surf, points, rigid_target=rigid)
    R1, K1 = c.residual(penalty, cd, td, size), c.tangent(penalty, cd, td, size)
    R, K, status = assemble(surf, points, penalty, cd, td, n_dofs=size, rigid_target=rigid,
                            chunk=7)
    np.testing.assert_array_equal(status, c.status)
    np.testing.assert_allclose(R, R1, rtol=0, atol=1e-14 * np.abs(R1).max())
    assert abs(K - K1).max() <= 1e-14 * abs(K1).max()
    return c


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_chunked_assemble_is_the_one_shot_assembly(fillet, rigid):
    sc, surf = fillet
    points = sc.sample(60, band=0.02, seed=4)
    c = check_chunked_assemble(surf, points, rigid, np.random.default_rng(11))
    assert len(c) >= 10 and len(set(c.projection.source[c.contactor])) >= 3


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_bad_contactors_fail_and_nothing_answered_is_no_element(box, rigid):
    bad = np.array([[np.nan, 0.5, 0.5], [1.0, np.inf, 0.5]])
    c = contact(box, bad, rigid_target=rigid)
    assert len(c) == 0 and c.nodes.shape[0] == 0 and (c.status == FAILED).all()
    assert c.residual(1.0, np.arange(6).reshape(2, 3)).shape == (6,)
    points = np.vstack([bad, [[1.0, 0.5, 0.9]]])
    c = contact(box, points, rigid_target=rigid)
    assert c.contactor.tolist() == [2] and (c.status[:2] == FAILED).all()
    assert c.gap[0] == pytest.approx(-0.1, abs=1e-13)


def test_a_pairing_needs_one_surface(box):
    with pytest.raises(ValueError, match="one diffuse surface"):
        contact(box, [[1.0, 0.5, 0.9]], pairing=np.zeros(1, np.int64))


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_cli_elements_per_patch(tmp_path, rigid):
    """`diffsurf project --elements` on a box: the elements per patch (not one surface over
    the whole box, whose smoothed corners would make the gaps wrong), in file point numbers;
    --save-pairs still takes one surface (its file format), and says so."""
    from samples import run

    path = gmsh_scenes.box(tmp_path / "b.msh", size=0.25)
    points = _box_points()
    csv = tmp_path / "p.csv"
    np.savetxt(csv, points, delimiter=",", header="x,y,z", comments="")
    args = ["project", path, csv, "--elements", tmp_path / "e.npz", "-o", tmp_path / "o.csv"]
    res = run(*args, *(["--rigid-target"] if rigid else []))
    assert res.exit_code == 0, res.output + res.stderr
    assert "6 smooth patches" in res.stderr
    e = np.load(tmp_path / "e.npz")
    surf = _patched(path)
    c = contact(surf, points, rigid_target=rigid)
    np.testing.assert_array_equal(e["contactor"], c.contactor)
    np.testing.assert_array_equal(e["gap"], c.gap)
    np.testing.assert_allclose(e["gap"], _box_sdf(points[c.contactor]), rtol=0, atol=1e-13)
    t, _, _ = read_surface(path, None)
    np.testing.assert_array_equal(
        e["nodes"], np.where(c.nodes >= 0, t.nodes[np.maximum(c.nodes, 0)], -1))
    if not rigid:
        res = run(*args, "--save-pairs", tmp_path / "s.npz", "--overwrite")
        assert res.exit_code == 0, res.output + res.stderr
        assert "--feature-angle ignored" in res.stderr and "patches" not in res.stderr
