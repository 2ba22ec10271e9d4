"""Peak memory of `diffsurf project` on a large contactor cloud (issue 5: 2M points < 1 GB).

Writes N points near a 1692-node sphere to a CSV file, runs the CLI on it as a subprocess (CSV
in, CSV out, default preset) and prints the child's peak resident memory (ru_maxrss) and its
wall time, next to the size of the data itself.

    python benchmarks/memory.py            # 2,000,000 points
    python benchmarks/memory.py -n 200000
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

from diffsurf_cli.testing.shapes import Sphere


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", type=int, default=2_000_000, help="contactor points")
    args = parser.parse_args()
    nodes, faces = Sphere(radius=1.0).mesh(13)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(args.n, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (args.n, 1))
    with tempfile.TemporaryDirectory() as tmp:
        import meshio

        target = os.path.join(tmp, "sphere.vtu")
        meshio.write(target, meshio.Mesh(nodes, [("triangle", faces)]))
        points = os.path.join(tmp, "points.csv")
        with open(points, "w") as fh:
            fh.write("id,x,y,z\n")
            ids = np.arange(args.n)
            for i in range(0, args.n, 100_000):
                block = np.column_stack([ids[i:i + 100_000], pts[i:i + 100_000]])
                np.savetxt(fh, block, delimiter=",", fmt=["%d", "%.17g", "%.17g", "%.17g"])
        out = os.path.join(tmp, "out.csv")
        cmd = [sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", target, points,
               "-o", out]
        t = time.perf_counter()
        subprocess.run(cmd, check=True)
        wall = time.perf_counter() - t
        peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss  # KiB on Linux
        in_mb = os.path.getsize(points) / 2**20
        out_mb = os.path.getsize(out) / 2**20
        rows = sum(1 for _ in open(out)) - 1
    print(f"points: {args.n}  (input CSV {in_mb:.0f} MiB, output CSV {out_mb:.0f} MiB, "
          f"{rows} rows written)")
    print(f"peak resident memory of `diffsurf project`: {peak_kb / 1024:.0f} MiB "
          f"(target < 1024 MiB)")
    print(f"wall time: {wall:.1f} s  ({args.n / wall:,.0f} points/s end to end)")
    return 0 if rows == args.n else 1


if __name__ == "__main__":
    sys.exit(main())
