"""The facets' and the diffuse surface's setup, measured once and shared (issue 36): the node
identity, the node spacing and the facet tables are bit for bit the oracle's
(tests/reference_facet_setup.py: today's implementations before the sharing), standalone and
inside a PatchedSurface (its whole target's facets, each patch's facets and surface), on
icospheres, the sample meshes, second-order cells, CAD-like multi-patch targets with tags,
open surfaces, triangle soups (exact duplicates), flip=True and `moved`."""
from __future__ import annotations

import numpy as np
import pytest

import reference_facet_setup as ref
from diffsurf_cli.facet import _engine
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import facet_corners
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.nodes import SharedNodes, node_spacing
from diffsurf_cli.patches import segment as _segment
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.targets import read_surface

DIFFUSE_KEYS = ("first", "duplicates", "normals", "node_spacing", "origin", "axes", "signed",
                "fold_normals", "ruled")


def _icosphere(sub):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices, dtype=np.float64), [np.asarray(m.faces, dtype=np.int64)]


def _soup(sub):
    """An unmerged STL's triangles: every node repeated at each facet, -0.0 beside 0.0."""
    nodes, faces = _icosphere(sub)
    f = faces[0]
    soup = nodes[f].reshape(-1, 3)
    soup[soup == 0.0] = -0.0
    soup[::2][soup[::2] == 0.0] = 0.0
    return soup, [np.arange(len(soup)).reshape(-1, 3)]


def _open_plate():
    """A curved open quad sheet, its last row of nodes repeated (a zone boundary)."""
    u, v = np.meshgrid(np.linspace(0, 2, 23), np.linspace(0, 1, 13), indexing="ij")
    nodes = np.stack([u.ravel(), v.ravel(), 0.2 * np.sin(u.ravel()) * v.ravel()], axis=1)
    idx = np.arange(len(nodes)).reshape(u.shape)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1)
    quads = quads.reshape(-1, 4)
    extra = nodes[idx[-1]]                        # copies of the last row, used by its quads
    copy = len(nodes) + np.arange(len(extra))
    nodes = np.concatenate([nodes, extra])
    last = np.isin(quads, idx[-1])
    remap = np.full(len(nodes), -1)
    remap[idx[-1]] = copy
    quads = np.where(last & (np.arange(len(quads))[:, None] % 2 == 0), remap[quads], quads)
    return nodes, [quads]


def _read(path):
    _, nodes, faces = read_surface(path)
    return np.asarray(nodes, dtype=np.float64), faces


def _tags(path):
    target, nodes, faces = read_surface(path)
    tags = None if target.tags is None else np.concatenate(target.tags)
    return np.asarray(nodes, dtype=np.float64), faces, tags


def _equal(a, b, what):
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and a.dtype == b.dtype, what
        assert np.array_equal(a, b, equal_nan=a.dtype.kind == "f"), what
        if a.dtype.kind == "f":  # bit for bit: -0.0 is not 0.0
            assert np.array_equal(a.view(np.uint64 if a.itemsize == 8 else np.uint32),
                                  b.view(np.uint64 if b.itemsize == 8 else np.uint32)), what
    else:
        assert a == b, what


def _check_facets(fs: FacetSurface, nodes, flip, name=""):
    spacing, tables = ref.facet_geometry(nodes, fs.facets, flip)
    _equal(fs.node_spacing, spacing, f"{name}: node_spacing")
    assert set(fs._tables) == set(tables)
    for key, value in tables.items():
        if key in _engine.INDEX_TABLES + ("kind",):  # stored int32 / int8 (issue 36), the
            got = fs._tables[key]                    # oracle's values
            assert got.dtype == (np.int8 if key == "kind" else np.int32), f"{name}: {key}"
            assert np.array_equal(got, value) and got.shape == value.shape, f"{name}: {key}"
            continue
        _equal(fs._tables[key], value, f"{name}: {key}")


def _check_diffuse(ds: DiffuseSurface, nodes, faces, flip, name="", pinned=False):
    want = ref.diffuse_setup(nodes, faces, flip)
    for key in DIFFUSE_KEYS:
        if pinned and key in ("origin", "axes", "ruled"):  # moved(): a global frame's own
            continue
        _equal(getattr(ds, key), want[key], f"{name}: {key}")
    assert want["distinct_count"] == len(np.unique(ds.first))


def _check_patched(ps: PatchedSurface, flip, name):
    nodes = ps.nodes
    _equal(ps.key, ref.node_identity(nodes), f"{name}: key")
    _equal(ps.corners, np.concatenate([np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1)
                                       for f in map(facet_corners, ps.faces)]), f"{name}: corners")
    _check_facets(ps.facet_surface(), nodes, flip, name)
    for p, (fs, ds, used) in enumerate(zip(ps.patch_facets, ps.surfaces, ps.patch_nodes)):
        pts = nodes[used]
        if fs is not None and fs is not ps.facet_surface():
            _check_facets(fs, pts, flip, f"{name} patch {p}")
        if ds is not None:
            _check_diffuse(ds, pts, ds.faces, flip, f"{name} patch {p}")


def _scenes(tmp):
    from diffsurf_cli.testing import gmsh_scenes

    yield "icosphere3", *_icosphere(3), None
    yield "soup", *_soup(2), None
    yield "open plate", *_open_plate(), None
    for path in ("sample_meshes/cylinder.msh", "sample_meshes/cylinder_tri.stl",
                 "sample_meshes/torus.msh", "sample_meshes/plate_and_cylinder.msh"):
        yield path, *_tags(path)
    pytest.importorskip("gmsh")
    yield "sphere tri6", *_read(gmsh_scenes.sphere_surface(tmp / "s6.msh", size=0.4)), None
    yield "sphere quad8", *_read(gmsh_scenes.sphere_surface(
        tmp / "s8.msh", size=0.4, quads=True, incomplete=True)), None
    yield "fillet box", *_tags(gmsh_scenes.fillet_box(tmp / "fb.msh", size=0.15))
    yield "fillet box o2", *_tags(gmsh_scenes.fillet_box(tmp / "fb2.msh", size=0.2, order=2))


def test_identity_and_spacing_are_the_oracles(tmp_path):
    from diffsurf_cli.tune import node_spacing as tune_spacing

    for name, nodes, _, _ in _scenes(tmp_path):
        shared = SharedNodes(nodes)
        first, distinct, group = ref.merge(nodes)
        _equal(shared.first, ref.node_identity(nodes), name)
        _equal(shared.first, first, name)
        _equal(shared.distinct, distinct, name)
        _equal(shared.group, group, name)
        _equal(shared.spacing, ref.facet_spacing(nodes), name)     # cKDTree's
        _equal(node_spacing(nodes), ref.diffuse_setup(nodes, [])["node_spacing"], name)
        distinct_nodes = nodes[distinct]
        _equal(tune_spacing(distinct_nodes), ref.tune_spacing(distinct_nodes), name)
        # a patch's identity from the target's: the subset's own lexsort
        rng = np.random.default_rng(0)
        used = np.flatnonzero(rng.random(len(nodes)) < 0.4)
        sub = shared.subset(used)
        for a, b in zip((sub.first, sub.distinct, sub.group), ref.merge(nodes[used])):
            _equal(a, b, name)


@pytest.mark.parametrize("flip", [False, True])
def test_standalone_surfaces_are_the_oracles(tmp_path, flip):
    for name, nodes, faces, _ in _scenes(tmp_path):
        fs = FacetSurface(nodes, [facet_corners(f) for f in faces], flip=flip)
        _check_facets(fs, nodes, flip, name)
        ds = DiffuseSurface(nodes, faces, flip=flip)
        _check_diffuse(ds, nodes, ds.faces, flip, name)
        moved = nodes + 0.01 * np.sin(3 * nodes[:, [1, 2, 0]])
        _check_facets(fs.moved(moved), moved, flip, name + " moved")
        _check_diffuse(ds.moved(moved), moved, ds.faces, flip, name + " moved",
                       pinned=ds.frame == "global")


@pytest.mark.parametrize("flip", [False, True])
def test_patched_surface_tables_are_the_oracles(tmp_path, flip):
    for name, nodes, faces, tags in _scenes(tmp_path):
        variants = [dict(feature_angle=None), dict()]
        if tags is not None:
            variants += [dict(tags=tags), dict(tags=tags, smooth_tags=True)]
        for kw in variants:
            try:
                ps = PatchedSurface(nodes, faces, flip=flip, **kw)
            except ValueError:  # a target the patches refuse (the oracle's too)
                continue
            _check_patched(ps, flip, f"{name} {sorted(kw)}")
            moved = ps.moved(nodes * 1.01 + 0.003)
            _check_facets(moved.facet_surface(), moved.nodes, flip, f"{name} {sorted(kw)} moved")


def test_node_identity_is_segments():
    nodes, _ = _soup(2)
    _equal(SharedNodes(nodes).first, _segment.node_identity(nodes), "segment's key")


def test_compiled_facet_passes_are_numpys():
    """`facet._setup` against the numpy it replaces, on random mixed facet tables: repeated
    and signed-zero coordinates (min/max ties), non-manifold and repeated edges."""
    from diffsurf_cli.facet import _setup

    rng = np.random.default_rng(3)
    for n, F in ((5, 40), (60, 300), (2000, 5000)):
        X = rng.choice([-0.0, 0.0, 1.0, -1.5, 2.25], size=(n, 3))
        X[: n // 2] = rng.normal(size=(n // 2, 3))
        facets = rng.integers(0, n, size=(F, 4))
        facets[rng.random(F) < 0.5, 3] = -1
        corner = X[np.where(facets >= 0, facets, facets[:, :1])]
        bounds, centroid = _setup.facet_boxes(X, facets)
        _equal(bounds, np.concatenate([corner.min(axis=1), corner.max(axis=1)], axis=1), "box")
        _equal(centroid, corner.mean(axis=1), "centroid")
        order = rng.permutation(F).astype(np.int64)
        _equal(_setup.facet_corners(X, facets, order), corner[order], "corners")
        kind = np.where(facets[:, 3] < 0, 3, 4).astype(np.int64)
        tri = (kind == 3)[:, None]
        b = np.where(tri, facets[:, [1, 2, 0, 0]], facets[:, [1, 2, 3, 0]])
        real = np.arange(4)[None, :] < kind[:, None]
        key = (np.minimum(facets, b) * n + np.maximum(facets, b))[real]
        inc = (4 * np.arange(F)[:, None] + np.arange(4)[None, :])[real]
        by_edge = np.argsort(key, kind="stable")
        new = np.ones(len(key), bool)
        new[1:] = key[by_edge][1:] != key[by_edge][:-1]
        edge = np.empty(len(key), dtype=np.int64)
        edge[by_edge] = np.cumsum(new) - 1
        fedge = np.full((F, 4), -1, dtype=np.int64)
        fedge[real] = edge
        got = _setup.facet_edges(facets, kind, n)
        _equal(got[0], fedge, "fedge")
        _equal(got[1], np.append(np.flatnonzero(new), len(key)).astype(np.int64), "edge_ptr")
        _equal(got[2], inc[by_edge], "edge_inc")
