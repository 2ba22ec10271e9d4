"""The facets' hierarchy's oriented bounds (`facet._engine.oriented_bounds`, issue 31): every
node's cylinder holds every corner of its facets, and the search pruned by them gives the
answers of the search pruned by boxes alone, bit for bit."""
import numpy as np
import pytest
import trimesh

from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.testing.shapes import Cylinder, Torus


def _targets():
    ico = trimesh.creation.icosphere(subdivisions=4)
    yield "icosphere", np.asarray(ico.vertices), [np.asarray(ico.faces, np.int64)]
    nodes, quads = Cylinder(radius=1.0, length=3.0).mesh_quads(24, 12)
    yield "cylinder quads", nodes, [quads]
    nodes, faces = Torus(major=2.0, minor=0.5).mesh(24)
    yield "torus", nodes, [faces]
    rng = np.random.default_rng(0)  # a soup facing every way: loose bounds, still bounds
    soup = rng.normal(size=(300, 3))
    yield "soup", soup, [rng.integers(0, 300, (200, 3))]


@pytest.mark.parametrize("name,nodes,faces", list(_targets()), ids=lambda v: v
                         if isinstance(v, str) else "")
def test_every_node_holds_its_facets(name, nodes, faces):
    t = FacetSurface(nodes, faces, check_winding=False)._tables
    cyl, link, corner, kind = t["cyl"], t["link"], t["corner"], t["kind"]
    lo = np.zeros(len(link), np.int64)
    hi = np.zeros(len(link), np.int64)
    for n in range(len(link) - 1, -1, -1):
        if link[n, 1] > 0:
            lo[n], hi[n] = link[n, 0], link[n, 0] + link[n, 1]
        else:
            lo[n] = min(lo[n + 1], lo[link[n, 0]])
            hi[n] = max(hi[n + 1], hi[link[n, 0]])
    for n in range(len(link)):
        c, axis, rho, half = cyl[n, :3], cyl[n, 3:6], cyl[n, 6], cyl[n, 7]
        assert abs(np.linalg.norm(axis) - 1) < 1e-12
        P = np.concatenate([corner[s, :kind[s]] for s in range(lo[n], hi[n])]) - c
        z = P @ axis
        lat = np.linalg.norm(P - z[:, None] * axis, axis=1)
        assert (np.abs(z) <= half).all() and (lat <= rho).all(), (name, n)


@pytest.mark.parametrize("name,nodes,faces", list(_targets())[:3], ids=lambda v: v
                         if isinstance(v, str) else "")
def test_answers_are_those_of_the_boxes(name, nodes, faces):
    rng = np.random.default_rng(1)
    scale = np.ptp(nodes, axis=0).max()
    points = np.concatenate([nodes[rng.integers(0, len(nodes), 3000)]
                             + rng.normal(size=(3000, 3)) * 0.05 * scale,
                             rng.normal(size=(200, 3)) * 5 * scale])
    surface = FacetSurface(nodes, faces)
    a = surface.project(points)
    del surface._tables["cyl"]  # the search by boxes alone
    surface._engine = None
    b = surface.project(points)
    for field in ("gap", "normal", "proximal_point", "facet", "status"):
        assert np.array_equal(getattr(a, field), getattr(b, field), equal_nan=True), field
