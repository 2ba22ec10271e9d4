"""What the speed benchmarks share (patch_speed.py, crossover.py): the filleted box scene,
contactors near a target's facets, and waiting for idle CPUs before a two-thread round."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: where the scenes' meshes are cached (git-ignored)
OUT = HERE / "out" / "patch_speed"

#: element size of the filleted box (~10k nodes)
FILLET_SIZE = 0.0315


def fillet_box() -> str:
    """Scene (a)'s mesh (meshed once, cached in OUT)."""
    from diffsurf_cli.testing import gmsh_scenes

    path = OUT / f"fillet_box_{FILLET_SIZE}.msh"
    if not path.exists():
        OUT.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.msh")
        gmsh_scenes.fillet_box(tmp, size=FILLET_SIZE)
        os.replace(tmp, path)
    return str(path)


def points_near(facets, m: int, band: float = 0.02, seed: int = 1) -> np.ndarray:
    """m points uniform in the box of the facets' nodes grown by band x its diagonal, kept
    where their distance to the facets is within that."""
    rng = np.random.default_rng(seed)
    lo, hi = facets.nodes.min(axis=0), facets.nodes.max(axis=0)
    w = band * float(np.linalg.norm(hi - lo))
    got, total = [], 0
    while total < m:
        p = rng.uniform(lo - w, hi + w, size=(max(4 * m, 10_000), 3))
        p = p[np.abs(facets.project(p).gap) <= w]
        got.append(p)
        total += len(p)
    return np.ascontiguousarray(np.concatenate(got)[:m])


def idle_cpus(seconds: float = 0.3) -> float:
    """CPUs idle over the next `seconds` (/proc/stat; the count of CPUs elsewhere)."""
    def sample():
        with open("/proc/stat") as fh:
            v = [float(t) for t in fh.readline().split()[1:]]
        return sum(v), v[3] + v[4]

    try:
        t0, i0 = sample()
        time.sleep(seconds)
        t1, i1 = sample()
    except OSError:
        return float(os.cpu_count())
    return os.cpu_count() * (i1 - i0) / max(t1 - t0, 1e-9)


def wait_idle(limit: float) -> float:
    """Wait (at most `limit` seconds) until at least 2 CPUs are idle, so that the second
    thread is not measured against another process; the idle CPUs found."""
    end = time.perf_counter() + limit
    while True:
        idle = idle_cpus()
        if idle >= 1.8 or time.perf_counter() > end:
            return idle


def best_cpu(run, repeat: int) -> float:
    """The least CPU time (process time: every thread's) of `repeat` calls of run()."""
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time()
        run()
        best = min(best, time.process_time() - c0)
    return best
