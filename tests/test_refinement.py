"""Refinement invariance (issue 34, items 1 and 3): the smooth surface is a function of the
polyhedron, not of how its flat facets are cut.

A node that adds no geometry (in the plane of a facet cut in pieces, on a straight side
of one: `segment.geometry_free`) is left out of the diffuse surfaces' fits, which are fitted
over the polyhedron's own facets there, and makes no flat face; the guard bounds the smooth
surface by the sags of those facets. Measured against exact references, 20,000 points within
±0.1 radius of the sphere (±1 mm of the sample cylinder's radius of 10), as the issue did:

- an icosphere(3) with 30 facets split at their centroid: RMS gap error 4.5e-4 against 3.1e-5
  unsplit before (31 patches: each split facet a flat face);
- an icosphere(2) refined linearly (trimesh.remesh.subdivide): 9.3e-3 against 5.3e-4;
- the sample cylinder's quads refined linearly into four: 0.035 (the facets') against 6.8e-4;
- a cylinder's quads cut into four triangles around their centre;
- a gmsh sphere of curved second-order cells (triangle6, quad9, quad8), each cut in four on
  its own map (`refine.refine_on_map`: the same curved cells): triangle6 1.52x the RMS of
  the uncut mesh before at π/8 (the fit pulled to the cells' O(h³) error); its new nodes are
  found (`segment.cut_on_map`) and the diffuse surface is the uncut mesh's. A mesher's
  refinement that moved them onto the sphere added geometry: none found.

Genuine flat faces stay exact (a gmsh box refined linearly: its faces are bounded by sharp
edges), and the command line says what it did on stderr.
"""
from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np
import pytest

from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.projection import OUTSIDE
from diffsurf_cli.targets import build_surface, read_surface
from diffsurf_cli.testing import gmsh_scenes
from diffsurf_cli.testing.refine import (
    quads_to_triangles,
    refine_on_map,
    refine_quads,
    sample_cylinder_points,
    split_centroids,
)
from diffsurf_cli.testing.shapes import Cylinder
from samples import run

trimesh = pytest.importorskip("trimesh")

CYLINDER = Path(__file__).resolve().parent.parent / "sample_meshes" / "cylinder.msh"


def sphere_points(m=20000, seed=1):
    rng = np.random.default_rng(seed)
    n = rng.standard_normal((m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    offset = rng.uniform(-0.1, 0.1, m)
    return n * (1 + offset)[:, None], offset


def cylinder_points(m=5000, seed=2):
    """Around the sample cylinder, away from its open edges (`refine.sample_cylinder_points`)."""
    return sample_cylinder_points(m, np.random.default_rng(seed))


def scores(surface, points, exact, floor):
    """(RMS of gap - exact gap, wrong signs where |exact| > floor), every point answered;
    the target's orientation (outward or inward normals) read from the median sign."""
    res = surface.project(points)
    assert np.all(res.status < OUTSIDE) and np.all(np.isfinite(res.gap))
    gap = res.gap * np.sign(np.median(res.gap * exact))
    wrong = int(np.sum((np.sign(gap) != np.sign(exact)) & (np.abs(exact) > floor)))
    return float(np.sqrt(np.mean((gap - exact) ** 2))), wrong


def test_split_icosphere():
    """30 centroid splits: as accurate as the unsplit mesh (14.5x worse before), no more
    wrong signs, one patch (31 before: each split facet a flat face), 30 nodes found."""
    mesh = trimesh.creation.icosphere(subdivisions=3)
    nodes, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    points, exact = sphere_points()
    floor = 2e-3 * np.sqrt(3)
    rms0, wrong0 = scores(build_surface(nodes, [faces]), points, exact, floor)
    split = build_surface(*(lambda n, f: (n, [f]))(*split_centroids(nodes, faces)))
    rms, wrong = scores(split, points, exact, floor)
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    assert split.npatches == 1
    assert split.geometry_free == 30


def test_refined_icosphere():
    """An icosphere(2) refined linearly: RMS within 1.5x the unrefined mesh's (17.6x before,
    0.79x the facets')."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    nodes, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    points, exact = sphere_points()
    floor = 2e-3 * np.sqrt(3)
    rms0, wrong0 = scores(build_surface(nodes, [faces]), points, exact, floor)
    fine_nodes, fine_faces = trimesh.remesh.subdivide(nodes, faces)
    refined = build_surface(fine_nodes, [fine_faces])
    rms, wrong = scores(refined, points, exact, floor)
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    assert refined.geometry_free == len(fine_nodes) - len(nodes)  # every new node


def test_refined_sample_cylinder():
    """The sample cylinder's quads refined into four: RMS within 1.5x the unrefined mesh's
    (51x before: the facets' own, each strip between two rulings a flat face). The new
    nodes on the rulings are on the cylinder and stay; those inside the strips go."""
    _, nodes, faces = read_surface(str(CYLINDER))
    points, exact = cylinder_points()
    floor = 1e-3 * np.linalg.norm(nodes.max(axis=0) - nodes.min(axis=0))
    rms0, wrong0 = scores(build_surface(nodes, faces), points, exact, floor)
    fine_nodes, quads = refine_quads(nodes, np.vstack(faces))
    refined = build_surface(fine_nodes, [quads])
    rms, wrong = scores(refined, points, exact, floor)
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    assert refined.geometry_free == 16 * 5 + 64  # the circumferential middles, the centres



def torus_points(m=20000, seed=3, big=2.0, r=0.5):
    """Uniform on the torus (R=2, r=0.5) by area, moved along its normal by ±0.1 r: (points,
    exact signed distances)."""
    rng = np.random.default_rng(seed)
    psi = np.empty(0)
    while len(psi) < m:
        p = rng.uniform(0, 2 * np.pi, 2 * m)
        psi = np.concatenate([psi, p[rng.uniform(0, big + r, 2 * m) < big + r * np.cos(p)]])
    psi, phi = psi[:m], rng.uniform(0, 2 * np.pi, m)
    normal = np.column_stack([np.cos(psi) * np.cos(phi), np.cos(psi) * np.sin(phi),
                              np.sin(psi)])
    rho = big + r * np.cos(psi)
    foot = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), r * np.sin(psi)])
    offset = rng.uniform(-0.1, 0.1, m) * r
    return foot + offset[:, None] * normal, offset


def test_refined_coarse_torus():
    """A torus of 8 facets around its tube (45° bends: a coarse smooth curve, one surface)
    refined linearly: one surface still, RMS within 1.5x the unrefined mesh's (1.7x before,
    the facets' own: 192 patches, each original quad a flat face, its bends creases, the
    refined facets' vertex rings not reaching the next bend). The crease rule reads the
    bends over the polyhedron's facets (`segment.facet_units`): every new node is found."""
    mesh = trimesh.creation.torus(major_radius=2, minor_radius=0.5, major_sections=24,
                                  minor_sections=8)
    nodes, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    points, exact = torus_points()
    floor = 1e-3 * np.linalg.norm(np.ptp(nodes, axis=0))
    coarse = build_surface(nodes, [faces])
    rms0, wrong0 = scores(coarse, points, exact, floor)
    fine_nodes, fine_faces = trimesh.remesh.subdivide(nodes, faces)
    refined = build_surface(fine_nodes, [fine_faces])
    rms, wrong = scores(refined, points, exact, floor)
    assert coarse.npatches == refined.npatches == 1
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    assert refined.geometry_free == len(fine_nodes) - len(nodes)

def test_quads_cut_into_triangles():
    """A cylinder's quads cut into four triangles around their centre (a mesher's quad to
    triangle conversion): as accurate as the quads."""
    shape = Cylinder(radius=1.0, length=2.0)
    nodes, quads = shape.mesh_quads(16)
    points, exact = cylinder_points_of(nodes)
    floor = 1e-3 * np.linalg.norm(nodes.max(axis=0) - nodes.min(axis=0))
    rms0, wrong0 = scores(build_surface(nodes, [quads]), points, exact, floor)
    cut = build_surface(*(lambda n, f: (n, [f]))(*quads_to_triangles(nodes, quads)))
    rms, wrong = scores(cut, points, exact, floor)
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    assert cut.geometry_free == len(quads)


def cylinder_points_of(nodes, m=5000, seed=4):
    """Around a cylinder of radius 1 about the z axis, away from its ends."""
    rng = np.random.default_rng(seed)
    lo, hi = nodes[:, 2].min(), nodes[:, 2].max()
    theta = rng.uniform(0, 2 * np.pi, m)
    offset = rng.uniform(-0.1, 0.1, m)
    r = 1 + offset
    z = rng.uniform(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo), m)
    return np.column_stack([r * np.cos(theta), r * np.sin(theta), z]), offset


def test_flat_faces_stay_exact(tmp_path):
    """A gmsh box refined linearly (each triangle into four): its faces are bounded by
    sharp edges, genuine faces: no node is geometry-free, and points over a face get its
    plane's distance exactly."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.testing import gmsh_scenes

    _, nodes, faces = read_surface(gmsh_scenes.box(tmp_path / "box.msh", size=0.3))
    fine_nodes, fine_faces = trimesh.remesh.subdivide(nodes, np.vstack(faces))
    surf = build_surface(fine_nodes, [fine_faces])
    assert surf.geometry_free == 0
    rng = np.random.default_rng(5)
    m = 2000
    points = np.column_stack([rng.uniform(0.2, 1.8, m), rng.uniform(0.2, 0.8, m),
                              1.0 + rng.uniform(-0.05, 0.05, m)])
    res = surf.project(points)
    assert np.max(np.abs(np.abs(res.gap) - np.abs(points[:, 2] - 1.0))) < 1e-12


def test_note_on_stderr_and_in_the_api(tmp_path):
    """The command line says how many nodes add no geometry and what it did (one line on
    stderr); the surface declares it (`PatchedSurface.geometry_free`)."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    nodes, faces = split_centroids(np.asarray(mesh.vertices), np.asarray(mesh.faces), 12)
    target = tmp_path / "split.msh"
    meshio.write(str(target), meshio.Mesh(nodes, [("triangle", faces)]), file_format="gmsh22",
                 binary=False)
    surf = build_surface(nodes, [faces])
    assert isinstance(surf, PatchedSurface) and surf.geometry_free == 12
    points = tmp_path / "points.csv"
    points.write_text("x,y,z\n0.1,0.2,1.05\n")
    result = run("project", target, points, "-o", tmp_path / "out.csv")
    assert result.exit_code == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if "add no geometry" in line]
    assert len(lines) == 1 and "12 nodes add no geometry" in lines[0]


def test_moved_and_contact_element_on_a_refined_target():
    """A refined target moved rigidly answers as at its reference positions, moved, at the
    moved points (the facets on all their nodes; a moved target's diffuse surface on all of
    them too, those that add no geometry lifted onto the reference surface: within 1e-3 of
    the reference's answers, tests/test_moved_targets.py), and the rigid target's contact
    element's gap is the projection's, its nodes the reference surface's: none of those that
    add no geometry."""
    from diffsurf_cli.element.element import contact

    mesh = trimesh.creation.icosphere(subdivisions=2)
    nodes, faces = trimesh.remesh.subdivide(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    surf = build_surface(nodes, [faces])
    free = np.flatnonzero(surf.refinement.free)
    assert len(free) == len(nodes) - len(mesh.vertices)
    points, _ = sphere_points(500, seed=7)
    shift = np.array([0.3, -0.2, 0.1])
    res = surf.project(points)
    here = surf.moved(nodes).project(points)
    moved = surf.moved(nodes + shift).project(points + shift)
    np.testing.assert_allclose(moved.gap, here.gap, rtol=0, atol=1e-12)
    np.testing.assert_allclose(here.gap, res.gap, rtol=0, atol=1e-3)
    near = np.flatnonzero(np.abs(res.gap) < 0.05)
    c = contact(surf, points[near])
    np.testing.assert_allclose(c.gap, res.gap[near][c.contactor], rtol=0, atol=1e-13)
    used = c.nodes[c.nodes >= 0]
    assert len(used) and not np.isin(used, free).any()


SECOND_ORDER = {"triangle6": {}, "quad9": {"quads": True},
                "quad8": {"quads": True, "incomplete": True}}


@pytest.mark.parametrize("kind, size", [("triangle6", np.pi / 6), ("triangle6", np.pi / 8),
                                        ("quad9", np.pi / 6), ("quad9", np.pi / 8),
                                        ("quad8", np.pi / 6)])
def test_second_order_cut_on_its_map(tmp_path, kind, size):
    """A gmsh sphere of curved second-order cells, each cut into four on its own map: every
    new node adds no geometry, the diffuse surface is the uncut mesh's (to round-off), and
    the answers are within 1.5x the uncut RMS with no more wrong signs (triangle6 at π/8:
    1.52x before; no node found before on any)."""
    path = gmsh_scenes.sphere_surface(tmp_path / "s.msh", size=size, order=2,
                                      **SECOND_ORDER[kind])
    _, nodes, faces = read_surface(path)
    assert len(faces) == 1
    fine_nodes, fine = refine_on_map(nodes, faces[0])
    coarse, refined = build_surface(nodes, faces), build_surface(fine_nodes, [fine])
    assert coarse.npatches == refined.npatches == 1
    assert refined.geometry_free == len(fine_nodes) - len(nodes)  # every new node
    points, exact = sphere_points()
    floor = 2e-3 * np.sqrt(3)
    rms0, wrong0 = scores(coarse, points, exact, floor)
    rms, wrong = scores(refined, points, exact, floor)
    assert rms <= 1.5 * rms0
    assert wrong <= wrong0
    np.testing.assert_allclose(refined.surfaces[0].project(points).gap,
                               coarse.surfaces[0].project(points).gap, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", list(SECOND_ORDER))
def test_second_order_moved_onto_the_cad_adds_geometry(tmp_path, kind):
    """The same cut with its new nodes moved onto the sphere (a mesher's refinement with
    the CAD): they are off the parent's map by the cell's error, geometry: none found."""
    path = gmsh_scenes.sphere_surface(tmp_path / "s.msh", size=np.pi / 6, order=2,
                                      **SECOND_ORDER[kind])
    _, nodes, faces = read_surface(path)
    fine_nodes, fine = refine_on_map(
        nodes, faces[0], move=lambda x: x / np.linalg.norm(x, axis=1, keepdims=True))
    assert build_surface(fine_nodes, [fine]).geometry_free == 0


def test_second_order_flat_grid_stays():
    """A flat regular grid of quad9 (and the same cut in four on its map) is four cells of a
    larger one many ways over: a flat face's cells, left as they are (no node found; its
    plane exact)."""
    m = 6  # cells a side
    t = np.linspace(0.0, 1.0, 2 * m + 1)
    x, y = np.meshgrid(t, t, indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    at = np.arange(x.size).reshape(x.shape)
    i, j = (a.ravel() for a in np.meshgrid(np.arange(m) * 2, np.arange(m) * 2, indexing="ij"))
    quads = np.column_stack([at[i, j], at[i + 2, j], at[i + 2, j + 2], at[i, j + 2],
                             at[i + 1, j], at[i + 2, j + 1], at[i + 1, j + 2], at[i, j + 1],
                             at[i + 1, j + 1]])
    rng = np.random.default_rng(5)
    points = np.column_stack([rng.uniform(0.2, 0.8, (200, 2)), rng.uniform(-0.05, 0.05, 200)])
    for target in ((nodes, quads), refine_on_map(nodes, quads)):
        surf = build_surface(target[0], [target[1]])
        assert surf.geometry_free == 0
        res = surf.project(points)
        np.testing.assert_allclose(np.abs(res.gap), np.abs(points[:, 2]), rtol=0, atol=1e-12)
