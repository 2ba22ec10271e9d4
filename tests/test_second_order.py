"""Second-order surface cells (triangle6, quad8, quad9; issue 11 item 3): mid-side nodes get
the normals of their cells and count in the support, the sheet test, smooth and tune.

Scenes: a unit sphere meshed by gmsh (OpenCASCADE) with curved second-order cells, points within
±5% of it; the exact gap is |x| - 1, the facets' (FacetSurface on the corner facets) in the
same run are the peer."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")
from diffsurf_cli import io
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import cell_faces, corner_faces, node_normals
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.projection import OUTSIDE
from diffsurf_cli.testing import gmsh_scenes
from samples import run

KINDS = {"triangle6": {}, "quad9": {"quads": True}, "quad8": {"quads": True, "incomplete": True}}


@pytest.fixture(scope="module", params=list(KINDS))
def sphere(request, tmp_path_factory):
    path = gmsh_scenes.sphere_surface(tmp_path_factory.mktemp("so") / "sphere.msh",
                                      **KINDS[request.param])
    target = io.read_target(path)
    assert [kind for kind, _ in target.cells] == [request.param]
    return request.param, path, target


def _points(m=1500, seed=0):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.uniform(0.95, 1.05, m)
    return d * r[:, None], r - 1.0


def _local(target, faces):
    return [np.searchsorted(target.nodes, f) for f in faces(target.cells)]


def test_mid_side_nodes_get_their_cells_normals(sphere):
    _, _, target = sphere
    nodes = target.points[target.nodes]
    radial = nodes / np.linalg.norm(nodes, axis=1, keepdims=True)
    with_cells = node_normals(nodes, _local(target, cell_faces))
    corners = node_normals(nodes, _local(target, corner_faces))
    mid = ~np.any(corners != 0, axis=1)  # nodes in no corner facet: the mid-side ones
    assert mid.sum() > len(nodes) / 3
    # every node now has the outward normal (mesh size 0.25: facet normals within ~10 degrees)
    assert np.all(np.einsum("ij,ij->i", with_cells, radial) > np.cos(np.radians(15)))
    # corners keep the normal they had
    np.testing.assert_allclose(with_cells[~mid], corners[~mid], atol=1e-12)


def test_no_point_outside_and_10x_better_than_the_facets(sphere):
    kind, _, target = sphere
    nodes = target.points[target.nodes]
    x, exact = _points()
    diffuse = DiffuseSurface(nodes, _local(target, cell_faces)).project(x)
    facets = FacetSurface(nodes, _local(target, corner_faces)).project(x)
    assert not np.any(diffuse.status >= OUTSIDE), (kind, np.unique(diffuse.reason))
    err = np.sqrt(np.mean((diffuse.gap - exact) ** 2))
    err_facets = np.sqrt(np.mean((facets.gap - exact) ** 2))
    assert err * 10 < err_facets, (kind, err, err_facets)


def test_corner_faces_alone_still_work(sphere):
    """The Python API of corner facets is unchanged (mid-side nodes then have no normal)."""
    _, _, target = sphere
    nodes = target.points[target.nodes]
    x, exact = _points(200, seed=1)
    result = DiffuseSurface(nodes, _local(target, corner_faces)).project(x)
    good = result.status < OUTSIDE
    assert good.any()
    assert np.all(np.abs(result.gap[good] - exact[good]) < 0.05)


def test_cli_project_smooth_and_tune_on_a_second_order_target(sphere, tmp_path):
    kind, path, target = sphere
    x, exact = _points(300, seed=2)
    csv = tmp_path / "points.csv"
    np.savetxt(csv, x, delimiter=",", header="x,y,z", comments="")
    out = tmp_path / "gaps.csv"
    result = run("project", path, csv, "-o", out, "-q")
    assert result.exit_code == 0, result.stderr
    import polars as pl

    table = pl.read_csv(out)
    assert not table["status"].is_in(["outside", "failed"]).any()
    assert np.max(np.abs(table["gap"].to_numpy() - exact)) < 1e-3

    smoothed = tmp_path / "smooth.vtu"
    result = run("smooth", path, "-o", smoothed, "-q")
    assert result.exit_code == 0, result.stderr
    import meshio

    mesh = meshio.read(smoothed)
    placed = mesh.point_data["placed"] == 1
    # placed vertices lie on the sphere (the facets are 1e-2 off it between nodes)
    assert np.max(np.abs(np.linalg.norm(mesh.points[placed], axis=1) - 1)) < 1e-3
    if kind == "quad8":
        # the centre of a quad8 cell has no node: it lies about one node spacing from the
        # nearest node, at the edge of the 'off-target' test (tol.OUTSIDE_SPACINGS); a face
        # centre or two stay on the facets, reported (placed 0). Measured: 1 of 308.
        assert (~placed).sum() <= 0.01 * len(placed)
    else:
        assert placed.all()

    if kind != "triangle6":
        return  # tune takes a few seconds: once is enough
    result = run("tune", path, "--sample", "20")
    assert result.exit_code == 0, result.stderr
    lines = result.stdout.strip().splitlines()
    rows = [line.split() for line in lines[1:-1]]
    loo_rms = [float(r[2]) for r in rows]
    assert rows and np.all(np.isfinite(loo_rms)), result.stdout
    # every held-out node answered (holding out a corner once took its cells' mid-side nodes'
    # normals with it: 19 of 20 outside)
    assert all(r[6] == "0" for r in rows), result.stdout
    assert not lines[-1].endswith("none")
