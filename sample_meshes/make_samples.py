"""Generate the sample contact scene (units: mm), in the spirit of Chamoret et al.

A rigid half cylinder (the faceted target, radius 10, axis along z through x = 32.5,
y = 30) is pressed into the top face (y = 20) of an elastic plate 65 x 20 x 5 mm.  The
plate's top-face nodes are displaced upwards by ``0.6 exp(-((x - 32.5) / 6)^2)`` so the
nodes near x = 32.5 penetrate the cylinder by up to ~0.6 mm.  Deterministic; run with::

    python sample_meshes/make_samples.py
"""
from pathlib import Path

import meshio
import numpy as np

from diffsurf_cli.testing.shapes import Cylinder

HERE = Path(__file__).resolve().parent

RADIUS = 10.0
AXIS_XY = (32.5, 30.0)
Z_RANGE = (-2.5, 7.5)
N_AROUND = 16  # facets over the half circle (11.25 degrees each)
N_ALONG = 4

PLATE_LENGTH = 65.0
PLATE_TOP = 20.0
PLATE_THICKNESS = 5.0
PLATE_STEP = 1.25
BUMP = 0.6
BUMP_WIDTH = 6.0


def target():
    """The exact lower half cylinder (outward normals point down, towards the plate)."""
    return Cylinder(
        radius=RADIUS,
        length=Z_RANGE[1] - Z_RANGE[0],
        theta_range=(np.pi, 2.0 * np.pi),
        center=(AXIS_XY[0], AXIS_XY[1], 0.5 * (Z_RANGE[0] + Z_RANGE[1])),
    )


def plate_top():
    """Displaced top-face nodes (x fastest, 53 x 5) and quads oriented +y (out of the plate)."""
    nx = int(round(PLATE_LENGTH / PLATE_STEP)) + 1
    nz = int(round(PLATE_THICKNESS / PLATE_STEP)) + 1
    x = PLATE_STEP * np.arange(nx)
    z = PLATE_STEP * np.arange(nz)
    zz, xx = np.meshgrid(z, x, indexing="ij")  # node k = iz * nx + ix
    xx, zz = xx.ravel(), zz.ravel()
    yy = PLATE_TOP + BUMP * np.exp(-(((xx - 0.5 * PLATE_LENGTH) / BUMP_WIDTH) ** 2))
    points = np.column_stack([xx, yy, zz])
    iz, ix = np.meshgrid(np.arange(nz - 1), np.arange(nx - 1), indexing="ij")
    k = (iz * nx + ix).ravel()
    # (z, x) counter-clockwise: e_z x e_x = +e_y, out of the plate towards the cylinder
    quads = np.stack([k, k + nx, k + nx + 1, k + 1], axis=1)
    return points, quads


def _normals(points, cells):
    a = points[cells]
    if cells.shape[1] == 3:
        return np.cross(a[:, 1] - a[:, 0], a[:, 2] - a[:, 0])
    return np.cross(a[:, 2] - a[:, 0], a[:, 3] - a[:, 1])


def _tags(sizes, tags):
    return [np.full(s, t, dtype=int) for s, t in zip(sizes, tags)]


def main():
    cyl = target()
    cv, cq = cyl.mesh_quads(N_AROUND, m=N_ALONG)
    _, ct = cyl.mesh(N_AROUND, m=N_ALONG)
    # orientation checks: facet normals out of the cylinder (downwards / radial)
    for cells in (cq, ct):
        centroid = cv[cells].mean(axis=1)
        assert np.all(np.einsum("ij,ij->i", _normals(cv, cells), cyl.closest(centroid)[1]) > 0)
    pv, pq = plate_top()
    assert np.all(_normals(pv, pq)[:, 1] > 0)

    # 1. faceted rigid target, quads, Gmsh 2.2 ASCII, physical group "cylinder"
    mesh = meshio.Mesh(
        cv,
        [("quad", cq)],
        cell_data={"gmsh:physical": _tags([len(cq)], [1]),
                   "gmsh:geometrical": _tags([len(cq)], [1])},
        field_data={"cylinder": np.array([1, 2])},
    )
    meshio.write(HERE / "cylinder.msh", mesh, file_format="gmsh22", binary=False)

    # 2. same half cylinder, triangulated, binary STL
    meshio.write(HERE / "cylinder_tri.stl", meshio.Mesh(cv, [("triangle", ct)]), binary=True)

    # 3. contactor nodes
    with open(HERE / "plate.csv", "w", encoding="ascii", newline="\n") as fh:
        fh.write("id,x,y,z\n")
        for i, (x, y, z) in enumerate(pv.tolist(), start=1):
            fh.write(f"{i},{x!r},{y!r},{z!r}\n")

    # 4. both surfaces in one Gmsh file, plus line cells (the cylinder's straight edges)
    nt, nzc = N_AROUND + 1, N_ALONG + 1  # cylinder nodes: theta-major, k = i * nzc + j
    j = np.arange(N_ALONG)
    lines = np.concatenate(
        [np.stack([i * nzc + j, i * nzc + j + 1], axis=1) for i in (0, nt - 1)]
    )
    offset = len(cv)
    sizes = [len(cq), len(pq), len(lines)]
    both = meshio.Mesh(
        np.concatenate([cv, pv]),
        [("quad", cq), ("quad", pq + offset), ("line", lines)],
        cell_data={
            "gmsh:physical": _tags(sizes, [1, 2, 3]),
            "gmsh:geometrical": _tags(sizes, [1, 2, 3]),
        },
        field_data={
            "cylinder": np.array([1, 2]),
            "plate_top": np.array([2, 2]),
            "edges": np.array([3, 1]),
        },
    )
    meshio.write(HERE / "plate_and_cylinder.msh", both, file_format="gmsh22", binary=False)

    # 5. plate top face as a VTU quad mesh, with the node ids of plate.csv
    meshio.write(
        HERE / "plate.vtu",
        meshio.Mesh(pv, [("quad", pq)], point_data={"id": np.arange(1, len(pv) + 1)}),
    )

    # read back and report
    for name in ("cylinder.msh", "cylinder_tri.stl", "plate_and_cylinder.msh", "plate.vtu"):
        m = meshio.read(HERE / name)
        blocks = ", ".join(f"{b.type} x {len(b.data)}" for b in m.cells)
        size = (HERE / name).stat().st_size
        print(f"{name:24s} {size:7d} B  {len(m.points)} points, {blocks}")
    csv = np.loadtxt(HERE / "plate.csv", delimiter=",", skiprows=1)
    assert np.array_equal(csv[:, 1:], pv) and np.array_equal(csv[:, 0], np.arange(1, len(pv) + 1))
    print(f"{'plate.csv':24s} {(HERE / 'plate.csv').stat().st_size:7d} B  {len(csv)} nodes")

    _, _, d = cyl.closest(pv)
    inside = d < 0
    print(
        f"plate nodes inside the exact cylinder: {inside.sum()} of {len(pv)} "
        f"({inside.sum() // 5} per z row), max penetration {-d.min():.4f} mm"
    )
    # the facets are chords inside the exact cylinder: against the faceted target the
    # penetration is smaller by up to the sagitta R (1 - cos(pi / (2 N_AROUND)))
    print(f"facet sagitta {RADIUS * (1 - np.cos(np.pi / N_AROUND / 2)):.4f} mm")


if __name__ == "__main__":
    main()
