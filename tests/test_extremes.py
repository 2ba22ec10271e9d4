"""Numerical extremes of the diffuse projection (issue 6): scale, degenerate supports, far and
steep contactors, interpolation through a node, Newton failure, ill-conditioned fits.

Every case is a test named after it. Each either gets a correct finite answer, checked against
an exact shape (`shapes`), or a status 'outside'/'failed' with the reason that
applies; `check_consistent` checks on every result that status, reason and NaNs agree. Every
case runs on the compiled engine (the numpy reference is checked against it in test_engine.py).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from diffsurf_cli import tol
from diffsurf_cli.element.element import contact
from diffsurf_cli.mls import surface as surface_mod
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import CONTACT, FAILED, OK, OPEN, OUTSIDE, PENETRATION, REASONS, STATUS
from diffsurf_cli.testing.shapes import Cylinder, Paraboloid, Plane, Saddle, Sphere, Torus
from reference import beyond_hull as _beyond_hull

ENGINES = getattr(surface_mod, "ENGINES", (None,))
REASON = {name: i for i, name in enumerate(REASONS)}
#: Reasons that go with each trouble status.
OUTSIDE_REASONS = {REASON[r] for r in ("few-nodes", "ill-conditioned", "off-target", "steep")}
FAILED_REASONS = {REASON[r] for r in ("bad-point", "no-convergence", "recentre")}
THIN = {REASON["few-nodes"], REASON["ill-conditioned"]}


# --------------------------------------------------------------------------- helpers
def build(nodes, faces=None, engine=None, **options):
    """A DiffuseSurface on `engine` (None: the default, for a core without engines)."""
    if engine is not None:
        options["engine"] = engine
    faces = None if faces is None else [faces] if isinstance(faces, np.ndarray) else faces
    return DiffuseSurface(nodes, faces, **options)


def check_consistent(result):
    """Status, reason and geometry agree on every row.

    open/contact/penetration ⇔ reason 'ok' ⇔ finite gap, unit normal and proximal point, the
    gap's sign matching the status; outside ⇔ a support reason (few-nodes, ill-conditioned,
    off-target, steep), failed ⇔ a point or solver reason, both with NaN gap, normal, proximal
    point and curvature; the reciprocal condition number is a number in [0, 1].
    """
    status, reason = result.status, result.reason
    assert status.dtype == np.int8 and reason.dtype == np.int8
    assert np.all((status >= 0) & (status < len(STATUS)))
    assert np.all((reason >= 0) & (reason < len(REASONS)))
    good = status <= PENETRATION
    np.testing.assert_array_equal(reason == OK, good)
    assert all(r in OUTSIDE_REASONS for r in reason[status == OUTSIDE]), result.reason_names
    assert all(r in FAILED_REASONS for r in reason[status == FAILED]), result.reason_names
    geometry = (result.gap[:, None], result.normal, result.proximal_point)
    finite = np.all(np.concatenate([np.isfinite(g) for g in geometry], axis=1), axis=1)
    np.testing.assert_array_equal(finite, good)
    nan = np.all(np.concatenate([np.isnan(g) for g in geometry + (result.curvature,)], axis=1),
                 axis=1)
    np.testing.assert_array_equal(nan, ~good)
    assert np.all(np.abs(np.linalg.norm(result.normal[good], axis=1) - 1) < 1e-12)
    assert np.all(result.gap[status == OPEN] > 0)
    assert np.all(result.gap[status == PENETRATION] < 0)
    # NaN where nothing was fitted: a NaN contactor, or one far from every node (off-target)
    fitted = ~np.isin(reason, [REASON["bad-point"], REASON["off-target"]])
    assert not np.isnan(result.rcond[fitted]).any(), result.rcond
    rcond = result.rcond[~np.isnan(result.rcond)]
    assert np.all((rcond >= 0) & (rcond <= 1 + 1e-12)), rcond
    return result


def reasons(result):
    return {name: int(c) for name, c in zip(REASONS, np.bincount(result.reason,
                                                                   minlength=len(REASONS))) if c}


def unsigned_error(result, dist):
    """|gap - exact| on the answered rows (all rows must have a finite exact value)."""
    good = result.status <= PENETRATION
    return np.abs(result.gap[good] - dist[good])


@pytest.fixture(params=ENGINES)
def engine(request):
    return request.param


# --------------------------------------------------------------------------- 1. scale
def _scene(kind):
    """Target, contactors and the options of a scale test, at unit scale."""
    if kind == "sphere":
        shape = Sphere(center=(0.1, -0.2, 0.3), radius=1.0)
        nodes, faces = shape.mesh(6)
        return shape, nodes, faces, shape.sample_near(150, 0.05, 1), {}
    if kind == "saddle-global":
        shape = Saddle(a=0.4, size=1.0)
        nodes, faces = shape.mesh(10)
        return shape, nodes, faces, shape.sample_near(150, 0.1, 2), {"frame": "global"}
    shape = Cylinder(radius=1.0, length=2.0)
    nodes, faces = shape.mesh_quads(24)
    return shape, nodes, faces, shape.sample_near(150, 0.05, 3), {}


SCENES = ("sphere", "saddle-global", "cylinder-quads")


@pytest.mark.parametrize("weight", ["wendland", "singular"])
@pytest.mark.parametrize("kind", SCENES)
@pytest.mark.parametrize("scale", [1e-9, 1e9], ids=["1e-9", "1e+9"])
def test_scene_scaled(scale, kind, weight, engine):
    """Target and contactors scaled by 1e-9 and 1e+9: gaps scale exactly, normals are
    unchanged. Measured: gaps agree to 7e-15 of the unit-scale gaps, normals to 3e-15; the
    bound 1e-12 (relative to the spacing h) leaves two decades of margin for round-off only."""
    shape, nodes, faces, points, options = _scene(kind)
    unit = check_consistent(build(nodes, faces, engine, weight=weight, **options).project(points))
    scaled = check_consistent(build(nodes * scale, faces, engine, weight=weight,
                                    **options).project(points * scale))
    assert np.all(unit.status <= PENETRATION), reasons(unit)
    np.testing.assert_array_equal(scaled.status, unit.status)
    h = float(np.max(build(nodes, faces, engine).node_spacing))
    np.testing.assert_allclose(scaled.gap / scale, unit.gap, rtol=0, atol=1e-12 * h)
    np.testing.assert_allclose(scaled.normal, unit.normal, rtol=0, atol=1e-12)
    np.testing.assert_allclose(scaled.proximal_point / scale, unit.proximal_point, rtol=0,
                               atol=1e-12 * h)
    np.testing.assert_allclose(scaled.curvature * scale, unit.curvature, rtol=1e-9, atol=1e-9)
    # and the error against the exact surface is the unit-scale one
    _, _, dist = shape.closest(points)
    np.testing.assert_allclose(np.abs(scaled.gap / scale - dist), np.abs(unit.gap - dist),
                               rtol=0, atol=1e-12 * h)


@pytest.mark.parametrize("weight", ["wendland", "singular"])
@pytest.mark.parametrize("kind", SCENES)
def test_scene_translated_by_1e6(kind, weight, engine):
    """Target and contactors moved by 1e6 (all three axes): every coordinate is then only known
    to u = 1e6 eps = 2.2e-10, so gaps and proximal points can only be that good. Measured: they
    move by at most 0.8 u, normals by 0.4 u/h; the error against the exact surface is the
    unit-scale error plus that (sphere 5.5e-5 -> 5.5e-5, saddle exact 2e-16 -> 1.5e-10)."""
    shape, nodes, faces, points, options = _scene(kind)
    shift = np.array([1e6, -1e6, 1e6])
    u = 1e6 * np.finfo(float).eps
    unit = check_consistent(build(nodes, faces, engine, weight=weight, **options).project(points))
    moved = check_consistent(build(nodes + shift, faces, engine, weight=weight,
                                   **options).project(points + shift))
    np.testing.assert_array_equal(moved.status, unit.status)
    h = float(np.min(build(nodes, faces, engine).node_spacing))
    np.testing.assert_allclose(moved.gap, unit.gap, rtol=0, atol=8 * u)
    np.testing.assert_allclose(moved.normal, unit.normal, rtol=0, atol=8 * u / h)
    np.testing.assert_allclose(moved.proximal_point - shift, unit.proximal_point, rtol=0,
                               atol=8 * u)
    _, _, dist = shape.closest(points)
    e_unit, e_moved = np.abs(unit.gap - dist).max(), np.abs(moved.gap - dist).max()
    assert e_moved <= e_unit + 8 * u, (e_moved, e_unit)


@pytest.mark.parametrize("scale", [1e-60, 1e60])
def test_target_beyond_the_supported_range_is_refused(scale, engine):
    """Past tol.COORDINATE_MAX / SPACING_MIN fourth powers of lengths leave float64: the target
    is refused with a one-line message, not projected wrongly or crashed on; just inside the
    range the scaling is still exact."""
    nodes, faces = Sphere().mesh(4)
    with pytest.raises(ValueError, match="rescale the mesh") as err:
        build(nodes * scale, faces, engine)
    assert "\n" not in str(err.value)
    points = Sphere().sample_near(50, 0.05, 3)
    unit = build(nodes, faces, engine).project(points)
    inside = 1e-45 if scale < 1 else 1e45
    near = check_consistent(build(nodes * inside, faces, engine).project(points * inside))
    np.testing.assert_array_equal(near.status, unit.status)
    np.testing.assert_allclose(near.gap / inside, unit.gap, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- 2. degenerate support
@pytest.mark.parametrize("engine", ["kernel", "numpy"]
                         if "kernel" in ENGINES else ENGINES)
@pytest.mark.parametrize("frame", ["auto", "global", "local"])
def test_collinear_target(frame, engine):
    """All nodes on one line: no support can fix a surface; every point is outside, with
    'few-nodes' or 'ill-conditioned' and the condition number that says so."""
    x = np.linspace(0.0, 1.0, 21)
    nodes = np.column_stack([x, 0.5 * x, 0.2 * x])
    points = np.array([[0.5, 0.25, 0.2], [0.5, 0.35, 0.1], [0.3, 0.15, 0.06], [0.0, 0.0, 0.1]])
    result = check_consistent(build(nodes, None, engine, frame=frame).project(points))
    assert np.all(result.status == OUTSIDE), reasons(result)
    assert set(result.reason) <= THIN, reasons(result)
    ill = result.reason == REASON["ill-conditioned"]
    assert np.all(result.rcond[ill] < tol.RCOND_MIN["quadratic"]), result.rcond


@pytest.mark.parametrize("frame", ["auto", "local"])
def test_collinear_nodes_near_a_point(frame, engine):
    """A plane patch with a wire of collinear nodes sticking out of one edge. Along the wire the
    support is a line: the full basis cannot be fitted. In a local frame the wire's own nodes
    fix the frame, and a row leaves e3 anywhere around it: 'few-nodes' or 'ill-conditioned',
    except near the patch, where the support widened for a thin support reaches the patch's
    edge and the fit is the plane that holds both (the wire lies in it: the exact answer).
    In the global frame ('auto': the patch is a height field) the patch fixes e3: the wire is
    fitted with a reduced basis (polynomial along it, constant across: basis.REDUCED), a ruled
    extrusion along e3 x a, which is the patch's plane: the exact answer. Over the patch,
    exact answers."""
    shape = Plane(origin=(0, 0, 0), normal=(0.2, -0.1, 1.0), size=1.0)
    patch_nodes, faces = shape.mesh(10)
    wire = shape.origin + np.linspace(1.25, 3.0, 8)[:, None] * shape.u
    nodes = np.vstack([patch_nodes, wire])
    over_wire = wire[2:6] + 0.05 * shape.normal + 0.01 * shape.v
    over_patch = shape.sample_near(40, 0.2, 5)
    surface = build(nodes, faces, engine, frame=frame)
    wired = check_consistent(surface.project(over_wire))
    good = wired.status <= PENETRATION
    if surface.frame == "global":
        assert np.all(good), reasons(wired)
        assert np.all(wired.terms[1:] < 6) and np.all(wired.terms > 0), wired.terms
    else:
        assert good.sum() <= 1 and not good[1:].any(), reasons(wired)
        assert set(wired.reason[~good]) <= THIN | {REASON["off-target"]}, reasons(wired)
    np.testing.assert_allclose(wired.gap[good], 0.05, rtol=0, atol=1e-12)
    on = check_consistent(surface.project(over_patch))
    assert np.all(on.status <= PENETRATION), reasons(on)
    _, _, dist = shape.closest(over_patch)
    np.testing.assert_allclose(on.gap, dist, rtol=0, atol=1e-12)


def test_nodes_on_a_circle_cannot_fix_a_quadratic(engine):
    """Support nodes all on one circle: s² + t² is constant on them, so the quadratic moment
    matrix is singular although the nodes are not collinear (rcond ~ 1e-16, reported). A ring
    has no direction to turn a reduced basis along (neither a row nor two: tol.STRIP_RANK), so
    the reduced basis fitted is the plane [1, a, b] (basis.REDUCED), which needs none: the
    exact plane, as the linear basis gives (a control). The points are inside the ring, within
    a node spacing of it (the middle is too far from every node)."""
    theta = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    nodes = np.column_stack([np.cos(theta), np.sin(theta), 0.3 * np.cos(theta)])  # a plane
    points = np.array([[0.9, 0.1, 0.5], [-0.7, 0.6, -0.4], [0.1, -0.92, 0.2]])
    quadratic = check_consistent(build(nodes, None, engine, frame="global", support="knn",
                                       k=24).project(points))
    assert np.all(quadratic.status <= PENETRATION), reasons(quadratic)
    assert np.all(quadratic.rcond < 1e-12)
    np.testing.assert_array_equal(quadratic.terms, 3)
    linear = check_consistent(build(nodes, None, engine, frame="global", support="knn", k=24,
                                    basis="linear").project(points))
    assert np.all(linear.status <= PENETRATION), reasons(linear)
    np.testing.assert_array_equal(linear.terms, 3)
    _, _, dist = Plane(normal=(-0.3, 0.0, 1.0)).closest(points)
    np.testing.assert_allclose(np.abs(linear.gap), np.abs(dist), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.abs(quadratic.gap), np.abs(dist), rtol=0, atol=1e-12)


def _split_in_two_zones(nodes, faces):
    """The same mesh with the nodes of the second half of the facets copied: every node of
    the second zone is a new node, those on the zone boundary are exact duplicates."""
    half = len(faces) // 2
    used = np.unique(faces[half:])
    remap = np.arange(len(nodes))
    remap[used] = len(nodes) + np.arange(len(used))
    return np.vstack([nodes, nodes[used]]), [faces[:half], remap[faces[half:]]]


@pytest.mark.parametrize("weight", ["wendland", "singular"])
def test_duplicated_nodes(weight, engine):
    """Exact duplicates (an FE mesh in two zones with its own copy of the boundary nodes) are
    merged for the fit, not refused: each position enters a support once, as its first node,
    so the fit is the merged target's; the answers stay those of the merged target to well
    under its error against the exact sphere (the node spacing at a point and local frames
    still see both copies: measured 1.9e-5 against an error of 1.8e-4), and the contact
    element, which refits over the stored support, finds the same gap."""
    shape = Sphere()
    nodes, faces = shape.mesh(6)
    points = shape.sample_near(200, 0.05, 1)
    _, _, dist = shape.closest(points)
    merged = check_consistent(build(nodes, faces, engine, weight=weight).project(points))
    twin_nodes, twin_faces = _split_in_two_zones(nodes, faces)
    surface = build(twin_nodes, twin_faces, engine, weight=weight)
    assert surface.duplicates
    twin = check_consistent(surface.project(points, keep_patch=True))
    np.testing.assert_array_equal(twin.status, merged.status)
    error = np.abs(merged.gap - dist).max()
    assert np.abs(twin.gap - merged.gap).max() < 0.25 * error
    assert np.abs(twin.gap - dist).max() < 1.1 * error
    # supports hold first occurrences only, each once
    index = twin.patch.index
    assert np.all(surface.first[index[index >= 0]] == index[index >= 0])
    rows = np.sort(np.where(index >= 0, index, -np.arange(1, index.shape[1] + 1)), axis=1)
    assert np.all(np.diff(rows, axis=1) > 0)
    # the contact element agrees with the projection it is built on
    elements = contact(surface, points, second=False).elements
    assert len(elements) > 20
    for e in elements:
        assert abs(e.gap - twin.gap[e.contactor]) < 1e-12, e.contactor
        assert len(np.unique(e.nodes)) == len(e.nodes)


def test_duplicated_nodes_of_a_global_frame_target(engine):
    """Duplicates in a height field: the fit reproduces the saddle exactly as without them."""
    shape = Saddle(a=0.4)
    nodes, faces = shape.mesh_quads(10)
    points = shape.sample_near(100, 0.1, 4)
    twin = np.vstack([nodes, nodes[::3]])
    result = check_consistent(build(twin, faces, engine, frame="global").project(points))
    assert np.all(result.status <= PENETRATION), reasons(result)
    _, _, dist = shape.closest(points)
    np.testing.assert_allclose(result.gap, dist, rtol=0, atol=1e-12)


def test_too_few_distinct_nodes_is_refused():
    """Fewer (distinct) nodes than basis terms, or k below the basis size: a one-line
    ValueError at construction (the CLI turns it into 'diffsurf: error: FILE: ...')."""
    five = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.1], [2, 0, 0.2]], float)
    with pytest.raises(ValueError, match=r"^the target has 5 nodes; the quadratic basis "
                                         r"needs at least 6 \(the linear basis fits them: "
                                         r'basis="linear"\)$'):
        DiffuseSurface(five)
    with pytest.raises(ValueError, match=r"^the target has 5 distinct nodes; the quadratic"):
        DiffuseSurface(np.vstack([five, five[:3]]))
    with pytest.raises(ValueError, match=r"^the target has 9 nodes; the cubic basis needs "
                                         r"at least 10 \(the quadratic basis fits them"):
        DiffuseSurface(np.vstack([five, five[:4] + 3]), basis="cubic")
    with pytest.raises(ValueError, match=r"^k=4 is below the quadratic basis size 6$"):
        DiffuseSurface(np.vstack([five, five + 3]), support="knn", k=4)


@pytest.mark.parametrize("basis, count", [("linear", 3), ("quadratic", 6), ("cubic", 10)])
@pytest.mark.parametrize("frame", ["global", "local"])
def test_tiny_target(basis, count, frame, engine):
    """A target with exactly as many nodes as basis terms (on a tilted plane): points over it
    get the exact plane or 'outside' ('few-nodes' where the disc holds fewer nodes,
    'off-target' past the hull); never a wrong number."""
    rng = np.random.default_rng(count)
    shape = Plane(origin=(0.5, -0.2, 0.1), normal=(0.3, -0.2, 1.0), size=1.0)
    st = rng.uniform(-1, 1, (count, 2))
    nodes = shape.origin + st[:, :1] * shape.u + st[:, 1:] * shape.v
    grid = np.linspace(-1.5, 1.5, 7)
    s, t = (g.ravel() for g in np.meshgrid(grid, grid))
    points = (shape.origin + s[:, None] * shape.u + t[:, None] * shape.v
              + rng.uniform(-0.3, 0.3, (len(s), 1)) * shape.normal)
    result = check_consistent(build(nodes, None, engine, basis=basis, frame=frame,
                                    support="knn", k=count).project(points))
    good = result.status <= PENETRATION
    assert good.any() and (~good).any(), reasons(result)
    _, _, dist = shape.closest(points)
    # no faces: the orientation is arbitrary, the distance is not
    np.testing.assert_allclose(np.abs(result.gap[good]), np.abs(dist[good]), rtol=0, atol=1e-9)


def test_support_on_one_side_beyond_an_open_edge(engine):
    """Contactors moved out past an open edge of a curved patch, straight and at 35 degrees
    to the frame axes: the support is all on one side. A proximal point within HULL_SPACINGS
    of the support's hull is answered (the fit extrapolates a little); past it the point is
    'outside' ('off-target', or 'few-nodes' once the disc is empty); answered gaps are those
    of the exact (unbounded) surface: to round-off in the global frame, which reproduces the
    quadratic, to 0.03 h in local frames (measured 0.022 h at the edge, 2e-4 h inside)."""
    shape = Paraboloid(a=0.3, b=0.1, c=0.2, size=1.0)
    nodes, faces = shape.mesh(10)
    h = shape.spacing(10)
    beyond = np.linspace(-0.5, 5.0, 45)
    across = (-0.3, 0.3, 0.9)
    for phi in (0.0, np.radians(35.0)):
        c, s = np.cos(phi), np.sin(phi)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        grid = np.array([[1 + b * h, y] for y in across for b in beyond])
        exact = np.column_stack([grid, shape.height(*grid.T) + 0.05])  # before the rotation
        for frame in ("global", "local"):
            for weight in ("wendland", "singular"):
                surface = build(nodes @ rot.T, faces, engine, frame=frame, weight=weight)
                result = check_consistent(surface.project(exact @ rot.T, keep_patch=True))
                good = result.status <= PENETRATION
                past = np.tile(beyond, len(across))
                assert np.all(good[past <= 0]), (frame, weight, reasons(result))
                assert not good[past >= 1.5].any(), (frame, weight, reasons(result))
                trouble = set(result.reason[~good])
                assert trouble <= {REASON[r] for r in ("off-target", "few-nodes",
                                                        "ill-conditioned")}, reasons(result)
                # accepted proximal points are within the hull slack of the node square
                plan = (result.proximal_point[good] @ rot)[:, :2]
                out = np.hypot(*np.maximum(np.abs(plan) - 1.0, 0.0).T)
                slack = surface_mod.HULL_SPACINGS * result.patch.spacing[good]
                assert np.all(out <= 1.25 * slack), (frame, weight, (out / h).max())
                _, _, dist = shape.closest(exact[good])
                bound = 1e-12 if frame == "global" else 0.03 * h
                assert np.abs(result.gap[good] - dist).max() < bound, (frame, weight, phi)


def _hull_distance(points, x):
    """Distance from x to the convex hull of 2-D points (0 inside), the slow obvious way."""
    hull = ConvexHull(points)
    if np.all(hull.equations[:, :2] @ x + hull.equations[:, 2] <= 0):
        return 0.0
    v = points[hull.vertices]
    a, b = v, np.roll(v, -1, axis=0)
    t = np.clip(np.einsum("ij,ij->i", x - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * (b - a) - x, axis=1)))


def test_off_target_hull_test_matches_convex_hull_distance():
    """The reference's hull test, reference.beyond_hull (free arc of directions to the slack
    discs) against the distance to scipy's convex hull, on random supports in and around the
    point."""
    rng = np.random.default_rng(6)
    m, K = 2000, 12
    ds = rng.uniform(-1, 1, (m, K)) + rng.uniform(-1.5, 1.5, (m, 1))
    dt = rng.uniform(-1, 1, (m, K)) + rng.uniform(-1.5, 1.5, (m, 1))
    live = rng.uniform(size=(m, K)) < 0.7
    live[:, :3] = True
    slack = rng.uniform(0, 0.3, m)
    got = _beyond_hull(ds, dt, live, slack)
    dist = np.array([_hull_distance(np.column_stack([ds[i][live[i]], dt[i][live[i]]]),
                                    np.zeros(2)) for i in range(m)])
    clear = np.abs(dist - slack) > 1e-12
    np.testing.assert_array_equal(got[clear], (dist > slack)[clear])
    assert 0.2 < got.mean() < 0.8  # both answers are exercised


# --------------------------------------------------------------------------- 3. on a node
def _node_targets():
    sphere = Sphere(radius=1.0)
    saddle = Saddle(a=0.4)
    paraboloid = Paraboloid(a=0.3, b=0.1, c=0.2)
    noisy, noisy_faces = paraboloid.mesh(10)
    noisy = noisy + np.random.default_rng(0).normal(0, 0.01, noisy.shape)
    return {"sphere": (*sphere.mesh(6), {}),
            "saddle-global": (*saddle.mesh(8), {"frame": "global"}),
            "noisy-global": (noisy, noisy_faces, {"frame": "global"}),
            "cylinder-quads": (*Cylinder().mesh_quads(16), {})}


@pytest.mark.parametrize("name", ["sphere", "saddle-global", "noisy-global", "cylinder-quads"])
def test_contactor_exactly_on_a_node_with_the_singular_weight(name, engine):
    """With the singular (interpolating) weight the surface passes through the nodes: a
    contactor exactly on a node has a finite answer, its proximal point is the node and its
    gap 0 (status 'contact'), even for nodes off any polynomial (noisy)."""
    nodes, faces, options = _node_targets()[name]
    surface = build(nodes, faces, engine, weight="singular", **options)
    result = check_consistent(surface.project(nodes))
    h = surface.node_spacing
    assert np.all(result.status == CONTACT), reasons(result)
    assert np.all(np.abs(result.gap) <= tol.CONTACT * h)
    assert np.all(np.linalg.norm(result.proximal_point - nodes, axis=1) <= 1e-12 * h)


def test_contactor_on_a_node_with_an_approximant_weight_is_not_interpolated(engine):
    """Control: the Wendland weight smooths the noisy nodes, so the node test above can fail."""
    nodes, faces, options = _node_targets()["noisy-global"]
    surface = build(nodes, faces, engine, weight="wendland", **options)
    result = check_consistent(surface.project(nodes))
    assert np.sum(result.status != CONTACT) > len(nodes) // 2
    h = float(np.median(surface.node_spacing))
    assert np.linalg.norm(result.proximal_point - nodes, axis=1).max() > 1e-3 * h


# --------------------------------------------------------------------------- 4. far away
def test_far_contactors(engine):
    """Far from the target a contactor either gets the right answer or is reported: off a
    closed sphere the projection is exact (to the fit) up to 5 radii; farther, the tilt of
    the local frame, times the distance, costs accuracy (within 1e-3 of the gap while a
    support is found under the contactor), and then the support is empty: far from every
    node, 'outside', 'off-target' (issue 32); at the centre, equidistant from everything and
    farther than the support radius from every node, 'outside', 'off-target' too; off a plane
    the gap is exact up to 1e6 away, and past its edges the point is 'outside'."""
    sphere = Sphere()
    nodes, faces = sphere.mesh(8)
    ray = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    distances = np.array([1.5, 2.0, 3.0, 5.0, 10.0, 1e3, 1e6, 1e40])
    points = np.vstack([distances[:, None] * ray, np.zeros((1, 3))])
    result = check_consistent(build(nodes, faces, engine).project(points))
    good = result.status <= PENETRATION
    assert good[:4].all(), reasons(result)
    np.testing.assert_allclose(result.gap[:4], distances[:4] - 1.0, rtol=0,
                               atol=2e-3 * sphere.spacing(8))
    far = good[:-1] & (distances > 5)
    np.testing.assert_allclose(result.gap[:-1][far], distances[far] - 1.0, rtol=1e-3)
    assert np.all(result.status[4:-1][~far[4:]] == OUTSIDE), reasons(result)
    assert np.all(result.status[5:-1] == OUTSIDE), reasons(result)
    assert np.all(result.reason[5:] == REASON["off-target"]), reasons(result)

    plane = Plane(origin=(0.2, -0.1, 0.3), normal=(0.1, 0.2, 1.0), size=1.0)
    nodes, faces = plane.mesh(10)
    above = plane.origin + np.array([1e3, -1e6, 1e100])[:, None] * plane.normal
    aside = plane.origin + np.array([3.0, 10.0, 1e3, 1e6, 1e40])[:, None] * (plane.u + plane.v)
    for frame in ("global", "local"):
        surface = build(nodes, faces, engine, frame=frame)
        up = check_consistent(surface.project(above))
        np.testing.assert_allclose(up.gap[:2], [1e3, -1e6], rtol=1e-12)
        # 1e100 away, steps in units of the spacing no longer resolve: reported, or exact
        assert up.status[2] >= OUTSIDE or abs(up.gap[2] / 1e100 - 1) < 1e-12
        side = check_consistent(surface.project(aside))
        assert np.all(side.status == OUTSIDE), reasons(side)


@pytest.mark.parametrize("engine", ENGINES)
def test_contactor_with_huge_finite_coordinates(engine):
    """A finite contactor whose squared distances overflow (1e200) is 'outside', no crash."""
    nodes, faces = Sphere().mesh(4)
    result = check_consistent(build(nodes, faces, engine).project([[1e200, 0, 0],
                                                                   [0, -1e300, 1e300]]))
    assert np.all(result.status == OUTSIDE), reasons(result)


# --------------------------------------------------------------------------- 5. steep / global
@pytest.mark.parametrize("case", ["sphere", "sphere-no-faces", "cylinder-quads",
                                  "torus-no-faces"])
def test_closed_target_over_a_forced_global_frame_is_steep(case, engine):
    """One mean plane cannot parametrise a closed target: its far sheet lies under the near one
    and a fit mixes them (before: 'ok' with errors up to one radius). Every point is 'outside'
    with the reason 'steep' (the fix is a local frame), with or without facets."""
    if case.startswith("sphere"):
        shape = Sphere()
        nodes, faces = shape.mesh(8)
    elif case == "cylinder-quads":
        shape = Cylinder()
        nodes, faces = shape.mesh_quads(24)
    else:
        shape = Torus()
        nodes, faces = shape.mesh(32)
    points = shape.sample_near(300, 0.05, 1)
    faces = None if case.endswith("no-faces") else faces
    result = check_consistent(build(nodes, faces, engine, frame="global").project(points))
    assert np.all(result.reason == REASON["steep"]), reasons(result)


@pytest.mark.parametrize("faces", [True, False], ids=["faces", "no-faces"])
def test_vertical_edges_of_a_half_cylinder_over_a_forced_global_frame(faces, engine):
    """A half cylinder seen from its mean plane turns vertical at its two edges, where a
    global fit stops converging (measured: 5e-3 at any resolution, 1000 times the local
    frame's error). Points whose support reaches there are 'steep'; the others are answered,
    within 0.01 h of the exact cylinder; 'auto' picks local frames and answers all."""
    shape = Cylinder(radius=1.0, length=2.0, theta_range=(0.0, np.pi))
    nodes, quads = shape.mesh_quads(48)
    h = shape.spacing(48)
    points = shape.sample_near(400, 0.02, 1)
    _, _, dist = shape.closest(points)
    result = check_consistent(build(nodes, quads if faces else None, engine,
                                    frame="global").project(points))
    good = result.status <= PENETRATION
    assert set(result.reason[~good]) == {REASON["steep"]}, reasons(result)
    assert 0.3 < good.mean() < 0.9, reasons(result)
    assert np.abs(np.abs(result.gap[good]) - np.abs(dist[good])).max() < 0.01 * h
    # the steep points are those near the vertical edges (|x| near the radius)
    assert np.abs(points[~good, 0]).min() > np.abs(points[good, 0]).min()
    auto = check_consistent(build(nodes, quads, engine).project(points))
    assert np.all(auto.status <= PENETRATION), reasons(auto)


def test_spherical_cap_over_a_global_frame_is_not_steep(engine):
    """Control: a cap whose rim is 72.5 degrees from the plane is a height field; nothing is
    refused, and the answers are within 0.05 h of the exact sphere."""
    shape = Sphere()
    nodes, faces = shape.mesh(6)
    keep = nodes[:, 2] > 0.3
    faces = (np.cumsum(keep) - 1)[faces[np.all(keep[faces], axis=1)]]
    nodes = nodes[keep]
    d = np.random.default_rng(8).standard_normal((300, 3))
    d[:, 2] = np.abs(d[:, 2]) + 2.0
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = 1.05 * d[d[:, 2] > 0.6]
    result = check_consistent(build(nodes, faces, engine, frame="global").project(points))
    assert np.all(result.status == OPEN), reasons(result)
    assert np.abs(result.gap - 0.05).max() < 0.05 * shape.spacing(6)


# --------------------------------------------------------------------------- 6. huge k
@pytest.mark.parametrize("k", ["n", "10n"])
def test_huge_k(k, engine):
    """k as large as the whole target, or larger: the support is every node (minus the far
    sheet where facets show it). Height fields stay exact; a faced sphere gets one coarse but
    honest fit per point (within 0.05 h); a faceless sphere, whose support would wrap around
    both sheets (before: 'ok' with errors of a radius), is 'steep'."""
    saddle = Saddle(a=0.4)
    nodes, faces = saddle.mesh(8)
    kk = len(nodes) if k == "n" else 10 * len(nodes)
    points = saddle.sample_near(100, 0.1, 2)
    flat = check_consistent(build(nodes, faces, engine, frame="global", support="knn",
                                  k=kk).project(points))
    assert np.all(flat.status <= PENETRATION), reasons(flat)
    np.testing.assert_allclose(flat.gap, saddle.closest(points)[2], rtol=0, atol=1e-12)

    sphere = Sphere()
    nodes, faces = sphere.mesh(4)
    kk = len(nodes) if k == "n" else 10 * len(nodes)
    points = sphere.sample_near(100, 0.05, 1)
    _, _, dist = sphere.closest(points)
    faced = check_consistent(build(nodes, faces, engine, support="knn", k=kk).project(points))
    assert np.all(faced.status <= PENETRATION), reasons(faced)
    assert np.abs(faced.gap - dist).max() < 0.05 * sphere.spacing(4)
    bare = check_consistent(build(nodes, None, engine, support="knn", k=kk).project(points))
    assert np.all(bare.reason == REASON["steep"]), reasons(bare)


# --------------------------------------------------------------------------- 7. Newton
def test_newton_that_does_not_converge_is_failed(engine, monkeypatch):
    """With a single Newton step allowed nothing converges on a sphere: every point is
    'failed' with 'no-convergence', NaN geometry, one iteration, and its rcond still
    reported; with the limit restored the same points are answered."""
    shape = Sphere()
    nodes, faces = shape.mesh(6)
    points = shape.sample_near(100, 0.05, 2)
    monkeypatch.setattr(tol, "NEWTON_MAX_ITER", 1)
    result = check_consistent(build(nodes, faces, engine).project(points))
    assert np.all(result.status == FAILED), reasons(result)
    assert np.all(result.reason == REASON["no-convergence"])
    assert np.all(result.iterations == 1)
    assert np.all(result.rcond >= tol.RCOND_MIN["quadratic"])
    monkeypatch.undo()
    again = check_consistent(build(nodes, faces, engine).project(points))
    assert np.all(again.status <= PENETRATION), reasons(again)


# --------------------------------------------------------------------------- 8. conditioning
def test_ill_conditioned_moment_matrix_is_detected(engine):
    """Target nodes on three concentric rings drawn together (radii 1 - δ, 1, 1 + δ, on a tilted
    plane): s² + t² is ever closer to a constant on the support, which column scaling cannot
    undo, and rcond falls like δ. Every row reports its rcond; above tol.RCOND_MIN the quadratic
    basis gives the plane exactly; below it the plane [1, a, b] is fitted instead (the reduced
    basis of rings, which have no direction: basis.REDUCED, tol.STRIP_RANK), exactly too."""
    plane = Plane(normal=(-0.3, -0.2, 1.0))
    theta = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    deltas = np.geomspace(0.3, 1e-5, 13)
    rconds, ill = [], []
    for delta in deltas:
        xy = np.vstack([r * np.column_stack([np.cos(theta + 0.1 * k), np.sin(theta + 0.1 * k)])
                        for k, r in enumerate((1 - delta, 1.0, 1 + delta))])
        nodes = np.column_stack([xy, 0.3 * xy[:, 0] + 0.2 * xy[:, 1]])
        # contactors over nodes of the rings (their proximal points are on the target)
        offset = np.array([0.01, -0.02, 0.005, 0.0])
        points = nodes[[24, 30, 40, 5]] + offset[:, None] * plane.normal
        result = check_consistent(build(nodes, None, engine, frame="global", support="knn",
                                        k=len(nodes)).project(points))
        assert np.all(result.support == len(nodes))
        low = result.rcond < tol.RCOND_MIN["quadratic"]
        np.testing.assert_array_equal(result.terms, np.where(low, 3, 6))
        good = result.status <= PENETRATION
        assert np.all(good), reasons(result)
        _, _, dist = plane.closest(points)
        np.testing.assert_allclose(np.abs(result.gap[good]), np.abs(dist[good]), rtol=0,
                                   atol=1e-12)
        rconds.append(result.rcond.mean())
        ill.append(low.all())
    rconds = np.array(rconds)
    assert not ill[0] and ill[-1], rconds  # the sweep spans both sides of the threshold
    slope = np.polyfit(np.log(deltas[3:]), np.log(rconds[3:]), 1)[0]
    assert 0.9 < slope < 1.1, (slope, rconds)
