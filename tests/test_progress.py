"""Long jobs draw a progress bar on stderr when it is a terminal, and nothing otherwise."""
from __future__ import annotations

import subprocess
import sys

import meshio
import numpy as np
import pytest

from diffsurf_cli.mls.surface import CHUNK
from diffsurf_cli.testing.shapes import Sphere
from samples import run_on_terminal


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """A sphere target and more contactors than one chunk."""
    tmp = tmp_path_factory.mktemp("progress")
    nodes, faces = Sphere(radius=1.0).mesh(6)
    target = tmp / "sphere.vtu"
    meshio.write(target, meshio.Mesh(nodes, [("triangle", faces)]))
    rng = np.random.default_rng(1)
    d = rng.normal(size=(CHUNK + 500, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0.95, 1.05, (len(d), 1))
    points = tmp / "points.csv"
    np.savetxt(points, pts, delimiter=",", header="x,y,z", comments="", fmt="%.17g")
    return tmp, str(target), str(points)


def _run(args, stderr_tty: bool):
    cmd = [sys.executable, "-m", "diffsurf_cli.cli", *args]
    if not stderr_tty:
        p = subprocess.run(cmd, capture_output=True, timeout=300)
        return p.returncode, p.stdout, p.stderr
    return run_on_terminal(cmd, timeout=300)


def test_progress_bar_on_a_terminal(job):
    tmp, target, points = job
    code, out, err = _run(["project", target, points], stderr_tty=True)
    assert code == 0, err
    assert b"projecting" in err and f"{CHUNK + 500}/{CHUNK + 500}".encode() in err
    # stdout is the result only
    lines = out.decode().splitlines()
    assert lines[0].startswith("x,y,z,gap") and len(lines) == CHUNK + 501


@pytest.mark.parametrize("args", [[], ["-q"]])
def test_progress_silent_when_not_a_terminal_or_quiet(job, args):
    tmp, target, points = job
    code, out, err = _run([*args, "project", target, points], stderr_tty=False)
    assert code == 0, err
    assert b"projecting" not in err
    if args:
        assert err == b""
    code, out, err = _run(["-q", "project", target, points], stderr_tty=True)
    assert code == 0 and b"projecting" not in err



def test_eta_counts_from_the_work_not_the_setup(job, monkeypatch, tmp_path):
    """Issue 22, item 14: `project` on 2M points showed an ETA of 8:54 for an 18-second job:
    click's ETA is the time since the bar's start over the work done, and the bar started
    before the engine was built. It now counts from the work's start (the surface's
    progress(0)). `diffsurf project` on a terminal, with a fake clock: 20 s of setup inside
    the projection, then 1 s a chunk; every ETA shown is the chunks left, in seconds."""
    import io
    import re
    import time

    from diffsurf_cli.cli import main
    from diffsurf_cli.patches.surface import PatchedSurface

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    clock = [1000.0]
    monkeypatch.setattr(time, "time", lambda: clock[0])
    project = PatchedSurface.project

    def slow(self, points, *, progress=None, **kw):
        clock[0] += 20.0  # building the engine, ordering the points

        def tick(n):
            clock[0] += 1.0 if n else 0.0  # a chunk's work
            progress(n)

        return project(self, points, progress=tick if progress else None, **kw)

    monkeypatch.setattr(PatchedSurface, "project", slow)
    monkeypatch.setattr(sys, "stderr", Terminal())
    _, target, _ = job
    chunks = 10
    rng = np.random.default_rng(2)
    d = rng.normal(size=(chunks * CHUNK, 3))
    points = tmp_path / "points.csv"
    np.savetxt(points, d / np.linalg.norm(d, axis=1, keepdims=True), delimiter=",",
               header="x,y,z", comments="", fmt="%.17g")
    main(["project", target, str(points), "-o", str(tmp_path / "r.parquet")],
         standalone_mode=False)
    shown = sys.stderr.getvalue()
    assert "projecting" in shown
    etas = [3600 * int(h) + 60 * int(m) + int(s)
            for h, m, s in re.findall(r"(\d\d):(\d\d):(\d\d)", shown)]
    assert len(etas) >= chunks - 2 and max(etas) <= chunks, shown
