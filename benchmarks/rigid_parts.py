"""The rigid-target element on the real-parts battery (`real_parts.py`'s gmsh rows, their
cached contactors): how many contactors the projection answers but a patch's rigid surface
cannot (no closest point within its blend's reach: deep behind a narrow patch), which the
node-to-facet element answers instead (`element.patched_contact`), and how many still get no
element. One line per row and a total; run `benchmarks/real_parts.py` first.

    python benchmarks/rigid_parts.py [ROW ...]     (default: every gmsh row)
"""
from __future__ import annotations

import warnings

import numpy as np

import parts
import real_parts as rp
from diffsurf_cli.element.element import contact
from diffsurf_cli.patches.surface import FACETS
from diffsurf_cli.projection import OK, PENETRATION
from diffsurf_cli.targets import surface_from_file


def main() -> None:
    rows, count = rp.study_rows(__doc__.splitlines()[0], lambda r: r.family == "gmsh")
    print("| row | contactors the projection answers | the rigid surface cannot: the facets "
          "answer (penetrating) | no element |")
    print("|---|---|---|---|")
    total = np.zeros(3, np.int64)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for row in rows:
            ref, _, _ = rp.reference(row, count)
            _, surf = surface_from_file(str(parts.OUT / row.target), zone=row.zone)
            p = surf.project(ref.points)
            q = contact(surf, ref.points, rigid_target=True, second=False).projection
            answered = p.status <= PENETRATION
            by_facets = answered & (p.source >= 0) & (q.source == FACETS) & (q.reason == OK)
            none = answered & (q.status > PENETRATION)
            n = np.array([by_facets.sum(), (by_facets & (q.gap < 0)).sum(), none.sum()])
            total += n
            print(f"| {row.name} | {answered.sum()} | {n[0]} ({n[1]}) | {n[2]} |", flush=True)
    print(f"| total | | {total[0]} ({total[1]}) | {total[2]} |")


if __name__ == "__main__":
    main()
