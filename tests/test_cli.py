"""End-to-end tests of `diffsurf project`, run in-process with click's CliRunner.

The sample scene (sample_meshes/README.md): a faceted half cylinder (radius 10, axis along z
through x = 32.5, y = 30) pressed into a plate whose top-face nodes (plate.csv) bulge to
y = 20 + 0.6 exp(-((x - 32.5)/6)^2); the 25 nodes with 30 <= x <= 35 are inside the cylinder.
File-format details of the I/O layer are tested in test_io.py; here only the command.
"""
from __future__ import annotations

import csv
import io
import os
import subprocess
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest
from click.testing import CliRunner

from diffsurf_cli import __version__
from diffsurf_cli.cli import main
from samples import BOTH, CYLINDER, CYLINDER_STL, PLATE_CSV, PLATE_VTU

RESULT_COLUMNS = ["gap", "nx", "ny", "nz", "px", "py", "pz", "status", "support", "iterations",
                  "rcond", "reason", "terms", "facet_gap"]
HEADER = ["id", "x", "y", "z"] + RESULT_COLUMNS
STATUSES = {"open", "contact", "penetration", "outside", "failed"}
STATUS_CODE = {"open": 0, "contact": 1, "penetration": 2, "outside": 3, "failed": 4}
FLOATS = ["x", "y", "z", "gap", "nx", "ny", "nz", "px", "py", "pz"]


# -------------------------------------------------------------------------------------------
# helpers
# -------------------------------------------------------------------------------------------


def invoke(*args, input=None):
    return CliRunner().invoke(main, [str(a) for a in args], input=input)


def ok(*args, input=None):
    result = invoke(*args, input=input)
    assert result.exit_code == 0, (result.stderr, result.exception)
    return result


def project(*extra, target=CYLINDER, points=PLATE_CSV, input=None):
    return ok("project", target, points, *extra, input=input)


def fail(*args, code=1, input=None):
    """Run a command expected to fail cleanly; return its (single) stderr error line."""
    result = invoke(*args, input=input)
    assert result.exit_code == code, (result.exit_code, result.stdout, result.stderr,
                                      result.exception)
    assert result.stdout == ""
    assert "Traceback" not in result.stderr
    # a clean exit, not an uncaught exception turned into exit 1 by the runner
    assert isinstance(result.exception, SystemExit), result.exception
    return result.stderr


def error_line(stderr: str) -> str:
    """The `diffsurf: error: ...` line; asserts there is exactly one and nothing after it."""
    lines = [ln for ln in stderr.splitlines() if ln.startswith("diffsurf: error:")]
    assert len(lines) == 1, stderr
    assert stderr.rstrip("\n").splitlines()[-1] == lines[0], stderr
    return lines[0]


def parse(stdout: str):
    """Parse CSV text into (header, list of dict rows)."""
    reader = csv.DictReader(io.StringIO(stdout))
    rows = list(reader)
    return reader.fieldnames, rows


def column(rows, name) -> np.ndarray:
    return np.array([float(r[name]) for r in rows])


def statuses(rows) -> np.ndarray:
    return np.array([r["status"] for r in rows])


def plate_input():
    """(ids, xyz) of plate.csv as written in the file."""
    with open(PLATE_CSV, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return [r["id"] for r in rows], np.array([[float(r[k]) for k in "xyz"] for r in rows])


def penetrating(xyz) -> np.ndarray:
    return (xyz[:, 0] >= 30 - 1e-9) & (xyz[:, 0] <= 35 + 1e-9)


def exact_gap(xyz) -> np.ndarray:
    """Signed distance to the exact cylinder (valid below its axis: all plate nodes)."""
    return np.hypot(xyz[:, 0] - 32.5, xyz[:, 1] - 30.0) - 10.0


def gaps(*extra, **kw):
    _, rows = parse(project(*extra, **kw).stdout)
    return column(rows, "gap"), statuses(rows)


def same_gaps(a, b, tol=1e-12):
    return np.array_equal(np.isnan(a), np.isnan(b)) and np.allclose(
        a[~np.isnan(a)], b[~np.isnan(b)], rtol=0, atol=tol)


@pytest.fixture(scope="module")
def default_run():
    """The default run on the sample scene: (result, header, rows)."""
    result = project()
    header, rows = parse(result.stdout)
    return result, header, rows


@pytest.fixture(scope="module")
def default_gaps(default_run):
    _, _, rows = default_run
    return column(rows, "gap"), statuses(rows)


@pytest.fixture
def one_triangle(tmp_path):
    path = tmp_path / "tri.vtu"
    meshio.write(str(path), meshio.Mesh(
        np.array([[20.0, 25.0, 0.0], [45.0, 25.0, 0.0], [32.5, 25.0, 5.0]]),
        [("triangle", np.array([[0, 1, 2]]))]))
    return str(path)


# -------------------------------------------------------------------------------------------
# CSV in, CSV out
# -------------------------------------------------------------------------------------------


def test_csv_header_and_rows(default_run):
    result, header, rows = default_run
    ids, xyz = plate_input()
    assert header == HEADER
    assert len(rows) == len(ids) == 265
    assert [r["id"] for r in rows] == ids  # passed through, same order
    got = np.column_stack([column(rows, k) for k in "xyz"])
    np.testing.assert_array_equal(got, xyz)  # coordinates round-trip exactly (repr)
    assert set(statuses(rows)) <= STATUSES
    for r in rows:
        for k in FLOATS:
            float(r[k])
        assert int(r["support"]) >= 0 and int(r["iterations"]) >= 0


def test_csv_stdout_is_only_csv(default_run):
    result, _, _ = default_run
    lines = result.stdout.splitlines()
    assert lines[0] == ",".join(HEADER)
    assert all(len(ln.split(",")) == len(HEADER) for ln in lines)
    assert "diffsurf:" not in result.stdout
    assert result.stdout.endswith("\n")


def test_log_goes_to_stderr(default_run):
    result, _, _ = default_run
    err = result.stderr
    assert all(ln.startswith("diffsurf: ") for ln in err.splitlines()), err
    assert "85 nodes, 64 facets" in err
    assert "265 contactors" in err
    assert "25 penetration" in err


def test_penetrating_nodes(default_run):
    _, _, rows = default_run
    _, xyz = plate_input()
    gap, status = column(rows, "gap"), statuses(rows)
    pen = penetrating(xyz)
    assert pen.sum() == 25
    assert (gap[pen] < 0).all()
    assert (status[pen] == "penetration").all()
    assert not (status[~pen] == "penetration").any()
    assert (gap[~pen & ~np.isnan(gap)] > 0).all()
    # the diffuse surface of the nodes is much closer to the cylinder than its facets
    # (sagitta 0.048 mm)
    np.testing.assert_allclose(gap[pen], exact_gap(xyz)[pen], atol=5e-3)


def test_normals_and_proximal_points(default_run):
    _, _, rows = default_run
    _, xyz = plate_input()
    gap = column(rows, "gap")
    live = ~np.isnan(gap)
    n = np.column_stack([column(rows, k) for k in ("nx", "ny", "nz")])[live]
    p = np.column_stack([column(rows, k) for k in ("px", "py", "pz")])[live]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-12)
    assert (n[:, 1] < 0).all()  # cylinder normals point out of it, towards the plate (-y)
    # x = p + g n
    np.testing.assert_allclose(p + gap[live, None] * n, xyz[live], atol=1e-9)
    # proximal points lie on the cylinder (radius 10 about the axis) to within the sagitta
    np.testing.assert_allclose(np.hypot(p[:, 0] - 32.5, p[:, 1] - 30), 10, atol=0.05)


def test_nan_rows_for_outside(default_run):
    _, _, rows = default_run
    for r in rows:
        if r["status"] in ("outside", "failed"):
            assert all(r[k] == "NaN" for k in RESULT_COLUMNS[:7]), r


# -------------------------------------------------------------------------------------------
# stdin
# -------------------------------------------------------------------------------------------


def test_stdin_same_as_file(default_run):
    text = Path(PLATE_CSV).read_text()
    result = project(points="-", input=text)
    assert result.stdout == default_run[0].stdout
    assert "diffsurf: -: 265 contactors" in result.stderr.splitlines()


def test_stdin_headerless_three_columns(default_run):
    _, xyz = plate_input()
    text = "\n".join(",".join(repr(v) for v in row) for row in xyz.tolist()) + "\n"
    header, rows = parse(project(points="-", input=text).stdout)
    assert header == ["x", "y", "z"] + RESULT_COLUMNS
    _, _, ref = default_run
    assert len(rows) == len(ref)
    for got, want in zip(rows, ref):
        assert got == {k: v for k, v in want.items() if k != "id"}


def test_stdin_empty_is_an_error():
    line = error_line(fail("project", CYLINDER, "-", input=""))
    assert "<stdin>" in line


# -------------------------------------------------------------------------------------------
# -o FILE and --overwrite
# -------------------------------------------------------------------------------------------


def test_output_file(tmp_path, default_run):
    out = tmp_path / "out.csv"
    result = project("-o", out)
    assert result.stdout == ""
    assert "265 contactors" in result.stderr
    assert out.read_text() == default_run[0].stdout
    assert os.listdir(tmp_path) == ["out.csv"]  # no temporary file left behind


def test_output_refuses_to_overwrite(tmp_path):
    out = tmp_path / "out.csv"
    project("-o", out)
    before = out.read_bytes()
    stat = out.stat()
    line = error_line(fail("project", CYLINDER, PLATE_CSV, "-o", out))
    assert str(out) in line
    assert "--overwrite" in line
    assert out.read_bytes() == before
    assert out.stat().st_mtime_ns == stat.st_mtime_ns


def test_overwrite_replaces(tmp_path, default_run):
    out = tmp_path / "out.csv"
    out.write_text("old\n")
    result = project("-o", out, "--overwrite")
    assert result.stdout == ""
    assert out.read_text() == default_run[0].stdout


def test_failed_run_leaves_existing_output(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("old\n")
    fail("project", CYLINDER, tmp_path / "missing.csv", "-o", out, "--overwrite")
    assert out.read_text() == "old\n"


def test_output_dash_is_stdout(default_run):
    assert project("-o", "-").stdout == default_run[0].stdout


# -------------------------------------------------------------------------------------------
# mesh output
# -------------------------------------------------------------------------------------------


def test_vtu_output_from_csv(tmp_path, default_run):
    out = tmp_path / "result.vtu"
    result = project("-o", out)
    assert result.stdout == ""
    mesh = meshio.read(out)
    _, _, rows = default_run
    _, xyz = plate_input()
    np.testing.assert_allclose(mesh.points, xyz)
    pd = mesh.point_data
    assert pd["gap"].shape == (265,)
    np.testing.assert_array_equal(pd["gap"], column(rows, "gap"))
    assert pd["normal"].shape == (265, 3)
    np.testing.assert_array_equal(
        pd["normal"], np.column_stack([column(rows, k) for k in ("nx", "ny", "nz")]))
    assert pd["proximal_point"].shape == (265, 3)
    np.testing.assert_array_equal(
        pd["proximal_point"], np.column_stack([column(rows, k) for k in ("px", "py", "pz")]))
    assert pd["status"].dtype.kind in "iu"
    np.testing.assert_array_equal(pd["status"], [STATUS_CODE[s] for s in statuses(rows)])
    assert (pd["status"][penetrating(xyz)] == STATUS_CODE["penetration"]).all()
    np.testing.assert_array_equal(pd["id"], np.arange(1, 266))  # numeric pass-through


def test_vtu_output_keeps_contactor_cells(tmp_path, default_gaps):
    out = tmp_path / "result.vtu"
    project("-o", out, points=PLATE_VTU)
    mesh = meshio.read(out)
    src = meshio.read(PLATE_VTU)
    assert [b.type for b in mesh.cells] == ["quad"]
    assert len(mesh.cells[0].data) == 208
    np.testing.assert_array_equal(mesh.cells[0].data, src.cells[0].data)
    np.testing.assert_allclose(mesh.points, src.points)
    assert mesh.point_data["normal"].shape == (len(src.points), 3)
    # same nodes as plate.csv, so the same gaps
    order = np.argsort(src.point_data["id"].ravel())
    assert same_gaps(mesh.point_data["gap"][order], default_gaps[0], 1e-12)


def test_mesh_points_to_csv(default_gaps):
    header, rows = parse(project(points=PLATE_VTU).stdout)
    assert header[-len(RESULT_COLUMNS):] == RESULT_COLUMNS
    assert len(rows) == 265


# -------------------------------------------------------------------------------------------
# zones and target formats
# -------------------------------------------------------------------------------------------


def test_zone_matches_single_surface_file(default_gaps):
    result = project("--zone", "cylinder", target=BOTH)
    assert "zone 'cylinder'" in result.stderr
    _, rows = parse(result.stdout)
    assert same_gaps(column(rows, "gap"), default_gaps[0], 1e-12)
    assert (statuses(rows) == default_gaps[1]).all()


def test_without_zone_the_plate_is_part_of_the_target(default_gaps):
    gap, _ = gaps(target=BOTH)
    assert not same_gaps(gap, default_gaps[0], 1e-6)


def test_unknown_zone_lists_zones():
    line = error_line(fail("project", BOTH, PLATE_CSV, "--zone", "nope"))
    assert BOTH in line and "'nope'" in line
    for name in ("cylinder", "plate_top", "edges"):
        assert name in line


def test_triangulated_stl_target(default_gaps):
    result = project(target=CYLINDER_STL)
    assert "128 facets" in result.stderr
    _, rows = parse(result.stdout)
    gap, status = column(rows, "gap"), statuses(rows)
    _, xyz = plate_input()
    pen = penetrating(xyz)
    assert (status[pen] == "penetration").all()
    # same nodes as the quad mesh: the diffuse surface hardly depends on the facets
    np.testing.assert_allclose(gap[pen], default_gaps[0][pen], atol=1e-3)
    np.testing.assert_allclose(gap[pen], exact_gap(xyz)[pen], atol=5e-3)


def test_facet_method(default_gaps):
    gap, status = gaps("--method", "facet")
    _, xyz = plate_input()
    pen = penetrating(xyz)
    assert (status[pen] == "penetration").all()
    assert (gap[pen] < 0).all()
    both = ~np.isnan(gap) & ~np.isnan(default_gaps[0])
    assert np.abs(gap[both] - default_gaps[0][both]).max() > 1e-3  # faceted, not smooth
    # a chord lies inside the circle: facet gaps are never below the exact ones, and differ
    # by at most the sagitta
    err = gap[pen] - exact_gap(xyz)[pen]
    assert (err > -1e-9).all() and (err < 0.049).all()


def test_facet_method_rejects_recentre():
    fail("project", CYLINDER, PLATE_CSV, "--method", "facet", "--recentre", code=2)


# -------------------------------------------------------------------------------------------
# engine options
# -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("args, logged", [
    (["--basis", "linear"], "basis linear"),
    (["--basis", "cubic"], "basis cubic"),
    (["--weight", "singular"], "weight singular"),
    (["--weight", "gauss"], "weight gauss"),
    (["--frame", "global"], "frame: global"),
    (["--frame", "local"], "frame: local"),
    (["--support", "knn", "-k", "20"], "support knn"),
    (["--radius", "3"], "support radius"),
    (["--recentre"], "basis quadratic"),
])
def test_engine_options(args, logged, default_gaps):
    result = project(*args)
    assert logged in result.stderr
    header, rows = parse(result.stdout)
    assert header == HEADER
    assert len(rows) == 265
    status = statuses(rows)
    assert set(status) <= STATUSES
    gap = column(rows, "gap")
    _, xyz = plate_input()
    pen = penetrating(xyz)
    # every setting finds the interpenetration (cubic may lack support on node rows)
    assert (status[pen] == "penetration").sum() >= 20
    assert (gap[pen][status[pen] == "penetration"] < 0).all()
    assert not (status[~pen] == "penetration").any()
    if args != ["--frame", "local"]:  # 'auto' picks the local frame for the half cylinder
        assert not same_gaps(gap, default_gaps[0], 1e-9), "option had no effect"


def test_recentre_converges_to_same_contact_state(default_gaps):
    gap, status = gaps("--recentre")
    assert (status == default_gaps[1]).all()
    # Near the target the contactor's own fit is centred close to its proximal point, so the
    # two agree closely; far off (gaps of 20 mm here) the fit is centred a few spacings from
    # the proximal point and only re-centring is exact, so those rows are left out.
    near = ~np.isnan(gap) & (np.abs(default_gaps[0]) < 2.0)
    assert near.sum() >= 25
    np.testing.assert_allclose(gap[near], default_gaps[0][near], atol=1e-3)


def test_knn_below_basis_size():
    line = error_line(fail("project", CYLINDER, PLATE_CSV, "--support", "knn", "-k", "4"))
    assert "k=4" in line


def test_flip_normals(default_gaps):
    gap, status = gaps("--flip-normals")
    ref_gap, ref_status = default_gaps
    assert same_gaps(gap, -ref_gap, 1e-9)
    swap = {"open": "penetration", "penetration": "open"}
    assert list(status) == [swap.get(s, s) for s in ref_status]


def test_flip_normals_facet():
    ref, _ = gaps("--method", "facet")
    gap, _ = gaps("--method", "facet", "--flip-normals")
    assert same_gaps(gap, -ref, 1e-12)


# -------------------------------------------------------------------------------------------
# root options
# -------------------------------------------------------------------------------------------


def test_quiet(default_run):
    result = ok("-q", "project", CYLINDER, PLATE_CSV)
    assert result.stderr == ""
    assert result.stdout == default_run[0].stdout


def test_quiet_still_reports_errors():
    stderr = fail("-q", "project", CYLINDER, "nope.csv")
    assert stderr.splitlines() == [error_line(stderr)]


@pytest.mark.parametrize("cmd", [["--help"], ["project", "--help"], ["project", "-h"]])
def test_help_shows_examples(cmd):
    result = ok(*cmd)
    assert "Examples:" in result.stdout
    assert "diffsurf project target.msh points.csv -o gaps.csv" in result.stdout
    assert "cat points.csv | diffsurf project target.vtu - > gaps.csv" in result.stdout


def test_project_help_lists_options():
    out = ok("project", "--help").stdout
    for opt in ("--basis", "--weight", "--support", "--radius", "--frame", "--recentre",
                "--flip-normals", "--zone", "--method", "--overwrite", "--output"):
        assert opt in out


def test_version():
    result = ok("--version")
    assert __version__ in result.stdout
    assert "diffsurf" in result.stdout


# -------------------------------------------------------------------------------------------
# errors
# -------------------------------------------------------------------------------------------


def test_missing_target(tmp_path):
    missing = tmp_path / "missing.msh"
    line = error_line(fail("project", missing, PLATE_CSV))
    assert str(missing) in line and "no such file" in line


def test_missing_points(tmp_path):
    missing = tmp_path / "missing.csv"
    line = error_line(fail("project", CYLINDER, missing))
    assert str(missing) in line and "no such file" in line


def test_directory_target(tmp_path):
    line = error_line(fail("project", tmp_path, PLATE_CSV))
    assert str(tmp_path) in line and "directory" in line


def test_unknown_target_extension(tmp_path):
    path = tmp_path / "target.foo"
    path.write_text("hello\n")
    line = error_line(fail("project", path, PLATE_CSV))
    assert str(path) in line and "'.foo'" in line and ".msh" in line


def test_garbage_msh(tmp_path):
    path = tmp_path / "garbage.msh"
    path.write_bytes(bytes(range(256)) * 4)
    line = error_line(fail("project", path, PLATE_CSV))
    assert str(path) in line and "cannot read" in line


def test_wrong_column_count(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("id,x,y,z\n1,0,20,0\n2,1,20\n")
    line = error_line(fail("project", CYLINDER, path))
    assert str(path) in line and "line 3" in line


def test_wrong_column_count_on_stdin():
    line = error_line(fail("project", CYLINDER, "-", input="1,2,3\n4,5,6\n7,8\n"))
    assert "<stdin>" in line and "line 3" in line


def test_non_numeric_text(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("x,y,z\n1,20,0\n2,abc,0\n")
    line = error_line(fail("project", CYLINDER, path))
    assert str(path) in line and "line 3" in line and "'abc'" in line


@pytest.mark.parametrize("args, option", [
    (["--radius", "0.5"], "--radius"),
    (["--basis", "quartic"], "--basis"),
    (["--weight", "box"], "--weight"),
    (["--method", "nearest"], "--method"),
    (["--support", "knn", "-k", "2"], "-k"),
    (["--residual", "R.mtx"], "--penalty"),
    (["--tangent", "K.mtx"], "--penalty"),
])
def test_bad_options_exit_2(args, option, tmp_path):
    args = [str(tmp_path / a) if a.endswith(".mtx") else a for a in args]
    stderr = fail("project", CYLINDER, PLATE_CSV, *args, code=2)
    assert option in stderr
    assert os.listdir(tmp_path) == []  # checked before any work: nothing written


def test_missing_argument_exits_2():
    assert "POINTS" in fail("project", CYLINDER, code=2)


def test_output_to_missing_directory(tmp_path):
    out = tmp_path / "nodir" / "out.csv"
    line = error_line(fail("project", CYLINDER, PLATE_CSV, "-o", out))
    assert str(out) in line and "does not exist" in line
    assert not out.parent.exists()
    assert os.listdir(tmp_path) == []


def test_output_unknown_extension(tmp_path):
    out = tmp_path / "out.foo"
    line = error_line(fail("project", CYLINDER, PLATE_CSV, "-o", out))
    assert str(out) in line
    assert os.listdir(tmp_path) == []


def test_too_few_target_nodes(one_triangle, tmp_path):
    """3 nodes cannot determine the quadratic basis: the target gets the largest basis they
    determine, the plane of its triangle (issue 19, item 4), with the facets where that
    plane has no answer."""
    import meshio

    out = tmp_path / "gaps.csv"
    project("-o", out, target=one_triangle)
    table = np.genfromtxt(out, delimiter=",", names=True, dtype=None, encoding=None)
    mesh = meshio.read(one_triangle)
    tri = mesh.points[mesh.cells[0].data[0]]
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n /= np.linalg.norm(n)
    xyz = np.stack([table["x"], table["y"], table["z"]], axis=1)
    answered = table["status"] != "outside"
    assert answered.any()
    plane = (table["terms"] == 3) & answered
    assert plane.any()
    np.testing.assert_allclose(np.abs(table["gap"][plane]),
                               np.abs((xyz[plane] - tri[0]) @ n), rtol=0, atol=1e-9)


def test_one_triangle_with_linear_basis(one_triangle):
    # 3 nodes determine a linear fit: a valid (if small) target, no crash
    header, rows = parse(project("--basis", "linear", target=one_triangle).stdout)
    assert header == HEADER and len(rows) == 265


# -------------------------------------------------------------------------------------------
# -v: tracebacks on request
# -------------------------------------------------------------------------------------------


def test_verbose_error_keeps_the_exception(tmp_path):
    missing = tmp_path / "missing.msh"
    result = invoke("-v", "project", missing, PLATE_CSV)
    assert result.exit_code == 1
    assert not isinstance(result.exception, SystemExit)  # propagated: Python prints it
    assert str(missing) in str(result.exception)


def test_verbose_error_prints_traceback(tmp_path):
    missing = tmp_path / "missing.msh"
    proc = subprocess.run(
        [sys.executable, "-m", "diffsurf_cli.cli", "-v", "project", str(missing), PLATE_CSV],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert "Traceback" in proc.stderr
    assert len(proc.stderr.splitlines()) > 1
    assert str(missing) in proc.stderr


def test_not_verbose_no_traceback_in_real_process(tmp_path):
    missing = tmp_path / "missing.msh"
    proc = subprocess.run(
        [sys.executable, "-m", "diffsurf_cli.cli", "project", str(missing), PLATE_CSV],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    assert proc.stdout == ""
    assert proc.stderr == f"diffsurf: error: {missing}: no such file\n"
