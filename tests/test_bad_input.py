"""Bad input for the command line (issue 6, "Bad input" and "Also"): every case is a CLI test.

Each failing case asserts what the user sees and what is left on disk:
- exit code 1 (2 for bad options), nothing on stdout;
- with -q, stderr is one or two lines, the first starting `diffsurf: error:`, naming the file
  (and the line, for CSV) and what was expected; no traceback;
- with -v, the original exception propagates (a real process prints its traceback);
- the output directory is unchanged byte for byte: no new file, no temporary file, and an
  existing output is kept when refused (no --overwrite) or when the command fails midway.

A NaN or inf coordinate in a contactor row is not an error: the row is kept, in place, with
status `failed` and reason `bad-point`.

Cases run in-process with click's CliRunner; a few also run as a real process, where the
traceback (or its absence) is what Python prints.
"""
from __future__ import annotations

import collections
import csv
import io as _io
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import meshio
import numpy as np
import pytest
import scipy.io
from click.testing import CliRunner

from diffsurf_cli.cli import main
from samples import BOTH, CYLINDER, N_PLATE, PLATE_CSV, SAMPLES

# -------------------------------------------------------------------------------------------
# running the command and checking what the user sees
# -------------------------------------------------------------------------------------------


def invoke(*args, input=None):
    return CliRunner().invoke(main, [str(a) for a in args], input=input)


def snapshot(directory: Path) -> dict:
    """Every file under ``directory`` (hidden temporary files included) with its bytes."""
    return {str(p.relative_to(directory)): p.read_bytes()
            for p in sorted(directory.rglob("*")) if p.is_file()}


def check_error(result, code: int = 1, contains=()) -> str:
    """Assert a clean failure (exit ``code``, nothing on stdout, no traceback); return stderr.

    For exit 1 the whole of stderr (commands are run with -q) is one or two lines, the first
    `diffsurf: error: ...`. Exit 2 is click's usage error, which names the option.
    """
    err = result.stderr
    assert result.exit_code == code, (result.exit_code, err, result.exception)
    assert isinstance(result.exception, SystemExit), result.exception  # not an uncaught error
    assert result.stdout == ""
    assert "Traceback" not in err
    if code == 1:
        lines = err.splitlines()
        assert 1 <= len(lines) <= 2, err
        assert lines[0].startswith("diffsurf: error: "), err
    else:
        assert "Error: " in err, err
    for text in contains:
        assert text in err, (text, err)
    return err.splitlines()[0] if code == 1 else err.strip().splitlines()[-1]


def check_verbose(args, input, name: str | None) -> None:
    """With -v the original exception propagates (Python prints its traceback), exit 1.

    ``name``: the file its message names; None for an error of the numerical core, whose
    message (the traceback's last line) is about the data, not the file.
    """
    result = invoke("-v", *args, input=input)
    assert result.exit_code == 1, (result.stderr, result.exception)
    assert not isinstance(result.exception, SystemExit), result.stderr
    if name is None:
        assert isinstance(result.exception, ValueError), result.exception
    else:
        assert name in str(result.exception), (name, result.exception)


# -------------------------------------------------------------------------------------------
# bad files, made once
# -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> dict:
    """Paths of bad (and a few good) input files, by name."""
    d = tmp_path_factory.mktemp("in")
    files = {}

    def put(name, data):
        path = d / name
        path.write_bytes(data if isinstance(data, bytes) else data.encode())
        files[name] = str(path)

    # targets
    put("target.foo", "1 2 3\n")
    put("garbage.msh", bytes(range(256)) * 4)
    put("empty_file.msh", b"")
    put("truncated.msh", (SAMPLES / "cylinder.msh").read_bytes()[:3000])
    for ext, kwargs in (("msh", {"file_format": "gmsh22", "binary": False}), ("obj", {})):
        empty = d / f"empty_mesh.{ext}"
        no_points = meshio.Mesh(np.zeros((0, 3)), [("triangle", np.zeros((0, 3), int))])
        meshio.write(str(empty), no_points, **kwargs)
        files[f"empty_mesh.{ext}"] = str(empty)
    pts = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]])
    nosurf = d / "no_surface.msh"
    # lines only (volume cells would be read as their boundary)
    meshio.write(str(nosurf), meshio.Mesh(pts, [("line", np.array([[0, 4], [1, 2]]))]),
                 file_format="gmsh22", binary=False)
    files["no_surface.msh"] = str(nosurf)
    tri = d / "one_triangle.vtu"
    meshio.write(str(tri), meshio.Mesh(
        np.array([[20.0, 25.0, 0.0], [45.0, 25.0, 0.0], [32.5, 25.0, 5.0]]),
        [("triangle", np.array([[0, 1, 2]]))]))
    files["one_triangle.vtu"] = str(tri)
    d.joinpath("a_directory.msh").mkdir()
    files["a_directory.msh"] = str(d / "a_directory.msh")
    # contactors
    put("points.foo", "1,2,3\n")
    put("wrong_columns.csv", "id,x,y,z\n1,0,20,0\n2,1,20\n3,2,20,0\n")
    put("non_numeric.csv", "x,y,z\n1,20,0\n2,abc,0\n")
    put("binary.csv", b"x,y,z\n1,20,0\n\x89PNG\xff\xfe\x00\x01,2,3\n")
    put("latin1.csv", "x,y,z\n1,20,0\n\u00e9t\u00e9,2,3\n".encode("latin-1"))
    put("header_only.csv", "id,x,y,z\n")
    put("comments_only.csv", "# nothing here\n\n")
    put("utf16.csv", "x,y,z\n1,20,0\n2,20,0\n".encode("utf-16"))
    put("no_xyz_header.csv", "id,a,b,c\n1,2,3,4\n")
    put("garbage_points.vtu", b"<?xml version='1.0'?>\n<VTKFile type='Unstr" + bytes(300))
    put("huge_line.csv", "x,y,z\n1,20,0\n" + "1," * 200_000 + "2,3\n")
    put("not_pairs.npz", "x,y,z\n1,2,3\n")
    return files


# -------------------------------------------------------------------------------------------
# the cases: (command line, stdin, expected exit, text the message must contain)
# -------------------------------------------------------------------------------------------


def _target_cases(b):
    """Bad TARGET files, for `project` and `smooth` alike: name -> (target, message parts)."""
    return {
        "missing_file": ("/nonexistent/dir/target.msh", ["no such file"]),
        "directory_instead_of_file": (b["a_directory.msh"], ["is a directory, expected a file"]),
        "unknown_extension": (b["target.foo"],
                              ["unknown mesh format '.foo'", "meshio reads .msh, .vtu"]),
        "garbage_msh": (b["garbage.msh"],
                        ["cannot read mesh, expected a valid .msh file (as gmsh: "]),
        "truncated_msh": (b["truncated.msh"],
                          ["cannot read mesh, expected a valid .msh file (as gmsh: "]),
        "empty_file": (b["empty_file.msh"], ["empty file, expected a mesh"]),
        "empty_mesh": (b["empty_mesh.obj"], ["empty mesh, expected points"]),
        "empty_mesh_gmsh": (b["empty_mesh.msh"], ["cannot read mesh, expected a valid .msh file",
                                                  "an empty section where nodes or cells were "
                                                  "expected"]),
        "no_surface_cells": (b["no_surface.msh"], ["no surface cells (triangle/quad) or volume "
                                                   "cells", "2 line"]),
        "mesh_on_stdin_as_target": ("-", ["a mesh cannot be read from stdin",
                                          "expected a mesh file name"]),
    }


def _points_cases(b):
    """Bad POINTS for `project`: name -> (points, stdin, message parts)."""
    return {
        "missing_points_file": ("/nonexistent/points.csv", None, ["no such file"]),
        "points_directory": (b["a_directory.msh"], None, ["is a directory, expected a file"]),
        "points_unknown_extension": (b["points.foo"], None,
                                     ["unknown contactor file format '.foo'", "expected .csv"]),
        "csv_wrong_column_count": (b["wrong_columns.csv"], None,
                                   ["line 3", "expected 4 comma separated columns", "got 3"]),
        "csv_wrong_column_count_stdin": ("-", "1,2,3\n4,5,6\n7,8\n",
                                         ["<stdin>, line 3", "expected 3 comma separated"]),
        "csv_non_numeric_text": (b["non_numeric.csv"], None,
                                 ["line 3", "expected a number for y, got 'abc'"]),
        "csv_binary_bytes": (b["binary.csv"], None,
                             ["not a text CSV file (contains NUL bytes, the first on line 3)"]),
        "csv_non_utf8_bytes": (b["latin1.csv"], None,
                               ["not a text CSV file (bytes at offset 13, on line 3, are not "
                                "UTF-8 text)"]),
        "csv_binary_bytes_stdin": ("-", b"x,y,z\n\x89PNG\xff\xfe,1,2\n",
                                   ["<stdin>", "not a text CSV file"]),
        "empty_stdin": ("-", "", ["<stdin>: no data rows, expected CSV lines x,y,z"]),
        "csv_header_only": (b["header_only.csv"], None,
                            ["no data rows after the header, expected CSV lines x,y,z"]),
        "csv_comments_only": (b["comments_only.csv"], None,
                              ["no data rows, expected CSV lines x,y,z"]),
        "csv_header_without_xyz": (b["no_xyz_header.csv"], None,
                                   ["line 1", "header has no 'x' column",
                                    "expected columns named x,y,z"]),
        "csv_utf16": (b["utf16.csv"], None, ["UTF-16 text, expected UTF-8"]),
        "csv_huge_line": (b["huge_line.csv"], None,
                          ["line 3", "expected 3 comma separated columns", "got 200002"]),
        "mesh_on_stdin_as_points": ("-", (SAMPLES / "cylinder.msh").read_text(),
                                    ["<stdin>, line 1", "looks like a Gmsh mesh",
                                     "not supported, expected CSV x,y,z"]),
        "binary_mesh_on_stdin_as_points": ("-", (SAMPLES / "cylinder_tri.stl").read_bytes(),
                                           ["<stdin>", "not a text CSV file"]),
        "garbage_mesh_as_points": (b["garbage_points.vtu"], None,
                                   ["cannot read mesh, expected a valid .vtu file (as vtu: "]),
    }


# the case names, for parametrize (the files exist only once the fixture has run)
TARGET_CASES = list(_target_cases(collections.defaultdict(str)))
POINTS_CASES = list(_points_cases(collections.defaultdict(str)))


def _name_in_message(path):
    return "<stdin>" if path == "-" else path


@pytest.fixture
def outdir(tmp_path):
    d = tmp_path / "out"
    d.mkdir()
    return d


@pytest.mark.parametrize("case", TARGET_CASES)
@pytest.mark.parametrize("command", ["project", "smooth"])
def test_bad_target(case, command, bad, outdir):
    target, parts = _target_cases(bad)[case]
    old = outdir / ("old.csv" if command == "project" else "old.vtu")
    old.write_bytes(b"previous result\n")
    new = outdir / ("new.csv" if command == "project" else "new.vtu")
    if command == "project":
        args = ["project", target, PLATE_CSV, "-o", new]
    else:
        args = ["smooth", target, "-o", new]
    stdin = None
    before = snapshot(outdir)
    line = check_error(invoke("-q", *args, input=stdin), 1,
                       [f"diffsurf: error: {target}: "] + parts)
    assert snapshot(outdir) == before
    # --overwrite over an existing output, and the input is bad: the old file survives
    args[args.index(new)] = old
    check_error(invoke("-q", *args, "--overwrite", input=stdin), 1, [line])
    assert snapshot(outdir) == before
    check_verbose(args + ["--overwrite"], stdin, target)
    assert snapshot(outdir) == before


@pytest.mark.parametrize("case", POINTS_CASES)
def test_bad_points(case, bad, outdir):
    points, stdin, parts = _points_cases(bad)[case]
    name = _name_in_message(points)
    old = outdir / "old.csv"
    old.write_bytes(b"previous result\n")
    before = snapshot(outdir)
    args = ["project", CYLINDER, points, "-o", outdir / "new.csv"]
    check_error(invoke("-q", *args, input=stdin), 1, [f"diffsurf: error: {name}"] + parts)
    assert snapshot(outdir) == before
    args[-1] = old
    check_error(invoke("-q", *args, "--overwrite", input=stdin), 1, parts)
    assert snapshot(outdir) == before
    check_verbose(args + ["--overwrite"], stdin, name)
    assert snapshot(outdir) == before


def test_mesh_on_stdin_as_points_says_not_supported(outdir):
    """A mesh piped as POINTS should be recognised and refused as such, not parsed as CSV."""
    result = invoke("-q", "project", CYLINDER, "-", input=(SAMPLES / "cylinder.msh").read_text())
    line = check_error(result, 1, ["<stdin>"])
    assert "mesh" in line and "not supported" in line, line


def test_default_verbosity_error_is_the_last_line(bad):
    """Without -q the log lines come first and the error line is the last, and the only one."""
    result = invoke("project", CYLINDER, bad["non_numeric.csv"])
    assert result.exit_code == 1
    lines = result.stderr.splitlines()
    assert [ln for ln in lines if ln.startswith("diffsurf: error:")] == [lines[-1]]
    assert lines[-1].startswith(f"diffsurf: error: {bad['non_numeric.csv']}, line 3: ")
    assert "Traceback" not in result.stderr


# -------------------------------------------------------------------------------------------
# outputs: existing, unwritable, wrong kind, named twice
# -------------------------------------------------------------------------------------------

OUTPUT_OPTIONS = {  # option -> (file name, extra arguments it needs)
    "-o": ("result.csv", []),
    "--residual": ("R.mtx", ["--penalty", "1e3"]),
    "--tangent": ("K.mtx", ["--penalty", "1e3"]),
    "--save-pairs": ("P.npz", []),
}


def _project_with_output(option, path):
    name, extra = OUTPUT_OPTIONS[option]
    return ["project", CYLINDER, PLATE_CSV, option, path, *extra]


@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS) + ["smooth -o"])
def test_output_already_exists(option, outdir):
    if option == "smooth -o":
        path = outdir / "smooth.vtu"
        args = ["smooth", CYLINDER, "-o", path]
    else:
        path = outdir / OUTPUT_OPTIONS[option][0]
        args = _project_with_output(option, path)
    path.write_bytes(b"keep me \x00\xff\n")
    before = snapshot(outdir)
    check_error(invoke("-q", *args), 1,
                [f"diffsurf: error: {path}: already exists (use --overwrite)"])
    assert snapshot(outdir) == before
    check_verbose(args, None, str(path))
    # and --overwrite replaces it
    assert invoke("-q", *args, "--overwrite").exit_code == 0
    assert path.read_bytes() != b"keep me \x00\xff\n"
    assert sorted(snapshot(outdir)) == [path.name]


@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS) + ["smooth -o"])
def test_output_parent_missing(option, outdir):
    path = outdir / "no" / "such" / ("smooth.vtu" if option == "smooth -o"
                                      else OUTPUT_OPTIONS[option][0])
    args = (["smooth", CYLINDER, "-o", path] if option == "smooth -o"
            else _project_with_output(option, path))
    check_error(invoke("-q", *args), 1, [f"{path}: directory '{path.parent}' does not exist"])
    assert snapshot(outdir) == {}
    assert not (outdir / "no").exists()


@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS) + ["smooth -o"])
def test_output_parent_is_a_file(option, outdir):
    (outdir / "file").write_text("x")
    path = outdir / "file" / ("smooth.vtu" if option == "smooth -o"
                              else OUTPUT_OPTIONS[option][0])
    args = (["smooth", CYLINDER, "-o", path] if option == "smooth -o"
            else _project_with_output(option, path))
    before = snapshot(outdir)
    check_error(invoke("-q", *args), 1, [f"{path}: '{path.parent}' is not a directory"])
    assert snapshot(outdir) == before


@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS) + ["smooth -o"])
def test_output_unwritable_directory(option, outdir, monkeypatch):
    """The OS refuses to create files there (as for root on a read-only file system)."""
    ro = outdir / "readonly"
    ro.mkdir()
    real = tempfile.mkstemp

    def refuse(*args, dir=None, **kwargs):
        if dir is not None and os.path.samefile(dir, ro):
            raise PermissionError(13, "Permission denied", str(Path(dir) / ".tmpXYZ"))
        return real(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    path = ro / ("smooth.vtu" if option == "smooth -o" else OUTPUT_OPTIONS[option][0])
    args = (["smooth", CYLINDER, "-o", path] if option == "smooth -o"
            else _project_with_output(option, path))
    line = check_error(invoke("-q", *args), 1,
                       [f"{path}: cannot create a file in '{ro}' (Permission denied)"])
    assert ".tmp" not in line  # the temporary name means nothing to the user
    assert snapshot(outdir) == {}


@pytest.mark.skipif(os.geteuid() == 0 if hasattr(os, "geteuid") else True,
                    reason="root writes into read-only directories")
@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS))
def test_output_read_only_directory(option, outdir):
    ro = outdir / "readonly"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        path = ro / OUTPUT_OPTIONS[option][0]
        check_error(invoke("-q", *_project_with_output(option, path)), 1,
                    [f"{path}: directory '{ro}' is not writable"])
        assert os.listdir(ro) == []
    finally:
        ro.chmod(0o700)


@pytest.mark.parametrize("option", list(OUTPUT_OPTIONS))
def test_output_is_a_directory(option, outdir):
    path = outdir / OUTPUT_OPTIONS[option][0]
    path.mkdir()
    check_error(invoke("-q", *_project_with_output(option, path), "--overwrite"), 1,
                [f"{path}: is a directory, expected an output file name"])
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("option, name, message", [
    ("-o", "result.foo",
     "unknown output format '.foo', expected .csv, .tsv, .parquet, .vtu, .vtk, .msh or .avs"),
    ("--residual", "R.csv", "expected a .mtx file name"),
    ("--tangent", "K.txt", "expected a .mtx file name"),
    ("--save-pairs", "P.csv", "expected a .npz file name"),
    ("smooth -o", "smooth.csv", "a surface mesh needs a mesh format"),
])
def test_output_wrong_format(option, name, message, outdir):
    path = outdir / name
    if option == "smooth -o":
        args = ["smooth", CYLINDER, "-o", path]
    else:
        args = ["project", CYLINDER, PLATE_CSV, option, path, *OUTPUT_OPTIONS[option][1]]
    check_error(invoke("-q", *args), 1, [f"diffsurf: error: {path}: {message}"])
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("option", ["--residual", "--tangent", "--save-pairs", "smooth -o"])
def test_stdout_dash_for_a_file_output_is_a_bad_option(option, outdir):
    args = (["smooth", CYLINDER, "-o", "-"] if option == "smooth -o"
            else _project_with_output(option, "-"))
    check_error(invoke("-q", *args), 2,
                [f"'{option.split()[-1]}'", "'-' (stdout)", "expected a file name"])
    assert not os.path.exists("-")


@pytest.mark.parametrize("first, second", [("--residual", "--tangent"), ("-o", "--save-pairs"),
                                           ("-o", "--tangent")])
def test_same_file_for_two_outputs_is_a_bad_option(first, second, outdir):
    path = outdir / "same.npz"
    args = ["project", CYLINDER, PLATE_CSV, first, path, second, path, "--penalty", "1e3"]
    check_error(invoke("-q", *args), 2, [first, second, "expected a file per output"])
    assert snapshot(outdir) == {}


def test_failure_writing_last_output_keeps_old_files(outdir, monkeypatch):
    """-o out.csv fails (a full disk, say) after R, K and the pairing were written.

    With --overwrite the earlier outputs already exist: all are kept as they were, and no new
    or temporary file is left.
    """
    from diffsurf_cli.io import table

    def full_disk(sink, *args, **kwargs):
        with open(sink, "wb") as fh:
            fh.write(b"half a row,")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(table, "write_csv", full_disk)
    names = {"--residual": "R.mtx", "--tangent": "K.mtx", "--save-pairs": "P.npz", "-o": "out.csv"}
    args = ["project", CYLINDER, PLATE_CSV, "--penalty", "1e3"]
    for option, name in names.items():
        args += [option, outdir / name]
    message = f"{outdir / 'out.csv'}: cannot write (No space left on device)"
    check_error(invoke("-q", *args), 1, [message])
    assert snapshot(outdir) == {}  # none of the four appeared
    for name in names.values():
        (outdir / name).write_bytes(b"old " + name.encode())
    before = snapshot(outdir)
    check_error(invoke("-q", *args, "--overwrite"), 1, [message])
    assert snapshot(outdir) == before


def test_all_outputs_written_together(outdir):
    """The batch commit writes every output when nothing fails (the counterpart of the above)."""
    args = ["project", CYLINDER, PLATE_CSV, "--penalty", "1e3", "--residual", outdir / "R.mtx",
            "--tangent", outdir / "K.mtx", "--save-pairs", outdir / "P.npz",
            "-o", outdir / "out.csv"]
    assert invoke("-q", *args).exit_code == 0
    assert sorted(snapshot(outdir)) == ["K.mtx", "P.npz", "R.mtx", "out.csv"]


# -------------------------------------------------------------------------------------------
# --pairs that does not match the inputs
# -------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pairings(tmp_path_factory, bad) -> dict:
    """Pairings stored by --save-pairs on several scenes, and damaged copies."""
    d = tmp_path_factory.mktemp("pairs")
    three = d / "three.csv"
    three.write_text("x,y,z\n30,20,0\n32.5,19.6,2.5\n35,20,5\n")
    made = {
        "diffuse": ["project", CYLINDER, PLATE_CSV],
        "facet": ["project", CYLINDER, PLATE_CSV, "--method", "facet"],
        "three": ["project", CYLINDER, three],
        "both": ["project", BOTH, PLATE_CSV],
        "both_facet": ["project", BOTH, PLATE_CSV, "--method", "facet"],
    }
    paths = {"three.csv": str(three), "not_pairs.npz": bad["not_pairs.npz"]}
    for name, args in made.items():
        paths[name] = str(d / f"{name}.npz")
        assert invoke("-q", *args, "--save-pairs", paths[name]).exit_code == 0
    good = dict(np.load(paths["diffuse"]))
    damaged = {
        "nan_radius": dict(good, radius=np.full_like(good["radius"], np.nan)),
        "short_axes": dict(good, axes=good["axes"][:3]),
        "float_index": dict(good, index=good["index"].astype(float)),
        "negative_index": dict(good, index=np.full_like(good["index"], -5)),
        "text_count": dict(good, n_contactors=np.array("many")),
        "no_method": {"x": np.zeros(3)},
    }
    for name, arrays in damaged.items():
        paths[name] = str(d / f"{name}.npz")
        np.savez(paths[name], **arrays)
    return paths


PAIRS_CASES = {  # name -> (pairing, extra arguments, message parts)
    "pairs_other_contactor_count": ("three", [], [
        "pairing made for 3 contactors and 85 target points, the inputs have 265 and 85"]),
    "pairs_other_target": ("diffuse", ["--target", BOTH, "--zone", "cylinder"], [
        "pairing made for 265 contactors and 85 target points, the inputs have 265 and 350"]),
    "pairs_other_method": ("diffuse", ["--method", "facet"],
                           ["pairing made with --method diffuse, not facet"]),
    "pairs_other_zone": ("both", ["--target", BOTH, "--zone", "cylinder"], [
        "the pairing's support nodes are not surface nodes of the target"]),
    "pairs_other_zone_facet": ("both_facet", ["--target", BOTH, "--zone", "cylinder",
                                              "--method", "facet"],
                               ["the pairing's facets are not facets of the target"]),
    "pairs_not_an_npz": ("not_pairs.npz", [], [
        "not an .npz archive, expected a pairing file written by --save-pairs"]),
    "pairs_npz_of_other_arrays": ("no_method", [], ["no pairing method (diffuse or facet)"]),
    "pairs_nan_radius": ("nan_radius", [], ["'radius' holds NaN or inf"]),
    "pairs_wrong_shape": ("short_axes", [], ["'axes' is float64 of shape (3, 3, 3), expected "
                                             "floats of shape (265x3x3)"]),
    "pairs_float_indices": ("float_index", [], ["'index' is float64", "expected integers"]),
    "pairs_negative_indices": ("negative_index", [], ["'index' holds negative indices"]),
    "pairs_count_not_a_number": ("text_count", [], ["'n_contactors' is not a count"]),
    "pairs_missing_file": ("/nonexistent/P.npz", [], ["no such file"]),
    "pairs_from_stdin": ("-", [], ["cannot be read from stdin, expected a file name"]),
}


@pytest.mark.parametrize("case", list(PAIRS_CASES))
def test_pairs_not_matching(case, pairings, outdir):
    key, extra, parts = PAIRS_CASES[case]
    pairs = pairings.get(key, key)
    target = CYLINDER
    if "--target" in extra:
        i = extra.index("--target")
        target, extra = extra[i + 1], extra[:i] + extra[i + 2:]
    old = outdir / "old.csv"
    old.write_bytes(b"old\n")
    before = snapshot(outdir)
    for penalty in ([], ["--penalty", "1e3", "--residual", outdir / "R.mtx"]):
        args = ["project", target, PLATE_CSV, "--pairs", pairs, *extra, *penalty]
        check_error(invoke("-q", *args, "-o", outdir / "new.csv"), 1,
                    [f"diffsurf: error: {pairs}: "] + parts)
        check_error(invoke("-q", *args, "-o", old, "--overwrite"), 1, parts)
        assert snapshot(outdir) == before
    check_verbose(args, None, pairs)


# -------------------------------------------------------------------------------------------
# NaN and inf contactors: kept, in place, flagged
# -------------------------------------------------------------------------------------------

NAN_CSV = ("id,x,y,z\n"
           "1,20.0,20.0,1.25\n"
           "2,nan,20.0,1.25\n"
           "3,32.5,20.3,2.5\n"
           "4,inf,20.0,0.0\n"
           "5,31.0,20.2,3.75\n"
           "6,-inf,20.0,nan\n"
           "7,40.0,20.1,5.0\n")
BAD_ROWS = [1, 3, 5]  # 0-based rows holding NaN or inf


def _rows(stdout):
    return list(csv.DictReader(_io.StringIO(stdout)))


@pytest.fixture(scope="module")
def nan_csv(tmp_path_factory):
    d = tmp_path_factory.mktemp("nan")
    path = d / "nan.csv"
    path.write_text(NAN_CSV)
    finite = d / "finite.csv"
    lines = NAN_CSV.splitlines()
    finite.write_text("\n".join([lines[0]] + [ln for i, ln in enumerate(lines[1:])
                                              if i not in BAD_ROWS]) + "\n")
    return str(path), str(finite)


STATUSES_ON_TARGET = ("open", "contact", "penetration")


@pytest.mark.parametrize("extra", [[], ["--method", "facet"], ["--recentre"],
                                   ["--frame", "global"], ["--support", "knn"]],
                         ids=["diffuse", "facet", "recentre", "global", "knn"])
def test_nan_or_inf_row_is_kept_and_flagged(extra, nan_csv):
    path, finite = nan_csv
    result = invoke("-q", "project", CYLINDER, path, *extra)
    assert result.exit_code == 0, result.stderr
    rows = _rows(result.stdout)
    assert [r["id"] for r in rows] == ["1", "2", "3", "4", "5", "6", "7"]  # none dropped
    for i, r in enumerate(rows):
        if i in BAD_ROWS:
            assert (r["status"], r["reason"]) == ("failed", "bad-point"), r
            assert all(np.isnan(float(r[k])) for k in ("gap", "nx", "px")), r
        else:
            assert r["reason"] != "bad-point", r
            # (a forced global frame may leave some good rows outside: steep or too thin)
            assert np.isfinite(float(r["gap"])) == (r["status"] in STATUSES_ON_TARGET), r
    # the bad rows do not disturb the others
    alone = _rows(invoke("-q", "project", CYLINDER, finite, *extra).stdout)
    good = [r for i, r in enumerate(rows) if i not in BAD_ROWS]
    assert [r["id"] for r in alone] == [r["id"] for r in good]
    for a, r in zip(alone, good):
        assert float(a["gap"]) == pytest.approx(float(r["gap"]), rel=0, abs=1e-12, nan_ok=True)
        assert a["status"] == r["status"]


def test_nan_row_with_contact_element(nan_csv, outdir):
    path, _ = nan_csv
    R, K = outdir / "R.mtx", outdir / "K.mtx"
    result = invoke("-q", "project", CYLINDER, path, "--penalty", "1e3", "--residual", R,
                    "--tangent", K)
    assert result.exit_code == 0, result.stderr
    rows = _rows(result.stdout)
    assert [r["status"] for i, r in enumerate(rows) if i in BAD_ROWS] == ["failed"] * 3
    r = np.asarray(scipy.io.mmread(str(R))).ravel()
    k = scipy.io.mmread(str(K)).toarray()
    assert np.isfinite(r).all() and np.isfinite(k).all()
    assert any(r[3 * i:3 * i + 3].any() for i in range(len(rows)) if i not in BAD_ROWS)
    for i in BAD_ROWS:  # a failed contactor has no element
        assert not r[3 * i:3 * i + 3].any() and not k[3 * i:3 * i + 3].any()


def test_nan_row_in_mesh_output(nan_csv, outdir):
    path, _ = nan_csv
    out = outdir / "out.vtu"
    assert invoke("-q", "project", CYLINDER, path, "-o", out).exit_code == 0
    mesh = meshio.read(str(out))
    assert len(mesh.points) == 7
    status = mesh.point_data["status"]
    assert status[BAD_ROWS].tolist() == [4, 4, 4]  # 4: failed
    assert (np.delete(status, BAD_ROWS) != 4).all()
    np.testing.assert_array_equal(mesh.point_data["id"], np.arange(1, 8))


def test_nan_row_with_frozen_pairs(nan_csv, outdir):
    path, _ = nan_csv
    pairs = outdir / "P.npz"
    assert invoke("-q", "project", CYLINDER, path, "--save-pairs", pairs).exit_code == 0
    result = invoke("-q", "project", CYLINDER, path, "--pairs", pairs)
    assert result.exit_code == 0, result.stderr
    rows = _rows(result.stdout)
    assert [(r["status"], r["reason"]) for i, r in enumerate(rows) if i in BAD_ROWS] == \
        [("failed", "bad-point")] * 3


def test_nan_row_with_frozen_facet_pairs(nan_csv, outdir):
    path, _ = nan_csv
    pairs = outdir / "P.npz"
    args = ["project", CYLINDER, path, "--method", "facet"]
    assert invoke("-q", *args, "--save-pairs", pairs).exit_code == 0
    result = invoke("-q", *args, "--pairs", pairs)
    assert result.exit_code == 0, result.stderr
    rows = _rows(result.stdout)
    assert len(rows) == 7
    assert [(r["status"], r["reason"]) for i, r in enumerate(rows) if i in BAD_ROWS] == \
        [("failed", "bad-point")] * 3


def test_huge_number_is_inf_and_flagged(tmp_path):
    """A 400-digit coordinate overflows to inf: the row is kept and flagged, not an error."""
    path = tmp_path / "big.csv"
    path.write_text("x,y,z\n30,20,0\n1" + "0" * 400 + ",20,0\n35,20,0\n")
    result = invoke("-q", "project", CYLINDER, path)
    assert result.exit_code == 0, result.stderr
    rows = _rows(result.stdout)
    assert [r["x"] for r in rows] == ["30.0", "inf", "35.0"]
    assert [r["status"] for r in rows][1] == "failed"
    assert rows[1]["reason"] == "bad-point"


# -------------------------------------------------------------------------------------------
# inputs that must work
# -------------------------------------------------------------------------------------------


def test_crlf_line_ends_work(tmp_path):
    text = Path(PLATE_CSV).read_text()
    crlf = tmp_path / "plate_crlf.csv"
    crlf.write_bytes(text.replace("\n", "\r\n").encode())
    a = invoke("-q", "project", CYLINDER, PLATE_CSV)
    b = invoke("-q", "project", CYLINDER, crlf)
    c = invoke("-q", "project", CYLINDER, "-", input=crlf.read_bytes())
    assert a.exit_code == b.exit_code == c.exit_code == 0, (b.stderr, c.stderr)
    assert b.stdout == a.stdout and c.stdout == a.stdout
    assert len(_rows(a.stdout)) == N_PLATE


# -------------------------------------------------------------------------------------------
# a real process: no traceback, or one with -v
# -------------------------------------------------------------------------------------------


def _process(*args, stdin=None):
    return subprocess.run([sys.executable, "-m", "diffsurf_cli.cli", *map(str, args)],
                          input=stdin, capture_output=True, timeout=120)


@pytest.mark.parametrize("case", ["garbage_msh", "csv_non_numeric_text", "output_exists",
                                  "pairs_other_contactor_count"])
def test_real_process_traceback_only_with_verbose(case, bad, pairings, tmp_path):
    exists = tmp_path / "exists.csv"
    exists.write_text("old\n")
    args, name = {
        "garbage_msh": (["smooth", bad["garbage.msh"], "-o", tmp_path / "s.vtu"],
                        bad["garbage.msh"]),
        "csv_non_numeric_text": (["project", CYLINDER, bad["non_numeric.csv"]],
                                 bad["non_numeric.csv"]),
        "output_exists": (["project", CYLINDER, PLATE_CSV, "-o", exists], str(exists)),
        "pairs_other_contactor_count": (["project", CYLINDER, PLATE_CSV, "--pairs",
                                         pairings["three"]], pairings["three"]),
    }[case]
    quiet = _process("-q", *args)
    assert quiet.returncode == 1 and quiet.stdout == b""
    err = quiet.stderr.decode()
    assert err.startswith(f"diffsurf: error: {name}") and err.count("\n") == 1, err
    assert "Traceback" not in err
    loud = _process("-v", *args)
    assert loud.returncode == 1 and loud.stdout == b""
    assert "Traceback (most recent call last)" in loud.stderr.decode()
    assert name in loud.stderr.decode()
    assert exists.read_text() == "old\n"
    assert sorted(os.listdir(tmp_path)) == ["exists.csv"]


def test_real_process_mesh_on_stdin_as_target():
    proc = _process("-q", "project", "-", PLATE_CSV, stdin=(SAMPLES / "cylinder.msh").read_bytes())
    assert proc.returncode == 1 and proc.stdout == b""
    assert proc.stderr.decode() == ("diffsurf: error: -: a mesh cannot be read from stdin, "
                                    "expected a mesh file name (only CSV contactors can come "
                                    "on stdin)\n")


def test_real_process_binary_stdin():
    proc = _process("-q", "project", CYLINDER, "-", stdin=b"x,y,z\n\xff\xfe\x00\x01,2,3\n")
    assert proc.returncode == 1 and proc.stdout == b""
    err = proc.stderr.decode()
    assert err.startswith("diffsurf: error: <stdin>") and err.count("\n") == 1, err


def test_truncated_binary_msh4_is_a_read_error_at_every_cut(tmp_path):
    """Issue 22, item 10: a truncated binary .msh v4 raised 'ValueError: quad cells of 2
    nodes are not supported' from the method's code, outside the reader's handling. Cut
    anywhere, the file reads, or is refused in one line naming it (ReadError)."""
    import meshio

    from diffsurf_cli.io import ReadError
    from diffsurf_cli.targets import read_surface
    from samples import CYLINDER

    mesh = meshio.read(CYLINDER)
    whole = tmp_path / "whole.msh"
    meshio.write(whole, meshio.Mesh(mesh.points, [(b.type, b.data) for b in mesh.cells
                                                  if b.type == "quad"]),
                 file_format="gmsh", binary=True)
    data = whole.read_bytes()
    cut = tmp_path / "cut.msh"
    for end in range(40, len(data), 3):
        cut.write_bytes(data[:end])
        try:
            read_surface(str(cut))
        except ReadError as exc:
            assert str(cut) in str(exc) and "\n" not in str(exc)


def test_a_panic_in_the_parquet_reader_is_a_read_error(tmp_path, monkeypatch):
    """Issue 22, item 10: a corrupt Parquet file ended in an 84-line Rust panic (pyo3's
    PanicException derives from BaseException). It is one line naming the file."""
    import polars as pl

    from diffsurf_cli.io import ReadError, read_contactors

    path = tmp_path / "p.parquet"
    pl.DataFrame({"x": [0.0], "y": [0.0], "z": [0.0]}).write_parquet(path)

    def panic(*args, **kwargs):
        raise pl.exceptions.PanicException("index out of bounds")

    monkeypatch.setattr(pl, "read_parquet", panic)
    with pytest.raises(ReadError, match="p.parquet: cannot read Parquet"):
        read_contactors(str(path))
