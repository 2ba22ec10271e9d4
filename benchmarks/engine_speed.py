"""CPU time per point of the projection engine against the old ctypes C kernel, in one run.

Scenes (default options, the same points for every engine):

(a) 200k points within ±5% of a unit sphere meshed with 1692 nodes (`Sphere().mesh(13)`);
(b) 100k points within ±5% of a unit sphere meshed with 400,002 nodes (`Sphere().mesh(200)`).

Each engine runs in its own subprocess: the new one from this tree, the old one (commit
201ecf9, before the one-engine rework: `_old.checkout()` builds it in a worktree). Each
builds its DiffuseSurface (not timed), warms up on 2000 points, then projects the cloud
`--repeat` times; the figure is the best run's CPU time (time.process_time: all threads
summed) divided by the number of points, and its wall time likewise. libigl's pseudonormal
`signed_distance` on scene (a), when importable, is timed the same way in-process (its AABB
tree is built inside every call, as its API does). Ratios are printed, never asserted.

    python benchmarks/engine_speed.py [--repeat R] [--points-a N] [--points-b N]

Instructions per point, repeatable where timings are not (compare versions of the kernel):
`--callgrind N` only projects N points of scene (a) (of scene (b) with `--scene b`) with this
tree's engine, for

    OMP_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/engine.cg \
        --collect-atstart=no \
        --toggle-collect='*Target_*project*' "$(python -c 'import sys; print(sys.executable)')" \
        benchmarks/engine_speed.py --callgrind 20000 [--scene b]

(the instructions of the engine's `Target.project` call alone; divide the "Collected" count
by N; the interpreter itself, not a pyenv shim, must run under valgrind).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(HERE))

WORKER = r"""
import json, sys, time
import numpy as np
# an editable install's import hook would shadow PYTHONPATH: keep it out for the old tree
sys.meta_path = [f for f in sys.meta_path
                 if "__editable__" not in str(getattr(f, "__module__", ""))]
try:
    from diffsurf_cli.mls.surface import DiffuseSurface
except ImportError:
    from diffsurf_cli.surface import DiffuseSurface
import diffsurf_cli
data = np.load(sys.argv[1])
repeat = int(sys.argv[2])
surface = DiffuseSurface(data["nodes"], [data["faces"]])
points = data["points"]
surface.project(points[:2000])
best = None
for _ in range(repeat):
    c0, w0 = time.process_time(), time.perf_counter()
    result = surface.project(points)
    c1, w1 = time.process_time(), time.perf_counter()
    if best is None or c1 - c0 < best[0]:
        best = (c1 - c0, w1 - w0)
np.save(sys.argv[3], result.gap)
print(json.dumps({"cpu": best[0], "wall": best[1], "module": diffsurf_cli.__file__,
                  "answered": int((result.status <= 2).sum())}))
"""


def scene(n_mesh: int, m: int, seed: int):
    """The sphere's mesh and the cloud, cached in benchmarks/out (meshing the 400k-node
    sphere takes seconds, minutes under valgrind)."""
    from shapes import Sphere

    shape = Sphere()
    cache = HERE / "out" / f"scene-sphere{n_mesh}-{m}-{seed}.npz"
    if cache.exists():
        with np.load(cache) as data:
            return data["nodes"], data["faces"], data["points"], shape
    nodes, faces = shape.mesh(n_mesh)
    points = shape.sample_near(m, 0.05, np.random.default_rng(seed))
    cache.parent.mkdir(exist_ok=True)
    tmp = cache.with_suffix(".tmp.npz")
    np.savez(tmp, nodes=nodes, faces=faces, points=points)
    os.replace(tmp, cache)
    return nodes, faces, points, shape


def run_worker(path: Path, data: str, repeat: int, out: str) -> dict:
    """CPU and wall time of the tree at `path` (first on PYTHONPATH) on the scene `data`."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(path) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-c", WORKER, data, str(repeat), out], env=env,
                          capture_output=True, text=True, cwd=tempfile.gettempdir())
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_igl(nodes, faces, points, repeat: int):
    try:
        import igl
    except ImportError:
        return None
    v = np.ascontiguousarray(nodes)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    kind = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
    igl.signed_distance(points[:2000], v, f, sign_type=kind)
    best = None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        igl.signed_distance(points, v, f, sign_type=kind)
        c1, w1 = time.process_time(), time.perf_counter()
        if best is None or c1 - c0 < best[0]:
            best = (c1 - c0, w1 - w0)
    return {"cpu": best[0], "wall": best[1]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--points-a", type=int, default=200_000)
    ap.add_argument("--points-b", type=int, default=100_000)
    ap.add_argument("--callgrind", type=int, metavar="N",
                    help="only project N points of one scene with this tree's engine")
    ap.add_argument("--scene", choices=("a", "b"), default="a",
                    help="the scene --callgrind projects (default a)")
    args = ap.parse_args()
    if args.callgrind:
        # this tree's engine, not an editable install's (the script's own folder comes first)
        sys.path.insert(0, str(ROOT))
        from diffsurf_cli.mls.surface import DiffuseSurface
        import diffsurf_cli

        print(f"engine of {Path(diffsurf_cli.__file__).parent}")

        nodes, faces, points, _ = scene(13 if args.scene == "a" else 200, args.callgrind, 1)
        surface = DiffuseSurface(nodes, [faces])
        surface.engine  # the grids, outside the counted call
        result = surface.project(points)
        print(f"{args.callgrind} points, {int((result.status <= 2).sum())} answered")
        return
    import _old

    old = _old.checkout()
    threads = os.environ.get("OMP_NUM_THREADS", str(os.cpu_count()))
    print(f"CPU time per point (all threads summed; OMP_NUM_THREADS={threads}, "
          f"{os.cpu_count()} CPUs), best of {args.repeat}; old = {old.name}")
    print()
    print("| scene | engine | CPU µs/point | wall µs/point | answered | new/old CPU |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, n_mesh, m in (("(a) sphere 1692 nodes", 13, args.points_a),
                                 ("(b) sphere 400002 nodes", 200, args.points_b)):
            nodes, faces, points, shape = scene(n_mesh, m, 1)
            data = os.path.join(tmp, "scene.npz")
            np.savez(data, nodes=nodes, faces=faces, points=points)
            new = run_worker(ROOT, data, args.repeat, os.path.join(tmp, "new.npy"))
            was = run_worker(old, data, args.repeat, os.path.join(tmp, "old.npy"))
            assert "old-" in was["module"] and "old-" not in new["module"], (was, new)
            gn, go = np.load(os.path.join(tmp, "new.npy")), np.load(os.path.join(tmp, "old.npy"))
            exact = shape.closest(points)[2]
            for name, r, g in (("new (Cython)", new, gn), ("old (ctypes C)", was, go)):
                ok = ~np.isnan(g)
                err = np.abs(g[ok] - exact[ok]).max()
                ratio = f"{new['cpu'] / was['cpu']:.2f}" if r is new else ""
                print(f"| {label} | {name} | {1e6 * r['cpu'] / m:.2f} | "
                      f"{1e6 * r['wall'] / m:.2f} | {r['answered']} (max gap err {err:.1e}) "
                      f"| {ratio} |")
            if n_mesh == 13:
                igl = run_igl(nodes, faces, points, args.repeat)
                if igl is not None:
                    print(f"| {label} | libigl signed_distance (pseudonormal) | "
                          f"{1e6 * igl['cpu'] / m:.2f} | {1e6 * igl['wall'] / m:.2f} | all | "
                          f"new/igl {new['cpu'] / igl['cpu']:.2f} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
