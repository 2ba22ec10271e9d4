"""CPU time per point of the projection engine against the old ctypes C kernel, in one run.

Scenes (default options, the same points for every engine):

(a) 200k points within ±5% of a unit sphere meshed with 1692 nodes (`Sphere().mesh(13)`);
(b) 100k points within ±5% of a unit sphere meshed with 400,002 nodes (`Sphere().mesh(200)`).

Each engine runs in its own subprocess: the new one from this tree, the old one (commit
201ecf9, before the one-engine rework: `_old.checkout()` builds it in a worktree). Each
builds its DiffuseSurface (not timed) and warms up on 2000 points; then the engines project
the cloud in turn, `--repeat` rounds of new, old (and libigl's pseudonormal
`signed_distance` on scene (a), when importable, in this process, its AABB tree built inside
every call as its API does), so that a machine whose speed drifts during the run weighs on
all of them alike. The figure is each engine's best round: CPU time (time.process_time, all
threads summed) per point, and its wall time likewise; the ratio of the bests is printed,
and the spread of the ratio round by round. Ratios are printed, never asserted.

    python benchmarks/engine_speed.py [--repeat R] [--points-a N] [--points-b N]

Instructions per point, repeatable where timings are not (compare versions of the kernel):
`--callgrind N` only projects N points of scene (a) (of scene (b) with `--scene b`) with this
tree's engine, for

    OMP_NUM_THREADS=1 valgrind --tool=callgrind --callgrind-out-file=/tmp/engine.cg \
        --collect-atstart=no \
        --toggle-collect='__pyx_pw_*Target_5project' \
        "$(python -c 'import sys; print(sys.executable)')" \
        benchmarks/engine_speed.py --callgrind 20000 [--scene b]

(the instructions of the engine's `Target.project` call alone; divide the "Collected" count
by N; the interpreter itself, not a pyenv shim, must run under valgrind). The pattern names
Cython's Python-facing wrapper only: one that also matches the function it calls (as
'*Target_*project*' does, under Cython 3.3) toggles collection off again inside it, and
counts a few thousand instructions in all. `--patched` projects them with the scene wrapped
as a `PatchedSurface` of one patch (`feature_angle=None`: the faceted closest point, the
projection, the on-patch test and the guard in one compiled pass), counted with
`--toggle-collect='__pyx_pw_*PatchedPass*project*'`: its instructions over the bare
projection's are the pass's own. `--old` with
`--toggle-collect='*diffsurf_project*'` counts the old kernel's calls (its C kernel alone: not
the Python between its 8192-point chunks), for a new/old ratio that does not move with the
machine.
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
surface = DiffuseSurface(data["nodes"], [data["faces"]])
points = data["points"]
surface.project(points[:2000])
print(json.dumps({"module": diffsurf_cli.__file__}), flush=True)
result = None
for line in sys.stdin:  # one projection of the cloud a "run" line
    if line.strip() != "run":
        break
    c0, w0 = time.process_time(), time.perf_counter()
    result = surface.project(points)
    c1, w1 = time.process_time(), time.perf_counter()
    print(json.dumps({"cpu": c1 - c0, "wall": w1 - w0}), flush=True)
np.save(sys.argv[2], result.gap)
print(json.dumps({"answered": int((result.status <= 2).sum())}), flush=True)
"""


def scene(n_mesh: int, m: int, seed: int):
    """The sphere's mesh and the cloud, cached in benchmarks/out (meshing the 400k-node
    sphere takes seconds, minutes under valgrind)."""
    from diffsurf_cli.testing.shapes import Sphere

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


class Timed:
    """An engine's rounds: `record` keeps its best (least CPU) round."""

    best = None

    def record(self, r: dict) -> dict:
        if self.best is None or r["cpu"] < self.best["cpu"]:
            self.best = r
        return r


class Worker(Timed):
    """An engine in its own process (the tree at `path` first on PYTHONPATH), its target
    built once: `run()` projects the cloud once and returns its CPU and wall time."""

    def __init__(self, path: Path, data: str, out: str):
        env = dict(os.environ)
        env["PYTHONPATH"] = str(path) + os.pathsep + env.get("PYTHONPATH", "")
        self.proc = subprocess.Popen([sys.executable, "-c", WORKER, data, out], env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, cwd=tempfile.gettempdir())
        self.module = self._reply()["module"]

    def _reply(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"the worker failed (exit {self.proc.wait()})")
        return json.loads(line)

    def run(self) -> dict:
        self.proc.stdin.write("run\n")
        self.proc.stdin.flush()
        return self.record(self._reply())

    def close(self) -> int:
        """Stop the worker (it saves its last gaps); the number of contactors answered."""
        self.proc.stdin.write("quit\n")
        self.proc.stdin.flush()
        answered = self._reply()["answered"]
        self.proc.wait()
        return answered


class Igl(Timed):
    """libigl's pseudonormal signed distance on the same points, in this process (its AABB
    tree built inside every call, as its API does)."""

    def __init__(self, igl, nodes, faces, points):
        self.igl = igl
        self.v = np.ascontiguousarray(nodes)
        self.f = np.ascontiguousarray(faces, dtype=np.int64)
        self.points = points
        self.kind = igl.SignedDistanceType.SIGNED_DISTANCE_TYPE_PSEUDONORMAL
        igl.signed_distance(points[:2000], self.v, self.f, sign_type=self.kind)

    def run(self) -> dict:
        c0, w0 = time.process_time(), time.perf_counter()
        self.igl.signed_distance(self.points, self.v, self.f, sign_type=self.kind)
        c1, w1 = time.process_time(), time.perf_counter()
        return self.record({"cpu": c1 - c0, "wall": w1 - w0})


def libigl(nodes, faces, points):
    """An `Igl` of the scene, None where libigl is not installed."""
    try:
        import igl
    except ImportError:
        return None
    return Igl(igl, nodes, faces, points)


def spread(values) -> str:
    return f"{min(values):.2f}-{max(values):.2f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--points-a", type=int, default=200_000)
    ap.add_argument("--points-b", type=int, default=100_000)
    ap.add_argument("--callgrind", type=int, metavar="N",
                    help="only project N points of one scene with this tree's engine")
    ap.add_argument("--scene", choices=("a", "b"), default="a",
                    help="the scene --callgrind projects (default a)")
    ap.add_argument("--patched", action="store_true",
                    help="--callgrind the scene as a one-patch PatchedSurface (its compiled pass)")
    ap.add_argument("--old", action="store_true",
                    help="--callgrind the old kernel (collect '*diffsurf_project*')")
    args = ap.parse_args()
    if args.callgrind:
        if args.old:
            import _old

            # the old tree's package, and no editable install's import hook to shadow it
            sys.meta_path[:] = [f for f in sys.meta_path
                                if "__editable__" not in str(getattr(f, "__module__", ""))]
            _old.load(_old.checkout())
            from diffsurf_cli.surface import DiffuseSurface
        else:
            from diffsurf_cli.mls.surface import DiffuseSurface
        import diffsurf_cli

        print(f"engine of {Path(diffsurf_cli.__file__).parent}")

        nodes, faces, points, _ = scene(13 if args.scene == "a" else 200, args.callgrind, 1)
        if args.patched:
            from diffsurf_cli.patches.surface import PatchedSurface

            surface = PatchedSurface(nodes, [faces], feature_angle=None)
        else:
            surface = DiffuseSurface(nodes, [faces])
        getattr(surface, "engine", None)  # the grids, outside the counted call
        result = surface.project(points)
        print(f"{args.callgrind} points, {int((result.status <= 2).sum())} answered")
        return
    import _old

    old = _old.checkout()
    threads = os.environ.get("OMP_NUM_THREADS", str(os.cpu_count()))
    print(f"CPU time per point (all threads summed; OMP_NUM_THREADS={threads}, "
          f"{os.cpu_count()} CPUs), best of {args.repeat}; old = {old.name}")
    print()
    print("| scene | engine | CPU µs/point | wall µs/point | answered | new/peer CPU "
          "| new/peer, each round |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, n_mesh, m in (("(a) sphere 1692 nodes", 13, args.points_a),
                                 ("(b) sphere 400002 nodes", 200, args.points_b)):
            nodes, faces, points, shape = scene(n_mesh, m, 1)
            data = os.path.join(tmp, "scene.npz")
            np.savez(data, nodes=nodes, faces=faces, points=points)
            new = Worker(ROOT, data, os.path.join(tmp, "new.npy"))
            was = Worker(old, data, os.path.join(tmp, "old.npy"))
            assert "old-" in was.module and "old-" not in new.module, (was.module, new.module)
            igl = libigl(nodes, faces, points) if n_mesh == 13 else None
            # rounds in turn (new, old, libigl, new, ...): a machine that slows down or speeds
            # up during the run weighs on every engine alike
            rounds = {"old": [], "igl": []}
            for _ in range(args.repeat):
                n = new.run()["cpu"]
                rounds["old"].append(n / was.run()["cpu"])
                if igl is not None:
                    rounds["igl"].append(n / igl.run()["cpu"])
            answered = {"new": new.close(), "old": was.close()}
            gn, go = np.load(os.path.join(tmp, "new.npy")), np.load(os.path.join(tmp, "old.npy"))
            exact = shape.closest(points)[2]
            for name, key, r, g in (("new (Cython)", "new", new, gn),
                                    ("old (ctypes C)", "old", was, go)):
                ok = ~np.isnan(g)
                err = np.abs(g[ok] - exact[ok]).max()
                ratio = f"{new.best['cpu'] / was.best['cpu']:.2f}" if r is was else ""
                each = spread(rounds["old"]) if r is was else ""
                print(f"| {label} | {name} | {1e6 * r.best['cpu'] / m:.2f} | "
                      f"{1e6 * r.best['wall'] / m:.2f} | {answered[key]} (max gap err "
                      f"{err:.1e}) | {ratio} | {each} |")
            if igl is not None:
                print(f"| {label} | libigl signed_distance (pseudonormal) | "
                      f"{1e6 * igl.best['cpu'] / m:.2f} | {1e6 * igl.best['wall'] / m:.2f} | "
                      f"all | {new.best['cpu'] / igl.best['cpu']:.2f} | "
                      f"{spread(rounds['igl'])} |")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
