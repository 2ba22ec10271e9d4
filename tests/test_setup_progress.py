"""Issue 36, item 3: the target's setup (reading it, building its surface and its engine) shows
its stages on stderr when it is a terminal and the setup lasts a second or more, as the
projection's bar does, and logs its time; nothing extra on a small target, off a terminal or
with -q."""
from __future__ import annotations

import io
import os
import re
import subprocess
import sys

import numpy as np
import pytest

from diffsurf_cli import cli
from diffsurf_cli.cli import main
from diffsurf_cli.targets import STAGES, surface_from_file
from samples import run_on_terminal

common = cli.common  # the threshold's module (the entry point's package, not imported apart)

HERE = os.path.dirname(__file__)
CYLINDER = os.path.join(HERE, "..", "sample_meshes", "cylinder.msh")
PLATE = os.path.join(HERE, "..", "sample_meshes", "plate.csv")

#: what the default surface goes through, in order (the command line adds 'engine')
PATCHED = ["reading", "winding", "node identity", "edges and patches", "facets",
           "edge classes", "rings", "guard bounds", "curved cells", "diffuse surface"]


def _increasing(stages):
    return [STAGES.index(s) for s in stages] == sorted(STAGES.index(s) for s in stages)


@pytest.mark.parametrize("kw, expected", [
    ({}, PATCHED),  # the default: per smooth patch
    ({"feature_angle": 180}, PATCHED),  # one diffuse surface over the whole target
    ({"method": "facet"}, ["reading", "winding", "facets"]),
])
def test_the_build_calls_progress_with_its_stages_in_order(kw, expected):
    stages = []
    _, surf = surface_from_file(CYLINDER, preset="fast", progress=stages.append, **kw)
    assert stages == expected and _increasing(stages)
    # the callback changes nothing: the same surface without it
    _, plain = surface_from_file(CYLINDER, preset="fast", **kw)
    pts = np.loadtxt(PLATE, delimiter=",", skiprows=1, usecols=(1, 2, 3))
    a, b = surf.project(pts), plain.project(pts)
    assert np.isfinite(a.gap).any() and np.array_equal(a.gap, b.gap, equal_nan=True)


def _run(args, *, tty: bool, threshold: float | None = 0.0):
    """`diffsurf ARGS` in a child, stderr a pseudo-terminal or a pipe, the setup's threshold
    (`common.SETUP_REPORT_SECONDS`) set to `threshold` (0: always shown, without a target
    large enough to take a second)."""
    code = ("import diffsurf_cli.cli.common as c; "
            + (f"c.SETUP_REPORT_SECONDS = {threshold!r}; " if threshold is not None else "")
            + "from diffsurf_cli.cli import main; main(prog_name='diffsurf')")
    cmd = [sys.executable, "-c", code, *args]
    if not tty:
        p = subprocess.run(cmd, capture_output=True, timeout=120)
        return p.returncode, p.stderr
    code, _, err = run_on_terminal(cmd, timeout=120)
    return code, err


def test_the_setup_line_on_a_terminal(tmp_path):
    code, err = _run(["project", CYLINDER, PLATE, "-o", str(tmp_path / "r.csv")], tty=True)
    assert code == 0, err
    text = err.decode()
    for stage in ("reading", "guard bounds", "diffuse surface", "engine"):
        assert f"\r\x1b[Kdiffsurf: setting up the target: {stage} (" in text, text
    # one self-overwriting line: it never ends a line itself, and is cleared before each log
    # line and at the setup's end
    assert not re.search(r"setting up the target: [^\r\n]*\n", text), text
    tail = text[text.index("setting up the target: engine"):]
    assert tail.index("\r\x1b[K") < tail.index("diffsurf: target set up in ")
    assert "diffsurf: target set up in " in text and "status: " in text


def test_the_setup_line_is_cleared_before_the_projection_bar(tmp_path):
    """On a terminal, the projection's bar (more contactors than a chunk) starts on a clean
    line: the setup's line is cleared before it."""
    from diffsurf_cli.mls.surface import CHUNK

    rng = np.random.default_rng(3)
    d = rng.normal(size=(CHUNK + 10, 3))
    points = tmp_path / "points.csv"
    np.savetxt(points, d, delimiter=",", header="x,y,z", comments="", fmt="%.6g")
    code, err = _run(["project", CYLINDER, str(points), "-o", str(tmp_path / "r.csv")],
                     tty=True)
    assert code == 0, err
    text = err.decode()
    last = text.rindex("setting up the target")
    bar = text.index("diffsurf: projecting")
    assert last < bar and "\r\x1b[K" in text[last:bar]


@pytest.mark.parametrize("quiet", [False, True])
def test_nothing_extra_off_a_terminal_or_quiet(tmp_path, quiet):
    args = ["-q"] if quiet else []
    code, err = _run([*args, "project", CYLINDER, PLATE, "-o", str(tmp_path / "r.csv")],
                     tty=False)
    assert code == 0, err
    assert b"setting up" not in err and b"\x1b" not in err and b"\r" not in err
    # the log line only (none under -q)
    assert (b"target set up in" in err) is not quiet
    if quiet:
        code, err = _run(["-q", "project", CYLINDER, PLATE, "-o", str(tmp_path / "q.csv")],
                         tty=True)
        assert code == 0 and err == b"", err


def test_a_small_target_says_nothing_on_a_terminal(tmp_path):
    """Below the threshold (a setup much shorter than it): no line, no time logged."""
    code, err = _run(["project", CYLINDER, PLATE, "-o", str(tmp_path / "r.csv")], tty=True,
                     threshold=1e9)
    assert code == 0, err
    assert b"setting up" not in err and b"set up in" not in err and b"\x1b" not in err
    assert common.SETUP_REPORT_SECONDS == 1.0  # the default: a second


@pytest.mark.parametrize("threshold, logged", [(0.0, True), (1e9, False)])
def test_the_setup_time_is_logged_past_the_threshold(tmp_path, monkeypatch, threshold,
                                                     logged):
    """In process: 'target set up in N s' on the 'diffsurf' logger (stderr) when the setup
    took the threshold or more, for project and smooth."""
    monkeypatch.setattr(common, "SETUP_REPORT_SECONDS", threshold)
    for args in (["project", CYLINDER, PLATE, "-o", str(tmp_path / "r.csv")],
                 ["smooth", CYLINDER, "-o", str(tmp_path / "s.vtu"), "--preset", "fast"]):
        monkeypatch.setattr(sys, "stderr", io.StringIO())
        main(args, standalone_mode=False)
        shown = sys.stderr.getvalue()
        assert ("diffsurf: target set up in " in shown) is logged, shown
        assert "setting up" not in shown  # not a terminal
