"""Targets with features (issue 11): gap errors of the patched diffuse surface and of the facets,
in the same run, per scene and region, against the exact signed distance.

Scenes (gmsh OpenCASCADE, diffsurf_cli/testing/feature_scenes.py): a box, a box with filleted
edges, a capped cylinder, a plate 2 thick meshed 0.4 on top and 2.5 below, a lens (two spherical
caps meeting at a sharp circular edge). Contactors: drawn uniformly within 2% of the part size
of its surface (inside and outside). Regions by the exact closest point: flat faces, within two
elements of a sharp edge, fillets, curved faces. Printed per region: RMS and max |gap - exact|
of diffsurf (default options, `PatchedSurface`) and of the facets (`FacetSurface`), their ratio
(facets / diffsurf: > 1 diffsurf better; 'both 0' where both are at round-off, below 1e-12 of
the part size, 'diff 0' where diffsurf is), % of points diffsurf leaves outside; then the same
target as one diffuse surface (the former default, `--feature-angle 180`), and the thin wall:
points 0.3 below the bottom face.

`--no-tags` segments by the feature angle alone (an STL has no face tags); `--angles` prints the
largest facet-to-facet angles of smooth targets (what the default feature angle must exceed).

Then the CPU time per contactor of the patches, of one diffuse surface and of the facets, in
the same run, and the ratio patches / one surface.

    python benchmarks/feature_targets.py [--points N] [--speed-points N] [--no-tags] [--angles]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.frame import facet_corners
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.patches.segment import FEATURE_ANGLE_DEG, facet_edges, node_identity
from diffsurf_cli.patches.surface import PatchedSurface
from diffsurf_cli.targets import read_surface
from diffsurf_cli.testing import feature_scenes as fs
from diffsurf_cli.testing import gmsh_scenes


def _row(scene, region, v, size):
    n, drms, dmax, frms, fmax, out = v

    def ratio(f, d):  # at round-off (below 1e-12 of the part size): no ratio
        if max(f, d) < 1e-12 * size:
            return "both 0"
        return "diff 0" if d < 1e-12 * size else f"{f / d:9.1f}"
    print(f"| {scene:20s} | {region:6s} | {n:5d} | {drms:8.1e} | {dmax:8.1e} | {frms:8.1e} | "
          f"{fmax:8.1e} | {ratio(frms, drms):>9s} | {ratio(fmax, dmax):>9s} | {out:5.1f} |")


def angles(tmp):
    print("largest facet-to-facet angles (degrees) of smooth targets, max and 99th percentile:")
    shapes = [("sample cylinder", "sample_meshes/cylinder.msh"),
              ("sample torus", "sample_meshes/torus.msh")]
    for size in (0.5, 0.35, 0.25):
        shapes.append((f"gmsh sphere r=1 h={size}",
                       gmsh_scenes.sphere_surface(tmp / f"s{size}.msh", size=size, order=1)))
    for size in (0.3, 0.2):
        shapes.append((f"gmsh capped cylinder r=0.5 h={size} (side)",
                       gmsh_scenes.capped_cylinder(tmp / f"c{size}.msh", size=size)))
    root = Path(__file__).resolve().parents[1]
    for name, path in shapes:
        path = path if Path(path).is_absolute() else str(root / path)
        t, nodes, faces = read_surface(path, None)
        if "capped" in name:  # the side alone: its facets' normals have no z component
            keep = [f[np.abs(_normals(nodes, f)[:, 2]) < 0.5] for f in faces]
            faces = keep
        a = dihedral_angles(nodes, faces)
        print(f"  {name:42s} {a.max():6.1f} {np.percentile(a, 99):6.1f}")
    print(f"default feature angle: {FEATURE_ANGLE_DEG}°")


def _cpu(surf, points, repeat=3):
    """Best CPU time per point of surf.project(points), engines built by a first call."""
    surf.project(points[:10])
    best = np.inf
    for _ in range(repeat):
        t = time.process_time()
        surf.project(points)
        best = min(best, time.process_time() - t)
    return best / len(points)


def _normals(nodes, f):
    from diffsurf_cli.mls.frame import facet_area_vectors

    a = facet_area_vectors(nodes, [f])
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def dihedral_angles(nodes, faces) -> np.ndarray:
    """Angle (degrees) between the normals of the two facets of each manifold edge: what the
    feature angle is compared with."""
    from diffsurf_cli.mls.frame import facet_area_vectors

    fac, _, edge, ne = facet_edges(faces, node_identity(nodes))
    area = facet_area_vectors(nodes, faces)
    unit = area / np.maximum(np.linalg.norm(area, axis=1, keepdims=True), 1e-300)
    order = np.argsort(edge, kind="stable")
    e, f = edge[order], fac[order]
    count = np.bincount(e, minlength=ne)
    first = np.ones(len(e), bool)
    first[1:] = e[1:] != e[:-1]
    i = np.flatnonzero(first & (count[e] == 2))
    cos = np.clip(np.einsum("ij,ij->i", unit[f[i]], unit[f[i + 1]]), -1, 1)
    return np.degrees(np.arccos(cos))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--speed-points", type=int, default=100000,
                        help="contactors of the CPU-time comparison (each call of an engine "
                             "has a fixed cost: patches make several)")
    parser.add_argument("--no-tags", action="store_true")
    parser.add_argument("--angles", action="store_true")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.angles:
            angles(tmp)
            return
        print(f"gap error |gap - exact| per region, {args.points} contactors per scene within 2% "
              f"of the part size; ratio = facets / diffsurf; feature angle {FEATURE_ANGLE_DEG}°"
              f"{', no face tags' if args.no_tags else ', face tags of the file'}")
        head = ("| scene                | region | n     | diff RMS | diff max | fac RMS  "
                "| fac max  | RMS x     | max x     | out % |")
        print(head)
        print("|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|")
        former, speed = [], []
        for name, make in fs.SCENES.items():
            scene = make(tmp)
            t, nodes, faces = read_surface(scene.path, None)
            tags = None if args.no_tags or t.tags is None else np.concatenate(t.tags)
            surf = PatchedSurface(nodes, faces, tags=tags)
            facets = FacetSurface(nodes, [facet_corners(f) for f in faces])
            points = scene.sample(args.points)
            table, _ = fs.errors(scene, points, surf, facets)
            label = f"{scene.name} ({surf.npatches})"
            for region, v in table.items():
                _row(label, region, v, scene.size)
            whole = DiffuseSurface(nodes, faces)
            one, _ = fs.errors(scene, points, whole, facets)
            many = scene.sample(args.speed_points, seed=2)
            speed.append((scene.name, *(_cpu(s, many) for s in (surf, whole, facets)),
                          surf.npatches))
            former.append((scene.name, one, scene.size))
            if name == "thin_plate":
                rng = np.random.default_rng(1)
                below = np.column_stack([rng.uniform(0.5, 9.5, 2000), rng.uniform(0.5, 9.5, 2000),
                                         np.full(2000, -0.3)])
                wall = (surf.project(below), DiffuseSurface(nodes, faces).project(below))
        print("\nthe same points on one diffuse surface over the whole target "
              "(--feature-angle 180, the former default):")
        print(head)
        for name, one, size in former:
            for region, v in one.items():
                _row(name, region, v, size)
        print(f"\nCPU time per contactor, {args.speed_points} contactors (process time, best of 3; "
              f"surfaces built beforehand):")
        for name, t_patch, t_one, t_fac, npatch in speed:
            print(f"  {name:18s} {npatch:3d} patches {1e6 * t_patch:7.2f} µs, one surface "
                  f"{1e6 * t_one:7.2f} µs, facets {1e6 * t_fac:7.2f} µs: patches / one = "
                  f"{t_patch / t_one:5.2f}")
        print("\nfillets of radius 0.25 by element size (5000 contactors each): how narrow a "
              "fillet the quadratic basis still fits")
        for size in (0.07, 0.1, 0.15, 0.2, 0.3):
            scene = fs.fillet_box(tmp, size=size)
            t, nodes, faces = read_surface(scene.path, None)
            surf = PatchedSurface(nodes, faces, tags=np.concatenate(t.tags))
            facets = FacetSurface(nodes, [facet_corners(f) for f in faces])
            table, raw = fs.errors(scene, scene.sample(5000), surf, facets)
            n, drms, dmax, frms, fmax, out = table["fillet"]
            print(f"  h {size:4.2f} ({0.25 * np.pi / 2 / size:3.1f} elements across): RMS "
                  f"{drms:.1e} vs facets {frms:.1e} ({frms / drms:5.1f}x), max {dmax:.1e} vs "
                  f"{fmax:.1e}; answered by the facets {100 * (raw[1].source == -1).mean():4.1f}%,"
                  f" outside {out:.1f}%")
        print("\na CAD-like part (gmsh_scenes.holed_block: a block with a through hole and four "
              "filleted edges, h 0.12), against the same part meshed 8x finer (its facets' own "
              "error, ~1e-4 on the fillets and the hole, bounds the ratios), 8000 contactors "
              "within 0.06:")
        coarse = gmsh_scenes.holed_block(tmp / "part.msh", 0.12)
        fine = gmsh_scenes.holed_block(tmp / "part_fine.msh", 0.015)
        t, nodes, faces = read_surface(coarse, None)
        _, nf, ff = read_surface(fine, None)
        reference = FacetSurface(nf, [facet_corners(f) for f in ff])
        rng = np.random.default_rng(0)
        pts = rng.uniform([-0.1, -0.1, -0.1], [3.1, 2.1, 1.1], (60000, 3))
        pts = pts[np.abs(reference.project(pts).gap) < 0.06][:8000]
        exact = reference.project(pts).gap
        surf = PatchedSurface(nodes, faces, tags=np.concatenate(t.tags))
        for label, s_ in ((f"patches ({surf.npatches})", surf),
                          ("one surface", DiffuseSurface(nodes, faces)),
                          ("facets", FacetSurface(nodes, [facet_corners(f) for f in faces]))):
            p = s_.project(pts)
            ok = np.isin(p.status, (0, 1, 2))
            e = np.abs(p.gap[ok] - exact[ok])
            wrong = (np.sign(p.gap) != np.sign(exact)) & (np.abs(exact) > 1e-3) & ok
            print(f"  {label:13s} RMS {np.sqrt(np.mean(e ** 2)):.1e} max {e.max():.1e}, "
                  f"outside {100 * (~ok).mean():.1f}%, wrong sign {int(wrong.sum())}")
        print("\nthin wall: 2000 points 0.3 below the bottom face of the plate (exact gap +0.3):")
        for label, p in zip(("patches", "one surface"), wall):
            ok = np.isin(p.status, (0, 1, 2))
            g = p.gap[ok]
            print(f"  {label:12s} gap min {g.min():+.4f} max {g.max():+.4f}; "
                  f"|gap - 0.3| max {np.abs(g - 0.3).max():.1e}; outside {100 * (~ok).mean():.1f}%")


if __name__ == "__main__":
    main()
