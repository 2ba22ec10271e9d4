"""Coarse curved targets (issue 35, item 4): diffsurf's default, diffsurf as one surface,
MeshLab's APSS and the facets, side by side in one run, against the exact signed distance.

Targets: the issue's table (trimesh tori R=2, r=0.5 of 16x8, 24x8 and 48x16 sections, trimesh
icospheres of 1 and 2 subdivisions, radius 1), then gmsh OpenCASCADE meshes of first-order
triangles at k = 2, 3, 4, 6 and 8 elements per quarter circle (mesh size (pi/2) r / k): a sphere
r=1, a torus R=2, r=0.5 (k counts along the tube) and a closed capped cylinder r=0.5, height 2
(`gmsh_scenes.capped_cylinder`), measured only on its curved side away from the caps: the
exact foot of every point has 0.5 <= z <= 1.5, at least one radius (two elements at k=2) from
either cap. Every node of every target lies on its exact surface.

Points: the same 20,000 per target for every variant, uniform by area on the exact surface (on
the cylinder, its side's middle half) and moved along the exact normal by uniform(-0.1, 0.1) x
the radius (the tube's radius r on a torus), so that the exact gap is that offset (checked
against the closed forms: sphere |x| - r, torus sqrt((sqrt(x²+y²) - R)² + z²) - r, cylinder
sqrt(x²+y²) - r).

Variants: `build_surface(nodes, faces)` (what `diffsurf project` builds: patches bounded by
creases, edges sharper than the 40° feature angle that are no bend of a coarse smooth curve:
`segment.creases`); `build_surface(nodes, faces, feature_angle=180)` (one
diffuse surface over the whole target); MeshLab's APSS (compare.py's `apss_project`: pymeshlab,
its default filter scale 2, the target's vertices with the vertex normals MeshLab computes from
the facets as the point set); the facets (`FacetSurface(nodes, faces)`); and
`build_surface(nodes, faces, method="quadric")` (`diffsurf project --method quadric`: moving
algebraic quadrics fitted to the nodes' positions and normals, `mls.quadric`; numpy, so its
seconds are not the compiled engine's). APSS gives no signed
gap of its own: `apss_gap` signs its distance |x - p| by (x - p)·n_exact, with the exact normal
(as compare.py does), so APSS's sign borrows the exact surface's orientation: it is wrong only
where its projection p lies beyond x along the exact normal.

Columns per variant: RMS of (gap - exact gap) over the points it answers; wrong signs, the
points it answers where sign(gap) != sign(exact gap) and |exact gap| > 1e-3 x the diagonal of
the target's bounding box (closer to the surface the sign is not counted); % not answered
(status outside or failed, a non-finite gap, APSS's NaN). The second table: the default's
patch count, the % of points the facets answered (source -1: a sharp edge or the guard) in the
default and in one surface, and the seconds of each variant (build and projection).

    python benchmarks/coarse_targets.py [--points N]

Writes benchmarks/results/coarse_targets.txt (the command and date at the top).
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
import trimesh

import compare
from compare import apss_gap, apss_project
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.patches.surface import FACETS
from diffsurf_cli.projection import OUTSIDE
from diffsurf_cli.targets import build_surface, read_surface
from diffsurf_cli.testing import gmsh_scenes

RESULTS = Path(__file__).resolve().parent / "results"
#: offsets along the exact normal: uniform(-OFFSET, OFFSET) x the radius
OFFSET = 0.1
#: a sign is counted only where |exact gap| > SIGN_FLOOR x the target's diagonal
SIGN_FLOOR = 1e-3
#: elements per quarter circle of the gmsh targets
PER_QUARTER = (2, 3, 4, 6, 8)
VARIANTS = ("default", "one surface", "quadric", "APSS", "facets")


@dataclass
class Target:
    name: str
    nodes: np.ndarray
    faces: list          # facet blocks indexing nodes
    kind: str            # 'sphere', 'torus', 'cylinder'
    dims: tuple          # sphere (r,), torus (R, r), cylinder (r, height)


# -- exact surfaces: sampled points and closed-form signed distances ------------------------
def exact_distance(kind, dims, x):
    """The exact signed distance (outside > 0) of points x to the target's surface."""
    rho = np.hypot(x[:, 0], x[:, 1])
    if kind == "sphere":
        return np.linalg.norm(x, axis=1) - dims[0]
    if kind == "torus":
        return np.hypot(rho - dims[0], x[:, 2]) - dims[1]
    return rho - dims[0]  # the cylinder's side (points away from its caps)


def sample(kind, dims, m, rng):
    """m points uniform by area on the exact surface, moved along the exact normal by
    uniform(-OFFSET, OFFSET) x the radius; returns (points, exact normal, offset)."""
    if kind == "sphere":
        n = rng.standard_normal((m, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        foot, r = dims[0] * n, dims[0]
    elif kind == "torus":
        big, r = dims
        psi = np.empty(0)
        while len(psi) < m:  # area density proportional to R + r cos(psi)
            p = rng.uniform(0, 2 * np.pi, 2 * m)
            keep = rng.uniform(0, big + r, 2 * m) < big + r * np.cos(p)
            psi = np.concatenate([psi, p[keep]])
        psi, phi = psi[:m], rng.uniform(0, 2 * np.pi, m)
        n = np.column_stack([np.cos(psi) * np.cos(phi), np.cos(psi) * np.sin(phi), np.sin(psi)])
        rho = big + r * np.cos(psi)
        foot = np.column_stack([rho * np.cos(phi), rho * np.sin(phi), r * np.sin(psi)])
    else:  # the cylinder's side, the middle half of its height
        r, height = dims
        theta = rng.uniform(0, 2 * np.pi, m)
        n = np.column_stack([np.cos(theta), np.sin(theta), np.zeros(m)])
        foot = r * n + np.column_stack([np.zeros((m, 2)), rng.uniform(0.25, 0.75, m) * height])
    offset = rng.uniform(-OFFSET, OFFSET, m) * r
    return foot + offset[:, None] * n, n, offset


# -- targets ---------------------------------------------------------------------------------
def trimesh_targets():
    out = []
    for major, minor in ((16, 8), (24, 8), (48, 16)):
        mesh = trimesh.creation.torus(major_radius=2, minor_radius=0.5, major_sections=major,
                                      minor_sections=minor)
        out.append(Target(f"trimesh torus {major}x{minor}", np.asarray(mesh.vertices),
                          [np.asarray(mesh.faces)], "torus", (2.0, 0.5)))
    for sub in (1, 2):
        mesh = trimesh.creation.icosphere(subdivisions=sub)
        out.append(Target(f"icosphere {sub}", np.asarray(mesh.vertices),
                          [np.asarray(mesh.faces)], "sphere", (1.0,)))
    return out


def gmsh_targets(tmp: Path):
    out = []
    for k in PER_QUARTER:
        size = np.pi / 2 / k
        path = gmsh_scenes.sphere_surface(tmp / f"sphere{k}.msh", radius=1.0, size=size, order=1)
        out.append(("sphere", k, path, (1.0,)))
        path = gmsh_scenes.torus(tmp / f"torus{k}.msh", 2.0, 0.5, 0.5 * size)
        out.append(("torus", k, path, (2.0, 0.5)))
        path = gmsh_scenes.capped_cylinder(tmp / f"cyl{k}.msh", radius=0.5, height=2.0,
                                           size=0.5 * size)
        out.append(("cylinder", k, path, (0.5, 2.0)))
    targets = []
    for kind, k, path, dims in out:
        _, nodes, faces = read_surface(path)
        targets.append(Target(f"gmsh {kind} k={k}", nodes, faces, kind, dims))
    return targets


# -- variants: (gap, answered, % answered by the facets or None, seconds) ---------------------
def run_diffsurf(target, points, **options):
    start = time.perf_counter()
    surf = build_surface(target.nodes, target.faces, **options)
    res = surf.project(points)
    seconds = time.perf_counter() - start
    answered = (res.status < OUTSIDE) & np.isfinite(res.gap)
    if res.source is None:  # the quadric method: one surface, the facets never answer
        return res.gap, answered, None, seconds, 1
    facets = 100.0 * float(np.mean(res.source == FACETS))
    return res.gap, answered, facets, seconds, surf.npatches


def run_apss(target, points, normal):
    start = time.perf_counter()
    faces = np.concatenate([np.asarray(f) for f in target.faces])
    projected, _, _, _ = apss_project(target.nodes, faces, points)
    seconds = time.perf_counter() - start
    gap = apss_gap(points, projected, normal)
    return gap, np.all(np.isfinite(projected), axis=1) & np.isfinite(gap), None, seconds, None


def run_facets(target, points):
    start = time.perf_counter()
    res = FacetSurface(target.nodes, target.faces).project(points)
    seconds = time.perf_counter() - start
    return res.gap, (res.status < OUTSIDE) & np.isfinite(res.gap), None, seconds, None


def errors(gap, answered, exact, floor):
    """(RMS of gap - exact over the answered points, wrong signs among them beyond `floor`,
    % not answered)."""
    e = gap[answered] - exact[answered]
    rms = float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")
    far = answered & (np.abs(exact) > floor)
    wrong = int(np.sum(np.sign(gap[far]) != np.sign(exact[far])))
    return rms, wrong, 100.0 * (1.0 - float(np.mean(answered)))


def measure(target, m, seed):
    """Every variant on the same m points of `target`: a row of both tables."""
    rng = np.random.default_rng(seed)
    points, normal, offset = sample(target.kind, target.dims, m, rng)
    exact = exact_distance(target.kind, target.dims, points)
    assert np.max(np.abs(exact - offset)) < 1e-9, "the offset is not the exact gap"
    floor = SIGN_FLOOR * float(np.linalg.norm(np.ptp(target.nodes, axis=0)))
    runs = {"default": run_diffsurf(target, points),
            "one surface": run_diffsurf(target, points, feature_angle=180),
            "quadric": run_diffsurf(target, points, method="quadric"),
            "APSS": run_apss(target, points, normal),
            "facets": run_facets(target, points)}
    row = {"name": target.name, "nodes": len(target.nodes),
           "patches": runs["default"][4]}
    for name, (gap, answered, facets, seconds, _) in runs.items():
        row[name] = errors(gap, answered, exact, floor)
        row[name + " facets"] = facets
        row[name + " s"] = seconds
    return row


# -- report ----------------------------------------------------------------------------------
def cell(v):
    rms, wrong, missed = v
    return f"{rms:.1e} ({wrong:,}, {missed:.1f}%)"


def tables(rows, m):
    lines = [f"RMS of gap - exact gap (wrong signs, % not answered), {m:,} points per target; "
             f"signs counted where |exact| > {SIGN_FLOOR:g} x the target's diagonal",
             "", "| target | nodes | " + " | ".join(VARIANTS) + " |",
             "|---|---:|" + "---:|" * len(VARIANTS)]
    for r in rows:
        lines.append(f"| {r['name']} | {r['nodes']} | "
                     + " | ".join(cell(r[v]) for v in VARIANTS) + " |")
    lines += ["", "default's patches, % of points the facets answered (source -1), seconds "
              "(build + projection)", "",
              "| target | patches | default % facets | one surface % facets | "
              + " | ".join(f"{v} s" for v in VARIANTS) + " |",
              "|---|---:|---:|---:|" + "---:|" * len(VARIANTS)]
    for r in rows:
        lines.append(f"| {r['name']} | {r['patches']} | {r['default facets']:.1f} | "
                     f"{r['one surface facets']:.1f} | "
                     + " | ".join(f"{r[v + ' s']:.2f}" for v in VARIANTS) + " |")
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000, help="points per target")
    args = parser.parse_args(argv)
    if compare.pymeshlab is None:
        sys.exit("coarse_targets.py: MeshLab's APSS needs pymeshlab: pip install pymeshlab")
    logging.getLogger("diffsurf").setLevel(logging.WARNING)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        targets = trimesh_targets() + gmsh_targets(Path(tmp))
    rows = []
    for i, target in enumerate(targets):
        rows.append(measure(target, args.points, seed=35 + i))
        print(f"{target.name}: done", file=sys.stderr, flush=True)
    lines = tables(rows, args.points)
    lines.append(f"\ntotal {time.perf_counter() - start:.0f} s")
    command = " ".join(["$ python benchmarks/coarse_targets.py", *(argv or sys.argv[1:])])
    head = [command, datetime.now().strftime("%Y-%m-%d %H:%M"), ""]
    text = "\n".join(head + lines) + "\n"
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "coarse_targets.txt").write_text(text)


if __name__ == "__main__":
    main()
