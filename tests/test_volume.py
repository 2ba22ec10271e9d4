"""Volume meshes as targets (issue 11 item 4): the boundary of the volume cells (faces used by
one cell, oriented outward, mid-side nodes included), of one zone, or the boundary faces whose
nodes are all in a node set.

Scenes: gmsh (OpenCASCADE) tetra meshes of a box and a cylinder, order 1 and 2, and
structured hexahedra / wedges / pyramids built here by hand, first and second order."""
from __future__ import annotations

import itertools

import meshio
import numpy as np
import pytest

from diffsurf_cli import io
from diffsurf_cli.io.boundary import boundary_faces
from diffsurf_cli.mls.frame import facet_area_vectors, facet_corners
from samples import run


def _checks(points, cells):
    """Count, closedness (each corner edge in exactly two faces, once each way) and enclosed
    volume (> 0: outward) of boundary faces."""
    corners = [facet_corners(c) for _, c in cells]
    edges = np.concatenate([np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)
                            for f in corners])
    directed = {tuple(e) for e in edges}
    assert len(directed) == len(edges), "an edge used twice the same way: faces misoriented"
    assert all((b, a) in directed for a, b in directed), "an open edge"
    # divergence theorem: V = 1/3 sum over faces of (centroid . area vector)
    areas = facet_area_vectors(points, corners)
    centroids = np.concatenate([points[f].mean(axis=1) for f in corners])
    return float(np.sum(centroids * areas) / 3.0)


def _mid_sides_at_midpoints(points, cells):
    """Straight-sided cells: each mid-side node is the midpoint of its side (order check)."""
    for kind, conn in cells:
        k = 3 if kind.startswith("triangle") else 4
        if conn.shape[1] < 2 * k:
            continue
        for j in range(k):
            mid = 0.5 * (points[conn[:, j]] + points[conn[:, (j + 1) % k]])
            np.testing.assert_allclose(points[conn[:, k + j]], mid, atol=1e-9)
        if conn.shape[1] == 9:
            np.testing.assert_allclose(points[conn[:, 8]], points[conn[:, :4]].mean(axis=1),
                                       atol=1e-9)


def hexa_box(n=(3, 4, 2), order=1, kind="hexahedron"):
    """A structured mesh of (0..1)^3: hexahedra, or each hexahedron split into two wedges or
    six pyramids... kept simple: hexahedron(20/27) or wedge(15); second order by midpoints."""
    nx, ny, nz = n
    g = [np.linspace(0, 1, m + 1) for m in n]
    pts = np.array(list(itertools.product(*g)))  # index (i, j, k) -> (i*(ny+1) + j)*(nz+1) + k
    idx = lambda i, j, k: (i * (ny + 1) + j) * (nz + 1) + k  # noqa: E731
    hexa = []
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        hexa.append([idx(i, j, k), idx(i + 1, j, k), idx(i + 1, j + 1, k), idx(i, j + 1, k),
                     idx(i, j, k + 1), idx(i + 1, j, k + 1), idx(i + 1, j + 1, k + 1),
                     idx(i, j + 1, k + 1)])
    hexa = np.array(hexa)
    if kind == "wedge":
        conn = np.concatenate([hexa[:, [0, 1, 2, 4, 5, 6]], hexa[:, [0, 2, 3, 4, 6, 7]]])
    elif kind == "pyramid":  # a centre node per hexahedron, six pyramids to it
        centre = len(pts) + np.arange(len(hexa))
        pts = np.concatenate([pts, pts[hexa].mean(axis=1)])
        faces = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6),
                 (3, 0, 4, 7)]
        conn = np.concatenate([np.column_stack([hexa[:, list(f)], centre]) for f in faces])
    else:
        conn = hexa
    ctype = {"hexahedron": "hexahedron", "wedge": "wedge", "pyramid": "pyramid"}[kind]
    if order == 2:
        from diffsurf_cli.io import boundary as b

        edges = {"hexahedron": b._HEXA_EDGES, "wedge": b._WEDGE_EDGES,
                 "pyramid": b._PYRAMID_EDGES}[kind]
        extra = [(e[0], e[1]) for e in edges]
        if kind == "hexahedron":  # hexahedron27: face centres and the volume centre too
            extra += [c[0] for c in b._HEXA27_CENTRES] + [tuple(range(8))]
            ctype = "hexahedron27"
        else:
            ctype = {"wedge": "wedge15", "pyramid": "pyramid13"}[kind]
        new = np.stack([pts[conn[:, list(e)]].mean(axis=1) for e in extra], axis=1)
        new = new.reshape(-1, 3)
        # merge shared nodes by position
        allp = np.concatenate([pts, new])
        uniq, inv = np.unique(np.round(allp, 12), axis=0, return_inverse=True)
        inv = inv.ravel()
        conn = np.column_stack([inv[conn], inv[len(pts):].reshape(len(conn), -1)])
        pts = uniq
    return pts, [(ctype, conn)]


@pytest.mark.parametrize("kind,order", [("hexahedron", 1), ("hexahedron", 2), ("wedge", 1),
                                        ("wedge", 2), ("pyramid", 1), ("pyramid", 2)])
def test_structured_box_boundary(kind, order):
    pts, cells = hexa_box(kind=kind, order=order)
    faces, used = boundary_faces(pts, cells)
    assert used == {cells[0][0]: len(cells[0][1])}
    nquads = 2 * (3 * 4 + 4 * 2 + 3 * 2)  # the box's outer grid faces
    count = {k: len(c) for k, c in faces}
    if kind == "hexahedron":
        assert sum(count.values()) == nquads
        assert list(count) == (["quad"] if order == 1 else ["quad9"])
    elif kind == "wedge":  # top and bottom quads split in two, sides stay quads
        assert sum(count.values()) == nquads + 2 * 3 * 4
    else:  # every outer quad is a pyramid's base
        assert sum(count.values()) == nquads
    assert _checks(pts, faces) == pytest.approx(1.0)
    _mid_sides_at_midpoints(pts, faces)
    # no interior face: every boundary node lies on the box's surface
    nodes = np.unique(np.concatenate([c.ravel() for _, c in faces]))
    assert np.all(np.min(np.minimum(pts[nodes], 1 - pts[nodes]), axis=1) < 1e-12)


def test_inverted_cells_still_give_outward_faces():
    pts, cells = hexa_box()
    kind, conn = cells[0]
    flipped = conn[:, [4, 5, 6, 7, 0, 1, 2, 3]]  # negative Jacobian: a mirrored numbering
    faces, _ = boundary_faces(pts, [(kind, flipped)])
    assert _checks(pts, faces) == pytest.approx(1.0)


pytest.importorskip("gmsh")
from diffsurf_cli.testing import gmsh_scenes  # noqa: E402


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("vol")
    out = {}
    for shape, order in itertools.product(("box", "cylinder"), (1, 2)):
        out[shape, order] = gmsh_scenes.volume(tmp / f"{shape}{order}.msh", shape, order=order,
                                               physical=True)
    out["all"] = gmsh_scenes.volume(tmp / "all.msh", "box", order=1)  # surfaces written too
    return out


@pytest.mark.parametrize("shape,order", [("box", 1), ("box", 2), ("cylinder", 1),
                                         ("cylinder", 2)])
def test_gmsh_tetra_volume_is_read_as_its_boundary(scenes, shape, order):
    path = scenes[shape, order]
    mesh = meshio.read(path)
    assert [b.type for b in mesh.cells] == ["tetra" if order == 1 else "tetra10"]
    target = io.read_target(path)
    assert target.boundary == {mesh.cells[0].type: len(mesh.cells[0].data)}
    assert [k for k, _ in target.cells] == ["triangle" if order == 1 else "triangle6"]
    volume = _checks(target.points, target.cells)
    # the enclosed volume is the tetras' (by the divergence theorem: outward, closed, no hole)
    tet = mesh.points[mesh.cells[0].data[:, :4]]
    cells_volume = np.sum(np.abs(np.einsum("ij,ij->i", np.cross(tet[:, 1] - tet[:, 0],
                                                                tet[:, 2] - tet[:, 0]),
                                           tet[:, 3] - tet[:, 0]))) / 6
    assert volume == pytest.approx(cells_volume, rel=1e-12)
    assert volume == pytest.approx(1.0 if shape == "box" else np.pi * 0.25, rel=0.1)
    if shape == "box":
        _mid_sides_at_midpoints(target.points, target.cells)
        nodes = target.points[target.nodes]
        assert np.all(np.min(np.minimum(nodes, 1 - nodes), axis=1) < 1e-9)
    # the boundary is the union of gmsh's own boundary faces: count by Euler (closed sphere)
    tri = sum(len(c) for _, c in target.cells)
    corners = np.unique(np.concatenate([facet_corners(c).ravel() for _, c in target.cells]))
    assert len(corners) - 3 * tri // 2 + tri == 2


def test_zone_of_the_volume_cells(scenes):
    target = io.read_target(scenes["box", 1], zone="part")
    assert target.boundary and len(target.cells) == 1


def test_a_file_with_surface_cells_keeps_them(scenes):
    """gmsh without physical groups writes the surface triangles too: they are the target
    (as before), the tetra are ignored."""
    target = io.read_target(scenes["all"])
    assert target.boundary == {} and target.ignored.get("tetra", 0) > 0


def _project(target_path, points, tmp_path, name, *extra):
    csv = tmp_path / "points.csv"
    np.savetxt(csv, points, delimiter=",", header="x,y,z", comments="")
    out = tmp_path / f"{name}.csv"
    result = run("project", target_path, csv, "-o", out, "-q", "--overwrite", *extra)
    assert result.exit_code == 0, result.stderr
    import polars as pl

    return pl.read_csv(out)


@pytest.mark.parametrize("order", [1, 2])
def test_project_on_a_volume_mesh_equals_its_surface_mesh(scenes, order, tmp_path):
    target = io.read_target(scenes["cylinder", order])
    surface = tmp_path / "surface.vtu"
    meshio.write(surface, meshio.Mesh(target.points, target.cells))
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, 2 * np.pi, 200)
    r = rng.uniform(0.45, 0.55, 200)
    x = np.column_stack([r * np.cos(theta), r * np.sin(theta), rng.uniform(0.2, 0.8, 200)])
    for method in ("diffuse", "facet"):
        a = _project(scenes["cylinder", order], x, tmp_path, "vol", "--method", method)
        b = _project(str(surface), x, tmp_path, "surf", "--method", method)
        np.testing.assert_array_equal(a["gap"].to_numpy(), b["gap"].to_numpy())
        assert (a["status"] == b["status"]).all()
        assert not a["status"].is_in(["outside", "failed"]).any()
        # outward: points outside the cylinder have positive gaps (beyond the facets' sag,
        # h^2 / 8R = 0.0225 for elements of 0.3)
        clear = np.abs(r - 0.5) > 0.03
        assert clear.sum() > 50
        assert np.all(np.sign(a["gap"].to_numpy()[clear]) == np.sign(r - 0.5)[clear])


def test_node_set_selects_boundary_faces(tmp_path):
    pts, cells = hexa_box(order=1)
    top = np.flatnonzero(pts[:, 2] > 1 - 1e-12)
    path = tmp_path / "box.inp"  # an Abaqus deck: the node set is an *NSET
    meshio.write(path, meshio.Mesh(pts, cells, point_sets={"TOP": top}))
    mesh = meshio.read(path)
    if "TOP" not in mesh.point_sets:
        pytest.skip("this meshio writes no *NSET")
    target = io.read_target(str(path), zone="TOP")
    assert [k for k, _ in target.cells] == ["quad"] and len(target.cells[0][1]) == 3 * 4
    assert np.all(target.points[target.nodes][:, 2] == 1.0)
    assert np.all(facet_area_vectors(target.points, [target.cells[0][1]])[:, 2] > 0)
