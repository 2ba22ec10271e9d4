"""Tests of the faceted target (`diffsurf_cli.facet`): the compiled engine against the slow,
obvious brute force of `reference_facet.py` on every scene, the pseudonormal sign on a
non-convex closed block, facets the nearest nodes do not reach, bad and huge contactors, the
frozen pairing (`project_with`), and the surface's input checks.
"""
from __future__ import annotations

import zlib

import numpy as np
import pytest

from diffsurf_cli.facet import surface as facet_surface
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.projection import BAD_POINT, CONTACT, FAILED, OK, OPEN, PENETRATION
from diffsurf_cli.testing.shapes import Cylinder, Saddle, Sphere, Torus, random_rotation
from reference_facet import ReferenceFacets, closest_on_facet, facet_point

# -- scenes ------------------------------------------------------------------------------------

def _polycube(quads: bool, mixed: bool = False):
    """The closed surface of [0, 2]³ less the cube [1, 2]³: convex edges, concave edges, a
    concave vertex (1, 1, 1) and vertices where convex and concave edges meet. Unit squares
    as quads, as two triangles each, or (`mixed`) alternately. Outward normals."""
    cells = {(i, j, k) for i in range(2) for j in range(2) for k in range(2)} - {(1, 1, 1)}
    index, nodes, tris, quad = {}, [], [], []

    def node(p):
        if p not in index:
            index[p] = len(nodes)
            nodes.append(p)
        return index[p]

    for c in sorted(cells):
        for axis in range(3):
            for step in (-1, 1):
                nb = list(c)
                nb[axis] += step
                if tuple(nb) in cells:
                    continue
                # the face of cell c on its `step` side along `axis`, counter-clockwise seen
                # from outside
                u, v = [a for a in range(3) if a != axis]
                base = list(c)
                base[axis] += 1 if step > 0 else 0
                corners = []
                for du, dv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                    p = list(base)
                    p[u] += du
                    p[v] += dv
                    corners.append(node(tuple(p)))
                x = np.array([nodes[i] for i in corners], float)
                n = np.cross(x[1] - x[0], x[3] - x[0])
                if n[axis] * step < 0:
                    corners = corners[::-1]
                if quads and (not mixed or (sum(c) + axis) % 2 == 0):
                    quad.append(corners)
                else:
                    tris += [[corners[0], corners[1], corners[2]], [corners[0], corners[2],
                                                                     corners[3]]]
    faces = [np.array(f, dtype=np.int64).reshape(-1, n) for f, n in ((tris, 3), (quad, 4)) if f]
    return np.array(nodes, float), faces


def _inside_polycube(p):
    inside_box = np.all((p > 0) & (p < 2), axis=1)
    in_notch = np.all(p > 1, axis=1)
    return inside_box & ~in_notch


def _mixed_saddle():
    """Twisted bilinear quads, every other one split into two triangles (open)."""
    nodes, quads = Saddle().mesh_quads(6)
    split = np.arange(len(quads)) % 2 == 1
    q = quads[split]
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return nodes, [tris, quads[~split]]


def _sphere():
    rot = random_rotation(7)
    nodes, faces = Sphere(radius=2.0).mesh(3)
    return nodes @ rot.T + np.array([3.0, -2.0, 5.0]), [faces]


def _torus():
    nodes, quads = Torus(major=1.0, minor=0.4).mesh_quads(12)
    return nodes, [quads]


def _saddle():
    nodes, quads = Saddle().mesh_quads(5)
    return nodes, [quads]


def _half_cylinder():
    nodes, quads = Cylinder(radius=1.0, length=2.0, theta_range=(np.pi, 2 * np.pi)).mesh_quads(8)
    return nodes, [quads]


SCENES = {
    "sphere-triangles-closed": _sphere,
    "torus-quads-closed": _torus,
    "saddle-quads-open": _saddle,
    "saddle-mixed-open": _mixed_saddle,
    "half-cylinder-quads-open": _half_cylinder,
    "polycube-triangles-closed": lambda: _polycube(False),
    "polycube-quads-closed": lambda: _polycube(True),
    "polycube-mixed-closed": lambda: _polycube(True, mixed=True),
}


def _probe_points(nodes, faces, rng, m=150):
    """Points everywhere a search can go wrong: random in and around the box, near nodes and
    edge midpoints (1e-3 and 1e-8 of a spacing off), on nodes, far away (1e3 sizes)."""
    lo, hi = nodes.min(0), nodes.max(0)
    size = np.linalg.norm(hi - lo)
    h = size / np.sqrt(len(nodes))
    box = rng.uniform(lo - 0.2 * size, hi + 0.2 * size, (m, 3))
    f = np.concatenate([b[:, :3] for b in faces])
    mid = 0.5 * (nodes[f[:, 0]] + nodes[f[:, 1]])
    pick = rng.choice(len(nodes), 20, replace=False)
    near_nodes = nodes[pick] + rng.standard_normal((20, 3)) * 1e-3 * h
    near_mids = mid[rng.choice(len(mid), 20, replace=False)] + \
        rng.standard_normal((20, 3)) * 1e-8 * h
    on_nodes = nodes[rng.choice(len(nodes), 5, replace=False)]
    u = rng.standard_normal((10, 3))
    far = 0.5 * (lo + hi) + 1e3 * size * u / np.linalg.norm(u, axis=1, keepdims=True)
    return np.concatenate([box, near_nodes, near_mids, on_nodes, far]), size


def _assert_matches(res, ref, points, surf, size):
    """The engine's answer is the reference's, to rounding: same status, gap, proximal point
    and normal; its facet is a closest facet and its ξ maps to its proximal point."""
    np.testing.assert_array_equal(res.status, ref.status)
    np.testing.assert_array_equal(res.reason, ref.reason)
    ok = ref.status != FAILED
    scale = size + np.abs(points[ok]).max(axis=1)
    assert np.all(np.abs(res.gap[ok] - ref.gap[ok]) <= 1e-12 * scale)
    # where two features are within rounding of each other (a point on the border of a
    # vertex's Voronoi region), the proximal point is determined to sqrt(ε) x distance
    dist = np.linalg.norm(points[ok] - ref.proximal_point[ok], axis=1)
    assert np.all(np.abs(res.proximal_point[ok] - ref.proximal_point[ok]).max(1)
                  <= 1e-11 * size + 1e-7 * dist)
    sharp = dist > 1e-6 * size  # the direction to a point on the target is round-off there
    np.testing.assert_allclose(res.normal[ok][sharp], ref.normal[ok][sharp], atol=1e-9)
    for i, s in zip(np.flatnonzero(ok), scale):
        f = res.facet[i]
        kind = 3 if surf.facets[f, 3] < 0 else 4
        corners = surf.nodes[surf.facets[f, :kind]]
        np.testing.assert_allclose(facet_point(corners, kind, res.param[i]),
                                   res.proximal_point[i], atol=1e-12 * size)
        # the engine's facet is one of the closest (by the reference's own closest point on it)
        own = facet_point(corners, kind, closest_on_facet(points[i], corners, kind))
        assert abs(np.linalg.norm(points[i] - own) - abs(ref.gap[i])) <= 1e-12 * s
    assert np.all(np.isnan(res.gap[~ok])) and np.all(res.facet[~ok] == -1)


# -- the engine against the brute force --------------------------------------------------------

@pytest.mark.parametrize("name", SCENES)
def test_project_matches_brute_force(name):
    nodes, faces = SCENES[name]()
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    points, size = _probe_points(nodes, faces, rng)
    surf = FacetSurface(nodes, faces)
    res = surf.project(points)
    ref = ReferenceFacets(nodes, faces).project(points)
    _assert_matches(res, ref, points, surf, size)
    # every status the scene can give is exercised
    assert (res.status == CONTACT).any()
    if "closed" in name:
        assert (res.status == OPEN).any() and (res.status == PENETRATION).any()


@pytest.mark.parametrize("name", SCENES)
def test_project_with_matches_brute_force(name):
    nodes, faces = SCENES[name]()
    rng = np.random.default_rng(1 + zlib.crc32(name.encode()))
    points, size = _probe_points(nodes, faces, rng, m=60)
    surf = FacetSurface(nodes, faces)
    given = rng.integers(-1, len(surf.facets), len(points))
    res = surf.project_with(points, given)
    ref = ReferenceFacets(nodes, faces).project_with(points, given)
    np.testing.assert_array_equal(res.status, ref.status)
    ok = ref.status != FAILED
    assert np.all(given[~ok] == -1)
    assert np.all(res.facet[ok] == given[ok])
    np.testing.assert_allclose(res.param[ok], ref.param[ok], atol=1e-7)
    scale = size + np.abs(points[ok]).max(axis=1)
    assert np.all(np.abs(res.gap[ok] - ref.gap[ok]) <= 1e-12 * scale)
    dist = np.abs(ref.gap[ok])
    assert np.all(np.abs(res.proximal_point[ok] - ref.proximal_point[ok]).max(1)
                  <= 1e-11 * size + 1e-7 * dist)


@pytest.mark.parametrize("name", ["sphere-triangles-closed", "torus-quads-closed",
                                  "saddle-mixed-open"])
def test_project_with_own_pairing_is_project(name):
    nodes, faces = SCENES[name]()
    points, _ = _probe_points(nodes, faces, np.random.default_rng(2))
    points[3] = np.nan
    surf = FacetSurface(nodes, faces)
    res = surf.project(points)
    again = surf.project_with(points, res.facet)
    for field in ("gap", "normal", "proximal_point", "status", "reason", "facet", "param"):
        np.testing.assert_array_equal(getattr(again, field), getattr(res, field), field)


# -- the sign: pseudonormals --------------------------------------------------------------------

@pytest.mark.parametrize("quads, mixed", [(False, False), (True, False), (True, True)],
                         ids=["triangles", "quads", "mixed"])
def test_sign_is_inside_outside_on_a_non_convex_block(quads, mixed):
    """Around every edge and vertex of the notched cube (convex, concave, and vertices where
    both meet), the gap is negative exactly inside the solid."""
    nodes, faces = _polycube(quads, mixed)
    surf = FacetSurface(nodes, faces)
    rng = np.random.default_rng(11)
    grid = np.array(np.meshgrid(*[np.arange(3.0)] * 3, indexing="ij")).reshape(3, -1).T
    around = np.concatenate([grid + rng.uniform(-0.3, 0.3, (len(grid), 3))
                             for _ in range(150)])
    mids = np.concatenate([(grid + 0.5 * e) for e in np.eye(3)])
    around = np.concatenate([around, np.concatenate(
        [mids + rng.uniform(-0.2, 0.2, (len(mids), 3)) for _ in range(40)])])
    res = surf.project(around)
    inside = _inside_polycube(around)
    clear = np.abs(res.gap) > 1e-9
    assert clear.sum() > 5000
    np.testing.assert_array_equal(res.gap[clear] < 0, inside[clear])
    np.testing.assert_array_equal(res.status[clear] == PENETRATION, inside[clear])



def _pyramid():
    """A closed pyramid, 4 high on a 2 x 2 base (triangles): at its apex the facet normals
    are more than 90° apart."""
    nodes = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [0, 0, 4]], float)
    faces = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [0, 2, 1], [0, 3, 2]])
    return nodes, faces


def test_sign_at_a_sharp_vertex():
    """Around the apex, the gap is negative exactly inside; there a facet holding the
    proximal point often has an outside contactor below its plane (the chosen facet's own
    side, the former rule, depends on which of the tied facets a search picks)."""
    nodes, faces = _pyramid()
    surf = FacetSurface(nodes, faces)
    rng = np.random.default_rng(12)
    points = np.concatenate([nodes[4] + rng.uniform(-0.3, 0.3, (3000, 3)),
                             nodes[rng.integers(0, 4, 2000)] + rng.uniform(-0.2, 0.2, (2000, 3))])
    res = surf.project(points)
    x = nodes[faces]
    plane = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    offset = np.einsum("fd,fd->f", plane, x[:, 0])
    inside = np.all(points @ plane.T < offset, axis=1)
    clear = np.abs(res.gap) > 1e-9
    np.testing.assert_array_equal(res.gap[clear] < 0, inside[clear])
    ref = ReferenceFacets(nodes, faces).project(points)
    np.testing.assert_array_equal(res.status, ref.status)
    d = points - res.proximal_point
    holds = np.abs(res.proximal_point @ plane.T - offset) < 1e-12  # on the facet's plane
    wrong = holds & ((d @ plane.T < 0) != inside[:, None])
    assert (wrong.any(axis=1) & clear & ~inside).sum() > 100


def test_sign_at_convex_and_concave_edges_and_vertices():
    nodes, faces = _polycube(True)
    surf = FacetSurface(nodes, faces)
    e = 1e-3
    cases = {
        # just outside a convex edge and a convex vertex of the block
        (2 + e, 0.5, 0 - e): (OPEN, np.sqrt(2) * e),
        (2 + e, -e, -e): (OPEN, np.sqrt(3) * e),
        # just inside the concave edge x = y = 1 (z in 1..2) and the concave vertex (1, 1, 1):
        # the edge and the vertex are the closest points
        (1 - e, 1 - e, 1.5): (PENETRATION, -np.sqrt(2) * e),
        (1 - e, 1 - e, 1 - e): (PENETRATION, -np.sqrt(3) * e),
        # just outside them, in the notch
        (1 + e, 1 + e, 1.5): (OPEN, e),
        (1 + e, 1 + e, 1 + e): (OPEN, e),
        # next to the vertex (1, 1, 2), where two convex edges and a concave one meet
        (1 - e, 1 - e, 2 + e): (OPEN, e),
        (1 + e, 1 + e, 2 - e): (OPEN, e),
    }
    res = surf.project(np.array(list(cases)))
    want = np.array(list(cases.values()))
    np.testing.assert_array_equal(res.status, want[:, 0].astype(int))
    np.testing.assert_allclose(res.gap, want[:, 1], rtol=1e-12)
    flipped = FacetSurface(nodes, faces, flip=True).project(np.array(list(cases)))
    np.testing.assert_array_equal(flipped.gap, -res.gap)
    np.testing.assert_array_equal(flipped.normal, -res.normal)
    np.testing.assert_array_equal(flipped.status == PENETRATION, res.status == OPEN)


# -- what the former search missed ------------------------------------------------------------

def test_large_facets_and_slivers_are_found():
    """Two large triangles under a fine patch, and a fan of slivers: the closest facet's
    corners are far from the contactor's nearest nodes."""
    big = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], float)
    g = np.linspace(0, 1, 21)
    fine = np.array(np.meshgrid(g, g, [1.0], indexing="ij")).reshape(3, -1).T
    ij = np.arange(21 * 21).reshape(21, 21)
    q = np.stack([ij[:-1, :-1], ij[1:, :-1], ij[1:, 1:], ij[:-1, 1:]], -1).reshape(-1, 4) + 4
    # slivers: a fan of 200 triangles 20 long and 1e-3 wide at their far end, at z = -3
    t = np.arange(201) * 1e-4
    fan = np.concatenate([[[0.0, 5.0, -3.0]], np.stack([np.full(201, 20.0), 5 + t,
                                                        np.full(201, -3.0)], -1)])
    off = 4 + len(fine)
    fan_f = np.stack([np.zeros(200, int), np.arange(1, 201), np.arange(2, 202)], -1) + off
    nodes = np.concatenate([big, fine, fan])
    faces = [np.array([[0, 1, 2], [0, 2, 3]]), q, fan_f]
    points = np.array([[5, 5, 0.3], [8, 2, -0.2], [5, 5, 0.7], [12, 5.01, -2.5],
                       [19, 5.0101, -3.2], [3, 9, 0.45]])
    res = FacetSurface(nodes, faces).project(points)
    ref = ReferenceFacets(nodes, faces).project(points)
    np.testing.assert_array_equal(res.status, ref.status)
    np.testing.assert_allclose(res.gap, ref.gap, rtol=1e-12)
    np.testing.assert_allclose(res.gap, [0.3, -0.2, 0.7, 0.5, -0.2, 0.45], rtol=1e-12)
    exact = points * [1, 1, 0] + [0, 0, 1] * np.array([0, 0, 0, -3, -3, 0])[:, None]
    np.testing.assert_allclose(res.proximal_point[[0, 1, 2, 5]], exact[[0, 1, 2, 5]],
                               atol=1e-14)
    # on the slivers (aspect 2e5), the position along them is ill-conditioned
    np.testing.assert_allclose(res.proximal_point[3:5], exact[3:5], atol=1e-4)
    # the former search (facets around the 12 nearest nodes) misses them: the scene can fail
    old = ReferenceFacets(nodes, faces, candidates=12).project(points)
    assert (np.abs(old.gap - ref.gap) > 4).sum() == 2


# -- bad and extreme contactors ---------------------------------------------------------------

def test_bad_points_are_failed_rows():
    nodes, faces = _sphere()
    surf = FacetSurface(nodes, faces)
    points = np.array([[3, -2, 5], [np.nan, 0, 0], [0, np.inf, 0], [-np.inf, 0, 1],
                       [3, -2, 7.5]])
    res = surf.project(points)
    bad = np.array([False, True, True, True, False])
    assert np.all(res.status[bad] == FAILED) and np.all(res.reason[bad] == BAD_POINT)
    assert np.all(res.status[~bad] != FAILED) and np.all(res.reason[~bad] == OK)
    for field in (res.gap, res.normal, res.proximal_point, res.rcond, res.curvature, res.param):
        assert np.isnan(field[bad]).all() and np.isfinite(field[~bad]).all()
    assert np.all(res.facet[bad] == -1) and np.all(res.support[bad] == 0)
    assert res.status[0] == PENETRATION and res.status[4] == OPEN


@pytest.mark.parametrize("magnitude", [1e20, 1e155, 1e300])
def test_huge_coordinates_are_far_and_open(magnitude):
    """Far contactors of a closed target are outside: gap ≈ distance > 0, status open, and the
    proximal point is the target's extreme node in their direction (no overflow, no ties
    broken at random)."""
    nodes, faces = _sphere()
    centre = np.array([3.0, -2.0, 5.0])
    rng = np.random.default_rng(4)
    u = np.concatenate([np.eye(3), -np.eye(3), rng.standard_normal((30, 3))])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = magnitude * u
    res = FacetSurface(nodes, faces).project(points)
    assert np.all(res.status == OPEN), res.status
    assert np.all(np.isfinite(res.gap)) and np.all(res.gap > 0)
    np.testing.assert_allclose(res.gap, np.linalg.norm(points / magnitude - res.proximal_point
                                                       / magnitude, axis=1) * magnitude,
                               rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(res.normal, axis=1), 1.0, rtol=1e-12)
    # the extreme point of the target in direction u (from the centre the point is seen from)
    dirs = (points - centre) / magnitude
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    reach = np.einsum("ij,ij->i", res.proximal_point - centre, dirs)
    best = ((nodes - centre) @ dirs.T).max(axis=0)
    assert np.all(reach >= best - 1e-12)


@pytest.mark.parametrize("magnitude", [1e20, 1e155])
def test_huge_coordinates_on_an_open_target_do_not_crash(magnitude):
    nodes, faces = _half_cylinder()
    points = magnitude * np.array([[1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [-1, 1, 1]])
    res = FacetSurface(nodes, faces).project(points)
    assert np.all(res.status != FAILED)
    np.testing.assert_allclose(np.abs(res.gap) / magnitude,
                               np.linalg.norm(points / magnitude, axis=1), rtol=1e-12)
    # straight below the open half cylinder (y < 0 side, its outside) it is open
    assert res.status[2] == OPEN and res.status[1] == PENETRATION


def test_cli_facet_method_with_huge_coordinates(tmp_path):
    """issue 14, item 7: `--method facet` at 1e155 ended in an IndexError and at 1e20 gave a
    penetration of -1e20. Beside the sample's lower half cylinder (normals out, downwards),
    far along x at the plate's height is outside: open, closest to the rim x = 42.5, y = 30."""
    import csv

    from samples import CYLINDER, run

    path = tmp_path / "big.csv"
    path.write_text("x,y,z\n1e155,20,0\n1e20,20,0\n-1e20,20,2.5\n30,-1e300,2\n")
    result = run("-q", "project", CYLINDER, path, "--method", "facet")
    assert result.exit_code == 0, result.stderr
    rows = list(csv.DictReader(result.stdout.splitlines()))
    assert [r["status"] for r in rows] == ["open"] * 4
    assert [float(r["gap"]) for r in rows] == pytest.approx([1e155, 1e20, 1e20, 1e300],
                                                             rel=1e-12)
    np.testing.assert_allclose([(float(r["px"]), float(r["py"])) for r in rows[:3]],
                               [(42.5, 30), (42.5, 30), (22.5, 30)], atol=1e-9)


def test_far_points_match_the_brute_force():
    """From 1e3 to 1e6 target sizes (where float64 still resolves the target), the far
    ranking picks the same closest point as |p - x|²."""
    nodes, faces = _torus()
    rng = np.random.default_rng(9)
    u = rng.standard_normal((60, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    points = u * np.logspace(3, 6, 60)[:, None]
    res = FacetSurface(nodes, faces).project(points)
    ref = ReferenceFacets(nodes, faces).project(points)
    np.testing.assert_array_equal(res.status, ref.status)
    np.testing.assert_allclose(res.gap, ref.gap, rtol=1e-13)
    np.testing.assert_allclose(res.proximal_point, ref.proximal_point, atol=1e-9)


# -- invariance and the surface's interface ----------------------------------------------------

def test_answers_do_not_depend_on_facet_order_or_placement():
    nodes, faces = _polycube(True, mixed=True)
    rng = np.random.default_rng(5)
    points = rng.uniform(-0.5, 2.5, (400, 3))
    res = FacetSurface(nodes, faces).project(points)
    shuffled = [f[rng.permutation(len(f))] for f in faces[::-1]]
    again = FacetSurface(nodes, shuffled).project(points)
    np.testing.assert_allclose(again.gap, res.gap, atol=1e-14)
    np.testing.assert_allclose(again.proximal_point, res.proximal_point, atol=1e-14)
    np.testing.assert_array_equal(again.status, res.status)
    rot, shift = random_rotation(3), np.array([1e3, -2e3, 5e2])
    moved = FacetSurface(nodes @ rot.T + shift, faces).project(points @ rot.T + shift)
    np.testing.assert_allclose(moved.gap, res.gap, atol=1e-11)
    np.testing.assert_array_equal(moved.status, res.status)


def test_points_in_any_layout_and_chunks_with_progress(monkeypatch):
    nodes, faces = _torus()
    rng = np.random.default_rng(6)
    points = rng.uniform(-1.5, 1.5, (50, 3)).astype(np.float32).astype(np.float64)
    surf = FacetSurface(nodes, np.concatenate(faces))
    res = surf.project(points)
    for other in (points.tolist(), points.astype(np.float32), np.asfortranarray(points),
                  np.repeat(points, 2, axis=0)[::2]):
        np.testing.assert_array_equal(surf.project(other).gap, res.gap)
    done = []
    monkeypatch.setattr(facet_surface, "CHUNK", 7)
    chunked = surf.project(points, progress=done.append)
    np.testing.assert_array_equal(chunked.gap, res.gap)
    assert done == [0, *range(7, 50, 7), 50]  # progress(0): the work starts
    assert len(surf.project(np.empty((0, 3))).gap) == 0


def test_spatial_order_changes_nothing():
    """Large clouds are taken in Morton order (from 2048 points): each row's answer is the
    one it gets alone, bit for bit, and the order is a permutation of the rows."""
    nodes, faces = _torus()
    rng = np.random.default_rng(8)
    points = rng.uniform(-1.6, 1.6, (6000, 3))
    points[::997] = np.nan
    points[5] = 1e200
    surf = FacetSurface(nodes, faces)
    order = facet_surface._spatial_order(points, surf._tables)
    assert not np.array_equal(order, np.arange(len(points)))
    np.testing.assert_array_equal(np.sort(order), np.arange(len(points)))
    whole = surf.project(points)
    parts = [surf.project(points[i:i + 1000]) for i in range(0, len(points), 1000)]
    for field in ("gap", "normal", "proximal_point", "status", "facet", "param", "iterations"):
        np.testing.assert_array_equal(getattr(whole, field),
                                      np.concatenate([getattr(p, field) for p in parts]), field)


@pytest.mark.parametrize("nodes, faces, message", [
    (np.zeros((3, 3)), [np.empty((0, 3), int)], "needs surface cells"),
    (np.eye(3), [np.array([[0, 1, 2, 0, 1]])], "3 or 4 corners"),
    (np.eye(3), [np.array([[0, 1, 3]])], "index the 3 nodes"),
    (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [np.array([[0, 1, 2]])], "NaN"),
    (np.eye(3) * 1e60, [np.array([[0, 1, 2]])], "beyond the supported"),
])
def test_bad_targets_are_refused(nodes, faces, message):
    with pytest.raises(ValueError, match=message):
        FacetSurface(nodes, faces)


def test_bad_pairings_are_refused():
    nodes, faces = _sphere()
    surf = FacetSurface(nodes, faces)
    points = np.zeros((2, 3))
    for facet in ([0], [0, len(surf.facets)], [0, -2]):
        with pytest.raises(ValueError, match="pairing"):
            surf.project_with(points, facet)


def test_degenerate_facets_give_answers_not_crashes():
    """A zero-area triangle and a quad collapsed to a triangle among good facets."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0, 0], [2, 0, 0],
                      [2, 1, 0]], float)
    faces = [np.array([[0, 1, 2], [0, 2, 3], [0, 4, 1]]), np.array([[1, 5, 6, 6]])]
    points = np.array([[0.5, -0.1, 0.1], [0.5, 0.0, 0.0], [1.5, 0.3, 0.2], [1.5, 0.3, -0.2],
                       [0.5, 0.5, 0.2]])
    res = FacetSurface(nodes, faces).project(points)
    assert np.all(np.isfinite(res.gap)) and np.all(np.isfinite(res.normal))
    np.testing.assert_allclose(res.gap[2:], [0.2, -0.2, 0.2], atol=1e-12)
    np.testing.assert_allclose(np.abs(res.gap[:2]), [np.hypot(0.1, 0.1), 0.0], atol=1e-12)
    assert res.status[1] == CONTACT


def test_points_on_edges_and_vertices_get_the_pseudonormal():
    """Issue 22, item 8: a point exactly on a facet edge (or at a vertex) is at round-off
    distance from its closest point, whose direction was returned as the normal (an axis, for
    272 of 1,280 edge midpoints of a sphere). On the target at an edge or a vertex, the normal
    is the pseudonormal there: within a facet's bend of the sphere's radial direction."""
    from diffsurf_cli.testing.shapes import Sphere

    nodes, faces = Sphere(radius=1.0).mesh(8)
    surf = FacetSurface(nodes, [faces])
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    on = np.vstack([0.5 * (nodes[edges[:, 0]] + nodes[edges[:, 1]]), nodes])
    proj = surf.project(on)
    radial = on / np.linalg.norm(on, axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", proj.normal, radial)
    assert (proj.status == CONTACT).all()
    assert cos.min() > np.cos(np.radians(5.0)), np.degrees(np.arccos(cos.min()))
    np.testing.assert_allclose(np.linalg.norm(proj.normal, axis=1), 1.0, rtol=0, atol=1e-15)
