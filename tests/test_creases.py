"""The crease rule (issue 35, item 1: `segment.creases`): an edge past the feature angle is a
crease unless it is a bend of a coarse smooth curve (it turns by at most `tol.CURVE_MAX_DEG`
and the facets on either side of it turn across themselves by a comparable angle in the same
sense). A box's edge turns 90° between two flat faces; a tube of 8 facets around turns 45° at
every edge, uniformly.

Each case is checked against the plain angle rule (dihedral angle > 40°): where the rule
changes the answer (the coarse torus, a cylinder's side), the old answer is the other one.
"""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches import surface as _surface
from diffsurf_cli.patches.segment import (
    FEATURE_ANGLE_DEG,
    creases,
    edge_table,
    node_identity,
    segment,
)
from diffsurf_cli.patches.surface import SHARP, PatchedSurface
from diffsurf_cli.targets import build_surface, read_surface


def dihedral(nodes, faces):
    """(ne,) each edge's angle between its two facets' normals, degrees (NaN where the edge
    has not exactly two facets), and the edges' ends."""
    faces = [np.asarray(f) for f in faces]
    edges = edge_table(faces, node_identity(nodes))
    area = _frame.facet_area_vectors(nodes, faces)
    unit = area / np.linalg.norm(area, axis=1)[:, None]
    angle = np.full(edges.ne, np.nan)
    for i in range(edges.ne):
        half = edges.order[edges.start[i]:edges.start[i + 1]]
        if len(half) == 2:
            a, b = edges.fac[half]
            angle[i] = np.degrees(np.arccos(np.clip(unit[a] @ unit[b], -1, 1)))
    return angle, edges.ends


def angle_rule(nodes, faces):
    """The former rule: every edge past the default feature angle is a crease."""
    angle, _ = dihedral(nodes, faces)
    return np.nan_to_num(angle) > FEATURE_ANGLE_DEG


def trimesh_parts(mesh):
    return np.asarray(mesh.vertices, dtype=np.float64), [np.asarray(mesh.faces)]


# -- the rule on small exact meshes ----------------------------------------------------------
def test_box_edges_are_creases():
    """A box of one facet pair a face: its 12 edges turn 90° at every edge, as a tube of 4
    facets around would (each face's facets see the next face turn the same way): past
    `tol.CURVE_MAX_DEG`, creases all; the faces' diagonals none."""
    nodes, faces = trimesh_parts(trimesh.creation.box())
    crease = creases(nodes, faces)
    angle, _ = dihedral(nodes, faces)
    assert crease.sum() == 12
    np.testing.assert_array_equal(crease, angle > 45)
    np.testing.assert_array_equal(crease, angle_rule(nodes, faces))


def test_coarse_torus_has_no_creases():
    """A trimesh torus of 16 x 8 sections: 8 facets around the tube, 45° at 128 edges, every
    one a bend of the coarse tube, none a crease (the angle rule: all 128)."""
    nodes, faces = trimesh_parts(trimesh.creation.torus(2.0, 0.5, major_sections=16,
                                                        minor_sections=8))
    assert angle_rule(nodes, faces).sum() == 128
    assert not creases(nodes, faces).any()
    assert segment(nodes, faces).max() == 0          # one patch (the angle rule: 8)


@pytest.mark.parametrize("sections", [7, 8])
def test_cylinder_rims_are_creases_its_side_not(sections):
    """A closed trimesh cylinder of 7 or 8 facets around (51° or 45° between its sides'
    facets): its caps' rims (90° to a flat cap) creases, its side's edges not (the angle
    rule: both)."""
    nodes, faces = trimesh_parts(trimesh.creation.cylinder(radius=0.5, height=2.0,
                                                           sections=sections))
    crease = creases(nodes, faces)
    angle, ends = dihedral(nodes, faces)
    z = nodes[ends][:, :, 2]
    rim = (z[:, 0] == z[:, 1]) & (np.abs(z[:, 0]) == 1.0) & (angle > 80)
    side = (z[:, 0] != z[:, 1]) & (angle > FEATURE_ANGLE_DEG)
    assert rim.sum() == 2 * sections and side.sum() >= sections
    assert crease[rim].all()
    assert not crease[side].any()
    assert angle_rule(nodes, faces)[side].all()
    # the side is one patch, each cap its own
    assert segment(nodes, faces).max() == 2


def test_hexagonal_prism_edges_are_creases():
    """Six facets around turn 60°, past `tol.CURVE_MAX_DEG`: a hexagonal prism (a nut) keeps
    its edges, pattern or not."""
    nodes, faces = trimesh_parts(trimesh.creation.cylinder(radius=0.5, height=2.0,
                                                           sections=6))
    np.testing.assert_array_equal(creases(nodes, faces), angle_rule(nodes, faces))


# -- CAD parts: flat faces turn by nothing ---------------------------------------------------
@pytest.fixture(scope="module")
def cad(tmp_path_factory):
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    tmp = tmp_path_factory.mktemp("creases")
    out = {"box": gmsh_scenes.box(tmp / "box.msh"),
           "chamfer": gmsh_scenes.chamfer_box(tmp / "chamfer.msh"),
           # a fillet of two cells (radius 0.25, cells of 0.2): 45° between them, 22° to the
           # flat faces; the fillet's facets turn across themselves by half its middle bend
           "fillet": gmsh_scenes.fillet_box(tmp / "fillet.msh", size=0.2),
           "plate": gmsh_scenes.thin_plate(tmp / "plate.msh")}
    return {k: read_surface(p)[1:] for k, p in out.items()}


@pytest.mark.parametrize("part", ["box", "chamfer", "fillet", "plate"])
def test_cad_creases_kept(cad, part):
    """A gmsh box (90°), a box chamfered at 45°, a box whose fillets are two cells wide (45°
    at their middle), a thin plate: every edge past the feature angle stays a crease (a
    flat face, or a fillet's turn half its middle bend, on one side)."""
    nodes, faces = cad[part]
    crease = creases(nodes, faces)
    assert crease.sum() > 0
    np.testing.assert_array_equal(crease, angle_rule(nodes, faces))


# -- the patched surface follows the rule everywhere -----------------------------------------
@pytest.fixture(scope="module")
def torus():
    nodes, faces = trimesh_parts(trimesh.creation.torus(2.0, 0.5, major_sections=24,
                                                        minor_sections=8))
    return nodes, faces, build_surface(nodes, faces), build_surface(nodes, faces,
                                                                     feature_angle=180)


def test_coarse_torus_default_is_one_surface(torus):
    """The default (40°) answers a coarse torus as one diffuse surface does: one patch, no
    sharp edge, the guard's bounds and every answer the same bits (issue 35: the angle rule
    gave 8 patches and 2.8e-2 RMS against 1.9e-2)."""
    nodes, faces, default, one = torus
    assert default.npatches == 1
    assert not (default.edge_class == SHARP).any()
    for name in ("gap_bound", "gap_lo", "gap_hi", "normal_angle", "normal_turn"):
        np.testing.assert_array_equal(getattr(default, name), getattr(one, name), name)
    rng = np.random.default_rng(35)
    points = rng.uniform(-2.7, 2.7, (4000, 3)) * [1, 1, 0.3]
    a, b = default.project(points), one.project(points)
    np.testing.assert_array_equal(a.gap, b.gap)
    np.testing.assert_array_equal(a.source, b.source)


def test_coarse_torus_cells_follow_the_tube(torus):
    """Under one patch, the curved cells' corner normals are split at creases only: on the
    coarse torus at none (the angle rule split them at every 45° edge, flattening the
    cells across the tube)."""
    _, _, _, one = torus
    np.testing.assert_array_equal(_surface._crease_normals(one), one.corner_normal)



def test_the_elements_sharp_nodes_follow_the_rule():
    """`element.sharp_nodes` (where a bare DiffuseSurface's open contactor that the facets
    find penetrating has no answer) takes the patches' rule: a box's 8 corners, a coarse
    cylinder's rim nodes, no node of a coarse torus (the angle alone made every node of the
    torus sharp)."""
    from diffsurf_cli import FacetSurface
    from diffsurf_cli.element.element import sharp_nodes

    box = trimesh.creation.box()
    assert len(sharp_nodes(FacetSurface(box.vertices, [box.faces]))) == 8
    tube = trimesh.creation.torus(2.0, 0.5, major_sections=16, minor_sections=8)
    assert len(sharp_nodes(FacetSurface(tube.vertices, [tube.faces]))) == 0
    cyl = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=8)
    rim = np.flatnonzero((np.abs(np.abs(cyl.vertices[:, 2]) - 1.0) < 1e-12)
                         & (np.hypot(cyl.vertices[:, 0], cyl.vertices[:, 1]) > 0.5))
    facets = FacetSurface(cyl.vertices, [cyl.faces])
    np.testing.assert_array_equal(sharp_nodes(facets), rim)
    # found once per facets (a solver's every iteration on a rigid target asks again), and
    # read-only, since every call shares it
    assert sharp_nodes(facets) is sharp_nodes(facets) and not sharp_nodes(facets).flags.writeable
    assert sharp_nodes(facets, 89.0) is not sharp_nodes(facets)


# -- a crease that runs out inside one smooth region (issue 34, item 2) ----------------------
def sheet(profile, n=8):
    """A sheet z = profile(x, y) over [-1, 1] x [0, 2] of n x n cells (x = 0 a grid line),
    each cut in two triangles wound toward +z."""
    x, y = np.linspace(-1, 1, n + 1), np.linspace(0, 2, n + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    nodes = np.stack([X.ravel(), Y.ravel(), profile(X, Y).ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return nodes, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def fold(X, Y):
    """A fold along x = 0 between two nearly flat sides (a crease of the CAD), 70° at y = 0,
    running out at y = 2: past the feature angle for y < 1, so both sides are one region."""
    return 0.7 * (1 - Y / 2) * np.abs(X)


def groove(X, Y):
    """A groove one cell wide: two bends of the same sense at x = 0 and x = 0.25 (a fillet
    that one cell cannot resolve), 60° at y = 0, running out at y = 2."""
    return np.tan(np.radians(60 * (1 - Y / 2))) * (np.maximum(-X, 0) + np.maximum(X - 0.25, 0))


def _in_region_sharp(surf):
    """The sharp edges (the surface's manifold edges) between facets of one smooth region."""
    a, b = surf.edge_facets[:, 0], surf.edge_facets[:, 1]
    return np.flatnonzero(surf.edge_sharp & (surf.smooth_region[a] == surf.smooth_region[b]))


def _normals_at(surf, at):
    """The corner normals at the node at (x, y) = `at` and their angles to their own facets'
    normals, degrees."""
    k = np.flatnonzero(np.all(np.isclose(surf.nodes[:, :2], at), axis=1))[0]
    f, j = np.nonzero(surf.corners == k)
    normal = surf.corner_normal[f, j]
    cos = np.clip(np.einsum("ij,ij->i", normal, surf.facet_normal[f]), -1, 1)
    return normal, np.degrees(np.arccos(cos))


@pytest.mark.parametrize("profile, flat", [(fold, True), (groove, False)])
def test_flat_sided_tells_a_crease_from_an_unresolved_fillet(profile, flat):
    """`segment.flat_sided`: at the fold's sharp edges neither side turns (a crease of the
    CAD); at the groove's, the facets past its one-cell strip turn again the same way."""
    from diffsurf_cli.patches.segment import _two_facets, flat_sided

    nodes, faces = sheet(profile)
    key = node_identity(nodes)
    edges = edge_table([faces], key)
    fa, fb = _two_facets(edges)
    which = np.flatnonzero(np.diff(edges.start) == 2)
    area = _frame.facet_area_vectors(nodes, [faces])
    cos = np.einsum("ij,ij->i", area[fa], area[fb]) / np.linalg.norm(area[fa], axis=1) \
        / np.linalg.norm(area[fb], axis=1)
    sharp = np.flatnonzero(cos < np.cos(np.radians(FEATURE_ANGLE_DEG)))
    assert len(sharp) >= 3
    got = flat_sided(nodes, [faces], key, edges, area, fa[sharp], fb[sharp], which[sharp])
    assert np.all(got == flat)


def test_crease_running_out_takes_each_sides_normal():
    """Where a crease of the CAD ends inside one smooth region, each corner at its nodes takes
    its own side's normal (`surface._crease_fans`): within 5° of its facet's (the region's
    normal averaged the two sides, some 27° off each)."""
    surf = PatchedSurface(*sheet(fold))
    assert len(_in_region_sharp(surf)) and surf.smooth_region.max() == 0
    _, off = _normals_at(surf, (0.0, 0.25))
    assert off.max() < 5.0


def test_unresolved_fillet_running_out_keeps_its_regions_normals():
    """A fillet one cell wide is sharp by angle but no crease of the CAD: at its nodes the
    corners keep the region's one normal, which carries its bend."""
    surf = PatchedSurface(*sheet(groove))
    assert len(_in_region_sharp(surf)) and surf.smooth_region.max() == 0
    normal, off = _normals_at(surf, (0.0, 0.25))
    np.testing.assert_array_equal(normal, np.broadcast_to(normal[0], normal.shape))
    assert off.max() > 10.0


# -- the polyhedron's facets, and creases of the CAD below the feature angle (issue 34) -------
def test_refined_coarse_torus_has_no_creases():
    """The coarse torus refined linearly (each triangle into four, new nodes on the chords):
    the rule reads its bends over the polyhedron's facets (`segment.facet_units`), whose
    rings reach the next bend; the refined facets' own do not (their neighbours across the
    tube are half as wide, coplanar with them: a flat side), and every 45° bend was a
    crease."""
    mesh = trimesh.creation.torus(major_radius=2, minor_radius=0.5, major_sections=24,
                                  minor_sections=8)
    nodes, faces = trimesh.remesh.subdivide(mesh.vertices, mesh.faces)
    assert np.nanmax(dihedral(nodes, [faces])[0]) > FEATURE_ANGLE_DEG
    assert not creases(nodes, [faces]).any()


def test_cad_crease_below_the_feature_angle_is_sharp():
    """A fold of 30° between two flat sides (below the feature angle): a crease of the CAD
    (`segment.cad_creases`: neither side turns), a sharp edge whose nodes take each side's
    own normal; it was smooth, its nodes' normals averaging the sides, 15° off each."""
    nodes, faces = sheet(lambda X, Y: np.tan(np.radians(15)) * np.abs(X))
    surf = PatchedSurface(nodes, faces)
    a, b = surf.edge_facets[:, 0], surf.edge_facets[:, 1]
    fold = np.isclose(np.einsum("ij,ij->i", surf.facet_normal[a], surf.facet_normal[b]),
                      np.cos(np.radians(30)))
    assert fold.sum() >= 8 and np.array_equal(surf.edge_sharp, fold)
    _, off = _normals_at(surf, (0.0, 1.0))
    assert off.max() < 1e-6


def test_coarse_curve_below_the_feature_angle_is_no_crease():
    """A sheet bent round by 25° to 28° at every grid line along y (a coarse cylinder of
    radius 1.2): its sides turn as much, no crease."""
    def arc(X, Y):
        return np.sqrt(1.44 - X ** 2)

    nodes, faces = sheet(arc, n=4)
    angles = dihedral(nodes, [faces])[0]
    assert np.nanmax(angles) > 20.0
    surf = PatchedSurface(nodes, faces)
    assert not surf.edge_sharp.any() and surf.cad_crease is None


def test_zigzag_strip_is_no_crease(tmp_path):
    """A second-order fillet box whose fillets are under one cell: the corner facets across a
    fillet zigzag (alternately ±17°, 34.5° apart), both sides turning back: no crease of the
    CAD."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", size=0.3, fillet=0.15, order=2)
    _, nodes, faces = read_surface(path)
    surf = PatchedSurface(nodes, faces)
    a, b = surf.edge_facets[:, 0], surf.edge_facets[:, 1]
    cos = np.einsum("ij,ij->i", surf.facet_normal[a], surf.facet_normal[b])
    assert ((cos < np.cos(np.radians(30))) & (cos > np.cos(np.radians(40)))).sum() >= 10
    assert surf.cad_crease is None
