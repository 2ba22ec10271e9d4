"""The compiled edge passes (issue 36: `patches/_edges.pyx`) against the numpy they replaced
(`reference_setup3.py`), bit for bit: the segmentation's edge cosines (compared as bits with
np.einsum's), its flat faces, and `PatchedSurface._classify_edges`' tables (edge and node
classes, edge facets, sharp edges, smooth regions), on the topology cases (icospheres, a
triangle soup, open and non-manifold surfaces, the sample meshes, second-order cells, tagged
CAD targets), a flattened icosphere (flat faces), and on random normals, labels and tags
with zero, -0, NaN, tiny and huge rows and every feature angle."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import reference_setup3 as ref
from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches import _edges
from diffsurf_cli.patches import segment as sg
from diffsurf_cli.patches.surface import PatchedSurface
from test_topology_fast import CASES, _icosphere


def _flattened(sub):
    """An icosphere with its caps cut flat: two flat faces meeting curved facets."""
    nodes, faces = _icosphere(sub)
    nodes = nodes.copy()
    nodes[:, 2] = np.clip(nodes[:, 2], -0.6, 0.6)
    return nodes, faces


ALL = dict(CASES, **{"flattened-3": lambda tmp: (*_flattened(3), None)})


@pytest.fixture(scope="module", params=list(ALL))
def case(request, tmp_path_factory):
    nodes, faces, tags = ALL[request.param](tmp_path_factory.mktemp("setup3"))
    return request.param, np.asarray(nodes, float), [np.asarray(f) for f in faces], tags


def _same(a, b, name):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (name, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype.kind == "f":  # bits: -0.0 against 0.0 and NaN payloads count
        a, b = a.view(np.int64), b.view(np.int64)
    assert np.array_equal(a, b), (name, np.flatnonzero((a != b).ravel())[:10])


def _odd_rows(area, rng):
    """area with some rows zero, -0, NaN, tiny, huge, axis-aligned and negated."""
    area = area.copy()
    F = len(area)
    for value in (0.0, -0.0, np.nan, 1e-300, 1e300, -1.0):
        rows = rng.integers(0, F, max(1, F // 50))
        if value in (1e-300, 1e300):
            area[rows] *= value
        elif value == -1.0:
            area[rows] = -area[rows]
        else:
            area[rows, rng.integers(0, 3, len(rows))] = value
    area[rng.integers(0, F, max(1, F // 50))] = 0.0
    area[rng.integers(0, F, max(1, F // 50))] = -0.0
    return area


def test_segment_cosines_flat_faces_and_two_facets(case):
    name, nodes, faces, tags = case
    key = sg.node_identity(nodes)
    edges = sg.edge_table(faces, key)
    fa, fb = sg._two_facets(edges)
    ra, rb = ref.two_facets(edges)
    _same(fa, ra, (name, "fa"))
    _same(fb, rb, (name, "fb"))
    area = _frame.facet_area_vectors(nodes, faces)
    rng = np.random.default_rng(7)
    nf = len(area)
    for what, a in (("area", area), ("odd", _odd_rows(area, rng)),
                    ("random", rng.normal(size=area.shape) * 10.0 ** rng.integers(-5, 5, nf)[:,
                                                                                          None])):
        cos = _edges.segment_cosines(np.ascontiguousarray(a), fa, fb)
        _same(cos, ref.segment_cosines(a, fa, fb), (name, what, "cos"))
        unit = ref.segment_unit(a)
        _same(sg._flat_faces(nodes, faces, fa, fb, nf, key, edges, cos),
              ref.flat_faces(nodes, faces, fa, fb, unit, key, edges), (name, what, "flat"))


def test_classify_edges(case):
    name, nodes, faces, tags = case
    key = sg.node_identity(nodes)
    edges = sg.edge_table(faces, key)
    area = _frame.facet_area_vectors(nodes, faces)
    nf = len(area)
    rng = np.random.default_rng(11)
    unit = area / np.linalg.norm(area, axis=1, keepdims=True).clip(1e-300)
    normals = {"unit": unit, "odd": _odd_rows(unit, rng),
               "random": rng.normal(size=unit.shape)}
    labels = {"one": np.zeros(nf, np.int64), "segment": sg.segment(nodes, faces),
              "random": rng.integers(0, 4, nf)}
    tag_sets = [None, rng.integers(0, 3, nf)] + ([np.asarray(tags)] if tags is not None else [])
    for angle in (None, 40.0, 10.0, 180.0, 250.0, 0.0):
        for nname, normal in normals.items():
            for lname, label in labels.items():
                for t in tag_sets:
                    for smooth_tags in ((False, True) if t is not None else (False,)):
                        view = SimpleNamespace(
                            key=key, label=label, corners=np.zeros((nf, 4), np.int64),
                            nodes=nodes, facet_normal=normal, feature_angle=angle,
                            smooth_tags=smooth_tags, tags=t, coarse_bend=None,
                            cad_crease=None)
                        old = ref.classify_edges(view, edges)
                        PatchedSurface._classify_edges(view, faces, edges)
                        for field in ("edge_class", "vertex_class", "edge_facets", "edge_sharp",
                                      "smooth_region"):
                            _same(getattr(view, field), getattr(old, field),
                                  (name, angle, nname, lname, smooth_tags, field))


def test_target_grid_is_built_once_with_the_same_tables(case):
    """`_projection.Target` keeps the grid `build_grid` gave for the caller's nodes as the
    grid of its renumbered nodes where no bound of their box is zero: the tables are those
    `build_grid` gives for the renumbered nodes (lo, cell, dims, start; order the identity).
    Where a bound is zero it builds the grid again (the cases below include both)."""
    from diffsurf_cli.mls._search import build_grid

    name, nodes, faces, tags = case
    rng = np.random.default_rng(5)
    clouds = [nodes, nodes + 3.0, nodes * 1e-7 - 1e-9, rng.normal(size=(2000, 3)),
              np.round(rng.normal(size=(3000, 3)), 1) + 0.05,  # ties, duplicates
              np.c_[rng.random((500, 2)) + 1.0, np.full(500, 2.5)],  # a flat row of cells
              np.abs(rng.normal(size=(400, 3)))]  # lo may be 0: rebuilt
    for x in clouds:
        x = np.ascontiguousarray(x, dtype=np.float64)
        spacing = (x.max(axis=0) - x.min(axis=0)).max() / 40 + 1e-300
        for cell in (spacing, 3 * spacing, 1e-9):
            lo, c, dims, start, perm = build_grid(x, cell)
            hi = [x[:, e].max() for e in range(3)]
            if not all(lo[e] != 0 and hi[e] != 0 for e in range(3)):
                continue  # Target builds it again
            lo2, c2, dims2, start2, order2 = build_grid(np.ascontiguousarray(x[perm]), cell)
            _same(lo, lo2, (name, "lo"))
            assert c == c2
            _same(dims, dims2, (name, "dims"))
            _same(start, start2, (name, "start"))
            _same(order2, np.arange(len(x), dtype=np.int64), (name, "order"))
