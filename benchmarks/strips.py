"""One-element-wide strips (issue 11 item 2): % of points outside before and after the reduced
bases, and the gap error against the exact surface, diffuse and facets, measured in one run.

    python benchmarks/strips.py

Scenes: strips along an arc of radius 10, one element across (quads and triangles: two rows of
nodes; quad8 and quad9: three), over 0.9π (a local frame) and π/3 (the global frame); a strip
4 wide with elements 0.44 long (its supports near an edge hold one row: a ruled extrusion);
and a CalculiX-like deck: the contact surface (the boundary faces of an *NSET) of a half
annulus of C3D8 cells one cell thick, graded towards its bottom. Points: within ±5% of the part
size of the strip (near the contact zone for the deck); exact gap: the signed distance to the
cylinder of radius 10. "before" is this tree with the reduced bases switched off
(basis.REDUCED emptied: the full basis or nothing, the old rule), in the same run. The facets:
FacetSurface on the linear (sub-)facets, the peer. Every preset of `diffsurf tune`.
"""
from __future__ import annotations

import os
import tempfile

import numpy as np

from diffsurf_cli import io
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls import basis
from diffsurf_cli.mls.frame import cell_faces, linear_facets
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.presets import PRESETS
from diffsurf_cli.projection import PENETRATION

R = 10.0


def arc_strip(kind, arc, n, width):
    """Nodes and cells of a strip along the arc (0, arc) of radius R, `width` along z, one
    element across; outward (theta x z)."""
    order2 = kind in ("quad8", "quad9")
    k = 2 * n if order2 else n
    theta = arc * np.arange(k + 1) / k
    rows = 3 if order2 else 2
    z = width * (np.arange(rows) / (rows - 1) - 0.5)
    index, nodes = {}, []
    for i, th in enumerate(theta):
        for j in range(rows):
            if kind == "quad8" and j == 1 and i % 2:
                continue
            index[i, j] = len(nodes)
            nodes.append([R * np.cos(th), R * np.sin(th), z[j]])
    cells = []
    for e in range(n):
        if order2:
            i = 2 * e
            c = [(i, 0), (i + 2, 0), (i + 2, 2), (i, 2), (i + 1, 0), (i + 2, 1), (i + 1, 2), (i, 1)]
            if kind == "quad9":
                c.append((i + 1, 1))
            cells.append([index[p] for p in c])
        elif kind == "quad":
            cells.append([index[e, 0], index[e + 1, 0], index[e + 1, 1], index[e, 1]])
        else:
            cells += [[index[e, 0], index[e + 1, 0], index[e + 1, 1]],
                      [index[e, 0], index[e + 1, 1], index[e, 1]]]
    return np.array(nodes), [np.array(cells)]


def near_arc(arc, width, m, rng, row_band=None):
    """Points near the strip (5% of the part size off it, 5% of the ends and edges kept clear;
    with `row_band`, only within that distance of the two edges) and their signed distances."""
    size = 2 * R * np.sin(min(0.5 * arc, 0.5 * np.pi))
    theta = rng.uniform(0.05 * arc, 0.95 * arc, m)
    if row_band is None:
        z = rng.uniform(-0.45 * width, 0.45 * width, m)
    else:
        z = np.where(rng.random(m) < 0.5, -1, 1) * (0.5 * width - rng.uniform(0, row_band, m))
    r = R + rng.uniform(-0.05 * size, 0.05 * size, m)
    return np.column_stack([r * np.cos(theta), r * np.sin(theta), z]), r - R


def deck_scene(m, rng):
    """The CalculiX-like deck (as tests/test_strips.py's): target nodes and cells of the
    contact surface (read back through io.read_target, --zone CONTACT), points, distances."""
    import meshio

    n, rings = 40, 3
    u = np.linspace(-1.0, 1.0, n + 1)
    theta = 1.5 * np.pi + 0.5 * np.pi * np.sign(u) * np.abs(u) ** 1.5
    radii = np.linspace(5.0, R, rings + 1)
    pts = np.array([[r * np.cos(t), r * np.sin(t), zz] for zz in (0.0, 1.0) for t in theta
                    for r in radii])

    def node(k, i, j):
        return (k * (n + 1) + i) * (rings + 1) + j

    hexa = [[node(0, i, j), node(0, i, j + 1), node(0, i + 1, j + 1), node(0, i + 1, j),
             node(1, i, j), node(1, i, j + 1), node(1, i + 1, j + 1), node(1, i + 1, j)]
            for i in range(n) for j in range(rings)]
    contact = np.flatnonzero(np.isclose(np.hypot(pts[:, 0], pts[:, 1]), R))
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "deck.inp")
        meshio.write(path, meshio.Mesh(pts, [("hexahedron", np.array(hexa))],
                                       point_sets={"CONTACT": contact}))
        target = io.read_target(path, zone="CONTACT")
    nodes = target.points[target.nodes]
    faces = [np.searchsorted(target.nodes, f) for f in cell_faces(target.cells)]
    th = 1.5 * np.pi + rng.uniform(-0.6, 0.6, m)
    r = R + rng.uniform(-1.0, 1.0, m)
    x = np.column_stack([r * np.cos(th), r * np.sin(th), rng.uniform(0.02, 0.98, m)])
    return nodes, faces, x, r - R


def scenes(m=2000, seed=0):
    rng = np.random.default_rng(seed)
    for kind in ("quad", "triangle", "quad8", "quad9"):
        for arc, name in ((0.9 * np.pi, "0.9pi"), (np.pi / 3, "pi/3")):
            nodes, faces = arc_strip(kind, arc, 36 if kind in ("quad", "triangle") else 18, 1.0)
            yield (f"{kind} strip {name}", nodes, faces) + near_arc(arc, 1.0, m, rng)
    nodes, faces = arc_strip("quad", np.pi / 3, 24, 4.0)
    yield ("quad strip 4 wide, rows",) + (nodes, faces) + near_arc(np.pi / 3, 4.0, m, rng, 0.05)
    yield ("CalculiX-like deck",) + deck_scene(m, rng)


def measure(nodes, faces, x, dist, settings):
    surface = DiffuseSurface(nodes, faces, **settings)
    after = surface.project(x)
    saved = dict(basis.REDUCED)
    try:
        for key in basis.REDUCED:
            basis.REDUCED[key] = ()
        before = DiffuseSurface(nodes, faces, **settings).project(x)
    finally:
        basis.REDUCED.update(saved)
    ok = after.status <= PENETRATION
    e = np.abs(after.gap[ok] - dist[ok])
    terms = np.bincount(after.terms[ok], minlength=11)
    return (100 * np.mean(before.status > PENETRATION), 100 * np.mean(~ok),
            np.sqrt(np.mean(e**2)) if ok.any() else np.nan, e.max() if ok.any() else np.nan,
            ",".join(f"{t}:{c}" for t, c in enumerate(terms) if c), surface.frame)


def main():
    print(f"{'scene':<26} {'preset':<9} {'frame':<6} {'out% before':>11} {'out% after':>10} "
          f"{'rms diffuse':>11} {'rms facets':>10} {'facets/diff':>11} {'max diffuse':>11} "
          f"{'max facets':>10}  terms:count")
    for name, nodes, faces, x, dist in scenes():
        peer = FacetSurface(nodes, linear_facets(faces)).project(x)
        ef = np.abs(peer.gap - dist)
        rms_f, max_f = np.sqrt(np.mean(ef**2)), ef.max()
        for preset, settings in PRESETS.items():
            settings = {k: v for k, v in settings.items()
                        if k in ("basis", "weight", "support", "radius", "k", "frame",
                                 "recentre")}
            b, a, rms, top, terms, frame = measure(nodes, faces, x, dist, settings)
            print(f"{name:<26} {preset:<9} {frame:<6} {b:>11.1f} {a:>10.1f} {rms:>11.2e} "
                  f"{rms_f:>10.2e} {rms_f / rms:>11.0f} {top:>11.2e} {max_f:>10.2e}  {terms}")


if __name__ == "__main__":
    main()
