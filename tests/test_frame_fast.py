"""The frame's compiled passes (issue 36) against the numpy they replaced
(tests/reference_frame.py), bit for bit: the facets' area vectors and the node normals
(`mls.frame`, one compiled pass a block instead of np.cross and np.add.at), the winding
check's facet volumes (`facet._setup.facet_volumes`, numpy's einsum of np.cross), the
diffuse engine's grid (`mls._search.build_grid`, a counting sort instead of argsort and
searchsorted) and its rings of empty cells (scipy's chessboard distance), the height-field
test's row norms; on icospheres, a triangle soup, an open sheet of quads and triangles, the
sample meshes, second-order cells (tri6, quad8, quad9), CAD-like tagged targets, meshes far
from unit size, and random facet tables (repeated corners, signed zeros, mixed triangles and
quads). Also what shares them: the segmentation given the area vectors, and
`build_surface`'s facet count."""
from __future__ import annotations

import numpy as np
import pytest

import reference_frame as ref
from diffsurf_cli.facet import _setup
from diffsurf_cli.mls import _search
from diffsurf_cli.mls import frame as _frame
from diffsurf_cli.patches import segment as sg
from diffsurf_cli.projection import inside_out
from diffsurf_cli.targets import _facet_count, read_surface

trimesh = pytest.importorskip("trimesh")


def _bits(a, b, what):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (what, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype.kind == "f":  # bit for bit: -0.0 is not 0.0, NaN payloads alike
        assert np.array_equal(a.view(np.uint64), b.view(np.uint64)), (
            what, np.flatnonzero((a.view(np.uint64) != b.view(np.uint64)).ravel())[:10])
    else:
        assert np.array_equal(a, b), what


def _icosphere(sub):
    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices, dtype=np.float64), [np.asarray(m.faces, dtype=np.int64)]


def _soup(sub):
    nodes, (faces,) = _icosphere(sub)
    soup = nodes[faces].reshape(-1, 3)
    soup[soup == 0.0] = -0.0
    return soup, [np.arange(len(soup)).reshape(-1, 3)]


def _sheet():
    """A warped open sheet: quads, and triangles in a second block."""
    u, v = np.meshgrid(np.linspace(0, 2, 17), np.linspace(0, 1, 9), indexing="ij")
    nodes = np.stack([u.ravel(), v.ravel(), 0.3 * np.sin(2 * u.ravel()) * v.ravel()], axis=1)
    idx = np.arange(len(nodes)).reshape(u.shape)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], axis=-1)
    quads = quads.reshape(-1, 4)
    return nodes, [quads[::2], np.concatenate([quads[1::2, :3], quads[1::2, [0, 2, 3]]])]


def _read(path):
    target, nodes, faces = read_surface(str(path))
    tags = None if target.tags is None else np.concatenate(target.tags)
    return np.asarray(nodes, dtype=np.float64), faces, tags


def _scenes(tmp):
    yield "icosphere4", *_icosphere(4), None
    yield "soup", *_soup(2), None
    yield "sheet", *_sheet(), None
    for path in ("sample_meshes/cylinder.msh", "sample_meshes/cylinder_tri.stl",
                 "sample_meshes/torus.msh", "sample_meshes/plate_and_cylinder.msh"):
        yield path, *_read(path)
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    yield "sphere tri6", *_read(gmsh_scenes.sphere_surface(tmp / "s6.msh", size=0.4))
    yield "sphere quad8", *_read(gmsh_scenes.sphere_surface(
        tmp / "s8.msh", size=0.4, quads=True, incomplete=True))
    yield "sphere quad9", *_read(gmsh_scenes.sphere_surface(
        tmp / "s9.msh", size=0.4, quads=True))
    yield "fillet box", *_read(gmsh_scenes.fillet_box(tmp / "fb.msh", size=0.15))
    yield "fillet box o2", *_read(gmsh_scenes.fillet_box(tmp / "fb2.msh", size=0.2, order=2))


def test_area_vectors_and_node_normals_are_the_oracles(tmp_path):
    """Area vectors of the corners and of the full cells (mid-side nodes given), and node
    normals over full and linear sub-facets, at unit size and far from it (1e-80, 1e80,
    offset 1e6): the same bits as numpy's np.cross and np.add.at."""
    for name, nodes, faces, _ in _scenes(tmp_path):
        corners = [_frame.facet_corners(f) for f in faces]
        for scale, shift in ((1.0, 0.0), (1e-80, 0.0), (1e80, 0.0), (1.0, 1e6)):
            x = nodes * scale + shift
            what = f"{name} x{scale:g}+{shift:g}"
            _bits(_frame.facet_area_vectors(x, faces), ref.facet_area_vectors(x, faces), what)
            _bits(_frame.facet_area_vectors(x, corners), ref.facet_area_vectors(x, corners),
                  what)
            _bits(_frame.node_normals(x, faces), ref.node_normals(x, faces), what)
            sub = _frame.linear_facets(faces)
            _bits(_frame.node_normals(x, sub), ref.node_normals(x, sub), what + " linear")


def test_compiled_passes_on_random_facet_tables():
    """Random mixed facet tables: repeated corners (degenerate facets, zero vectors and
    signed zeros), negative indices (wrapped as numpy's), both orientations."""
    rng = np.random.default_rng(5)
    for n, F in ((4, 30), (50, 2000), (3000, 20000)):
        x = rng.normal(size=(n, 3)) * rng.uniform(1e-3, 1e3, size=(n, 1))
        x[rng.random((n, 3)) < 0.1] = -0.0
        x[rng.random((n, 3)) < 0.1] = 0.0
        for k in (3, 4, 6, 8, 9):
            f = rng.integers(0, n, size=(F, k))
            _bits(_frame.facet_area_vectors(x, [f]), ref.facet_area_vectors(x, [f]), k)
            _bits(_frame.node_normals(x, [f, f[::-1, ::-1]]),
                  ref.node_normals(x, [f, f[::-1, ::-1]]), k)
        f = rng.integers(-n, n, size=(F, 3))
        _bits(_frame.facet_area_vectors(x, [f]), ref.facet_area_vectors(x, [f]), "negative")
        out = np.zeros((n, 3))
        _setup.add_facet_rows(out, f, np.ones((F, 3)))
        want = np.zeros((n, 3))
        for j in range(3):
            np.add.at(want, f[:, j], np.ones((F, 3)))
        _bits(out, want, "add rows")
        corners = rng.integers(0, n, size=(F, 4))
        corners[rng.random(F) < 0.5, 3] = -1
        tri = corners[:, 3] < 0
        xc = x - 0.5 * (x.min(axis=0) + x.max(axis=0))
        vol = np.empty(F)
        vol[tri] = _setup.facet_volumes(xc, corners[tri][:, :3])
        vol[~tri] = _setup.facet_volumes(xc, corners[~tri])
        _bits(vol, ref.facet_volumes(x, corners), "volumes")
    with pytest.raises(IndexError):
        _frame.facet_area_vectors(np.zeros((3, 3)), [np.array([[0, 1, 3]])])
    with pytest.raises(IndexError):
        _setup.facet_volumes(np.zeros((3, 3)), np.array([[0, 1, -4]]))
    _bits(_frame.facet_area_vectors(np.zeros((0, 3)), []), np.zeros((0, 3)), "none")
    _bits(_frame.node_normals(np.zeros((2, 3)), []), np.zeros((2, 3)), "no facets")


def test_facet_volumes_are_inside_outs(tmp_path):
    """The winding check's volumes, facet by facet, as the oracle's einsum of np.cross, on
    every scene (its facets as given, and reversed); the report itself is compared with the
    former inside_out in test_topology_fast.py."""
    for name, nodes, faces, _ in _scenes(tmp_path):
        blocks = [_frame.facet_corners(f) for f in faces]
        for bl in (blocks, [f[:, ::-1] for f in blocks]):
            x = nodes - 0.5 * (nodes.min(axis=0) + nodes.max(axis=0))
            got = np.concatenate([_setup.facet_volumes(np.ascontiguousarray(x), f) for f in bl])
            want = ref.facet_volumes(nodes, np.concatenate(
                [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in bl]))
            _bits(got, want, name)
        facets, volume = inside_out(nodes, [f[:, ::-1] for f in blocks])
        assert facets == 0 or volume < 0, name


def test_grid_is_the_oracles():
    """The engine's grid: a counting sort, the same (lo, cell, dims, start, order) as the
    stable argsort and searchsorted, on a sphere, clouds, coincident nodes, a flat and
    elongated box (the cell grows), one node and none, bounds at -0.0 and 0.0."""
    rng = np.random.default_rng(2)
    clouds = [_icosphere(5)[0], rng.normal(size=(1000, 3)), rng.normal(size=(1, 3)),
              np.zeros((0, 3)), np.repeat(rng.normal(size=(10, 3)), 5, axis=0),
              rng.uniform(size=(5000, 3)) * [1, 1e-9, 1e3],
              np.array([[0.0, 0, 0], [1, 1, 1], [1, 1, 1], [0.5, 0.5, 0.5], [-0.0, 0, 1]])]
    # bounds at signed zeros: which of -0.0 and 0.0 the box keeps, as numpy's reduction
    clouds += [rng.choice([-0.0, 0.0, 1.0, -1.0, 2.0], size=(n, 3)) for n in (2, 7, 300)
               for _ in range(10)]
    for x in clouds:
        for cell in (0.0, -1.0, 1e-3, 0.02, 0.3, 7.0):
            got, want = _search.build_grid(x, cell), ref.build_grid(x, cell)
            assert got[1] == want[1]
            for a, b in zip(got[:1] + got[2:], want[:1] + want[2:]):
                _bits(a, b, (len(x), cell))


def test_empty_rings_are_the_chessboard_distance():
    """The grid's rings of empty cells (`_search.empty_rings`, the chamfer's two sweeps over
    cells in raster order, neighbours clipped to the grid once a cell): scipy's chessboard
    distance transform to the nearest cell with a node, capped at 255 (255 everywhere on an
    empty grid), as the former sweep with a test per neighbour gave (checked the same)."""
    from scipy import ndimage

    rng = np.random.default_rng(4)
    clouds = [_icosphere(5)[0], rng.normal(size=(1000, 3)), rng.normal(size=(1, 3)),
              np.zeros((0, 3)), rng.uniform(size=(3000, 3)) * [1, 1e-9, 1e3],
              np.array([[0.0, 0, 0], [300, 1, 1]]), np.array([[0.0, 0, 0], [0, 0, 2]])]
    for x in clouds:
        for cell in (1e-3, 0.01, 0.05, 0.3, 1.0):
            _, _, dims, start, _ = _search.build_grid(x, cell)
            full = (np.diff(start) > 0).reshape(tuple(int(d) for d in dims))
            want = (np.full(full.size, 255, np.uint8) if not full.any() else np.minimum(
                ndimage.distance_transform_cdt(~full, metric="chessboard"), 255).astype(
                    np.uint8).ravel())
            _bits(_search.empty_rings(dims, start), want, (len(x), cell))


def test_segment_given_area_vectors(tmp_path):
    """The segmentation with the area vectors its caller has (PatchedSurface) is the one
    that computes them; `build_surface`'s facet count is the former sum of lengths (of one
    (F, k) array: its rows', F * k, nonzero where it has facets)."""
    for name, nodes, faces, tags in _scenes(tmp_path):
        area = _frame.facet_area_vectors(nodes, faces)
        for kw in (dict(), dict(feature_angle=20.0)) + (
                (dict(tags=tags, smooth_tags=True),) if tags is not None else ()):
            _bits(sg.segment(nodes, faces, area=area, **kw), sg.segment(nodes, faces, **kw),
                  name)
    faces = _icosphere(2)[1][0]
    for given in (faces, faces[:, :0], [faces, faces[:3]], np.zeros((0, 3), np.int64),
                  [[0, 1, 2]], [], [np.zeros((0, 4), np.int64)], faces.reshape(1, -1, 3)):
        assert _facet_count(given) == sum(len(f) for f in given)


def test_row_norms_and_height_field(tmp_path):
    """`frame.row_norms` is np.linalg.norm(axis=1) bit for bit (C and Fortran order, signed
    zeros, tiny and huge rows); `is_height_field` decides as before on every scene's facets
    in both orientations, over their mean plane and tilted frames, with zero-area facets."""
    rng = np.random.default_rng(7)
    v = rng.normal(size=(20001, 3)) * rng.uniform(1e-150, 1e150, size=(20001, 1))
    v[::5, 1] = -0.0
    v[::11] = 0.0
    for x in (v, np.asfortranarray(v), v[::3]):
        _bits(_frame.row_norms(x), np.linalg.norm(x, axis=1), "norms")
    for name, nodes, faces, _ in _scenes(tmp_path):
        area = _frame.facet_area_vectors(nodes, faces)
        area[::7] = 0.0
        _, axes = _frame.mean_plane(nodes)
        tilt = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        for a in (area, -area, area[:1], area[:0], np.zeros((4, 3))):
            for ax in (axes, tilt, np.eye(3)):
                assert _frame.is_height_field(ax, a) == ref.is_height_field(ax, a), name


def test_height_field_sampled(tmp_path):
    """frame='auto' (`mls.surface._height_field`: a sample of the facets first, all of them
    where the sample does not settle it) decides as `is_height_field` of all the facets did
    (tests/reference_frame.py), on every scene in both orientations and tilted frames, on
    plates (a height field) with one facet turned past the limit or to just within it, and on
    big spheres and hemispheres (past the sample's size)."""
    from diffsurf_cli.mls.surface import HEIGHT_FIELD_SAMPLE, _height_field

    rng = np.random.default_rng(11)
    scenes = [(name, nodes, faces) for name, nodes, faces, _ in _scenes(tmp_path)]
    nodes, faces = _icosphere(4)
    scenes.append(("big sphere", nodes, faces))
    top = nodes[faces[0]].mean(axis=1)[:, 2] > 0.0
    scenes.append(("big cap", nodes, [faces[0][top]]))
    # a wavy plate of 2 x 40 x 40 facets, one facet (a sampled one, or not) turned steep
    n = 41
    u, w = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    plate = np.column_stack([u.ravel(), w.ravel(), 0.02 * np.sin(3 * u.ravel())])
    q = (np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None]).ravel()
    tri = np.concatenate([np.column_stack([q, q + n, q + 1]),
                          np.column_stack([q + 1, q + n, q + n + 1])])
    assert len(tri) >= 16 * HEIGHT_FIELD_SAMPLE
    scenes.append(("plate", plate, [tri]))
    for at in (0, HEIGHT_FIELD_SAMPLE, 5):
        for z in (5.0, 0.9, 1e-3):
            p = plate.copy()
            p[tri[at, 0], 2] += z
            scenes.append((f"plate {at} {z}", p, [tri]))
    for name, nodes, faces in scenes:
        faces = faces if isinstance(faces, list) else [faces]
        area = _frame.facet_area_vectors(nodes, faces)
        _, axes = _frame.mean_plane(nodes)
        tilt = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        for flip in (False, True):
            a = -area if flip else area
            for ax in (axes, tilt, np.eye(3), -np.eye(3)):
                assert _height_field(nodes, faces, ax, flip) == ref.is_height_field(ax, a), name
