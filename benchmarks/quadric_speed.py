"""The quadric method's cost (issue 35) beside the default surface's, measured in the same run.

What: CPU time of `QuadricSurface.project` (the compiled re-centring, `mls._quadric`, after the
facets' foot of each contactor) and of `build_surface`'s default `project`, on the same points;
and of `contact()` (the element with ℳ: numpy for the quadric method, compiled for the default)
on the same penetrating contactors. Targets: trimesh tori R=2, r=0.5 of 24x8 and 48x16
sections and a 642-node icosphere; points within ±5% of the tube radius (the sphere's) of the
exact surface. Build excluded; best of `REPEAT` runs (process time: both threads count).

    python benchmarks/quadric_speed.py [--points N] [--elements N]

Writes benchmarks/results/quadric_speed.txt (the command and date at the top).
"""
from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import trimesh

from diffsurf_cli.element.element import contact
from diffsurf_cli.targets import build_surface

RESULTS = Path(__file__).resolve().parent / "results"
REPEAT = 3


def targets():
    t24 = trimesh.creation.torus(2.0, 0.5, major_sections=24, minor_sections=8)
    t48 = trimesh.creation.torus(2.0, 0.5, major_sections=48, minor_sections=16)
    ico = trimesh.creation.icosphere(3)
    return [("trimesh torus 24x8", t24, "torus"), ("trimesh torus 48x16", t48, "torus"),
            ("icosphere 3", ico, "sphere")]


def points(kind, m, seed, band=0.05, inside=False):
    """Points near the exact surface (all penetrating with `inside`)."""
    rng = np.random.default_rng(seed)
    off = rng.uniform(-band, 0.0 if inside else band, m)
    if kind == "sphere":
        d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * (1 + off)[:, None]
    u, v = rng.uniform(0, 2 * np.pi, (2, m))
    n = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    return np.stack([2 * np.cos(u), 2 * np.sin(u), 0 * u], 1) + (0.5 + 0.5 * off)[:, None] * n


def best(f, *args):
    """The least CPU time of `REPEAT` calls f(*args)."""
    times = []
    for _ in range(REPEAT):
        start = time.process_time()
        f(*args)
        times.append(time.process_time() - start)
    return min(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=20000)
    parser.add_argument("--elements", type=int, default=1000)
    args = parser.parse_args(argv)
    lines = ["CPU µs a contactor (best of 3; build excluded); ratio = quadric / default", "",
             "| target | nodes | project: default | quadric | ratio | contact(), ℳ: default "
             "| quadric | ratio |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for i, (name, mesh, kind) in enumerate(targets()):
        nodes, faces = np.asarray(mesh.vertices), [np.asarray(mesh.faces)]
        default = build_surface(nodes, faces)
        quadric = build_surface(nodes, faces, method="quadric")
        x = points(kind, args.points, i)
        default.project(x[:100])  # the engines built
        quadric.project(x[:100])
        p_d = best(default.project, x) / len(x) * 1e6
        p_q = best(quadric.project, x) / len(x) * 1e6
        xe = points(kind, args.elements, 10 + i, inside=True)
        e_d = best(contact, default, xe) / len(xe) * 1e6
        e_q = best(contact, quadric, xe) / len(xe) * 1e6
        lines.append(f"| {name} | {len(nodes)} | {p_d:.1f} | {p_q:.1f} | {p_q / p_d:.1f} | "
                     f"{e_d:.1f} | {e_q:.0f} | {e_q / e_d:.0f} |")
        print(f"{name}: done", file=sys.stderr, flush=True)
    command = " ".join(["$ python benchmarks/quadric_speed.py", *(argv or sys.argv[1:])])
    text = "\n".join([command, datetime.now().strftime("%Y-%m-%d %H:%M"), "", *lines]) + "\n"
    print(text)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "quadric_speed.txt").write_text(text)


if __name__ == "__main__":
    main()
