"""The guard's tables from the compiled pass (`patches/_guard.pyx`, issue 36) are bit for bit
the former numpy's (tests/reference_guard.py): the corner normals, edge lengths and bends
(`corner_normals`) and the guard's bounds (`guard_bounds`), which decide which answers the guard
takes, on spheres (noisy, open, flipped, moved), quads, second-order cells, tagged CAD targets
(smooth_tags or not), the sample meshes and degenerate facets."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import reference_guard as ref
from diffsurf_cli.patches import surface as _surface
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.testing.shapes import Cylinder, Sphere, Torus

SAMPLES = Path(__file__).resolve().parent.parent / "sample_meshes"


def _bits(a) -> bytes:
    """The bytes of an array: -0 differs from +0, a NaN equals itself."""
    a = np.ascontiguousarray(a)
    return a.dtype.str.encode() + str(a.shape).encode() + a.tobytes()


def _check(surf):
    """surf's tables against the oracle's, computed from the same inputs."""
    for name, new, old in zip(("corner_normal", "edge_length", "edge_bend"),
                              _surface.corner_normals(surf), ref.corner_normals(surf)):
        assert _bits(new) == _bits(old), name
        assert _bits(getattr(surf, name)) == _bits(old), name
    names = ("gap_bound", "gap_lo", "gap_hi", "normal_angle", "normal_turn")
    for name, new, old in zip(names, _surface.guard_bounds(surf), ref.guard_bounds(surf)):
        assert _bits(new) == _bits(old), name
        assert _bits(getattr(surf, name)) == _bits(old), name
    assert _bits(_surface.support_floor(surf)) == _bits(ref.support_floor(surf))


def _icosphere(sub, noise=0.0, seed=0):
    trimesh = pytest.importorskip("trimesh")
    m = trimesh.creation.icosphere(subdivisions=sub)
    nodes = np.array(m.vertices)
    if noise:
        h = np.linalg.norm(nodes[m.edges[:, 0]] - nodes[m.edges[:, 1]], axis=1).mean()
        nodes += np.random.default_rng(seed).normal(scale=noise * h, size=nodes.shape)
    return nodes, np.array(m.faces)


@pytest.mark.parametrize("angle", [30.0, None, 10.0, 180.0])
@pytest.mark.parametrize("noise", [0.0, 0.2])
def test_icospheres(angle, noise):
    nodes, faces = _icosphere(3, noise)
    _check(PatchedSurface(nodes, faces, feature_angle=angle))


@pytest.mark.parametrize("flip", [False, True])
def test_open_flipped_and_moved(flip):
    """A hemisphere (open edges: the envelope on either side), flipped or not, and moved."""
    nodes, faces = _icosphere(3, 0.1, seed=3)
    keep = nodes[faces].mean(axis=1)[:, 2] > 0.1
    surf = PatchedSurface(nodes, faces[keep], flip=flip, check_winding=False)
    assert (surf.edge_class == _surface.OPEN_EDGE).any()
    _check(surf)
    moved = surf.moved(nodes + np.random.default_rng(5).normal(scale=0.02, size=nodes.shape))
    _check(moved)
    _check(moved.moved(nodes * 1.5))


def test_degenerate_facets_and_coincident_nodes():
    """A seam of coincident nodes (one node by identity), a zero-area facet, a repeated
    corner, a facet whose nodes coincide."""
    nodes, faces = _icosphere(2, 0.05, seed=1)
    n = len(nodes)
    dup = np.arange(0, n, 3)
    nodes = np.concatenate([nodes, nodes[dup]])            # the copies: same identity
    seam = np.isin(faces[:, 0], dup)
    faces[seam, 0] = n + np.searchsorted(dup, faces[seam, 0])
    extra = np.array([[0, 0, 1], [2, 2, 2], [faces[0, 0], faces[0, 1], faces[0, 0]]])
    nodes = np.concatenate([nodes, nodes[[5, 5, 5]]])       # three nodes at one place
    extra = np.concatenate([extra, [[len(nodes) - 3, len(nodes) - 2, len(nodes) - 1]]])
    surf = PatchedSurface(nodes, np.concatenate([faces, extra]), check_winding=False)
    _check(surf)
    _check(surf.moved(nodes[::-1].copy()))


@pytest.mark.parametrize("shape", ["cylinder-quads", "torus-quads", "torus-triangles",
                                   "sphere-triangles", "mixed"])
def test_shapes(shape):
    name, kind = shape.split("-") if "-" in shape else (shape, "")
    if name == "mixed":  # a triangle block and a quad block in one target
        nodes, quads = Cylinder(radius=1.0, length=2.0).mesh_quads(8)
        tri = np.concatenate([quads[::2, [0, 1, 2]], quads[::2, [0, 2, 3]]])
        surf = PatchedSurface(nodes, [tri, quads[1::2]], feature_angle=None)
    else:
        obj = {"cylinder": Cylinder(radius=1.0, length=2.0), "torus": Torus(1.0, 0.4),
               "sphere": Sphere()}[name]
        build = obj.mesh_quads if kind == "quads" else obj.mesh
        nodes, faces = build(12)
        nodes = nodes + np.random.default_rng(2).normal(scale=1e-3, size=nodes.shape)
        surf = PatchedSurface(nodes, faces, check_winding=False)
    _check(surf)
    _check(surf.moved(surf.nodes * [1.0, 2.0, 0.5]))


@pytest.mark.parametrize("name", ["cylinder.msh", "cylinder_tri.stl", "torus.msh",
                                  "plate_and_cylinder.msh"])
@pytest.mark.parametrize("smooth_tags", [False, True])
def test_sample_meshes(name, smooth_tags):
    from diffsurf_cli.targets import read_surface

    target, nodes, faces = read_surface(str(SAMPLES / name))
    tags = None if target.tags is None else np.concatenate(target.tags)
    if smooth_tags and tags is None:
        pytest.skip("no tags")
    surf = PatchedSurface(nodes, faces, tags=tags, smooth_tags=smooth_tags)
    _check(surf)
    _check(PatchedSurface(nodes, faces, tags=tags, smooth_tags=smooth_tags, flip=True,
                          feature_angle=None, check_winding=False))


@pytest.mark.parametrize("order", [1, 2])
def test_fillet_box_tags(order, tmp_path):
    """A CAD-like box with fillets (26 tagged faces), first and second order."""
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import read_surface
    from diffsurf_cli.testing import gmsh_scenes

    path = gmsh_scenes.fillet_box(tmp_path / "f.msh", size=0.25, order=order)
    target, nodes, faces = read_surface(str(path))
    tags = np.concatenate(target.tags)
    for kw in ({"tags": tags, "smooth_tags": True}, {"tags": tags}, {},
               {"feature_angle": 180.0, "tags": tags, "smooth_tags": True},
               {"tags": tags.astype(float) / 2, "smooth_tags": True}):
        surf = PatchedSurface(nodes, faces, **kw)
        _check(surf)
    _check(surf.moved(nodes + 0.01 * np.sin(7 * nodes)))


@pytest.mark.parametrize("quads", [False, True])
def test_second_order_spheres(quads, tmp_path):
    pytest.importorskip("gmsh")
    from diffsurf_cli.targets import read_surface
    from diffsurf_cli.testing import gmsh_scenes

    for incomplete in (False, True) if quads else (False,):
        path = gmsh_scenes.sphere_surface(tmp_path / f"s{incomplete}.msh", size=0.4, order=2,
                                          quads=quads, incomplete=incomplete)
        _, nodes, faces = read_surface(str(path))
        surf = PatchedSurface(nodes, faces, feature_angle=None)
        _check(surf)
        _check(surf.moved(nodes * 1.1))


def test_ring_index_types():
    """The ring's CSR in int32 (a scipy matrix's) or int64 (past 2^31 ring entries) gives the
    same bounds."""
    from types import SimpleNamespace

    nodes, faces = _icosphere(2, 0.1)
    surf = PatchedSurface(nodes, faces, feature_angle=20.0)
    ring = surf.ring
    for dtype in (np.int32, np.int64):
        surf.ring = SimpleNamespace(indptr=np.asarray(ring.indptr, dtype),
                                    indices=np.asarray(ring.indices, dtype))
        _check(surf)
