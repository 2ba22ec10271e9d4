"""Refinement invariance (issue 34): diffsurf on a mesh and on the same polyhedron cut finer
(facets split at their centroid, a linear refinement, quads cut into triangles), against the
exact surface, with the facets alongside.

Targets (every node on the exact surface; the cut's new nodes on its chords, or on its
curved cells):

- trimesh icospheres of radius 1: icosphere(3) with 30 facets (seeded) split at their
  centroid; icosphere(2) refined linearly (`trimesh.remesh.subdivide`);
- a trimesh torus R=2, r=0.5 of 24x8 sections: 30 centroid splits, and refined linearly;
- the sample cylinder (sample_meshes/cylinder.msh, quads, radius 10): each quad into four;
- a cylinder of quads (`testing.shapes.Cylinder`, radius 1, 16 around): each quad into four
  triangles around its centre;
- a gmsh sphere (OpenCASCADE, 3 elements per quarter circle): refined linearly; the same of
  curved second-order cells (triangle6, quad9: mid-side nodes on the sphere), each cut into
  four on its own map (`testing.refine.refine_on_map`: the new nodes on the curved cells);
- a CAD part: gmsh's box with its 12 edges filleted (`testing.gmsh_scenes.fillet_box`, radius
  0.25, triangles of 0.15), refined linearly, against the exact rounded box;
- a threaded part (`gmsh_scenes.thread`: a helical thread, pitch about three elements; issue
  34's item 2) and the same refined linearly, against its CAD meshed four times finer.

Points: 20,000 per sphere and torus (5,000 per cylinder) uniform on the exact surface (a
cylinder's middle half along its axis, the sample cylinder's lower half away from its open
edges), moved along the exact normal by uniform(-0.1, 0.1) x the radius (the tube's on the
torus); on the filleted box and the thread, uniform on the coarse facets and moved along
their normal by uniform(-0.02, 0.02) x the diagonal; the same points for a target and its
cut. Columns: RMS of (gap - exact gap); wrong
signs beyond 1e-3 of the target's diagonal; the nodes found to add no geometry
(`PatchedSurface.geometry_free`); the patches; the RMS ratio cut / uncut (the issue's
criterion: <= 1.5) and the facets' RMS (a second-order mesh's: its cells' corners, flat).

Every target is built as `build_surface(nodes, faces)` without face tags (as from an STL):
the thread's row is its STL variant, the harder of issue 34's two (without face tags, a
flank meeting the core below the feature angle is told from a fillet by its bends alone:
docs/smoothing.md, "Creases and coarse curves"); its tagged mesh is `tests/test_thread.py`'s.

    python benchmarks/refinement.py

Writes benchmarks/results/refinement.txt (the command and date at the top).
"""
from __future__ import annotations

import sys
import tempfile
from datetime import datetime
from pathlib import Path

import numpy as np
import trimesh

from diffsurf_cli.facet.surface import FacetSurface
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

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
SAMPLE = HERE.parent / "sample_meshes" / "cylinder.msh"


def subdivide(nodes, faces):
    return trimesh.remesh.subdivide(np.asarray(nodes, float), np.vstack(faces))


# -- exact surfaces -----------------------------------------------------------------------
def sphere_points(m, rng):
    n = rng.standard_normal((m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = rng.uniform(-0.1, 0.1, m)
    return n * (1 + off)[:, None], off


def torus_points(m, rng, big=2.0, r=0.5):
    psi = np.empty(0)
    while len(psi) < m:
        p = rng.uniform(0, 2 * np.pi, 2 * m)
        psi = np.concatenate([psi, p[rng.uniform(0, big + r, 2 * m) < big + r * np.cos(p)]])
    psi, phi = psi[:m], rng.uniform(0, 2 * np.pi, m)
    n = np.column_stack([np.cos(psi) * np.cos(phi), np.cos(psi) * np.sin(phi), np.sin(psi)])
    rho = big + r * np.cos(psi)
    foot = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), r * np.sin(psi)])
    off = rng.uniform(-0.1, 0.1, m) * r
    return foot + off[:, None] * n, off


def cylinder_points(m, rng, lo, hi):
    theta = rng.uniform(0, 2 * np.pi, m)
    off = rng.uniform(-0.1, 0.1, m)
    z = rng.uniform(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo), m)
    return np.column_stack([(1 + off) * np.cos(theta), (1 + off) * np.sin(theta), z]), off


# -- measure --------------------------------------------------------------------------------
def scores(surface, points, exact, floor):
    """RMS of gap - exact gap and wrong signs over the answered points (the target's
    orientation read from the median sign), and the points not answered."""
    res = surface.project(points)
    ok = (res.status < OUTSIDE) & np.isfinite(res.gap)
    gap = res.gap[ok] * np.sign(np.median(res.gap[ok] * exact[ok]))
    wrong = int(np.sum((np.sign(gap) != np.sign(exact[ok])) & (np.abs(exact[ok]) > floor)))
    return float(np.sqrt(np.mean((gap - exact[ok]) ** 2))), wrong, int((~ok).sum())


def row(name, nodes, faces, points, exact):
    floor = 1e-3 * float(np.linalg.norm(np.ptp(nodes, axis=0)))
    surf = build_surface(nodes, faces)
    rms, wrong, lost = scores(surf, points, exact, floor)
    flat = [np.asarray(f)[:, :4 if np.shape(f)[1] in (4, 8, 9) else 3] for f in faces]
    frms, fwrong, _ = scores(FacetSurface(nodes, flat), points, exact, floor)  # corners
    return dict(name=name, nodes=len(nodes), rms=rms, wrong=wrong, lost=lost,
                free=surf.geometry_free, patches=surf.npatches, facets=frms,
                fwrong=fwrong)


def pairs(tmp):
    rng = np.random.default_rng(1)
    out = []
    ico3 = trimesh.creation.icosphere(subdivisions=3)
    pts = sphere_points(20000, rng)
    out.append(("icosphere(3)", (ico3.vertices, [ico3.faces]), "30 centroid splits",
                (lambda v, f: (v, [f]))(*split_centroids(ico3.vertices, ico3.faces)), pts))
    ico2 = trimesh.creation.icosphere(subdivisions=2)
    out.append(("icosphere(2)", (ico2.vertices, [ico2.faces]), "refined linearly",
                (lambda v, f: (v, [f]))(*subdivide(ico2.vertices, [ico2.faces])), pts))
    torus = trimesh.creation.torus(major_radius=2, minor_radius=0.5, major_sections=24,
                                   minor_sections=8)
    tpts = torus_points(20000, rng)
    out.append(("torus 24x8", (torus.vertices, [torus.faces]), "30 centroid splits",
                (lambda v, f: (v, [f]))(*split_centroids(torus.vertices, torus.faces)), tpts))
    out.append(("torus 24x8", (torus.vertices, [torus.faces]), "refined linearly",
                (lambda v, f: (v, [f]))(*subdivide(torus.vertices, [torus.faces])), tpts))
    _, nodes, faces = read_surface(str(SAMPLE))
    out.append(("sample cylinder", (nodes, faces), "quads into four",
                (lambda v, f: (v, [f]))(*refine_quads(nodes, np.vstack(faces))),
                sample_cylinder_points(5000, rng)))
    cyl_nodes, quads = Cylinder(radius=1.0, length=2.0).mesh_quads(16)
    lo, hi = cyl_nodes[:, 2].min(), cyl_nodes[:, 2].max()
    out.append(("cylinder of quads 16", (cyl_nodes, [quads]), "quads into 4 triangles",
                (lambda v, f: (v, [f]))(*quads_to_triangles(cyl_nodes, quads)),
                cylinder_points(5000, rng, lo, hi)))
    path = gmsh_scenes.sphere_surface(tmp / "sphere.msh", size=np.pi / 6, order=1)
    _, gnodes, gfaces = read_surface(path)
    out.append(("gmsh sphere k=3", (gnodes, gfaces), "refined linearly",
                (lambda v, f: (v, [f]))(*subdivide(gnodes, gfaces)), pts))
    for kind, quads in (("triangle6", False), ("quad9", True)):  # the same curved cells
        path = gmsh_scenes.sphere_surface(tmp / f"{kind}.msh", size=np.pi / 6, quads=quads)
        _, gnodes, gfaces = read_surface(path)
        out.append((f"gmsh sphere k=3 {kind}", (gnodes, gfaces), "cut in four on its map",
                    (lambda v, f: (v, [f]))(*refine_on_map(gnodes, gfaces[0])), pts))
    # a CAD part: a box with its 12 edges filleted, its exact distance a rounded box's
    path = gmsh_scenes.fillet_box(tmp / "fillet.msh", size=0.15)
    _, bnodes, bfaces = read_surface(path)
    near = surface_points(bnodes, bfaces, 20000, rng)
    out.append(("gmsh filleted box", (bnodes, bfaces), "refined linearly",
                (lambda v, f: (v, [f]))(*subdivide(bnodes, bfaces)),
                (near, rounded_box(near))))
    # a threaded part (pitch about three elements) against its CAD meshed four times finer
    path = gmsh_scenes.thread(tmp / "thread.msh", 0.5 / 3)
    _, tnodes, tfaces = read_surface(path)
    _, fine_nodes, fine_faces = read_surface(gmsh_scenes.thread(tmp / "fine.msh", 0.5 / 12))
    near = surface_points(tnodes, tfaces, 20000, rng)
    out.append(("gmsh thread", (tnodes, tfaces), "refined linearly",
                (lambda v, f: (v, [f]))(*subdivide(tnodes, tfaces)),
                (near, FacetSurface(fine_nodes, fine_faces).project(near).gap)))
    return out


def surface_points(nodes, faces, count, rng, band=0.02):
    """`count` points uniform by area on the triangles `faces`, moved along their normal by
    uniform(-band, band) x the diagonal (as benchmarks/real_parts.py seeds its rows)."""
    tri = np.vstack(faces)[:, :3]
    x0, x1, x2 = (nodes[tri[:, k]] for k in range(3))
    cross = np.cross(x1 - x0, x2 - x0)
    area = np.linalg.norm(cross, axis=1)
    pick = rng.choice(len(tri), count, p=area / area.sum())
    u, v = rng.random((2, count))
    over = u + v > 1
    u[over], v[over] = 1 - u[over], 1 - v[over]
    diag = float(np.linalg.norm(np.ptp(nodes, axis=0)))
    return (x0[pick] + u[:, None] * (x1 - x0)[pick] + v[:, None] * (x2 - x0)[pick]
            + rng.uniform(-band, band, count)[:, None] * diag * (cross / area[:, None])[pick])


def rounded_box(points, size=(2.0, 1.0, 1.0), radius=0.25):
    """The signed distance to `gmsh_scenes.fillet_box`'s CAD: the box (0..size) with every
    edge and corner rounded by `radius` (quarter cylinders, eighth spheres)."""
    half = np.asarray(size) / 2
    q = np.abs(points - half) - (half - radius)
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0) - radius


def main() -> int:
    lines = [f"# `python benchmarks/refinement.py` on {datetime.now():%Y-%m-%d %H:%M}", "",
             "| target | cut | nodes | RMS | wrong | lost | free | patches | RMS cut/uncut "
             "| facets' RMS | facets' wrong |", "|---" * 11 + "|"]
    with tempfile.TemporaryDirectory() as tmp:
        for name, uncut, cut, refined, (points, exact) in pairs(Path(tmp)):
            a = row(name, *uncut, points, exact)
            b = row(name, *refined, points, exact)
            for label, r in (("-", a), (cut, b)):
                ratio = "" if r is a else f"{b['rms'] / a['rms']:.2f}"
                lines.append(f"| {name} | {label} | {r['nodes']} | {r['rms']:.3e} | "
                             f"{r['wrong']} | {r['lost']} | {r['free']} | {r['patches']} | "
                             f"{ratio} | {r['facets']:.3e} | {r['fwrong']} |")
    text = "\n".join(lines) + "\n"
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "refinement.txt").write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
