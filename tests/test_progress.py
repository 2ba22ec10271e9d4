"""Long jobs draw a progress bar on stderr when it is a terminal, and nothing otherwise."""
from __future__ import annotations

import os
import pty
import subprocess
import sys
import tempfile

import meshio
import numpy as np
import pytest

from diffsurf_cli.mls.surface import CHUNK
from diffsurf_cli.testing.shapes import Sphere


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
    master, slave = pty.openpty()
    # stdout to a file: a pipe nobody reads while the terminal is drained would fill and block
    sink = tempfile.TemporaryFile()
    p = subprocess.Popen(cmd, stdout=sink, stderr=slave)
    os.close(slave)
    err = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        err += chunk
    p.wait(timeout=300)
    os.close(master)
    sink.seek(0)
    out = sink.read()
    return p.returncode, out, err


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


def test_eta_counts_from_the_work_not_the_setup(monkeypatch):
    """Issue 22, item 14: `project` on 2M points showed an ETA of 8:54 for an 18-second job:
    click's ETA is the time since the bar's start over the work done, and the bar started
    before the table was read and the engine built. The ETA now counts from progress(0), the
    work's start. A fake clock: 20 s of setup, then 1 s a chunk, 10 of 100 chunks done: 90 s
    to go."""
    import io
    import re
    import time
    from types import SimpleNamespace

    from diffsurf_cli.cli.common import progress_bar

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    clock = [1000.0]
    monkeypatch.setattr(time, "time", lambda: clock[0])
    monkeypatch.setattr(sys, "stderr", Terminal())
    ctx = SimpleNamespace(obj={})
    with progress_bar(ctx, 100 * CHUNK, "projecting") as update:
        assert update is not None
        clock[0] += 20.0  # reading the points, building the engine
        update(0)
        for i in range(1, 11):
            clock[0] += 1.0
            update(i * CHUNK)
        shown = sys.stderr.getvalue()
    h, m, s = map(int, re.findall(r"(\d\d):(\d\d):(\d\d)", shown)[-1])
    assert 80 <= 3600 * h + 60 * m + s <= 100, shown[-200:]
