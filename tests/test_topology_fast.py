"""The compiled topology tables (issue 36: `patches/_topology.pyx`) against the numpy they
replaced (`reference_topology.py`), bit for bit: the node identity, the facet edges, the
segmentation, the edges' and nodes' classes, the smooth regions, the facet rings and their
patches, and the inside-out check, on icospheres (merged and as a triangle soup), open and
non-manifold surfaces, the sample meshes, second-order cells, tagged CAD targets, flip and
moved surfaces."""
from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import reference_topology as ref
from diffsurf_cli.patches import segment as sg
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import inside_out
from diffsurf_cli.targets import read_surface
from samples import CYLINDER, CYLINDER_STL, SAMPLES

trimesh = pytest.importorskip("trimesh")


def _icosphere(sub):
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices, dtype=np.float64), [np.asarray(m.faces, dtype=np.int64)]


def _soup(sub):
    """Every facet with nodes of its own (an STL): coincident nodes are one node."""
    nodes, (faces,) = _icosphere(sub)
    return nodes[faces].reshape(-1, 3), [np.arange(3 * len(faces)).reshape(-1, 3)]


def _open_cap(sub):
    nodes, (faces,) = _icosphere(sub)
    return nodes, [faces[nodes[faces].mean(axis=1)[:, 2] > 0.2]]


def _t_junction():
    """Two boxes' faces sharing an edge with a fin (a non-manifold edge of three facets), a
    facet with a repeated corner, and -0.0 coordinates meeting 0.0."""
    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1],
                      [0.5, 0.5, -1], [2, 0.5, 0.3], [-0.0, -0.0, 0.0], [1, 0, -0.0]], float)
    faces = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [0, 5, 1], [1, 5, 2],
                      [2, 5, 3], [3, 5, 0], [1, 2, 6], [7, 8, 6], [6, 6, 2]])
    return nodes, [faces]


def _file(path):
    t, nodes, faces = read_surface(str(path))
    tags = None if t.tags is None or any(x is None for x in t.tags) else np.concatenate(t.tags)
    return nodes, faces, tags


def _gmsh(tmp, what):
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    if what == "sphere-o2":
        path = gmsh_scenes.sphere_surface(tmp / "s.msh", size=0.4, order=2)
    elif what == "sphere-o2-quads":
        path = gmsh_scenes.sphere_surface(tmp / "s.msh", size=0.4, order=2, quads=True)
    elif what == "box-quads":
        path = gmsh_scenes.box(tmp / "b.msh", size=0.3, quads=True)
    elif what == "fillet-box":
        path = gmsh_scenes.fillet_box(tmp / "f.msh", size=0.15)
    else:
        path = gmsh_scenes.fillet_box(tmp / "f.msh", size=0.3, fillet=0.15, order=2)
    return _file(path)


CASES = {
    "icosphere-3": lambda tmp: (*_icosphere(3), None),
    "soup-2": lambda tmp: (*_soup(2), None),
    "open-cap-3": lambda tmp: (*_open_cap(3), None),
    "t-junction": lambda tmp: (*_t_junction(), None),
    "cylinder.msh": lambda tmp: _file(CYLINDER),
    "cylinder_tri.stl": lambda tmp: _file(CYLINDER_STL),
    "torus.msh": lambda tmp: _file(SAMPLES / "torus.msh"),
    "plate_and_cylinder.msh": lambda tmp: _file(SAMPLES / "plate_and_cylinder.msh"),
    "sphere-o2": lambda tmp: _gmsh(tmp, "sphere-o2"),
    "sphere-o2-quads": lambda tmp: _gmsh(tmp, "sphere-o2-quads"),
    "box-quads": lambda tmp: _gmsh(tmp, "box-quads"),
    "fillet-box": lambda tmp: _gmsh(tmp, "fillet-box"),
    "fillet-box-o2": lambda tmp: _gmsh(tmp, "fillet-box-o2"),
}


@pytest.fixture(scope="module", params=list(CASES))
def case(request, tmp_path_factory):
    nodes, faces, tags = CASES[request.param](tmp_path_factory.mktemp("topo"))
    return request.param, np.asarray(nodes, float), [np.asarray(f) for f in faces], tags


def _options(tags):
    """The surfaces built of each case: default, tags (CAD faces or not), flip, one patch,
    tags only (180)."""
    out = [dict(), dict(flip=True), dict(feature_angle=None), dict(feature_angle=180.0)]
    if tags is not None:
        out += [dict(tags=tags), dict(tags=tags, smooth_tags=True)]
    return out


def _build(nodes, faces, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return PatchedSurface(nodes, faces, **kw)


def _same(a, b, name):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape, (name, a.shape, b.shape)
    assert np.array_equal(a, b), (name, np.flatnonzero((a != b).ravel())[:10])


def test_surface_tables_are_the_former_numpy_tables(case):
    """Every table of a PatchedSurface the compiled pass now builds: the same entries (and
    integer dtypes: int64 labels, rings and their patches, int8 classes) as numpy's."""
    name, nodes, faces, tags = case
    for kw in _options(tags):
        surf = _build(nodes, faces, **kw)
        _same(surf.key, ref.node_identity(surf.nodes), (name, kw, "key"))
        if surf.feature_angle is not None:
            label = ref.segment(surf.nodes, surf.faces, surf.feature_angle, kw.get("tags"),
                                smooth_tags=kw.get("smooth_tags", False))
            _same(surf.label, label, (name, kw, "label"))
            assert surf.label.dtype == label.dtype
        view = SimpleNamespace(**{k: getattr(surf, k) for k in (
            "key", "label", "corners", "kind", "nodes", "facet_normal", "feature_angle",
            "smooth_tags", "tags", "npatches")})
        old = ref.classify_edges(view, surf.faces)
        for field in ("edge_class", "vertex_class", "edge_facets", "edge_sharp",
                      "smooth_region"):
            _same(getattr(surf, field), getattr(old, field), (name, kw, field))
            want = np.int32 if field == "edge_facets" else getattr(old, field).dtype
            assert getattr(surf, field).dtype == want, field  # int32 indices: issue 36
        old = ref.rings(view)
        _same(surf.ring.indptr, old.ring.indptr, (name, kw, "ring.indptr"))
        _same(surf.ring.indices, old.ring.indices, (name, kw, "ring.indices"))
        _same(surf.ring_ptr, old.ring_ptr, (name, kw, "ring_ptr"))
        _same(surf.ring_patches, old.ring_patches, (name, kw, "ring_patches"))
        for arr in (surf.ring.indptr, surf.ring.indices, surf.ring_ptr, surf.ring_patches):
            assert arr.dtype == np.int32  # what the compiled passes read (issue 36)
        moved = surf.moved(surf.nodes * 1.01 + 0.003)  # the topology tables are kept
        for field in ("key", "label", "edge_class", "vertex_class", "edge_facets",
                      "smooth_region", "ring_ptr", "ring_patches"):
            _same(getattr(moved, field), getattr(surf, field), (name, kw, "moved", field))


def test_segmentation_options_and_facet_edges(case):
    name, nodes, faces, tags = case
    key = ref.node_identity(nodes)
    new, old = sg.facet_edges(faces, key), ref.facet_edges(faces, key)
    for a, b, what in zip(new, old, ("fac", "loc", "edge", "ne")):
        _same(a, b, (name, what))
    table = sg.edge_table(faces, key)
    _same(table.order, np.argsort(old[2], kind="stable"), (name, "order"))
    _same(table.start, np.concatenate([[0], np.cumsum(np.bincount(old[2]))]), (name, "start"))
    rng = np.random.default_rng(3)
    nf = sum(len(f) for f in faces)
    random_tags = rng.integers(0, 3, nf)
    for kw in (dict(), dict(feature_angle=180.0), dict(feature_angle=20.0),
               dict(flat_faces=False), dict(tags=random_tags),
               dict(tags=random_tags, smooth_tags=True)):
        _same(sg.segment(nodes, faces, **kw), ref.segment(nodes, faces, **kw), (name, kw))


def test_inside_out_reports_as_before(case):
    """The winding check: facets and volume the same, float for float, whatever the node
    identity given (first occurrence, np.unique's rank, none), the facets as given, all
    reversed, and half of them reversed."""
    name, nodes, faces, tags = case
    blocks = [sg._frame.facet_corners(f) for f in faces]
    reversed_ = [f[:, ::-1] for f in blocks]
    half = [np.where((np.arange(len(f)) % 2 == 0)[:, None], f, f[:, ::-1]) for f in blocks]
    rank = np.unique(nodes, axis=0, return_inverse=True)[1].ravel()
    for fs in (faces, reversed_, half):
        for ident in (None, sg.node_identity(nodes), rank):
            assert inside_out(nodes, fs, ident) == ref.inside_out(nodes, fs, ident), name
    key = sg.node_identity(nodes)
    assert (inside_out(nodes, reversed_, key, sg.edge_table(reversed_, key))
            == ref.inside_out(nodes, reversed_, key))


def test_node_identity_is_np_unique_first_occurrence():
    rng = np.random.default_rng(0)
    base = rng.integers(-3, 4, (400, 3)).astype(float) * 0.25  # many coincident nodes
    base[rng.random(400) < 0.2, 0] *= -1.0  # -0.0 where 0.0: one position
    base[::37, 1] = np.nan  # NaN: each node its own
    _same(sg.node_identity(base), ref.node_identity(base), "grid")
    grid = np.stack(np.meshgrid(*[np.linspace(-1, 1, 30)] * 3), -1).reshape(-1, 3)
    both = np.vstack([grid, grid[rng.permutation(len(grid))[:5000]]])
    _same(sg.node_identity(both), ref.node_identity(both), "repeated")
    _same(sg.node_identity(np.zeros((0, 3))), np.zeros(0, np.int64), "empty")


def test_components_number_groups_as_scipy():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(1)
    for F, m in ((1, 0), (50, 10), (500, 300), (2000, 1900), (300, 2000)):
        a, b = rng.integers(0, F, m), rng.integers(0, F, m)
        old = connected_components(coo_matrix((np.ones(m), (a, b)), shape=(F, F)),
                                   directed=False)[1]
        _same(sg.components(F, a, b), old, (F, m))
