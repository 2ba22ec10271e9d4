"""The target's setup at FE scale (issue 36): CPU and memory a node of the default surface
against one `DiffuseSurface`, `FacetSurface` and libigl, and `diffsurf project` end to end.

Each figure is taken in a child process of its own (one thread), on a trimesh icosphere of
the given subdivisions (6: 41k nodes, 7: 163k, 8: 655k, 9: 2.6M), so that one measurement's
caches and high-water mark do not leak into another's:

- setup: CPU (process time) of building the surface and projecting a first 1,000 points (the
  lazy tables are built there); libigl: its AABB tree and 1,000 `signed_distance` queries
  (pseudonormal sign);
- bytes a node: the child's peak resident memory during the setup less its resident memory
  before it (nodes, faces and the imports already there), over the node count;
- end to end (--cli): `diffsurf project target.vtu points.csv -o out.csv` with as many
  contactors as target nodes, within ±5% of the sphere, against `--method facet`: the child's
  CPU (user + system) and peak resident memory.

    OMP_NUM_THREADS=1 python benchmarks/setup_cost.py                 # 41k, 163k, 655k
    OMP_NUM_THREADS=1 python benchmarks/setup_cost.py --levels 6 7 8 9 --cli 7
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile

KINDS = ("default", "diffuse", "facet", "libigl")


def _child(level: int, kind: str) -> dict:
    """Runs in the child: one setup, its CPU and memory."""
    import time

    import numpy as np
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=level)
    nodes = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    del mesh
    rng = np.random.default_rng(0)
    d = rng.normal(size=(1000, 3))
    points = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (1000, 1))
    if kind == "libigl":
        import igl
    else:
        from diffsurf_cli.facet.surface import FacetSurface
        from diffsurf_cli.mls.surface import DiffuseSurface
        from diffsurf_cli.targets import build_surface
    before = _rss_kib()
    t = time.process_time()
    if kind == "libigl":
        sign = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
        igl.signed_distance(points, nodes, faces.astype(np.int32), sign_type=sign)
    else:
        make = {"default": build_surface, "diffuse": DiffuseSurface,
                "facet": FacetSurface}[kind]
        surface = make(nodes, faces)
        surface.project(points)
    cpu = time.process_time() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"nodes": len(nodes), "cpu": cpu, "bytes_per_node": max(peak - before, 0) * 1024
            / len(nodes)}


def _rss_kib() -> int:
    """The resident memory now (KiB), from /proc (ru_maxrss is the high-water mark)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


def setup(level: int, kind: str) -> dict | None:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    run = subprocess.run([sys.executable, __file__, "--child", str(level), kind], env=env,
                         capture_output=True, text=True)
    if run.returncode != 0:
        if "No module named 'igl'" in run.stderr:
            return None
        raise SystemExit(f"{kind} at level {level} failed:\n{run.stderr}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def end_to_end(level: int) -> list[tuple[str, float, float]]:
    """`diffsurf project` of the level's sphere with as many contactors as nodes: (method,
    CPU s, peak MiB) for the default and --method facet."""
    import meshio
    import numpy as np
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=level)
    rng = np.random.default_rng(1)
    n = len(mesh.vertices)
    d = rng.normal(size=(n, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (n, 1))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        target = os.path.join(tmp, "t.vtu")
        meshio.write(target, meshio.Mesh(mesh.vertices, [("triangle", mesh.faces)]))
        points = os.path.join(tmp, "p.csv")
        np.savetxt(points, pts, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
        for method in ("diffuse", "facet"):
            out = os.path.join(tmp, f"out-{method}.csv")
            cmd = [sys.executable, "-m", "diffsurf_cli", "-q", "project", target, points,
                   "-o", out, "--overwrite"]
            if method == "facet":
                cmd += ["--method", "facet"]
            script = ("import resource, subprocess, sys, json\n"
                      "subprocess.run(sys.argv[1:], check=True)\n"
                      "r = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
                      "print(json.dumps([r.ru_utime + r.ru_stime, r.ru_maxrss]))\n")
            run = subprocess.run([sys.executable, "-c", script, *cmd], capture_output=True,
                                 text=True, env=dict(os.environ, OMP_NUM_THREADS="1"))
            if run.returncode != 0:
                raise SystemExit(run.stderr)
            cpu, peak = json.loads(run.stdout.strip().splitlines()[-1])
            rows.append((method, cpu, peak / 1024))
    return rows


def main() -> int:
    if sys.argv[1:2] == ["--child"]:
        print(json.dumps(_child(int(sys.argv[2]), sys.argv[3])))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[6, 7, 8],
                        help="icosphere subdivisions (6: 41k nodes ... 9: 2.6M)")
    parser.add_argument("--cli", type=int, nargs="*", default=[6],
                        help="levels of the end-to-end `diffsurf project` run (none: skip)")
    args = parser.parse_args()
    print("setup: build + first 1,000 points, one thread; CPU s (µs a node), bytes a node")
    print(f"{'nodes':>9}  " + "  ".join(f"{k:>24}" for k in KINDS) + "  default/facet")
    for level in args.levels:
        res = {k: setup(level, k) for k in KINDS}
        n = res["default"]["nodes"]
        cells = []
        for k in KINDS:
            r = res[k]
            if r is None:
                cells.append(f"{'n/a (no libigl)':>24}")
                continue
            us = r["cpu"] / n * 1e6
            cells.append(f"{r['cpu']:7.2f} ({us:5.1f}) {r['bytes_per_node']:6.0f} B")
        ratio = res["default"]["cpu"] / res["facet"]["cpu"]
        print(f"{n:>9,}  " + "  ".join(cells) + f"  {ratio:12.2f}x")
    for level in args.cli or ():
        rows = end_to_end(level)
        (_, c_d, m_d), (_, c_f, m_f) = rows
        print(f"diffsurf project, level {level}: default {c_d:.2f} s CPU {m_d:.0f} MiB; "
              f"--method facet {c_f:.2f} s {m_f:.0f} MiB; ratio {c_d / c_f:.2f}x CPU")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
