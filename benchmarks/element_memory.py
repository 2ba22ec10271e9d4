"""Peak memory of the contact element assembled in chunks (`diffsurf_cli.assemble`, issue 12).

N contactors within ±5% of a 1692-node sphere (half of them penetrate), every one with its own
3 DOFs and the target's nodes after them; `assemble` projects, builds and assembles the
elements chunk by chunk. Each case runs in a fresh child process, which prints its peak
resident memory (ru_maxrss) before `assemble` (the scene: points, DOF maps, surface) and after
it, next to the size of what it returns (R, and K in CSR); the chunk's own footprint is what
is left. Peers, measured in the same run: the same scene at N/4 (how the peak grows with N),
and at N/4 the one-shot assembly `contact(...)` then `residual` and `tangent` (every element
of the cloud alive at once).

    python benchmarks/element_memory.py                    # rigid target, 1,000,000 contactors
    python benchmarks/element_memory.py --mode full -n 200000
    python benchmarks/element_memory.py --mode facet-rigid -n 100000

Modes: rigid (diffuse surface, rigid target: needs diffsurf_cli.element.rigid), full (the full
diffuse element), facet, facet-rigid (node-to-facet).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(mode: str, n: int, chunk: int | None, one_shot: bool = False) -> dict:
    import numpy as np

    from diffsurf_cli import DiffuseSurface, FacetSurface, assemble, contact
    from diffsurf_cli.projection import PENETRATION
    from diffsurf_cli.testing.shapes import Sphere

    nodes, faces = Sphere(radius=1.0).mesh(13)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n, 3))
    points = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (n, 1))
    surface = (FacetSurface(nodes, [faces]) if mode.startswith("facet")
               else DiffuseSurface(nodes, [faces]))
    rigid = mode.endswith("rigid")
    contactor_dofs = np.arange(3 * n).reshape(n, 3)
    target_dofs = None if rigid else 3 * n + np.arange(3 * len(nodes)).reshape(-1, 3)
    penalty = np.full(n, 1e3)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.process_time()
    if one_shot:
        c = contact(surface, points, rigid_target=rigid)
        R = c.residual(penalty, contactor_dofs, target_dofs)
        K = c.tangent(penalty, contactor_dofs, target_dofs)
        status = c.status
    else:
        R, K, status = assemble(surface, points, penalty, contactor_dofs, target_dofs,
                                rigid_target=rigid, chunk=chunk)
    cpu = time.process_time() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out = R.nbytes + K.data.nbytes + K.indices.nbytes + K.indptr.nbytes + status.nbytes
    return {"n": n, "elements": int(np.sum(status == PENETRATION)), "nnz": int(K.nnz),
            "before_mib": before / 1024, "peak_mib": peak / 1024, "out_mib": out / 2**20,
            "cpu_s": cpu}


def run(mode: str, n: int, chunk: int | None, one_shot: bool = False) -> dict:
    cmd = [sys.executable, __file__, "--child", "--mode", mode, "-n", str(n)]
    if chunk:
        cmd += ["--chunk", str(chunk)]
    if one_shot:
        cmd += ["--one-shot"]
    res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    if res.returncode:
        sys.exit(f"{' '.join(cmd)} failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", choices=["rigid", "full", "facet", "facet-rigid"],
                        default="rigid")
    parser.add_argument("-n", type=int, default=None,
                        help="contactors (1,000,000 rigid, 200,000 otherwise)")
    parser.add_argument("--chunk", type=int, default=None, help="contactors per chunk")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--one-shot", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    n = args.n or (1_000_000 if args.mode == "rigid" else 200_000)
    if args.child:
        print(json.dumps(child(args.mode, n, args.chunk, args.one_shot)))
        return 0
    if args.mode == "rigid":
        try:
            import diffsurf_cli.element.rigid  # noqa: F401
        except ImportError:
            sys.exit("--mode rigid needs diffsurf_cli.element.rigid (the rigid-target element)")
    quarter = max(n // 4, 1)
    rows = [run(args.mode, quarter, args.chunk), run(args.mode, n, args.chunk),
            run(args.mode, quarter, None, one_shot=True)]
    print(f"mode {args.mode}, chunk {args.chunk or 'default'}; 1692-node sphere, contactors "
          f"within ±5% of it")
    print(f"{'':>9} {'contactors':>11} {'elements':>9} {'K nnz':>11} {'scene MiB':>10} "
          f"{'peak MiB':>9} {'R+K MiB':>8} {'extra MiB':>10} {'CPU s':>7}")
    for r, how in zip(rows, ("chunked", "chunked", "one shot")):
        extra = r["peak_mib"] - r["before_mib"] - r["out_mib"]
        r["extra"] = extra
        print(f"{how:>9} {r['n']:>11,} {r['elements']:>9,} {r['nnz']:>11,} "
              f"{r['before_mib']:>10.0f} {r['peak_mib']:>9.0f} {r['out_mib']:>8.0f} "
              f"{extra:>10.0f} {r['cpu_s']:>7.1f}")
    small, big, once = rows
    print(f"x{big['n'] / small['n']:.0f} contactors: "
          f"peak x{big['peak_mib'] / small['peak_mib']:.2f}, extra beyond scene and result "
          f"x{big['extra'] / max(small['extra'], 1e-9):.2f}")
    print(f"{small['n']:,} contactors, chunked against one shot: peak "
          f"x{small['peak_mib'] / once['peak_mib']:.2f}, extra "
          f"x{small['extra'] / max(once['extra'], 1e-9):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
