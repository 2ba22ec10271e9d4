"""The guard (issue 19; docs/facets-bound.md): a diffuse answer whose
gap differs from the facets' by more than `gap_bound` at the faceted foot, or whose normal is
farther from the foot facet's than `normal_angle`, is replaced by the facets' answer (reason
'guard', `Projection.source` -1).

- where diffsurf is right (exact shapes: spheres, tori, cylinders, gmsh spheres of first and
  second order), the guard changes nothing, and a target of one patch answers as its
  `DiffuseSurface`, bit for bit;
- the calibration that `patches.surface.guard_bounds` documents holds on those shapes: the
  facets' own error is at most 1.5 of its local sags, an accurate diffuse answer passes;
- a fit gone wrong where the facets are flat (a raised node reached by a wide support) is
  rejected: the projection, the command line and the rigid-target contact element answer
  with the facets' plane, reason 'guard'.

(`smooth` under the guard: tests/test_real_parts.py, on a CAD STL.)
"""
from __future__ import annotations

import meshio
import numpy as np
import polars as pl
import pytest

from diffsurf_cli import tol
from diffsurf_cli.element.element import contact
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import GUARD, OUTSIDE, PENETRATION
from diffsurf_cli.testing.shapes import Cylinder, Sphere, Torus
from samples import run

FIELDS = ("gap", "normal", "proximal_point", "status", "reason", "support", "iterations",
          "rcond", "curvature", "terms", "source", "facet", "facet_gap", "facet_normal")


def _mesh(kind, tmp_path_factory):
    """(exact shape, nodes, facet blocks) of a smooth target where diffsurf is accurate."""
    name, _, n = kind.partition(" ")
    if name.startswith("gmsh"):
        pytest.importorskip("gmsh")
        from diffsurf_cli.targets import read_surface
        from diffsurf_cli.testing import gmsh_scenes

        path = gmsh_scenes.sphere_surface(tmp_path_factory.mktemp("sphere") / "s.msh",
                                          size=0.3, order=int(n))
        _, nodes, faces = read_surface(path)
        return Sphere(), nodes, faces
    shape = {"sphere": Sphere(), "torus": Torus(1.0, 0.4),
             "cylinder": Cylinder(radius=1.0, length=2.0)}[name.split("-")[0]]
    build = shape.mesh_quads if name.endswith("quads") else shape.mesh
    nodes, faces = build(int(n))
    return shape, nodes, [faces]


SHAPES = ["sphere 2", "sphere 4", "sphere 8", "torus-quads 24", "torus-triangles 24",
          "cylinder-quads 12", "cylinder-triangles 24", "gmsh-sphere 1", "gmsh-sphere 2"]


@pytest.fixture(scope="module", params=SHAPES)
def smooth_target(request, tmp_path_factory):
    """A smooth target of one patch, guarded and not, and 1500 contactors within 0.3 node
    spacings of it (away from open ends) with their exact gaps."""
    shape, nodes, faces = _mesh(request.param, tmp_path_factory)
    guarded = PatchedSurface(nodes, faces, feature_angle=None)
    h = float(np.median(guarded.node_spacing))
    points = shape.sample_near(1500, 0.3 * h, rng=7)
    exact = shape.closest(points)[2]
    return request.param, nodes, faces, guarded, points, exact


def test_guard_is_silent_where_diffsurf_is_right(smooth_target):
    """(a) On smooth targets where the smooth surface is accurate, the guard rejects nothing:
    guard on and off give the same answers, every one of them from the diffuse surface, and
    those are the target's own `DiffuseSurface`'s, bit for bit."""
    name, nodes, faces, guarded, points, exact = smooth_target
    on = guarded.project(points)
    off = PatchedSurface(nodes, faces, feature_angle=None, guard=False).project(points)
    assert not (on.reason == GUARD).any(), (name, (on.reason == GUARD).sum())
    for field in FIELDS:
        np.testing.assert_array_equal(getattr(on, field), getattr(off, field), err_msg=field)
    assert (on.source == 0).all(), (name, np.unique(on.source))
    alone = DiffuseSurface(nodes, faces).project(points)
    for field in ("gap", "normal", "proximal_point", "status", "reason", "support",
                  "iterations", "rcond", "curvature", "terms"):
        np.testing.assert_array_equal(getattr(on, field), getattr(alone, field),
                                      err_msg=field)


def test_guard_calibration(smooth_target):
    """(b) The calibration `guard_bounds` documents: with the local sag s at the faceted foot
    f0 (gap_bound = GUARD_SAG_MARGIN s + GUARD_FLOOR h), the facets' own error (against the
    exact shape) is at most 1.5 s; an accurate diffuse answer (error at most s / 2) differs
    from the facets' by less than GUARD_SAG_MARGIN s, and its normal from f0's by less than
    normal_angle[f0]: the guard never rejects what is right."""
    name, nodes, faces, surf, points, exact = smooth_target
    p = surf.project(points)
    f0 = p.facet
    assert (f0 >= 0).all()
    h = surf.node_spacing[surf.corners[f0, 0]]
    sag = (surf.gap_bound[f0] - tol.GUARD_FLOOR * h) / tol.GUARD_SAG_MARGIN
    assert (sag > 0).all()
    facet_error = np.abs(p.facet_gap - exact) / sag
    assert facet_error.max() <= 1.5, (name, facet_error.max())
    accurate = np.abs(p.gap - exact) <= sag / 2
    assert accurate.mean() > 0.99, (name, accurate.mean())
    off = np.abs(p.gap - p.facet_gap)[accurate] / sag[accurate]
    assert off.max() < tol.GUARD_SAG_MARGIN, (name, off.max())
    cos = np.einsum("ij,ij->i", p.normal, surf.facet_normal[f0])
    angle = np.arccos(np.clip(cos, -1.0, 1.0))
    assert (angle < surf.normal_angle[f0])[accurate].all(), (
        name, (angle / surf.normal_angle[f0])[accurate].max())


# --------------------------------------------------------------------------------------------
# a fit gone wrong where the facets are flat
# --------------------------------------------------------------------------------------------

N = 10
BUMP = (5, 5)


def bump_grid():
    """A flat square 10 x 10 of right triangles (spacing 1, z = 0, facing +z) but for one node
    raised by 0.5 (the bump): its facets turn by 27 degrees, under the feature angle."""
    x, y = np.meshgrid(np.arange(N + 1.0), np.arange(N + 1.0), indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    tris = []
    for i in range(N):
        for j in range(N):
            a, b, c, d = i * (N + 1) + j, (i + 1) * (N + 1) + j, (i + 1) * (N + 1) + j + 1, \
                i * (N + 1) + j + 1
            tris += [(a, b, c), (a, c, d)]
    bump = BUMP[0] * (N + 1) + BUMP[1]
    nodes[bump, 2] = 0.5
    return nodes, np.array(tris), bump


def flat_contactors(m=4000, seed=0):
    """Contactors within 0.3 of the square whose vertical foot's facet, and every facet
    sharing a node with it, have no node on the bump or next to it: the facets around the
    foot are flat (their sag, the guard's bound, is round-off), their exact gap is z.
    Returns points (k, 3), the foot facets (k,)."""
    nodes, tris, bump = bump_grid()
    rng = np.random.default_rng(seed)
    points = np.column_stack([rng.uniform(1, 9, (m, 2)), rng.uniform(-0.3, 0.3, m)])
    i, j = np.floor(points[:, 0]).astype(int), np.floor(points[:, 1]).astype(int)
    upper = points[:, 1] - j > points[:, 0] - i
    foot = 2 * (i * N + j) + upper
    near_bump = np.unique(tris[(tris == bump).any(axis=1)])        # the bump and its ring
    ring_of = [(np.isin(tris, tris[f]).any(axis=1)) for f in range(len(tris))]
    flat = np.array([not np.isin(tris[ring_of[f]], near_bump).any() for f in foot])
    return points[flat], foot[flat]


RADIUS = 3.0  # supports of 3 spacings: those of flat feet near the bump reach it


def test_guard_rejects_a_fit_gone_wrong_over_flat_facets():
    """(c) Over the flat part of the bump grid, with supports of 3 spacings, the fits that
    reach the raised node bulge the smooth surface off the plane of the facets around the
    foot, where the guard's bound is round-off: those answers are rejected (reason 'guard',
    source -1: the facets' gap, exactly z, and their normal +z), and every answer there is
    the plane's to the guard's floor. With the guard off, they are the bulge (up to 0.0075
    off: the guard had cause)."""
    nodes, tris, _ = bump_grid()
    points, foot = flat_contactors()
    surf = PatchedSurface(nodes, tris, feature_angle=None, radius=RADIUS)
    p = surf.project(points)
    np.testing.assert_array_equal(p.facet, foot)
    np.testing.assert_allclose(surf.gap_bound[foot], tol.GUARD_FLOOR, rtol=1e-12)
    guarded = p.reason == GUARD
    assert guarded.sum() >= 100, guarded.sum()
    assert (p.source[guarded] == -1).all() and (p.status[guarded] < OUTSIDE).all()
    np.testing.assert_allclose(p.gap[guarded], points[guarded, 2], rtol=0, atol=1e-14)
    np.testing.assert_allclose(p.facet_gap[guarded], points[guarded, 2], rtol=0, atol=1e-14)
    np.testing.assert_allclose(p.normal[guarded], np.tile([0.0, 0.0, 1.0], (guarded.sum(), 1)),
                               rtol=0, atol=1e-14)
    assert (p.terms[guarded] == 0).all()
    assert np.abs(p.gap - points[:, 2]).max() <= tol.GUARD_FLOOR + 1e-14
    # without the guard: the same contactors get the bulge, beyond the bound
    q = PatchedSurface(nodes, tris, feature_angle=None, radius=RADIUS, guard=False).project(
        points)
    bulge = np.abs(q.gap - q.facet_gap)
    cos = np.einsum("ij,ij->i", q.normal, surf.facet_normal[foot])
    rejected = ~(bulge <= surf.gap_bound[foot]) | ~(cos >= np.cos(surf.normal_angle[foot]))
    np.testing.assert_array_equal(guarded, rejected)
    assert bulge.max() > 1e-3


def test_cli_answers_the_plane_where_its_fit_bulges(tmp_path):
    """(c) The same through the command line (`--feature-angle 180 --radius 3`: one surface
    over the bump grid): over its flat part every gap is the plane's, to the guard's floor,
    and the rejected ones say 'guard'.

    Before issue 19: 296 of its 2355 contactors off the plane, by up to 0.0075."""
    nodes, tris, _ = bump_grid()
    points, _ = flat_contactors()
    path = tmp_path / "grid.vtu"
    meshio.write(path, meshio.Mesh(nodes, [("triangle", tris)]))
    src, out = tmp_path / "p.parquet", tmp_path / "o.parquet"
    pl.DataFrame({"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}).write_parquet(src)
    res = run("project", path, src, "-o", out, "--feature-angle", "180", "--radius", RADIUS)
    assert res.exit_code == 0, res.output + res.stderr
    table = pl.read_parquet(out)
    assert np.abs(table["gap"].to_numpy() - points[:, 2]).max() <= tol.GUARD_FLOOR + 1e-14
    reason = table["reason"].to_numpy()
    assert (reason == "guard").sum() >= 100 and set(reason) == {"ok", "guard"}


def test_rigid_element_is_the_facets_where_the_guard_rejects():
    """(e) The rigid-target contact element on the bump grid (`contact(..., rigid_target=True)`,
    supports of 3 spacings): over the flat part every penetrating contactor has an element
    whose gap is the plane's to the guard's floor; where the guard rejects the smooth
    surface (the projection's, or the rigid blend of the node fits that reach the bump), the
    element is the facets' (reason 'guard', gap exactly z, ∂g/∂x^c = +z, ∂²g/∂x^c² = 0).

    Before issue 19 (`--rigid-target --elements`, the same scene): 431 of the 1177 elements
    off the plane, by up to 0.0060."""
    nodes, tris, _ = bump_grid()
    points, _ = flat_contactors()
    surf = PatchedSurface(nodes, tris, feature_angle=None, radius=RADIUS)
    c = contact(surf, points, rigid_target=True)
    below = np.flatnonzero(points[:, 2] < -1e-9)
    np.testing.assert_array_equal(c.contactor, below)
    assert (c.status[below] == PENETRATION).all()
    np.testing.assert_allclose(c.gap, points[below, 2], rtol=0, atol=tol.GUARD_FLOOR + 1e-14)
    guarded = c.reason[c.contactor] == GUARD
    assert guarded.sum() >= 100, guarded.sum()
    assert (c.projection.source[c.contactor[guarded]] == -1).all()
    np.testing.assert_allclose(c.gap[guarded], points[c.contactor[guarded], 2], rtol=0,
                               atol=1e-14)
    np.testing.assert_allclose(c.N[guarded], np.tile([0.0, 0.0, 1.0], (guarded.sum(), 1)),
                               rtol=0, atol=1e-14)
    np.testing.assert_allclose(c.M[guarded], 0.0, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------------------------
# the side: facets that bend toward their normal lie under the surface they interpolate
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("flip", [False, True])
def test_guard_side_follows_the_bend(flip):
    """(d) On a sphere's facets (convex: they bend toward their outward normals) a smooth
    surface may rise above them by GUARD_SAG_MARGIN sags and sink under them by only
    GUARD_OTHER_SIDE of a sag: the bound on g - g_f is [-1.75 s, 0.25 s] (to the floor); with
    flipped normals the facets bend away from them and the bound is its mirror. A gap that
    sinks half the envelope under the facets is rejected, one that rises as much passes."""
    nodes, tris = Sphere().mesh(3)
    surf = PatchedSurface(nodes, tris, feature_angle=None, flip=flip)
    h = surf.node_spacing[surf.corners[:, 0]]
    floor = tol.GUARD_FLOOR * h
    sag = (surf.gap_bound - floor) / tol.GUARD_SAG_MARGIN
    assert (sag > 0).all()
    rise, sink = tol.GUARD_SAG_MARGIN * sag + floor, tol.GUARD_OTHER_SIDE * sag + floor
    lo, hi = (-sink, rise) if flip else (-rise, sink)
    np.testing.assert_allclose(surf.gap_lo, lo, rtol=1e-12)
    np.testing.assert_allclose(surf.gap_hi, hi, rtol=1e-12)
    # the gap grows where the surface sinks under the (outward) facets, shrinks where it rises
    f = np.arange(len(tris))
    half = 0.5 * surf.gap_bound
    normal = (-1.0 if flip else 1.0) * surf.facet_normal
    inward = -1.0 if flip else 1.0     # g - g_f of a surface sunk under the facets
    gf = np.zeros(len(f))
    assert not surf.within_guard(gf + inward * half, normal, f, gf).any()
    assert surf.within_guard(gf - inward * half, normal, f, gf).all()


def test_guard_side_is_the_envelope_at_an_open_boundary():
    """(d) Past an open boundary the facets' gap is the distance to its edge, which a surface
    continued past it undercuts whatever its bend: a facet touching the boundary of an open
    sphere gets the envelope on either side, the others their side."""
    nodes, tris = Sphere().mesh(4)
    centre = nodes[tris].mean(axis=1)
    keep = tris[centre[:, 2] > -0.3]
    used = np.unique(keep)
    remap = np.full(len(nodes), -1)
    remap[used] = np.arange(len(used))
    surf = PatchedSurface(nodes[used], remap[keep], feature_angle=None)
    f, j = np.nonzero(surf.edge_class == 2)               # the open edges (triangles)
    open_nodes = np.union1d(surf.corners[f, j], surf.corners[f, (j + 1) % 3])
    ring = np.isin(surf.corners, open_nodes).any(axis=1)  # facets touching them
    assert len(f) and ring.any() and (~ring).any()
    np.testing.assert_array_equal(surf.gap_lo[ring], -surf.gap_bound[ring])
    np.testing.assert_array_equal(surf.gap_hi[ring], surf.gap_bound[ring])
    assert (surf.gap_hi[~ring] < 0.5 * surf.gap_bound[~ring]).all()


def test_guard_allows_the_turn_between_the_two_feet(tmp_path):
    """A point a fraction of a node spacing deep in a fillet about one spacing wide (second
    order, CAD faces as tags: linkrods o2-tags of the battery): its proximal point and its
    faceted foot are apart, and the surface turns between them by more than the spread of
    the facet normals around the foot. The normal check allows that turn (normal_turn times
    the distance): no diffuse answer that is the nearer to the CAD is sent to the facets
    (without it, 53 of 991 were), and the smooth surface stays more accurate than them."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import surface_from_file
    from diffsurf_cli.testing import gmsh_scenes
    from diffsurf_cli.testing.feature_scenes import _box_sdf

    size, fillet, hi = 0.3, 0.15, np.array([2.0, 1.0, 1.0])
    path = gmsh_scenes.fillet_box(tmp_path / "fillets.msh", *hi, fillet=fillet, size=size,
                                  order=2)
    _, guarded = surface_from_file(str(path))
    _, free = surface_from_file(str(path), guard=False)
    points = np.random.default_rng(2).uniform(-0.1, hi + 0.1, (60000, 3))
    exact = _box_sdf(points, np.full(3, fillet), hi - fillet) - fillet
    deep = (exact > -size) & (exact < -0.2 * size)
    points, exact = points[deep][:6000], exact[deep][:6000]
    p, u = guarded.project(points), free.project(points)
    nearer = ((np.abs(u.gap - exact) <= np.abs(u.facet_gap - exact) / 3) & (u.facet >= 0)
              & (u.source >= 0))
    assert nearer.sum() > 500
    # what the normal check without the turn would have rejected among them
    foot = points - u.facet_gap[:, None] * u.facet_normal
    apart = np.linalg.norm(u.proximal_point - foot, axis=1)
    without = ~guarded.within_guard(u.gap, u.normal, u.facet, u.facet_gap)
    assert (nearer & without).sum() > 20
    assert not (nearer & ~guarded.within_guard(u.gap, u.normal, u.facet, u.facet_gap,
                                               apart)).any()
    # the compiled pass decides so too
    assert not (nearer & (p.reason == GUARD)).any(), (nearer & (p.reason == GUARD)).sum()
    rms = np.sqrt(np.mean((p.gap - exact) ** 2))
    assert rms < 0.5 * np.sqrt(np.mean((p.facet_gap - exact) ** 2))
