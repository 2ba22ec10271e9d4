"""Issue 32, the table readers against a hostile tester: a Parquet file that makes polars panic,
CSV text with old Mac (CR-only) line ends, and a number written with Python's ``_`` digit
grouping. Each test failed before its fix."""
from __future__ import annotations

import base64
import io as _io
import os
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from diffsurf_cli import io
from diffsurf_cli.io import table

ROOT = Path(__file__).resolve().parent.parent
CYLINDER = str(ROOT / "sample_meshes" / "cylinder.msh")

#: a three-row x, y, z Parquet file (polars 2.1, uncompressed, no statistics) with byte 14, in
#: the first data page's header, set to 0x7f: polars panics reading it ("Thrift out of range")
#: and Rust prints the panic and a backtrace on file descriptor 2 before pyo3 raises.
PANICKING_PARQUET = zlib.decompress(base64.b64decode(
    "eNp9Uk1PwkAQndaGEOLBA7tpTQ+92EAkCvUDMBodwKhRETHReKyUqolaA2qBix79AZ79PZ78IZ48ePLkDl3LQeKm6Z"
    "vZN+/t22Qb2CwwYDmWyzGNPbIESwCoAKApMFyf6xHCBksZM5AwdKXHgGu8zut2EkZa+KtNbkQ4NdL2Y+2T8r84LcX6"
    "SDyIxd8KGCZPsjoXE6J6UuLyW5ZMNfa2tU4Q3AlnlppRRXCJfYkDYWeYxqp9bI69HP9SWRrsd8Ucn58/TzAO9ptqjo"
    "/IX4nnHwrX7KSANAXUJ7HZPDhZ6bYu2teu/qLO0yqdolib9Cs9iL53KPvh1i5iF6tDPMTZhuDDkPZ3EM/l3L6ASosa"
    "qmgOsdoi621qKyjniYomBO8SH1tgZZmqHvn3wl8TOpf4mhRhSPnCndi1TVMHA7pEGB9SOY/4cOh8RFYCmzKvDFBblu"
    "dvIZ6SWeSHuAZ6vRFcuZ2ulbnt310EN1nrod3pXgY3ljNXmMtbmbP7yyvPKvrlvHPmLfi+5xR9v+R4hUWnWHLzZdcp"
    "L/m+4xfdtld2ssaqCRB9MC2eWUO8+x81SZIs"))


def run_cli(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "diffsurf_cli", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


def write(tmp_path, name: str, data: bytes) -> str:
    path = tmp_path / name
    path.write_bytes(data)
    return str(path)


# --------------------------------------------------------------------------------------------
# item 7: a Parquet file that makes polars panic
# --------------------------------------------------------------------------------------------


def test_the_fixture_makes_polars_itself_flood_stderr(tmp_path):
    # the premise: polars alone prints the panic (and a backtrace) on stderr
    bad = write(tmp_path, "bad.parquet", PANICKING_PARQUET)
    code = ("import polars as pl, sys\ntry:\n    pl.read_parquet(sys.argv[1])\n"
            "except BaseException as exc:\n    print(type(exc).__name__)\n")
    done = subprocess.run([sys.executable, "-c", code, bad], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "RUST_BACKTRACE": "1"})
    assert done.stdout.strip() == "PanicException"
    assert "panicked at" in done.stderr and len(done.stderr.splitlines()) > 3


@pytest.mark.parametrize("backtrace", ["0", "1", "full"])
def test_corrupt_parquet_gives_one_line_on_stderr(tmp_path, backtrace):
    bad = write(tmp_path, "bad.parquet", PANICKING_PARQUET)
    env = {**os.environ, "RUST_BACKTRACE": backtrace}
    done = subprocess.run([sys.executable, "-m", "diffsurf_cli", "project", "-q", CYLINDER, bad,
                           "-o", str(tmp_path / "out.csv")], capture_output=True, text=True,
                          timeout=120, env=env)
    assert done.returncode == 1, done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"diffsurf: error: {bad}: cannot read Parquet")
    assert not (tmp_path / "out.csv").exists()


def test_corrupt_parquet_read_error_and_nothing_on_fd2(tmp_path, capfd):
    bad = write(tmp_path, "bad.parquet", PANICKING_PARQUET)
    with pytest.raises(io.ReadError) as info:
        io.read_contactors(bad)
    assert str(info.value).startswith(f"{bad}: cannot read Parquet (")
    assert "\n" not in str(info.value)
    out, err = capfd.readouterr()
    assert err == "" and out == ""
    # file descriptor 2 is the test's again
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


#: the fixture's file with byte 12 (the first page's value count) set to 0x7f instead: polars
#: asks for 2**61 bytes and the process aborts (SIGABRT), which no Python code can catch.
ABORTING_PARQUET = zlib.decompress(base64.b64decode(
    "eNp9Uk1PwkAQndaGEOLBA7tpTQ+92EgkCvUDMBodxKhRETHReKyUCglSA2qBix79AZ79PZ78IZ48ePLkDl3rhbhp+m"
    "b2zXv7Ntka1vMMWJZls+xRFAmWAFABQFNgvD63IoRtljLmIGHoyoAB13iVV+0k/Gq1SdrkdoQzf9phrH1S/henpVj/"
    "E49i8bcChsmTrMrFhKielLj8liVTjaN9rRcEd8KZpeZUEVziUOJI2BmmsWGfmxMvx79Ulgb7XTEn5+fPU4yD/aaaky"
    "PyV+L5h8I1OykgTQH1aazXTy7W+41W88bVX9QlWsVLFGuXfsUH0Q9OZT/eOkTs484YT3GhJvgwpP0DxGs5dyyg3KCG"
    "KppD3GmQ9T61ZZTzREUTgneJjy2wvEbVgPwH4a8JnUt8RYowpHzhQezapKmTEV0ijA8pX0d8OHY+IyuBdZlXBqisyf"
    "P3EC/JLPJD3AS9Wgs6bq9vzd8O71pBN2M9NHv9dtC1nMX8Ys6av7pvdzyr4JdyzpW37PueU/D9ouPlV5xC0c2VXKe0"
    "6vuOX3CbXsnJGBsmQPTBrHhmNfHufwAqh5Io"))


def test_the_abort_fixture_makes_polars_itself_abort(tmp_path):
    # the premise: polars alone kills the process (SIGABRT), no exception to catch
    bad = write(tmp_path, "abort.parquet", ABORTING_PARQUET)
    code = "import polars as pl, sys\npl.read_parquet(sys.argv[1])\n"
    done = subprocess.run([sys.executable, "-c", code, bad], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == -6, (done.returncode, done.stderr[-300:])
    assert "memory allocation of" in done.stderr


def test_parquet_that_makes_polars_abort_gives_one_line(tmp_path):
    # the page headers are checked before polars reads: the value count -64 is refused
    bad = write(tmp_path, "abort.parquet", ABORTING_PARQUET)
    done = run_cli("project", "-q", CYLINDER, bad, "-o", str(tmp_path / "out.csv"))
    assert done.returncode == 1, (done.returncode, done.stderr[-300:])
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"diffsurf: error: {bad}: not a valid Parquet file (row group 0, "
                               f"column 0, page at byte 4: value count -64), expected ")
    assert not (tmp_path / "out.csv").exists()


def test_stderr_written_during_a_good_read_is_kept(tmp_path, capfd, monkeypatch):
    # what another thread (or polars) writes on fd 2 while a Parquet file is read is not lost
    import polars as pl

    good = str(tmp_path / "good.parquet")
    pl.DataFrame({"x": [1.0], "y": [2.0], "z": [3.0], "id": ["a"]}).write_parquet(good)
    real = pl.read_parquet

    def noisy(*args, **kwargs):
        os.write(2, b"a warning\n")
        return real(*args, **kwargs)

    monkeypatch.setattr(pl, "read_parquet", noisy)
    c = io.read_contactors(good)
    assert c.points.tolist() == [[1.0, 2.0, 3.0]] and c.passthrough_names == ["id"]
    assert capfd.readouterr().err == "a warning\n"
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


# --------------------------------------------------------------------------------------------
# item 16a: CR-only line ends
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("data, points, rows", [
    (b"x,y,z\r1,2,3\r", [[1, 2, 3]], [[]]),
    (b"x,y,z\r1,2,3\r4,5,6", [[1, 2, 3], [4, 5, 6]], [[], []]),
    (b"# made on a Mac\rid;x;y;z\r\ra;1;2;3\rb;4;5;6\r", [[1, 2, 3], [4, 5, 6]],
     [["a"], ["b"]]),
    (b'id,x,y,z\r"p, q",1,2,3\r"r ""s""",4,5,6\r', [[1, 2, 3], [4, 5, 6]],
     [["p, q"], ['r "s"']]),
    (b"\xef\xbb\xbf1 2 3\r4 5 6\r", [[1, 2, 3], [4, 5, 6]], [[], []]),
])
def test_cr_only_line_ends_are_read(tmp_path, data, points, rows):
    c = io.read_contactors(write(tmp_path, "mac.csv", data))
    assert c.points.tolist() == points
    assert c.passthrough_rows() == rows
    # and the same text on stdin
    s = io.read_contactors("-", stdin=_io.TextIOWrapper(_io.BytesIO(data), encoding="utf-8"))
    assert s.points.tolist() == points and s.passthrough_rows() == rows


def test_cr_only_errors_name_the_line(tmp_path):
    path = write(tmp_path, "mac.csv", b"x,y,z\r1,2,3\r4,five,6\r")
    with pytest.raises(io.ReadError, match=r"mac\.csv, line 3: expected a number for y, "
                                           r"got 'five'$"):
        io.read_contactors(path)


def test_cr_only_file_through_the_cli(tmp_path):
    path = write(tmp_path, "mac.csv", b"x,y,z\r1,0,0.5\r0,1,0.5\r")
    out = tmp_path / "out.csv"
    done = run_cli("project", "-q", CYLINDER, path, "-o", str(out))
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert len(out.read_text().splitlines()) == 3


def test_a_lone_cr_in_a_file_with_line_feeds_is_still_text(tmp_path):
    # only a file without any \n has its lines end at \r: elsewhere a \r inside a quoted field
    # is the field's text (the writer quotes such text, and it must read back as itself)
    c = io.read_contactors(write(tmp_path, "t.csv", b'id,x,y,z\n"a\rb",1,2,3\n'))
    assert c.passthrough_rows() == [["a\rb"]]


# --------------------------------------------------------------------------------------------
# item 16b: 1_000 is not a CSV number
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("data, where", [
    (b"x,y,z\n1_000,2,3\n", "line 2: expected a number for x, got '1_000'"),
    (b"x,y,z\n1,2,3\n4,5_0,6\n", "line 3: expected a number for y, got '5_0'"),
    (b"1,2,3_3\n", "line 1: expected a number for z, got '3_3'"),
    (b"1_0,2,3\n4,5,6\n", "line 1: expected a number for x, got '1_0'"),
    (b"x;y;z\n1;2;3\n4;5;1e1_0\n", "line 3: expected a number for z, got '1e1_0'"),
    (b'id,x,y,z\n"a,b",1,2,3\n"c", 1_5 ,2,3\n', "line 3: expected a number for x, got '1_5'"),
    (b'id,x,y,z\n"a\nb",1,2,3\n"c",1,2,"3_0"\n', "line 4: expected a number for z, got '3_0'"),
    (b"x y z\n1 2 3\n4 5 6_000.5\n", "line 3: expected a number for z, got '6_000.5'"),
])
def test_underscore_in_a_number_is_an_error(tmp_path, data, where):
    path = write(tmp_path, "u.csv", data)
    with pytest.raises(io.ReadError) as info:
        io.read_contactors(path)
    assert str(info.value) == f"{path}, {where}"


def test_underscore_in_a_pass_through_field_is_text(tmp_path):
    c = io.read_contactors(write(tmp_path, "u.csv", b"id,x,y,z\n1_000,1,2,3\n"))
    assert c.passthrough_rows() == [["1_000"]]
    assert np.array_equal(c.points, [[1.0, 2.0, 3.0]])


def test_underscore_error_through_the_cli(tmp_path):
    path = write(tmp_path, "u.csv", b"x,y,z\n1_000,2,3\n")
    done = run_cli("project", "-q", CYLINDER, path, "-o", str(tmp_path / "out.csv"))
    assert done.returncode == 1
    assert done.stderr.splitlines() == [
        f"diffsurf: error: {path}, line 2: expected a number for x, got '1_000'"]


def test_underscore_in_a_large_file_found_in_any_block(monkeypatch, tmp_path):
    rows = "".join(f"{i},{i}.5,1e-3\n" for i in range(500))
    data = ("x,y,z\n" + rows + "7,8_0,9\n" + rows).encode()
    monkeypatch.setattr(table, "READ_BLOCK", 257)
    path = write(tmp_path, "big.csv", data)
    with pytest.raises(io.ReadError, match=r"line 502: expected a number for y, got '8_0'$"):
        io.read_contactors(path)
