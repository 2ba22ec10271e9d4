"""libigl's pseudonormal `signed_distance` under callgrind (issue 31: the default path is to
cost at most libigl's at 2.5k nodes): instructions a point, its AABB tree built inside the
call as its API does. Run it twice, with and without the call, and subtract:

    PY=/root/.pyenv/versions/3.11.7/bin/python3   # the real interpreter, not a shim
    valgrind --tool=callgrind --callgrind-out-file=/tmp/igl0 $PY benchmarks/callgrind_igl.py 0
    valgrind --tool=callgrind --callgrind-out-file=/tmp/igl1 $PY benchmarks/callgrind_igl.py 1
    # (I refs of the second - I refs of the first) / --points

The points are `query_cost.cloud`'s (within ±5% of a unit icosphere of 4 subdivisions,
2,562 nodes), the first `--points` of its 100,000.
"""
from __future__ import annotations

import argparse
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np


def main(argv=None):
    import igl
    import trimesh

    from query_cost import cloud

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("call", type=int, choices=(0, 1), help="1: call signed_distance")
    ap.add_argument("--points", type=int, default=20_000)
    ap.add_argument("--level", type=int, default=4)
    args = ap.parse_args(argv)
    mesh = trimesh.creation.icosphere(subdivisions=args.level)
    V = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    F = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    points = cloud(100_000)[:args.points]
    if args.call:
        igl.signed_distance(points, V, F,
                            sign_type=igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)


if __name__ == "__main__":
    main()
