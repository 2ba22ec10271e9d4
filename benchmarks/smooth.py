"""Vertex error of `smooth` against the exact surface: facets, diffsurf variants, MeshLab APSS.

Every shape is meshed coarsely, refined uniformly (2 levels), and its refined vertices are
(a) left on the facets, (b) placed on the diffuse surface by `diffsurf_cli.smooth` with several
engine settings, and (c) projected by MeshLab's APSS (pymeshlab, if installed) onto the MLS
surface of the same original nodes. A last APSS row lets MeshLab subdivide by itself
(maxsubdivisions=2), on its own vertex set. Errors are distances to the exact surface.

    python benchmarks/smooth.py
"""
from __future__ import annotations

import time

import numpy as np

from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.smooth import refine, smooth
from diffsurf_cli.testing import shapes

LEVELS = 2
VARIANTS = {
    "diffsurf default": {},
    "diffsurf singular": {"weight": "singular"},
    "diffsurf cubic": {"basis": "cubic"},
    "diffsurf recentre": {"recentre": True},
}
CASES = [
    ("sphere", shapes.Sphere(), 4),
    ("sphere", shapes.Sphere(), 8),
    ("half cylinder (open)", shapes.Cylinder(theta_range=(np.pi, 2 * np.pi)), 8),
    ("half cylinder (open)", shapes.Cylinder(theta_range=(np.pi, 2 * np.pi)), 16),
    ("torus", shapes.Torus(), 32),
    ("torus", shapes.Torus(), 64),
]


def error(shape, points):
    return np.abs(shape.closest(points)[2])


def apss(vertices, faces, proxy_vertices, proxy_faces, subdivisions=0):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=proxy_vertices, face_matrix=proxy_faces))
    ms.set_current_mesh(0)
    # APSS needs a per-vertex radius on the point set first, or it crashes
    ms.compute_custom_radius_scalar_attribute_per_vertex(nbneighbors=16)
    start = time.perf_counter()
    ms.compute_mls_projection_apss(controlmesh=0, proxymesh=1, maxsubdivisions=subdivisions)
    elapsed = time.perf_counter() - start
    ms.set_current_mesh(1)
    return ms.current_mesh().vertex_matrix(), elapsed


def main():
    try:
        import pymeshlab  # noqa: F401  (only probing whether APSS is available)
        have_apss = True
    except ImportError:
        have_apss = False
        print("pymeshlab not installed: APSS rows skipped (pip install pymeshlab)\n")
    print("| shape | n | nodes | refined vertices | method | max error | RMS error "
          "| vs facets (max) | time s |")
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|")
    for name, shape, n in CASES:
        v, f = shape.mesh(n)
        rv, rf = refine(v, [f], LEVELS)
        base = error(shape, rv)
        rows = [("facets (refined, not moved)", base, 0.0, len(rv))]
        for label, options in VARIANTS.items():
            start = time.perf_counter()
            out = smooth(DiffuseSurface(v, [f], **options), [f], LEVELS)
            elapsed = time.perf_counter() - start
            rows.append((label, error(shape, out.vertices), elapsed, len(out.vertices)))
        if have_apss:
            pv, elapsed = apss(v, f, rv, rf[0])
            rows.append(("MeshLab APSS (same vertices)", error(shape, pv), elapsed, len(pv)))
            pv, elapsed = apss(v, f, v, f, subdivisions=LEVELS)
            rows.append((f"MeshLab APSS maxsubdivisions={LEVELS}", error(shape, pv), elapsed,
                         len(pv)))
        for label, err, elapsed, count in rows:
            print(f"| {name} | {n} | {len(v)} | {count} | {label} | {err.max():.2e} | "
                  f"{np.sqrt(np.mean(err ** 2)):.2e} | {base.max() / err.max():.1f}x | "
                  f"{elapsed:.3f} |")


if __name__ == "__main__":
    main()
