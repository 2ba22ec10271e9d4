"""Where two threads start to pay: the wall time of each compiled entry point with a parallel
loop on batches of m contactors, on one thread (a plain loop) and on two (one parallel
region), in one run (`tol.PARALLEL_MIN` holds the crossovers measured here).

Scene: the filleted box of `patch_speed.py` (gmsh, 12 filleted edges, ~10k nodes) and
contactors within ±2% of its diagonal, m of them drawn at random and sorted along the grid as
the surfaces sort them (a solver's contactors are spread over the target). Each kernel is
driven through its public caller, every other kernel held on one thread:

- project: `DiffuseSurface.project` (`Target.project`); project_with: `project_with` on the
  pairing of an earlier projection;
- pass: `PatchedSurface.project` (`PatchedPass.project`);
- facets: `FacetSurface.project`;
- supports, elements: `_element.supports` and `_element.elements` (the diffuse contact
  element, full basis: `diffuse.diffuse_elements`'s calls) on the pairing of a projection;
- rigid: `RigidTarget.evaluate`; nearest: `_search.nearest_distances` (the node spacing's
  search, run on the target's nodes);
- facet_elements: `_element.facet_elements` (the node-to-facet element) on the facets'
  projection of the batch.

For each batch size, `--rounds` rounds of `--calls` calls on one thread and on two in turn
(`OMP_NUM_THREADS` must allow two), back to back as a solver makes them, after waiting (up to
`--wait-idle` seconds) for two idle CPUs (the table says how many there were). Printed: each
variant's fastest call (what an idle machine gives: calls that no other process delayed) and
its median, and the ratios 1 thread / 2 threads (> 1: two threads win); the crossover is the
first m from which the ratio stays above 1. The threads are chosen by `tol.PARALLEL_MIN`
(set here per kernel: 1 forces two threads, a huge value one). Ratios are printed, never asserted.

    python benchmarks/crossover.py [--kernels project,pass,...] [--rounds R] [--calls C]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from common import fillet_box, points_near, wait_idle
from diffsurf_cli import tol
from diffsurf_cli.threads import max_threads

KERNELS = ("project", "project_with", "pass", "facets", "supports", "elements", "rigid",
           "nearest", "facet_elements")
SIZES = (8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096)
NEVER = 1 << 62


def drivers():
    """kernel -> f(points): one call of the kernel's public caller on these contactors."""
    from diffsurf_cli.element import _element
    from diffsurf_cli.element.rigid import RigidTarget
    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.mls import _search
    from diffsurf_cli.mls.frame import facet_corners
    from diffsurf_cli.mls.surface import DiffuseSurface
    from diffsurf_cli.targets import read_surface, surface_from_file

    path = fillet_box()
    _, nodes, faces = read_surface(path)
    plain = DiffuseSurface(nodes, faces)
    _, patched = surface_from_file(path)
    facets = FacetSurface(nodes, [facet_corners(f) for f in faces])
    rigid = RigidTarget.for_surface(plain)
    pool = points_near(facets, 20_000, seed=3)

    pairing = {}  # batch size -> the pairing of the batch's projection, the support arrays

    def paired(x):
        if len(x) not in pairing:
            proj = plain.project(x, keep_patch=True)
            pa = proj.patch
            full = pa.reduced < 0  # the full basis's rows (one call of the element kernels)
            arrays = [np.ascontiguousarray(a[full]) for a in
                      (x, pa.origin, pa.axes, pa.radius, pa.index, proj.proximal_point)]
            kept, count = np.empty_like(arrays[4]), np.empty(int(full.sum()), np.int64)
            _element.supports(plain.nodes, *arrays[:5], plain.basis, plain.weight, kept, count)
            K = int(count.max(initial=0))
            e = len(count)
            size = 3 * (K + 1)
            pairing[len(x)] = (pa, arrays, kept, count, np.ascontiguousarray(kept[:, :K]),
                               (np.empty(e), np.empty((e, size)), np.empty((e, size, size))))
        return pairing[len(x)]

    def supports(x):
        _, arrays, kept, count, _, _ = paired(x)
        _element.supports(plain.nodes, *arrays[:5], plain.basis, plain.weight, kept, count)

    def elements(x):
        _, arrays, _, count, nodes_k, out = paired(x)
        xc, origin, axes, radius, _, xd = arrays
        _element.elements(plain.nodes, xc, origin, axes, radius, xd, nodes_k, count,
                          plain.basis, plain.weight, *out)

    faceted = {}  # batch size -> the facet element kernel's arguments

    def facet_elements(x):
        if len(x) not in faceted:
            proj = facets.project(x)
            ok = proj.facet >= 0
            side = np.where(np.einsum("ij,ij->i", x - proj.proximal_point, proj.normal) >= 0,
                            1.0, -1.0)
            e = int(ok.sum())
            faceted[len(x)] = (np.ascontiguousarray(facets.facets[proj.facet[ok]]),
                               np.ascontiguousarray(x[ok]),
                               np.ascontiguousarray(proj.param[ok]),
                               np.ascontiguousarray(side[ok]),
                               np.empty(e), np.zeros((e, 15)), np.zeros((e, 15, 15)))
        corners, xc, xi, side, *out = faceted[len(x)]
        _element.facet_elements(facets.nodes, corners, xc, xi, side, facets.sign, *out)

    return pool, {
        "facet_elements": facet_elements,
        "project": plain.project,
        "project_with": lambda x: plain.project_with(x, paired(x)[0]),
        "pass": patched.project,
        "facets": facets.project,
        "supports": supports,
        "elements": elements,
        "rigid": rigid.evaluate,
        "nearest": lambda x: _search.nearest_distances(plain.nodes, 8, x),
    }


def batch(pool, m, seed=0):
    """m contactors of the pool at random, in the order of their grid cells."""
    rng = np.random.default_rng(seed + m)
    x = pool[rng.choice(len(pool), size=m, replace=False)]
    cell = np.ptp(pool, axis=0).max() / 64
    c = np.floor((x - x.min(axis=0)) / cell).astype(np.int64)
    return np.ascontiguousarray(x[np.lexsort((c[:, 2], c[:, 1], c[:, 0]))])


def timed(fn, x):
    w0 = time.perf_counter()
    fn(x)
    return time.perf_counter() - w0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kernels", default=",".join(KERNELS))
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)))
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=10)
    ap.add_argument("--wait-idle", type=float, default=60.0, metavar="S",
                    help="before each batch size, wait up to S seconds for 2 idle CPUs")
    args = ap.parse_args(argv)
    kernels = args.kernels.split(",")
    sizes = [int(s) for s in args.sizes.split(",")]
    if max_threads() < 2:
        raise SystemExit("OpenMP allows one thread here (OMP_NUM_THREADS): nothing to compare")
    saved = dict(tol.PARALLEL_MIN)
    pool, drive = drivers()
    print(f"wall time per call (ms) over {args.rounds} rounds of {args.calls} calls on each "
          f"in turn, fastest and median; "
          f"{os.cpu_count()} CPUs, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}, "
          f"GOMP_SPINCOUNT={os.environ.get('GOMP_SPINCOUNT')}; load "
          f"{os.getloadavg()[0]:.1f}")
    for kernel in kernels:
        print(f"\n{kernel}\n| m | 1 thread, min | 2 threads, min | 1/2 | 1 thread, median | "
              f"2 threads, median | 1/2 | idle CPUs before |\n|---|---|---|---|---|---|---|---|")
        fn = drive[kernel]
        crossover = {"min": None, "median": None}

        def threads(n, kernel=kernel):
            tol.PARALLEL_MIN.update({k: NEVER for k in saved})
            tol.PARALLEL_MIN[kernel] = NEVER if n == 1 else 1

        for m in sizes:
            x = batch(pool, m)
            idle = wait_idle(args.wait_idle)
            walls = {1: [], 2: []}
            for _ in range(args.rounds):
                for n in (1, 2):
                    threads(n)
                    fn(x)  # warm (a pairing, a cache)
                for _ in range(args.calls):  # one call on each, in turn
                    for n in (1, 2):
                        threads(n)
                        walls[n].append(timed(fn, x))
            row = [f"| {m} "]
            for stat, f in (("min", np.min), ("median", np.median)):
                one, two = f(walls[1]), f(walls[2])
                ratio = one / two
                if ratio <= 1:
                    crossover[stat] = None
                elif crossover[stat] is None:
                    crossover[stat] = m
                row.append(f"| {1e3 * one:.3f} | {1e3 * two:.3f} | {ratio:.2f} ")
            print("".join(row) + f"| {idle:.1f} |", flush=True)
        print(f"crossover of {kernel} (two threads faster from there on): "
              f"{crossover['min']} by the fastest calls, {crossover['median']} by the median")
        tol.PARALLEL_MIN.update(saved)


if __name__ == "__main__":
    main()
