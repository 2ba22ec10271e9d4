"""How closely the compiled diffuse element agrees with its jet oracle (issue 12, item 1).

The cases of tests/test_element_engine.py (five scenes x three bases x three weights, the
penetrating contactors of each): the worst |Δg| / R, ‖Δ𝒩‖ / ‖𝒩‖ and ‖Δℳ‖ / ‖ℳ‖ between
`diffuse.diffuse_elements` and tests/oracle_element.py, per scene and overall. The test
asserts 1e-10; this prints the figures. The oracle lives with the tests: tests/ on the path.

    PYTHONPATH=tests python benchmarks/element_oracle.py
"""
from __future__ import annotations

import numpy as np

import oracle_element  # tests/oracle_element.py (PYTHONPATH=tests)
from diffsurf_cli.element.diffuse import diffuse_elements
from diffsurf_cli.mls.basis import BASES
from diffsurf_cli.mls.weight import WEIGHTS
from diffsurf_cli.testing.element_scenes import ALL_SCENES, pairing


def main():
    total = np.zeros(3)
    count = 0
    for scene in ALL_SCENES:
        worst = np.zeros(3)
        for basis in BASES:
            for weight in WEIGHTS:
                surf, points, proj, rows = pairing(scene, basis, weight)
                args = (surf, points, proj.patch, proj.proximal_point, rows)
                g0, _, N0, M0 = oracle_element.diffuse_elements(*args)
                g1, _, N1, M1 = diffuse_elements(*args)
                err = [np.max(np.abs(g1 - g0) / proj.patch.radius[rows]),
                       np.max(np.linalg.norm(N1 - N0, axis=1) / np.linalg.norm(N0, axis=1)),
                       np.max(np.linalg.norm(M1 - M0, axis=(1, 2))
                              / np.linalg.norm(M0, axis=(1, 2)))]
                worst = np.maximum(worst, err)
                count += len(rows)
        total = np.maximum(total, worst)
        print(f"{scene:13s} |dg|/R {worst[0]:.1e}   |dN|/|N| {worst[1]:.1e}   "
              f"|dM|/|M| {worst[2]:.1e}")
    print(f"{'all':13s} |dg|/R {total[0]:.1e}   |dN|/|N| {total[1]:.1e}   "
          f"|dM|/|M| {total[2]:.1e}   ({count} elements, {len(BASES)} bases x "
          f"{len(WEIGHTS)} weights)")


if __name__ == "__main__":
    main()
