"""`diffsurf project` end to end (CSV in, CSV out, default preset) against the version before
the one-engine rework, measured in the same run.

200k points within ±5% of a unit sphere meshed with ~1.6k nodes (`Sphere().mesh(13)`); each
version runs as its own process (`python -m diffsurf_cli.cli project ...`), `--repeat` times
alternately; the figures are the smallest CPU time (user + system, of the child process and its
threads) and the smallest wall time. Parquet in and out is timed too when the installed version
reads it. Ratios above 1 favour the new version.

    python benchmarks/cli_speed.py [--points N] [--repeat R]
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

from _old import BEFORE_ONE_ENGINE, checkout, environ
from diffsurf_cli import io as dio
from diffsurf_cli.testing.shapes import Sphere


def timed(cmd, env=None, cwd=None):
    """(CPU seconds, wall seconds) of one subprocess run. It runs in `cwd`, away from this
    source tree: `python -m` puts the working directory first on the path, where the tree's
    diffsurf_cli would shadow the old version on PYTHONPATH."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, cwd=cwd, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    old = checkout()
    sphere = Sphere()
    nodes, faces = sphere.mesh(13)
    points = sphere.sample_near(args.points, 0.05, rng=np.random.default_rng(0))
    with tempfile.TemporaryDirectory() as tmp:
        target = os.path.join(tmp, "sphere.vtu")
        dio.write_mesh(target, nodes, [faces], {})
        csv = os.path.join(tmp, "points.csv")
        np.savetxt(csv, points, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
        runs = {
            "new (CSV)": ([sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", target, csv,
                           "--overwrite", "-o", os.path.join(tmp, "new.csv")], None),
            f"old {BEFORE_ONE_ENGINE} (CSV)": (
                [sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", target, csv,
                 "--overwrite", "-o", os.path.join(tmp, "old.csv")], environ(old)),
        }
        try:
            import polars as pl

            pq = os.path.join(tmp, "points.parquet")
            frame = pl.DataFrame({"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]})
            frame.write_parquet(pq)
            probe = subprocess.run([sys.executable, "-m", "diffsurf_cli.cli", "project", target,
                                    pq, "-q", "-o", os.path.join(tmp, "probe.parquet")],
                                   capture_output=True)
            if probe.returncode == 0:
                runs["new (Parquet)"] = ([sys.executable, "-m", "diffsurf_cli.cli", "project",
                                          target, pq, "-q", "--overwrite", "-o",
                                          os.path.join(tmp, "new.parquet")], None)
        except ImportError:
            pass
        where = "import diffsurf_cli; print(diffsurf_cli.__file__)"
        version = subprocess.run([sys.executable, "-c", where], env=environ(old), cwd=tmp,
                                 capture_output=True, text=True).stdout
        assert str(old) in version, f"the old run would import {version}"  # not this tree
        best = {name: [np.inf, np.inf] for name in runs}
        for _ in range(args.repeat):
            for name, (cmd, env) in runs.items():
                cpu, wall = timed(cmd, env, cwd=tmp)
                best[name][0] = min(best[name][0], cpu)
                best[name][1] = min(best[name][1], wall)
    print(f"`diffsurf project` end to end, {args.points} points near a {len(nodes)}-node sphere, "
          f"best of {args.repeat} ({os.cpu_count()} cores)")
    print(f"{'version':24s} {'CPU s':>8s} {'wall s':>8s} {'µs CPU/point':>13s}")
    for name, (cpu, wall) in best.items():
        print(f"{name:24s} {cpu:8.3f} {wall:8.3f} {1e6 * cpu / args.points:13.2f}")
    old_name = f"old {BEFORE_ONE_ENGINE} (CSV)"
    for name in best:
        if name != old_name:
            print(f"ratio old/new CPU, {name}: {best[old_name][0] / best[name][0]:.2f}  "
                  f"wall: {best[old_name][1] / best[name][1]:.2f}")


if __name__ == "__main__":
    main()
