"""The contact element's edge cases (issue 33, item 5 and item 2's refusal): every one gives an
honest status, never a crash and never a plausible wrong number.

- 0 contactors: an empty `Contact` on every surface, deformable or rigid, and in `assemble`;
- a far contactor on a rigid target: `open` with its distance, at any distance;
- a contactor inside a box's edge or corner, on the plain `DiffuseSurface` (which rounds the
  edge): never `open`: no answer, and in `c.lost`;
- a contactor past an open edge: `outside off-target` and not in `c.lost` (nothing penetrates);
- a far contactor with a frozen pairing: reason `off-target`, as without one;
- too few nodes for the basis: the API's message names the keyword, the CLI's the flag;
- friction with `rigid_target=True` on a moved (deformable) target: refused.
"""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli.element.element import assemble, contact
from diffsurf_cli.element.friction import Coulomb
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import (
    FAILED,
    OFF_TARGET,
    OPEN,
    OUTSIDE,
    PENETRATION,
    STATUS,
)
from diffsurf_cli.testing.shapes import Plane, Saddle, Sphere

SURFACES = (DiffuseSurface, FacetSurface, PatchedSurface)


def _statuses(c):
    return [STATUS[s] for s in c.status]


# ---------------------------------------------------------------------------- 0 contactors
@pytest.mark.parametrize("kind", SURFACES, ids=lambda k: k.__name__)
@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_no_contactors_give_an_empty_contact(kind, rigid):
    """Before: the full element on a DiffuseSurface raised 'cannot reshape array of size 0'."""
    nodes, faces = Sphere().mesh(4)
    surface = kind(nodes, [faces])
    none = np.zeros((0, 3))
    c = contact(surface, none, rigid_target=rigid)
    assert len(c) == 0 and c.status.shape == (0,) and c.reason.shape == (0,)
    assert c.lost.shape == (0,) and c.N.shape[0] == 0
    dofs = np.zeros((0, 3), np.int64)
    target = None if rigid else np.arange(3 * len(nodes)).reshape(-1, 3)
    n = 3 * len(nodes)
    assert not c.residual(1.0, dofs, target, n_dofs=n).any()
    assert c.tangent(1.0, dofs, target, n_dofs=n).nnz == 0
    if not rigid:  # the empty pairing is one to reuse
        again = contact(surface, none, pairing=c.pairing)
        assert len(again) == 0 and again.status.shape == (0,)
    R, K, status = assemble(surface, none, 1.0, dofs, target, n_dofs=n, rigid_target=rigid)
    assert R.shape == (n,) and not R.any() and K.nnz == 0 and status.shape == (0,)


# ---------------------------------------------------------------------------- far and rigid
def _largest_sag(nodes, faces, radius):
    """The largest chordal sag of the facets of a sphere of `radius`: L²/(8 radius) of its
    longest edge (how far the sphere, and a smooth surface through the nodes, departs from
    them)."""
    tri = nodes[faces]
    longest = max(np.linalg.norm(tri[:, k] - tri[:, (k + 1) % 3], axis=1).max() for k in range(3))
    return longest**2 / (8 * radius)


@pytest.mark.parametrize("sizes", [3, 300, 1000, 3000, 1e4, 1e6])
def test_a_far_contactor_on_a_rigid_target_is_open_with_its_distance(sizes):
    """Before: 'failed no-convergence' at 300, 3,000, 1e4 and 1e6 target sizes, `open` at
    1,000 for some directions only: the closest point's Newton asked a step below 1e-13 node
    spacings, under the round-off of y − x^c + λ∇Φ = 0 (two terms of the size of the
    distance). Far away, the distance to the smooth rigid surface is the distance to the
    facets to within how far that surface departs from them: GUARD_SAG_MARGIN x the facets'
    largest sag (tol.py: the guard's measured bound), plus the round-off of the distance."""
    from diffsurf_cli import tol

    nodes, faces = Sphere().mesh(12)
    surface = DiffuseSurface(nodes, [faces])
    rng = np.random.default_rng(7)
    direction = rng.normal(size=(8, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * (1.0 + 2.0 * sizes)  # `sizes` diameters from the sphere
    c = contact(surface, points, rigid_target=True)
    assert np.all(c.status == OPEN), _statuses(c)
    assert len(c) == 0 and len(c.lost) == 0
    facet_gap = FacetSurface(nodes, [faces]).project(points).gap
    bound = tol.GUARD_SAG_MARGIN * _largest_sag(nodes, faces, 1.0) + 1e-12 * sizes
    gap = c.projection.gap
    assert np.all(gap > 0)
    assert np.abs(gap - facet_gap).max() <= bound, np.abs(gap - facet_gap).max()
    # a closest point: the contactor lies on the surface's normal there, to the round-off of
    # the distance (the kernel's positions are relative to x^c: 16 ulps of it, its floor)
    along = points - c.projection.proximal_point
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    angle = np.linalg.norm(np.cross(along, c.projection.normal), axis=1)
    assert angle.max() <= 16 * np.finfo(float).eps * (1.0 + 2.0 * sizes), angle.max()


# ---------------------------------------------------------------------------- inside a box
@pytest.fixture(scope="module")
def gmsh_box(tmp_path_factory):
    """A unit box of gmsh triangles of about 0.2 (diffsurf_cli.testing.gmsh_scenes)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import read_surface
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.box(tmp_path_factory.mktemp("edges") / "box.msh", 1.0, 1.0, 1.0,
                           size=0.2)
    _, nodes, faces = read_surface(path)
    return nodes, faces


@pytest.mark.parametrize("rigid", [False, True], ids=["full", "rigid"])
def test_a_contactor_inside_a_box_edge_or_corner_is_never_open(gmsh_box, rigid):
    """Before: on the plain DiffuseSurface (the docs' snippets' surface), which rounds the
    box's edges, contactors 0.01 inside an edge and a corner were `open` (+0.0138, +0.0339;
    rigid +0.0024, +0.0289) and not in `lost`. They are inside the faceted target: no
    answer (failed, reason 'guard': the smooth surface contradicts the facets), NaN gap, and
    in `c.lost`. Contactors well inside a face or outside stay answered as before."""
    nodes, faces = gmsh_box
    surface = DiffuseSurface(nodes, faces)
    inside = np.array([[0.99, 0.99, 0.5],     # 0.01 inside an edge
                       [0.99, 0.99, 0.99],    # 0.01 inside a corner
                       [0.01, 0.5, 0.01],     # and another edge
                       [0.01, 0.01, 0.01]])   # and another corner
    control = np.array([[0.5, 0.5, 1.01],    # 0.01 above a face's middle: open
                        [0.5, 0.5, 0.99],    # 0.01 below it: penetrating
                        [1.3, 0.5, 0.5]])    # 0.3 off a face: open
    c = contact(surface, np.vstack([inside, control]), rigid_target=rigid)
    status = c.status
    assert np.all(status[:4] == FAILED), _statuses(c)
    assert np.all(np.isnan(c.projection.gap[:4]))
    assert set(range(4)) <= set(c.lost.tolist())
    assert not np.isin(c.contactor, np.arange(4)).any()  # no element
    assert list(status[4:]) == [OPEN, PENETRATION, OPEN], _statuses(c)
    np.testing.assert_allclose(c.projection.gap[[4, 6]], [0.01, 0.3], atol=1e-9)
    assert 5 in c.contactor and len(c.lost) == 4


def test_a_smooth_concave_target_keeps_its_answers_within_the_sag():
    """The other side of the rule above: on a resolved smooth target (no sharp edge) the
    diffuse surface departs from the facets by a chordal sag, inside them where the target
    is concave (the inside of a sphere): contactors on the smooth surface, which its facets
    find just penetrating, keep their answers."""
    shape = Sphere()
    nodes, faces = shape.mesh(8)
    surface = DiffuseSurface(nodes, [faces], flip=True)  # the target is the sphere's outside
    points = shape.sample_near(2000, 0.0, rng=1)
    assert (FacetSurface(nodes, [faces], flip=True).project(points).status
            == PENETRATION).sum() > 1000
    for rigid in (False, True):
        c = contact(surface, points, rigid_target=rigid)
        assert not np.any(c.status == FAILED) and len(c.lost) == 0


# ---------------------------------------------------------------------------- open edges
def test_past_an_open_edge_is_outside_and_not_lost():
    """Before: a contactor past a saddle's open edge was `outside off-target` and in `lost`
    at once (the facets' sign past an edge is only the side of its facet's plane there). Past
    an open edge (its faceted foot on the edge, beside the edge's facet) nothing penetrates:
    outside off-target, not lost, whatever the surface."""
    shape = Saddle(a=0.5, size=1.0)
    nodes, faces = shape.mesh(10)  # over [-1, 1]², z = ±0.5 at the edges' middles
    past = np.array([[3.0, 0.0, 0.0], [30.0, 0.0, 0.0], [1.8, 0.05, 0.0], [1.8, 0.05, 0.5],
                     [1.8, 0.05, 1.0], [0.05, -1.8, -0.5], [0.05, -1.8, -1.0],
                     [0.05, -1.8, 0.0], [1.5, 1.5, 0.0], [0.2, 0.1, -30.0]])
    facets = FacetSurface(nodes, [faces])
    assert (facets.project(past).status == PENETRATION).sum() >= 6  # the facets' side
    for surface in (DiffuseSurface(nodes, [faces]), PatchedSurface(nodes, [faces])):
        for rigid in (False, True):
            c = contact(surface, past, rigid_target=rigid)
            assert np.all(c.status == OUTSIDE), _statuses(c)
            assert np.all(c.reason == OFF_TARGET)
            assert len(c.lost) == 0, (type(surface).__name__, rigid, c.lost)


# ---------------------------------------------------------------------------- far, frozen
@pytest.mark.parametrize("kind", [DiffuseSurface, PatchedSurface], ids=lambda k: k.__name__)
def test_a_far_contactor_with_a_frozen_pairing_is_off_target(kind):
    """Before: with the pairing of the step's start, a contactor gone far from every node was
    'outside few-nodes' (the frozen path never asked `projection.mark_far`); without a
    pairing it is 'outside off-target' (docs/solver.md)."""
    nodes, faces = Sphere().mesh(6)
    surface = kind(nodes, [faces])
    start = np.array([[0.0, 0.0, 1.05], [0.3, 0.2, 0.9]])
    pairing = contact(surface, start).pairing
    far = np.array([[0.0, 80.0, 1.05], [0.3, 50.0, 0.9]])  # far along the frozen plane
    for target in (surface, surface.moved(nodes)):
        c = contact(target, far, pairing=pairing)
        assert np.all(c.status == OUTSIDE) and np.all(c.reason == OFF_TARGET), \
            [STATUS[s] for s in c.status]
        assert np.all(np.isnan(c.projection.gap)) and len(c) == 0


# ---------------------------------------------------------------------------- messages
def test_too_few_nodes_names_the_keyword_in_the_api_and_the_flag_on_the_command_line(tmp_path):
    """Before: the API's error named the command line's flag `--basis linear`. A target of 4
    nodes in a line (its facets degenerate, dropped: a cloud of nodes, one DiffuseSurface)."""
    import meshio
    from click.testing import CliRunner

    from diffsurf_cli.cli import main

    four = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    with pytest.raises(ValueError, match=r'^the target has 4 nodes; the quadratic basis needs '
                                         r'at least 6 \(the linear basis fits them: '
                                         r'basis="linear"\)$'):
        DiffuseSurface(four)
    target = tmp_path / "four.vtu"
    meshio.write(str(target), meshio.Mesh(four, [("triangle", np.array([[0, 1, 2], [1, 2, 3]]))]))
    points = tmp_path / "p.csv"
    points.write_text("x,y,z\n1,0.5,0\n")
    res = CliRunner().invoke(main, ["project", str(target), str(points)])
    assert res.exit_code == 1
    assert res.output.strip().endswith(
        "four.vtu: the target has 4 nodes; the quadratic basis needs at least 6 (the linear "
        "basis fits them: --basis linear)"), res.output


def test_friction_on_a_moved_target_taken_as_rigid_is_refused():
    """Before: accepted, and the moved (deformable) target silently got no reaction."""
    nodes, faces = Sphere().mesh(6)
    points = np.array([[0.0, 0.0, 0.97]])
    for kind in SURFACES:
        surface = kind(nodes, [faces])
        contact(surface, points, rigid_target=True, friction=Coulomb(0.3))  # fixed: fine
        moved = surface.moved(nodes * 1.01)
        with pytest.raises(ValueError, match=r"moved target.*no reaction.*drop rigid_target"):
            contact(moved, points, rigid_target=True, friction=Coulomb(0.3))
        contact(moved, points, rigid_target=True)  # without friction: the fixed shape it has


@pytest.mark.parametrize("rigid", [True, False])
def test_a_contactor_penetrating_within_the_contact_tolerance_keeps_its_element(rigid):
    """|g| within `tol.CONTACT` spacings is status contact; where g < 0 the contactor still
    penetrates and has its element (force ε g): a large penalty's equilibrium lies there;
    where g = 0 it touches and has one too (force 0, issue 37's flat start); g > 0: none."""
    from diffsurf_cli import tol
    from diffsurf_cli.projection import CONTACT as CONTACT_STATUS

    nodes, faces = Plane(size=5.0).mesh(10)  # z = 0 over [-5, 5]², spacing 1
    surface = DiffuseSurface(nodes, [faces])
    depth = 0.5 * tol.CONTACT  # spacing 1
    x = np.array([[0.3, 0.2, -depth], [1.3, 0.2, depth], [2.3, 0.2, 0.0]])
    c = contact(surface, x, rigid_target=rigid)
    assert (c.status == CONTACT_STATUS).all()
    assert list(c.contactor) == [0, 2] and c.gap[1] == 0.0
    eps = 1e3
    dofs = np.arange(9).reshape(3, 3)
    target = None if rigid else 9 + np.arange(3 * len(nodes)).reshape(-1, 3)
    r = c.residual(eps, dofs, target)
    np.testing.assert_allclose(r[:3], eps * c.gap[0] * c.N[0, :3], rtol=1e-12)
    assert -r[2] > 0 and not r[3:9].any()  # the force -R pushes the contactor out (+z)
    assert not c.residual(eps, dofs, target)[6:9].any()  # touching: no force


def test_a_large_penalty_converges_where_its_penetration_is_below_the_tolerance():
    """One contactor on a spring pulled 1 below a flat rigid target, penalty 1e10 (its
    equilibrium penetration 1e-10, below the contact tolerance): Newton converges; with the
    element dropped there it cycled between that point and the spring's pull."""
    nodes, faces = Plane(size=5.0).mesh(10)  # z = 0 over [-5, 5]², spacing 1
    surface = DiffuseSurface(nodes, [faces])
    k, eps, y = 1.0, 1e10, np.array([0.3, 0.2, -1.0])
    dofs = np.arange(3).reshape(1, 3)
    x = np.array([[0.3, 0.2, 0.5]])
    for _ in range(30):
        c = contact(surface, x, rigid_target=True)
        r = k * (x[0] - y) + c.residual(eps, dofs, n_dofs=3)
        if np.linalg.norm(r) <= 1e-9:
            break
        K = k * np.eye(3) + c.tangent(eps, dofs, n_dofs=3).toarray()
        x = x - np.linalg.solve(K, r)[None]
    assert np.linalg.norm(r) <= 1e-9, r
    np.testing.assert_allclose(x[0, 2], -1.0 / (1.0 + eps), rtol=1e-6)
