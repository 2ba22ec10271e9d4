"""Scenes meshed by gmsh's OpenCASCADE kernel for the tests of second-order cells and volume
meshes, and parts with features: each function writes a .msh file (format 2.2) and returns its
path. gmsh is a test dependency (the `test` extra), imported when a scene is meshed; the tests
skip without it."""
from __future__ import annotations

import contextlib


def _gmsh():
    """The gmsh module, or an ImportError that says how to install it."""
    try:
        import gmsh
    except ImportError as exc:
        raise ImportError("diffsurf_cli.testing.gmsh_scenes needs gmsh: "
                          "pip install 'diffsurf[test]' (or pip install gmsh)") from exc
    return gmsh


@contextlib.contextmanager
def _model(name):
    gmsh = _gmsh()
    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add(name)
        yield gmsh
    finally:
        gmsh.finalize()


def _write(path, dim, order, quads=False, incomplete=False):
    gmsh = _gmsh()
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
    with _model("sphere") as gmsh:
        gmsh.model.occ.addSphere(0, 0, 0, radius)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, order, quads, incomplete)


def volume(path, shape="box", size=0.3, order=1, physical=False):
    """A tetra volume mesh of a unit box (0..1)^3 or a cylinder (radius 0.5, height 1, axis z
    through the origin), elements of about `size`; with `physical`, only the volume cells are
    written (a physical volume group 'part'), else every entity's cells (surfaces too)."""
    with _model(shape) as gmsh:
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


# --- parts with features (tests/test_patches.py, benchmarks/feature_targets.py) ---------
def box(path, lx=2.0, ly=1.0, lz=1.0, size=0.2, order=1, quads=False, dim=2):
    """The surface (dim 2) or a volume mesh (dim 3) of a box (0..lx) x (0..ly) x (0..lz),
    elements of about `size`, of `order` 1 or 2, triangles or `quads` on the surface."""
    with _model("box") as gmsh:
        gmsh.model.occ.addBox(0, 0, 0, lx, ly, lz)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, dim, order, quads)


def fillet_box(path, lx=2.0, ly=1.0, lz=1.0, fillet=0.25, size=0.07, order=1):
    """The surface of a box (0..lx) x (0..ly) x (0..lz) with all 12 edges filleted (radius
    `fillet`: quarter cylinders, and eighth spheres at the corners), triangles of about
    `size`, of `order` 1 or 2. Each OpenCASCADE face is one entity (gmsh:geometrical)."""
    with _model("fillet_box") as gmsh:
        tag = gmsh.model.occ.addBox(0, 0, 0, lx, ly, lz)
        gmsh.model.occ.synchronize()
        edges = [e[1] for e in gmsh.model.getEntities(1)]
        gmsh.model.occ.fillet([tag], edges, [fillet], removeVolume=True)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, order)


def chamfer_box(path, chamfer=0.2, size=0.1):
    """The surface of a unit box (0..1)^3 with its 12 edges chamfered at 45° (`chamfer`
    wide), triangles of about `size`: flat faces meeting at 45° and 135° edges."""
    with _model("chamfer_box") as gmsh:
        tag = gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        edges = [e[1] for e in gmsh.model.getEntities(1)]
        surfaces = [gmsh.model.getAdjacencies(1, e)[0][0] for e in edges]
        gmsh.model.occ.chamfer([tag], edges, surfaces, [chamfer], removeVolume=True)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def torus(path, major=2.0, minor=0.5, size=0.1):
    """The surface of a torus around the z axis (radii `major` and `minor`), triangles of
    about `size`."""
    with _model("torus") as gmsh:
        gmsh.model.occ.addTorus(0, 0, 0, major, minor)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def capped_cylinder(path, radius=0.5, height=1.0, size=0.08):
    """The surface of a closed cylinder (axis z, base at the origin), triangles of about
    `size`: flat caps, a curved side, two circular sharp edges."""
    with _model("capped_cylinder") as gmsh:
        gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, height, radius)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def thin_plate(path, lx=10.0, ly=10.0, lz=2.0, top=0.4, bottom=2.5):
    """The surface of a plate (0..lx) x (0..ly) x (0..lz) meshed with triangles of about `top`
    on its top face (z = lz) and `bottom` on its bottom face (z = 0), graded on the sides."""
    with _model("thin_plate") as gmsh:
        gmsh.model.occ.addBox(0, 0, 0, lx, ly, lz)
        gmsh.model.occ.synchronize()
        for dim, tag in gmsh.model.getEntities(0):
            z = gmsh.model.getValue(0, tag, [])[2]
            gmsh.model.mesh.setSize([(dim, tag)], top if z > lz / 2 else bottom)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 1)
        return _write(path, 2, 1)


def l_block(path, size=0.15):
    """The surface of an L-shaped block: the box (0..2) x (0..1) x (0..1) less the box
    (1..2) x (0..1) x (0.5..1): convex and concave sharp edges, flat faces (a polyhedron: its
    facets are exact)."""
    with _model("l_block") as gmsh:
        a = gmsh.model.occ.addBox(0, 0, 0, 2, 1, 1)
        b = gmsh.model.occ.addBox(1, -0.1, 0.5, 1.2, 1.2, 0.6)
        gmsh.model.occ.cut([(3, a)], [(3, b)])
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def lens(path, radius=1.0, offset=1.2, size=0.1):
    """The surface of a lens: the intersection of two balls of `radius` centred at z = ±offset/2:
    two spherical caps meeting at a sharp circular edge (in the plane z = 0)."""
    with _model("lens") as gmsh:
        a = gmsh.model.occ.addSphere(0, 0, -offset / 2, radius)
        b = gmsh.model.occ.addSphere(0, 0, offset / 2, radius)
        gmsh.model.occ.intersect([(3, a)], [(3, b)])
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def holed_block(path, size=0.12):
    """A CAD-like part: the block (0..3) x (0..2) x (0..1) with a through hole of radius 0.5
    (axis z through (1.5, 1)) and its four vertical edges filleted (radius 0.3): flat faces,
    sharp straight and circular edges, a concave cylinder, convex fillets."""
    with _model("holed_block") as gmsh:
        b = gmsh.model.occ.addBox(0, 0, 0, 3, 2, 1)
        c = gmsh.model.occ.addCylinder(1.5, 1, -0.5, 0, 0, 2, 0.5)
        out, _ = gmsh.model.occ.cut([(3, b)], [(3, c)])
        gmsh.model.occ.synchronize()
        edges = []
        for _, tag in gmsh.model.getEntities(1):
            x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(1, tag)
            if abs(z1 - z0 - 1) < 1e-6 and abs(x1 - x0) < 1e-6 and abs(y1 - y0) < 1e-6 \
                    and min(abs(x0), abs(x0 - 3)) < 1e-6:
                edges.append(tag)
        gmsh.model.occ.fillet([out[0][1]], edges, [0.3], removeVolume=True)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        return _write(path, 2, 1)


def thread(path, size, radius=1.0, pitch=0.5, depth=0.25, turns=6):
    """A core cylinder of `radius` with a helical thread of triangular profile (`depth` high,
    0.8 `pitch` wide at its base) swept along a helix of `turns` turns, meshed with
    first-order triangles of about `size`; CAD faces as tags (issue 34: a threaded part)."""
    import numpy as np

    with _model("thread") as gmsh:
        occ = gmsh.model.occ
        angle = np.linspace(0, 2 * np.pi * turns, 40 * turns + 1)
        base = 0.9 * radius
        helix = occ.addBSpline([occ.addPoint(base * np.cos(a), base * np.sin(a),
                                             pitch * a / (2 * np.pi)) for a in angle])
        half = 0.4 * pitch
        p = [occ.addPoint(base, 0, -half), occ.addPoint(radius + depth, 0, 0),
             occ.addPoint(base, 0, half)]
        loop = occ.addCurveLoop([occ.addLine(p[0], p[1]), occ.addLine(p[1], p[2]),
                                 occ.addLine(p[2], p[0])])
        ridge = occ.addPipe([(2, occ.addPlaneSurface([loop]))], occ.addWire([helix]),
                            "GuidePlan")
        core = occ.addCylinder(0, 0, -pitch, 0, 0, pitch * (turns + 2), radius)
        occ.fuse([(3, core)], ridge)
        occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.model.mesh.generate(2)
        gmsh.write(str(path))
    return str(path)
