"""The compiled foreign clearance (`patches.clearance.foreign_clearance`, `_clearance.pyx`)
against its numpy version before issue 36 (tests/reference_clearance.py, the oracle): bit for
bit on every target of more than one patch, with the arrays the compiled pass builds it from;
+inf on a target of one patch, whose pass then answers as with the oracle's finite bound.
The feature clearance (`feature_clearance`, its early return reordered) bit for bit too."""
from __future__ import annotations

import pathlib

import numpy as np
import pytest

import reference_clearance as oracle
from diffsurf_cli.patches import _pass, clearance
from diffsurf_cli.patches.surface import PatchedSurface
from test_clearance import _box

SAMPLES = pathlib.Path(__file__).resolve().parent.parent / "sample_meshes"


def _check(args):
    """The new bound and the oracle's on the same arguments: identical bytes where the
    target has more than one patch (and with other bounds, per facet), +inf where it has
    one."""
    new = clearance.foreign_clearance(*args)
    old = oracle.foreign_clearance(*args)
    assert new.dtype == old.dtype and new.shape == old.shape
    if int(np.max(args[2])) == 0:
        assert np.all(np.isinf(new) & (new > 0))
        return 1
    assert new.tobytes() == old.tobytes(), np.abs(new - old).max()
    rng = np.random.default_rng(len(args[1]))
    for bound in (rng.uniform(0.0, 0.5 * np.ptp(args[0][:, 0]), len(args[1])),
                  np.zeros(len(args[1]))):
        a = args[:5] + (bound,)
        assert clearance.foreign_clearance(*a).tobytes() == oracle.foreign_clearance(*a).tobytes()
    return int(np.max(args[2])) + 1


def _engine_args(surf, monkeypatch, name="foreign_clearance"):
    """The arguments the compiled pass gives clearance.NAME (`PatchedPass.__init__`)."""
    seen = []

    def record(*args):
        seen.append(args)
        return getattr(clearance, name)(*args)

    monkeypatch.setattr(_pass, name, record)
    surf._pass = None
    surf.engine  # noqa: B018 - built for its call
    monkeypatch.undo()
    assert len(seen) == 1
    args = seen[0]
    if len(args[0]) == 0 and len(args[1]):
        # no feature edge, one patch: the pass gives no (F, 4, 3) corners (issue 36), both
        # clearances are +inf without them; the oracles get the facets' own corners
        assert np.all(getattr(clearance, name)(*args) == np.inf)
        args = (_corners(surf),) + tuple(args[1:])
    return args


def _corners(surf):
    """The facets' corners in their own order, as the pass made them (`PatchedPass`)."""
    tables = surf.facet_surface()._tables
    return np.asarray(tables["corner"])[np.asarray(tables["slot"])]


def _check_features(args):
    new, old = clearance.feature_clearance(*args), oracle.feature_clearance(*args)
    assert new.dtype == old.dtype and new.tobytes() == old.tobytes()


def _compare(surf, monkeypatch):
    _check_features(_engine_args(surf, monkeypatch, "feature_clearance"))
    npatches = _check(_engine_args(surf, monkeypatch))
    assert npatches == surf.npatches
    moved = surf.moved(surf.nodes * 1.01 + 1e-3 * np.sin(7.0 * surf.nodes[:, [1, 2, 0]]))
    _check(_engine_args(moved, monkeypatch))
    _check_features(_engine_args(moved, monkeypatch, "feature_clearance"))
    return npatches


def _gmsh_surface(path, **kw):
    from diffsurf_cli.targets import build_surface, read_surface

    target, nodes, faces = read_surface(str(path))
    return build_surface(nodes, faces, **kw), target


@pytest.mark.parametrize("n", [1, 2, 3, 8])
def test_identical_on_cubes(n, monkeypatch):
    """Six patches; n = 1, 2: 12 and 48 facets, no more than the 32 neighbours (n=1) or
    barely more (n=2: the K-th's bound at every facet)."""
    nodes, faces = _box(n)
    assert _compare(PatchedSurface(nodes, [faces]), monkeypatch) == 6
    _compare(PatchedSurface(nodes, [faces], flip=True), monkeypatch)


def test_identical_on_an_open_surface_and_a_thin_shell(monkeypatch):
    from diffsurf_cli.testing.shapes import Sphere

    nodes, faces = _box(6)
    centre = nodes[faces].mean(axis=1)
    assert _compare(PatchedSurface(nodes, [faces[centre[:, 2] > 1e-9]]), monkeypatch) > 1
    outer, tri = Sphere().mesh(3)
    shell = np.vstack([outer, 0.96 * outer])
    assert _compare(PatchedSurface(shell, [np.vstack([tri, tri[:, ::-1] + len(outer)])]),
                    monkeypatch) == 2


@pytest.mark.parametrize("name", ["plate_and_cylinder.msh", "cylinder.msh",
                                  "cylinder_tri.stl", "torus.msh"])
def test_identical_on_the_sample_meshes(name, monkeypatch):
    surf, _ = _gmsh_surface(SAMPLES / name)
    _compare(surf, monkeypatch)


@pytest.mark.parametrize("order", [1, 2])
def test_identical_on_filleted_boxes(order, tmp_path, monkeypatch):
    """CAD-like: faces, fillets and their creases; second-order cells; the gmsh tags as
    patches (smooth_tags)."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", size=0.12, order=order)
    surf, target = _gmsh_surface(path)
    assert _compare(surf, monkeypatch) > 6
    tagged, _ = _gmsh_surface(path, tags=np.concatenate(target.tags),
                              smooth_tags=target.faces_tagged)
    assert _compare(tagged, monkeypatch) > 6


@pytest.mark.parametrize("scene", ["l_block", "holed_block", "quad_box"])
def test_identical_on_other_parts(scene, tmp_path, monkeypatch):
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    if scene == "quad_box":
        path = gmsh_scenes.box(tmp_path / "b.msh", size=0.25, order=2, quads=True)
    else:
        path = getattr(gmsh_scenes, scene)(tmp_path / "p.msh")
    surf, _ = _gmsh_surface(path)
    assert _compare(surf, monkeypatch) > 1


@pytest.mark.parametrize("F", [1, 2, 5, 31, 32, 33, 200, 5000])
def test_identical_on_synthetic_clouds(F):
    """Facets of any shape, centroids repeated (ties of every distance, the K-th's too),
    on a grid and at random; rings that hold, or miss, their facet's own patch."""
    rng = np.random.default_rng(F)
    kind = rng.choice([3, 4], F)
    corner = rng.normal(size=(F, 4, 3)) * rng.uniform(0.01, 1.0, (F, 1, 1))
    grid = rng.integers(0, 4, (F, 1, 3)).astype(float)
    corner[: F // 2] = 0.1 * corner[: F // 2] + grid[: F // 2]
    dup = rng.integers(0, F, F // 4)
    corner[rng.integers(0, F, F // 4)] = corner[dup]
    label = rng.integers(0, 5, F)
    ring_ptr = np.zeros(F + 1, np.int64)
    rings = []
    for f in range(F):
        r = set(rng.choice(5, rng.integers(0, 4), replace=False).tolist())
        if rng.uniform() < 0.9:
            r.add(int(label[f]))
        rings.append(sorted(r))
        ring_ptr[f + 1] = ring_ptr[f] + len(r)
    ring = np.array([p for r in rings for p in r], np.int64)
    bound = rng.uniform(0.0, 0.2, F)
    if label.max() == 0:
        label[0] = 1
    _check((corner, kind, label, ring_ptr, ring, bound))


def _answers(surf, points):
    res = surf.project(points)
    return {f: np.asarray(getattr(res, f)) for f in
            ("gap", "normal", "proximal_point", "status", "reason", "source", "support",
             "iterations", "rcond", "curvature", "terms", "facet", "facet_gap")}


@pytest.mark.parametrize("scene", ["icosphere", "torus"])
def test_one_patch_answers_as_with_the_oracle(scene, monkeypatch):
    """A target of one patch: +inf, no tree; the pass's answers are those it gives with the
    oracle's finite bound (which makes it search for foreign patches, and find none)."""
    if scene == "icosphere":
        trimesh = pytest.importorskip("trimesh")
        m = trimesh.creation.icosphere(subdivisions=3)
        nodes, faces = np.asarray(m.vertices), [np.asarray(m.faces)]
        from diffsurf_cli.targets import build_surface
        surf = build_surface(nodes, faces)
    else:
        surf, _ = _gmsh_surface(SAMPLES / "torus.msh")
        nodes = surf.nodes
    assert surf.npatches == 1
    _check_features(_engine_args(surf, monkeypatch, "feature_clearance"))
    args = _engine_args(surf, monkeypatch)
    assert np.all(clearance.foreign_clearance(*args) == np.inf)
    assert np.all(np.isfinite(oracle.foreign_clearance(*args)))
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    w = 0.2 * np.linalg.norm(hi - lo)
    points = np.random.default_rng(4).uniform(lo - w, hi + w, (3000, 3))
    surf._pass = None
    fast = _answers(surf, points)
    corner = _corners(surf)
    monkeypatch.setattr(_pass, "foreign_clearance", lambda c, *rest: oracle.foreign_clearance(
        corner if len(c) == 0 else c, *rest))
    surf._pass = None
    slow = _answers(surf, points)
    for key in fast:
        assert fast[key].tobytes() == slow[key].tobytes(), key


@pytest.mark.parametrize("n, m", [(1, 50), (7, 1), (300, 5000), (4000, 20000)])
def test_nearest_distance_is_cKDTree_s(n, m):
    """The compiled nearest sample (feature_clearance's query): cKDTree's distances bit for
    bit; samples on lines, repeated, points near and far, in any order."""
    from scipy.spatial import cKDTree

    from diffsurf_cli.patches import _clearance

    rng = np.random.default_rng(n + m)
    t = rng.uniform(0.0, 1.0, (n, 1))
    samples = np.where(rng.uniform(size=(n, 1)) < 0.5, t * [1.0, 0.0, 0.0], t * [0.0, 1.0, 1.0])
    samples[rng.integers(0, n, n // 5)] = samples[rng.integers(0, n, n // 5)]
    points = rng.normal(size=(m, 3)) * rng.choice([0.01, 1.0, 100.0], (m, 1))
    points[: m // 3] = samples[rng.integers(0, n, m // 3)]
    new = _clearance.nearest_distance(np.ascontiguousarray(samples), points, np.empty(m))
    assert new.tobytes() == cKDTree(samples).query(points)[0].tobytes()


@pytest.mark.parametrize("F", [1, 3, 40, 3000])
def test_feature_clearance_on_synthetic_facets(F):
    rng = np.random.default_rng(F)
    kind = rng.choice([3, 4], F)
    corner = rng.normal(size=(F, 4, 3)) + rng.integers(0, 3, (F, 1, 3))
    edge_class = rng.integers(0, 5, (F, 4))
    args = (corner, kind, edge_class, (1, 3), 1e-12)
    assert clearance.feature_clearance(*args).tobytes() == \
        oracle.feature_clearance(*args).tobytes()
