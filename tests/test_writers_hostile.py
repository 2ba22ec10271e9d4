"""Issue 32 (a newcomer's third hour), the writers: every pass-through column type against
every output kind (item 3), columns a mesh cannot hold (item 4), an output that is an input
(item 16a) and the OS's reason when a disk is full (item 16b)."""
from __future__ import annotations

import datetime as dt
import decimal
import errno
import io
import json
import os
import subprocess
import sys
import textwrap

import meshio
import numpy as np
import polars as pl
import pytest

import diffsurf_cli.io as dio
from diffsurf_cli.io import contactors as dcontactors
from samples import CYLINDER, PLATE_CSV, run

OUTPUTS = ("stdout", ".csv", ".tsv", ".parquet", ".vtu", ".vtk", ".msh", ".avs")
MESHES = (".vtu", ".vtk", ".msh", ".avs")
#: the meshio formats of MESHES that store point data as float64
FLOAT_MESHES = (".msh", ".avs")


def error_line(result) -> str:
    """The one `diffsurf: error:` line of a clean failure (exit 1, no traceback)."""
    assert result.exit_code == 1, (result.exit_code, result.stderr, result.exception)
    assert isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.stderr
    lines = [ln for ln in result.stderr.splitlines() if ln.startswith("diffsurf: error:")]
    assert len(lines) == 1, result.stderr
    assert result.stderr.rstrip("\n").splitlines()[-1] == lines[0], result.stderr
    return lines[0]


# --------------------------------------------------------------------------------------------
# item 3: every pass-through type, every output kind
# --------------------------------------------------------------------------------------------

D = dt.timedelta
#: name -> the column (3 rows; most with a null, as a Parquet input may have).
COLUMNS = {
    "duration": pl.Series([D(seconds=1.5), D(days=2, hours=3), None], dtype=pl.Duration("us")),
    "date": pl.Series([dt.date(2020, 1, 31), dt.date(1, 1, 1), None]),
    "datetime_tz": pl.Series([dt.datetime(2020, 1, 1, 12), dt.datetime(2021, 6, 1, 0, 0, 5),
                              dt.datetime(1999, 12, 31)]).dt.replace_time_zone("Europe/Paris"),
    "time": pl.Series([dt.time(12, 30), dt.time(0, 0, 0, 5), None]),
    "boolean": pl.Series([True, False, None]),
    "boolean_full": pl.Series([True, False, True]),
    "string": pl.Series(["a", "b,c", None]),
    "categorical": pl.Series(["a", "b", "a"], dtype=pl.Categorical),
    "enum": pl.Series(["a", "b", "a"], dtype=pl.Enum(["a", "b"])),
    "decimal": pl.Series([decimal.Decimal("1.10"), decimal.Decimal("-2.25"), None],
                         dtype=pl.Decimal(10, 2)),
    "binary": pl.Series([b"\x00a", b"b", None]),
    "list": pl.Series([[1, 2], [3], []]),
    "array": pl.Series([[1, 2], [3, 4], [5, 6]], dtype=pl.Array(pl.Int64, 2)),
    "struct": pl.Series([{"a": 1}, {"a": 2}, {"a": 3}]),
    "null": pl.Series([None, None, None]),
    "int8": pl.Series([1, -2, 3], dtype=pl.Int8),
    "int128": pl.Series([1, -(2**60), 3], dtype=pl.Int128),
    "int128_big": pl.Series([1, 2**100, 3], dtype=pl.Int128),
    "uint64_big": pl.Series([2**64 - 1, 0, 1], dtype=pl.UInt64),
    "int64_2p53": pl.Series([2**53 + 1, 0, -5], dtype=pl.Int64),
    "float32": pl.Series([1.5, float("nan"), -0.25], dtype=pl.Float32),
    "float64_null": pl.Series([1.5, None, 2.0]),
}

def _iso_duration(d: D) -> str:
    """ISO 8601 text of a non-negative duration (P2DT3H, PT1M30S, PT1.5S)."""
    days, rest = d.days, d - D(days=d.days)
    hours, rest = divmod(rest, D(hours=1))
    minutes, rest = divmod(rest, D(minutes=1))
    seconds = rest.total_seconds()
    time = ((f"{hours}H" if hours else "") + (f"{minutes}M" if minutes else "")
            + (f"{seconds:g}S" if seconds else ""))
    return "P" + (f"{days}D" if days else "") + (f"T{time}" if time else "")


def _csv_field(value):
    """The CSV field a value must read back from, independent of polars: ISO 8601 for dates,
    date-times and durations, true/false, a null as an empty field (a time of day is a
    dt.time: its text is parsed, the number of fractional digits being free)."""
    if value is None:
        return ""
    if isinstance(value, D):
        return _iso_duration(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, dt.datetime):
        return value.strftime("%Y-%m-%dT%H:%M:%S.%f%z")
    if isinstance(value, dt.date):
        return value.isoformat()
    if isinstance(value, float):
        return "NaN" if value != value else repr(value)
    if isinstance(value, dt.time):
        return value
    return str(value)


def _read_field(text: str, expected):
    """``text`` as a dt.time where a time is expected (HH:MM:SS[.fraction])."""
    if isinstance(expected, dt.time) and text:
        hms, _, fraction = text.partition(".")
        h, m, sec = map(int, hms.split(":"))
        return dt.time(h, m, sec, int((fraction or "0").ljust(6, "0")[:6]))
    return text


def _csv_accepts(name: str) -> bool:
    return name not in ("binary", "list", "array", "struct")


def _mesh_values(name: str, ext: str):
    """The point data a mesh holds for the column, or None if it must be refused."""
    s = COLUMNS[name]
    if s.null_count() or not (s.dtype.is_integer() or s.dtype.is_float()
                              or s.dtype == pl.Boolean):
        return None
    if s.dtype.is_integer():
        bound = 2**53 if ext in FLOAT_MESHES else 2**63 - 1
        if max(abs(v) for v in s.to_list()) > bound:
            return None
        return np.array(s.to_list(), dtype=np.int64)
    if s.dtype == pl.Boolean:
        return np.array(s.to_list(), dtype=np.int64)
    return np.array(s.to_list(), dtype=np.float64)


def _contactors(name: str):
    pts = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    columns = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "gap": np.array([1.0, 2, 3])}
    return dio.Contactors("in.parquet", pts, [name], [COLUMNS[name].alias(name)]), columns


@pytest.mark.parametrize("out", OUTPUTS)
@pytest.mark.parametrize("name", sorted(COLUMNS))
def test_every_passthrough_type_round_trips_or_is_refused_up_front(tmp_path, name, out):
    """Item 3: a Duration column made a polars traceback after the CSV header on stdout, and
    every non-numeric column vanished from a mesh. Each (type, output) either round-trips
    (CSV: the value's text, ISO 8601 for a Duration; Parquet: the type and values; a mesh:
    the numbers) or is refused before anything is written, by one line naming the column,
    its type and the output format."""
    contactors, columns = _contactors(name)
    series = COLUMNS[name]
    path = None if out == "stdout" else str(tmp_path / f"o{out}")
    if out in MESHES:
        expected = _mesh_values(name, out)
    elif out == ".parquet":
        expected = True
    else:
        expected = _csv_accepts(name)
    stdout = io.StringIO()
    if expected is None or expected is False:
        for check in (lambda: dcontactors.check_passthrough(path, contactors),
                      lambda: dio.write_result(path, contactors, columns, stdout=stdout)):
            with pytest.raises(dio.WriteError) as err:
                check()
            message = str(err.value)
            assert "\n" not in message
            assert f"'{name}'" in message and str(series.dtype) in message, message
            assert (out in message) if out in MESHES else ("CSV" in message or "TSV" in message)
        assert stdout.getvalue() == ""
        assert path is None or not os.path.exists(path)
        assert os.listdir(tmp_path) == []  # no temporary file either
        return
    dcontactors.check_passthrough(path, contactors)
    dio.write_result(path, contactors, columns, stdout=stdout)
    if out == ".parquet":
        back = pl.read_parquet(path)[name]
        assert back.dtype == series.dtype and back.equals(series.alias(name))
    elif out in MESHES:
        back = meshio.read(path).point_data[name]
        assert np.array_equal(back.astype(expected.dtype), expected, equal_nan=True)
        assert np.array_equal(back, expected, equal_nan=True)
    else:
        text = stdout.getvalue() if path is None else open(path, encoding="utf-8").read()
        sep = "\t" if out == ".tsv" else ","
        lines = text.splitlines()
        assert lines[0].split(sep)[0] == name
        fields = [ln.split(sep)[0] if '"' not in ln else ln[1:ln.index('"', 1)]
                  for ln in lines[1:]]
        expected = [_csv_field(v) for v in series.to_list()]
        assert [_read_field(f, e) for f, e in zip(fields, expected)] == expected


def test_duration_parquet_to_stdout_is_iso_text(tmp_path):
    """Item 3, the reported case: `diffsurf project cylinder.msh in.parquet` with a Duration
    column wrote the header, then a polars traceback. Its ISO 8601 text is written."""
    source = tmp_path / "in.parquet"
    pl.DataFrame({"wait": pl.Series([D(seconds=90), None], dtype=pl.Duration("ms")),
                  "x": [30.0, 31.0], "y": [20.0, 20.0], "z": [0.0, 0.0]}).write_parquet(source)
    result = run("project", CYLINDER, source)
    assert result.exit_code == 0, (result.stderr, result.exception)
    lines = result.stdout.splitlines()
    assert lines[0].startswith("wait,x,y,z,gap")
    assert [ln.split(",")[0] for ln in lines[1:]] == ["PT1M30S", ""]


def test_unwritable_column_refused_before_stdout_gets_a_byte(tmp_path):
    """Item 3: the refusal comes before the header, and before the projection."""
    source = tmp_path / "in.parquet"
    pl.DataFrame({"blob": [b"\x00", b"\x01"], "x": [30.0, 31.0], "y": [20.0, 20.0],
                  "z": [0.0, 0.0]}).write_parquet(source)
    result = run("project", CYLINDER, source)
    line = error_line(result)
    assert result.stdout == ""
    assert "'blob'" in line and "Binary" in line and "CSV" in line
    assert "status:" not in result.stderr  # refused before the work


# --------------------------------------------------------------------------------------------
# item 4: a text column and a mesh output
# --------------------------------------------------------------------------------------------


@pytest.fixture
def named_points(tmp_path):
    """plate.csv with a text column 'name' (and its numeric 'id')."""
    rows = open(PLATE_CSV, encoding="utf-8").read().splitlines()
    out = [rows[0] + ",name"] + [f"{r},node{k}" for k, r in enumerate(rows[1:])]
    path = tmp_path / "named.csv"
    path.write_text("\n".join(out) + "\n")
    return path


@pytest.mark.parametrize("ext", MESHES)
def test_text_column_in_a_mesh_is_refused_naming_it(tmp_path, named_points, ext):
    """Item 4: a text pass-through column was dropped from .vtu/.vtk/.msh/.avs with exit 0.
    One line names the column and the format, suggests .csv/.parquet, before the projection;
    nothing is written."""
    out = tmp_path / f"o{ext}"
    result = run("project", CYLINDER, named_points, "-o", out)
    line = error_line(result)
    assert "'name'" in line and ext in line and ".csv" in line and ".parquet" in line, line
    assert "'id'" not in line  # numbers have their place in point data
    assert not out.exists() and sorted(os.listdir(tmp_path)) == ["named.csv"]
    assert "status:" not in result.stderr


def test_numeric_columns_still_reach_the_mesh(tmp_path):
    """Item 4's refusal is for what a mesh cannot hold: plate.csv's integer ids are kept."""
    out = tmp_path / "o.vtu"
    result = run("project", CYLINDER, PLATE_CSV, "-o", out)
    assert result.exit_code == 0, result.stderr
    ids = meshio.read(out).point_data["id"]
    assert ids.dtype.kind == "i" and ids.tolist() == list(range(1, len(ids) + 1))


# --------------------------------------------------------------------------------------------
# item 16a: an output that is an input
# --------------------------------------------------------------------------------------------


@pytest.fixture
def inputs(tmp_path):
    """Copies of the target and the points, a symlink and a hard link to the points, and a
    pairing file."""
    target = tmp_path / "target.msh"
    target.write_bytes(open(CYLINDER, "rb").read())
    points = tmp_path / "points.csv"
    points.write_bytes(open(PLATE_CSV, "rb").read())
    (tmp_path / "link.csv").symlink_to("points.csv")
    os.link(points, tmp_path / "hard.csv")
    assert run("project", target, points, "--save-pairs", tmp_path / "pairs.npz",
               "-o", tmp_path / "first.csv").exit_code == 0
    return tmp_path


def _snapshot(folder):
    return {n: (folder / n).read_bytes() for n in sorted(os.listdir(folder))
            if not (folder / n).is_symlink()}


CASES = [
    (("project", "target.msh", "points.csv", "-o", "points.csv"), "points.csv"),
    (("project", "target.msh", "points.csv", "-o", "./points.csv"), "points.csv"),
    (("project", "target.msh", "points.csv", "-o", "link.csv"), "points.csv"),
    (("project", "target.msh", "points.csv", "-o", "hard.csv"), "points.csv"),
    (("project", "target.msh", "points.csv", "-o", "target.msh"), "target.msh"),
    (("project", "target.msh", "points.csv", "--penalty", "1", "--residual", "target.msh"),
     "target.msh"),
    (("project", "target.msh", "points.csv", "--penalty", "1", "--tangent", "points.csv"),
     "points.csv"),
    (("project", "target.msh", "points.csv", "--elements", "target.msh"), "target.msh"),
    (("project", "target.msh", "points.csv", "--save-pairs", "points.csv"), "points.csv"),
    (("project", "target.msh", "points.csv", "--pairs", "pairs.npz", "--save-pairs",
      "pairs.npz"), "pairs.npz"),
    (("smooth", "target.msh", "-o", "target.msh"), "target.msh"),
    (("smooth", "target.msh", "-o", "./target.msh"), "target.msh"),
    (("tune", "target.msh", "points.csv", "--plot", "points.csv"), "points.csv"),
    (("tune", "target.msh", "--plot", "target.msh"), "target.msh"),
]


@pytest.mark.parametrize("overwrite", [True, False])
@pytest.mark.parametrize("args,victim", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_output_that_is_an_input_is_refused(inputs, monkeypatch, args, victim, overwrite):
    """Item 16a: `-o POINTS --overwrite` replaced the input. Every output of every command is
    refused when it is an input file, under any name (./x, a symlink, a hard link), with or
    without --overwrite (without it, the message must not suggest --overwrite); the error
    names the output and the input, and no file changes."""
    monkeypatch.chdir(inputs)
    before = _snapshot(inputs)
    result = run(*args, *(["--overwrite"] if overwrite else []))
    line = error_line(result)
    output = args[args.index(next(a for a in args if a in ("-o", "--residual", "--tangent",
                                                            "--elements", "--save-pairs",
                                                            "--plot"))) + 1]
    assert f"error: {output}:" in line and victim in line and "input" in line, line
    assert "--overwrite" not in line
    assert _snapshot(inputs) == before


# --------------------------------------------------------------------------------------------
# item 16b: a full disk
# --------------------------------------------------------------------------------------------


def test_a_writer_error_carrying_enospc_says_so(tmp_path, monkeypatch):
    """Item 16b: meshio wraps the OSError of a full disk in its own error ('problem writing
    element 1024'); the one-line error gives the OS's reason instead."""
    def full(tmp, mesh, file_format, **kwargs):
        with open(tmp, "wb") as fh:
            fh.write(b"$MeshFormat\n")
        try:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), tmp)
        except OSError as exc:
            raise meshio.WriteError("problem writing element 1024") from exc

    monkeypatch.setattr(meshio, "write", full)
    contactors = dio.read_contactors(PLATE_CSV)
    p = len(contactors.points)
    columns = {"x": contactors.points[:, 0], "y": contactors.points[:, 1],
               "z": contactors.points[:, 2], "gap": np.zeros(p)}
    for ext in MESHES:
        with pytest.raises(dio.WriteError) as err:
            dio.write_result(str(tmp_path / f"o{ext}"), contactors, columns)
        assert str(err.value) == f"{tmp_path / f'o{ext}'}: cannot write (No space left on device)"
    assert os.listdir(tmp_path) == []


_FULL_SCRIPT = textwrap.dedent("""
    import json, resource, signal, sys
    import numpy as np
    import diffsurf_cli.io as dio
    from diffsurf_cli.io.pairs import save_elements, write_matrix
    import scipy.sparse as sp

    folder, limit = sys.argv[1], int(sys.argv[2])
    rng = np.random.default_rng(0)
    p = 8000
    pts = rng.random((p, 3))
    c = dio.Contactors("x.csv", pts)
    columns = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "gap": rng.random(p),
               "status": np.zeros(p, np.int64)}
    faces = [rng.integers(0, p, (p, 3))]
    jobs = {ext: (lambda ext=ext: dio.write_result(f"{folder}/o{ext}", c, columns,
                                                   labels={"status": ("open",)}))
            for ext in (".csv", ".tsv", ".parquet", ".vtu", ".vtk", ".msh", ".avs")}
    for ext in (".vtk", ".msh", ".stl", ".obj", ".ply"):
        jobs["mesh" + ext] = (lambda ext=ext: dio.write_mesh(f"{folder}/s{ext}", pts, faces, {}))
    jobs[".mtx"] = lambda: write_matrix(f"{folder}/k.mtx", sp.random(3000, 3000, 0.01,
                                                                     random_state=0))
    jobs[".npz"] = lambda: save_elements(f"{folder}/e.npz", {"gap": rng.random(4 * p)})
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig = plt.figure(figsize=(16, 16))  # over 64 KiB as PNG
        plt.plot(rng.random(p))
        jobs[".png"] = lambda: dio.write_figure(f"{folder}/f.png", fig)
    except ImportError:
        pass
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, resource.getrlimit(
        resource.RLIMIT_FSIZE)[1]))
    out = {}
    for name, job in jobs.items():
        try:
            job()
            out[name] = "written"
        except dio.WriteError as exc:
            out[name] = str(exc)
    print(json.dumps(out))
""")


def _write_all_under_limit(folder, limit: int) -> dict:
    result = subprocess.run([sys.executable, "-c", _FULL_SCRIPT, str(folder), str(limit),
                             PLATE_CSV], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout.splitlines()[-1])


def test_every_format_gives_the_os_reason_when_the_file_cannot_grow(tmp_path):
    """Item 16b without root: a file size limit (RLIMIT_FSIZE) makes every write past 8 KiB
    fail with EFBIG, as a full disk fails with ENOSPC; numpy's tofile (most mesh writers)
    drops the errno ('60000 requested and 8178 written'). Every format says 'File too large'
    and leaves nothing."""
    out = _write_all_under_limit(tmp_path, 8192)
    reason = os.strerror(errno.EFBIG)
    bad = {k: v for k, v in out.items() if not v.endswith(f": cannot write ({reason})")}
    assert not bad, bad
    assert os.listdir(tmp_path) == []


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (root only; skipped elsewhere)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    folder = tmp_path / "full"
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(folder)],
                             capture_output=True)
    if mounted.returncode:
        pytest.skip(f"cannot mount a tmpfs: {mounted.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def test_every_format_says_no_space_left_on_a_full_disk(tiny_disk):
    """Item 16b on a real full disk: '.msh: problem writing element 1024' (or '20000
    requested and 2338 written') became 'No space left on device', for every format."""
    out = _write_all_under_limit(tiny_disk, 1 << 40)
    reason = os.strerror(errno.ENOSPC)
    bad = {k: v for k, v in out.items() if not v.endswith(f": cannot write ({reason})")}
    assert not bad, bad
    assert os.listdir(tiny_disk) == []
