"""The contact patch test (issue 37): the diffuse element against node-to-facet, one pass each
way and two-pass, on matching and non-matching meshes, in one run.

The model is `diffsurf_cli.testing.patch_test` (scikit-fem, two elastic blocks on [0, 1]², a
uniform pressure p = 1e-4 on top, E = 1, ν = 0.3; the exact answer: σ_zz = -p everywhere,
the interface's nodal forces p times each node's tributary area). Printed per mesh and pass:
the largest |σ_zz + p| / p over both interface layers, and the largest deviation of the
interface nodal forces from the consistent ones (relative), for

- node-to-facet (`FacetSurface`);
- diffuse, a bare `DiffuseSurface` with its defaults (quadratic basis, Wendland weight);
- diffuse, linear basis (`basis="linear"`);
- diffuse, interpolating weight and linear basis (`weight="singular", basis="linear"`);
- diffuse via facets: the default diffuse element's gap and normal, its force passed to the
  target through the shape functions of the facet it faces (`testing.facet_transfer`, a
  study, not the library's element), with its default weight and basis, and with the
  interpolating weight and the linear basis;

at the penalty ε_i = `PENALTY` x tributary area (penetrations about 1e-7 of a 1/5 element),
each from the upper block lowered by 1e-9 (node-to-facet cannot start from touching bodies:
a contactor that Poisson's expansion carries a little past the open edge of its target gets
the distance to that edge as its penetration, and Newton diverges; the diffuse element starts
from a flat start, g = 0, tests/test_patch_test.py). Then the two-pass runs again at 0.1 and
10 times the penalty: node-to-facet's error falls as 1/ε; a method whose error does not fall
does not pass the test in the limit. Last, what each surface gives on a curved target
(unit icospheres): the weight and basis that pass the patch test must keep the accuracy the
smoothing is for. Between them, one pass again with the contactors at
`GAUSS` x `GAUSS` Gauss points of the contactor face's facets (contact integrated over the
contactor surface, issue 37's item 3): node-to-facet then nearly passes (the target's nodal
forces are its facets' shape functions integrated against the pressure, as a mortar
method's), the diffuse element does not (the diffuse shape functions are not the face's).

Then why (`why`): a tied contact stalls as the unilateral one; both faces bent together by a
quadratic keep every gap of both passes 0 on a smoothed face, while the exact solution's
interface forces do work on that bend; a uniform pressure reaches the target's nodes through
the diffuse shape functions with shares a third off the face's tributary areas.

A trailing "!" marks a run whose Newton stopped at 12 iterations without reaching 1e-8 of the
load (the round-off floor of these penalties is a few 1e-9).

    python benchmarks/patch_test.py

Results: benchmarks/results/patch_test.txt.
"""
from __future__ import annotations

import argparse

from diffsurf_cli.testing import patch_test as pt

#: The surfaces compared (`patch_test.solve`'s kinds) and their column titles.
KINDS = (("facets", "node-to-facet", False), ("diffuse", "diffuse", False),
         ("diffuse:basis=linear", "diffuse linear", False),
         ("diffuse:weight=singular,basis=linear", "diffuse singular+linear", False),
         ("diffuse", "diffuse via facets", True),
         ("diffuse:weight=singular,basis=linear", "sing.+lin. via facets", True))

#: The meshes: (name, `patch_test.build` arguments).
MESHES = (
    ("hex 5x5 / 4x4", dict(lower=(5, 5), upper=(4, 4))),
    ("hex 4x4 / 4x4 matching", dict(lower=(4, 4), upper=(4, 4))),
    ("hex 4x4 / 4x4 offset 0.3", dict(lower=(4, 4), upper=(4, 4), shift_upper=(0.3, 0.3))),
    ("hex 6x6 / 5x5", dict(lower=(6, 6), upper=(5, 5))),
    ("hex 3x3 / 7x7", dict(lower=(3, 3), upper=(7, 7))),
    ("tet 4x4 / 4x4 matching", dict(lower=(4, 4), upper=(4, 4), tetra=True)),
    ("tet 5x5 / 4x4", dict(lower=(5, 5), upper=(4, 4), tetra=True)),
)

START = 1e-9      # the upper block lowered by this much at the start of Newton
GAUSS = 4         # Gauss points per direction of the contactor facets (the third table)


def cell(r) -> str:
    return f"{r.stress:.1e} / {r.force:.1e}{'' if r.converged else '!'}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sweep", type=float, nargs="+", default=[0.1, 10.0],
                    help="penalty factors of the two-pass sweep")
    args = ap.parse_args(argv)
    print("σ_zz deviation / nodal-force deviation (relative), penalty "
          f"{pt.PENALTY:.0f} x tributary area, Newton from {START:g} lowered\n")
    head = "".join(f"{title:>26}" for _, title, _ in KINDS)
    print(f"{'mesh':>26} {'pass':>6}{head}")
    models = {name: pt.build(**kw) for name, kw in MESHES}
    for name, model in models.items():
        for way in ("upper", "lower", "two"):
            row = [pt.solve(model, way, kind, start=START, max_iter=12, tol=1e-8,
                            transfer=facets) for kind, _, facets in KINDS]
            print(f"{name:>26} {way:>6}" + "".join(f"{cell(r):>26}" for r in row), flush=True)
    print(f"\none pass, the contactors the {GAUSS} x {GAUSS} Gauss points of the contactor "
          "face's facets (their element acting on the facet's nodes through its shape "
          "functions), not its nodes")
    print(f"{'mesh':>26} {'pass':>6}{head}")
    for name, model in models.items():
        for way in ("upper", "lower"):
            row = [pt.solve(model, way, kind, start=START, max_iter=12, tol=1e-8, gauss=GAUSS,
                            transfer=facets) for kind, _, facets in KINDS]
            print(f"{name:>26} {way:>6}" + "".join(f"{cell(r):>26}" for r in row), flush=True)
    print("\ntwo-pass against the penalty (x the one above): an error that falls as 1/ε passes "
          "in the limit")
    print(f"{'mesh':>26} {'ε x':>6}{head}")
    for name, model in models.items():
        for factor in args.sweep:
            row = [pt.solve(model, "two", kind, penalty=pt.PENALTY * factor, start=START,
                            max_iter=12, tol=1e-8, transfer=facets)
                   for kind, _, facets in KINDS]
            print(f"{name:>26} {factor:>6g}" + "".join(f"{cell(r):>26}" for r in row),
                  flush=True)
    why(models)
    curved()


def why(models):
    """Why two-pass stalls and one pass does not converge with refinement
    (docs/patch_test.md): a tied contact stalls alike; both faces bent together by a
    quadratic keep every gap of both passes 0 on a smoothed face, while the consistent
    interface forces do work on that bend; and a finely integrated uniform pressure reaches
    the target's nodes through the diffuse shape functions with shares that are not the
    face's tributary areas."""
    import numpy as np

    model = models["hex 5x5 / 4x4"]
    print("\nwhy two-pass stalls, hex 5x5 / 4x4 (diffuse via facets, two-pass):")
    for factor in (0.1, 10.0):
        row = [pt.solve(model, "two", "diffuse", penalty=pt.PENALTY * factor, start=START,
                        max_iter=12, tol=1e-8, transfer=True, tied=tied)
               for tied in (False, True)]
        print(f"  ε x {factor:>4g}: unilateral {cell(row[0])}, tied {cell(row[1])}")
    bends = {"x²": lambda X: X[:, 0] ** 2, "x² + y²": lambda X: X[:, 0] ** 2 + X[:, 1] ** 2}
    kinds = (("facets", "node-to-facet"), ("diffuse", "diffuse"),
             ("diffuse:weight=singular", "diffuse singular"), ("default", "default surface"),
             ("diffuse:basis=linear", "diffuse linear"))
    print("both faces bent together by s q: the largest |gap| / s over both passes, and the "
          "consistent forces' work on it / p")
    print(f"{'q':>10}" + "".join(f"{title:>20}" for _, title in kinds) + f"{'work / p':>12}")
    for name, q in bends.items():
        print(f"{name:>10}" + "".join(f"{pt.common_bend(model, kind, q):>20.1e}"
                                      for kind, _ in kinds)
              + f"{pt.bend_work(model, q):>12.2e}")
    lower = model.lower
    print("a uniform pressure on the 5 x 5 face through its contact (90,000 points): the "
          "largest |nodal share - tributary area| / largest area")
    print("".join(f"{title:>20}" for kind, title in kinds[:4]))
    off = [np.abs(pt.pressure_shares(lower, kind) - lower.area).max() / lower.area.max()
           for kind, _ in kinds[:4]]
    print("".join(f"{v:>20.1e}" for v in off), flush=True)


def curved(levels=(2, 3, 4), count: int = 20_000):
    """What each surface costs on a curved target: RMS gap error on unit icospheres, points
    within a spacing of the sphere, exact references."""
    import numpy as np
    import trimesh

    from diffsurf_cli import DiffuseSurface, FacetSurface

    surfaces = (("node-to-facet", lambda V, F: FacetSurface(V, [F])),
                ("diffuse", lambda V, F: DiffuseSurface(V, [F])),
                ("diffuse linear", lambda V, F: DiffuseSurface(V, [F], basis="linear")),
                ("diffuse singular", lambda V, F: DiffuseSurface(V, [F], weight="singular")),
                ("singular+linear", lambda V, F: DiffuseSurface(V, [F], weight="singular",
                                                                basis="linear")))
    print("\ncurved targets: RMS gap error on unit icospheres, points within a spacing")
    print(f"{'nodes':>8}" + "".join(f"{name:>20}" for name, _ in surfaces))
    rng = np.random.default_rng(0)
    for level in levels:
        mesh = trimesh.creation.icosphere(level)
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        d = rng.normal(size=(count, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        h = float(np.median(mesh.edges_unique_length))
        p = d * (1 + rng.uniform(-1, 1, (count, 1)) * h)
        exact = np.linalg.norm(p, axis=1) - 1
        row = [np.sqrt(np.nanmean((make(V, F).project(p).gap - exact) ** 2))
               for _, make in surfaces]
        print(f"{len(V):>8}" + "".join(f"{v:>20.1e}" for v in row), flush=True)


if __name__ == "__main__":
    main()
