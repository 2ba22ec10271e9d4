"""Tests of diffsurf_cli.io: reading targets and contactors, writing results (the CSV and
Parquet rules in detail: test_table.py)."""
import contextlib
import io
import os
import stat
import struct
import subprocess
import sys
import tempfile
import threading
import traceback
import warnings

import meshio
import numpy as np
import pytest

from diffsurf_cli.io import (
    SURFACE_CELL_TYPES,
    Contactors,
    ReadError,
    WriteError,
    check_output_path,
    read_contactors,
    read_target,
    write_result,
)
from diffsurf_cli.io import contactors as dcontactors
from diffsurf_cli.io import formats as dformats
from diffsurf_cli.io import mesh as dmesh
from diffsurf_cli.io import paths as dpaths
from diffsurf_cli.io import table as dtable
from samples import BOTH, CYLINDER, N_PLATE, PLATE_CSV, PLATE_VTU

STATUS = ("open", "contact", "penetration", "outside", "failed")


# --------------------------------------------------------------------------------------------
# fixtures
# --------------------------------------------------------------------------------------------


def _points():
    # 0..3 unit square, 4..5 extend it to x = 2, 6..9 mid-side nodes of the square, 10 apex
    return np.array(
        [
            [0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0],
            [0.5, 0, 0], [1, 0.5, 0], [0.5, 1, 0], [0, 0.5, 0], [0, 0, 1],
            [3, 3, 3],  # referenced by nothing
        ],
        dtype=float,
    )


def _mixed_mesh(**kwargs):
    cells = [
        ("triangle", np.array([[1, 4, 5], [1, 5, 2]])),
        ("quad8", np.array([[0, 1, 2, 3, 6, 7, 8, 9]])),
        ("line", np.array([[0, 1]])),
        ("tetra", np.array([[0, 1, 3, 10]])),
    ]
    return meshio.Mesh(_points(), cells, **kwargs)


def _gmsh_mesh():
    return _mixed_mesh(
        cell_data={
            "gmsh:physical": [np.array([1, 1]), np.array([2]), np.array([3]), np.array([1])],
            "gmsh:geometrical": [np.array([1, 1]), np.array([2]), np.array([3]), np.array([4])],
        },
        # 'vol' shares tag 1 with 'right' but is 3-D: it must not select the triangles
        field_data={
            "right": np.array([1, 2]),
            "left": np.array([2, 2]),
            "edge": np.array([3, 1]),
            "vol": np.array([1, 3]),
        },
    )


ABAQUS_INP = """*Heading
 diffsurf test
*Node
1, 0.0, 0.0, 0.0
2, 1.0, 0.0, 0.0
3, 1.0, 1.0, 0.0
4, 0.0, 1.0, 0.0
5, 2.0, 0.0, 0.0
6, 2.0, 1.0, 0.0
7, 0.0, 0.0, 1.0
*Element, type=S3, elset=RIGHT
1, 2, 5, 6
2, 2, 6, 3
*Element, type=S4
3, 1, 2, 3, 4
*Element, type=C3D4
4, 1, 2, 4, 7
*Elset, elset=LEFT
3, 4
"""

GMSH41_ASCII = """$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
1
2 5 "top"
$EndPhysicalNames
$Entities
0 0 1 0
1 0 0 0 1 1 0 1 5 0
$EndEntities
$Nodes
1 4 1 4
2 1 0 4
1
2
3
4
0 0 0
1 0 0
1 1 0
0 1 0
$EndNodes
$Elements
1 2 1 2
2 1 2 2
1 1 2 3
2 1 3 4
$EndElements
"""


def _csv_contactors(n=4):
    pts = np.arange(3 * n, dtype=float).reshape(n, 3) / 7.0
    return Contactors("in.csv", pts, ["id"], [[f"{i:03d}"] for i in range(n)], None)


def _result_columns(c):
    n = len(c.points)
    rng = np.random.default_rng(1)
    return {
        "x": c.points[:, 0],
        "y": c.points[:, 1],
        "z": c.points[:, 2],
        "gap": rng.normal(size=n),
        "nx": np.ones(n),
        "ny": np.zeros(n),
        "nz": np.zeros(n),
        "status": np.arange(n) % len(STATUS),
        "iterations": np.arange(n, dtype=np.int64),
    }


# --------------------------------------------------------------------------------------------
# read_contactors: CSV
# --------------------------------------------------------------------------------------------


def test_csv_header_passthrough_kept(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("id,x,y,z,label\n007,0.1,2,-3e-5,  a b\n008, 1 ,2,3,c;d\n")
    c = read_contactors(str(f))
    assert c.passthrough_names == ["id", "label"]
    # surrounding whitespace is stripped, everything else kept as text
    assert c.passthrough_rows() == [["007", "a b"], ["008", "c;d"]]
    np.testing.assert_array_equal(c.points, [[0.1, 2, -3e-5], [1, 2, 3]])
    assert c.points.dtype == np.float64
    assert c.mesh is None


def test_csv_header_any_order_and_case(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text(" Z , name, X,Y\n3,p,1,2\n")
    c = read_contactors(str(f))
    np.testing.assert_array_equal(c.points, [[1, 2, 3]])
    assert c.passthrough_names == ["name"]
    assert c.passthrough_rows() == [["p"]]


def test_csv_headerless_three_columns(tmp_path):
    f = tmp_path / "points.txt"
    f.write_text("1,2,3\n4,5,6\n")
    c = read_contactors(str(f))
    np.testing.assert_array_equal(c.points, [[1, 2, 3], [4, 5, 6]])
    assert c.passthrough_names == []
    assert c.passthrough_rows() == [[], []]


def test_csv_headerless_five_columns_last_three_are_xyz(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("10,007,1,2,3\n11,008,4,5,6\n")
    c = read_contactors(str(f))
    np.testing.assert_array_equal(c.points, [[1, 2, 3], [4, 5, 6]])
    assert c.passthrough_names == ["col1", "col2"]
    assert c.passthrough_rows() == [["10", "007"], ["11", "008"]]


def test_csv_comments_and_blank_lines(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("# contactors\n\nx,y,z\n  # indented comment, with commas\n1,2,3\n\n\r\n4,5,6\r\n")
    c = read_contactors(str(f))
    np.testing.assert_array_equal(c.points, [[1, 2, 3], [4, 5, 6]])


def test_csv_nan_and_inf_kept(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("x,y,z\nnan,1,2\n1,inf,-inf\n")
    c = read_contactors(str(f))
    assert np.isnan(c.points[0, 0])
    assert c.points[1, 1] == np.inf and c.points[1, 2] == -np.inf


def test_csv_from_stdin():
    c = read_contactors("-", stdin=io.StringIO("id,x,y,z\na,1,2,3\n"))
    assert c.path == "-"
    np.testing.assert_array_equal(c.points, [[1, 2, 3]])
    assert c.passthrough_rows() == [["a"]]


def test_csv_utf8_bom_header(tmp_path):
    f = tmp_path / "points.csv"
    f.write_bytes("\ufeffx,y,z\n1,2,3\n".encode("utf-8"))
    np.testing.assert_array_equal(read_contactors(str(f)).points, [[1, 2, 3]])


def test_csv_wrong_column_count_names_line(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("# c\nx,y,z\n1,2,3\n\n4,5\n")
    with pytest.raises(ReadError, match=r"points\.csv, line 5: expected 3 .*got 2"):
        read_contactors(str(f))


def test_csv_non_numeric_coordinate(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("1,2,3\n4,5,6\n\n7,abc,9\n")
    with pytest.raises(ReadError, match=r"points\.csv, line 4: .*y.*'abc'") as exc:
        read_contactors(str(f))
    assert "\n" not in str(exc.value)


def test_csv_header_without_xyz(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(ReadError, match=r"points\.csv, line 1: header has no 'x'"):
        read_contactors(str(f))


def test_csv_too_few_columns(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("1,2\n")
    with pytest.raises(ReadError, match="expected 3 numeric columns"):
        read_contactors(str(f))


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "x,y,z\n"])
def test_csv_empty(tmp_path, text):
    f = tmp_path / "points.csv"
    f.write_text(text)
    with pytest.raises(ReadError, match="no data rows"):
        read_contactors(str(f))


@pytest.mark.parametrize("data", [b"1,2,3\n\x00\x00\x01", b"\xff\xfe\x89PNG garbage \xc3\x28"])
def test_csv_binary_garbage(tmp_path, data):
    f = tmp_path / "points.csv"
    f.write_bytes(data)
    with pytest.raises(ReadError, match=r"points\.csv: not a text CSV file"):
        read_contactors(str(f))


def test_csv_missing_file(tmp_path):
    with pytest.raises(ReadError, match=r"nope\.csv: no such file"):
        read_contactors(str(tmp_path / "nope.csv"))


def test_csv_directory(tmp_path):
    d = tmp_path / "dir.csv"
    d.mkdir()
    with pytest.raises(ReadError, match="is a directory"):
        read_contactors(str(d))


def test_contactors_unknown_extension(tmp_path):
    f = tmp_path / "points.xyz"
    f.write_text("1,2,3\n")
    with pytest.raises(ReadError, match=r"points\.xyz: unknown contactor file format '\.xyz'"):
        read_contactors(str(f))


def test_contactors_from_mesh(tmp_path):
    f = tmp_path / "contactors.vtu"
    meshio.write(str(f), _mixed_mesh())
    c = read_contactors(str(f))
    np.testing.assert_array_equal(c.points, _points())
    assert c.passthrough_names == [] and c.passthrough == []
    assert c.passthrough_rows() == [[]] * len(_points())
    assert isinstance(c.mesh, meshio.Mesh)


# --------------------------------------------------------------------------------------------
# write_result
# --------------------------------------------------------------------------------------------


def test_write_csv_round_trip_exact(tmp_path):
    n = 6
    pts = np.array([[0.1, 1e-300, -0.0], [1 / 3, 2 / 3, 1e16], [np.pi, -np.e, 5e-324]] * 2)
    c = Contactors("in.csv", pts, ["id", "label"], [[f"00{i}", "a b"] for i in range(n)], None)
    gap = np.array([0.1, np.nan, np.inf, -1e-300, 123456789.123456789, 2.0**-1074])
    cols = {"gap": gap, "status": np.array([0, 1, 2, 3, 4, 0]), "n": np.arange(n), "x": pts[:, 0]}
    out = tmp_path / "out.csv"
    write_result(str(out), c, cols, labels={"status": STATUS})

    lines = out.read_text().splitlines()
    assert lines[0] == "id,label,gap,status,n,x"
    assert lines[1] == "000,a b,0.1,open,0,0.1"
    assert lines[2].split(",")[2:4] == ["NaN", "contact"]
    rows = [line.split(",") for line in lines[1:]]
    assert [r[3] for r in rows] == list(STATUS) + ["open"]
    back = np.array([float(r[2]) for r in rows])
    # bit-for-bit, NaN included
    assert back.view(np.int64).tolist() == gap.view(np.int64).tolist()
    assert [float(r[5]) for r in rows] == pts[:, 0].tolist()
    assert [r[4] for r in rows] == [str(i) for i in range(n)]


def test_write_csv_then_read_back_keeps_passthrough(tmp_path):
    f = tmp_path / "points.csv"
    f.write_text("id,x,y,z,label\n007,0.1,0.2,0.3,  a b\n")
    c = read_contactors(str(f))
    out = tmp_path / "out.csv"
    write_result(str(out), c, {"x": c.points[:, 0], "y": c.points[:, 1], "z": c.points[:, 2]})
    assert out.read_text() == "id,label,x,y,z\n007,a b,0.1,0.2,0.3\n"
    again = read_contactors(str(out))
    assert again.passthrough_rows() == c.passthrough_rows()
    np.testing.assert_array_equal(again.points, c.points)


def test_write_stdout():
    c = _csv_contactors(2)
    buf = io.StringIO()
    write_result("-", c, {"gap": np.array([0.5, -1.0])}, stdout=buf)
    assert buf.getvalue() == "id,gap\n000,0.5\n001,-1.0\n"
    buf = io.StringIO()
    write_result(None, c, {"status": np.array([4, 1])}, labels={"status": STATUS}, stdout=buf)
    assert buf.getvalue() == "id,status\n000,failed\n001,contact\n"


def test_write_vtu_point_data(tmp_path):
    c = _csv_contactors(5)
    cols = _result_columns(c)
    cols["x"] = cols["x"] + 10.0
    out = tmp_path / "out.vtu"
    write_result(str(out), c, cols, labels={"status": STATUS})
    m = meshio.read(str(out))
    np.testing.assert_array_equal(m.points[:, 0], c.points[:, 0] + 10.0)
    np.testing.assert_array_equal(m.point_data["gap"], cols["gap"])
    assert m.point_data["normal"].shape == (5, 3)
    np.testing.assert_array_equal(m.point_data["normal"][:, 0], 1.0)
    assert m.point_data["status"].dtype.kind == "i"
    np.testing.assert_array_equal(m.point_data["status"], cols["status"])
    # "007"-style pass-through ids are numeric, so they become point data
    np.testing.assert_array_equal(m.point_data["id"], np.arange(5))
    assert not {"x", "y", "z", "nx", "ny", "nz"} & set(m.point_data)
    assert m.cells[0].type == "vertex" and len(m.cells[0].data) == 5


def test_write_mesh_reuses_contactor_cells_and_skips_text(tmp_path):
    src = tmp_path / "contactors.vtu"
    meshio.write(str(src), _mixed_mesh())
    c = read_contactors(str(src))
    n = len(c.points)
    c.passthrough_names = ["tag"]
    c.passthrough = dtable.text_columns([["a"]] * n, 1)
    out = tmp_path / "out.vtk"
    write_result(str(out), c, {"gap": np.linspace(0, 1, n)})
    m = meshio.read(str(out))
    assert [b.type for b in m.cells] == ["triangle", "quad8", "line", "tetra"]
    assert "tag" not in m.point_data
    np.testing.assert_array_equal(m.points, _points())


def test_write_msh(tmp_path):
    c = _csv_contactors(3)
    out = tmp_path / "out.msh"
    write_result(str(out), c, {"gap": np.array([1.0, 2.0, 3.0])})
    m = meshio.read(str(out))
    np.testing.assert_array_equal(m.point_data["gap"], [1.0, 2.0, 3.0])


def test_refuses_to_overwrite_before_work(tmp_path, monkeypatch):
    out = tmp_path / "out.csv"
    out.write_text("keep me")

    def boom(*a, **k):
        raise AssertionError("no work must be done")

    monkeypatch.setattr(dcontactors, "_validate_columns", boom)
    with pytest.raises(WriteError, match=r"out\.csv: already exists \(use --overwrite\)"):
        write_result(str(out), _csv_contactors(), {})
    assert out.read_text() == "keep me"
    with pytest.raises(WriteError, match="already exists"):
        check_output_path(str(out), overwrite=False)


def test_overwrite_replaces(tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("old")
    write_result(str(out), _csv_contactors(1), {"gap": np.array([2.5])}, overwrite=True)
    assert out.read_text() == "id,gap\n000,2.5\n"
    assert os.listdir(tmp_path) == ["out.csv"]


def test_missing_parent_directory(tmp_path):
    out = tmp_path / "no" / "such" / "out.csv"
    with pytest.raises(WriteError, match=r"out\.csv: directory .* does not exist"):
        write_result(str(out), _csv_contactors(1), {"gap": np.array([1.0])})
    assert not (tmp_path / "no").exists()


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root writes anywhere")
def test_unwritable_directory_leaves_nothing(tmp_path):
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o500)
    try:
        with pytest.raises(WriteError, match="not writable"):
            write_result(str(d / "out.csv"), _csv_contactors(1), {"gap": np.array([1.0])})
        assert os.listdir(d) == []
    finally:
        d.chmod(0o700)


def test_unwritable_when_creation_fails(tmp_path, monkeypatch):
    # as root the permission check passes, so also simulate the OS refusing the file
    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(WriteError, match=r"out\.csv: cannot create a file in .*Permission denied"):
        write_result(str(tmp_path / "out.csv"), _csv_contactors(1), {"gap": np.array([1.0])})
    assert os.listdir(tmp_path) == []


def test_failure_mid_write_leaves_no_temp_file(tmp_path, monkeypatch):
    def broken_write(filename, *a, **k):
        with open(filename, "w") as fh:
            fh.write("half")
        raise RuntimeError("disk full\nsecond line")

    monkeypatch.setattr(meshio, "write", broken_write)
    out = tmp_path / "out.vtu"
    with pytest.raises(WriteError, match=r"out\.vtu: cannot write \(disk full\)$"):
        write_result(str(out), _csv_contactors(), {"gap": np.zeros(4)})
    assert os.listdir(tmp_path) == []


def test_failure_mid_csv_keeps_old_file(tmp_path, monkeypatch):
    out = tmp_path / "out.csv"
    out.write_text("old")
    real = dtable._result_series
    calls = []

    def flaky(name, values, words):
        calls.append(1)
        if len(calls) > 1:
            raise MemoryError("out of memory")
        return real(name, values, words)

    monkeypatch.setattr(dtable, "_result_series", flaky)
    with pytest.raises(WriteError, match="out of memory"):
        write_result(str(out), _csv_contactors(), {"a": np.zeros(4), "b": np.zeros(4)},
                     overwrite=True)
    assert out.read_text() == "old"
    assert os.listdir(tmp_path) == ["out.csv"]


def test_unknown_output_extension(tmp_path):
    """Issue 22, item 16: a result's unknown extension suggests the formats that hold a result
    only (it suggested .stl, .obj, .ply, then refused them)."""
    with pytest.raises(WriteError,
                       match=r"out\.xyz: unknown output format '\.xyz', expected \.csv") as info:
        check_output_path(str(tmp_path / "out.xyz"), overwrite=False)
    assert ".stl" not in str(info.value) and ".vtu" in str(info.value)


def test_output_is_a_directory(tmp_path):
    d = tmp_path / "out.csv"
    d.mkdir()
    with pytest.raises(WriteError, match="is a directory"):
        check_output_path(str(d), overwrite=True)


def test_check_output_path_accepts_stdout_and_mesh(tmp_path):
    check_output_path(None, False)
    check_output_path("-", False)
    check_output_path(str(tmp_path / "r.vtu"), False)
    check_output_path(str(tmp_path / "r.txt"), False)


def test_bad_columns_rejected(tmp_path):
    c = _csv_contactors(3)
    out = tmp_path / "out.csv"
    with pytest.raises(WriteError, match=r"column 'gap' has shape \(2,\), expected \(3,\)"):
        write_result(str(out), c, {"gap": np.zeros(2)})
    with pytest.raises(WriteError, match="codes outside"):
        write_result(str(out), c, {"status": np.array([0, 1, 9])}, labels={"status": STATUS})
    assert not out.exists()


# --------------------------------------------------------------------------------------------
# read_target
# --------------------------------------------------------------------------------------------


def _check_mixed_target(t, quad_type="quad8"):
    assert [ct for ct, _ in t.cells] == ["triangle", quad_type]
    np.testing.assert_array_equal(t.cells[0][1], [[1, 4, 5], [1, 5, 2]])
    assert all(c.dtype == np.int64 for _, c in t.cells)
    assert t.nodes.dtype == np.int64
    assert t.points.shape == (12, 3) and t.points.dtype == np.float64


@pytest.mark.parametrize(
    "fmt,kwargs", [("gmsh22", {"binary": False}), ("gmsh22", {"binary": True})]
)
def test_target_msh22(tmp_path, fmt, kwargs):
    f = tmp_path / "target.msh"
    meshio.write(str(f), _gmsh_mesh(), file_format=fmt, **kwargs)
    t = read_target(str(f))
    _check_mixed_target(t)
    # mid-side nodes count; the apex 10 (only in the tetra) and point 11 do not
    np.testing.assert_array_equal(t.nodes, np.arange(10))
    assert t.ignored == {"line": 1, "tetra": 1}
    np.testing.assert_array_equal(t.points, _points())


def test_target_msh_zone_by_physical_name(tmp_path):
    f = tmp_path / "target.msh"
    meshio.write(str(f), _gmsh_mesh(), file_format="gmsh22", binary=False)
    t = read_target(str(f), zone="right")
    assert [ct for ct, _ in t.cells] == ["triangle"]
    np.testing.assert_array_equal(t.nodes, [1, 2, 4, 5])
    assert t.ignored == {}
    t = read_target(str(f), zone="left")
    assert [ct for ct, _ in t.cells] == ["quad8"]
    with pytest.raises(ReadError, match=r"no surface cells .* in zone 'edge'; it has: 1 line"):
        read_target(str(f), zone="edge")
    # a zone of volume cells is the boundary of its cells (issue 11: once refused)
    t = read_target(str(f), zone="vol")
    assert [ct for ct, _ in t.cells] == ["triangle"] and len(t.cells[0][1]) == 4
    assert t.boundary == {"tetra": 1} and t.ignored == {}


def test_target_unknown_zone_lists_names(tmp_path):
    f = tmp_path / "target.msh"
    meshio.write(str(f), _gmsh_mesh(), file_format="gmsh22", binary=False)
    with pytest.raises(ReadError, match=r"target\.msh: unknown zone 'cylinder'") as exc:
        read_target(str(f), zone="cylinder")
    for name in ("right", "left", "edge", "vol"):
        assert repr(name) in str(exc.value)


def test_target_msh41_ascii_zone(tmp_path):
    f = tmp_path / "target.msh"
    f.write_text(GMSH41_ASCII)
    t = read_target(str(f), zone="top")
    np.testing.assert_array_equal(t.cells[0][1], [[0, 1, 2], [0, 2, 3]])
    np.testing.assert_array_equal(t.nodes, [0, 1, 2, 3])


def test_target_inp_zone_by_elset(tmp_path):
    f = tmp_path / "target.inp"
    f.write_text(ABAQUS_INP)
    t = read_target(str(f))
    assert [ct for ct, _ in t.cells] == ["triangle", "quad"]
    assert t.ignored == {"tetra": 1}
    t = read_target(str(f), zone="RIGHT")
    assert [ct for ct, _ in t.cells] == ["triangle"]
    np.testing.assert_array_equal(t.nodes, [1, 2, 4, 5])
    t = read_target(str(f), zone="LEFT")
    assert [ct for ct, _ in t.cells] == ["quad"]
    assert t.ignored == {"tetra": 1}
    with pytest.raises(ReadError, match=r"available zones: .*'LEFT'"):
        read_target(str(f), zone="nope")


def test_target_inp_written_by_meshio(tmp_path):
    f = tmp_path / "target.inp"
    meshio.write(str(f), _mixed_mesh())
    t = read_target(str(f))
    _check_mixed_target(t)
    assert t.ignored == {"line": 1, "tetra": 1}


def test_target_vtu(tmp_path):
    f = tmp_path / "target.vtu"
    meshio.write(str(f), _mixed_mesh())
    t = read_target(str(f))
    _check_mixed_target(t)
    assert t.ignored == {"line": 1, "tetra": 1}


def test_target_vtk_2d_points_padded(tmp_path):
    f = tmp_path / "target.vtk"
    pts = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    meshio.write(str(f), meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3]]))]))
    t = read_target(str(f))
    assert t.points.shape == (4, 3)
    np.testing.assert_array_equal(t.points[:, 2], 0.0)


@pytest.mark.parametrize("ext", ["stl", "obj", "ply"])
def test_target_triangle_formats(tmp_path, ext):
    f = tmp_path / f"target.{ext}"
    pts = _points()[:6]
    tris = np.array([[1, 4, 5], [1, 5, 2], [0, 1, 2]])
    meshio.write(str(f), meshio.Mesh(pts, [("triangle", tris)]))
    t = read_target(str(f))
    assert [ct for ct, _ in t.cells] == ["triangle"]
    # STL stores facets, so compare geometry rather than indices
    np.testing.assert_allclose(np.sort(t.points[t.cells[0][1]].reshape(-1, 3), axis=0),
                               np.sort(pts[tris].reshape(-1, 3), axis=0))


def test_target_obj_with_quads(tmp_path):
    f = tmp_path / "target.obj"
    pts = _points()[:6]
    meshio.write(str(f), meshio.Mesh(pts, [("triangle", np.array([[1, 4, 5], [1, 5, 2]])),
                                           ("quad", np.array([[0, 1, 2, 3]]))]))
    t = read_target(str(f))
    assert sorted(ct for ct, _ in t.cells) == ["quad", "triangle"]
    np.testing.assert_array_equal(t.nodes, np.arange(6))


def test_target_no_surface_cells(tmp_path):
    f = tmp_path / "target.msh"
    m = meshio.Mesh(_points(), [("line", np.array([[0, 1], [1, 2]])),
                                ("vertex", np.array([[3]]))])
    meshio.write(str(f), m, file_format="gmsh22", binary=False)
    with pytest.raises(ReadError, match=r"^\S*target\.msh: no surface cells \(triangle/quad\) "
                                        r"or volume cells \(tetra/hexahedron/wedge/pyramid\) "
                                        r"found; it has: 2 line, 1 vertex$"):
        read_target(str(f))


def test_target_of_volume_cells_is_their_boundary(tmp_path):
    """Volume cells and no surface cells: the faces used by one cell (issue 11; once refused
    as 'no surface cells'); lines are still ignored."""
    f = tmp_path / "target.msh"
    m = meshio.Mesh(_points(), [("tetra", np.array([[0, 1, 3, 10], [1, 2, 3, 10]])),
                                ("line", np.array([[0, 1]]))])
    meshio.write(str(f), m, file_format="gmsh22", binary=False)
    t = read_target(str(f))
    assert t.boundary == {"tetra": 2} and t.ignored == {"line": 1}
    assert [ct for ct, _ in t.cells] == ["triangle"] and len(t.cells[0][1]) == 6  # 8 - shared
    np.testing.assert_array_equal(t.nodes, [0, 1, 2, 3, 10])


def test_target_nan_coordinates(tmp_path):
    f = tmp_path / "target.vtu"
    pts = _points()
    pts[2, 1] = np.nan
    meshio.write(str(f), meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))]))
    with pytest.raises(ReadError, match=r"target\.vtu: non-finite coordinates .* point 2"):
        read_target(str(f))


@pytest.mark.parametrize(
    "data",
    [
        b"\x00\x01garbage\xff" * 50,
        b"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\nlots\n",
        b"$MeshFormat\n2.2 1 8\n" + struct.pack("i", 7) + b"\n$EndMeshFormat\n$Nodes\n3\n",
        b"",
    ],
)
def test_target_garbage_msh(tmp_path, data, capsys):
    f = tmp_path / "target.msh"
    f.write_bytes(data)
    with pytest.raises(ReadError, match=r"target\.msh: ") as exc:
        read_target(str(f))
    assert "\n" not in str(exc.value)
    # meshio.read would print to stdout (where CSV results go) and sys.exit
    assert capsys.readouterr().out == ""


def test_target_garbage_stl(tmp_path):
    f = tmp_path / "target.stl"
    f.write_bytes(b"solid x\n facet normal nonsense\n")
    with pytest.raises(ReadError, match=r"target\.stl: "):
        read_target(str(f))


def test_target_unknown_extension(tmp_path):
    f = tmp_path / "target.xyz"
    f.write_text("1 2 3\n")
    with pytest.raises(ReadError, match=r"target\.xyz: unknown mesh format '\.xyz' "
                                        r"\(meshio reads \.msh, \.vtu"):
        read_target(str(f))


def test_target_missing_and_directory(tmp_path):
    with pytest.raises(ReadError, match=r"target\.msh: no such file"):
        read_target(str(tmp_path / "target.msh"))
    d = tmp_path / "dir.vtu"
    d.mkdir()
    with pytest.raises(ReadError, match="is a directory, expected a file"):
        read_target(str(d))


def test_surface_cell_types():
    assert set(SURFACE_CELL_TYPES) == {"triangle", "triangle6", "triangle7", "quad", "quad8",
                                       "quad9"}


# --------------------------------------------------------------------------------------------
# outputs that cannot hold the results, and outputs written in place (issue 14, item 3)
# --------------------------------------------------------------------------------------------

#: every extension meshio writes, and its format (as write_result would choose it)
WRITER_EXTENSIONS = sorted(
    (ext, dformats.writer_format("r" + ext))
    for ext, formats in meshio.extension_to_filetypes.items()
    if any(f in meshio._helpers._writer_map for f in formats)
    and ext not in (".ele", ".node"))  # tetgen: two files, refused as such


def _result_round_trip(tmp_path, ext, fmt, source):
    """Write a result in ``fmt`` and read it back: whether the points and every point data
    array survive (None if the writer needs a module that is not installed)."""
    p = len(source.points) if source is not None else 7
    pts = source.points if source is not None else np.random.default_rng(3).normal(size=(p, 3))
    cols = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "gap": np.linspace(-1, 1, p),
            "nx": pts[:, 0], "ny": pts[:, 1], "nz": pts[:, 2], "px": pts[:, 0] + 1,
            "py": pts[:, 1], "pz": pts[:, 2], "status": np.arange(p) % 5,
            "support": np.arange(p) + 9, "rcond": np.linspace(0.1, 0.2, p)}
    result = dmesh.result_mesh(pts, cols, {"status": STATUS}, {"id": np.arange(p) * 1.0}, source)
    path = str(tmp_path / f"r{'s' if source is not None else 'c'}{ext}")
    try:
        with warnings.catch_warnings(), contextlib.redirect_stderr(io.StringIO()), \
                contextlib.redirect_stdout(io.StringIO()):
            warnings.simplefilter("ignore")
            dmesh.meshio_write(path, result, fmt)
            back = dmesh.read_mesh(path)
    except ModuleNotFoundError:
        return None
    except Exception:  # noqa: BLE001 - a writer that cannot write it loses everything
        return False
    if back.points.shape[0] != p or not np.allclose(back.points[:, :3], pts):
        return False
    return all(name in back.point_data and np.allclose(
        np.asarray(back.point_data[name]).reshape(values.shape), values)
        for name, values in result.point_data.items())


@pytest.mark.parametrize("ext,fmt", WRITER_EXTENSIONS)
def test_result_formats_are_those_that_keep_every_column(tmp_path, ext, fmt):
    # write a result as a cloud of points and over a surface mesh's cells, read it back: the
    # formats accepted for results are exactly those that keep the points and every column
    plate = meshio.read(PLATE_VTU)
    kept = [_result_round_trip(tmp_path, ext, fmt, source) for source in (None, plate)]
    if None in kept:
        assert fmt not in dformats.RESULT_FORMATS, f"{fmt} could not be checked here"
    else:
        assert (fmt in dformats.RESULT_FORMATS) == all(kept), (fmt, kept)
    path = str(tmp_path / f"out{ext}")
    if fmt in dformats.RESULT_FORMATS:
        check_output_path(path, False)
        return
    with pytest.raises(WriteError) as info:
        check_output_path(path, False)
    message = str(info.value)
    assert message.startswith(f"{path}: the {fmt} format cannot hold the results, it would lose ")
    assert message.endswith("expected .csv, .tsv, .parquet, .vtu, .vtk, .msh or .avs")
    assert "\n" not in message and not os.path.exists(path)


def test_surface_mesh_outputs_still_take_any_format(tmp_path):
    # a smoothed surface is a mesh, not a result: STL, OBJ, PLY hold it
    for ext in (".stl", ".obj", ".ply", ".off"):
        check_output_path(str(tmp_path / f"s{ext}"), False, kind="mesh")


@pytest.mark.parametrize("ext", [".stl", ".ply", ".obj", ".off", ".inp", ".dat"])
def test_project_refuses_lossy_output_before_any_work(tmp_path, ext):
    from samples import run

    out = tmp_path / f"r{ext}"
    # the target does not even exist: the output is refused before it is read
    res = run("project", tmp_path / "missing.msh", PLATE_CSV, "-o", out)
    assert res.exit_code == 1 and not out.exists()
    assert res.stderr.startswith(f"diffsurf: error: {out}: the ") and "cannot hold" in res.stderr
    assert res.stderr.count("\n") == 1


@pytest.mark.parametrize("ext,sep", [(".csv", ","), (".tsv", "\t"), (".txt", "\t")])
def test_text_outputs_by_extension(tmp_path, ext, sep):
    c = _csv_contactors(5)
    cols = _result_columns(c)
    out = tmp_path / f"r{ext}"
    write_result(str(out), c, cols, labels={"status": STATUS})
    lines = out.read_text().splitlines()
    assert lines[0] == sep.join(["id"] + list(cols))
    assert all(line.count(sep) == len(cols) for line in lines)
    back = read_contactors(str(out))  # the separator is sniffed
    assert back.points.tobytes() == np.column_stack([cols["x"], cols["y"], cols["z"]]).tobytes()
    assert [r[0] for r in back.passthrough_rows()] == [f"{i:03d}" for i in range(5)]


def test_dev_null_is_an_output(tmp_path):
    from samples import run

    assert dpaths.writes_in_place("/dev/null") and not dpaths.writes_in_place(str(tmp_path))
    check_output_path("/dev/null", False)  # exists, yet no --overwrite needed
    c = _csv_contactors(3)
    write_result("/dev/null", c, _result_columns(c), labels={"status": STATUS})
    res = run("-q", "project", CYLINDER, PLATE_CSV, "-o", "/dev/null")
    assert res.exit_code == 0, res.stderr
    assert res.stdout == "" and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    # the other outputs need a file
    with pytest.raises(WriteError, match=r"^/dev/null: not a regular file"):
        check_output_path("/dev/null", True, kind="matrix")
    fifo = tmp_path / "r.parquet"
    os.mkfifo(fifo)
    with pytest.raises(WriteError, match=r"r\.parquet: not a regular file, and Parquet needs"):
        check_output_path(str(fifo), True)


@pytest.mark.slow
def test_dev_stdout_is_an_output(tmp_path):
    res = subprocess.run([sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", CYLINDER,
                          PLATE_CSV, "-o", "/dev/stdout"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    want = subprocess.run([sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", CYLINDER,
                           PLATE_CSV], capture_output=True, text=True)
    assert res.stdout == want.stdout and res.stdout.startswith("id,x,y,z,gap,")
    # stdout redirected to a file: /dev/stdout is that file, written, never replaced by a rename
    out = tmp_path / "redirected.csv"
    with open(out, "w") as fh:
        subprocess.run([sys.executable, "-m", "diffsurf_cli.cli", "-q", "project", CYLINDER,
                        PLATE_CSV, "-o", "/dev/stdout"], stdout=fh, check=True)
    assert out.read_text() == want.stdout


def test_fifo_is_an_output(tmp_path):
    fifo = tmp_path / "results.tsv"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    c = _csv_contactors(4)
    try:
        write_result(str(fifo), c, _result_columns(c), labels={"status": STATUS})
    finally:  # whatever happened, let a reader still waiting see an end of file (without
        # blocking when it has already read everything and gone: ENXIO, no reader)
        try:
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        except OSError:
            pass
        reader.join(timeout=30)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)  # still the FIFO
    assert got and got[0].decode().startswith("id\tx\ty\tz\tgap\t")


# --------------------------------------------------------------------------------------------
# the point data of a mesh given as contactors (issue 14, item 4)
# --------------------------------------------------------------------------------------------


def test_mesh_contactors_pass_their_point_data_through(tmp_path):
    from samples import run

    # plate.vtu holds the plate.csv points with their id as point data: both give the same id
    out_mesh, out_csv = tmp_path / "m.csv", tmp_path / "c.csv"
    assert run("-q", "project", CYLINDER, PLATE_VTU, "-o", out_mesh).exit_code == 0
    assert run("-q", "project", CYLINDER, PLATE_CSV, "-o", out_csv).exit_code == 0
    mesh_rows = read_contactors(str(out_mesh))
    csv_rows = read_contactors(str(out_csv))
    assert mesh_rows.passthrough_names[0] == "id" == csv_rows.passthrough_names[0]
    ids = [r[0] for r in mesh_rows.passthrough_rows()]
    assert ids == [r[0] for r in csv_rows.passthrough_rows()] and len(set(ids)) == N_PLATE
    # and to a mesh output, as point data of the same name
    out = tmp_path / "m.vtu"
    assert run("-q", "project", CYLINDER, PLATE_VTU, "-o", out).exit_code == 0
    np.testing.assert_array_equal(meshio.read(str(out)).point_data["id"],
                                  meshio.read(PLATE_VTU).point_data["id"])


def test_mesh_point_data_columns_scalars_vectors_and_types(tmp_path):
    pts = _points()
    p = len(pts)
    u = np.arange(3 * p, dtype=np.float64).reshape(p, 3) / 7
    mesh = meshio.Mesh(pts, [("triangle", np.array([[0, 1, 2]]))], point_data={
        "temperature": np.linspace(0, 1, p), "u": u, "node": np.arange(p, dtype=np.int32),
        "flag": (np.arange(p) % 2 == 0).astype(np.uint8), "one": np.ones((p, 1))})
    src = tmp_path / "c.vtu"
    meshio.write(str(src), mesh)
    c = read_contactors(str(src))
    assert c.passthrough_names == ["temperature", "u_0", "u_1", "u_2", "node", "flag", "one"]
    np.testing.assert_array_equal(c.passthrough[2].to_numpy(), u[:, 1])
    assert c.passthrough[4].dtype.is_integer() and c.passthrough[5].to_list()[:2] == [1, 0]
    cols = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "gap": np.linspace(-1, 1, p)}
    write_result(str(tmp_path / "r.csv"), c, cols)
    back = read_contactors(str(tmp_path / "r.csv"))
    assert back.passthrough_names == ["temperature", "u_0", "u_1", "u_2", "node", "flag",
                                      "one", "gap"]
    np.testing.assert_array_equal(dtable.numbers(back.passthrough[3]), u[:, 2])  # bit for bit
    assert back.passthrough[4].to_list() == [str(i) for i in range(p)]
    write_result(str(tmp_path / "r.parquet"), c, cols)
    import polars as pl

    frame = pl.read_parquet(tmp_path / "r.parquet")
    assert frame["node"].dtype == pl.Int32 and frame["u_0"].to_list() == u[:, 0].tolist()
    # a mesh output keeps the vector whole, under its name
    write_result(str(tmp_path / "r.vtu"), c, cols)
    m = meshio.read(str(tmp_path / "r.vtu"))
    np.testing.assert_array_equal(m.point_data["u"], u)
    np.testing.assert_array_equal(m.point_data["node"], np.arange(p))
    assert "u_0" not in m.point_data


# --------------------------------------------------------------------------------------------
# Abaqus/CalculiX zones ignore case; reader failures in words (issue 14, item 9)
# --------------------------------------------------------------------------------------------

#: a small hand-written deck: a cylinder-like strip of S4 shells (ELSET=Cyl) and a plate of S3
#: shells (ELSET=Plate), with a node set.
DECK = """*HEADING
diffsurf test deck
*NODE
1, 0., 0., 0.
2, 1., 0., 0.
3, 2., 0., 0.
4, 0., 1., 0.5
5, 1., 1., 0.5
6, 2., 1., 0.5
7, 0., 2., 0.
8, 1., 2., 0.
9, 2., 2., 0.
10, 0., 0., -1.
11, 1., 0., -1.
12, 0., 1., -1.
*ELEMENT, TYPE=S4, ELSET=Cyl
1, 1, 2, 5, 4
2, 2, 3, 6, 5
3, 4, 5, 8, 7
4, 5, 6, 9, 8
*ELEMENT, TYPE=S3, ELSET=Plate
5, 10, 11, 12
*NSET, NSET=Top
7, 8, 9
"""


def _deck(tmp_path, text=DECK, name="deck.inp"):
    path = tmp_path / name
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize("cyl,plate", [("Cyl", "Plate"), ("cyl", "plate"), ("CYL", "PLATE"),
                                       ("cYl", "pLATE")])
def test_inp_zone_ignores_case(tmp_path, cyl, plate):
    t = read_target(_deck(tmp_path), zone=cyl)
    assert [kind for kind, _ in t.cells] == ["quad"] and len(t.cells[0][1]) == 4
    t = read_target(_deck(tmp_path), zone=plate)
    assert [kind for kind, _ in t.cells] == ["triangle"]


def test_inp_zones_that_differ_only_by_case(tmp_path):
    text = DECK.replace("ELSET=Plate", "ELSET=CYL")
    path = _deck(tmp_path, text)
    assert [k for k, _ in read_target(path, zone="CYL").cells] == ["triangle"]  # exact first
    assert [k for k, _ in read_target(path, zone="Cyl").cells] == ["quad"]
    with pytest.raises(ReadError) as info:
        read_target(path, zone="cyl")
    assert str(info.value) == (f"{path}: zone 'cyl' matches 'Cyl', 'CYL', which differ only by "
                               f"case (Abaqus names ignore it), expected one of them exactly")
    with pytest.raises(ReadError, match=r"unknown zone 'cylinder'; available zones: 'Cyl', "):
        read_target(path, zone="cylinder")


def test_other_formats_keep_case_sensitive_zones():
    # a Gmsh physical name is matched exactly (Gmsh names are case-sensitive)
    with pytest.raises(ReadError, match=r"unknown zone 'CYLINDER'; available zones: .*'cylinder'"):
        read_target(BOTH, zone="CYLINDER")
    assert read_target(BOTH, zone="cylinder").cells


def test_cli_zone_lowercase_on_inp(tmp_path):
    from samples import run

    points = tmp_path / "p.csv"
    points.write_text("id,x,y,z\n1,0.5,0.5,1\n2,1.5,1.5,-0.5\n")
    out = tmp_path / "r.csv"
    res = run("-q", "project", _deck(tmp_path), points, "--zone", "cyl", "--method", "facet",
              "-o", out)
    assert res.exit_code == 0, res.stderr
    assert read_contactors(str(out)).passthrough_names[:2] == ["id", "gap"]


def test_reader_failure_in_words(tmp_path):
    from samples import run

    path = _deck(tmp_path, DECK.replace("5, 10, 11, 12", "5, 10, 11, 17"), "bad.inp")
    with pytest.raises(ReadError) as info:
        read_target(path)
    # meshio fails (KeyError 17); the deck reader then names the line (issue 19 item 6)
    assert str(info.value) == (f"{path}: line 22: element 5 refers to node 17, which the deck "
                               f"does not define")
    assert isinstance(info.value.__context__, KeyError)  # meshio's original, for -v
    res = run("project", path, PLATE_CSV)
    assert res.exit_code == 1 and "np." not in res.stderr and res.stderr.count("\n") == 1
    # -v: the traceback shows the reader's own error above the one line naming the file
    res = run("-v", "project", path, PLATE_CSV)
    assert isinstance(res.exception, ReadError) and path in str(res.exception)
    shown = "".join(traceback.format_exception(res.exception))
    assert "KeyError: np.int64(17)" in shown or "KeyError: 17" in shown


@pytest.mark.parametrize("exc,reason", [
    (KeyError(np.int32(17)), "it refers to id 17, which it does not define"),
    (KeyError("vertex"), "'vertex' was expected and is missing"),
    (IndexError("index 9 is out of bounds for axis 0 with size 6"),
     "a reference to an entry that does not exist (index 9 is out of bounds for axis 0 with "
     "size 6)"),
    (IndexError(), "a reference to an entry that does not exist"),
    (ValueError("cannot reshape np.int64(7) into np.float32(1.5)"),
     "cannot reshape 7 into 1.5"),
])
def test_reader_reasons(exc, reason):
    from diffsurf_cli.io.errors import reader_reason

    assert reader_reason(exc) == reason


def test_missing_values_read_as_floats_by_polars_pandas_and_numpy(tmp_path):
    """Issue 22, item 3: a NaN (an 'outside' row) among the first rows is written so that
    polars infers a float column (it took 'nan' for text), and pandas and numpy read floats."""
    import pandas as pd
    import polars as pl

    n = 5
    pts = np.arange(3.0 * n).reshape(n, 3)
    c = Contactors("in.csv", pts, ["id"], [[str(i)] for i in range(n)], None)
    gap = np.array([np.nan, 0.5, np.nan, -0.25, 1.0])
    out = tmp_path / "out.csv"
    write_result(str(out), c, {"gap": gap, "status": np.array([3, 0, 4, 2, 0])},
                 labels={"status": STATUS})
    frame = pl.read_csv(out)
    assert frame.schema["gap"] == pl.Float64, frame.schema
    np.testing.assert_array_equal(frame["gap"].to_numpy(), gap)
    assert pd.read_csv(out)["gap"].dtype == np.float64
    np.testing.assert_array_equal(pd.read_csv(out)["gap"].to_numpy(), gap)
    back = np.genfromtxt(out, delimiter=",", names=True, dtype=None, encoding="utf-8")
    np.testing.assert_array_equal(back["gap"], gap)
    np.testing.assert_array_equal(np.loadtxt(out, delimiter=",", skiprows=1, usecols=1), gap)


#: The array types VTK's legacy reader (vtkDataReader) reads: those its writer writes.
VTK_LEGACY_TYPES = {"bit", "unsigned_char", "char", "unsigned_short", "short", "unsigned_int",
                    "int", "unsigned_long", "long", "float", "double", "vtktypeuint64",
                    "vtktypeint64"}


def test_vtk_results_use_types_vtks_legacy_reader_reads(tmp_path):
    """Issue 22, item 1: `-o result.vtk` lost all point data in VTK and ParaView
    ('Unsupported data type: vtktypeint8', the terms column). Every array of the file is of a
    type VTK's own legacy reader knows, and an integer pass-through column stays integer."""
    import re
    import subprocess
    import sys

    from samples import SAMPLES

    out = tmp_path / "result.vtk"
    subprocess.run([sys.executable, "-m", "diffsurf_cli", "project",
                    str(SAMPLES / "cylinder.msh"), str(SAMPLES / "plate.csv"), "-o", str(out),
                    "-q"], check=True)
    text = out.read_bytes().decode("latin-1")
    fields = re.findall(r"^([A-Za-z_]\w*) (\d+) (\d+) (\w+)$", text, flags=re.M)
    names = {f[0]: f[3] for f in fields}
    assert {"gap", "status", "terms", "id"} <= set(names), names
    assert set(names.values()) <= VTK_LEGACY_TYPES, names
    assert names["id"] == "vtktypeint64"
