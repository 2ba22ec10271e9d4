"""Write sample_meshes/torus.msh: an unstructured triangle mesh of a torus, made with Gmsh.

An OpenCASCADE torus (core radius R = 10, tube radius r = 3, axis z, centre at the origin),
surface-meshed with triangles of size about 1.2 (mesh size 1.2 at every point), written as
Gmsh 2.2 ASCII with the surface as physical group "torus" (tag 1). Facet normals point out of
the solid torus, as diffsurf expects of a target.

Unlike `shapes.Torus.mesh` (a structured grid, anisotropic on the inner equator),
this is the kind of mesh a user brings: unstructured, nearly isotropic, with irregular
valences. It is the closed curved target of `diffsurf tune` in the issue-5 report:

    python sample_meshes/make_torus_gmsh.py      # needs `pip install gmsh`
    diffsurf tune sample_meshes/torus.msh

Deterministic for a given Gmsh version (the report used gmsh 4.15.2).
"""
from __future__ import annotations

import os
import sys

import numpy as np

MAJOR, MINOR = 10.0, 3.0
SIZE = 1.2
HERE = os.path.dirname(os.path.abspath(__file__))


def make(path: str) -> None:
    import gmsh

    gmsh.initialize(["-noenv"])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("torus")
        solid = gmsh.model.occ.addTorus(0, 0, 0, MAJOR, MINOR)
        gmsh.model.occ.synchronize()
        surfaces = [tag for dim, tag in gmsh.model.getBoundary([(3, solid)], oriented=False)]
        gmsh.model.addPhysicalGroup(2, surfaces, tag=1, name="torus")
        gmsh.option.setNumber("Mesh.MeshSizeMin", SIZE)
        gmsh.option.setNumber("Mesh.MeshSizeMax", SIZE)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay: near-isotropic triangles
        gmsh.option.setNumber("Mesh.RandomSeed", 1)
        gmsh.model.mesh.generate(2)
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.option.setNumber("Mesh.Binary", 0)
        gmsh.option.setNumber("Mesh.SaveAll", 0)  # only the physical group's elements
        gmsh.write(path)
    finally:
        gmsh.finalize()


def check(path: str) -> None:
    """Read the file back: every node on the exact torus, facets facing out of the solid."""
    import meshio

    mesh = meshio.read(path)
    tri = np.concatenate([c.data for c in mesh.cells if c.type == "triangle"])
    nodes = np.unique(tri)
    p = mesh.points
    rho = np.hypot(p[nodes, 0], p[nodes, 1])
    off = np.abs(np.hypot(rho - MAJOR, p[nodes, 2]) - MINOR)
    a, b, c = p[tri[:, 0]], p[tri[:, 1]], p[tri[:, 2]]
    normal = np.cross(b - a, c - a)
    centre = (a + b + c) / 3
    e = np.column_stack([centre[:, 0], centre[:, 1], np.zeros(len(centre))])
    e *= MAJOR / np.linalg.norm(e, axis=1, keepdims=True)
    outward = np.einsum("ij,ij->i", normal, centre - e) > 0
    edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    length = np.linalg.norm(p[edges[:, 0]] - p[edges[:, 1]], axis=1)
    print(f"{path}: {len(nodes)} nodes, {len(tri)} triangles, edge length "
          f"{length.min():.2f}..{length.max():.2f} (mean {length.mean():.2f}); "
          f"largest node distance to the exact torus {off.max():.1e}; "
          f"{outward.sum()} of {len(tri)} facets face out; {os.path.getsize(path)} bytes")
    if not outward.all():
        sys.exit(f"{path}: {len(tri) - outward.sum()} facets face into the torus")


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "torus.msh")
    make(out)
    check(out)
