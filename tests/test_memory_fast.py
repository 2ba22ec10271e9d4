"""The default surface's tables sized to the scene (issue 36, memory): what a PatchedSurface no
longer keeps is recomputed bit for bit where it is needed.

- a first-order target keeps no (F, 9, 3) table of curved cells: the pass computes a cell
  where it needs it (`_pass.cell_of`), `cell_rows` and `cell_coef` too; the coefficients are
  the oracle's (tests/reference_cells_setup.py) and the pass's answers those it gives with
  the full table;
- the corner normals are kept compacted (`_pass.compact_normals`), the edges' lengths and
  bends recomputed on demand: the oracle's (tests/reference_guard.py) bit for bit;
- int32 index tables (the facets' search, the vertex rings, the edges' facets) and no copy of
  the facets in the patch surfaces.

On icospheres, the sample meshes, second-order cells (and a target mixing them with
first-order facets), CAD-like targets with tags and creases under one patch, an open sheet,
flip=True and `moved`."""
from __future__ import annotations

import copy

import numpy as np
import pytest

import reference_cells_setup as ref_cells
import reference_guard as ref_guard
from diffsurf_cli.patches import _pass
from diffsurf_cli.patches.surface import CELLS, PatchedSurface, corner_normals
from diffsurf_cli.targets import read_surface

FIELDS = ("gap", "normal", "proximal_point", "status", "reason", "support", "iterations",
          "rcond", "curvature", "source", "facet", "facet_gap", "facet_normal", "cell",
          "cell_param")


def _same(a, b, what=""):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (what, a.shape, b.shape, a.dtype, b.dtype)
    assert a.tobytes() == b.tobytes(), what


def _read(path):
    target, nodes, faces = read_surface(str(path))
    tags = None if target.tags is None else np.concatenate(target.tags)
    return np.asarray(nodes, dtype=np.float64), faces, tags


def _icosphere(sub):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices, dtype=np.float64), [np.asarray(m.faces, dtype=np.int64)]


def _open_plate():
    u, v = np.meshgrid(np.linspace(0, 2, 15), np.linspace(0, 1, 9), indexing="ij")
    nodes = np.stack([u.ravel(), v.ravel(), 0.2 * np.sin(u.ravel()) * v.ravel()], axis=1)
    idx = np.arange(len(nodes)).reshape(u.shape)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1)
    return nodes, [quads.reshape(-1, 4)]


def _scenes(tmp):
    """(name, nodes, faces, options) of varied targets."""
    nodes, faces = _icosphere(3)
    yield "icosphere", nodes, faces, {}
    yield "icosphere flip", nodes, [f[:, ::-1] for f in faces], {"flip": True}
    yield "open plate", *_open_plate(), {}
    for name in ("cylinder.msh", "torus.msh", "plate_and_cylinder.msh", "cylinder_tri.stl"):
        nodes, faces, tags = _read(f"sample_meshes/{name}")
        yield name, nodes, faces, {"tags": tags}
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    nodes, faces, tags = _read(gmsh_scenes.fillet_box(tmp / "fb.msh", size=0.15))
    yield "fillet box", nodes, faces, {"tags": tags, "smooth_tags": True}
    yield "fillet box, one patch", nodes, faces, {"feature_angle": None}  # crease normals
    nodes, faces, tags = _read(gmsh_scenes.fillet_box(tmp / "fb2.msh", size=0.2, order=2))
    yield "fillet box o2", nodes, faces, {"tags": tags, "smooth_tags": True}
    nodes, faces, _ = _read(gmsh_scenes.sphere_surface(tmp / "s6.msh", size=0.4))
    yield "sphere tri6", nodes, faces, {}
    f = np.concatenate(faces)
    half = len(f) // 2  # second-order cells beside first-order facets
    yield "sphere tri6 + tri3", nodes, [f[:half], np.ascontiguousarray(f[half:, :3])], {}
    nodes, faces, _ = _read(gmsh_scenes.sphere_surface(tmp / "s8.msh", size=0.4, quads=True,
                                                       incomplete=True))
    yield "sphere quad8", nodes, faces, {}


def _surfaces(tmp):
    for name, nodes, faces, kw in _scenes(tmp):
        surf = PatchedSurface(nodes, faces, **kw)
        yield name, surf
        moved = surf.moved(nodes * 1.01 + 2e-3 * np.sin(5.0 * nodes[:, [1, 2, 0]]))
        yield name + " moved", moved


def _points(surf, m=3000, seed=3):
    """Contactors near the target (within a few spacings) and around it."""
    rng = np.random.default_rng(seed)
    nodes = surf.nodes
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    size = float(np.max(hi - lo))
    at = nodes[rng.integers(0, len(nodes), m)]
    near = at + rng.normal(scale=0.02 * size, size=(m, 3))
    around = rng.uniform(lo - 0.2 * size, hi + 0.2 * size, (m // 3, 3))
    return np.concatenate([near, around])


def test_corner_tables_are_the_oracle_s(tmp_path):
    """The compacted corner normals and the recomputed edge lengths and bends: the oracle's
    `corner_normals`, bit for bit; the compact form is int32 and smaller."""
    for name, surf in _surfaces(tmp_path):
        want = ref_guard.corner_normals(surf)
        for field, old, new in zip(("corner_normal", "edge_length", "edge_bend"), want,
                                   corner_normals(surf)):
            _same(getattr(surf, field), old, (name, field))
            _same(new, old, (name, field, "corner_normals"))
        index, table = surf._normals
        assert index.dtype == np.int32 and index.shape == surf.corners.shape
        assert len(table) <= np.count_nonzero(surf.corners >= 0)
        assert surf._corner_normal is None and surf._edge_length is None


def test_cells_are_the_oracle_s_without_a_table(tmp_path):
    """has_cell, cell_coef (computed where no table is kept) and `cell_rows` of any facets:
    the oracle's coefficients bit for bit; a table only where second-order cells are."""
    seen_first_order = 0
    for name, surf in _surfaces(tmp_path):
        has, coef = ref_cells.cell_coefficients(surf)
        _same(surf.has_cell, has, (name, "has_cell"))
        _same(surf.cell_coef, coef, (name, "cell_coef"))
        second = any(f.shape[1] > 4 for f in surf.faces)
        assert (surf._cell_table is not None) == (second and bool(has.any())), name
        if not second and has.any():
            seen_first_order += 1
            assert surf._cell_normals is not None
        F = len(surf.corners)
        cells = np.random.default_rng(F).integers(0, F, 200)
        if has.any():
            _same(surf.cell_rows(cells), coef[cells], (name, "cell_rows"))
        else:
            assert not surf.cell_rows(cells).any()
        assert surf.cell_rows(np.zeros(0, np.int64)).shape == (0, 9, 3)
    assert seen_first_order >= 6


def _answers(surf, points):
    surf._pass = None
    res = surf.project(points)
    return {k: np.asarray(getattr(res, k)) for k in FIELDS}


@pytest.mark.parametrize("flip", [False, True])
def test_the_pass_answers_as_with_the_table(tmp_path, flip):
    """The compiled pass computing each first-order cell where it needs it answers bit for bit
    as it does reading the full (F, 9, 3) table (the former storage), curved cells answering
    some contactors."""
    answered = 0
    for name, nodes, faces, kw in _scenes(tmp_path):
        if flip:
            if kw.get("flip"):
                continue
            kw = dict(kw, flip=True)
        surf = PatchedSurface(nodes, faces, **kw)
        if surf._cell_table is not None or not surf.has_cell.any():
            continue
        points = _points(surf)
        fast = _answers(surf, points)
        table = copy.copy(surf)
        table._cell_table = ref_cells.cell_coefficients(surf)[1]
        slow = _answers(table, points)
        for key in FIELDS:
            _same(fast[key], slow[key], (name, key))
        answered += int(np.count_nonzero(fast["source"] == CELLS))
    assert answered > 10


def test_compact_normals_keep_every_bit():
    """Rows are shared only by corners at one node with the same bits (-0.0 is not 0.0);
    the expansion is the input, zero at a triangle's fourth corner."""
    from diffsurf_cli.patches.surface import _expand_normals

    rng = np.random.default_rng(5)
    F, n = 400, 90
    corners = rng.integers(0, n, (F, 4)).astype(np.int64)
    corners[: F // 2, 3] = -1
    key = np.arange(n, dtype=np.int64)
    key[n // 2:] = np.arange(n // 2)  # coincident nodes: one identity
    choices = np.array([[0.0, 0.0, 1.0], [-0.0, 0.0, 1.0], [0.6, 0.8, 0.0],
                        [0.6, 0.8, 1e-300]])
    normal = choices[rng.integers(0, len(choices), (F, 4))]
    normal[corners < 0] = 0.0
    index, table = _pass.compact_normals(normal, corners, key)
    assert index.dtype == np.int32 and np.all((index < 0) == (corners < 0))
    _same(_expand_normals(index, table), normal)
    # one row per (node identity, distinct bits)
    real = corners >= 0
    pairs = {(int(key[c]), normal[f, j].tobytes()) for (f, j), c in np.ndenumerate(corners)
             if real[f, j]}
    assert len(table) == len(pairs)


def test_index_tables_are_int32_and_faces_shared(tmp_path):
    """The tables the compiled passes read are int32 (kind int8); one patch's surface shares
    the target's facet blocks (read-only), the caller's own arrays are copied, not aliased."""
    nodes, faces = _icosphere(3)
    mine = faces[0].copy()
    surf = PatchedSurface(nodes, [mine])
    tables = surf.facet_surface()._tables
    for key in ("fnode", "fedge", "edge_ptr", "edge_inc", "link", "original", "slot"):
        assert tables[key].dtype == np.int32, key
    assert tables["kind"].dtype == np.int8
    for arr in (surf.ring.indptr, surf.ring.indices, surf.ring_ptr, surf.ring_patches,
                surf.edge_facets):
        assert arr.dtype == np.int32
    assert surf.surfaces[0].faces[0] is surf.faces[0]
    assert not np.shares_memory(surf.faces[0], mine) and mine.flags.writeable
    surf.project(_points(surf, 100))
    mine[:] = 0  # the caller's array is theirs
    assert surf.faces[0].max() > 0
