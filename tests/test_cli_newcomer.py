"""What a newcomer tripped on in the command line (issue 14): -v and -q on either side of the
command name (item 1), a warning when the contactors are the target's own nodes (item 8)."""
from __future__ import annotations

import numpy as np
import pytest

from diffsurf_cli.targets import coincident
from samples import BOTH, PLATE_VTU, run
from samples import CYLINDER as TARGET
from samples import PLATE_CSV as POINTS

_run = run


@pytest.mark.parametrize("where", ["before", "after"])
def test_quiet_on_either_side_of_the_command(where):
    args = ["project", TARGET, POINTS]
    result = _run(*(["-q", *args] if where == "before" else [*args, "-q"]))
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    assert result.stdout.startswith("id,x,y,z,gap")
    loud = _run(*args)
    assert "contactors" in loud.stderr  # the log line -q silenced


@pytest.mark.parametrize("command", [["project", TARGET, POINTS], ["smooth", TARGET, "-o", "x.vtu"],
                                     ["tune", TARGET]])
def test_every_command_takes_verbosity_options(command):
    result = _run(*command, "--help")
    assert result.exit_code == 0
    assert "-q, --quiet" in result.stdout and "-v, --verbose" in result.stdout


def test_verbose_after_the_command_shows_the_traceback(tmp_path):
    missing = str(tmp_path / "missing.msh")
    short = _run("project", missing, POINTS)
    assert short.exit_code == 1 and short.exception is not None
    assert isinstance(short.exception, SystemExit)  # one line, no traceback
    verbose = _run("project", missing, POINTS, "-v")
    assert verbose.exit_code == 1
    assert not isinstance(verbose.exception, SystemExit)  # the original error propagates


def test_warns_when_contactors_are_target_nodes():
    # no --zone on a two-body mesh: the plate is part of the target, every contactor is a
    # target node and came back 'contact' with no word
    whole = _run("project", BOTH, BOTH)
    assert whole.exit_code == 0, whole.output
    assert "350 of 350 contactors coincide with target nodes" in whole.stderr
    zoned = _run("project", BOTH, PLATE_VTU, "--zone", "cylinder")
    assert zoned.exit_code == 0 and "coincide" not in zoned.stderr


def test_coincident_matches_brute_force():
    rng = np.random.default_rng(3)
    nodes = np.round(rng.uniform(-1, 1, (300, 3)), 1)  # many shared x values
    points = np.concatenate([nodes[rng.integers(0, 300, 50)],
                             np.round(rng.uniform(-1, 1, (400, 3)), 1),
                             -0.0 * nodes[:1] + [[0.0, 0.0, 0.0]]])
    nodes = np.vstack([nodes, [[0.0, -0.0, 0.0]]])
    brute = sum(bool(np.any(np.all(nodes == p, axis=1))) for p in points)
    assert coincident(points, nodes) == brute > 50
    assert coincident(points[:0], nodes) == 0


@pytest.mark.parametrize("fmt", ["csv", "parquet", "vtu"])
def test_a_result_fed_back_as_points_is_refused_before_any_work(tmp_path, fmt):
    """Issue 22, item 4: a result used as POINTS holds gap, status, ... already; CSV wrote
    them twice, .vtu dropped the old ones silently, Parquet refused after all the computing.
    Every format now refuses at once, naming the clashing columns, and writes nothing."""
    first = tmp_path / f"first.{fmt}"
    assert run("project", TARGET, POINTS, "-o", first, "-q").exit_code == 0
    out = tmp_path / f"second.{fmt}"
    res = run("project", TARGET, first, "-o", out)
    assert res.exit_code != 0
    line = [x for x in res.stderr.splitlines() if "error" in x]
    assert len(line) == 1 and str(first) in line[0], res.stderr
    assert "gap" in line[0] and "status" in line[0] and "projecting" not in res.stderr
    assert not out.exists()
    # a result's own coordinates and id are not in the way: keep those, and it runs
    import polars as pl

    if fmt == "csv":
        kept = tmp_path / "kept.csv"
        pl.read_csv(first).select("id", "x", "y", "z").write_csv(kept)
        assert run("project", TARGET, kept, "-o", out, "-q").exit_code == 0


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_degenerate_facets_are_dropped_with_a_note(tmp_path, method):
    """Issue 22, item 7: zero-area triangles ([a, a, b], [b, a, b]) spanning a chord through a
    closed sphere answered points inside it 'open' (the facets too). They are dropped, the
    log says how many, and the points inside are penetrating."""
    import meshio

    from diffsurf_cli.testing.shapes import Sphere

    nodes, faces = Sphere(radius=1.0).mesh(5)
    a, b = int(np.argmax(nodes[:, 2])), int(np.argmin(nodes[:, 2]))
    path = tmp_path / "degenerate.stl"
    meshio.write(path, meshio.Mesh(nodes, [("triangle", np.vstack([faces, [[a, a, b],
                                                                           [b, a, b]]]))]))
    points = tmp_path / "inside.csv"
    points.write_text("x,y,z\n0,0,0.1\n0.05,0,-0.2\n")
    res = run("project", path, points, "--method", method)
    assert res.exit_code == 0, res.stderr
    assert "dropped 2 degenerate facets" in res.stderr
    rows = [line.split(",") for line in res.stdout.splitlines()[1:]]
    assert [r[10] for r in rows] == ["penetration", "penetration"], res.stdout


@pytest.mark.parametrize("method", ["diffuse", "facet"])
def test_inconsistent_winding_is_repaired_with_a_note(tmp_path, method):
    """Issue 22, item 6: 10% of a closed sphere's facets reversed gave wrong signs with status
    ok (the facets too). The facets that disagree with their neighbours are reversed, the log
    says how many, and every sign is the exact sphere's."""
    import meshio

    from diffsurf_cli.testing.shapes import Sphere

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(8)
    rng = np.random.default_rng(4)
    turned = rng.random(len(faces)) < 0.1
    faces[turned] = faces[turned][:, [0, 2, 1]]
    path = tmp_path / "wound.stl"
    meshio.write(path, meshio.Mesh(nodes, [("triangle", faces)]))
    pts = shape.sample_near(400, 0.05, rng=5)
    points = tmp_path / "points.csv"
    np.savetxt(points, pts, delimiter=",", header="x,y,z", comments="")
    res = run("project", path, points, "--method", method)
    assert res.exit_code == 0, res.stderr
    assert f"reversed {int(turned.sum())} facets" in res.stderr, res.stderr
    gap = np.array([float(line.split(",")[3]) for line in res.stdout.splitlines()[1:]])
    exact = np.linalg.norm(pts, axis=1) - 1.0
    big = np.abs(exact) > 0.01
    assert np.all(np.sign(gap[big]) == np.sign(exact[big]))


def test_a_non_orientable_target_is_left_as_it_is_with_a_warning(tmp_path):
    """A Möbius strip has no consistent orientation: nothing is reversed, a warning says so."""
    import meshio

    n, w = 24, 0.3
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    nodes = []
    for s in (-w, w):
        nodes.append(np.column_stack([(1 + s * np.cos(t / 2)) * np.cos(t),
                                      (1 + s * np.cos(t / 2)) * np.sin(t),
                                      s * np.sin(t / 2)]))
    nodes = np.vstack(nodes)  # row 0: 0..n-1, row 1: n..2n-1; the seam joins i=n-1 to 0 twisted
    quads = [[i, i + 1, n + i + 1, n + i] for i in range(n - 1)] + [[n - 1, n, 0, 2 * n - 1]]
    path = tmp_path / "moebius.vtu"
    meshio.write(path, meshio.Mesh(nodes, [("quad", np.array(quads))]))
    points = tmp_path / "p.csv"
    points.write_text("x,y,z\n1,0,0.05\n")
    res = run("project", path, points, "--method", "facet")
    assert res.exit_code == 0, res.stderr
    assert "no orientation fits" in res.stderr and "reversed" not in res.stderr, res.stderr


@pytest.mark.parametrize("offset, warned", [(1e15, True), (1e9, False), (0.0, False)])
def test_large_offsets_warn_of_the_digits_left(tmp_path, offset, warned):
    """Issue 22, item 9: a unit sphere moved by 1e15 gave 1,792 wrong signs, and the only
    warning blamed coincident contactors. The warning now names the cause: the digits of the
    node spacing the coordinates' magnitude leaves (none at 1e15; at 1e9 the answers are
    still right, and nothing is said)."""
    import meshio

    from diffsurf_cli.testing.shapes import Sphere

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(8)
    path = tmp_path / "moved.stl"
    meshio.write(path, meshio.Mesh(nodes + offset, [("triangle", faces)]))
    pts = shape.sample_near(5, 0.05, rng=1)
    points = tmp_path / "p.csv"
    np.savetxt(points, pts + offset, delimiter=",", header="x,y,z", comments="")
    res = run("project", path, points)
    assert res.exit_code == 0, res.stderr
    assert ("significant digits" in res.stderr) == warned, res.stderr
    if not warned:
        gap = np.array([float(line.split(",")[3]) for line in res.stdout.splitlines()[1:]])
        np.testing.assert_allclose(gap, np.linalg.norm(pts, axis=1) - 1.0, atol=1e-3)


@pytest.mark.parametrize("at", [1, 2], ids=["probe", "result"])
@pytest.mark.parametrize("fmt", ["csv", "parquet", "vtu"])
def test_sigterm_while_writing_leaves_nothing(tmp_path, monkeypatch, fmt, at):
    """Issue 22, item 11: SIGTERM (or SIGHUP) left the half-written temporary file next to the
    output (170 MB for a 2M-point CSV). It now unwinds as Ctrl-C does: the signal arrives
    while the output directory is probed, or while the result is being written; the run ends
    with status 128 + 15, and the directory holds nothing new. The handlers are restored
    afterwards."""
    import os
    import signal

    from diffsurf_cli.io import atomic

    real = atomic.os.close
    sent, closes = [], []

    def close_then_signal(fd):  # a temporary file exists: its writer is about to fill it
        real(fd)
        closes.append(fd)
        if len(closes) == at and not sent:
            sent.append(fd)
            os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(atomic.os, "close", close_then_signal)
    out = tmp_path / f"out.{fmt}"
    res = run("project", TARGET, POINTS, "-o", out, "-q")
    monkeypatch.undo()
    assert sent and res.exit_code == 128 + signal.SIGTERM, (res.exit_code, res.stderr)
    assert os.listdir(tmp_path) == [], os.listdir(tmp_path)
    assert signal.getsignal(signal.SIGTERM) == before


def test_one_contactor_is_singular(tmp_path):
    """Issue 22, item 16: '1 contactors' read as a typo."""
    points = tmp_path / "one.csv"
    points.write_text("x,y,z\n32.5,20.1,2.5\n")
    res = run("project", TARGET, points, "--penalty", "1", "--residual", tmp_path / "R.mtx",
              "-o", tmp_path / "o.csv")
    assert res.exit_code == 0, res.stderr
    assert f"{points}: 1 contactor\n" in res.stderr and "1 element\n" in res.stderr, res.stderr
    assert "1 contactors" not in res.stderr and "1 elements" not in res.stderr


def test_pairs_refuse_the_options_they_fix(tmp_path):
    """Issue 22, item 16: `--pairs P.npz --radius 5` ignored --radius without a word. The
    options a pairing fixes (frame, support, radius, k) are refused with it; the others run."""
    pairs = tmp_path / "P.npz"
    assert run("project", TARGET, POINTS, "--save-pairs", pairs, "-q",
               "-o", tmp_path / "a.csv").exit_code == 0
    for extra in (["--radius", "5"], ["-k", "12", "--frame", "global"]):
        res = run("project", TARGET, POINTS, "--pairs", pairs, *extra, "-o", tmp_path / "b.csv")
        assert res.exit_code == 2 and "would be ignored" in res.stderr, res.stderr
        assert all(flag in res.stderr for flag in extra[::2])
    assert run("project", TARGET, POINTS, "--pairs", pairs, "--basis", "quadratic", "-q",
               "-o", tmp_path / "c.csv").exit_code == 0


def test_too_few_nodes_suggests_the_basis_that_fits():
    """Issue 22, item 16: a 3-node target refused by the quadratic basis says which fits."""
    from diffsurf_cli import DiffuseSurface

    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    with pytest.raises(ValueError, match=r"needs at least 6 \(the linear basis fits them: "
                                         r'basis="linear"\)'):
        DiffuseSurface(tri, [np.array([[0, 1, 2]])])
    assert DiffuseSurface(tri, [np.array([[0, 1, 2]])], basis="linear").nterms == 3


def test_a_glob_or_directory_of_points_says_it_needs_workers(tmp_path):
    """Issue 22, item 16: `cloud/*.parquet` without --workers said "no such file", with no
    hint that partitions need --workers or --scheduler."""
    (tmp_path / "cloud").mkdir()
    for points in (str(tmp_path / "cloud" / "*.parquet"), str(tmp_path / "cloud")):
        res = run("project", TARGET, points)
        assert res.exit_code == 1 and "--workers" in res.stderr, res.stderr


@pytest.mark.parametrize("kind", ["diffuse", "patched"])
def test_projection_is_called_in_chunks_so_a_signal_acts_soon(monkeypatch, kind):
    """Issue 22, item 14: Ctrl-C acted only when the compiled projection of the whole cloud
    returned (1.1-1.8 s on 2M points here, 14 s reported with a slower preset). The cloud is
    now projected a chunk at a time, with or without a progress bar: a signal acts between
    two chunks."""
    from diffsurf_cli import DiffuseSurface, PatchedSurface
    from diffsurf_cli.mls import surface as mls_surface
    from diffsurf_cli.testing.shapes import Sphere

    shape = Sphere(radius=1.0)
    nodes, faces = shape.mesh(8)
    surf = (DiffuseSurface(nodes, [faces]) if kind == "diffuse"
            else PatchedSurface(nodes, [faces]))
    points = shape.sample_near(3 * mls_surface.CHUNK + 5, 0.05, rng=1)
    engine = surf.engine
    calls = []

    class Counting:
        def __getattr__(self, name):
            return getattr(engine, name)

        def project(self, *args, **kwargs):
            calls.append(1)
            return engine.project(*args, **kwargs)

    monkeypatch.setattr(type(surf), "engine", property(lambda self: Counting()))
    surf.project(points)  # no progress callback
    assert len(calls) >= 4, len(calls)
