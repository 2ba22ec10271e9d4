"""`diffsurf project --workers N` on a local Dask cluster, Parquet partitions in and out,
against one process in the same run: throughput, and peak memory per worker bounded whatever
the number of contactors.

The target is a unit sphere meshed with 25,002 nodes (`Sphere().mesh(50)`); the contactors lie
within ±0.05 of it, in Parquet partitions of `--partition` rows (an id column passed through).
Every run is the command line as a user types it, in its own process:

    diffsurf project sphere.vtu points-N/ -o out/ --workers W --overwrite

for N = `--points` / 4 and `--points`, W = 1 and 2 (`--workers`). The peer is the one-machine
command on one Parquet file of N / 4 rows (`diffsurf project sphere.vtu points.parquet -o
out.parquet`), its engine threaded over every core; the workers run one engine thread each.

Reported per run: wall time and throughput (contactors per wall second, cluster start-up
included), CPU time per contactor (user + system of the command and every process it started,
from getrusage), the peak resident memory of each worker as its tasks saw it (the command's
log), the largest peak of any process of the run (the command itself included: it holds the
target and, for the peer, every contactor), and the machine's load average at the end of the
run (above the run's own worker count, other work shared the cores and the times are longer);
'cores' is the CPU time over the wall time: the cores the run actually had.

    python benchmarks/cluster.py                      # 5M and 20M contactors (~10 min on 2 cores)
    python benchmarks/cluster.py --points 2000000     # a quick run
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from diffsurf_cli import io as dio
from diffsurf_cli.testing.shapes import Sphere

#: runs a command and prints, as JSON, the CPU time and the largest peak resident memory of
#: the command and every process it started and waited for (getrusage of the children)
_WRAP = """
import json, resource, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
wall = time.perf_counter() - t0
r = resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps({"rc": p.returncode, "wall": wall, "cpu": r.ru_utime + r.ru_stime,
                  "maxrss": r.ru_maxrss * 1024, "stderr": p.stderr}))
"""


def measure(cmd: list[str]) -> dict:
    out = subprocess.run([sys.executable, "-c", _WRAP, *cmd], check=True,
                         stdout=subprocess.PIPE, text=True).stdout
    run = json.loads(out)
    run["load"] = os.getloadavg()[0]  # other work on the machine over the last minute
    if run["rc"]:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{run['stderr']}")
    workers = re.search(r"peak memory per worker: ([\d, ]+) MB", run["stderr"])
    run["workers_mb"] = [int(v) for v in workers.group(1).split(",")] if workers else []
    return run


def write_points(directory: Path, total: int, partition: int) -> list[Path]:
    """Contactors within ±0.05 of the unit sphere, `partition` rows per Parquet file."""
    import polars as pl

    directory.mkdir(parents=True, exist_ok=True)
    sphere, paths = Sphere(), []
    for i, lo in enumerate(range(0, total, partition)):
        m = min(partition, total - lo)
        p = sphere.sample_near(m, 0.05, rng=np.random.default_rng(i))
        path = directory / f"part-{i:05d}.parquet"
        pl.DataFrame({"id": np.arange(lo, lo + m), "x": p[:, 0], "y": p[:, 1],
                      "z": p[:, 2]}).write_parquet(path)
        paths.append(path)
    return paths


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=20_000_000,
                    help="the larger count; the smaller is a quarter of it")
    ap.add_argument("--partition", type=int, default=500_000, help="rows per partition file")
    ap.add_argument("--workers", default="1,2", help="local worker counts to run")
    ap.add_argument("--no-peer", action="store_true", help="skip the one-process run")
    ap.add_argument("--dir", default=None, help="working directory (default: a temporary one "
                    "under benchmarks/out, removed at the end)")
    args = ap.parse_args(argv)
    workers = [int(w) for w in args.workers.split(",")]
    base = Path(__file__).resolve().parent / "out"
    base.mkdir(exist_ok=True)
    work = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="cluster-", dir=base))
    work.mkdir(parents=True, exist_ok=True)
    diffsurf = [sys.executable, "-m", "diffsurf_cli.cli", "project"]
    try:
        t0 = time.perf_counter()
        nodes, faces = Sphere().mesh(50)
        target = work / "sphere.vtu"
        dio.write_mesh(str(target), nodes, [faces], {}, overwrite=True)
        large = args.points
        small = max(args.partition, (large // 4) // args.partition * args.partition)
        paths = write_points(work / f"points-{large}", large, args.partition)
        subset = work / f"points-{small}"  # the first partitions of the larger set
        subset.mkdir(exist_ok=True)
        for p in paths[:small // args.partition]:
            if not (subset / p.name).exists():
                os.symlink(p, subset / p.name)
        print(f"target {len(nodes)} nodes; {large} contactors in {len(paths)} partitions of "
              f"{args.partition}; written in {time.perf_counter() - t0:.0f} s ({work})",
              flush=True)

        rows = []
        if not args.no_peer:
            import polars as pl

            one = work / f"points-{small}.parquet"
            pl.concat([pl.read_parquet(p) for p in sorted(subset.iterdir())]) \
                .write_parquet(one)
            run = measure([*diffsurf, str(target), str(one), "-o", str(work / "one.parquet"),
                           "--overwrite"])
            rows.append((small, "one process", run))
            print(f"  {small}: one process: {run['wall']:.1f} s", flush=True)
        for count, points in ((small, subset), (large, work / f"points-{large}")):
            for w in workers:
                run = measure([*diffsurf, str(target), str(points), "-o", f"{work / 'out'}/",
                               "--workers", str(w), "--overwrite", "-v"])
                rows.append((count, f"{w} worker{'s' if w > 1 else ''}", run))
                print(f"  {count}: {w} workers: {run['wall']:.1f} s", flush=True)
    finally:
        if not args.dir:
            shutil.rmtree(work, ignore_errors=True)

    print()
    print(f"{'contactors':>10}  {'run':<12} {'wall s':>7} {'contactors/s':>12} "
          f"{'CPU µs/pt':>9} {'cores':>5}  {'peak MB per worker':<18} "
          f"{'largest process MB':>18} {'load':>5}")
    for count, name, run in rows:
        print(f"{count:>10}  {name:<12} {run['wall']:7.1f} {count / run['wall']:12.0f} "
              f"{1e6 * run['cpu'] / count:9.2f} {run['cpu'] / run['wall']:5.2f}  "
              f"{', '.join(map(str, run['workers_mb'])) or '-':<18} "
              f"{run['maxrss'] / 2**20:18.0f} {run['load']:5.1f}")
    rate = {(c, n): c / r["wall"] for c, n, r in rows}
    mem = {(c, n): max(r["workers_mb"]) for c, n, r in rows if r["workers_mb"]}
    print()
    for w in workers[1:]:
        name = f"{w} workers"
        print(f"throughput {name} / 1 worker: "
              + ", ".join(f"{rate[(c, name)] / rate[(c, '1 worker')]:.2f} at {c}"
                          for c in (small, large)))
    if not args.no_peer:
        for w in workers:
            name = f"{w} worker{'s' if w > 1 else ''}"
            print(f"throughput {name} / one process at {small}: "
                  f"{rate[(small, name)] / rate[(small, 'one process')]:.2f}")
    for w in workers:
        name = f"{w} worker{'s' if w > 1 else ''}"
        print(f"peak memory per worker, {name}: {mem[(large, name)]} MB at {large} against "
              f"{mem[(small, name)]} MB at {small} (ratio "
              f"{mem[(large, name)] / mem[(small, name)]:.2f} for {large / small:.0f}x the "
              f"contactors)")


if __name__ == "__main__":
    main()
