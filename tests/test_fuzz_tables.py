"""Bounded fuzz run of the table readers (issue 32): CSV text and Parquet files of every kind a
user may hand `diffsurf project` as POINTS, valid and damaged.

CSV: separators , ; tab and spaces, a header or none, comments, blank lines, a byte order
mark, LF / CRLF / CR-only line ends, quoted fields (separators, quotes and line ends inside),
pass-through columns, NaN / inf, odd spellings of numbers, empty files; every file is checked
against the rules in plain Python (reference_table.py, via test_fuzz_readers): the same points
bit for bit, the same pass-through text, or a ReadError where the rules refuse it.

Parquet: coordinates of every numeric type and of wrong ones (text, bool, list, date, all
null), missing or repeated x / y / z, pass-through columns of every type (Duration, Date,
Datetime with and without a time zone, Time, bool, text, Categorical, Enum, Decimal, Binary,
List, Array, Struct, Null, integers of every width), nulls, NaN / inf, no rows; written by
polars or pyarrow with every compression codec, several row groups, small data pages,
dictionary encoding on or off, data page v1 / v2, statistics or not; then now and then
damaged (truncated, bytes changed, a range zeroed, garbage appended, nothing but PAR1). An
undamaged file must read to its own coordinates (null as NaN) or be refused for the reason the
rules give; a damaged one must read or be refused.

Every input is read by `io.read_contactors` in a worker process (this file run as a script),
so that an input that makes polars hang or abort the process is reported as such, with a
timeout per input, instead of stopping the test run; the worker also checks that a read
writes nothing on file descriptor 2 (a Rust panic prints there). The only allowed outcomes are
a valid Contactors or an `io.ReadError` of one line that names the file. A sample of the
inputs also goes through the CLI (`diffsurf project -q cylinder.msh FILE -o out.csv`): exit 0
or 1, no traceback, and for exit 1 exactly one `diffsurf: error:` line on stderr.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
CYLINDER = str(ROOT / "sample_meshes" / "cylinder.msh")

#: seconds an input may take to be read (a valid one takes milliseconds) before it counts
#: as a hang.
READ_TIMEOUT = 30
#: seconds a CLI run may take (it builds the cylinder's surface first).
CLI_TIMEOUT = 90
#: examples per test, and how many of them (every CLI_EVERY-th) also go through the CLI.
EXAMPLES = 120
CLI_EVERY = 15


# -------------------------------------------------------------------------------------------
# the worker: reads one file per request and says how it went (run as a script)
# -------------------------------------------------------------------------------------------


def _expected_parquet(spec: dict) -> str | None:
    """What an undamaged Parquet file of ``spec`` must give: None (it reads), else the
    start of the ReadError's reason."""
    lower = [n.lower() for n in spec["names"]]
    for axis in "xyz":
        if lower.count(axis) != 1:
            return f"{'no' if lower.count(axis) == 0 else 'more than one'} '{axis}' column"
    if spec["rows"] == 0:
        return "no data rows"
    if not all(spec["numeric"][lower.index(axis)] for axis in "xyz"):
        return "column '"
    return None


def _check_parquet(path: str, spec: dict, got, error) -> None:
    from test_fuzz_readers import Bug

    if spec.get("damaged"):
        return
    want = _expected_parquet(spec)
    if want is None:
        if error is not None:
            raise Bug(f"ReadError for a valid file: {error}")
        names = spec["names"]
        lower = [n.lower() for n in names]
        expected = np.array([[np.nan if v is None else float(v) for v in spec["columns"][
            lower.index(axis)]] for axis in "xyz"], dtype=np.float64).T.reshape(-1, 3)
        if not np.array_equal(got.points, expected, equal_nan=True):
            raise Bug(f"points {got.points.tolist()!r}, expected {expected.tolist()!r}")
        if got.passthrough_names != [n for n in names if n.lower() not in "xyz"]:
            raise Bug(f"pass-through names {got.passthrough_names!r}")
    elif error is None:
        raise Bug(f"read although it must be refused ({want})")
    elif want not in error:
        raise Bug(f"refused, but not for {want!r}: {error}")


def _serve() -> None:
    """Read requests (JSON lines: path, kind, spec) on stdin and answer each with a JSON line:
    outcome 'ok', 'error' or 'bug' and a detail. Runs with file descriptor 2 pointing to a
    file, to tell what a read writes there."""
    import contextlib
    import io as _io

    log = tempfile.TemporaryFile()
    # the answers go out on a copy of fd 1; fds 1 and 2 both point to the log, so that
    # whatever a read writes on either (a print, a C library's message) is caught below
    # instead of corrupting the answers; so does what the imports print (test_fuzz_readers
    # writes its seed files with meshio, which prints warnings)
    out = os.fdopen(os.dup(1), "w")
    sys.stdout.flush()
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)

    from diffsurf_cli import io
    from test_fuzz_readers import Bug, check_contactors, check_read_error, compare_with_reference
    for request in sys.stdin:
        req = json.loads(request)
        path, kind = req["path"], req["kind"]
        before = os.fstat(2).st_size
        detail = ""
        try:
            if kind == "csv":
                outcome = compare_with_reference(Path(path).read_bytes(),
                                                 os.path.dirname(path))
            else:
                got, error = None, None
                printed = _io.StringIO()
                try:
                    with contextlib.redirect_stdout(printed):
                        got = io.read_contactors(path)
                except io.ReadError as exc:
                    check_read_error(exc, path)
                    error = str(exc)
                else:
                    check_contactors(got)
                if printed.getvalue():
                    raise Bug(f"printed on stdout: {printed.getvalue()[:200]!r}")
                _check_parquet(path, req["spec"], got, error)
                outcome = "ok" if error is None else "error"
                detail = error or ""
        except Bug as exc:
            outcome, detail = "bug", str(exc)
        except BaseException as exc:  # noqa: BLE001 - anything else is a bug to report
            outcome, detail = "bug", f"{type(exc).__name__}: {exc}"
        sys.stdout.flush()
        sys.stderr.flush()
        if os.fstat(2).st_size != before:
            os.lseek(log.fileno(), before, os.SEEK_SET)
            text = os.read(log.fileno(), 400).decode("utf-8", "replace")
            outcome, detail = "bug", f"wrote on stdout or stderr: {text!r} ({detail})"
        out.write(json.dumps({"outcome": outcome, "detail": detail[:2000]}) + "\n")
        out.flush()


if __name__ == "__main__" and sys.argv[1:] == ["--worker"]:
    _serve()
    sys.exit(0)


# -------------------------------------------------------------------------------------------
# the test side
# -------------------------------------------------------------------------------------------

import polars as pl  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from test_fuzz_readers import CSV_INPUTS, csv_of_numbers  # noqa: E402
from test_tables_hostile import PANICKING_PARQUET  # noqa: E402


class Worker:
    """A worker process that reads files on request, restarted after a crash or a hang."""

    def __init__(self):
        self.proc = None

    def start(self):
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            [str(ROOT), str(TESTS), os.environ.get("PYTHONPATH", "")])}
        self.proc = subprocess.Popen([sys.executable, __file__, "--worker"],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, env=env, cwd=str(ROOT))

    def stop(self):
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def read(self, path: str, kind: str, spec: dict | None = None) -> dict:
        import selectors

        if self.proc is None or self.proc.poll() is not None:
            self.start()
        self.proc.stdin.write(json.dumps({"path": path, "kind": kind, "spec": spec}) + "\n")
        self.proc.stdin.flush()
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        # the first request waits for the worker's imports too
        ready = sel.select(READ_TIMEOUT + 30)
        sel.close()
        if not ready:
            self.stop()
            return {"outcome": "hang", "detail": f"no answer in {READ_TIMEOUT} s"}
        line = self.proc.stdout.readline()
        if not line:
            code = self.proc.wait()
            self.proc = None
            return {"outcome": "crash", "detail": f"the worker died (exit code {code})"}
        return json.loads(line)


@pytest.fixture(scope="module")
def worker():
    w = Worker()
    yield w
    w.stop()


@pytest.fixture(scope="module")
def workdir():
    with tempfile.TemporaryDirectory() as d:
        yield d


def run_cli(path: str, directory: str) -> None:
    """`diffsurf project -q cylinder.msh path -o out.csv`: exit 0 or 1, no traceback, and for
    exit 1 exactly one 'diffsurf: error:' line."""
    out = os.path.join(directory, "out.csv")
    if os.path.exists(out):
        os.remove(out)
    try:
        done = subprocess.run([sys.executable, "-m", "diffsurf_cli", "project", "-q", CYLINDER,
                               path, "-o", out], capture_output=True, text=True,
                              timeout=CLI_TIMEOUT, cwd=str(ROOT))
    except subprocess.TimeoutExpired:
        pytest.fail(f"the CLI hung on {path} ({Path(path).read_bytes()[:300]!r})")
    assert "Traceback" not in done.stderr, done.stderr
    assert done.returncode in (0, 1), (done.returncode, done.stderr[-2000:])
    if done.returncode == 1:
        lines = done.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("diffsurf: error: "), done.stderr
    else:
        assert done.stderr == "", done.stderr
        assert os.path.exists(out)


class Counter:
    """Which examples also go through the CLI: every CLI_EVERY-th."""

    def __init__(self):
        self.n = 0

    def cli_turn(self) -> bool:
        self.n += 1
        return self.n % CLI_EVERY == 1


FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def assert_read(result: dict, data_shown) -> None:
    assert result["outcome"] in ("ok", "error"), (result, data_shown)


# -------------------------------------------------------------------------------------------
# CSV
# -------------------------------------------------------------------------------------------

NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**6, 10**6).map(str),
    st.sampled_from(["nan", "-nan", "NaN", "inf", "-Infinity", "1e400", "-0.0", ".5", "5.",
                     "1e-320", " 2 ", "\u00a03", "1_000", "0x10", "", "1e", "\u0661",
                     "9" * 40]),
)
TEXT = st.one_of(
    st.text(alphabet="ab é,;\t\"'#_-:0123456789\u00a0", max_size=8),
    st.sampled_from(["", " ", "id", "x", "nan", "007", "1,5", 'a"b', "a\nb", "a\r\nb", "\u3000"]),
)


def _quote(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


@st.composite
def csv_tables(draw) -> bytes:
    """A CSV table: any separator, a header or none, pass-through columns before, between or
    after x, y, z, fields quoted now and then (always where they must be), comments and blank
    lines, a byte order mark, LF / CRLF / CR-only line ends; now and then a flaw (a short or
    long row, an unclosed quote, nothing at all)."""
    sep = draw(st.sampled_from([",", ";", "\t", " ", "  "]))
    npass = draw(st.integers(0, 3))
    header = draw(st.booleans())
    names = ["x", "y", "z"] + [f"p{j}" for j in range(npass)]
    order = draw(st.permutations(names)) if header else names[3:] + names[:3]
    if header:
        order = [draw(st.sampled_from([n, n.upper(), f" {n} "])) if n in "xyz" else n
                 for n in order]
    end = draw(st.sampled_from(["\n", "\r\n", "\r"]))

    def cell(name: str) -> str:
        if name.strip().lower() in "xyz":
            text = draw(NUMBER)
        elif header:
            text = draw(TEXT)
        else:  # a first row of text would be a header
            text = draw(st.integers(-99, 999).map(str))
        must = (sep in text or '"' in text or "\n" in text or "\r" in text
                or (sep.strip() == "" and text != text.strip()))
        if must or draw(st.integers(0, 6)) == 0:
            return _quote(text)
        return text

    lines = [draw(st.sampled_from(["# comment, with; commas", "#", ""]))
             for _ in range(draw(st.integers(0, 2)))]
    if header:
        lines.append(sep.join(order))
    for _ in range(draw(st.integers(0, 8))):
        row = [cell(n) for n in order]
        flaw = draw(st.sampled_from(["none"] * 12 + ["short", "long", "unclosed"]))
        if flaw == "short":
            row.pop()
        elif flaw == "long":
            row.append("1")
        elif flaw == "unclosed":
            row[0] = '"' + row[0]
        lines.append(sep.join(row))
        if draw(st.integers(0, 6)) == 0:
            lines.append(draw(st.sampled_from(["", "   ", "# c,o;m", "\t#"])))
    text = end.join(lines) + draw(st.sampled_from(["", end]))
    bom = draw(st.sampled_from([b"", b"", b"\xef\xbb\xbf"]))
    return bom + text.encode("utf-8")


CSV_ALL = st.one_of(csv_tables(), csv_of_numbers(), CSV_INPUTS,
                    st.sampled_from([b"", b"\n", b"\r", b"\r\n", b"\xef\xbb\xbf", b"x,y,z",
                                     b"x,y,z\r", b"#\r#\r", b'"', b"x,y,z\r1,2,3"]))


def test_csv_oracle_sees_cr_only_files():
    # the generator's CR-only files are real tables (not empty by accident)
    from test_fuzz_readers import reference_contactors

    got = reference_contactors(b"id;x;y;z\r\"a\rb\";1;2;3\r")
    assert got is not None and got[0].tolist() == [[1.0, 2.0, 3.0]]


@FUZZ
@given(data=CSV_ALL)
def test_fuzz_csv_tables(data, worker, workdir):
    counter = _COUNTERS.setdefault("csv", Counter())
    path = os.path.join(workdir, "points.csv")
    Path(path).write_bytes(data)
    assert_read(worker.read(path, "csv"), data[:400])
    if counter.cli_turn():
        run_cli(path, workdir)


# -------------------------------------------------------------------------------------------
# Parquet
# -------------------------------------------------------------------------------------------

_COUNTERS: dict = {}

FLOATS = st.one_of(st.none(), st.floats(allow_nan=True, allow_infinity=True, width=64))


def _coordinate(draw, rows: int):
    """(values for the spec, polars Series, numeric?) of one coordinate column."""
    import datetime as dt

    # mostly numbers, so that most files are tables to read
    kind = draw(st.sampled_from(["f64"] * 20 + ["f32", "i32", "i64", "u8", "i8", "decimal"] * 2
                                + ["str", "bool", "list", "date", "null"]))
    if kind in ("f64", "f32"):
        width = 64 if kind == "f64" else 32
        values = draw(st.lists(st.one_of(st.none(), st.floats(width=width)), min_size=rows,
                               max_size=rows))
        dtype = pl.Float64 if kind == "f64" else pl.Float32
        return values, pl.Series(values, dtype=dtype), True
    if kind in ("i32", "i64", "u8", "i8"):
        lo, hi, dtype = {"i32": (-2**31, 2**31 - 1, pl.Int32), "i64": (-2**53, 2**53, pl.Int64),
                         "u8": (0, 255, pl.UInt8), "i8": (-128, 127, pl.Int8)}[kind]
        values = draw(st.lists(st.one_of(st.none(), st.integers(lo, hi)), min_size=rows,
                               max_size=rows))
        return values, pl.Series(values, dtype=dtype), True
    if kind == "decimal":
        values = draw(st.lists(st.one_of(st.none(), st.integers(-10**6, 10**6)), min_size=rows,
                               max_size=rows))
        from decimal import Decimal

        series = pl.Series([None if v is None else Decimal(v) / 100 for v in values],
                           dtype=pl.Decimal(12, 2))
        return [None if v is None else v / 100 for v in values], series, True
    wrong = {"str": (pl.String, lambda i: str(i)), "bool": (pl.Boolean, lambda i: i % 2 == 0),
             "list": (pl.List(pl.Float64), lambda i: [float(i)]),
             "date": (pl.Date, lambda i: dt.date(2024, 1, 1 + i % 28)),
             "null": (pl.Null, lambda i: None)}[kind]
    series = pl.Series([wrong[1](i) for i in range(rows)], dtype=wrong[0])
    return None, series, False


def _passthrough(draw, rows: int) -> pl.Series:
    import datetime as dt
    from decimal import Decimal

    kind = draw(st.sampled_from(["i8", "u64", "f32", "bool", "str", "cat", "enum", "date",
                                 "datetime", "datetime_tz", "duration", "time", "decimal",
                                 "binary", "list", "array", "struct", "null", "f64"]))
    null = [draw(st.integers(0, 4)) == 0 for _ in range(rows)]

    def values(make):
        return [None if n else make(i) for i, n in enumerate(null)]

    words = ["a", "b,c", 'd"e', "f\ng", " h ", "é"]
    if kind == "i8":
        return pl.Series(values(lambda i: i % 100 - 50), dtype=pl.Int8)
    if kind == "u64":
        return pl.Series(values(lambda i: 2**64 - 1 - i), dtype=pl.UInt64)
    if kind in ("f32", "f64"):
        floats = [float("nan"), float("inf"), -0.0, 1e-300, 0.1]
        return pl.Series(values(lambda i: floats[i % 5]),
                         dtype=pl.Float32 if kind == "f32" else pl.Float64)
    if kind == "bool":
        return pl.Series(values(lambda i: i % 3 == 0), dtype=pl.Boolean)
    if kind in ("str", "cat", "enum"):
        dtype = {"str": pl.String, "cat": pl.Categorical, "enum": pl.Enum(words)}[kind]
        return pl.Series(values(lambda i: words[i % len(words)]), dtype=dtype)
    if kind == "date":
        return pl.Series(values(lambda i: dt.date(2024, 1, 1 + i % 28)), dtype=pl.Date)
    if kind in ("datetime", "datetime_tz"):
        unit = draw(st.sampled_from(["ms", "us", "ns"]))
        dtype = pl.Datetime(unit, "Europe/Paris" if kind == "datetime_tz" else None)
        return pl.Series(values(lambda i: dt.datetime(2024, 3, 31, 1, i % 60)), dtype=dtype)
    if kind == "duration":
        unit = draw(st.sampled_from(["ms", "us", "ns"]))
        return pl.Series(values(lambda i: dt.timedelta(seconds=i, microseconds=7)),
                         dtype=pl.Duration(unit))
    if kind == "time":
        return pl.Series(values(lambda i: dt.time(12, i % 60, 5)), dtype=pl.Time)
    if kind == "decimal":
        return pl.Series(values(lambda i: Decimal(i) / 8), dtype=pl.Decimal(20, 3))
    if kind == "binary":
        return pl.Series(values(lambda i: bytes([i % 256, 0, 255])), dtype=pl.Binary)
    if kind == "list":
        return pl.Series(values(lambda i: list(range(i % 3))), dtype=pl.List(pl.Int64))
    if kind == "array":
        return pl.Series(values(lambda i: [float(i), 1.0]), dtype=pl.Array(pl.Float64, 2))
    if kind == "struct":
        return pl.Series(values(lambda i: {"a": i, "b": words[i % 6]}),
                         dtype=pl.Struct({"a": pl.Int64, "b": pl.String}))
    return pl.Series([None] * rows, dtype=pl.Null)


@st.composite
def parquet_tables(draw):
    """(bytes of a Parquet file, spec: its column names, which are numeric, the coordinates'
    values, the row count, and whether it was damaged)."""
    rows = draw(st.sampled_from([0, 1, 2, 3, 7, 40]))
    names = draw(st.sampled_from([["x", "y", "z"]] * 6 + [["X", "Y", "Z"], ["x", "y"],
                                                          ["x", "y", "z", "X"], ["a", "b", "c"]]))
    npass = draw(st.integers(0, 3))
    columns, numeric, series = [], [], []
    for name in names:
        values, s, is_number = _coordinate(draw, rows)
        columns.append(values)
        numeric.append(is_number)
        series.append(s.alias(name))
    for j in range(npass):
        series.append(_passthrough(draw, rows).alias(f"p{j}"))
    order = draw(st.permutations(range(len(series))))
    series = [series[k] for k in order]
    names = [names[k] if k < len(names) else f"p{k - len(names)}" for k in order]
    columns = [columns[k] if k < len(columns) else None for k in order]
    numeric = [numeric[k] if k < len(numeric) else False for k in order]
    frame = pl.DataFrame(series)
    writer = draw(st.sampled_from(["polars", "pyarrow"]))
    codec = draw(st.sampled_from(["uncompressed", "snappy", "gzip", "lz4", "zstd", "brotli"]))
    group = draw(st.sampled_from([None, 1, 3, 16]))
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "t.parquet")
        if writer == "polars":
            frame.write_parquet(path, compression=codec, row_group_size=group,
                                statistics=draw(st.booleans()))
        else:
            import pyarrow.parquet as pq

            pq.write_table(frame.to_arrow(), path, compression="none" if codec ==
                           "uncompressed" else codec, row_group_size=group,
                           use_dictionary=draw(st.booleans()),
                           data_page_version=draw(st.sampled_from(["1.0", "2.0"])),
                           data_page_size=draw(st.sampled_from([None, 64])),
                           write_statistics=draw(st.booleans()))
        data = Path(path).read_bytes()
    damage = draw(st.sampled_from(["none"] * 5 + ["truncate", "bytes", "header", "header",
                                                  "zero", "append", "magic", "empty"]))
    if damage == "truncate":
        data = data[:draw(st.integers(0, len(data) - 1))]
    elif damage == "bytes":
        data = bytearray(data)
        for _ in range(draw(st.integers(1, 4))):
            data[draw(st.integers(0, len(data) - 1))] = draw(st.integers(0, 255))
        data = bytes(data)
    elif damage == "header":  # a page header (the first starts at byte 4): sizes, counts
        data = bytearray(data)
        data[min(len(data) - 1, 4 + draw(st.integers(0, 40)))] = draw(st.sampled_from(
            [0, 0x7F, 0xFF]))
        data = bytes(data)
    elif damage == "zero":
        a = draw(st.integers(0, len(data) - 1))
        b = draw(st.integers(a, min(len(data), a + 64)))
        data = data[:a] + bytes(b - a) + data[b:]
    elif damage == "append":
        data += draw(st.binary(min_size=1, max_size=32))
    elif damage == "magic":
        data = b"PAR1" + draw(st.sampled_from([b"", b"PAR1", b"\x00" * 8 + b"PAR1"]))
    elif damage == "empty":
        data = b""
    spec = {"names": names, "numeric": numeric, "columns": columns, "rows": rows,
            "damaged": damage != "none"}
    return data, spec


@FUZZ
@given(case=parquet_tables())
@example(case=(PANICKING_PARQUET, {"damaged": True}))  # a panic in polars: nothing on fd 2
def test_fuzz_parquet_tables(case, worker, workdir):
    data, spec = case
    counter = _COUNTERS.setdefault("parquet", Counter())
    path = os.path.join(workdir, "points.parquet")
    Path(path).write_bytes(data)
    assert_read(worker.read(path, "parquet", spec), spec)
    if counter.cli_turn():
        run_cli(path, workdir)
