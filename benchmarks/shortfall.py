"""Where the RMS error away from sharp edges comes from on the battery's tagged rows (issue 19's
">= 5x smaller than the facets'" criterion), one line per row, on its cached points and
reference (run `benchmarks/real_parts.py` first):

- ratio: the facets' RMS away from sharp edges over diffsurf's (the battery's);
- mesh-limited: the points where the facets err by more than 3x their RMS and diffsurf by at
  least half of that (geometry the coarse mesh does not carry: a cone's tip, a fillet one cell
  wide), their share of diffsurf's squared error, and the ratio without them;
- by the mesh's own answer: the share of diffsurf's squared error at points the facets or the
  second-order cells answered (the guard, a patch that cannot answer);
- near an edge: the share at points 1 to 1.5 local spacings from a sharp edge (one-sided
  supports);
- o2 cells no better (second-order rows): the share at points where the mesh's own curved
  cells (every point answered by them: the same target, its patches without a diffuse
  surface) err at least as much as diffsurf, by more than 3x diffsurf's RMS: there the
  target's own second-order geometry is off the CAD (a cell spanning a narrow fillet
  diagonally), and the ratio without them.

    python benchmarks/shortfall.py [ROW ...]     (default: every o1-tags and o2-tags row)

With ``DIFFSURF_BATTERY_COARSE=N`` in the environment, the rows of the diag/N battery
(``real_parts.py --coarse N``).
"""
from __future__ import annotations

import warnings

import numpy as np

import parts
import real_parts as rp
from diffsurf_cli.targets import surface_from_file


def shortfall(row: parts.Row, count: int) -> str:
    ref, _, _ = rp.reference(row, count)
    target = str(parts.OUT / row.target)
    _, surf = surface_from_file(target, zone=row.zone)
    p = surf.project(ref.points)
    e = np.abs(p.gap - ref.gap) / ref.diag
    f = np.abs(p.facet_gap - ref.gap) / ref.diag
    away = ~ref.near & np.isfinite(e)
    sse = np.sum(e[away] ** 2)
    ratio = np.sqrt(np.sum(f[away] ** 2) / sse)
    limited = away & (f > 3 * np.sqrt(np.mean(f[away] ** 2))) & (e >= 0.5 * f)
    rest = away & ~limited
    mesh = away & (p.source < 0)
    edge = away & (ref.edge <= 1.5)
    def share(m):
        return f"{100 * np.sum(e[m] ** 2) / sse:.0f}%"

    cells = "—"
    if row.variant == "o2-tags":  # the mesh's own cells answering every point
        surf.surfaces, surf._pass = [None] * len(surf.surfaces), None
        c = np.abs(surf.project(ref.points).gap - ref.gap) / ref.diag
        own = away & (c >= e) & (e > 3 * np.sqrt(sse / away.sum()))
        kept = away & ~own
        cells = (f"{own.sum()} ({share(own)}), "
                 f"{np.sqrt(np.sum(f[kept] ** 2) / np.sum(e[kept] ** 2)):.1f}")
    return (f"| {row.name} | {ratio:.1f} | {limited.sum()} ({share(limited)})"
            f" | {np.sqrt(np.sum(f[rest] ** 2) / np.sum(e[rest] ** 2)):.1f}"
            f" | {share(mesh)} | {share(edge)} | {cells} |")


def main() -> None:
    rows, count = rp.study_rows(__doc__.splitlines()[0],
                                lambda r: r.variant in ("o1-tags", "o2-tags"))
    print("| row | ratio | mesh-limited points (share of SSE) | ratio without them "
          "| SSE answered by the mesh | SSE 1-1.5 spacings from a sharp edge "
          "| o2 cells no better: points (share), ratio without them |")
    print("|---|---|---|---|---|---|---|")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for row in rows:
            print(shortfall(row, count), flush=True)


if __name__ == "__main__":
    main()
