"""Tests of diffsurf_cli.io.table (contactor tables in, result tables out, through polars),
against the slow, obvious reader in reference_table.py and float() for every number."""
import contextlib
import io as _io
import os
import struct
import tempfile
from unittest import mock

import numpy as np
import polars as pl
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import reference_table as ref
from diffsurf_cli import io as dio
from diffsurf_cli.io import table

STATUS = ("open", "contact", "penetration", "outside", "failed")
SETTINGS = settings(max_examples=300, deadline=None, database=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def same_floats(a, b) -> bool:
    """Bit for bit, except that every NaN equals every NaN of the same sign."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape or not np.array_equal(np.isnan(a), np.isnan(b)):
        return False
    if not np.array_equal(np.signbit(a), np.signbit(b)):
        return False
    keep = ~np.isnan(a)
    return np.array_equal(a[keep].view(np.uint64), b[keep].view(np.uint64))


def read_with(data: bytes, name: str, fast: bool):
    """``table.read_csv`` with its plain-file fast path on or off (off: `_read_plain` cannot
    tell, so the full reader runs): Contactors or the message."""
    off = contextlib.nullcontext() if fast else mock.patch.object(table, "_read_plain",
                                                                   return_value=None)
    with off:
        try:
            return dio.Contactors(name, *table.read_csv(data, table.csv_start(data, name), name))
        except dio.ReadError as exc:
            return str(exc)


def assert_identical(a, b, what=""):
    """Two readings are the same Contactors (or the same message): points bit for bit, the
    same names, the same pass-through Series (dtype, name and values)."""
    if isinstance(a, str) or isinstance(b, str):
        assert a == b, what
        return
    assert same_floats(a.points, b.points) and a.points.dtype == b.points.dtype, what
    assert a.points.flags.c_contiguous and b.points.flags.c_contiguous, what
    assert a.passthrough_names == b.passthrough_names, what
    assert len(a.passthrough) == len(b.passthrough), what
    for s, t in zip(a.passthrough, b.passthrough):
        assert s.dtype == t.dtype and s.name == t.name and s.to_list() == t.to_list(), what


def read_text(text: str, name: str = "t.csv"):
    """The reader on ``text``: (points, names, rows), or the ReadError message. Every text is
    read twice, with the fast path (polars.read_csv on a plain file) and by the full reader
    alone, and the two readings must be identical."""
    data = text.encode("utf-8")
    fast, full = read_with(data, name, True), read_with(data, name, False)
    assert_identical(fast, full, text)
    if isinstance(fast, str):
        return fast
    return fast.points, fast.passthrough_names, fast.passthrough_rows()


def reference(text: str, name: str = "t.csv"):
    try:
        return ref.read_csv(text.lstrip("\ufeff") if text.startswith("\ufeff") else text, name)
    except dio.ReadError as exc:
        return str(exc)


def assert_same(text: str):
    got, want = read_text(text), reference(text)
    if isinstance(want, str) or isinstance(got, str):
        assert got == want, text
        return
    assert same_floats(got[0], want[0]), text
    assert got[1:] == want[1:], text


def test_whitespace_is_str_isspace():
    every = "".join(chr(c) for c in range(0x110000) if chr(c).isspace())
    assert table.WHITESPACE == every
    # the reader strips each of them from fields and lines, as str.strip does
    for ch in every:
        if ch == "\n":
            continue
        assert_same(f"id{ch},x,y,z\n{ch}a{ch},1{ch},{ch}2,3{ch}\n")


# --------------------------------------------------------------------------------------------
# the rules, case by case
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text", [
    "id,x,y,z,label\n007,0.1,2,-3e-5,  a b\n008, 1 ,2,3,c;d\n",
    " Z , name, X,Y\n3,p,1,2\n",
    "10,007,1,2,3\n11,008,4,5,6\n",
    "# contactors\n\nx,y,z\n  # indented comment, with commas\n1,2,3\n\n\r\n4,5,6\r\n",
    "# c\nx,y,z\n1,2,3\n\n4,5\n",
    "1,2,3\n4,5,6\n\n7,abc,9\n",
    "x,y,z\n1,2,3\n4,5\n6,abc,7\n",       # the first bad line is reported, whatever its fault
    "x,y,z\n1,abc,3\n4,5\n",
    "x,y,z\n1,1e999999,\u0662\n2,\u0661x,3\n",  # non-ASCII digits: float() reads them
    "x,y,z\n1,\u00a05\u00a0,3\n",
    "x,y,z\n1_000,2__0,3\n",
    "x,y,z\n-nan,nan,-inf\n+nan,Infinity,-iNf\n",
    "x,y,z\n1,2,\n",
    "x,y,z\n,,\n",
    "\u00a0x,y,z\u3000\n\u20281,2,3\u2029\n",
    "a,b,c\n1,2,3\n", "1,2\n", "", "\n\n", "# only\n", "x,y,z\n", "x,y,z\n\n# c\n",
    "x,y,z,x\n1,2,3,4\n",
    "x,y,z\n1,2,3",  # no final newline
    "x,y,z", "id,x,y,z\n# c",
    "x,y,z\n1,2,3\n\x1c\n",
    "ü,x,y,z\nÄ,1,2,3\n ä ,4,5,6\n",
    "x,y,z,t\n1,2,3,\u00a0\n",
    '"x","y","z"\n1,2,3\n',
    "x,y,z\n1,2,3\n\ufeff4,5,6\n",  # a byte order mark inside is a character like others
    # separators
    "x;y;z\n1;2;3\n", "id;x;y;z\na,b;1;2;3\n", "1;2;3\n4;5\n",
    "x\ty\tz\n1\t2\t3\n", "id\tx\ty\tz\n\t1\t2\t3\n", "a b\t1\t2\t3\n",
    "x y z\n1 2 3\n", "id   x  y z\n a  1.5\t2 3\r\n", "1 2 3\n4  5   6\n7 8\n",
    "x,y,z\n1;2;3\n",    # the first line decides (comma), the second is then short
    "1,5;2,5;3,5\n",     # decimal commas: not supported, and said so by the line
    "x y z\n1,2 3 4\n", "1 2\n", "a;b\n",
])
def test_reader_matches_reference_on_known_cases(text):
    assert_same(text)


def test_separators_sniffed():
    for text, _sep in [("x;y;z\n1;2;3\n", ";"), ("x\ty\tz\n1\t2\t3\n", "\t"),
                      ("x y  z\n1 2 3\n", None), ("x,y,z\n1,2,3\n", ",")]:
        points, names, rows = read_text(text)
        np.testing.assert_array_equal(points, [[1, 2, 3]])
    # a pass-through field may hold another separator
    points, names, rows = read_text("name;x;y;z\nA, B;1;2;3\nC;4;5;6\n")
    assert names == ["name"] and rows == [["A, B"], ["C"]]
    # tab: empty fields are fields; whitespace: runs of spaces and tabs are one separator
    assert read_text("id\tx\ty\tz\n\t1\t2\t3\n")[2] == [[""]]
    assert read_text("id x y z\n a \t 1   2 3\n")[2] == [["a"]]
    # the count error names the separator
    message = read_text("x;y;z\n1;2;3\n4;5\n")
    assert message == "t.csv, line 3: expected 3 semicolon separated columns (as on line 1), got 2"


def test_header_and_passthrough():
    points, names, rows = read_text("id,x,y,z,label\n007,0.1,2,-3e-5,  a b\n008, 1 ,2,3,c;d\n")
    assert names == ["id", "label"] and rows == [["007", "a b"], ["008", "c;d"]]
    np.testing.assert_array_equal(points, [[0.1, 2, -3e-5], [1, 2, 3]])
    assert read_text("10,007,1,2,3\n")[1:] == (["col1", "col2"], [["10", "007"]])


def test_errors_name_file_and_line():
    assert read_text("# c\nx,y,z\n1,2,3\n\n4,5\n", "p.csv") == (
        "p.csv, line 5: expected 3 comma separated columns (as on line 2), got 2")
    assert read_text("1,2,3\n4,5,6\n\n7,abc,9\n", "p.csv") == (
        "p.csv, line 4: expected a number for y, got 'abc'")
    assert read_text("x,y,z\n1,2,3\n4,5\n6,abc,7\n") == (
        "t.csv, line 3: expected 3 comma separated columns (as on line 1), got 2")
    assert read_text("a,b,c\n1,2,3\n").startswith("t.csv, line 1: header has no 'x' column")


def plain_taken(text: str) -> bool:
    """Whether the fast path (polars.read_csv alone) read ``text``."""
    taken = []
    original = table._read_plain

    def spy(*args):
        taken.append(original(*args))
        return taken[-1]

    table._read_plain = spy
    try:
        read_text(text)
    finally:
        table._read_plain = original
    return bool(taken) and taken[0] is not None


@pytest.mark.parametrize("text", [
    "x,y,z\n1,2,3\n", "x,y,z\n1,2,3", "1,2,3\n4,5,6\n", "\ufeffx,y,z\n1,2,3\n",
    "\ufeff1,2,3\n", "# made by\n#  a tool\nid;x;y;z\r\n7;1;2;3\r\n", "x\ty\tz\n1\t2\t3\n",
    "x,y,z\n1,2,3\n\n\n\r\n", '"x","y","z"\n1,2,3\n',  # quotes in the header only
    "x,y,z\n-nan,+nan,NaN\n-inf,Infinity,1e999\n5e-324,-0.0,.5\n", "Z,x,y\n1,2,3\n",
    "7,8,1,2,3\n", "id,x,y,z\n,1,2,3\n", "x , y , z\n1,2,3\n", "é,x,y,z\nü,1,2,3\n",
])
def test_plain_files_take_the_fast_path(text):
    assert plain_taken(text)
    assert_same(text)


@pytest.mark.parametrize("text", [
    "id,x,y,z\n a,1,2,3\n",          # a text field the full reader strips
    "id,x,y,z\na\u00a0,1,2,3\n",
    "x,y,z\n1,2,3\n# later\n4,5,6\n",  # a comment among the rows
    "id,x,y,z\n#a,1,2,3\n",
    "x,y,z\n1,2,3\n\n4,5,6\n",        # a blank line among the rows
    "x,y,z\n1,2,3 \n", "x,y,z\n1_0,2,3\n", "x,y,z\n\u0661,2,3\n",
    "x,y,z,id\n1,2,3,a\n4,5,6\n",      # a short row ending in a text column
    "x,y,z\n1,2\n", "x,y,z\n1,2,3,4\n", "x y z\n1 2 3\n",
    "x,y,z\n\ufeff1,2,3\n",             # a byte order mark polars might drop
    "id,x,y,z,label\n007,0.1,2,-3e-5,a\"b\n008,1,2,3,\n",  # a quote in the rows
])
def test_other_files_take_the_full_reader(text):
    assert not plain_taken(text)
    assert_same(text)


PLAIN_NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda v: f"{v:.17e}"),
    st.integers(1, 2**52 - 1).map(lambda m: repr(m * 5e-324)),
    st.sampled_from(["-nan", "+nan", "-Infinity", "+inf", "1e400", ".5", "5.", "9" * 400,
                     "2.4703282292062327e-324", "1.7976931348623158e308"]),
)
#: pass-through fields of a file without a header (its first row must be all numbers)
ID = st.integers(-99, 10**6).map(str)
PLAIN_TEXT = st.text(alphabet="abc_-:\"'#é0123456789.", max_size=6)


@st.composite
def plain_files(draw):
    """Files the fast path is for (plain numbers, an optional header, leading comments, CRLF,
    a final line end or not), now and then with one flaw that sends them to the full reader."""
    sep = draw(st.sampled_from([",", ";", "\t"]))
    npass = draw(st.integers(0, 2))
    order = draw(st.permutations(["x", "y", "z"] + [f"p{j}" for j in range(npass)]))
    header = draw(st.booleans())
    if not header:
        order = [f"p{j}" for j in range(npass)] + ["x", "y", "z"]
    out = [draw(st.sampled_from(["# comment, with; commas", "#"]))
           for _ in range(draw(st.integers(0, 2)))]
    if header:
        out.append(sep.join(order))
    rows = [[draw(PLAIN_NUMBER) if n in "xyz" else draw(PLAIN_TEXT if header else ID)
             for n in order] for _ in range(draw(st.integers(1, 8)))]
    # one file in five has a flaw, in one of its rows
    flaw = draw(st.sampled_from(["none"] * 16 + ["short", "long", "token", "space"]))
    cells = rows[draw(st.integers(0, len(rows) - 1))]
    if flaw == "short":
        cells.pop()
    elif flaw == "long":
        cells.append("1")
    elif flaw == "token":  # what float() reads and polars does not, or neither reads
        cells[order.index("x")] = draw(st.sampled_from(["1_0", "0x1", "1e", " 1", "1 "]))
    elif flaw == "space":  # a field to strip
        cells[0] = draw(st.sampled_from([" ", "\t", "\u00a0", "\u3000"])) + cells[0]
    for r in rows:
        if flaw != "space" and r[0].startswith("#"):
            r[0] = "a" + r[0]  # not a comment line
    out += [sep.join(r) for r in rows]
    end = draw(st.sampled_from(["\n", "\r\n"]))
    text = draw(st.sampled_from(["", "\ufeff"])) + end.join(out) + draw(
        st.sampled_from(["", end, end + end]))
    # a quote in the rows: read line by line (quoted fields)
    return text, flaw == "none" and not any('"' in c for r in rows for c in r)


@SETTINGS
@given(plain_files())
def test_fast_path_matches_reference_on_plain_files(case):
    text, flawless = case
    assert_same(text)  # read_text: fast path and full reader identical, and the reference
    # and the fast path is not idle: every file without a flaw takes it
    assert plain_taken(text) or not flawless


@pytest.mark.slow
def test_same_rows_and_errors_for_every_block_size(monkeypatch):
    # polars gets the text in blocks of lines: every split gives the same rows, and the same
    # first bad line, numbered from the start of the file
    rng = np.random.default_rng(3)
    lines = ["# head", "id,x,y,z"]
    for i in range(300):
        if i % 7 == 0:
            lines.append("# comment, with, commas")
        if i % 11 == 0:
            lines.append("   ")
        x, y, z = rng.normal(size=3).tolist()
        lines.append(f"p{i}, {x!r},{y:.3e}\t,{z:.17g}\r")
    good = "\n".join(lines) + "\n"
    variants = [good, good.replace("\np123,", "\np123,1,", 1),
                good.replace("\np200,", "\np200,\u0661", 1).replace("\np250,", "\np250,x", 1),
                good.replace("\np50,", "\np50,-nan,1_0,", 1).replace(",", ";")]
    want = [reference(t) for t in variants]
    for block in (1, 2, 50, 1000, 1 << 25):
        monkeypatch.setattr(table, "READ_BLOCK", block)
        for text, expected in zip(variants, want):
            got = read_text(text)
            if isinstance(expected, str):
                assert got == expected
            else:
                assert same_floats(got[0], expected[0]) and got[1:] == expected[1:]
    assert isinstance(want[0], tuple) and isinstance(want[2], str)


# --------------------------------------------------------------------------------------------
# generated files against the reference
# --------------------------------------------------------------------------------------------

FIELD = st.one_of(
    st.sampled_from(["1", "-2.5", " 3e-3 ", "nan", "-nan", "-inf", "1e400", "1_0", ".5", "5.",
                     "abc", "", " ", "x", "Y", " z", "id", "\u00a0", "é", "7\u00a0", "\u0662",
                     "0x1", "1e", "#", "\t4\t", "\x1c5", "5\x1c", "\"x\"", "\u3000z\u3000",
                     "Infinity", "+.5", "1.e5", "1e+5", "infinit", "nan(1)", "0b1", "1d5"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet="0123456789.-+eE_ ", max_size=6),
)
SEP = st.sampled_from([",", ";", "\t", " ", "  "])
END = st.sampled_from(["\n", "\r\n", " \n", "\x1c\n"])


@st.composite
def generated_files(draw):
    sep = draw(SEP)
    line = st.one_of(
        st.lists(FIELD, min_size=1, max_size=6).map(sep.join),
        st.sampled_from(["", "   ", "# comment, with; commas", "  #x", "\r", "\u00a0", "\x1c"]),
    )
    header = draw(st.sampled_from(["", "x,y,z", "id,X, y ,Z,label", "Z,x,y", "x,x,y,z"]))
    header = header.replace(",", sep) + "\n" if header else ""
    lines = draw(st.lists(st.tuples(line, END), max_size=12))
    return header + "".join(a + b for a, b in lines)


@pytest.mark.slow
@SETTINGS
@given(generated_files())
def test_reader_matches_reference_on_generated_files(text):
    assert_same(text)


NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(allow_nan=False, allow_infinity=False).map(lambda v: f"{v:.17e}"),
    st.integers(1, 2**52 - 1).map(lambda m: repr(m * 5e-324)),  # every subnormal
    st.sampled_from(["1", " -2.5", "3e-3 ", "nan", "-Infinity", "1e400", "1_0", ".5", "5.",
                     "\u00a07", "\u0662", "5e-324", "0.1000000000000000055511151231257827",
                     "2.4703282292062327e-324", "2.4703282292062328e-324",
                     "1.7976931348623157e308", "1.7976931348623158e308", "9" * 400,
                     "0." + "0" * 330 + "1"]),
)
TEXT = st.text(alphabet="abcé _-;:\"'\t\u00a0\u3000\x1c0123456789,", max_size=8)
SPACE = st.sampled_from(["", " ", "\t", "\u00a0", "\u2003", "\x1c", "\r"])


@st.composite
def csv_files(draw):
    """Mostly valid files: a header (or not), rows of the right width, comments, blank lines,
    odd spaces and line ends, any separator; now and then a damaged row."""
    sep = draw(st.sampled_from([",", ";", "\t"]))
    npass = draw(st.integers(0, 3))
    order = draw(st.permutations(["x", "y", "z"] + [f"p{j}" for j in range(npass)]))
    header = draw(st.booleans())
    out = []
    if header:
        names = [draw(st.sampled_from([n, n.upper(), f" {n} ", f'"{n}"'])) for n in order]
        out.append(sep.join(names))
    for _ in range(draw(st.integers(0, 8))):
        kind = draw(st.sampled_from(["row"] * 6 + ["comment", "blank", "damaged"]))
        if kind == "comment":
            out.append(draw(SPACE) + "# note, with , commas; and ;")
        elif kind == "blank":
            out.append(draw(SPACE))
        else:
            cells = [draw(NUMBER) if n in "xyz" else draw(TEXT).replace(sep, "")
                     for n in order]
            if not header:  # without a header only the last three are coordinates
                cells = [draw(TEXT).replace(sep, "") for _ in range(npass)] + [
                    draw(NUMBER) for _ in range(3)]
            if kind == "damaged":
                cells = draw(st.sampled_from([cells[:-1], cells + ["1"], cells[:1] + ["abc"]
                                              + cells[2:]]))
            out.append(draw(SPACE) + sep.join(cells) + draw(SPACE))
    end = draw(st.sampled_from(["\n", "\r\n"]))
    return end.join(out) + draw(st.sampled_from(["", end]))


@pytest.mark.slow
@SETTINGS
@given(csv_files())
def test_reader_matches_reference_on_mostly_valid_files(text):
    assert_same(text)


# --------------------------------------------------------------------------------------------
# quoted fields (RFC 4180, on one line)
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("text,points,rows", [
    ('x,y,z\n"30","1",2\n', [[30, 1, 2]], [[]]),                     # quoted numbers
    ('"30";" 1 ";2\n', [[30, 1, 2]], [[]]),                            # no header, semicolons
    ('id,x,y,z\n"a,b",1,2,3\n', [[1, 2, 3]], [["a,b"]]),               # a separator inside
    ('id,x,y,z\n"say ""hi""",1,2,3\n', [[1, 2, 3]], [['say "hi"']]),   # doubled quotes
    ('id,x,y,z\n  "  padded " ,1,2,3\n', [[1, 2, 3]], [["  padded "]]),  # kept as quoted
    ('id,x,y,z\nab"c,1,2,3\n', [[1, 2, 3]], [['ab"c']]),               # a quote inside: text
    ('id x y z\n"a b" 1 2 3\n', [[1, 2, 3]], [["a b"]]),               # whitespace separated
    ('"id","x","y","z"\r\n"",1,2,3\r\n', [[1, 2, 3]], [[""]]),
    ('id,x,y,z\n"two\n# lines",1,2,3\n4,5,6,7\n', [[1, 2, 3], [5, 6, 7]],  # a line end inside
     [["two\n# lines"], ["4"]]),
])
def test_quoted_fields(text, points, rows):
    """Issue 22, item 5: '"30"' was 'expected a number', '"a,b"' a column-count error."""
    got = read_text(text)
    assert not isinstance(got, str), got
    np.testing.assert_array_equal(got[0], points)
    assert got[2] == rows
    assert_same(text)


@pytest.mark.parametrize("text,message", [
    ('id,x,y,z\n1,2,3,4\n"a,5,6,7\n5,6,7,8\n',
     "t.csv, line 3: a quoted field does not close (unbalanced quote)"),
    ('id,x,y,z\n"a"b,5,6,7\n', "t.csv, line 2: text after the closing quote of a field"),
    ('"x,y,z\n1,2,3\n', "t.csv, line 1: a quoted field does not close (unbalanced quote)"),
    ('x,y,z\n"1\n2",3,4\n', "t.csv, line 2: expected a number for x, got '1\\n2'"),
    ('x,y,z\n"a",2,3\n', "t.csv, line 2: expected a number for x, got 'a'"),
])
def test_broken_quotes_are_refused_with_their_line(text, message):
    """An unbalanced quote was passed through into output pandas and polars could not read."""
    assert read_text(text) == message
    assert reference(text) == message


QUOTED = st.one_of(
    NUMBER, TEXT,
    st.text(alphabet='ab ,;\t"', max_size=6).map(lambda t: '"' + t.replace('"', '""') + '"'),
    st.sampled_from(['"1"', '" 2.5 "', '""', '"a""b"', '"x,y"', '"unclosed', '"a"b', 'a"b',
                     ' "c" ', '"nan"']),
)


@st.composite
def quoted_files(draw):
    """Files with quoted fields anywhere: numbers, text with separators and doubled quotes
    inside, blanks around them; now and then a broken one."""
    sep = draw(st.sampled_from([",", ";", "\t", " "]))
    npass = draw(st.integers(0, 2))
    order = ["x", "y", "z"] + [f"p{j}" for j in range(npass)]
    out = [sep.join(draw(st.sampled_from([n, f'"{n}"', f' "{n}" '])) for n in order)]
    for _ in range(draw(st.integers(1, 6))):
        out.append(sep.join(draw(QUOTED) for _ in order))
    return draw(st.sampled_from(["\n", "\r\n"])).join(out) + "\n"


@pytest.mark.slow
@SETTINGS
@given(quoted_files())
def test_reader_matches_reference_on_quoted_files(text):
    assert_same(text)


@pytest.mark.parametrize("sep", [",", ";", "\t"])
def test_simply_quoted_rows_are_read_by_polars(sep, monkeypatch):
    """R's write.csv quotes every text field: such rows are read by polars' own quoting (a
    1M-row file: 4.2 s in Python, 0.96 s so), with the same result as the rules; rows with
    blanks around a quote, or a quote inside a field, are left to Python."""
    lines = [sep.join(['"id"', '"x"', '"y"', '"z"', '"label"'])]
    lines += [sep.join([f'"n{i}"', str(i), "2.5", "-1e-3", f'"a{sep}b ""{i}"" "'])
              for i in range(50)]
    lines += [sep.join(['"odd" ', "1", "2", "3", "x"]), sep.join(['a"b', "4", "5", "6", '""'])]
    text = "\n".join(lines) + "\n"
    settled = []
    original = table._quoted_by_polars

    def spy(rows, layout):
        out = original(rows, layout)
        settled.append(int(rows["q"].sum() - out["q"].sum()))
        return out

    monkeypatch.setattr(table, "_quoted_by_polars", spy)
    got = read_text(text)
    assert settled and settled[0] == 50, settled
    assert got[2][0] == ["n0", f'a{sep}b "0" '] and got[2][-2:] == [["odd", "x"], ['a"b', ""]]
    assert_same(text)


@pytest.mark.parametrize("first", [True, False])
def test_text_that_needs_quotes_makes_the_round_trip(tmp_path, first):
    """A pass-through column holding separators, quotes (an unbalanced one too), line ends,
    blanks at either end and a leading '#' (a Parquet input's text), through `diffsurf
    project` to CSV, reads back as itself with diffsurf, polars and pandas; so does a
    column name that needs quotes."""
    pd = pytest.importorskip("pandas")
    from samples import CYLINDER, run

    words = ["a,b", 'say "hi"', '"unclosed', "semi;colon", "  padded ", "#hash", "two\nlines",
             "plain", ""]
    xyz = np.column_stack([np.linspace(25, 40, len(words)), np.full(len(words), 20.5),
                           np.full(len(words), 2.5)])
    columns = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], 'odd "name", too': words}
    if first:
        columns = {'odd "name", too': words, **{k: columns[k] for k in "xyz"}}
    pl.DataFrame(columns).write_parquet(tmp_path / "in.parquet")
    out = tmp_path / "out.csv"
    done = run("project", CYLINDER, tmp_path / "in.parquet", "-o", out, "-q")
    assert done.exit_code == 0, done.stderr
    back = dio.read_contactors(str(out))
    assert back.passthrough_names[0] == 'odd "name", too'
    assert [r[0] for r in back.passthrough_rows()] == words
    np.testing.assert_array_equal(back.points, xyz)
    polars = pl.read_csv(out, infer_schema=False)  # (it keeps a header name's "" doubled)
    assert polars.to_series(0).fill_null("").to_list() == words  # pass-through columns first
    pandas = pd.read_csv(out, dtype=str, keep_default_na=False)
    assert pandas['odd "name", too'].tolist() == words
    assert polars["status"].to_list() == pandas["status"].tolist()


# --------------------------------------------------------------------------------------------
# files and stdin
# --------------------------------------------------------------------------------------------


def test_file_and_stdin_agree(tmp_path):
    text = "\ufeffid;x;y;z\r\n1;0.5;2;3\r\n2;\u00a01e-3 ;nan;4\r\n"
    f = tmp_path / "p.csv"
    f.write_bytes(text.encode("utf-8"))
    a = dio.read_contactors(str(f))
    raw = _io.TextIOWrapper(_io.BytesIO(text.encode("utf-8")), encoding="utf-8")
    b = dio.read_contactors("-", stdin=raw)
    c = dio.read_contactors("-", stdin=_io.StringIO(text))
    for other in (b, c):
        assert other.points.tobytes() == a.points.tobytes()
        assert other.passthrough_rows() == a.passthrough_rows() == [["1"], ["2"]]


def test_stdin_bytes_not_utf8():
    raw = _io.TextIOWrapper(_io.BytesIO(b"x,y,z\n1,2,\xff\n"), encoding="utf-8")
    with pytest.raises(dio.ReadError, match=r"^<stdin>: not a text CSV file \(bytes are not "
                                            r"UTF-8 text\)$"):
        dio.read_contactors("-", stdin=raw)


def test_stdin_all_leading_byte_order_marks_dropped():
    c = dio.read_contactors("-", stdin=_io.StringIO("\ufeff\ufeffx,y,z\n1,2,3\n"))
    np.testing.assert_array_equal(c.points, [[1, 2, 3]])


def test_parquet_is_not_read_from_stdin(tmp_path):
    # '-' is CSV text: Parquet bytes on stdin are refused as binary
    path = tmp_path / "p.parquet"
    pl.DataFrame({"x": [1.0], "y": [2.0], "z": [3.0]}).write_parquet(path)
    raw = _io.TextIOWrapper(_io.BytesIO(path.read_bytes()), encoding="utf-8")
    with pytest.raises(dio.ReadError, match="^<stdin>: not a text CSV file"):
        dio.read_contactors("-", stdin=raw)


# --------------------------------------------------------------------------------------------
# writing, and the round trip
# --------------------------------------------------------------------------------------------


def special_floats():
    rng = np.random.default_rng(20260521)
    tiny = 5e-324
    family = [0.0, -0.0, np.inf, -np.inf, np.nan, tiny, -tiny, 1e308, -1e308,
              np.finfo(float).max, np.finfo(float).tiny, np.nextafter(np.finfo(float).tiny, 0),
              0.1, 0.2, 0.3, 1 / 3, 1e16, 9999999999999998.0, 1e15, 123456789012345678.0,
              1e-4, 9.999999999999999e-05, 1e-5, 1e22, 1e23, 2.2250738585072014e-308]
    family += [10.0**k for k in range(-323, 309)] + [2.0**k for k in range(-1074, 1024)]
    subnormal = rng.integers(1, 2**52, size=3000, dtype=np.uint64).view(np.float64)
    random_bits = rng.integers(0, 2**64, size=200_000, dtype=np.uint64).view(np.float64)
    return np.concatenate([family, subnormal, -subnormal, random_bits])


def write_text(passthrough_names, passthrough, columns, labels=None, separator=",") -> str:
    """The writer's text on a stream; written to a file name (polars writes it itself when it
    can) it must be the same bytes."""
    buf = _io.BytesIO()
    table.write_csv(buf, passthrough_names, passthrough, columns, labels or {}, separator)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "t.csv")
        table.write_csv(path, passthrough_names, passthrough, columns, labels or {}, separator)
        with open(path, "rb") as fh:
            assert fh.read() == buf.getvalue()
    return buf.getvalue().decode("utf-8")


def test_file_names_written_by_polars_alone(monkeypatch):
    # the one-call path is taken (unique names, nothing to quote, not too many rows), and the
    # batched one for the rest: both give the bytes write_text compares
    calls = []
    original = pl.DataFrame.write_csv
    monkeypatch.setattr(pl.DataFrame, "write_csv",
                        lambda self, file=None, **kw: calls.append(kw["include_header"])
                        or original(self, file, **kw))
    x = np.array([0.1, np.nan, -0.0, 1e300])
    rows = table.text_columns([["a"], ["b"], ["c"], ["d"]], 1)
    assert write_text(["id"], rows, {"x": x}) == "id,x\na,0.1\nb,NaN\nc,-0.0\nd,1e+300\n"
    assert calls == [False, True]
    calls.clear()
    write_text(["x"], rows, {"x": x})  # two columns named x: batched
    assert calls == [False, False]
    calls.clear()
    monkeypatch.setattr(table, "WHOLE_ROWS", 3)
    write_text(["id"], rows, {"x": x})
    assert calls == [False, False]


def test_tab_separated_text():
    rows = table.text_columns([["a,b"], ["c\td"]], 1)
    text = write_text(["id"], rows, {"x": np.array([1.5, 2.0])}, separator="\t")
    assert text == 'id\tx\na,b\t1.5\n"c\td"\t2.0\n'  # a tab in a field is quoted, a comma not


def test_floats_written_read_back_bit_for_bit():
    values = special_floats()
    text = write_text([], [], {"v": values})
    lines = text.split("\n")
    assert lines[0] == "v" and lines[-1] == ""
    # float() is the reference reader of every field
    back = np.array([float(t) for t in lines[1:-1]])
    assert same_floats(back[~np.isnan(values)], values[~np.isnan(values)])
    assert np.isnan(back[np.isnan(values)]).all()
    assert set(t for t, v in zip(lines[1:-1], values) if np.isnan(v)) == {"NaN"}


@SETTINGS
@given(st.lists(st.floats(allow_nan=False, allow_infinity=True, allow_subnormal=True),
                min_size=1, max_size=30))
def test_floats_round_trip_hypothesis(values):
    values = np.array(values, dtype=np.float64)
    text = write_text([], [], {"x": values, "y": values[::-1].copy(), "z": -values})
    got = read_text(text)
    assert same_floats(got[0], np.column_stack([values, values[::-1], -values]))


def test_write_matches_reference_fields():
    rng = np.random.default_rng(11)
    n = 3000
    cols = {
        "x": rng.normal(size=n), "raw": rng.integers(0, 2**64, n, dtype=np.uint64).view(float),
        "f32": rng.normal(size=n).astype(np.float32), "status": rng.integers(0, 5, n),
        "i": rng.integers(-2**63, 2**63 - 1, n, dtype=np.int64, endpoint=True),
        "b": rng.integers(0, 2, n).astype(bool), "u8": rng.integers(0, 256, n).astype(np.uint8),
    }
    cols["i"][:3] = [-2**63, 2**63 - 1, 0]
    rows = [[f"id{i}", "é ü" if i % 3 else ""] for i in range(n)]
    text = write_text(["id", "note"], table.text_columns(rows, 2), cols, {"status": STATUS})
    lines = text.split("\n")
    assert lines[0] == "id,note,x,raw,f32,status,i,b,u8" and lines[-1] == ""
    fields = [line.split(",") for line in lines[1:-1]]
    assert [f[:2] for f in fields] == rows
    for k, (name, v) in enumerate(cols.items(), 2):
        got = [f[k] for f in fields]
        if name == "status":
            assert got == [STATUS[c] for c in v]
        elif v.dtype.kind == "f":  # float32 written as the float64 it is
            back = np.array([float(t) for t in got])
            assert same_floats(back, v.astype(np.float64)) or np.isnan(v).any()
            keep = ~np.isnan(v)
            assert same_floats(back[keep], v.astype(np.float64)[keep])
        else:
            assert got == [str(int(x)) for x in v.tolist()]


def test_write_batches_join_up(monkeypatch):
    monkeypatch.setattr(table, "WRITE_BATCH", 7)
    n = 50
    x = np.arange(n) / 3
    text = write_text(["id"], table.text_columns([[str(i)] for i in range(n)], 1),
                      {"x": x, "status": np.arange(n) % 5}, {"status": STATUS})
    monkeypatch.setattr(table, "WRITE_BATCH", 1 << 17)
    assert text == write_text(["id"], table.text_columns([[str(i)] for i in range(n)], 1),
                              {"x": x, "status": np.arange(n) % 5}, {"status": STATUS})
    assert text.count("\n") == n + 1


def test_write_text_stream_same_as_bytes():
    x = np.array([0.1, np.nan, -0.0])
    buf = _io.StringIO()
    table.write_csv(buf, ["id"], table.text_columns([["a"], ["b"], ["c"]], 1), {"x": x}, {})
    assert buf.getvalue() == write_text(["id"], table.text_columns([["a"], ["b"], ["c"]], 1),
                                        {"x": x}) == "id,x\na,0.1\nb,NaN\nc,-0.0\n"


def test_fields_with_a_comma_are_quoted():
    # only a non-comma input can give one; the output is then RFC 4180 CSV
    rows = [["A, B", 'say "hi"'], ["C", "D"]]
    text = write_text(["name", "note"], table.text_columns(rows, 2), {"x": np.array([1.0, 2.0])})
    import csv
    assert list(csv.reader(_io.StringIO(text))) == [["name", "note", "x"], rows[0] + ["1.0"],
                                                    rows[1] + ["2.0"]]
    # a field with quotes in it is quoted too (doubled inside), so it reads back as itself
    text = write_text(["q"], table.text_columns([['"x"']], 1), {"x": np.array([1.0])})
    assert text == 'q,x\n"""x""",1.0\n'
    # and fields that need nothing are written as they are
    text = write_text(["q"], table.text_columns([["x y"]], 1), {"x": np.array([1.0])})
    assert text == "q,x\nx y,1.0\n"


def test_csv_round_trip_through_files(tmp_path):
    rng = np.random.default_rng(2)
    n = 5000
    pts = rng.integers(0, 2**64, (n, 3), dtype=np.uint64).view(np.float64)
    pts[:8, 0] = [0.0, -0.0, np.inf, -np.inf, 5e-324, -5e-324, 1e308, 1e-308]
    ids = [[f"{i:06d}", "Stütze" if i % 2 else " "] for i in range(n)]
    c = dio.Contactors("in.csv", pts, ["id", "label"], ids)
    out = tmp_path / "out.csv"
    dio.write_result(str(out), c, {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2],
                                   "status": np.arange(n) % 5}, labels={"status": STATUS})
    back = dio.read_contactors(str(out))
    nan = np.isnan(pts)
    assert same_floats(back.points[~nan], pts[~nan]) and np.isnan(back.points[nan]).all()
    assert back.passthrough_names == ["id", "label", "status"]
    # a blank label is quoted, so it reads back as itself (issue 22, item 5)
    assert back.passthrough_rows() == [[a, b, STATUS[i % 5]] for i, (a, b) in enumerate(ids)]


# --------------------------------------------------------------------------------------------
# Parquet
# --------------------------------------------------------------------------------------------


def test_parquet_round_trip(tmp_path):
    values = special_floats()[:20000]
    n = len(values)
    pts = np.column_stack([values, values[::-1], -values])
    c = dio.Contactors("in.csv", pts, ["id"], [[f"{i}"] for i in range(n)])
    cols = {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2], "gap": values,
            "status": np.arange(n) % 5, "iterations": np.arange(n, dtype=np.int64)}
    out = tmp_path / "out.parquet"
    dio.write_result(str(out), c, cols, labels={"status": STATUS})
    back = dio.read_contactors(str(out))
    assert back.points.tobytes() == pts.tobytes()  # NaN payloads too: no text in between
    assert back.passthrough_names == ["id", "gap", "status", "iterations"]
    frame = pl.read_parquet(out)
    assert frame["gap"].to_numpy().tobytes() == values.tobytes()
    assert frame["status"].cast(pl.String).to_list() == [STATUS[i % 5] for i in range(n)]
    # a CSV's integer column stays integer (issue 22, item 2)
    assert frame["iterations"].dtype == pl.Int64 and frame["id"].dtype == pl.Int64
    assert frame["id"].to_list() == list(range(n))
    # the same words as the CSV output
    csv_out = tmp_path / "out.csv"
    dio.write_result(str(csv_out), c, cols, labels={"status": STATUS})
    again = dio.read_contactors(str(csv_out))
    assert [r[2] for r in again.passthrough_rows()] == frame["status"].cast(pl.String).to_list()


def test_parquet_in_keeps_types_to_parquet_and_csv(tmp_path):
    src = tmp_path / "in.parquet"
    pl.DataFrame({"ID": [7, 8], "X": [0.5, 1.0], "y": [2.0, 3.0], "Z": [1, 2],
                  "tag": ["a, b", None], "w": [1.5, None]}).write_parquet(src)
    c = dio.read_contactors(str(src))
    np.testing.assert_array_equal(c.points, [[0.5, 2, 1], [1, 3, 2]])
    assert c.passthrough_names == ["ID", "tag", "w"]
    out = tmp_path / "out.parquet"
    dio.write_result(str(out), c, {"gap": np.array([0.1, np.nan])})
    frame = pl.read_parquet(out)
    assert frame.columns == ["ID", "tag", "w", "gap"]
    assert frame["ID"].dtype == pl.Int64 and frame["ID"].to_list() == [7, 8]
    assert frame["tag"].to_list() == ["a, b", None]
    # to CSV: nulls are empty fields, a comma makes the file quoted (RFC 4180: "" is empty)
    text = _io.StringIO()
    dio.write_result("-", c, {"gap": np.array([0.1, np.nan])}, stdout=text)
    assert text.getvalue() == 'ID,tag,w,gap\n7,"a, b",1.5,0.1\n8,"","",NaN\n'
    import csv
    assert list(csv.reader(_io.StringIO(text.getvalue())))[2] == ["8", "", "", "NaN"]


def test_parquet_refuses_duplicate_names(tmp_path):
    c = dio.Contactors("in.csv", np.zeros((2, 3)), ["gap"], [["a"], ["b"]])
    out = tmp_path / "out.parquet"
    with pytest.raises(dio.WriteError, match=r"out\.parquet: two columns named 'gap'"):
        dio.write_result(str(out), c, {"gap": np.zeros(2)})
    assert not out.exists()
    dio.write_result(str(tmp_path / "out.csv"), c, {"gap": np.zeros(2)})  # CSV holds both


@pytest.mark.parametrize("frame,message", [
    ({"a": [1.0], "y": [1.0], "z": [1.0]}, r"p\.parquet: no 'x' column, expected a Parquet"),
    ({"x": [1.0], "X": [1.0], "y": [1.0], "z": [1.0]}, r"more than one 'x' column"),
    ({"x": ["1"], "y": [1.0], "z": [1.0]}, r"column 'x' holds String, expected numbers"),
    ({"x": [], "y": [], "z": []}, r"p\.parquet: no data rows"),
])
def test_parquet_bad_input(tmp_path, frame, message):
    path = tmp_path / "p.parquet"
    pl.DataFrame(frame, schema={k: (pl.Float64 if k != "x" or not frame[k] or
                                    not isinstance(frame[k][0], str) else pl.String)
                                for k in frame}).write_parquet(path)
    with pytest.raises(dio.ReadError, match=message):
        dio.read_contactors(str(path))


def test_parquet_null_coordinates_are_failed_rows(tmp_path):
    # a missing value is a contactor without a position: a 'failed' row, not a failed file
    # (issue 13: on a cluster, one bad row must not fail its whole partition)
    path = tmp_path / "p.parquet"
    pl.DataFrame({"id": [1, 2, 3], "x": [1.0, None, 0.5], "y": [0.0, 2.0, None],
                  "z": [0.0, 0.0, 0.0]}).write_parquet(path)
    c = dio.read_contactors(str(path))
    assert np.isnan(c.points[1, 0]) and np.isnan(c.points[2, 1]) and c.points[0, 0] == 1.0
    from diffsurf_cli.mls.surface import DiffuseSurface
    from diffsurf_cli.projection import FAILED
    from diffsurf_cli.testing.shapes import Plane

    nodes, faces = Plane().mesh(6)
    status = DiffuseSurface(nodes, [faces]).project(c.points).status
    assert status[1] == status[2] == FAILED and status[0] != FAILED


@pytest.mark.parametrize("data", [b"", b"x,y,z\n1,2,3\n", b"PAR1" + bytes(100),
                                  b"PAR1\x15\x00garbage PAR1"])
def test_parquet_not_parquet(tmp_path, data):
    path = tmp_path / "p.parquet"
    path.write_bytes(data)
    with pytest.raises(dio.ReadError, match=r"^\S*p\.parquet: (not a (valid )?Parquet file|"
                                            r"cannot read Parquet)") as exc:
        dio.read_contactors(str(path))
    assert "\n" not in str(exc.value)


def test_parquet_output_name_accepted(tmp_path):
    dio.check_output_path(str(tmp_path / "r.parquet"), False)
    dio.check_output_path(str(tmp_path / "r.PARQUET"), False)


def test_bits_helper():
    # the oracle's own check: same_floats tells -0.0 from 0.0 and NaN signs apart
    assert not same_floats([0.0], [-0.0])
    assert not same_floats([float("nan")], [-float("nan")])
    assert same_floats([struct.unpack("<d", struct.pack("<Q", 0x7FF8000000000001))[0]],
                       [float("nan")])


def test_csv_columns_keep_their_type_in_parquet_and_meshes(tmp_path):
    """Issue 22, item 2: a CSV's pass-through columns keep what they hold in Parquet and in a
    mesh's point data: integers as int64 (2^53 + 1 exactly), numbers as float64, codes with
    leading zeros and words as text (Parquet; a mesh holds numbers only)."""
    import meshio

    big = 2**53 + 1
    f = tmp_path / "points.csv"
    f.write_text("id,w,code,tag,x,y,z\n"
                 f"{big},1.5,007,a,0.1,0.2,0.3\n"
                 f"{big + 2},2,010,b,0.4,0.5,0.6\n")
    c = dio.read_contactors(str(f))
    cols = {"x": c.points[:, 0], "y": c.points[:, 1], "z": c.points[:, 2],
            "gap": np.array([0.1, 0.2])}
    dio.write_result(str(tmp_path / "o.parquet"), c, cols)
    frame = pl.read_parquet(tmp_path / "o.parquet")
    assert frame["id"].dtype == pl.Int64 and frame["id"].to_list() == [big, big + 2]
    assert frame["w"].dtype == pl.Float64 and frame["w"].to_list() == [1.5, 2.0]
    assert frame["code"].dtype == pl.String and frame["code"].to_list() == ["007", "010"]
    assert frame["tag"].dtype == pl.String
    # a mesh holds numbers only: the text column is refused, by name (issue 32, item 4)
    with pytest.raises(dio.WriteError, match="column 'tag' "):
        dio.write_result(str(tmp_path / "o.vtu"), c, cols)
    c = dio.Contactors(c.path, c.points, c.passthrough_names[:3], c.passthrough[:3])
    dio.write_result(str(tmp_path / "o.vtu"), c, cols)
    mesh = meshio.read(tmp_path / "o.vtu")
    assert mesh.point_data["id"].dtype.kind == "i"
    assert mesh.point_data["id"].tolist() == [big, big + 2]
    assert mesh.point_data["w"].tolist() == [1.5, 2.0]


@pytest.mark.parametrize("dtype", [pl.Categorical, "enum"])
def test_categorical_text_is_quoted_like_text(tmp_path, dtype):
    """A Parquet input's categorical text column (polars keeps Categorical and Enum through
    Parquet) is quoted where its fields need it, as a String column's are: it was written
    bare, so that 'a,b' made a row with a column too many for diffsurf, polars and pandas."""
    pd = pytest.importorskip("pandas")
    from samples import CYLINDER, run

    words = ["a,b", 'say "hi"', "  padded ", "semi;colon", "plain"]
    kind = pl.Enum(sorted(set(words))) if dtype == "enum" else dtype
    n = len(words)
    source = tmp_path / "in.parquet"
    pl.DataFrame({"tag": pl.Series(words, dtype=kind), "x": np.linspace(25, 40, n),
                  "y": np.full(n, 20.5), "z": np.full(n, 2.5)}).write_parquet(source)
    assert pl.read_parquet(source)["tag"].dtype == kind
    out = tmp_path / "out.csv"
    done = run("project", CYLINDER, source, "-o", out, "-q")
    assert done.exit_code == 0, done.stderr
    back = dio.read_contactors(str(out))
    assert [r[0] for r in back.passthrough_rows()] == words
    assert pl.read_csv(out, infer_schema=False)["tag"].to_list() == words
    assert pd.read_csv(out, dtype=str, keep_default_na=False)["tag"].tolist() == words
