"""Tables of contactors in and of results out, through polars: CSV text and Parquet.

CSV text is read by simple rules (see :func:`read_csv`): lines end at ``\\n`` (at ``\\r`` in a
file without ``\\n``); the separator (comma, semicolon, tab or runs of whitespace) is sniffed
from the first data lines; fields and numbers are what ``str.strip`` and ``float()`` make of
them (a number has no ``_``); a field may be quoted as RFC 4180
says. polars splits the lines and fields (with its own quoting where the quotes are simple,
`_quoted_by_polars`) and converts the numbers (correctly rounded); the few tokens it refuses,
and the other lines with a ``"``, are given to Python (``float()``, `_split_quoted`), which
also makes the error messages, with the file and line; a file whose quoted fields hold line
ends is read line by line (`_read_quoted`). Floats are written as the
shortest text that reads back to the same double (polars' writer), so every value makes the
round trip bit for bit; text is quoted where it would not read back as itself.

polars is imported by the functions that need it: a command that reads no table does not pay
for it. Nothing here knows about click or the method.
"""
from __future__ import annotations

import codecs
import contextlib
import io
import os
import sys
import tempfile
import threading

import numpy as np

from .errors import REASON_CHARS, ReadError, WriteError, first_line
from .parquet_check import check_parquet

__all__ = ["WHITESPACE", "SEPARATORS", "sniff_separator", "read_csv", "read_parquet",
           "write_csv", "write_parquet", "text_columns"]

#: what ``str.isspace`` calls whitespace (tests/test_table.py checks every code point): the
#: characters stripped from lines and fields, and that separate fields in whitespace mode.
WHITESPACE = ("\t\n\x0b\x0c\r\x1c\x1d\x1e\x1f \x85\xa0\u1680\u2000\u2001\u2002\u2003\u2004"
              "\u2005\u2006\u2007\u2008\u2009\u200a\u2028\u2029\u202f\u205f\u3000")
#: what ``float()`` strips from a number: WHITESPACE but the separators \x1c-\x1f.
_NUMBER_SPACE = WHITESPACE.replace("\x1c\x1d\x1e\x1f", "")
#: a run of WHITESPACE, in the syntax of polars' (Rust) regular expressions.
_WHITESPACE_RUN = (r"[\t\n\x0B\x0C\r\x1C-\x1F \x{85}\x{A0}\x{1680}\x{2000}-\x{200A}\x{2028}"
                   r"\x{2029}\x{202F}\x{205F}\x{3000}]+")

#: the separators tried, in order of preference, and their names in messages; None stands for
#: runs of whitespace.
SEPARATORS = ((",", "comma"), (";", "semicolon"), ("\t", "tab"), (None, "whitespace"))

#: data lines (after the first) that must split like the first for a separator to be chosen.
SNIFF_LINES = 20

#: bytes of CSV text handed to polars at a time: bounds the memory of the split fields.
READ_BLOCK = 1 << 25
#: rows of results formatted at a time: bounds the memory of the text.
WRITE_BATCH = 1 << 17
#: rows of results a file name gets in one polars call (it streams the text itself): bounds the
#: memory of the columns it is given.
WHOLE_ROWS = 1 << 20


#: what a line is stripped of before it is split at tabs: a tab there ends an empty field.
_SPACE_BUT_TAB = WHITESPACE.replace("\t", "")


def _split(line: str, sep: str | None) -> list[str]:
    """The fields of the data line ``line`` (as read, unstripped; a quoted field unquoted,
    and an unclosed one to the end of the line: for counting fields)."""
    if '"' in line:
        return [value for value, _ in _split_quoted(line, sep, strict=False)]
    if sep is None:
        return line.split()
    return line.strip(_SPACE_BUT_TAB if sep == "\t" else WHITESPACE).split(sep)


class _QuoteError(ValueError):
    """Text after the closing quote of a field."""


class _Unclosed(_QuoteError):
    """A quoted field that does not close on its line (it may on a later one)."""


def _split_quoted(line: str, sep: str | None, strict: bool = True) -> list:
    """The fields of ``line`` as (text, quoted) pairs (:func:`read_csv`'s quoting rules): a
    field whose first non-blank character is ``"`` is quoted: it runs to the next ``"`` not
    doubled (``""`` is one ``"``), and only blanks may follow up to the separator; its text
    is what the quotes hold, separators and blanks included. Unquoted fields are as
    ``_split`` cuts them (unstripped). _QuoteError where a quoted field breaks the rules
    (``strict``), else that field runs to the end of the line."""
    text = line.strip(_SPACE_BUT_TAB if sep == "\t" else WHITESPACE)
    n, i, out = len(text), 0, []
    while True:
        j = i
        while j < n and text[j] != sep and text[j] in WHITESPACE:
            j += 1
        if sep is None and j == n:
            return out
        if j < n and text[j] == '"':
            parts, k = [], j + 1
            while True:
                q = text.find('"', k)
                if q < 0:
                    if strict:
                        raise _Unclosed("a quoted field does not close (unbalanced quote)")
                    out.append((text[j + 1:], True))
                    return out
                parts.append(text[k:q])
                if text.startswith('"', q + 1):
                    parts.append('"')
                    k = q + 2
                    continue
                break
            e = q + 1
            while e < n and text[e] != sep and text[e] in WHITESPACE:
                e += 1
            if e < n and text[e] != sep and sep is not None:
                if strict:
                    raise _QuoteError("text after the closing quote of a field")
                e = text.find(sep, e)
                e = n if e < 0 else e
            elif e < n and sep is None and e == q + 1:
                if strict:
                    raise _QuoteError("text after the closing quote of a field")
                while e < n and text[e] not in WHITESPACE:
                    e += 1
            out.append(("".join(parts), True))
        else:
            if sep is None:
                e = j
                while e < n and text[e] not in WHITESPACE:
                    e += 1
                out.append((text[j:e], False))
            else:
                e = text.find(sep, i)
                e = n if e < 0 else e
                out.append((text[i:e], False))
        if e >= n:
            return out
        i = e + 1 if sep is not None else e


def _is_number(text: str) -> bool:
    """Whether ``float()`` reads ``text``: what tells a header from a first row of numbers (a
    first row holding ``1_000`` is then a row, which `_number` refuses naming the field)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _number(text: str) -> float:
    """A coordinate field as a number: what ``float()`` reads, but for digits grouped by ``_``
    (``1_000``), Python's syntax and no CSV convention's: ValueError."""
    if "_" in text:
        raise ValueError(f"not a number: {text!r}")
    return float(text)


def sniff_separator(lines: list[str]) -> tuple[str | None, str]:
    """The separator of the data lines ``lines`` (the header first if any).

    The first of comma, semicolon, tab and whitespace that splits the first line into at
    least three fields (x, y, z) and every other line into as many; failing that the first
    that splits the first line into three or more (the line that differs is then reported);
    failing that, comma.

    Returns
    -------
    sep : str or None
        None for runs of whitespace.
    name : str
        Its name in messages ('comma', ...).
    """
    splits = [(sep, name, [len(_split(line, sep)) for line in lines])
              for sep, name in SEPARATORS]
    for sep, name, counts in splits:
        if counts[0] >= 3 and all(c == counts[0] for c in counts):
            return sep, name
    for sep, name, counts in splits:
        if counts[0] >= 3:
            return sep, name
    return SEPARATORS[0]


def _head(data: bytes, pos: int, count: int):
    """The first ``count`` data lines (not blank, not a comment) from byte ``pos``: a list of
    (line number from ``pos``, text, start, position of the next line)."""
    out = []
    lineno = 0
    n = len(data)
    while pos < n and len(out) < count:
        end = data.find(b"\n", pos)
        nxt = n if end < 0 else end + 1
        lineno += 1
        text = data[pos:nxt].decode("utf-8")
        stripped = text.strip(WHITESPACE)
        if stripped and stripped[0] != "#":
            out.append((lineno, text, pos, nxt))
        pos = nxt
    return out


def read_csv(data: bytes, start: int, name: str):
    """Contactors from CSV text.

    Parameters
    ----------
    data : bytes
        UTF-8 text without NUL bytes; it starts at byte ``start`` (after a byte order mark).
    start : int
    name : str
        The file's name in messages.

    Returns
    -------
    points : (p, 3) float64
    names : list of str
        The pass-through columns' names.
    columns : list of polars.Series
        The pass-through columns, as text.

    Notes
    -----
    Lines end at ``\\n``; blank lines and lines whose first non-blank character is ``#`` are
    skipped; whitespace (``str.isspace``) is stripped from lines and fields, so CRLF line ends
    read as LF. The separator is sniffed (:func:`sniff_separator`). A field may be quoted (RFC
    4180, with any separator): one whose first non-blank character is ``"`` runs to the next
    ``"`` that is not doubled (``""`` is one ``"``), may hold separators, blanks and line ends
    (the row then goes on on the next lines), and only blanks may follow it up to the
    separator; its text is kept as it is, unstripped. A ``"`` inside an unquoted field is
    text. The first line is a header if any field is not a number: the columns named x, y, z
    (any case, one each) are the coordinates and the others are passed through. Without a
    header the last three columns are x, y, z and earlier ones are passed through as
    ``col1``, ``col2``, .... A coordinate is what ``float()`` reads (NaN and inf included); a
    pass-through field is kept as text. ReadError names the file and line of the first line
    that breaks a rule (a quoted field that never closes, text after a closing quote).
    A file without any ``\\n`` whose lines end at ``\\r`` (old Mac line ends) is read as if
    each ``\\r`` were ``\\n``; in a file with ``\\n`` a lone ``\\r`` is a character (blank
    at a field's ends, text inside quotes). A coordinate with a ``_`` (``1_000``, which
    ``float()`` reads) is not a number.
    """
    if data.find(b"\r", start) >= 0 and data.find(b"\n", start) < 0:
        # CR-only line ends: one byte for another, so offsets and line numbers stay as they are
        data = data.replace(b"\r", b"\n")
    head = _head(data, start, SNIFF_LINES + 1)
    if not head:
        raise ReadError(f"{name}: no data rows, expected CSV lines x,y,z")
    sep, sep_name = sniff_separator([text for _, text, _, _ in head])
    first_lineno, first, first_start, after = head[0]
    try:
        cells = _split_quoted(first, sep)
    except _QuoteError as exc:
        raise ReadError(f"{name}, line {first_lineno}: {exc}") from None
    fields = [text for text, _ in cells]
    ncols = len(fields)
    if not all(_is_number(f) for f in fields):
        names = [text if quoted else text.strip(WHITESPACE) for text, quoted in cells]
        lower = [n.lower() for n in names]
        idx = []
        for axis in ("x", "y", "z"):
            n = lower.count(axis)
            if n != 1:
                what = "no" if n == 0 else "more than one"
                shown = (sep if sep is not None else " ").join(names)
                raise ReadError(
                    f"{name}, line {first_lineno}: header has {what} '{axis}' column, "
                    f"expected columns named x,y,z (got {shown!r})"
                )
            idx.append(lower.index(axis))
        pidx = [j for j in range(ncols) if j not in idx]
        pnames = [names[j] for j in pidx]
        pos, line0 = after, first_lineno
    else:
        if ncols < 3:
            raise ReadError(
                f"{name}, line {first_lineno}: expected 3 numeric columns x,y,z, got {ncols}"
            )
        idx = [ncols - 3, ncols - 2, ncols - 1]
        pidx = list(range(ncols - 3))
        pnames = [f"col{j + 1}" for j in pidx]
        pos, line0 = first_start, first_lineno - 1

    layout = _Layout(name, sep, sep_name, ncols, idx, pidx, first_lineno)
    layout.quotes = data.find(b'"', pos) >= 0
    plain = None if layout.quotes else _read_plain(data, pos, layout)
    if plain is not None:
        return plain[0], pnames, plain[1]
    try:
        points, columns = _read_blocks(data, pos, line0, layout)
    except _Unclosed:  # a quoted field holds a line end: line by line (`_read_quoted`)
        points, columns = _read_quoted(data, pos, line0, layout)
    if not len(points):
        raise ReadError(f"{name}: no data rows after the header, expected CSV lines x,y,z")
    return points, pnames, columns


def _read_blocks(data: bytes, pos: int, line0: int, layout: _Layout):
    """The rows from byte ``pos`` (line ``line0 + 1``), a block of `READ_BLOCK` bytes at a
    time (`_read_block`): (points (p, 3), pass-through columns); _Unclosed where a quoted
    field does not close on its line."""
    blocks_points, blocks_text = [], []
    n = len(data)
    while pos < n:
        end = data.find(b"\n", min(pos + READ_BLOCK, n) - 1)
        end = n if end < 0 else end + 1
        points, text = _read_block(data[pos:end], line0, layout)
        blocks_points.append(points)
        blocks_text.append(text)
        line0 += data.count(b"\n", pos, end)
        pos = end
    points = np.concatenate(blocks_points) if blocks_points else np.zeros((0, 3))
    import polars as pl

    columns = [pl.concat([t[k] for t in blocks_text], rechunk=False) if blocks_text
               else pl.Series(f"p{k}", [], dtype=pl.String) for k in range(len(layout.pidx))]
    return points, columns


#: a character of WHITESPACE, in the syntax of polars' (Rust) regular expressions.
_WHITESPACE_CHAR = _WHITESPACE_RUN[:-1]
#: a pass-through field the full reader would strip, or a first field that starts a comment.
_NOT_AS_READ = f"^{_WHITESPACE_CHAR}|{_WHITESPACE_CHAR}$"


def _read_plain(data: bytes, pos: int, layout: _Layout):
    """The rows from byte ``pos`` on, read by ``polars.read_csv`` itself (the common case: a
    plain numeric file), or None when its reading cannot be shown to be the full reader's;
    the full reader then runs (and words the errors).

    What makes the two readings the same (tests/test_table.py checks that both readers agree
    on every test file): no ``"`` in the rows (the caller's condition; ``quote_char=None``); a
    comma, semicolon or tab separator, at which polars splits as ``str.split`` does; it refuses a
    row with too many fields, and a row with too few has a null in a float column (counted
    below), or, if the last column is text, fewer separators than ``ncols - 1`` per row
    (counted). Its float parser is correctly rounded and reads a subset of what ``float()``
    reads, with the same value (NaN signs too); it raises on the rest (``1_0``, non-ASCII
    digits, trailing spaces, ``#``), and so on a comment line or a blank line inside the rows
    (a null row). It strips the ``\r`` of a line end as the full reader does; a text field
    that the full reader would strip, or a first text field starting with ``#``, sends the
    file to the full reader. Trailing line ends are left out; a byte order mark at ``pos``
    (polars would drop it) too.

    Returns
    -------
    (points (p, 3) float64, pass-through columns as polars String Series) or None
    """
    sep = layout.sep
    if sep is None or data.startswith(_BOM, pos):
        return None
    # polars is given the whole text when it can skip to ``pos`` by itself (a copy of a large
    # file costs a fifth of the read): whole lines before it, or a byte order mark it drops
    end = len(data)
    while end > pos and data[end - 1] in b"\r\n":
        end -= 1
    skip = data.count(b"\n", 0, pos)
    if (skip or pos in (0, len(_BOM))) and data[end:] in (b"", b"\n", b"\r\n"):
        source = data
    else:
        source, skip = data[pos:end], 0
    import polars as pl

    ncols = layout.ncols
    text = set(layout.pidx)
    try:
        rows = pl.read_csv(source, skip_lines=skip, has_header=False, separator=sep,
                           quote_char=None,
                           schema={f"c{j}": pl.String if j in text else pl.Float64
                                   for j in range(ncols)},
                           empty_string_is_null=False, raise_if_empty=False, eol_char="\n")
    except Exception:  # noqa: BLE001 - whatever polars refuses, the full reader reads or words
        return None
    if rows.height == 0 or any(rows.get_column(f"c{j}").null_count() for j in range(ncols)):
        return None
    if ncols - 1 in text and data.count(sep.encode(), pos, end) != (ncols - 1) * rows.height:
        return None
    if text:
        checks = [pl.col(f"c{j}").str.contains(_NOT_AS_READ).any().alias(f"s{j}")
                  for j in sorted(text)]
        if 0 in text:
            checks.append(pl.col("c0").str.starts_with("#").any().alias("comment"))
        if any(rows.select(checks).row(0)):
            return None
    points = np.empty((rows.height, 3), np.float64)
    for axis, j in enumerate(layout.idx):
        points[:, axis] = rows.get_column(f"c{j}").to_numpy()
    return points, [rows.get_column(f"c{j}").alias(f"p{k}") for k, j in enumerate(layout.pidx)]


def _read_quoted(data: bytes, pos: int, line0: int, layout: _Layout):
    """The data rows from byte ``pos`` (line ``line0 + 1``) of a file with quotes, line by
    line in Python (:func:`_split_quoted`; a quoted field that holds line ends continues the
    row on the next lines): (points (p, 3) float64, pass-through columns as polars String
    Series); ReadError at the first row that breaks a rule, named by its first line."""
    import polars as pl

    points, texts = [], []
    lines = data[pos:].decode("utf-8").split("\n")
    at = 0
    while at < len(lines):
        k, line = line0 + 1 + at, lines[at]
        at += 1
        stripped = line.strip(WHITESPACE)
        if not stripped or stripped[0] == "#":
            continue
        while True:
            try:
                cells = (_split_quoted(line, layout.sep) if '"' in line
                         else [(t, False) for t in _split(line, layout.sep)])
                break
            except _Unclosed as exc:
                if at == len(lines):
                    raise ReadError(f"{layout.name}, line {k}: {exc}") from None
                line += "\n" + lines[at]  # the field's line end, and the row goes on
                at += 1
            except _QuoteError as exc:
                raise ReadError(f"{layout.name}, line {k}: {exc}") from None
        if len(cells) != layout.ncols:
            raise layout.count_error(k, len(cells))
        row = []
        for axis, j in enumerate(layout.idx):
            try:
                row.append(_number(cells[j][0]))
            except ValueError:
                shown = cells[j][0] if cells[j][1] else cells[j][0].strip(WHITESPACE)
                raise ReadError(f"{layout.name}, line {k}: expected a number for "
                                f"{'xyz'[axis]}, got {shown!r}") from None
        points.append(row)
        texts.append([t if quoted else t.strip(WHITESPACE)
                      for t, quoted in (cells[j] for j in layout.pidx)])
    columns = [pl.Series(f"p{k}", [r[k] for r in texts], dtype=pl.String)
               for k in range(len(layout.pidx))]
    return np.array(points, dtype=np.float64).reshape(-1, 3), columns


def _simple_quoted(sep: str) -> str:
    """A line (as split) whose fields polars' quoting reads as `_split_quoted` does, in the
    syntax of polars' regular expressions: every field quoted, ``"..."`` with ``""`` inside,
    right against its separators, or unquoted without ``"`` and without blanks at its ends
    (its text is then the same stripped or not)."""
    blank = _WHITESPACE_RUN[1:-2]  # the characters of the class
    s = "\\t" if sep == "\t" else sep
    edge, inner = f'[^"{s}{blank}\\x{{FEFF}}]', f'[^"{s}\\x{{FEFF}}]'
    field = f'(?:"(?:[^"]|"")*"|(?:{edge}(?:{inner}*{edge})?)?)'
    return f"^{field}(?:{s}{field})*$"


def _quoted_by_polars(rows, layout: _Layout):
    """``rows`` (`_read_block`'s) with the lines that hold a ``"`` and whose quoting is simple
    (`_simple_quoted`) read by polars' own quoting: their fields, numbers and pass-through
    text replaced, ``ok`` set and ``q`` cleared where they have the right field count; the
    other lines are left to `_split_quoted` (``q`` stays)."""
    import polars as pl

    ncols = layout.ncols
    cand = rows.select(pl.arg_where(
        pl.col("q") & pl.col("t").str.contains(_simple_quoted(layout.sep)))).to_series()
    if not len(cand):
        return rows
    text = rows["t"].gather(cand).str.join("\n").item() + "\n"
    try:
        parsed = pl.read_csv(text.encode("utf-8"), has_header=False, separator=layout.sep,
                             quote_char='"', schema={f"c{j}": pl.String for j in range(ncols)},
                             empty_string_is_null=False, raise_if_empty=False, eol_char="\n")
    except Exception:  # noqa: BLE001 - whatever polars refuses, _split_quoted reads or words
        return rows
    if parsed.height != len(cand):
        return rows
    whole = parsed.select(pl.all_horizontal(pl.all().is_not_null())).to_series()
    at = cand.filter(whole).cast(pl.UInt32)
    parsed = parsed.filter(whole)
    number = {axis: parsed.get_column(f"c{j}").str.strip_chars(_NUMBER_SPACE)
              .cast(pl.Float64, strict=False) for axis, j in zip("xyz", layout.idx)}
    new = {f"p{k}": parsed.get_column(f"c{j}") for k, j in enumerate(layout.pidx)}
    new.update(number)
    new["ok"] = pl.Series([True] * len(at))
    new["q"] = pl.Series([False] * len(at))
    return rows.with_columns(rows.get_column(name).scatter(at, values.cast(
        rows.schema[name])) for name, values in new.items())


class _Layout:
    """How the rows of one CSV file split: separator, columns and their roles."""

    def __init__(self, name, sep, sep_name, ncols, idx, pidx, first_lineno):
        self.name, self.sep, self.sep_name = name, sep, sep_name
        self.ncols, self.idx, self.pidx = ncols, idx, pidx
        self.first_lineno = first_lineno
        self.quotes = True  # whether the rows may hold a '"' (read_csv knows)

    def count_error(self, lineno: int, got: int) -> ReadError:
        return ReadError(f"{self.name}, line {lineno}: expected {self.ncols} {self.sep_name} "
                         f"separated columns (as on line {self.first_lineno}), got {got}")


def _read_block(block: bytes, line0: int, layout: _Layout):
    """The data rows of ``block`` (whole lines; its first line is line ``line0 + 1``):
    (points (r, 3) float64, pass-through columns as polars String Series)."""
    import polars as pl

    ncols = layout.ncols
    # one column of lines; the leading empty line keeps a byte order mark in the block's
    # first line (polars drops one at the start of its input) and makes row n line line0 + n
    lines = pl.read_csv(b"\n" + block, has_header=False, separator="\x00", quote_char=None,
                        infer_schema=False, new_columns=["line"], raise_if_empty=False,
                        eol_char="\n")
    # s: the line stripped, which says if it is blank or a comment; the text split into fields
    if layout.sep is None:
        text = pl.col("s").str.replace_all(_WHITESPACE_RUN, "\t")
    elif layout.sep == "\t":
        text = pl.col("line").str.strip_chars(_SPACE_BUT_TAB)
    else:
        text = pl.col("s")
    sep = layout.sep if layout.sep is not None else "\t"
    field = [pl.col("f").struct.field(f"field_{j}") for j in range(ncols + 1)]
    strip = [f.str.strip_chars(WHITESPACE) for f in field]
    number = [f.str.strip_chars(_NUMBER_SPACE).cast(pl.Float64, strict=False) for f in field]
    rows = (
        lines.lazy().with_row_index("n")
        .with_columns(s=pl.col("line").str.strip_chars(WHITESPACE))
        .filter(pl.col("s").str.len_bytes() > 0, ~pl.col("s").str.starts_with("#"))
        # only a file with a '"' in its rows has lines to look at for it (q), and to read
        # with polars' quoting (t: the text split)
        .select("n", f=text.str.split_exact(sep, ncols),
                t=text if layout.quotes else pl.lit(None, pl.String),
                q=(pl.col("line").str.contains('"', literal=True) if layout.quotes
                   else pl.lit(False)))
        .select(
            "n", "q", "t",
            *[strip[j].alias(f"p{k}") for k, j in enumerate(layout.pidx)],
            # exactly ncols fields: the last one there, none after it
            ok=field[ncols - 1].is_not_null() & field[ncols].is_null(),
            x=number[layout.idx[0]],
            y=number[layout.idx[1]],
            z=number[layout.idx[2]],
        )
        .collect()
    )
    if layout.sep is not None and rows["q"].any():
        rows = _quoted_by_polars(rows, layout)
    points = np.empty((rows.height, 3), np.float64)
    for axis, col in enumerate("xyz"):
        points[:, axis] = rows[col].to_numpy()
    # the rows polars did not settle: a wrong field count, a token it refuses (float() may
    # read it: '1_000', Arabic-Indic digits), a NaN (float() keeps the sign of '-nan'), or
    # a quote polars did not read (`_split_quoted`, which also gives their pass-through text)
    doubt = rows.select(pl.arg_where(~pl.col("ok") | pl.col("q") | pl.any_horizontal(
        pl.col("x", "y", "z").is_null() | pl.col("x", "y", "z").is_nan()))).to_series()
    columns = [rows[f"p{k}"] for k in range(len(layout.pidx))]
    if len(doubt):
        numbers = rows["n"].gather(doubt).to_list()
        texts = lines["line"].gather(numbers).to_list()
        quoted_rows, quoted_text = [], []
        for r, n, text in zip(doubt.to_list(), numbers, texts):
            try:
                cells = (_split_quoted(text, layout.sep) if '"' in text
                         else [(t, False) for t in _split(text, layout.sep)])
            except _Unclosed:
                raise  # a line end inside quotes: the caller reads line by line
            except _QuoteError as exc:
                raise ReadError(f"{layout.name}, line {line0 + n}: {exc}") from None
            if len(cells) != ncols:
                raise layout.count_error(line0 + n, len(cells))
            for axis, j in enumerate(layout.idx):
                try:
                    points[r, axis] = _number(cells[j][0])
                except ValueError:
                    shown = cells[j][0] if cells[j][1] else cells[j][0].strip(WHITESPACE)
                    raise ReadError(f"{layout.name}, line {line0 + n}: expected a number for "
                                    f"{'xyz'[axis]}, got {shown!r}") from None
            if '"' in text:
                quoted_rows.append(r)
                quoted_text.append([t if q else t.strip(WHITESPACE)
                                    for t, q in (cells[j] for j in layout.pidx)])
        if quoted_rows:
            at = pl.Series(quoted_rows, dtype=pl.UInt32)
            columns = [c.scatter(at, pl.Series([t[k] for t in quoted_text], dtype=pl.String))
                       for k, c in enumerate(columns)]
    return points, columns


# --------------------------------------------------------------------------------------------
# CSV text: encoding checks
# --------------------------------------------------------------------------------------------

#: the UTF-8 byte order mark.
_BOM = b"\xef\xbb\xbf"


def is_utf8(data: bytes) -> bool:
    """Whether ``data`` is valid UTF-8, checked in slices so no copy of the text is made."""
    if data.isascii():
        return True
    decoder = codecs.getincrementaldecoder("utf-8")()
    view = memoryview(data)
    step = 1 << 22
    try:
        for i in range(0, len(view), step):
            decoder.decode(view[i:i + step], i + step >= len(view))
    except UnicodeDecodeError:
        return False
    return True


def csv_start(data: bytes, name: str, all_boms: bool = False) -> int:
    """Where the text of ``data`` starts after its byte order mark (every leading one if
    ``all_boms``), once ``data`` is checked to be NUL-free UTF-8; the errors are
    :func:`_decode`'s."""
    if b"\x00" in data or not is_utf8(data):
        _decode(data, name)  # raises the ReadError that says what the bytes are
        raise ReadError(f"{name}: not a text CSV file")  # unreachable: _decode raised
    start = 0
    while data.startswith(_BOM, start):
        start += len(_BOM)
        if not all_boms:
            break
    return start


def stdin_bytes(stream) -> bytes | None:
    """The raw bytes under a strict UTF-8 text stream (read once, without a decoded copy),
    or None when the stream must be read as text."""
    buffer = getattr(stream, "buffer", None)
    if buffer is None or getattr(stream, "errors", None) != "strict":
        return None
    try:
        if codecs.lookup(stream.encoding).name != "utf-8":
            return None
    except (LookupError, TypeError, AttributeError):
        return None
    return buffer.read()


#: First words of the text mesh formats, to tell a mesh piped as CSV contactors.
_MESH_SIGNATURES = (("$MeshFormat", "Gmsh"), ("$NOD", "Gmsh"), ("<?xml", "XML (VTK)"),
                    ("<VTKFile", "VTK XML"), ("# vtk DataFile", "legacy VTK"),
                    ("solid", "ASCII STL"), ("ply", "PLY"), ("OFF", "OFF"),
                    ("*HEADING", "Abaqus"), ("*NODE", "Abaqus"))


def refuse_mesh_text(text, name: str) -> None:
    """A mesh on stdin cannot be read (meshio needs a file name): say so, rather than report
    its first line as a bad CSV header."""
    head = text[:4096]
    if not isinstance(head, str):  # bytes or a memoryview of them
        head = bytes(head).decode("utf-8", "replace")
    for lineno, line in enumerate(head.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        for word, kind in _MESH_SIGNATURES:
            if line.upper().startswith(word.upper()) and "," not in line:
                raise ReadError(
                    f"{name}, line {lineno}: looks like a {kind} mesh ({line[:20]!r}); a mesh "
                    f"on stdin is not supported, expected CSV x,y,z (give the mesh file's name)")
        return


def _decode(data: bytes, name: str) -> str:
    for bom, encoding in _UTF_BOMS:
        if data.startswith(bom) and _decodes(data, encoding):
            raise ReadError(f"{name}: {encoding} text, expected UTF-8 (or ASCII) CSV; convert it, "
                            f"e.g. iconv -f {encoding} -t UTF-8")
    newline = b"\n"
    if b"\x00" in data:
        line = data.count(newline, 0, data.index(b"\x00")) + 1
        raise ReadError(f"{name}: not a text CSV file (contains NUL bytes, the first on line "
                        f"{line})")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data.count(newline, 0, exc.start) + 1
        raise ReadError(f"{name}: not a text CSV file (bytes at offset {exc.start}, on line "
                        f"{line}, are not UTF-8 text)") from None


def _decodes(data: bytes, encoding: str) -> bool:
    try:
        data.decode(encoding)
    except UnicodeDecodeError:
        return False
    return True


#: byte order marks of the encodings that Windows tools write and a CSV reader meets.
_UTF_BOMS = ((b"\xff\xfe\x00\x00", "UTF-32"), (b"\x00\x00\xfe\xff", "UTF-32"),
             (b"\xff\xfe", "UTF-16"), (b"\xfe\xff", "UTF-16"))


# --------------------------------------------------------------------------------------------
# Parquet
# --------------------------------------------------------------------------------------------

#: the first (and last) bytes of every Parquet file.
_PARQUET_MAGIC = b"PAR1"


def coordinate_columns(names) -> list[int]:
    """Indices of the columns named x, y and z among `names` (any case, one each); a
    ValueError says which is missing or repeated."""
    lower = [str(n).lower() for n in names]
    idx = []
    for axis in "xyz":
        n = lower.count(axis)
        if n != 1:
            raise ValueError(f"{'no' if n == 0 else 'more than one'} '{axis}' column")
        idx.append(lower.index(axis))
    return idx


def _panic() -> type:
    """pyo3's PanicException (a Rust panic inside polars), or a class nothing raises."""
    import polars as pl

    found = getattr(pl.exceptions, "PanicException", None)
    return found if isinstance(found, type) else _NeverRaised


class _NeverRaised(Exception):
    """Stands for PanicException where polars does not export it."""


#: the state of `_fd2_held`: how many reads hold file descriptor 2, the descriptor it had
#: before them, the temporary file it points to meanwhile, and whether a read failed.
_FD2 = {"depth": 0, "saved": -1, "file": None, "failed": False}
_FD2_LOCK = threading.Lock()


def _flush_stderr() -> None:
    stream = sys.stderr
    with contextlib.suppress(Exception):
        if stream is not None:
            stream.flush()


@contextlib.contextmanager
def _fd2_held():
    """While a damaged Parquet file may make polars panic: file descriptor 2 points to a
    temporary file. A Rust panic prints its message and backtrace there before pyo3 raises
    PanicException (no Python setting, nor RUST_BACKTRACE=0 for the message, turns that
    off), and the caller's one-line ReadError says all that is to be said. When the last
    read ends, fd 2 is restored and what it received meanwhile (polars warnings, another
    thread's logging) is written there after all, unless a read failed: it is then dropped,
    a panic's text with it. Reads from several threads share one window (a count), so that
    none restores fd 2 under another. Where fd 2 cannot be held (closed, no temporary
    directory) nothing is held: the panic text then shows, the error is the same."""
    with _FD2_LOCK:
        if _FD2["depth"] == 0:
            try:
                capture = tempfile.TemporaryFile()
            except OSError:
                capture = None
            saved = -1
            if capture is not None:
                try:
                    _flush_stderr()
                    saved = os.dup(2)
                    os.dup2(capture.fileno(), 2)
                except OSError:
                    if saved >= 0:
                        os.close(saved)
                    capture.close()
                    saved, capture = -1, None
            _FD2.update(saved=saved, file=capture, failed=False)
        _FD2["depth"] += 1
    failed = False
    try:
        yield
    except BaseException:
        failed = True
        raise
    finally:
        with _FD2_LOCK:
            _FD2["failed"] = _FD2["failed"] or failed
            _FD2["depth"] -= 1
            if _FD2["depth"] == 0 and _FD2["file"] is not None:
                _flush_stderr()
                capture, saved = _FD2["file"], _FD2["saved"]
                _FD2.update(saved=-1, file=None)
                os.dup2(saved, 2)
                os.close(saved)
                with capture:
                    if not _FD2["failed"]:
                        capture.seek(0)
                        with contextlib.suppress(OSError):
                            for chunk in iter(lambda: capture.read(1 << 16), b""):
                                while chunk:
                                    chunk = chunk[os.write(2, chunk):]


def read_parquet(path: str):
    """Contactors from a Parquet file: the columns named x, y, z (any case, one each, numbers)
    and the others passed through with their types. A null coordinate reads as NaN: that row
    is a contactor without a position, which the projection reports 'failed' (bad-point), as
    it does NaN, and the rest of the file is answered.

    Returns
    -------
    points : (p, 3) float64
    names : list of str
    columns : list of polars.Series
    """
    import polars as pl

    expected = "expected a Parquet file with columns x, y, z"
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({first_line(exc)})") from None
    if magic != _PARQUET_MAGIC:
        raise ReadError(f"{path}: not a Parquet file (it does not start with PAR1), {expected}")
    # polars trusts the counts and sizes in the file: a huge page value count makes it abort
    # the process (no exception to catch), so they are checked first
    try:
        check_parquet(path)
    except OSError as exc:
        raise ReadError(f"{path}: cannot read ({first_line(exc)})") from None
    except ValueError as exc:
        raise ReadError(f"{path}: not a valid Parquet file ({first_line(exc)[:REASON_CHARS]}), "
                        f"{expected}") from None
    try:
        with _fd2_held():  # a panic's text and backtrace: not on the user's terminal
            table = pl.read_parquet(path)
    # polars raises several kinds for a damaged file; a panic in its Rust code comes as
    # pyo3's PanicException, a BaseException: caught by name, never KeyboardInterrupt
    except (Exception, _panic()) as exc:  # noqa: BLE001
        raise ReadError(f"{path}: cannot read Parquet ({first_line(exc)[:REASON_CHARS]}), "
                        f"{expected}") from None
    names = table.columns
    try:
        idx = coordinate_columns(names)
    except ValueError as exc:
        raise ReadError(f"{path}: {exc}, {expected} (got {', '.join(names) or 'no columns'})"
                        ) from None
    if table.height == 0:
        raise ReadError(f"{path}: no data rows, {expected}")
    points = np.empty((table.height, 3), np.float64)
    for axis, j in enumerate(idx):
        col = table.get_column(names[j])
        if not col.dtype.is_numeric():
            raise ReadError(f"{path}: column '{names[j]}' holds {col.dtype}, expected numbers")
        points[:, axis] = col.cast(pl.Float64).fill_null(float("nan")).to_numpy()
    pidx = [j for j in range(len(names)) if j not in idx]
    return points, [names[j] for j in pidx], [table.get_column(names[j]) for j in pidx]


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------


def text_columns(rows, ncols: int):
    """Rows of text (each a sequence of ``ncols`` str) as ``ncols`` polars String Series."""
    import polars as pl

    rows = [list(map(str, r)) for r in rows]
    for i, r in enumerate(rows):
        if len(r) != ncols:
            raise ValueError(f"row {i} has {len(r)} fields, expected {ncols}")
    return [pl.Series(f"p{j}", [r[j] for r in rows], dtype=pl.String) for j in range(ncols)]


def _result_series(name: str, values: np.ndarray, words):
    """One result column for polars: floats as Float64, label codes as their words (an Enum),
    booleans as 0/1, other integers as they are."""
    import polars as pl

    if words is not None:
        return pl.Series(name, list(words), dtype=pl.Enum(list(words))).gather(
            values.astype(np.int64, copy=False))
    if values.dtype.kind == "f":
        return pl.Series(name, values.astype(np.float64, copy=False))
    if values.dtype.kind == "b":
        return pl.Series(name, values.astype(np.int8))
    return pl.Series(name, values)


def csv_problem(column) -> str | None:
    """Why the pass-through ``column`` cannot be written as CSV text, None if it can.

    Text (String, Categorical, Enum), numbers (integers to 128 bits, floats, Decimal),
    Boolean (true/false), Date, Time, Datetime (ISO 8601, with its UTC offset where it has a
    time zone), Duration (ISO 8601, `_csv_text`) and Null columns have a field form; binary
    bytes and nested values (List, Array, Struct) have none (Parquet holds them).
    """
    import polars as pl

    dtype = column.dtype
    if dtype.is_nested():
        return "nested values, which have no CSV field form"
    if dtype == pl.Binary:
        return "binary bytes, which have no text form"
    if (dtype.is_numeric() or dtype.is_temporal()
            or dtype in (pl.Boolean, pl.String, pl.Null)
            or isinstance(dtype, (pl.Categorical, pl.Enum))):
        return None
    return "a type with no CSV field form"


def check_csv_column(name: str, column, label: str = "", separator: str = ",") -> None:
    """WriteError unless the pass-through ``column`` (named ``label``) can be written as CSV
    text to ``name`` (:func:`csv_problem`)."""
    why = csv_problem(column)
    if why is not None:
        text = "TSV" if separator == "\t" else "CSV"
        raise WriteError(f"{name}: pass-through column '{label or column.name}' of type "
                         f"{column.dtype} cannot be written as {text} text ({why}); write "
                         f".parquet, or drop the column from POINTS")


#: the mesh formats whose point data are stored, and read back, as float64: an integer beyond
#: 2**53 in magnitude would not come back as itself.
_FLOAT_POINT_DATA = ("gmsh22", "avsucd")


def point_data(column, fmt: str):
    """A pass-through column as the point data of a result mesh in meshio format ``fmt``:
    ``(values, None)`` with values (p,) int64 or float64, or ``(None, why not)`` ('' where
    the type itself says it).

    Integers are written as int64 (if every value fits, and fits 2**53 where ``fmt`` stores
    floats), floats as float64 (NaN kept), Boolean as 0/1; a CSV's text column where every
    field is a number (`numbers`). Nothing else has a place in point data, which are numbers:
    text, temporal, Decimal (not exact as a float), binary and nested columns, and columns
    with nulls or empty fields (a mesh has no empty value), are refused, never dropped.
    """
    import polars as pl

    dtype = column.dtype
    if dtype == pl.String:  # a CSV's: its integers int64, its other numbers (007) float64
        values = numbers(column)
        if values is None:
            empty = column.str.strip_chars(WHITESPACE).str.len_bytes() == 0
            return None, "empty fields" if empty.any() else "not numbers"
        column = pl.Series(column.name, values)
    elif not (dtype.is_integer() or dtype.is_float() or dtype == pl.Boolean):
        return None, ""
    elif column.null_count():
        return None, "nulls"
    if column.dtype == pl.Boolean:
        return column.cast(pl.Int64).to_numpy(), None
    if column.dtype.is_float():
        return column.cast(pl.Float64).to_numpy(), None
    bound = 2**53 if fmt in _FLOAT_POINT_DATA else 2**63 - 1
    if len(column) and (column.min() < -bound or column.max() > bound):
        return None, ("beyond 2**53, which this format stores as floats"
                      if fmt in _FLOAT_POINT_DATA else "beyond int64")
    return column.cast(pl.Int64).to_numpy(), None


def _csv_text(column):
    """A pass-through column ready for the CSV writer: NaN as 'NaN' (written for nulls), real
    nulls (a Parquet input's) as empty fields, categorical text (a Parquet input's) as text,
    so that its fields are quoted where they must be, as any text's are, and a Duration as
    its ISO 8601 text (PT1.5S, P2DT3H; polars writes no CSV field for a Duration)."""
    import polars as pl

    if isinstance(column.dtype, (pl.Categorical, pl.Enum)):
        column = column.cast(pl.String)
    elif isinstance(column.dtype, pl.Duration):
        column = column.dt.to_string("iso")
    if column.null_count() and column.dtype.is_temporal():
        # the CSV writer's own text, as without nulls (a cast writes ' ' for 'T' and drops
        # the fractions of a second of a Time), a null an empty field: one per line, none
        # holding a quote, a separator or a line end
        text = pl.DataFrame([column]).write_csv(None, include_header=False, null_value="",
                                                quote_style="never", line_terminator="\n")
        return pl.Series(column.name, text.split("\n")[:-1], dtype=pl.String)
    if column.null_count():
        return column.cast(pl.String).fill_null("")
    if column.dtype.is_float():
        return column.fill_nan(None)
    return column


def write_csv(sink, names: list, passthrough: list, columns: dict, labels: dict,
              separator: str = ",") -> None:
    """Write a header and the rows: the pass-through columns, then the result columns.

    Parameters
    ----------
    sink : str, or binary or text stream
        A file name (a new regular file) or a stream.
    names : list of str
        The pass-through columns' names.
    passthrough : list of polars.Series
    columns : dict of str to (p,) array
        Floats, integers, booleans (written 0/1) or the codes of a column in ``labels``.
    labels : dict of str to sequence of str
    separator : {',', '\\t'}
        Comma (CSV) or tab (TSV).

    Notes
    -----
    Floats are the shortest text that reads back to the same double (``NaN``, which polars,
    pandas and numpy all read as a float, ``inf``, ``-0.0``, ``1e-300``); labels are words.
    Fields are written as they are, unless one would not read back as itself (RFC 4180
    quoting, which diffsurf, polars and pandas read): a text field holding the separator, a
    ``"`` or a line end is quoted (``"`` doubled); if one has blanks at either end, or the
    first column's starts with ``#`` (a comment line), every text field is. A file name of up
    to ``WHOLE_ROWS`` rows is written by polars in one call (no text passes through Python);
    the bytes are the same.
    """
    import polars as pl

    texts = [_csv_text(s) for s in passthrough]
    header = list(names) + list(columns)
    style = _quote_style(texts, header, separator)
    needs_quotes = style != "never"
    p = len(next(iter(columns.values()))) if columns else (len(texts[0]) if texts else 0)
    values = {k: np.asarray(v) for k, v in columns.items()}
    options = dict(null_value="NaN", quote_style=style, line_terminator="\n",
                   separator=separator)

    def frame(start, stop, named=False):
        heads = header if named else [f"p{k}" for k in range(len(texts))] + [
            f"c{k}" for k in range(len(values))]
        return pl.DataFrame(
            [s.slice(start, stop - start).alias(h) for s, h in zip(texts, heads)]
            + [_result_series(h, v[start:stop], labels.get(key)).fill_nan(None)
               if v.dtype.kind == "f" else _result_series(h, v[start:stop], labels.get(key))
               for h, (key, v) in zip(heads[len(texts):], values.items())])

    if isinstance(sink, str):
        if (header and not needs_quotes and p <= WHOLE_ROWS and all(header)
                and len(set(header)) == len(header)):
            frame(0, p, named=True).write_csv(sink, include_header=True, **options)
            return
        with open(sink, "wb") as fh:
            write_csv(fh, names, passthrough, columns, labels, separator)
        return

    if needs_quotes:
        header = [_quoted(h) if _quote_needed(h, separator, k == 0) else h
                  for k, h in enumerate(header)]
    binary = not hasattr(sink, "encoding")

    def batches():
        for start in range(0, p, WRITE_BATCH):
            stop = min(start + WRITE_BATCH, p)
            batch = frame(start, stop)
            if batch.width == 0:  # rows without a field: empty lines
                text = "\n" * (stop - start)
                yield text.encode() if binary else text
            elif binary:
                buf = io.BytesIO()
                batch.write_csv(buf, include_header=False, **options)
                yield buf.getbuffer()
            else:
                yield batch.write_csv(None, include_header=False, **options)

    # the first batch is formatted before the header is written: a column polars cannot
    # format then fails before anything reaches a stream that cannot be taken back (stdout)
    chunks = batches()
    first = next(chunks, None)
    line = separator.join(header) + "\n"
    sink.write(line.encode("utf-8") if binary else line)
    # polars formats a batch in memory and Python writes it, so a closed pipe raises
    # BrokenPipeError here as for any other write
    if first is not None:
        sink.write(first)
    for chunk in chunks:
        sink.write(chunk)


def _quote_needed(text: str, separator: str = ",", first: bool = False) -> bool:
    """Whether ``text`` must be quoted to read back as itself (`read_csv`)."""
    return (separator in text or any(c in text for c in '"\n\r')
            or text != text.strip(WHITESPACE) or (first and text.startswith("#")))


def _quote_style(texts: list, header: list, separator: str) -> str:
    """polars' quote style for these pass-through columns (text first) and header names:
    'never' when every field reads back as itself unquoted; 'necessary' (separators, quotes,
    line ends) or 'non_numeric' (every text field: one has blanks at either end, or the first
    column's starts with '#', which polars would not quote)."""
    import polars as pl

    strings = [s for s in texts if s.dtype == pl.String]
    if any(bool(s.str.contains(_NOT_AS_READ).any()) for s in strings) or (
            texts and texts[0].dtype == pl.String
            and bool(texts[0].str.starts_with("#").any())):
        return "non_numeric"
    special = '[\t\n\r"]' if separator == "\t" else '[,\n\r"]'
    if any(bool(s.str.contains(special).any()) for s in strings) or any(
            _quote_needed(h, separator, k == 0) for k, h in enumerate(header)):
        return "necessary"
    return "never"


def _quoted(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


def write_parquet(path: str, names: list, passthrough: list, columns: dict,
                  labels: dict) -> None:
    """Write the pass-through columns then the result columns as one Parquet table.

    Floats stay float64 (NaN as NaN), labels are dictionary-encoded words (a polars Enum,
    the CSV's words), pass-through columns keep their types: a CSV's text columns the type
    their fields hold (`typed`: integers Int64, numbers Float64, else text). Column names
    must be unique.
    """
    import polars as pl

    frame = pl.DataFrame(
        [typed(s).alias(n) for n, s in zip(names, passthrough)]
        + [_result_series(k, np.asarray(v), labels.get(k)) for k, v in columns.items()])
    frame.write_parquet(path, compression="zstd", statistics=True)


def duplicate_name(names) -> str | None:
    """The first name that appears twice in ``names``, None if none does."""
    seen = set()
    for n in names:
        if n in seen:
            return n
        seen.add(n)
    return None


def numbers(column):
    """A pass-through column as (p,) int64 if every field is an integer (`typed`), float64 if
    every field is a number, else None."""
    import polars as pl

    column = typed(column)
    if column.dtype.is_integer() and not column.null_count():
        return column.cast(pl.Int64).to_numpy()
    if column.dtype.is_numeric() and not column.null_count():
        return column.cast(pl.Float64).to_numpy()
    if column.dtype != pl.String:
        return None
    values = column.str.strip_chars(WHITESPACE).cast(pl.Float64, strict=False)
    if values.null_count():
        return None
    return values.to_numpy()


#: An integer field as a CSV holds one, and a code with leading zeros (007: kept as text).
_INTEGER = r"^[+-]?(0|[1-9][0-9]*)$"
_CODE = r"^[+-]?0[0-9]+$"


def typed(column):
    """A text pass-through column (a CSV's) as the type its fields hold: Int64 where every
    non-empty field is an integer within int64 (no leading zeros: 007 is a code, kept as
    text), Float64 where every one is a number, else the text itself; empty fields are nulls
    in the typed columns. Other columns are returned as they are."""
    import polars as pl

    if column.dtype != pl.String:
        return column
    text = column.str.strip_chars(WHITESPACE)
    present = text.str.len_bytes() > 0
    if not present.any():
        return column
    text = pl.select(pl.when(present).then(text).otherwise(None)).to_series().alias(column.name)
    if text.drop_nulls().str.contains(_CODE).any():
        return column
    if text.drop_nulls().str.contains(_INTEGER).all():
        ints = text.cast(pl.Int64, strict=False)
        if ints.null_count() == text.null_count():  # none beyond int64
            return ints
    floats = text.cast(pl.Float64, strict=False)
    if floats.null_count() == text.null_count():
        return floats
    return column

