"""Real parts (issue 19: "never a plausible wrong number on a real part"), built here.

The issue's battery (benchmarks/real_parts.py) runs public meshes that are not part of the
repository; these tests rebuild what went wrong on them as small synthetic scenes, each with
an exact reference from its own geometry, run through the command line as a user runs it
(`samples.run`: ``diffsurf project TARGET POINTS.parquet -o OUT.parquet``):

- item 2, elongated quads on a curved face: a cylinder of radius 50 meshed with quads
  12.5 x 2.5 (hexahedral meshes' faces), long side around or along the axis; exact: the
  cylinder;
- items 1 and 3, a CAD STL: the triangle soup of an extruded profile (a slot, a narrow wall,
  a convex and a concave fillet of 3 segments: sharp edges and soft creases of 15 and 30
  degrees; big triangles and slivers; no tags); exact: the polyhedron itself;
- item 3, thin walls without tags: a plate 1 thick meshed at 6, and a curved wall (a pipe
  sector, radii 19 and 20) meshed at 6; exact: their signed distance;
- item 4, strips one element wide (curved and straight, cells ten times longer across than
  along, as an extruded 2D contact zone has them) and targets of one facet; exact: the
  cylinder, the plane.

What these scenes gave before issue 19 (commit 9f4a37c, the same files through its command
line) is in each test's docstring.
"""
from __future__ import annotations

import meshio
import numpy as np
import polars as pl
import pytest
import trimesh

from diffsurf_cli.patches.surface import CELLS, FACETS, PatchedSurface
from diffsurf_cli.testing import feature_scenes as fs
from diffsurf_cli.testing.shapes import Cylinder
from samples import run

ANSWERED = ("open", "contact", "penetration")


def project(tmp_path, target, points, *extra, name="out"):
    """`diffsurf project TARGET POINTS [EXTRA]` in-process on (m, 3) points; the output table
    (Parquet: floats exact, status and reason as words)."""
    src = tmp_path / f"{name}.in.parquet"
    out = tmp_path / f"{name}.parquet"
    pl.DataFrame({"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}).write_parquet(src)
    res = run("project", target, src, "-o", out, "--overwrite", *extra)
    assert res.exit_code == 0, res.output + res.stderr
    return pl.read_parquet(out)


def answered(table) -> np.ndarray:
    return np.isin(table["status"].to_numpy(), ANSWERED)


def wrong_signs(gap, exact, threshold) -> np.ndarray:
    """Rows whose gap has the wrong sign where the exact gap is farther than `threshold` from
    0 (closer, the sign of either is round-off or smoothing)."""
    return (np.abs(exact) > threshold) & (np.sign(gap) != np.sign(exact))


# --------------------------------------------------------------------------------------------
# item 2: elongated quads on a curved face
# --------------------------------------------------------------------------------------------

RADIUS = 50.0
LONG, SHORT = 12.5, 2.5


def elongated_cylinder(orientation):
    """A cylinder sector of radius 50 meshed with quads LONG x SHORT (arc x axial, or axial x
    arc), and 4000 contactors over it within +-1 of the surface, at least 2 SHORT from its
    open edges; their exact gaps."""
    if orientation == "around":  # 8 x 10 cells, 12.5 around (chordal sag 0.39), 2.5 along
        n, m, arc = 8, 10, LONG
    else:  # 20 x 4 cells, 2.5 around (sag 0.016), 12.5 along
        n, m, arc = 20, 4, SHORT
    span = n * arc / RADIUS
    length = m * (SHORT if arc == LONG else LONG)
    shape = Cylinder(radius=RADIUS, length=length, theta_range=(0.0, span))
    nodes, quads = shape.mesh_quads(n, m)
    rng = np.random.default_rng(19)
    k = 4000
    margin = 2 * SHORT
    theta = rng.uniform(margin / RADIUS, span - margin / RADIUS, k)
    z = rng.uniform(-length / 2 + margin, length / 2 - margin, k)
    r = RADIUS + rng.uniform(-1.0, 1.0, k)
    points = np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
    return nodes, quads, points, shape.closest(points)[2]


@pytest.fixture(scope="module", params=["around", "along"])
def elongated(request, tmp_path_factory):
    """(orientation, diffsurf's table, the facets' table, exact gaps, target diagonal)."""
    tmp = tmp_path_factory.mktemp(f"elongated_{request.param}")
    nodes, quads, points, exact = elongated_cylinder(request.param)
    # as a user's mesh: .vtu for one orientation, Gmsh 2.2 (one entity) for the other
    if request.param == "around":
        path = tmp / "cylinder.vtu"
        meshio.write(path, meshio.Mesh(nodes, [("quad", quads)]))
    else:
        path = tmp / "cylinder.msh"
        one = [np.ones(len(quads), int)]
        meshio.write(path, meshio.Mesh(nodes, [("quad", quads)], cell_data={
            "gmsh:physical": one, "gmsh:geometrical": one}), file_format="gmsh22")
    d = project(tmp, path, points, name="diffuse")
    f = project(tmp, path, points, "--method", "facet", name="facet")
    diag = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    return request.param, d, f, exact, diag


def test_elongated_quads_none_lost_and_no_wrong_sign(elongated):
    """Item 2: on quads 12.5 x 2.5 of a cylinder of radius 50, every contactor is answered and
    none has the wrong sign (|exact| > 1e-3 of the diagonal).

    Before: long side around, 142 of 4000 outside and 341 wrong signs (a support one row long,
    a plane across the cell: the facets' 0.39 error); long side along, 195 outside
    ('off-target'). Both orientations failed."""
    orientation, d, f, exact, diag = elongated
    ok = answered(d)
    assert ok.all(), (orientation, (~ok).sum(), np.unique(d["reason"].to_numpy()[~ok]))
    wrong = wrong_signs(d["gap"].to_numpy(), exact, 1e-3 * diag)
    assert not wrong.any(), (orientation, wrong.sum())


@pytest.mark.parametrize("elongated", [
    "around",
    pytest.param("along", marks=pytest.mark.xfail(strict=True, reason=(
        "issue 19 item 2: with the long side along the axis, the floor of the local spacing "
        "(0.55 x the quad's longest edge, tol.SUPPORT_FACET_FRACTION) applies across the "
        "curved short side too (the weight is isotropic): a support of radius 14 around a "
        "radius of 50, a quadratic fit off by up to 0.0095 (0.61 of the "
        "facets' 0.0156). Before issue 19: 0.0090 at most (0.58 of the "
        "facets'), but 195 of 4000 points lost"))),
], indirect=True)
def test_elongated_quads_beat_the_facets(elongated):
    """Item 2: the smooth surface of quads 12.5 x 2.5 on a cylinder of radius 50 is at least 5x
    more accurate than the facets (largest gap error against the exact cylinder).

    Before: long side around, 0.39, the facets' own error (a plane across each cell); long
    side along, 0.0090 (0.58 of the facets')."""
    orientation, d, f, exact, diag = elongated
    ok = answered(d)
    err = np.abs(d["gap"].to_numpy() - exact)[ok]
    ferr = np.abs(f["gap"].to_numpy() - exact)
    assert err.max() < ferr.max() / 5, (orientation, err.max(), ferr.max())


# --------------------------------------------------------------------------------------------
# items 1 and 3: a CAD STL (a sliver wall, soft and sharp creases, no tags)
# --------------------------------------------------------------------------------------------

WIDTH = 10.0  # the extrusion


def _arc(centre, radius, a0, a1, n):
    t = np.radians(np.linspace(a0, a1, n + 1))
    return [(centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)) for a in t]


def cad_profile(segments=3):
    """The profile (x, z) of the part, counterclockwise: a block 40 x 12 with a convex fillet
    (radius 3, `segments` chords) at its top right, a slot 1.5 wide and 8 deep, a step down
    through a concave fillet (radius 3) and a wall 1 thick at its left end."""
    pts = [(0.0, 0.0), (40.0, 0.0)] + _arc((37.0, 9.0), 3.0, 0.0, 90.0, segments)
    pts += [(31.0, 12.0), (31.0, 4.0), (29.5, 4.0), (29.5, 12.0), (12.0, 12.0)]
    pts += _arc((9.0, 9.0), 3.0, 0.0, -90.0, segments)
    pts += [(1.0, 6.0), (1.0, 12.0), (0.0, 12.0)]
    return np.array(pts)


def _ear_clip(poly):
    """Triangles of a simple counterclockwise polygon (k, 2), as a CAD exporter makes them:
    big triangles and slivers, no node inside."""
    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    left = list(range(len(poly)))
    tris = []
    while len(left) > 3:
        for k in range(len(left)):
            i, j, m = left[k - 1], left[k], left[(k + 1) % len(left)]
            a, b, c = poly[i], poly[j], poly[m]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex or straight
            if any(cross(a, b, poly[q]) >= 0 and cross(b, c, poly[q]) >= 0
                   and cross(c, a, poly[q]) >= 0 for q in left if q not in (i, j, m)):
                continue  # another vertex inside the ear
            tris.append((i, j, m))
            left.pop(k)
            break
        else:  # pragma: no cover - the profile is simple
            raise ValueError("not a simple polygon")
    tris.append(tuple(left))
    return np.array(tris)


def cad_part(segments=3):
    """The part as a CAD STL: the profile extruded along y over WIDTH, each planar face as
    few triangles as it takes (a rectangle: two; the ends: the profile ear-clipped), facing
    out. Returns nodes (n, 3), triangles (f, 3)."""
    prof = cad_profile(segments)
    k = len(prof)
    nodes = np.vstack([np.column_stack([prof[:, 0], np.zeros(k), prof[:, 1]]),
                       np.column_stack([prof[:, 0], np.full(k, WIDTH), prof[:, 1]])])
    cap = _ear_clip(prof)  # counterclockwise in (x, z): facing -y at y = 0
    i = np.arange(k)
    j = (i + 1) % k
    tris = np.vstack([cap, cap[:, ::-1] + k, np.column_stack([i, j + k, j]),
                      np.column_stack([i, i + k, j + k])])
    return nodes, tris


def _soft_sag(mesh) -> float:
    """The tessellation's sag allowance (benchmarks/real_parts.py): the largest w θ / 8 over
    edges whose facets meet at 0 < θ < 40°, w the width of either facet across the edge."""
    angle = mesh.face_adjacency_angles
    soft = (angle > 1e-9) & (angle < np.radians(40.0))
    edge = mesh.vertices[mesh.face_adjacency_edges]
    length = np.linalg.norm(edge[:, 1] - edge[:, 0], axis=1)
    width = 2 * mesh.area_faces[mesh.face_adjacency].max(axis=1) / length
    return float((width * angle / 8)[soft].max())


def _bound_at(surf, nodes, tris, points, tie):
    """The guard's bound at each point's exact faceted foot: the largest gap_bound of the
    facets nearest to it (within `tie`: a foot on an edge or a corner is on all of theirs)."""
    distance = np.stack([np.linalg.norm(trimesh.triangles.closest_point(
        np.repeat(nodes[c][None], len(points), axis=0), points) - points, axis=1)
        for c in tris], axis=1)                                           # (m, f)
    nearest = distance <= distance.min(axis=1, keepdims=True) + tie
    return np.where(nearest, surf.gap_bound[None], 0.0).max(axis=1), nearest


@pytest.fixture(scope="module")
def cad_stl(tmp_path_factory):
    """The CAD part written as a binary STL, 5000 contactors within 2% of its diagonal of its
    faces (uniform by area, offset along the facet normal), their exact signed distance to
    the polyhedron (trimesh: closest point and inside test), and diffsurf's answers through
    the command line."""
    tmp = tmp_path_factory.mktemp("cad")
    nodes, tris = cad_part()
    path = tmp / "part.stl"
    meshio.write(path, meshio.Mesh(nodes, [("triangle", tris)]), binary=True)
    nodes = nodes.astype(np.float32).astype(np.float64)  # what the STL holds
    mesh = trimesh.Trimesh(nodes, tris, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    diag = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    rng = np.random.default_rng(11)
    k = 5000
    face = rng.choice(len(tris), k, p=mesh.area_faces / mesh.area)
    u, v = rng.uniform(size=(2, k))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    corner = nodes[tris[face]]
    points = corner[:, 0] + u[:, None] * (corner[:, 1] - corner[:, 0]) \
        + v[:, None] * (corner[:, 2] - corner[:, 0])
    points += mesh.face_normals[face] * rng.uniform(-0.02, 0.02, (k, 1)) * diag
    _, distance, _ = trimesh.proximity.closest_point(mesh, points)
    exact = np.where(mesh.contains(points), -distance, distance)
    table = project(tmp, path, points)
    return nodes, tris, mesh, points, exact, diag, table, path


def test_cad_stl_answers_stay_within_the_guard_of_the_polyhedron(cad_stl):
    """Items 1 and 3: on a CAD STL (no tags; big triangles and slivers; sharp edges, soft
    creases of 15 and 30 degrees at coarse fillets), every contactor is answered and no answer
    is farther from the exact polyhedron than the guard's bound at its exact foot facet (the
    facets are the exact surface here: what the guard measures against); the guard answers
    where the smooth surface of the fillets and their slivers is a candidate, and nowhere
    else, with the mesh's own gap: the polyhedron's, or its facets curved through their
    normals within the guard's envelope.

    Before: 65 of 5000 answers beyond the bound, by up to 3.6 (4.96 off the polyhedron: fits
    across the fillets' slivers, proximal points on distant faces)."""
    nodes, tris, mesh, points, exact, diag, table, _ = cad_stl
    surf = PatchedSurface(nodes, [tris])  # the command line's surface of the same target
    ok = answered(table)
    assert ok.all(), np.unique(table["reason"].to_numpy()[~ok])
    err = np.abs(table["gap"].to_numpy() - exact)
    bound, feet = _bound_at(surf, nodes, tris, points, 1e-9 * diag)
    excess = err - bound
    assert excess.max() <= 1e-9 * diag, (excess.max(), points[np.argmax(excess)])
    # where the guard answered: where the smooth surface of the fillets is a candidate (a foot
    # facet sharing a node with a facet that has a node on a soft crease)
    angle = mesh.face_adjacency_angles
    soft = (angle > 1e-9) & (angle < np.radians(40.0))
    crease = np.zeros(len(nodes), bool)
    crease[mesh.face_adjacency_edges[soft].ravel()] = True
    reach = np.zeros(len(nodes), bool)
    reach[tris[crease[tris].any(axis=1)].ravel()] = True
    near = (feet & reach[tris].any(axis=1)[None]).any(axis=1)
    guard = table["reason"].to_numpy() == "guard"
    assert guard[near].sum() > 10 and not guard[~near].any(), (guard[near].sum(),
                                                                guard[~near].sum())
    # and it gives the mesh's own answer there: the polyhedron's, or its facets curved through
    # their corner normals (`cell_coefficients`) within the guard's envelope of it
    p = surf.project(points)
    np.testing.assert_allclose(p.gap, table["gap"].to_numpy(), rtol=0, atol=1e-9 * diag)
    facets, cells = guard & (p.source == FACETS), guard & (p.source == CELLS)
    assert facets.any() and cells.any() and not (guard & ~facets & ~cells).any()
    np.testing.assert_allclose(p.gap[facets], exact[facets], rtol=0, atol=1e-9 * diag)
    assert (np.abs(p.gap - exact)[cells] <= surf.gap_bound[p.facet[cells]]).all()


def test_cad_stl_no_wrong_sign(cad_stl):
    """Items 1 and 3: on the CAD STL, no answer has the wrong sign where the exact polyhedron's
    gap is beyond 1e-3 of the diagonal and beyond the tessellation's sag (closer than that,
    the facets' sign is not the smooth surface's; benchmarks/real_parts.py counts them so).

    Before issue 19: 138 of 5000. With the guard's sag from the turn of a facet's corner
    normals times its diameter: 68 (the right wall, a rectangle 9 x 10 as two triangles meeting
    the 3-chord fillet at 15 degrees, bulged by up to 1.26 inside a bound of 1.38, set by a
    fillet sliver's long diagonal: 10.1 x its 30 degree turn / 8, where the surface departs from
    that diagonal by 0.1); `patches.surface.guard_bounds` now counts the bend along each edge."""
    nodes, tris, mesh, points, exact, diag, table, _ = cad_stl
    wrong = wrong_signs(table["gap"].to_numpy(), exact, max(1e-3 * diag, _soft_sag(mesh)))
    assert not wrong.any(), (wrong.sum(), points[wrong][:5])


def test_smooth_moves_no_vertex_of_a_cad_stl_beyond_the_guard(cad_stl, tmp_path):
    """Items 1 and 3 (the guard, for `smooth`): refined twice and smoothed, no vertex of the
    CAD STL moves farther from its facets than the guard's bound of the facets it lies on;
    where the facets answer (sharp edges, the guard) vertices stay where they are.

    Before: 5 vertices of 546 moved beyond it, one by 3.7 beyond (5.0 in all)."""
    from diffsurf_cli.smooth import refine
    from diffsurf_cli.targets import read_surface

    _, _, _, _, _, diag, _, path = cad_stl
    out = tmp_path / "smooth.vtu"
    res = run("smooth", path, "-o", out, "--levels", "2")
    assert res.exit_code == 0, res.output + res.stderr
    smoothed = meshio.read(out)
    _, nodes, (tris,) = read_surface(str(path))  # the STL's merged nodes, as smooth reads them
    before, _ = refine(nodes, [tris], 2)
    assert len(before) == len(smoothed.points)
    moved = np.linalg.norm(smoothed.points - before, axis=1)
    np.testing.assert_allclose(smoothed.point_data["moved"], moved, rtol=0, atol=1e-9 * diag)
    # the bound of a vertex: the largest of the facets it lies on (an edge's, a corner's)
    surf = PatchedSurface(nodes, [tris])
    bound, _ = _bound_at(surf, nodes, tris, before, 1e-9 * diag)
    assert (moved <= bound + 1e-9 * diag).all(), (moved - bound).max()
    placed = smoothed.point_data["placed"].astype(bool)
    assert not moved[~placed].any() and (~placed).any()


# --------------------------------------------------------------------------------------------
# item 3: thin walls without tags
# --------------------------------------------------------------------------------------------


def _stl_of_msh(msh, stl):
    """The triangles of a Gmsh file as a binary STL (no tags); returns its nodes and
    triangles."""
    mesh = meshio.read(msh)
    tri = mesh.cells_dict["triangle"]
    used = np.unique(tri)
    nodes = mesh.points[used].astype(np.float32).astype(np.float64)
    tri = np.searchsorted(used, tri)
    meshio.write(stl, meshio.Mesh(nodes, [("triangle", tri)]), binary=True)
    return nodes, tri


def test_thin_plate_without_tags_keeps_its_sides(tmp_path):
    """Item 3: a plate 20 x 20 x 1 meshed at 6 (its faces 0.17 element apart), as an STL
    (no tags): contactors within 0.4 of either face, over the whole plate and past its
    edges, get the plate's exact signed distance.

    A regression test: this scene was already right before issue 19 (flat faces: a patch
    each)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    lo, hi = np.zeros(3), np.array([20.0, 20.0, 1.0])
    msh = gmsh_scenes.box(tmp_path / "plate.msh", lx=20.0, ly=20.0, lz=1.0, size=6.0)
    _stl_of_msh(msh, tmp_path / "plate.stl")
    rng = np.random.default_rng(3)
    k = 3000
    z = np.where(rng.integers(0, 2, k) == 1, 1.0, 0.0) + rng.uniform(-0.4, 0.4, k)
    points = np.column_stack([rng.uniform(-0.5, 20.5, (k, 2)), z])
    exact = fs._box_sdf(points, lo, hi)
    table = project(tmp_path, tmp_path / "plate.stl", points)
    assert answered(table).all()
    np.testing.assert_allclose(table["gap"].to_numpy(), exact, rtol=0, atol=1e-9)


def pipe_sector(path, size=6.0):
    """The surface of a pipe sector, radii 19 and 20, 90 degrees (x, y >= 0), z in 0..20,
    triangles of about `size` (gmsh), as a binary STL; returns its nodes and triangles."""
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("pipe")
        occ = gmsh.model.occ
        outer = occ.addCylinder(0, 0, 0, 0, 0, 20, 20.0)
        inner = occ.addCylinder(0, 0, -1, 0, 0, 22, 19.0)
        pipe, _ = occ.cut([(3, outer)], [(3, inner)])
        quarter = occ.addBox(0, 0, -1, 30, 30, 22)
        occ.intersect(pipe, [(3, quarter)])
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.model.mesh.generate(2)
        msh = str(path.with_suffix(".msh"))
        gmsh.write(msh)
    finally:
        gmsh.finalize()
    nodes, tri = _stl_of_msh(msh, path)
    if trimesh.Trimesh(nodes, tri, process=False).volume < 0:  # facing out
        tri = tri[:, ::-1].copy()
        meshio.write(path, meshio.Mesh(nodes, [("triangle", tri)]), binary=True)
    return nodes, tri


@pytest.fixture(scope="module")
def pipe(tmp_path_factory):
    """A curved wall 1 thick meshed at 6 (chordal sag 0.24), no tags; 4000 contactors within
    0.4 of either curved face, away from the sector's ends; their exact gaps, and diffsurf's
    and the facets' answers."""
    tmp = tmp_path_factory.mktemp("pipe")
    path = tmp / "pipe.stl"
    nodes, _ = pipe_sector(path)
    rng = np.random.default_rng(5)
    k = 4000
    theta = rng.uniform(0.05, np.pi / 2 - 0.05, k)
    r = np.where(rng.integers(0, 2, k) == 1, 20.0, 19.0) + rng.uniform(-0.4, 0.4, k)
    points = np.column_stack([r * np.cos(theta), r * np.sin(theta), rng.uniform(1, 19, k)])
    exact = np.maximum(r - 20.0, 19.0 - r)  # the nearer curved face's
    diag = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    return (points, exact, diag, project(tmp, path, points),
            project(tmp, path, points, "--method", "facet", name="facet"))


def test_curved_thin_wall_signs(pipe):
    """Item 3: a curved wall 1 thick meshed at 6 (sag 0.24), no tags: every contactor within
    0.4 of either face is answered with the sign of the wall's exact signed distance.

    A regression test: this scene was already right before issue 19."""
    points, exact, diag, table, _ = pipe
    assert answered(table).all()
    wrong = wrong_signs(table["gap"].to_numpy(), exact, 1e-3 * diag)
    assert not wrong.any(), wrong.sum()


def test_curved_thin_wall_gaps(pipe):
    """Item 3: on the curved wall, the gaps are those of the nearer smooth face: at least 5x
    more accurate than the facets (largest error against the exact signed distance).

    Before the search beyond the foot's ring (`clearance.foreign_clearance`): a contactor
    inside the wall 0.34-0.40 from the inner face had its faceted foot on the outer face's
    facets (the inner facets lie up to their sag 0.24 farther in), the outer face's smooth
    surface answered (gap about -0.62 where the exact is -0.36): 20 of 4000 points off by up
    to 0.305, more than the facets' largest error (0.272)."""
    points, exact, diag, table, facets = pipe
    err = np.abs(table["gap"].to_numpy() - exact)
    ferr = np.abs(facets["gap"].to_numpy() - exact)
    assert err.max() < ferr.max() / 5, (err.max(), ferr.max(), points[np.argmax(err)])


# --------------------------------------------------------------------------------------------
# item 4: strips one element wide, targets of one facet
# --------------------------------------------------------------------------------------------


def curved_strip(n=16, radius=0.8, arc=32.0, width=0.25):
    """A strip one element wide along an arc (an extruded 2D contact zone): n quads of
    radius x arc / n (0.028) along the arc by `width` (0.25) across, facing out."""
    theta = np.radians(arc) * np.arange(n + 1) / n
    nodes = np.vstack([np.column_stack([radius * np.cos(theta), radius * np.sin(theta),
                                        np.full(n + 1, z)]) for z in (0.0, width)])
    i = np.arange(n)
    return nodes, np.column_stack([i, i + 1, n + 2 + i, n + 1 + i])


def straight_strip(n=16, length=0.45, width=0.25):
    """A flat strip one element wide in the plane y = 0, facing +y: n quads length / n along
    x by `width` across (z)."""
    x = length * np.arange(n + 1) / n
    nodes = np.vstack([np.column_stack([x, np.zeros(n + 1), np.full(n + 1, z)])
                       for z in (0.0, width)])
    i = np.arange(n)
    return nodes, np.column_stack([i, n + 1 + i, n + 2 + i, i + 1])


@pytest.mark.parametrize("kind", ["curved", "straight"])
def test_strip_one_element_wide_is_answered(kind, tmp_path):
    """Item 4: contactors in front of a strip one element wide (within 2% of its diagonal,
    over its whole length and width, open edges included) are answered wherever the facets
    answer them (at most 1% lost), with the strip's exact gap: within the facets' chordal sag
    of the arc (curved), to round-off (straight).

    Before: 86% of 4000 outside (few-nodes, off-target) on both."""
    nodes, quads = curved_strip() if kind == "curved" else straight_strip()
    path = tmp_path / "strip.vtu"
    meshio.write(path, meshio.Mesh(nodes, [("quad", quads)]))
    rng = np.random.default_rng(4)
    k = 4000
    diag = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    offset = rng.uniform(-0.02, 0.02, k) * diag
    z = rng.uniform(0.0, 0.25, k)
    if kind == "curved":
        theta = rng.uniform(0.0, np.radians(32.0), k)
        r = 0.8 + offset
        points = np.column_stack([r * np.cos(theta), r * np.sin(theta), z])
        chord = 2 * 0.8 * np.sin(np.radians(32.0) / 16 / 2)
        tolerance = chord ** 2 / (8 * 0.8)  # the facets' sag: 1.2e-4
    else:
        points = np.column_stack([rng.uniform(0.0, 0.45, k), offset, z])
        tolerance = 1e-12
    facets = project(tmp_path, path, points, "--method", "facet", name="facet")
    table = project(tmp_path, path, points)
    ok, fok = answered(table), answered(facets)
    assert (~ok & fok).sum() <= 0.01 * k, np.unique(table["reason"].to_numpy()[~ok & fok])
    err = np.abs(table["gap"].to_numpy() - offset)[ok]
    assert err.max() <= tolerance, err.max()


@pytest.mark.parametrize("cell", ["quad", "triangle"])
def test_one_facet_target_is_its_plane(cell, tmp_path):
    """Item 4: a target of one facet (4 or 3 nodes: fewer than the quadratic basis) is answered
    with the plane of its facet (terms 3) and the exact gaps of that plane, in front of it.

    Before: refused ('the target has 4 nodes; the quadratic basis needs at least 6')."""
    if cell == "quad":  # a tilted rectangle 2 x 1.5
        nodes = np.array([[0, 0, 0], [2, 0, 0.5], [2, 1.5, 0.5], [0, 1.5, 0]], float)
    else:
        nodes = np.array([[0, 0, 0], [3, 0, 1], [0, 2, 0.5]], float)
    path = tmp_path / "one.vtu"
    meshio.write(path, meshio.Mesh(nodes, [(cell, np.arange(len(nodes))[None])]))
    normal = np.cross(nodes[1] - nodes[0], nodes[-1] - nodes[0])
    normal /= np.linalg.norm(normal)
    rng = np.random.default_rng(6)
    k = 300
    a, b = rng.uniform(0.02, 0.98, (2, k))
    if cell == "triangle":  # inside: a + b < 1
        fold = a + b > 0.98
        a[fold], b[fold] = 0.98 - a[fold], 0.98 - b[fold]
    base = nodes[0] + a[:, None] * (nodes[1] - nodes[0]) + b[:, None] * (nodes[-1] - nodes[0])
    offset = rng.uniform(-0.3, 0.3, k)
    table = project(tmp_path, path, base + offset[:, None] * normal)
    assert answered(table).all()
    assert (table["terms"].to_numpy() == 3).all()
    np.testing.assert_allclose(table["gap"].to_numpy(), offset, rtol=0, atol=1e-12)
    normals = table.select("nx", "ny", "nz").to_numpy()
    np.testing.assert_allclose(normals, np.broadcast_to(normal, normals.shape), atol=1e-12)
