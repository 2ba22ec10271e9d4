"""Bounded fuzz run of the readers at the file boundary (issue 6, "Also"; issue 32).

`io.read_contactors` gets random bytes and random mutations of a valid CSV; `io.read_target`
gets random mutations of the bytes of `sample_meshes/cylinder.msh` (Gmsh 2.2 ASCII), of an
ASCII STL, of `sample_meshes/plate.vtu` (zlib-compressed base64 VTU) and of a piece of the
cylinder written by meshio in 13 more formats (Gmsh 2.2 binary, Gmsh 4.1 ASCII and binary, VTU
ASCII and raw binary, legacy VTK ASCII and binary, binary STL, OBJ, PLY ASCII and binary, OFF,
an Abaqus/CalculiX deck), and every seed cut at the end of each of its lines. The only
allowed outcomes are a valid result (the shapes documented on `Target` and `Contactors`) or
an `io.ReadError` whose message is one line naming the file, within `READ_SECONDS`.
Anything else (an IndexError from meshio, a SystemExit, text printed on stdout where CSV
results go, a read that does not end) is a bug.

The strategies live here so that `benchmarks/fuzz_readers.py` runs the same ones for longer.
"""
from __future__ import annotations

import contextlib
import io as _io
import os
import signal
import tempfile
import threading
from pathlib import Path

import meshio
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference_table
from diffsurf_cli import io

SAMPLES = Path(__file__).resolve().parent.parent / "sample_meshes"

#: examples per target in the test suite (the benchmark script runs thousands): the first
#: three seeds (msh, stl, vtu) get EXAMPLES, the others, added in issue 32, MORE_EXAMPLES (the
#: whole fuzz test stays under a minute on one core).
EXAMPLES = 150
MORE_EXAMPLES = 100

#: seconds one read may take before it counts as a hang (a seed reads in milliseconds).
READ_SECONDS = 5


# -------------------------------------------------------------------------------------------
# seed files
# -------------------------------------------------------------------------------------------


def _ascii_stl() -> bytes:
    """The first 12 triangles of the sample cylinder as an ASCII STL."""
    mesh = meshio.read(str(SAMPLES / "cylinder_tri.stl"))
    tri = mesh.cells_dict["triangle"][:12]
    used, inverse = np.unique(tri, return_inverse=True)
    small = meshio.Mesh(mesh.points[used], [("triangle", inverse.reshape(tri.shape))])
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "seed.stl")
        meshio.write(path, small, file_format="stl", binary=False)
        return Path(path).read_bytes()


#: a small valid contactor CSV: header, a comment, a blank line, a pass-through column.
CSV_SEED = (b"id,x,y,z\n"
            b"# plate nodes\n"
            b"1,0.0,20.00000000000011,0.0\n"
            b"2,1.25,20.000000000000995,0.0\n"
            b"\n"
            b"3,2.5,20.00000000000833,1.25\n"
            b"4,3.75,20.00000000006408,2.5\n")

def _piece(kind: str) -> meshio.Mesh:
    """The first 8 quads of the sample cylinder (15 points), as quads or as 16 triangles."""
    mesh = meshio.read(str(SAMPLES / "cylinder.msh"))
    quads = mesh.cells_dict["quad"][:8]
    used, inverse = np.unique(quads, return_inverse=True)
    quads = inverse.reshape(quads.shape)
    cells = quads if kind == "quad" else np.concatenate([quads[:, [0, 1, 2]],
                                                         quads[:, [0, 2, 3]]])
    mesh = meshio.Mesh(mesh.points[used], [(kind, cells)])
    # the Gmsh writers warn on stderr for a block without them
    mesh.cell_data = {key: [np.ones(len(cells), dtype=np.int32)]
                      for key in ("gmsh:physical", "gmsh:geometrical")}
    return mesh


#: the other formats (issue 32): name -> (extension, meshio format, cell kind, writer options).
MESHIO_SEEDS = {
    "msh22-binary": (".msh", "gmsh22", "quad", {"binary": True}),
    "msh41-ascii": (".msh", "gmsh", "quad", {"binary": False}),
    "msh41-binary": (".msh", "gmsh", "quad", {"binary": True}),
    "vtu-ascii": (".vtu", "vtu", "quad", {"binary": False}),
    "vtu-binary": (".vtu", "vtu", "quad", {"binary": True, "compression": None}),
    "vtk-ascii": (".vtk", "vtk", "quad", {"binary": False}),
    "vtk-binary": (".vtk", "vtk", "quad", {"binary": True}),
    "stl-binary": (".stl", "stl", "triangle", {"binary": True}),
    "obj": (".obj", "obj", "quad", {}),
    "ply-ascii": (".ply", "ply", "quad", {"binary": False}),
    "ply-binary": (".ply", "ply", "quad", {"binary": True}),
    "off": (".off", "off", "triangle", {}),
    "inp": (".inp", "abaqus", "quad", {}),
}


def _meshio_seed(name: str) -> tuple[str, bytes]:
    ext, fmt, kind, options = MESHIO_SEEDS[name]
    mesh = _piece(kind)
    if not fmt.startswith("gmsh"):
        mesh.cell_data = {}
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "seed" + ext)
        meshio.write(path, mesh, file_format=fmt, **options)
        return ext, Path(path).read_bytes()


#: target seeds by name: (extension, bytes).
TARGET_SEEDS = {
    "msh": (".msh", (SAMPLES / "cylinder.msh").read_bytes()),
    "stl": (".stl", _ascii_stl()),
    "vtu": (".vtu", (SAMPLES / "plate.vtu").read_bytes()),
    **{name: _meshio_seed(name) for name in MESHIO_SEEDS},
}

#: text that tends to break number parsers and tokenisers.
SPECIAL_TOKENS = [b"nan", b"-inf", b"inf", b"1e400", b"-0", b"0x10", b"1_000", b"", b" ", b",",
                  b",,", b"\"", b"'", b"#", b"\r", b"\r\n", b"\t", b"\x00", b"\xff\xfe",
                  b"\xef\xbb\xbf", "é".encode(), "\u2212".encode(), "１".encode(),
                  "\u00a0".encode(), b"9" * 400, b"1." + b"1" * 2000, b"-" * 50, b"e",
                  b"$EndNodes", b"$Elements", b"endsolid", b"facet normal 0 0 1", b"</Piece>",
                  b"4294967296", b"-1", b"2147483648", b"99999999999999999999",
                  b'""', b'"a,b"', b'"x""y"', b'"1"', b'" 2 "', b'"open', b'"a"b', b'a"b']


# -------------------------------------------------------------------------------------------
# strategies
# -------------------------------------------------------------------------------------------


def _position(data: bytes):
    return st.integers(min_value=0, max_value=len(data))


@st.composite
def _mutation(draw, data: bytes) -> bytes:
    """One random edit of ``data``."""
    kind = draw(st.sampled_from(["truncate", "insert", "delete", "overwrite", "token",
                                 "swap-lines", "duplicate-line", "drop-line", "flip-bit"]))
    if not data and kind not in ("insert", "token"):
        kind = "insert"
    n = len(data)
    if kind == "truncate":
        return data[:draw(_position(data))]
    if kind == "insert":
        at = draw(_position(data))
        return data[:at] + draw(st.binary(min_size=1, max_size=40)) + data[at:]
    if kind == "token":
        at = draw(_position(data))
        return data[:at] + draw(st.sampled_from(SPECIAL_TOKENS)) + data[at:]
    if kind == "delete":
        at = draw(st.integers(0, n - 1))
        return data[:at] + data[at + draw(st.integers(1, 200)):]
    if kind == "overwrite":
        at = draw(st.integers(0, n - 1))
        new = draw(st.binary(min_size=1, max_size=20))
        return data[:at] + new + data[at + len(new):]
    if kind == "flip-bit":
        at = draw(st.integers(0, n - 1))
        return data[:at] + bytes([data[at] ^ (1 << draw(st.integers(0, 7)))]) + data[at + 1:]
    lines = data.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    j = draw(st.integers(0, len(lines) - 1))
    if kind == "swap-lines":
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "duplicate-line":
        lines.insert(j, lines[i])
    else:
        del lines[i]
    return b"\n".join(lines)


@st.composite
def mutated(draw, data: bytes, max_edits: int = 4) -> bytes:
    """``data`` after 1 to ``max_edits`` random edits."""
    for _ in range(draw(st.integers(1, max_edits))):
        data = draw(_mutation(data))
    return data


#: text for a quoted field: separators, blanks, quotes (doubled when quoted) and line ends.
QUOTABLE = st.text(alphabet='ab1.,; \t"\r\n', max_size=8)


def _quote(text: str) -> bytes:
    """``text`` as an RFC 4180 quoted field."""
    return ('"' + text.replace('"', '""') + '"').encode()


@st.composite
def csv_edits(draw) -> bytes:
    """CSV-specific damage to the seed: extra commas, long numbers, unicode, line ends, quoted
    fields (separators, doubled quotes, line ends inside; blanks around) and broken quotes (a
    quote never closed, text after a closing one)."""
    lines = CSV_SEED.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    kind = draw(st.sampled_from(["extra-comma", "long-number", "unicode", "crlf", "field",
                                 "quote", "quote", "broken-quote"]))
    if kind == "extra-comma":
        at = draw(st.integers(0, len(lines[i])))
        lines[i] = lines[i][:at] + b"," * draw(st.integers(1, 3)) + lines[i][at:]
    elif kind == "long-number":
        digits = draw(st.text("0123456789", min_size=1, max_size=3000)).encode()
        exp = draw(st.sampled_from([b"", b"e308", b"e-400", b"e99999999999"]))
        lines[i] = lines[i] + b"," + digits + exp if draw(st.booleans()) else (
            b"1," + digits + b"." + digits + exp + b",0,0")
    elif kind == "unicode":
        text = draw(st.text(min_size=1, max_size=30))
        at = draw(st.integers(0, len(lines[i])))
        lines[i] = lines[i][:at] + text.encode("utf-8", "surrogatepass") + lines[i][at:]
    elif kind == "crlf":
        return b"\r\n".join(lines)
    elif kind == "quote":  # a field quoted: as it was (a number stays one), or new text
        fields = lines[i].split(b",")
        k = draw(st.integers(0, len(fields) - 1))
        inner = fields[k].decode() if draw(st.booleans()) else draw(QUOTABLE)
        pad = st.sampled_from(["", " ", "\t"])
        fields[k] = draw(pad).encode() + _quote(inner) + draw(pad).encode()
        lines[i] = b",".join(fields)
    elif kind == "broken-quote":  # a quote at a field's start never closed, or closed early
        fields = lines[i].split(b",")
        k = draw(st.integers(0, len(fields) - 1))
        fields[k] = draw(st.sampled_from([b'"' + fields[k], b'"' + fields[k] + b'"x',
                                          b'"a""' + fields[k], fields[k] + b'"']))
        lines[i] = b",".join(fields)
    else:
        fields = lines[i].split(b",")
        k = draw(st.integers(0, len(fields) - 1))
        fields[k] = draw(st.sampled_from(SPECIAL_TOKENS))
        lines[i] = b",".join(fields)
    return b"\n".join(lines)


#: contactor CSV inputs: pure random bytes, random text, edits and mutations of the seed.
CSV_INPUTS = st.one_of(
    st.binary(max_size=300),
    st.text(alphabet=st.characters(codec="utf-8"), max_size=200).map(lambda t: t.encode()),
    st.text(alphabet="0123456789.,-+eE \n#xyzid", max_size=200).map(str.encode),
    csv_edits(),
    mutated(CSV_SEED),
    csv_edits().flatmap(mutated),
)


#: whitespace that str.strip removes (and so the reader must), ASCII and not.
SPACES = ["", " ", "  ", "\t", "\r", "\x0b", "\x0c", "\x1c", "\x85", "\xa0", "\u2003",
          "\u3000"]


def _halfway(x: float, up: bool) -> str:
    """The exact decimal midway between ``x`` and its neighbour: a round-half-even tie."""
    from decimal import Decimal, getcontext

    getcontext().prec = 1200
    with np.errstate(over="ignore"):
        y = float(np.nextafter(x, np.inf if up else -np.inf))
    if not np.isfinite(y):
        return repr(x)
    return format((Decimal(x) + Decimal(y)) / 2, "f" if abs(x) < 1e30 else "e")


@st.composite
def number_text(draw) -> str:
    """Spellings of numbers that float() accepts or refuses, to test a parser against it."""
    x = draw(st.floats(allow_nan=True, allow_infinity=True))
    # the kinds that may be invalid (underscore, special) are drawn less often, so that most
    # CSVs of several rows still read and their numbers get compared
    kind = draw(st.sampled_from(["repr", "e", "f", "g", "halfway", "halfway±1", "regex",
                                 "subnormal", "unicode-digits"] * 3 + ["underscore", "special"]))
    if kind == "repr":
        text = repr(x)
    elif kind in ("e", "f", "g"):
        spec = kind if draw(st.booleans()) else kind.upper()
        text = format(x, f".{draw(st.integers(0, 40))}{spec}")
    elif kind.startswith("halfway"):
        x = x if np.isfinite(x) else 1.0
        text = _halfway(x, draw(st.booleans()))
        if kind == "halfway±1" and text[-1].isdigit():
            text = text[:-1] + str((int(text[-1]) + draw(st.sampled_from([1, 9]))) % 10)
    elif kind == "regex":
        text = draw(st.from_regex(r"[+-]?(\d{1,30}(\.\d{0,30})?|\.\d{1,30})([eE][+-]?\d{1,4})?",
                                  fullmatch=True))
    elif kind == "underscore":
        text = draw(st.from_regex(r"[+-]?\d{1,3}(_{1,2}\d{1,3}){0,4}(\.\d(_?\d){0,5})?(e_?\d+)?",
                                  fullmatch=True))
    elif kind == "special":
        text = draw(st.sampled_from(["nan", "NaN", "-nan", "+NAN", "inf", "-Infinity", "+iNfInItY",
                                     "infinit", "in", "1e", "1.e5", ".e5", ".", "-", "+.5",
                                     "0x1p3", "1e-400", "-1e-400", "1e309", "4.9e-324",
                                     "2.4703282292062327e-324", "2.4703282292062328e-324",
                                     "1.7976931348623157e308", "1.7976931348623158e308",
                                     "1.797693134862315807e308", "9" * 40, "0" * 40 + "1",
                                     "0." + "0" * 330 + "1", "1" + "0" * 330]))
    elif kind == "subnormal":
        text = repr(draw(st.integers(1, 2 ** 52 - 1)) * 5e-324)  # every subnormal
    else:
        # Arabic-Indic and fullwidth digits: float() reads them, so must the reader
        digits = draw(st.sampled_from(["".join(map(chr, range(0x660, 0x66A))),
                                       "".join(map(chr, range(0xFF10, 0xFF1A)))]))
        text = "".join(digits[int(c)] if c.isdigit() else c for c in repr(abs(x) if np.isfinite(x)
                                                                         else 1.5))
    return draw(st.sampled_from(SPACES)) + text + draw(st.sampled_from(SPACES))


@st.composite
def csv_of_numbers(draw) -> bytes:
    """A CSV of rows of :func:`number_text`, with or without a header and an id column; now
    and then a field quoted (a number in quotes is still one; a quoted id may hold commas,
    quotes and line ends)."""
    header = draw(st.sampled_from(["", "x,y,z", "id,x,y,z", "X , Y , Z", '"x","y","z"',
                                   '"id", "x" ,"y","z"']))
    with_id = '"id"' in header or header.startswith("id") or (
        header == "" and draw(st.booleans()))

    def maybe_quoted(text: str) -> str:
        return _quote(text).decode() if draw(st.integers(0, 4)) == 0 else text

    rows = []
    for i in range(draw(st.integers(1, 4))):
        fields = [maybe_quoted(draw(number_text())) for _ in range(3)]
        if with_id:
            # without a header a text id would make the first row the header
            ids = ([str(i), f" p{i} ", "é", "", "\u2003a b", _quote(draw(QUOTABLE)).decode()]
                   if header else [str(i), f" {i}.0", f'"{i}"'])
            fields.insert(0, draw(st.sampled_from(ids)))
        rows.append(",".join(fields))
        if draw(st.integers(0, 5)) == 0:
            rows.append(draw(st.sampled_from(["", "# comment, with, commas", "   ", "\t# x"])))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    text = end.join(([header] if header else []) + rows) + end
    return text.encode("utf-8")


def target_inputs(kind: str):
    """Mutations of the seed file of ``kind`` (a key of TARGET_SEEDS)."""
    return mutated(TARGET_SEEDS[kind][1])


def line_cuts(data: bytes) -> list[int]:
    """The lengths of ``data`` cut at the end of each of its lines, its last byte left out,
    and, for a file of binary data, at every 7th byte (cuts that leave the file whole: none)."""
    cuts = {i + 1 for i, b in enumerate(data) if b == ord("\n")} | {len(data) - 1}
    if b"\0" in data:
        cuts |= set(range(0, len(data), 7))
    return sorted(c for c in cuts if c < len(data))


# -------------------------------------------------------------------------------------------
# oracles
# -------------------------------------------------------------------------------------------


class Bug(AssertionError):
    """A reader outcome that is neither a valid result nor a clean ReadError."""


class Hang(BaseException):
    """A read that did not end within READ_SECONDS (raised by an alarm; a BaseException, so
    that no `except Exception` of a reader takes it for a failure of the file)."""


@contextlib.contextmanager
def time_limit(seconds: int = READ_SECONDS):
    """Raise Hang in the block after ``seconds`` (where SIGALRM exists, in the main thread;
    elsewhere pytest-timeout's limit of the whole test remains)."""
    if not hasattr(signal, "SIGALRM") or threading.current_thread() is not \
            threading.main_thread():
        yield
        return

    def alarm(*_):
        raise Hang(f"no result within {seconds} s")

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def check_read_error(exc: io.ReadError, path: str) -> None:
    message = str(exc)
    if "\n" in message or "\r" in message:
        raise Bug(f"ReadError message spans lines: {message!r}")
    if not message.startswith(path):
        raise Bug(f"ReadError message does not start with the file name: {message!r}")


def check_target(t: io.Target) -> None:
    if not (isinstance(t.points, np.ndarray) and t.points.dtype == np.float64
            and t.points.ndim == 2 and t.points.shape[1] == 3 and len(t.points)):
        raise Bug(f"points {getattr(t.points, 'shape', None)} {getattr(t.points, 'dtype', None)}")
    if not t.cells:
        raise Bug("no cells")
    for kind, conn in t.cells:
        if kind not in io.SURFACE_CELL_TYPES:
            raise Bug(f"cell type {kind}")
        if not (conn.dtype == np.int64 and conn.ndim == 2 and len(conn)):
            raise Bug(f"{kind} connectivity {conn.shape} {conn.dtype}")
        if conn.min() < 0 or conn.max() >= len(t.points):
            raise Bug(f"{kind} connectivity out of range")
    nodes = t.nodes
    if not (nodes.dtype == np.int64 and nodes.ndim == 1 and np.all(np.diff(nodes) > 0)):
        raise Bug("nodes not sorted unique int64")
    expected = np.unique(np.concatenate([c.reshape(-1) for _, c in t.cells]))
    if not np.array_equal(nodes, expected):
        raise Bug("nodes are not the points of the cells")
    if not np.isfinite(t.points[nodes]).all():
        raise Bug("non-finite surface node")


def check_contactors(c: io.Contactors) -> None:
    p = c.points
    if not (isinstance(p, np.ndarray) and p.dtype == np.float64 and p.ndim == 2
            and p.shape[1] == 3 and len(p)):
        raise Bug(f"points {getattr(p, 'shape', None)} {getattr(p, 'dtype', None)}")
    if len(c.passthrough) != len(c.passthrough_names):
        raise Bug(f"{len(c.passthrough)} pass-through columns for {len(c.passthrough_names)} "
                  f"names")
    if any(len(col) != len(p) for col in c.passthrough):
        raise Bug("pass-through column of the wrong length")


def run_reader(reader, checker, path: str) -> str:
    """Call ``reader(path)``; return 'ok' or 'error', raise Bug on any other outcome."""
    out = _io.StringIO()
    try:
        with contextlib.redirect_stdout(out), time_limit():
            result = reader(path)
    except Hang as exc:
        raise Bug(f"a hang: {exc}") from None
    except io.ReadError as exc:
        check_read_error(exc, path)
        outcome = "error"
    except Exception as exc:
        raise Bug(f"{type(exc).__name__}: {exc}") from exc
    except SystemExit as exc:
        raise Bug(f"SystemExit({exc.code})") from exc
    else:
        checker(result)
        outcome = "ok"
    if out.getvalue():
        raise Bug(f"the reader printed on stdout: {out.getvalue()[:200]!r}")
    return outcome


def read_contactors_bytes(data: bytes, directory: str) -> str:
    path = os.path.join(directory, "points.csv")
    Path(path).write_bytes(data)
    return run_reader(io.read_contactors, check_contactors, path)


def reference_contactors(data: bytes):
    """The documented CSV rules (io.read_contactors) in plain Python: (points, names, rows),
    or None where the reader must raise ReadError. Slow and obvious, to check the fast one."""
    if b"\x00" in data:
        return None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        return None
    text = text[1:] if text.startswith("\ufeff") else text
    try:
        return reference_table.read_csv(text, "points.csv")
    except io.ReadError:
        return None


def same_floats(a: np.ndarray, b: np.ndarray) -> bool:
    """Bit for bit, except that every NaN equals every NaN (of the same sign)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
        return False
    if not np.array_equal(np.signbit(a), np.signbit(b)):
        return False
    keep = ~np.isnan(a)
    return np.array_equal(a[keep].view(np.uint64), b[keep].view(np.uint64))


def compare_with_reference(data: bytes, directory: str) -> str:
    """Read ``data`` and check the outcome against :func:`reference_contactors`."""
    path = os.path.join(directory, "points.csv")
    Path(path).write_bytes(data)
    got = None

    def keep(p):
        nonlocal got
        got = io.read_contactors(p)
        return got

    outcome = run_reader(keep, check_contactors, path)
    want = reference_contactors(data)
    if want is None:
        if outcome != "error":
            raise Bug("read although the rules say it is not a valid CSV")
        return outcome
    if outcome != "ok":
        raise Bug("ReadError although the rules read it")
    points, names, rows = want
    if not same_floats(got.points, points):
        bad = np.flatnonzero(~np.all((got.points == points) | (np.isnan(got.points)
                                                                & np.isnan(points)), axis=1))
        i = int(bad[0]) if len(bad) else 0
        raise Bug(f"row {i}: read {got.points[i].tolist()!r}, float() gives "
                  f"{points[i].tolist()!r}")
    if list(got.passthrough_names) != names:
        raise Bug(f"pass-through names {list(got.passthrough_names)!r}, expected {names!r}")
    if got.passthrough_rows() != rows:
        raise Bug(f"pass-through text {got.passthrough_rows()!r}, expected {rows!r}")
    return outcome


def read_target_bytes(kind: str, data: bytes, directory: str) -> str:
    path = os.path.join(directory, "target" + TARGET_SEEDS[kind][0])
    Path(path).write_bytes(data)
    return run_reader(io.read_target, check_target, path)


# -------------------------------------------------------------------------------------------
# tests
# -------------------------------------------------------------------------------------------

#: derandomized: the suite tests the same inputs on every run (no flaky CI); the benchmark
#: script explores new ones.
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@pytest.fixture(scope="module")
def workdir():
    with tempfile.TemporaryDirectory() as d:
        yield d


@pytest.mark.parametrize("kind", sorted(TARGET_SEEDS))
def test_seeds_are_valid(kind, workdir):
    assert read_target_bytes(kind, TARGET_SEEDS[kind][1], workdir) == "ok"


def test_csv_seed_is_valid(workdir):
    assert read_contactors_bytes(CSV_SEED, workdir) == "ok"


@FUZZ
@given(data=CSV_INPUTS)
def test_fuzz_read_contactors(data, workdir):
    read_contactors_bytes(data, workdir)


@FUZZ
@given(data=st.one_of(csv_of_numbers(), CSV_INPUTS))
def test_fuzz_read_contactors_matches_the_rules(data, workdir):
    """The CSV reader gives what str.strip / str.split / float() give, bit for bit (the rules
    in reference_table.py)."""
    compare_with_reference(data, workdir)


@pytest.mark.parametrize("kind", sorted(TARGET_SEEDS))
def test_fuzz_read_target(kind, workdir):
    examples = EXAMPLES if kind in ("msh", "stl", "vtu") else MORE_EXAMPLES

    @settings(FUZZ, max_examples=examples)
    @given(data=target_inputs(kind))
    def run(data):
        read_target_bytes(kind, data, workdir)

    run()


#: the seeds of formats that declare neither their end nor their counts: a file cut at the
#: end of a line is a valid file of fewer cells.
ENDLESS_FORMATS = ("obj", "inp")


@pytest.mark.parametrize("kind", sorted(TARGET_SEEDS))
def test_every_cut_of_the_seeds(kind, workdir):
    """A file cut at the end of any of its lines (a truncated download or copy) is a
    ReadError, not a hang (a PLY header that stops before its end made meshio's reader loop
    for ever) nor the cells before the cut (an ASCII STL cut at a facet's end, a binary PLY
    at a face's end), unless its format has no end and no counts."""
    data = TARGET_SEEDS[kind][1]
    for cut in line_cuts(data):
        try:
            outcome = read_target_bytes(kind, data[:cut], workdir)
            if outcome == "ok" and data[cut:].strip() and kind not in ENDLESS_FORMATS:
                raise Bug("read as a whole file")
        except Bug as exc:
            raise Bug(f"cut at byte {cut} of {len(data)}: {exc}") from exc
