"""The contact element on a target of several patches against its projection, in one run.

The fillet box of diffsurf_cli/testing/feature_scenes.py (2 x 1 x 1, fillets of radius 0.25,
triangles of `--size`; 7 patches: 6 flat faces, the fillets with their corners) and `--points`
contactors within 2 % of its size of the surface (about half penetrating). Timed, CPU time
(`time.process_time`, all threads), best of `--repeat`, every engine built before:

- the patched projection `PatchedSurface.project(points)`;
- `contact(patched, points)`: the full element (g, 𝒩, ℳ) per patch, and with second=False;
- `contact(patched, points, rigid_target=True)`;
- for scale, the same three on ONE DiffuseSurface over the whole box (what the CLI fell
  back to before), ratios to its own projection.

Printed: CPU per contactor and the ratio to the projection of the same surface; never
asserted. Needs gmsh.

    python benchmarks/patch_element.py [--points N] [--size H] [--repeat R]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from functools import partial
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
from diffsurf_cli.element.element import contact  # noqa: E402
from diffsurf_cli.mls.surface import DiffuseSurface  # noqa: E402
from diffsurf_cli.patches.surface import PatchedSurface  # noqa: E402
from diffsurf_cli.projection import PENETRATION  # noqa: E402
from diffsurf_cli.targets import read_surface  # noqa: E402
from diffsurf_cli.testing import feature_scenes as fs  # noqa: E402


def best(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        out = fn()
        times.append(time.process_time() - t0)
    return min(times), out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20_000)
    parser.add_argument("--size", type=float, default=0.05)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        sc = fs.fillet_box(Path(tmp), size=args.size)
        _, nodes, faces = read_surface(sc.path, None)
    points = sc.sample(args.points, band=0.02, seed=1)
    m = len(points)
    print(f"fillet box of {len(nodes)} nodes, {m} contactors, best of {args.repeat}")
    per = lambda t: 1e6 * t / m  # noqa: E731
    for name, surf in (("patched", PatchedSurface(nodes, faces)),
                       ("one surface", DiffuseSurface(nodes, faces))):
        contact(surf, points[:50], rigid_target=True)  # engines and rigid surfaces built
        t_proj, proj = best(partial(surf.project, points), args.repeat)
        t_full, c = best(partial(contact, surf, points), args.repeat)
        t_first, _ = best(partial(contact, surf, points, second=False), args.repeat)
        t_rigid, _ = best(partial(contact, surf, points, rigid_target=True), args.repeat)
        extra = f", {surf.npatches} patches" if name == "patched" else ""
        print(f"{name}{extra}: {int((proj.status == PENETRATION).sum())} penetrating, "
              f"{len(c)} elements (K = {c.nodes.shape[1]})")
        print(f"  projection                 {per(t_proj):9.2f} µs CPU per contactor")
        for label, t in (("contact (g, N, M)", t_full), ("contact, N only", t_first),
                         ("contact, rigid target", t_rigid)):
            print(f"  {label:<26} {per(t):9.2f} µs   ratio {t / t_proj:6.2f}")


if __name__ == "__main__":
    main()
