"""Bounded fuzz run of the readers at the file boundary (issue 6, "Also").

`io.read_contactors` gets random bytes and random mutations of a valid CSV; `io.read_target`
gets random mutations of the bytes of `sample_meshes/cylinder.msh` (Gmsh 2.2 ASCII), of an
ASCII STL and of `sample_meshes/plate.vtu` (zlib-compressed base64 VTU). The only allowed
outcomes are a valid result (the shapes documented on `Target` and `Contactors`) or an
`io.ReadError` whose message is one line naming the file. Anything else (an IndexError from
meshio, a SystemExit, text printed on stdout where CSV results go) is a bug.

The strategies live here so that `benchmarks/fuzz_readers.py` runs the same ones for longer.
"""
from __future__ import annotations

import contextlib
import io as _io
import os
import tempfile
from pathlib import Path

import meshio
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from diffsurf_cli import io

SAMPLES = Path(__file__).resolve().parent.parent / "sample_meshes"

#: examples per target in the test suite (the benchmark script runs thousands).
EXAMPLES = 150


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

#: target seeds by extension: (extension, bytes).
TARGET_SEEDS = {
    "msh": (".msh", (SAMPLES / "cylinder.msh").read_bytes()),
    "stl": (".stl", _ascii_stl()),
    "vtu": (".vtu", (SAMPLES / "plate.vtu").read_bytes()),
}

#: text that tends to break number parsers and tokenisers.
SPECIAL_TOKENS = [b"nan", b"-inf", b"inf", b"1e400", b"-0", b"0x10", b"1_000", b"", b" ", b",",
                  b",,", b"\"", b"'", b"#", b"\r", b"\r\n", b"\t", b"\x00", b"\xff\xfe",
                  b"\xef\xbb\xbf", "é".encode(), "\u2212".encode(), "１".encode(),
                  "\u00a0".encode(), b"9" * 400, b"1." + b"1" * 2000, b"-" * 50, b"e",
                  b"$EndNodes", b"$Elements", b"endsolid", b"facet normal 0 0 1", b"</Piece>",
                  b"4294967296", b"-1", b"2147483648", b"99999999999999999999"]


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


@st.composite
def csv_edits(draw) -> bytes:
    """CSV-specific damage to the seed: extra commas, long numbers, unicode, line ends."""
    lines = CSV_SEED.split(b"\n")
    i = draw(st.integers(0, len(lines) - 1))
    kind = draw(st.sampled_from(["extra-comma", "long-number", "unicode", "crlf", "field"]))
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


def target_inputs(kind: str):
    """Mutations of the seed file of ``kind`` ('msh', 'stl' or 'vtu')."""
    return mutated(TARGET_SEEDS[kind][1])


# -------------------------------------------------------------------------------------------
# oracles
# -------------------------------------------------------------------------------------------


class Bug(AssertionError):
    """A reader outcome that is neither a valid result nor a clean ReadError."""


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
    if len(c.passthrough) != len(p):
        raise Bug(f"{len(c.passthrough)} pass-through rows for {len(p)} points")
    width = len(c.passthrough_names)
    if any(len(row) != width for row in c.passthrough):
        raise Bug("pass-through row of the wrong width")


def run_reader(reader, checker, path: str) -> str:
    """Call ``reader(path)``; return 'ok' or 'error', raise Bug on any other outcome."""
    out = _io.StringIO()
    try:
        with contextlib.redirect_stdout(out):
            result = reader(path)
    except io.ReadError as exc:
        check_read_error(exc, path)
        outcome = "error"
    except Exception as exc:  # noqa: BLE001 - the point of the fuzz run
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


def read_target_bytes(kind: str, data: bytes, directory: str) -> str:
    path = os.path.join(directory, "target" + TARGET_SEEDS[kind][0])
    Path(path).write_bytes(data)
    return run_reader(io.read_target, check_target, path)


# -------------------------------------------------------------------------------------------
# tests
# -------------------------------------------------------------------------------------------

FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None,
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


@pytest.mark.parametrize("kind", sorted(TARGET_SEEDS))
def test_fuzz_read_target(kind, workdir):
    @FUZZ
    @given(data=target_inputs(kind))
    def run(data):
        read_target_bytes(kind, data, workdir)

    run()
