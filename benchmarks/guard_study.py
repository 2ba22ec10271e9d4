"""Where the RMS away from sharp edges comes from on a battery row (issue 19): the guard on and
off, and the share of the squared error by the size of the patch that answered.

For each row named (`benchmarks/real_parts.py`'s names, e.g. gmsh.Block.o1-tags), on its
cached points and reference (run real_parts.py first), prints:

- the RMS / diagonal of the points away from sharp edges, for diffsurf with the guard (as
  `diffsurf project` runs), without it (`guard=False`), and for the facets; the gross errors
  (> 1% of the diagonal) of each;
- of the points the guard sent to the facets: how many, and at how many the unguarded
  diffuse answer was the nearer to the reference;
- the points away from sharp edges by the node count of the patch whose diffuse surface
  answered them (unguarded; -1: the facets), with each class's RMS, diffuse and facets, and
  its share of each method's squared error.

    python benchmarks/guard_study.py gmsh.Block.o1-tags gmsh.linkrods.o1-tags
"""
from __future__ import annotations

import argparse

import numpy as np

import parts
import real_parts as rp
from diffsurf_cli.targets import surface_from_file

CLASSES = ((-1, 0), (0, 10), (10, 20), (20, 50), (50, 200), (200, 10**9))


def study(name: str, count: int) -> None:
    man = parts.Manifest.load(parts.OUT / "manifest.json")
    row = next((r for r in man.rows if r.name == name), None)
    if row is None:
        raise SystemExit(f"{name}: no such row in the battery")
    ref, _, _ = rp.reference(row, count)
    away = ~ref.near
    target = str(parts.OUT / row.target)
    err = {}
    surfaces = {}
    for label, kw in (("guarded", {"guard": True}), ("unguarded", {"guard": False})):
        _, s = surface_from_file(target, zone=row.zone, method="diffuse", **kw)
        p = s.project(ref.points)
        err[label] = np.abs(p.gap - ref.gap) / ref.diag
        surfaces[label] = (s, p)
    _, facets = surface_from_file(target, zone=row.zone, method="facet")
    err["facets"] = np.abs(facets.project(ref.points).gap - ref.gap) / ref.diag

    def rms(e, m):
        return float(np.sqrt(np.nanmean(e[m] ** 2))) if m.any() else float("nan")

    print(f"\n## {name}: {away.sum()} of {len(away)} points away from sharp edges\n")
    print("| | RMS away / diag | facets' RMS / it | gross (all points) |\n|---|---|---|---|")
    for label in ("guarded", "unguarded", "facets"):
        e = err[label]
        print(f"| {label} | {rms(e, away):.2e} | {rms(err['facets'], away) / rms(e, away):.1f}"
              f" | {int(np.sum(e > rp.GROSS))} |")
    moved = away & (err["guarded"] != err["unguarded"])
    better = int(np.sum(err["unguarded"][moved] < err["guarded"][moved]))
    print(f"\nthe guard sent {moved.sum()} of them to the facets: RMS "
          f"{rms(err['guarded'], moved):.2e} answered so, {rms(err['unguarded'], moved):.2e} "
          f"unguarded; the unguarded answer was the nearer at {better}")
    s, p = surfaces["unguarded"]
    labels, nodes = np.unique(s.label, return_counts=False), {}
    for lab in labels:
        corners = s.corners[s.label == lab]
        nodes[lab] = len(np.unique(corners[corners >= 0]))
    size = np.array([nodes.get(int(src), -1) if src >= 0 else -1 for src in p.source])
    d, f = err["unguarded"], err["facets"]
    print("\n| patch nodes | points | RMS diffuse | RMS facets | share of diffuse SSE | "
          "share of facets SSE |\n|---|---|---|---|---|---|")
    for lo, hi in CLASSES:
        m = away & ((size < 0) if lo < 0 else ((size >= lo) & (size < hi)))
        if m.any():
            print(f"| {'facets' if lo < 0 else f'{lo}-{hi - 1}' if hi < 10**9 else f'{lo}+'} "
                  f"| {m.sum()} | {rms(d, m):.2e} | {rms(f, m):.2e} "
                  f"| {np.sum(d[m] ** 2) / np.sum(d[away] ** 2):.2f} "
                  f"| {np.sum(f[m] ** 2) / np.sum(f[away] ** 2):.2f} |")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+", help="battery rows (family.part.variant)")
    ap.add_argument("--points", type=int, default=20000, help="contactors per row (cached)")
    args = ap.parse_args(argv)
    for name in args.rows:
        study(name, args.points)


if __name__ == "__main__":
    main()
