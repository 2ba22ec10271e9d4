"""Speed of the patched surface against one surface, plain projection and the facets, on one
and two threads, and of `contact()` in a solver's call pattern, in one run (issue 20).

Scenes (meshes cached in benchmarks/out/patch_speed, git-ignored):

(a) the filleted box: gmsh's box 2 x 1 x 1 with its 12 edges filleted (radius 0.25,
    `gmsh_scenes.fillet_box`), triangles of `common.FILLET_SIZE` (~10k nodes, 26 patches);
(b) a CAD part: gmsh's benchmark part Zylkopf.stp (a cylinder head, 137 CAD faces), meshed by
    gmsh's OpenCASCADE kernel at its diagonal / `CAD_DIVISIONS` (~49k nodes, 137 patches).
    Not committed: `--cad FILE` names the STEP file (or a mesh of it); else it is extracted
    from the local gmsh mirror (`parts.mirror`: `fetch github:live-clones/gmsh`), and the
    run says how to get it when the mirror is missing.

Contactors: `--points` drawn uniformly in the target's box grown by 2% of its diagonal, kept
where their distance to the facets is within 2% of the diagonal (inside and outside).

1. Projection, CPU (time.process_time, all threads summed) and wall time per point of
   - patched: `surface_from_file(path)`, the default `PatchedSurface` (patches, facets at
     sharp edges, guard);
   - one surface: `feature_angle=None`, the guarded `PatchedSurface` of one patch;
   - plain: `DiffuseSurface.project` over the whole target (no facets, no guard);
   - facets: `FacetSurface.project`;
   each at 1 and 2 threads (OMP_NUM_THREADS of two persistent worker processes, each with
   every surface built), `--repeat` rounds in turn (every variant on one thread, then on
   two, ...), so that a machine whose speed drifts weighs on all alike, each round after
   waiting (up to `--wait-idle` seconds) for two idle CPUs; each figure is its best round
   (least CPU). Printed with the issue's ratios: patched / one surface CPU at 1
   thread (target <= 1.3), CPU at 2 threads / 1 thread (<= 1.1) and wall at 2 threads / 1
   thread (<= 0.6 on an idle machine), with their spread round by round.
2. `contact()` in a solver's call pattern: on 10, 100, 1,000 and 10,000 contactors (the first
   of the cloud), `--iterations` calls (fewer for the largest batches: about `CONTACT_WORK`
   contactors in all, at least 5 calls), on the patched surface and on the plain
   `DiffuseSurface`, the full element (g, N, M) and the rigid target's, in the two-thread
   worker: one call on 1 thread (`threads.max_threads` held at 1: every kernel's plain loop,
   as OMP_NUM_THREADS=1 gives), one on 2, in turn, so that both see the same process and the
   same machine (two processes differ by up to 25% in such Python-heavy calls, whatever their
   threads); wall time per call, best of `--repeat` / 2 rounds, and the ratio 2 threads /
   1 thread (target <= 1: two threads never slower). `--solver-ms T` spends T ms of the
   calling thread's time after each call (a solver's own work), so OpenMP's idle thread has
   stopped spinning when the next call comes.

Ratios are printed, never asserted. Results: benchmarks/results/patch_speed.txt.

Instructions, repeatable where timings are not: `--callgrind N` only projects N points of a
scene with one variant (`--variant`, default patched), in this process, for

    OMP_NUM_THREADS=1 valgrind --tool=callgrind --collect-atstart=no \
        --toggle-collect='__pyx_pw_*PatchedPass*project*' \
        "$(python -c 'import sys; print(sys.executable)')" benchmarks/patch_speed.py \
        --callgrind 20000 [--scenes b] [--variant 'one surface']

(the compiled pass alone; `--toggle-collect='__pyx_pw_*Target_5project'` for plain).

    python benchmarks/patch_speed.py [--scenes a,b] [--points N] [--repeat R] [--cad FILE]
                                     [--iterations I] [--solver-ms T] [--no-contact]
                                     [--no-projection]
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

from common import OUT, fillet_box, points_near, wait_idle

#: the CAD part: gmsh's benchmark part (path in the gmsh repository) and its element size,
#: the CAD's bounding-box diagonal / CAD_DIVISIONS (~49k nodes)
CAD_PART = "benchmarks/statreport/Zylkopf.stp"
CAD_DIVISIONS = 145
#: contactors of the `contact()` rows, and the solver's calls of each row: `--iterations`,
#: fewer where that would be more than CONTACT_WORK contactors in all (at least 5)
CONTACT_SIZES = (10, 100, 1000, 10000)
CONTACT_WORK = 100_000
VARIANTS = ("patched", "one surface", "plain", "facets")


# --- scenes ----------------------------------------------------------------------------------
def cad_part(given: str | None = None) -> str:
    """Scene (b)'s mesh: `given` if it is a mesh, else the STEP file (`given`, or extracted
    from the gmsh mirror) meshed at its diagonal / CAD_DIVISIONS (cached in OUT)."""
    if given and Path(given).suffix.lower() not in (".step", ".stp"):
        return given
    if given:
        src = Path(given)
    else:
        import parts

        try:
            git_dir = parts.mirror("gmsh")
        except parts.MissingMirror as exc:
            raise SystemExit(f"scene (b) needs gmsh's {CAD_PART}: pass --cad FILE (a STEP "
                             f"file or its mesh), or bring the mirror: {exc}") from None
        src = parts.extract(git_dir, CAD_PART, OUT / Path(CAD_PART).name)
    path = OUT / f"{src.stem}_{CAD_DIVISIONS}.msh"
    if not path.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.msh")
        subprocess.run([sys.executable, __file__, "_mesh", str(src), str(tmp)], check=True)
        os.replace(tmp, path)
    return str(path)


def _mesh(src: str, out: str) -> None:
    """Mesh a STEP file's surface (a child process: gmsh is one global state)."""
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.occ.importShapes(src)
        gmsh.model.occ.synchronize()
        box = gmsh.model.getBoundingBox(-1, -1)
        h = float(np.linalg.norm(np.subtract(box[3:], box[:3]))) / CAD_DIVISIONS
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
        gmsh.option.setNumber("Mesh.Binary", 1)
        gmsh.model.mesh.generate(2)
        gmsh.write(out)
    finally:
        gmsh.finalize()


# --- the worker: every surface of a scene built once, in its own process ---------------------
def surfaces(path: str) -> dict:
    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.mls.frame import facet_corners
    from diffsurf_cli.mls.surface import DiffuseSurface
    from diffsurf_cli.targets import read_surface, surface_from_file

    _, nodes, faces = read_surface(path)
    return {"patched": surface_from_file(path)[1],
            "one surface": surface_from_file(path, feature_angle=None)[1],
            "plain": DiffuseSurface(nodes, faces),
            "facets": FacetSurface(nodes, [facet_corners(f) for f in faces])}


def worker(path: str, points_file: str) -> None:
    """Answer the parent's requests, one JSON line each, until 'quit'."""
    import logging

    from diffsurf_cli import threads
    from diffsurf_cli.element.element import contact

    omp_threads = threads.max_threads

    def one():
        return 1

    logging.disable(logging.INFO)
    surf = surfaces(path)
    points = np.load(points_file)
    for s in surf.values():  # engines (and grids) built outside the timings
        s.project(points[:200])
    for name in ("patched", "plain"):
        contact(surf[name], points[:200])
        contact(surf[name], points[:200], rigid_target=True)
    info = {"nodes": len(surf["plain"].nodes), "patches": surf["patched"].npatches}
    print(json.dumps(info), flush=True)
    for line in sys.stdin:
        req = json.loads(line)
        if req["op"] == "quit":
            break
        if req["op"] == "project":
            s = surf[req["variant"]]
            c0, w0 = time.process_time(), time.perf_counter()
            s.project(points)
            c1, w1 = time.process_time(), time.perf_counter()
        else:  # contact: calls on 1 and on 2 threads in turn, each variant's times summed
            s = surf[req["variant"]]
            x = points[:req["m"]]
            rigid = req["element"] == "rigid"
            pause = req["solver_ms"] / 1e3
            spent = {1: [0.0, 0.0], 2: [0.0, 0.0]}  # threads -> [cpu, wall]
            for i in range(req["iterations"]):
                for n in ((1, 2) if i % 2 == 0 else (2, 1)):
                    threads.max_threads = omp_threads if n == 2 else one
                    c0, w0 = time.process_time(), time.perf_counter()
                    contact(s, x, rigid_target=rigid)
                    c1, w1 = time.process_time(), time.perf_counter()
                    spent[n][0] += c1 - c0
                    spent[n][1] += w1 - w0
                    if pause:
                        t = time.perf_counter()
                        while time.perf_counter() - t < pause:  # the solver's own work
                            pass
            threads.max_threads = omp_threads
            print(json.dumps({n: {"cpu": c, "wall": w} for n, (c, w) in spent.items()}),
                  flush=True)
            continue
        print(json.dumps({"cpu": c1 - c0, "wall": w1 - w0}), flush=True)


class Worker:
    """A worker process on `threads` OpenMP threads."""

    def __init__(self, path: str, points_file: str, threads: int):
        env = dict(os.environ, OMP_NUM_THREADS=str(threads))
        self.proc = subprocess.Popen([sys.executable, __file__, "_worker", path, points_file],
                                     env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True)
        self.info = self._reply()

    def _reply(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"a worker failed (exit {self.proc.wait()})")
        return json.loads(line)

    def ask(self, **req) -> dict:
        self.proc.stdin.write(json.dumps(req) + "\n")
        self.proc.stdin.flush()
        return self._reply()

    def close(self) -> None:
        self.proc.stdin.write(json.dumps({"op": "quit"}) + "\n")
        self.proc.stdin.flush()
        self.proc.wait()


# --- the run ---------------------------------------------------------------------------------
def spread(values) -> str:
    return f"{min(values):.2f}-{max(values):.2f}"


def projection_table(workers: dict, m: int, repeat: int, label: str, wait: float) -> None:
    best: dict = {}
    rounds = []  # each round's figures: (variant, threads) -> {cpu, wall}
    idle = []
    for _ in range(repeat):
        idle.append(wait_idle(wait))
        got = {}
        for variant in VARIANTS:
            for threads in (1, 2):
                r = workers[threads].ask(op="project", variant=variant)
                got[variant, threads] = r
                if (variant, threads) not in best or r["cpu"] < best[variant, threads]["cpu"]:
                    best[variant, threads] = r
        rounds.append(got)
    print(f"\n### {label}: projection of {m} points (idle CPUs before each round: "
          f"{', '.join(f'{i:.1f}' for i in idle)})\n")
    print("| variant | CPU µs/pt, 1 thread | CPU µs/pt, 2 threads | wall µs/pt, 1 thread "
          "| wall µs/pt, 2 threads | CPU 2t/1t (<= 1.1) | wall 2t/1t (<= 0.6) |")
    print("|---|---|---|---|---|---|---|")
    for v in VARIANTS:
        b1, b2 = best[v, 1], best[v, 2]
        cpu = [r[v, 2]["cpu"] / r[v, 1]["cpu"] for r in rounds]
        wall = [r[v, 2]["wall"] / r[v, 1]["wall"] for r in rounds]
        print(f"| {v} | {1e6 * b1['cpu'] / m:.2f} | {1e6 * b2['cpu'] / m:.2f} | "
              f"{1e6 * b1['wall'] / m:.2f} | {1e6 * b2['wall'] / m:.2f} | "
              f"{b2['cpu'] / b1['cpu']:.2f} ({spread(cpu)}) | "
              f"{b2['wall'] / b1['wall']:.2f} ({spread(wall)}) |")
    ratio = [r["patched", 1]["cpu"] / r["one surface", 1]["cpu"] for r in rounds]
    print(f"\npatched / one surface, CPU at 1 thread (<= 1.3): "
          f"{best['patched', 1]['cpu'] / best['one surface', 1]['cpu']:.2f} "
          f"({spread(ratio)} round by round); patched / plain "
          f"{best['patched', 1]['cpu'] / best['plain', 1]['cpu']:.2f}, "
          f"one surface / plain {best['one surface', 1]['cpu'] / best['plain', 1]['cpu']:.2f}, "
          f"facets / plain {best['facets', 1]['cpu'] / best['plain', 1]['cpu']:.2f}")
    sys.stdout.flush()


def contact_table(workers: dict, repeat: int, iterations: int, solver_ms: float,
                  label: str, wait: float) -> None:
    print(f"\n### {label}: contact(), a solver's calls in a row"
          f"{f' ({solver_ms:g} ms of solver work between calls)' if solver_ms else ''}\n")
    print("| surface | element | contactors | calls | wall ms/call, 1 thread | "
          "wall ms/call, 2 threads | 2t/1t (<= 1) | CPU ms/call, 1 thread | "
          "CPU ms/call, 2 threads |")
    print("|---|---|---|---|---|---|---|---|---|")
    for variant in ("patched", "plain"):
        for element in ("full", "rigid"):
            for m in CONTACT_SIZES:
                calls = max(5, min(iterations, CONTACT_WORK // m))
                best = {1: None, 2: None}
                ratios = []
                for _ in range(repeat):
                    wait_idle(wait)
                    got = workers[2].ask(op="contact", variant=variant, element=element, m=m,
                                         iterations=calls, solver_ms=solver_ms)
                    got = {int(k): v for k, v in got.items()}
                    for n in (1, 2):
                        if best[n] is None or got[n]["wall"] < best[n]["wall"]:
                            best[n] = got[n]
                    ratios.append(got[2]["wall"] / got[1]["wall"])
                b1, b2 = best[1], best[2]
                print(f"| {variant} | {element} | {m} | {calls} | "
                      f"{1e3 * b1['wall'] / calls:.3f} | {1e3 * b2['wall'] / calls:.3f} | "
                      f"{b2['wall'] / b1['wall']:.2f} ({spread(ratios)}) | "
                      f"{1e3 * b1['cpu'] / calls:.3f} | {1e3 * b2['cpu'] / calls:.3f} |",
                      flush=True)


def callgrind(args) -> None:
    """Project `--callgrind` points of the first scene with one variant (nothing timed)."""
    import logging

    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.mls.frame import facet_corners
    from diffsurf_cli.targets import read_surface

    logging.disable(logging.INFO)
    key = args.scenes.split(",")[0]
    path = fillet_box() if key == "a" else cad_part(args.cad)
    _, nodes, faces = read_surface(path)
    points = points_near(FacetSurface(nodes, [facet_corners(f) for f in faces]), args.callgrind)
    surface = surfaces(path)[args.variant]
    getattr(surface, "engine", None)  # built outside the counted call
    result = surface.project(points)
    print(f"scene {key}, {args.variant}: {args.callgrind} points, "
          f"{int((result.status <= 2).sum())} answered")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="a,b")
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--cad", help="scene (b)'s STEP file or mesh (default: from the mirror)")
    ap.add_argument("--iterations", type=int, default=50)
    ap.add_argument("--solver-ms", type=float, default=0.0)
    ap.add_argument("--no-contact", action="store_true")
    ap.add_argument("--no-projection", action="store_true")
    ap.add_argument("--wait-idle", type=float, default=60.0, metavar="S",
                    help="before each round, wait up to S seconds for 2 idle CPUs")
    ap.add_argument("--callgrind", type=int, metavar="N",
                    help="only project N points of the first scene with --variant")
    ap.add_argument("--variant", choices=VARIANTS, default="patched")
    args = ap.parse_args(argv)
    if args.callgrind:
        return callgrind(args)
    env = {k: os.environ.get(k) for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    print(f"# python benchmarks/patch_speed.py {' '.join(argv or sys.argv[1:])}\n")
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f} at the start; best of "
          f"{args.repeat} rounds; environment {env}")
    from diffsurf_cli.facet.surface import FacetSurface
    from diffsurf_cli.mls.frame import facet_corners
    from diffsurf_cli.targets import read_surface

    scenes = {"a": ("(a) filleted box", fillet_box), "b": ("(b) CAD part Zylkopf",
                                                          lambda: cad_part(args.cad))}
    with tempfile.TemporaryDirectory() as tmp:
        for key in args.scenes.split(","):
            label, make = scenes[key]
            path = make()
            _, nodes, faces = read_surface(path)
            points = points_near(FacetSurface(nodes, [facet_corners(f) for f in faces]),
                                 args.points)
            points_file = os.path.join(tmp, f"points_{key}.npy")
            np.save(points_file, points)
            workers = {t: Worker(path, points_file, t) for t in (1, 2)}
            info = workers[1].info
            label = f"{label} ({info['nodes']} nodes, {info['patches']} patches)"
            try:
                if not args.no_projection:
                    projection_table(workers, len(points), args.repeat, label, args.wait_idle)
                if not args.no_contact:
                    contact_table(workers, max(3, args.repeat // 2), args.iterations,
                                  args.solver_ms, label, args.wait_idle)
            finally:
                for w in workers.values():
                    w.close()
    print(f"\nload {os.getloadavg()[0]:.1f} at the end")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "_worker":
        worker(sys.argv[2], sys.argv[3])
    elif len(sys.argv) > 1 and sys.argv[1] == "_mesh":
        _mesh(sys.argv[2], sys.argv[3])
    else:
        main()
