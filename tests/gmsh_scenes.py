"""Scenes meshed by gmsh's OpenCASCADE kernel for the tests of second-order cells and volume
meshes: each function writes a .msh file (format 2.2) and returns its path. gmsh is a test
dependency (the `test` extra); the tests skip without it."""
from __future__ import annotations

import contextlib

import pytest

gmsh = pytest.importorskip("gmsh")


@contextlib.contextmanager
def _model(name):
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(name)
        yield
    finally:
        gmsh.finalize()


def _write(path, dim, order, quads=False, incomplete=False):
    gmsh.model.occ.synchronize()
    gmsh.option.setNumber("Mesh.RecombineAll", 1 if quads else 0)
    gmsh.option.setNumber("Mesh.SecondOrderIncomplete", 1 if incomplete else 0)
    gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
    gmsh.model.mesh.generate(dim)
    if order > 1:
        gmsh.model.mesh.setOrder(order)
    gmsh.write(str(path))
    return str(path)


def sphere_surface(path, radius=1.0, size=0.25, order=2, quads=False, incomplete=False):
    """The surface of a sphere of `radius` at the origin, elements of about `size`, curved
    second-order cells (mid-side nodes on the sphere): triangle6, quad9, or quad8 with
    `incomplete`."""
    with _model("sphere"):
        gmsh.model.occ.addSphere(0, 0, 0, radius)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, order, quads, incomplete)


def volume(path, shape="box", size=0.3, order=1, physical=False):
    """A tetra volume mesh of a unit box (0..1)^3 or a cylinder (radius 0.5, height 1, axis z
    through the origin), elements of about `size`; with `physical`, only the volume cells are
    written (a physical volume group 'part'), else every entity's cells (surfaces too)."""
    with _model(shape):
        if shape == "box":
            tag = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        else:
            tag = gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 1, 0.5)
        gmsh.model.occ.synchronize()
        if physical:
            gmsh.model.addPhysicalGroup(3, [tag], name="part")
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 3, order)
