"""The curved-cell tables compiled (issue 36, `patches._cells`): `cell_coefficients` (has_cell,
cell_coef) and `hermite_midsides` are bit for bit the former numpy code's
(`tests/reference_cells_setup.py`, the oracle), byte by byte (signed zeros included), on
first-order icospheres (one patch, many, flipped, tagged, open), quad and mixed
triangle-quad tori, the sample meshes, gmsh spheres of second order (triangle6, triangle7,
quad8, quad9), gmsh fillet boxes of first and second order (CAD faces as tags), a flat box (no
table), moved targets, and corner normals made up to reach every branch (zero, along an edge,
not unit, NaN)."""
from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import reference_cells_setup as ref
from diffsurf_cli.patches.surface import (
    PatchedSurface,
    cell_coefficients,
    cell_tables,
    hermite_midsides,
)
from diffsurf_cli.testing.shapes import Torus

SAMPLES = Path(__file__).resolve().parent.parent / "sample_meshes"


def _same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _check(surf):
    """The surface's own tables, and those computed again, against the oracle's."""
    has, coef = ref.cell_coefficients(surf)
    assert _same(surf.has_cell, has) and _same(surf.cell_coef, coef)
    new_has, new_coef = cell_coefficients(surf)
    assert _same(new_has, has) and _same(new_coef, coef)
    assert _same(hermite_midsides(surf), ref.hermite_midsides(surf))
    return has


def _icosphere(sub=3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=sub)
    return np.asarray(m.vertices), np.asarray(m.faces)


def _octant(nodes, faces):
    c = nodes[faces].mean(axis=1)
    return (c[:, 0] > 0) + 2 * (c[:, 1] > 0) + 4 * (c[:, 2] > 0)


@pytest.mark.parametrize("case", ["default", "one patch", "flip", "tags", "smooth tags",
                                  "angle 180", "open", "moved"])
def test_icospheres(case):
    nodes, faces = _icosphere(3)
    kw = {}
    if case == "one patch":
        kw["feature_angle"] = None
    elif case == "flip":
        kw["flip"] = True
    elif case in ("tags", "smooth tags"):
        kw["tags"] = _octant(nodes, faces)
        kw["smooth_tags"] = case == "smooth tags"
    elif case == "angle 180":
        kw["feature_angle"] = 180.0
    elif case == "open":
        faces = faces[nodes[faces].mean(axis=1)[:, 2] > -0.3]
        used, faces = np.unique(faces, return_inverse=True)
        nodes, faces = nodes[used], faces.reshape(-1, 3)
    surf = PatchedSurface(nodes, [faces], **kw)
    assert _check(surf).all()
    if case in ("moved", "one patch"):
        rng = np.random.default_rng(7)
        moved = surf.moved(nodes * [1.0, 1.3, 0.8] + rng.normal(scale=0.01, size=nodes.shape))
        assert _check(moved).all()


def test_tori_quads_and_mixed_blocks():
    nodes, quads = Torus(1.0, 0.4).mesh_quads(24)
    _check(PatchedSurface(nodes, [quads], feature_angle=None))
    half = len(quads) // 2
    tris = np.concatenate([quads[:half, [0, 1, 2]], quads[:half, [0, 2, 3]]])
    surf = PatchedSurface(nodes, [tris, quads[half:]])
    assert _check(surf).all()
    _check(surf.moved(nodes * 1.1))


@pytest.mark.parametrize("name", ["cylinder.msh", "cylinder_tri.stl", "torus.msh",
                                  "plate_and_cylinder.msh"])
@pytest.mark.parametrize("angle", [40.0, 180.0])
def test_sample_meshes(name, angle):
    from diffsurf_cli.targets import surface_from_file

    _, surf = surface_from_file(str(SAMPLES / name), feature_angle=angle)
    assert isinstance(surf, PatchedSurface)
    assert _check(surf).any()


@pytest.mark.parametrize("kind", ["triangle6", "triangle7", "quad8", "quad9"])
def test_second_order_spheres(tmp_path, kind):
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import read_surface
    from diffsurf_cli.testing import gmsh_scenes

    opts = {"triangle6": {}, "triangle7": {}, "quad9": {"quads": True},
            "quad8": {"quads": True, "incomplete": True}}[kind]
    path = gmsh_scenes.sphere_surface(tmp_path / "s.msh", size=0.4, order=2, **opts)
    _, nodes, faces = read_surface(str(path))
    if kind == "triangle7":  # each triangle6 with its centre node, put on the sphere
        (tri6,) = faces
        centre = nodes[tri6].mean(axis=1)
        centre /= np.linalg.norm(centre, axis=1, keepdims=True)
        faces = [np.column_stack([tri6, len(nodes) + np.arange(len(tri6))])]
        nodes = np.concatenate([nodes, centre])
    surf = PatchedSurface(nodes, faces)
    assert _check(surf).all()
    _check(surf.moved(nodes * [1.0, 0.9, 1.2]))


@pytest.mark.parametrize("order", [1, 2])
def test_fillet_boxes(tmp_path, order):
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import surface_from_file
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", 2.0, 1.0, 1.0, fillet=0.15, size=0.15,
                                  order=order)
    for angle in (40.0, 180.0):
        _, surf = surface_from_file(str(path), feature_angle=angle)
        has = _check(surf)
        assert has.any() and (order == 2) == has.all()  # flat faces of first order: none


def test_flat_box_has_no_table():
    import trimesh

    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0)).subdivide()
    for angle in (40.0, None):
        surf = PatchedSurface(np.asarray(box.vertices), [np.asarray(box.faces)],
                              feature_angle=angle)
        assert not _check(surf).any() and surf.cell_coef.shape == (1, 9, 3)
        moved = surf.moved(surf.nodes * [1.0, 1.2, 0.9])
        assert not _check(moved).any()


@pytest.mark.parametrize("quads", [False, True])
def test_made_up_corner_normals(quads):
    """Every branch of the Hermite tangent: random normals of any length, zero ones, ones
    along their edge (no tangent: the straight edge), NaN; and some facets exactly flat."""
    if quads:
        nodes, faces = Torus(1.0, 0.4).mesh_quads(12)
    else:
        nodes, faces = _icosphere(2)
    surf = copy.copy(PatchedSurface(nodes, [faces]))
    rng = np.random.default_rng(3)
    F, k = faces.shape
    normal = rng.normal(size=(F, 4, 3)) * rng.uniform(0.1, 3.0, (F, 4, 1))
    normal[:, k:] = 0.0
    normal[rng.random((F, 4)) < 0.05] = 0.0
    edge = nodes[np.roll(faces, -1, axis=1)] - nodes[faces]
    along = rng.random((F, k)) < 0.1
    normal[:, :k][along] = edge[along] * rng.uniform(0.5, 2.0, (int(along.sum()), 1))
    normal[rng.random((F, 4)) < 0.01] = np.nan
    facet = surf.facet_normal[:, None, :]
    flat = rng.random(F) < 0.2                  # all corners the facet's normal: no cell
    normal[flat, :k] = np.broadcast_to(facet, (F, k, 3))[flat]
    surf.corner_normal = normal
    assert _same(hermite_midsides(surf), ref.hermite_midsides(surf))
    has, coef = ref.cell_coefficients(surf)
    new_has, new_coef = cell_coefficients(surf)
    assert _same(new_has, has) and _same(new_coef, coef)
    # which facets are curved, as the surface keeps it (`cell_tables`: `_cells.facet_curved`,
    # the same test stopping at the first curved edge), on these normals too
    assert _same(cell_tables(surf)[0], has)
    assert not has[flat].any() and has[~flat].mean() > 0.9
