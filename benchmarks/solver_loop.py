"""The contact element in a solver's loop (issue 21): CPU per contactor against the projection,
peak memory of `contact()`, and wall time of small batches on 1 and 2 threads, in one run.

Scene: a faceted sphere of radius 10 (`Sphere.mesh(--divisions)`, 16k nodes by default) as a
`DiffuseSurface` (and its `FacetSurface`), contactors drawn on random rays at depths uniform
in (0, `--depth`) node spacings inside it (0.25 by default: a penalty's penetrations; every
one penetrating, so every one gets an element).

1. CPU per contactor (user + system of this process, `time.process_time`, on one thread:
   `threads.max_threads` held at 1; best of `--repeat` rounds, each round every call once in
   turn), on 20,000 contactors:
   - projection: `surface.project(points)` (what a contactor costs with no element);
   - full element: `contact(surface, points)` (g, 𝒩; ℳ on demand past HESSIAN_BYTES), then
     building every ℳ (`np.asarray(c.M)`), then `Contact.residual` (summed by the compiled
     scatter `element._scatter_add`), then `Contact.tangent`
     (each element's ℳ built again and added into the CSR at once, in compiled code:
     `_element.tangent_elements`), beside the batch path it replaced (ℳ of a batch of
     elements written, then summed by `element._assembly.add`: the tangent with the
     `Hessians.tangent` hook off) and the numpy path before it (tests/test_tangent_compiled.py's
     `reference_tangent`: dense blocks per element and scipy's COO sums), and the ratio
     (contact + residual + tangent) / projection (<= 10, issue 33);
   - rigid element: `contact(surface, points, rigid_target=True)`, then its tangent;
   - node-to-facet element: `contact` on the `FacetSurface` (full, ℳ whole), then its
     tangent, against the facets' projection;
   printed with the issue's ratios: full element (g, 𝒩, ℳ) / projection (<= 10), rigid /
   projection (<= 2).
2. Peak memory of `contact(surface, points)` (tracemalloc: numpy's arrays are traced) at
   20,000 and `--large` (1,000,000) contactors, full and rigid element, next to the size of
   the arrays it returns (gap, 𝒩, nodes, the projection): what the call needs beyond its
   answer. The full element's ℳ past `element.blocks.HESSIAN_BYTES` is built on demand
   (`element.blocks.Hessians`): `Contact.tangent` then assembles it block by block; the tangent's
   own peak at 20,000 is printed too, and `assemble`'s at `--assemble` (100,000) contactors
   against the bytes of the K it returns (<= 1.3, issue 33).
3. Wall time of `contact()` per call at 10, 100, 1,000 and 10,000 contactors, full and rigid,
   one call on 1 thread (`threads.max_threads` held at 1) and one on 2 in turn, best of
   `--calls` calls each, and the ratio 2 threads / 1 thread (<= 1: two never slower).

Ratios are printed, never asserted. Results: benchmarks/results/solver_loop.txt.

    python benchmarks/solver_loop.py [--divisions D] [--repeat R] [--large M] [--calls C]
                                     [--assemble A]
"""
from __future__ import annotations

import argparse
import sys
import time
import tracemalloc

import numpy as np

from common import best_cpu
from diffsurf_cli import threads
from diffsurf_cli.element import element as _element
from diffsurf_cli.element.element import assemble, contact
from diffsurf_cli.facet.surface import FacetSurface
from diffsurf_cli.mls.surface import DiffuseSurface
from diffsurf_cli.testing.shapes import Sphere

RADIUS = 10.0



def _numpy_tangent():
    """The numpy path the compiled tangent replaced: tests/test_tangent_compiled.py's
    `reference_tangent`, loaded from its file."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "tests" / "test_tangent_compiled.py"
    spec = importlib.util.spec_from_file_location("test_tangent_compiled", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.reference_tangent


def batch_tangent(c, penalty, contactor_dofs, target_dofs):
    """The tangent as summed before ℳ was built and added at once: ℳ of a batch of elements
    written (`Hessians.take`), then added by `_assembly.add`."""
    hook = getattr(c.M, "tangent", None)
    if hook is not None:
        c.M.tangent = None
    try:
        return c.tangent(penalty, contactor_dofs, target_dofs)
    finally:
        if hook is not None:
            c.M.tangent = hook


def contactors(m: int, spacing: float, depth: float, seed: int = 1) -> np.ndarray:
    """m points on random rays of the sphere, 0-`depth` node spacings inside it."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((m, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * (RADIUS - rng.uniform(0.0, depth * spacing, (m, 1)))


def tangent_of(c, m: int, n: int, how=None):
    dofs = np.arange(3 * m).reshape(m, 3)
    target = None if c.rigid_target else 3 * m + np.arange(3 * n).reshape(-1, 3)
    if how is None:
        return c.tangent(1.0, dofs, target)
    return how(c, 1.0, dofs, target)


def residual_of(c, m: int, n: int):
    dofs = np.arange(3 * m).reshape(m, 3)
    return c.residual(1.0, dofs, None if c.rigid_target else
                      3 * m + np.arange(3 * n).reshape(-1, 3))


def answer_bytes(c) -> int:
    """Bytes of what `contact` returns (its arrays and the projection's), ℳ whole or not."""
    total = sum(a.nbytes for a in (c.contactor, c.nodes, c.gap, c.N))
    if isinstance(c.M, np.ndarray):
        total += c.M.nbytes
    p = c.projection
    for name in ("points", "gap", "normal", "proximal_point", "status", "support",
                 "iterations", "rcond", "curvature", "reason", "terms"):
        a = getattr(p, name, None)
        total += 0 if a is None else a.nbytes
    if p.patch is not None:
        total += sum(np.asarray(getattr(p.patch, f)).nbytes for f in
                     ("origin", "axes", "radius", "spacing", "index")
                     if getattr(p.patch, f) is not None)
    return total


def peak(run) -> tuple[float, object]:
    tracemalloc.start()
    tracemalloc.reset_peak()
    out = run()
    _, top = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return top, out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--divisions", type=int, default=40)
    ap.add_argument("--points", type=int, default=20_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--large", type=int, default=1_000_000)
    ap.add_argument("--calls", type=int, default=20)
    ap.add_argument("--depth", type=float, default=0.25)
    ap.add_argument("--assemble", type=int, default=100_000)
    args = ap.parse_args(argv)
    reference_tangent = _numpy_tangent()

    shape = Sphere(radius=RADIUS)
    nodes, faces = shape.mesh(args.divisions)
    diffuse, facets = DiffuseSurface(nodes, [faces]), FacetSurface(nodes, [faces])
    h = float(np.median(diffuse.node_spacing))
    points = contactors(args.points, h, args.depth)
    for s in (diffuse, facets):  # engines, grids and the rigid surface built outside timings
        contact(s, points[:100])
        contact(s, points[:100], rigid_target=True)
    print(f"# sphere R = {RADIUS}, {len(nodes)} nodes, spacing {h:.3g}; {len(points)} "
          f"contactors 0-{args.depth} spacings deep; OMP threads {threads.max_threads()}; "
          f"{time.strftime('%Y-%m-%d')}")

    print(f"\n## 1. CPU per contactor (user + system, best of {args.repeat})\n")
    m, n = len(points), len(nodes)
    built = {}
    omp = threads.max_threads

    def one():
        return 1

    threads.max_threads = one  # CPU of one thread: what a contactor costs, without spinning

    def run(name, call):
        return name, call

    calls = {
        "projection (diffuse)": run("p", lambda: diffuse.project(points)),
        "full element: contact()": run("full", lambda: contact(diffuse, points)),
        "full element: every ℳ built": run("M", lambda: np.asarray(built["full"].M)),
        "full element: residual": run("R", lambda: residual_of(built["full"], m, n)),
        "full element: tangent": run("K", lambda: tangent_of(built["full"], m, n)),
        "full element: tangent, ℳ written in batches, then added (e37eebe's flow)": run(
            "Kb", lambda: tangent_of(built["full"], m, n, batch_tangent)),
        "full element: tangent, numpy path (before issue 33)": run(
            "K0", lambda: tangent_of(built["full"], m, n, reference_tangent)),
        "rigid element: contact()": run("rigid", lambda: contact(diffuse, points,
                                                                 rigid_target=True)),
        "rigid element: tangent": run("Kr", lambda: tangent_of(built["rigid"], m, n)),
        "projection (facets)": run("pf", lambda: facets.project(points)),
        "node-to-facet element: contact()": run("facet", lambda: contact(facets, points)),
        "node-to-facet element: tangent": run("Kf", lambda: tangent_of(built["facet"], m, n)),
    }
    # in rounds, every call once a round: a slow spell of the machine falls on all the calls
    # of the rounds it lasts, not on one call's repeats (each call's best round is kept)
    cost = dict.fromkeys(calls, np.inf)
    for _ in range(args.repeat):
        for label, (name, call) in calls.items():
            def go(name=name, call=call):
                built[name] = call()
            cost[label] = min(cost[label], best_cpu(go, 1))
    built.clear()
    threads.max_threads = omp
    print("| call | µs / contactor |\n|---|---|")
    for name, c in cost.items():
        print(f"| {name} | {c / m * 1e6:.2f} |")
    p = cost["projection (diffuse)"]
    full = cost["full element: contact()"] + cost["full element: every ℳ built"]
    rigid = cost["rigid element: contact()"]
    print(f"\nfull element (g, 𝒩, ℳ) / projection (<= 10): {full / p:.1f}; "
          f"rigid element / projection (<= 2): {rigid / p:.2f}; "
          f"node-to-facet element / rigid element: "
          f"{cost['node-to-facet element: contact()'] / rigid:.2f}")
    loop = (cost["full element: contact()"] + cost["full element: residual"]
            + cost["full element: tangent"])
    old = cost["full element: tangent, numpy path (before issue 33)"]
    before = loop - cost["full element: tangent"] + old
    batch = loop - cost["full element: tangent"] + cost[
        "full element: tangent, ℳ written in batches, then added (e37eebe's flow)"]
    print(f"full element (contact + residual + tangent) / projection (<= 10): {loop / p:.2f} "
          f"(with ℳ in batches: {batch / p:.1f}; with the numpy tangent: {before / p:.1f}); "
          f"tangent: numpy / compiled {old / cost['full element: tangent']:.1f}")

    print("\n## 2. Peak memory of contact() (tracemalloc), MB\n")
    print("| contactors | element | peak | answer | peak - answer | ℳ |\n|---|---|---|---|---|---|")
    for count in (m, args.large):
        pts = contactors(count, h, args.depth, seed=2)
        for name, kw in (("full", {}), ("rigid", {"rigid_target": True})):
            top, c = peak(lambda pts=pts, kw=kw: contact(diffuse, pts, **kw))
            kind = ("on demand" if isinstance(c.M, _element.Hessians)
                    else f"{c.M.nbytes / 2**20:.0f} MB whole")
            ans = answer_bytes(c)
            print(f"| {count:,} | {name} | {top / 2**20:.0f} | {ans / 2**20:.0f} | "
                  f"{(top - ans) / 2**20:.0f} | {kind} |", flush=True)
            del c
    pts = contactors(m, h, args.depth, seed=2)
    whole = contact(diffuse, pts)
    top, K = peak(lambda: tangent_of(whole, m, n))
    print(f"\nContact.tangent at {m:,} (full): peak {top / 2**20:.0f} MB, the CSR it returns "
          f"{(K.data.nbytes + K.indices.nbytes + K.indptr.nbytes) / 2**20:.0f} MB")
    whole = K = None
    pts = contactors(args.assemble, h, args.depth, seed=3)
    top, K = peak(lambda: assemble(diffuse, pts, 1.0, np.arange(3 * len(pts)).reshape(-1, 3),
                                   3 * len(pts) + np.arange(3 * n).reshape(-1, 3))[1])
    kb = K.data.nbytes + K.indices.nbytes + K.indptr.nbytes
    print(f"assemble at {len(pts):,} (full): peak {top / 2**20:.0f} MB, the CSR it returns "
          f"{kb / 2**20:.0f} MB: peak / K (<= 1.3) {top / kb:.3f}")
    K = None

    print(f"\n## 3. Wall time of contact() per call, 1 and 2 threads (best of {args.calls} "
          f"calls)\n")
    print("| contactors | element | 1 thread, ms | 2 threads, ms | 2t / 1t (<= 1) |\n"
          "|---|---|---|---|---|")
    for count in (10, 100, 1000, 10000):
        x = points[:count]
        for name, kw in (("full", {}), ("rigid", {"rigid_target": True})):
            wall = {1: np.inf, 2: np.inf}
            for i in range(args.calls):
                for n in ((1, 2) if i % 2 == 0 else (2, 1)):
                    threads.max_threads = omp if n == 2 else one
                    w0 = time.perf_counter()
                    contact(diffuse, x, **kw)
                    wall[n] = min(wall[n], time.perf_counter() - w0)
            threads.max_threads = omp
            print(f"| {count:,} | {name} | {wall[1] * 1e3:.3f} | {wall[2] * 1e3:.3f} | "
                  f"{wall[2] / wall[1]:.2f} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
