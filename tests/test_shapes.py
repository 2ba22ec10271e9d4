"""Tests of the exact reference surfaces in ``shapes``."""
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from diffsurf_cli.testing.shapes import (
    Cylinder,
    Paraboloid,
    Plane,
    Saddle,
    Sphere,
    Torus,
    random_rotation,
)

SHAPES = {
    "sphere": lambda: Sphere(center=(0.3, -1.0, 2.0), radius=1.7),
    "cylinder": lambda: Cylinder(radius=1.2, length=3.0, center=(1.0, 2.0, -0.5)),
    "half_cylinder": lambda: Cylinder(radius=10.0, length=10.0, theta_range=(np.pi, 2 * np.pi),
                                      center=(32.5, 30.0, 2.5)),
    "saddle": lambda: Saddle(a=0.5, size=1.0),
    "paraboloid": lambda: Paraboloid(a=0.7, b=-0.4, c=0.2, size=1.5),
    "plane": lambda: Plane(origin=(1.0, -2.0, 0.5), normal=(1.0, 2.0, -0.5), size=2.0),
    "torus": lambda: Torus(major=1.0, minor=0.4, center=(0.5, 0.0, -1.0)),
}
QUAD_SHAPES = ["cylinder", "half_cylinder", "saddle", "paraboloid", "plane", "torus"]
CLOSED = {"sphere": 2, "torus": 0}  # Euler characteristic


def _scale(shape, vertices):
    return np.abs(vertices).max() + 1.0


def _offset_bound(shape):
    """Largest safe |offset| for round trips: 95 % of the reach (capped for the plane)."""
    return 0.95 * min(shape.reach, 3.0)


@pytest.fixture(params=sorted(SHAPES))
def named_shape(request):
    return request.param, SHAPES[request.param]()


@pytest.mark.parametrize("n", [3, 8])
def test_vertices_on_surface(named_shape, n):
    _, shape = named_shape
    v, f = shape.mesh(max(n, shape.min_n))
    assert v.dtype == float and v.ndim == 2 and v.shape[1] == 3
    assert f.ndim == 2 and f.shape[1] == 3 and np.issubdtype(f.dtype, np.integer)
    assert f.min() == 0 and f.max() == len(v) - 1  # every vertex used
    c, nrm, d = shape.closest(v)
    scale = _scale(shape, v)
    assert np.abs(d).max() <= 4e-15 * scale
    assert np.abs(c - v).max() <= 4e-15 * scale
    assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-15, rtol=0)


def _face_normals(v, faces):
    a = v[faces]
    if faces.shape[1] == 3:
        return np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0]), a.mean(axis=1)
    return np.cross(a[:, 2] - a[:, 0], a[:, 3] - a[:, 1]), a.mean(axis=1)


@pytest.mark.parametrize("n", [3, 8])
def test_orientation_outward(named_shape, n):
    _, shape = named_shape
    v, f = shape.mesh(max(n, shape.min_n))
    fn, centroid = _face_normals(v, f)
    _, nrm, d = shape.closest(centroid)
    cos = np.einsum("ij,ij->i", fn, nrm) / np.linalg.norm(fn, axis=1)
    assert np.all(cos > 0.5)
    # centroids of a faceted mesh of a convex-outward surface lie inside (chords)
    if isinstance(shape, (Sphere, Cylinder)):
        assert np.all(d < 0)


@pytest.mark.parametrize("name", QUAD_SHAPES)
def test_quads_match_triangles(name):
    shape = SHAPES[name]()
    vq, q = shape.mesh_quads(max(6, shape.min_n))
    vt, t = shape.mesh(max(6, shape.min_n))
    np.testing.assert_array_equal(vq, vt)
    assert q.shape[1] == 4 and len(t) == 2 * len(q)
    fn, centroid = _face_normals(vq, q)
    _, nrm, _ = shape.closest(centroid)
    assert np.all(np.einsum("ij,ij->i", fn, nrm) > 0)


def test_sphere_has_no_quads():
    with pytest.raises(NotImplementedError):
        Sphere().mesh_quads(3)


def _edges(faces):
    k = faces.shape[1]
    return np.concatenate([faces[:, [i, (i + 1) % k]] for i in range(k)])


@pytest.mark.parametrize("n", [3, 5])
def test_mesh_topology(named_shape, n):
    """Consistent orientation (no directed edge twice); closed meshes are watertight."""
    name, shape = named_shape
    _, f = shape.mesh(max(n, shape.min_n))
    e = _edges(f)
    directed = {tuple(x) for x in e.tolist()}
    assert len(directed) == len(e)
    if name in CLOSED:
        assert all((b, a) in directed for a, b in directed)
        n_edges = len(e) // 2
        v = np.unique(f).size
        assert v - n_edges + len(f) == CLOSED[name]


def test_sphere_counts_and_spacing():
    s = Sphere(radius=2.0)
    for n in (1, 2, 5, 10):
        v, f = s.mesh(n)
        assert len(v) == 10 * n * n + 2 and len(f) == 20 * n * n
        e = np.linalg.norm(np.diff(v[f][:, [0, 1, 2, 0]], axis=1), axis=2)
        assert 0.7 < e.min() / s.spacing(n) and e.max() / s.spacing(n) < 1.25


def test_structured_spacing():
    n = 12
    cyl = SHAPES["half_cylinder"]()
    v, q = cyl.mesh_quads(n)
    h = cyl.spacing(n)
    assert np.isclose(h, 10.0 * np.pi / n)
    around = np.linalg.norm(v[q[:, 1]] - v[q[:, 0]], axis=1)
    along = np.linalg.norm(v[q[:, 3]] - v[q[:, 0]], axis=1)
    assert np.allclose(around, 2 * 10.0 * np.sin(np.pi / n / 2))
    assert np.all((along > 0.6 * h) & (along < 1.5 * h))  # near-square cells
    _, q4 = cyl.mesh_quads(16, m=4)
    assert len(q4) == 64
    full = SHAPES["cylinder"]()
    v, q = full.mesh_quads(n)
    assert len(v) == n * (round(3.0 / full.spacing(n)) + 1)  # periodic: no seam duplicates

    for name in ("saddle", "paraboloid", "plane"):
        hf = SHAPES[name]()
        v, q = hf.mesh_quads(n)
        assert len(v) == (n + 1) ** 2 and len(q) == n * n
        plan = v if name != "plane" else np.column_stack([v @ hf.u, v @ hf.v])
        step = np.linalg.norm((plan[q[:, 1]] - plan[q[:, 0]])[:, :2], axis=1)
        assert np.allclose(step, hf.spacing(n))

    tor = SHAPES["torus"]()
    v, q = tor.mesh_quads(n)
    k = tor.tube_segments(n)
    assert k == 8 and len(q) == n * k
    e = np.linalg.norm(v[q[:, 1]] - v[q[:, 0]], axis=1)  # along the major circle
    lo, hi = 2 * (1.0 - 0.4) * np.sin(np.pi / n), 2 * (1.0 + 0.4) * np.sin(np.pi / n)
    assert np.all((e > lo - 1e-12) & (e < hi + 1e-12))
    assert tor.tube_segments(100) == 40
    with pytest.raises(ValueError, match="n must"):
        tor.mesh(7)
    for r in (0.1, 0.5, 0.95):  # the coarsest accepted torus mesh is outward everywhere
        t = Torus(major=1.0, minor=r)
        v, f = t.mesh(t.min_n)
        fn, centroid = _face_normals(v, f)
        assert np.all(np.einsum("ij,ij->i", fn, t.closest(centroid)[1]) > 0)


def test_closest_round_trip(named_shape):
    name, shape = named_shape
    rng = np.random.default_rng(1)
    p0 = shape.sample_near(300, 0.0, rng)
    c0, n0, d0 = shape.closest(p0)
    scale = np.abs(p0).max() + 1.0
    assert np.abs(d0).max() <= 4e-15 * scale
    assert np.abs(c0 - p0).max() <= 4e-15 * scale
    d = rng.uniform(-1.0, 1.0, len(p0)) * _offset_bound(shape)
    c, nrm, dist = shape.closest(p0 + d[:, None] * n0)
    # conditioning degrades like 1 / (1 - |d| kappa); 1e-13 covers 95 % of the reach
    assert np.abs(c - p0).max() <= 1e-13 * scale
    assert np.abs(nrm - n0).max() <= 1e-13 * scale
    assert np.abs(dist - d).max() <= 1e-14 * scale


def test_sample_near_offsets_and_margins(named_shape):
    name, shape = named_shape
    rng = np.random.default_rng(2)
    off = 0.5 * _offset_bound(shape)
    margin = 0.25 * (shape.size if hasattr(shape, "size") else getattr(shape, "length", 1.0))
    p = shape.sample_near(500, off, rng, margin=margin)
    assert p.shape == (500, 3)
    c, _, d = shape.closest(p)
    assert np.abs(d).max() <= off * (1 + 1e-12)
    assert np.abs(d).max() > 0.5 * off  # offsets really spread over [-off, off]
    assert (d > 0).any() and (d < 0).any()
    if isinstance(shape, Cylinder):
        rel = c - shape.center
        assert np.all(np.abs(rel[:, 2]) <= 0.5 * shape.length - margin + 1e-12)
        if not shape.full:
            theta = np.mod(np.arctan2(rel[:, 1], rel[:, 0]), 2 * np.pi)
            t0, t1 = shape.theta_range
            assert np.all(theta >= t0 + margin / shape.radius - 1e-12)
            assert np.all(theta <= t1 - margin / shape.radius + 1e-12)
    elif isinstance(shape, Plane):
        rel = c - shape.origin
        assert np.all(np.abs(rel @ shape.u) <= shape.size - margin + 1e-12)
        assert np.all(np.abs(rel @ shape.v) <= shape.size - margin + 1e-12)
    elif hasattr(shape, "size"):
        assert np.all(np.abs(c[:, :2]) <= shape.size - margin + 1e-12)
    # deterministic with a seed
    np.testing.assert_array_equal(shape.sample_near(5, off, 7), shape.sample_near(5, off, 7))


def test_sample_near_validation():
    with pytest.raises(ValueError, match="reach"):
        Sphere(radius=1.0).sample_near(10, 1.0, 0)
    with pytest.raises(ValueError, match="reach"):
        Saddle(a=0.5).sample_near(10, 1.0, 0)
    with pytest.raises(ValueError, match="margin"):
        Saddle(size=1.0).sample_near(10, 0.1, 0, margin=1.0)
    with pytest.raises(ValueError, match="margin"):
        Cylinder(theta_range=(0, 0.5)).sample_near(10, 0.1, 0, margin=0.3)
    with pytest.raises(ValueError):
        Sphere().sample_near(10, -0.1, 0)
    assert Plane().sample_near(0, 1.0, 0).shape == (0, 3)


def test_input_validation():
    with pytest.raises(ValueError, match=r"\(m, 3\)"):
        Sphere().closest([1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="finite"):
        Sphere().closest([[np.nan, 0, 0]])
    with pytest.raises(ValueError, match="centre"):
        Sphere().closest([[0.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="axis"):
        Cylinder().closest([[0.0, 0.0, 5.0]])
    with pytest.raises(ValueError, match="axis"):
        Torus().closest([[0.0, 0.0, 0.3]])
    with pytest.raises(ValueError, match="core"):
        Torus().closest([[1.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="radius"):
        Sphere(radius=-1.0)
    with pytest.raises(ValueError, match="minor"):
        Torus(major=1.0, minor=1.0)
    with pytest.raises(ValueError, match="theta_range"):
        Cylinder(theta_range=(1.0, 0.5))
    with pytest.raises(ValueError, match="normal"):
        Plane(normal=(0, 0, 0))
    with pytest.raises(ValueError, match="n must"):
        Saddle().mesh(0)
    with pytest.raises(ValueError, match="n must"):
        Saddle().mesh(2.5)
    # beyond the reach of the saddle: the stationary point on the axis is not a minimum
    with pytest.raises(ValueError, match="reach"):
        Saddle(a=0.5).closest([[0.0, 0.0, -3.0]])


@settings(max_examples=40, deadline=None)
@given(
    coef=st.tuples(*[st.floats(-2.0, 2.0) for _ in range(3)]),
    uv=st.tuples(st.floats(-0.9, 0.9), st.floats(-0.9, 0.9)),
    frac=st.floats(-0.9, 0.9),
)
def test_paraboloid_closest_property(coef, uv, frac):
    """Round trip on random quadratics, and no mesh vertex is closer than the answer."""
    shape = Paraboloid(*coef, size=1.0)
    x, y = uv
    base = np.array([[x, y, shape.height(np.array([x]), np.array([y]))[0]]])
    _, n0, _ = shape.closest(base)
    d = frac * min(shape.reach, 1.0)
    c, nrm, dist = shape.closest(base + d * n0)
    assert np.allclose(c, base, atol=1e-12, rtol=0)
    assert np.allclose(nrm, n0, atol=1e-12, rtol=0)
    assert abs(dist[0] - d) <= 1e-13
    v, _ = shape.mesh(12)
    assert np.linalg.norm(v - (base + d * n0), axis=1).min() >= abs(d) - 1e-12


def test_random_rotation():
    rng = np.random.default_rng(3)
    rots = np.array([random_rotation(rng) for _ in range(3000)])
    eye = np.einsum("kji,kjl->kil", rots, rots)
    assert np.allclose(eye, np.eye(3), atol=1e-13)
    assert np.allclose(np.linalg.det(rots), 1.0)
    assert np.abs(rots.mean(axis=0)).max() < 0.05  # Haar: E[R] = 0
    # rotating a plane and its query points rotates the answers
    r = random_rotation(4)
    plane = Plane(normal=(0, 0, 1), size=1.0)
    rplane = Plane(normal=r @ plane.normal, size=1.0)
    p = plane.sample_near(50, 0.5, 5)
    _, n1, d1 = plane.closest(p)
    _, n2, d2 = rplane.closest(p @ r.T)
    assert np.allclose(d1, d2, atol=1e-14) and np.allclose(n1 @ r.T, n2, atol=1e-14)


SAMPLES = Path(__file__).resolve().parents[1] / "sample_meshes"


@pytest.mark.skipif(not (SAMPLES / "cylinder.msh").exists(), reason="sample meshes not generated")
def test_sample_scene_consistent():
    """The sample target's nodes lie on the exact half cylinder, facets face the plate."""
    meshio = pytest.importorskip("meshio")
    cyl = Cylinder(radius=10.0, length=10.0, theta_range=(np.pi, 2 * np.pi),
                   center=(32.5, 30.0, 2.5))
    m = meshio.read(SAMPLES / "cylinder.msh")
    quads = m.cells_dict["quad"]
    assert len(quads) == 64 and m.field_data["cylinder"].tolist() == [1, 2]
    _, _, d = cyl.closest(m.points)
    assert np.abs(d).max() < 1e-13
    fn, centroid = _face_normals(m.points, quads)
    assert np.all(np.einsum("ij,ij->i", fn, cyl.closest(centroid)[1]) > 0)
    plate = np.loadtxt(SAMPLES / "plate.csv", delimiter=",", skiprows=1)
    assert plate.shape == (265, 4) and np.array_equal(plate[:, 0], np.arange(1, 266))
    assert np.sum(cyl.closest(plate[:, 1:])[2] < 0) == 25
