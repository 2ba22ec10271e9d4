"""The CSV rules of diffsurf_cli.io.table.read_csv in slow, obvious Python: the oracle the
polars reader is checked against (str.strip, str.split, float() on the decoded text, and a
character-by-character reading of quoted fields)."""
from __future__ import annotations

import numpy as np

from diffsurf_cli.io import ReadError

#: separators in order of preference, as the reader's docstring gives them.
SEPARATORS = ((",", "comma"), (";", "semicolon"), ("\t", "tab"), (None, "whitespace"))


#: whitespace but the tab: a line split at tabs is stripped of these only.
SPACE_BUT_TAB = "".join(chr(c) for c in range(0x110000) if chr(c).isspace() and c != 9)


class QuoteError(ValueError):
    pass


class Unclosed(QuoteError):
    """A quoted field still open at the end of the text: a row may go on on the next line."""


UNBALANCED = "a quoted field does not close (unbalanced quote)"
AFTER_QUOTE = "text after the closing quote of a field"


def fields(line: str, sep, strict: bool = True):
    """The fields of a data line as (text, quoted), one character at a time: a field whose
    first non-blank character is a double quote is quoted; inside, two quotes are one, one
    closes it, and only blanks may follow it up to the separator (QuoteError if `strict`, else
    the rest up to the separator is dropped; an unclosed one runs to the end of the line).
    An unquoted field is its text up to the separator, unstripped (whitespace mode: a run of
    non-blanks). The line is stripped first (a tab at either end of it ends an empty field
    when tabs separate)."""
    text = line.strip(SPACE_BUT_TAB if sep == "\t" else None)

    def is_sep(ch):
        return ch.isspace() if sep is None else ch == sep

    out, state, buf, pending = [], "start", [], []
    for ch in text:
        if state == "start":
            if ch == '"':
                state, buf = "quoted", []
            elif is_sep(ch):
                if sep is not None:
                    out.append(("".join(pending), False))
                pending = []
            elif ch.isspace():
                pending.append(ch)
            else:
                state, buf, pending = "plain", pending + [ch], []
        elif state == "plain":
            if is_sep(ch):
                out.append(("".join(buf), False))
                state, pending = "start", []
            else:
                buf.append(ch)
        elif state == "quoted":
            if ch == '"':
                state = "quote"
            else:
                buf.append(ch)
        elif state == "quote":  # after a quote inside a quoted field
            if ch == '"':
                buf.append('"')
                state = "quoted"
            elif is_sep(ch):
                out.append(("".join(buf), True))
                state, pending = "start", []
            elif ch.isspace():
                state = "after"
            elif strict:
                raise QuoteError(AFTER_QUOTE)
            else:
                state = "skip"
        elif state == "after":  # blanks after a closing quote
            if is_sep(ch) and sep is not None:
                out.append(("".join(buf), True))
                state, pending = "start", []
            elif ch.isspace():
                pass
            elif strict:
                raise QuoteError(AFTER_QUOTE)
            else:
                state = "skip"
        elif state == "skip":  # lenient: the rest of a broken quoted field
            if is_sep(ch):
                out.append(("".join(buf), True))
                state, pending = "start", []
    if state == "quoted":
        if strict:
            raise Unclosed(UNBALANCED)
        out.append(("".join(buf), True))
    elif state in ("quote", "after", "skip"):
        out.append(("".join(buf), True))
    elif state == "plain":
        out.append(("".join(buf), False))
    elif sep is not None:  # the last field is empty (or blanks)
        out.append(("".join(pending), False))
    return out


def split(line: str, sep):
    """The fields' texts (for counting them: quotes not checked)."""
    return [t for t, _ in fields(line, sep, strict=False)]


def is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def sniff(lines):
    """The separator of the data lines ``lines`` (at most 21)."""
    for sep, name in SEPARATORS:
        counts = [len(split(line, sep)) for line in lines]
        if counts[0] >= 3 and len(set(counts)) == 1:
            return sep, name
    for sep, name in SEPARATORS:
        if len(split(lines[0], sep)) >= 3:
            return sep, name
    return SEPARATORS[0]


def read_csv(text: str, name: str):
    """(points (p, 3) float64, pass-through names, rows of pass-through text); ReadError with
    the reader's message where the rules refuse ``text`` (decoded, BOM removed)."""
    if "\n" not in text:  # old Mac line ends: lines end at \r
        text = text.replace("\r", "\n")
    data = [(n, s) for n, s in enumerate(text.split("\n"), 1)
            if s.strip() and s.strip()[0] != "#"]
    if not data:
        raise ReadError(f"{name}: no data rows, expected CSV lines x,y,z")
    sep, sep_name = sniff([s for _, s in data[:21]])
    first_lineno, first = data[0]
    try:
        cells = fields(first, sep)
    except QuoteError as exc:
        raise ReadError(f"{name}, line {first_lineno}: {exc}") from None
    texts = [t for t, _ in cells]
    ncols = len(texts)
    if not all(is_number(f) for f in texts):
        names = [t if q else t.strip() for t, q in cells]
        lower = [n.lower() for n in names]
        idx = []
        for axis in "xyz":
            n = lower.count(axis)
            if n != 1:
                what = "no" if n == 0 else "more than one"
                shown = (sep if sep is not None else " ").join(names)
                raise ReadError(f"{name}, line {first_lineno}: header has {what} '{axis}' "
                                f"column, expected columns named x,y,z (got {shown!r})")
            idx.append(lower.index(axis))
        pidx = [j for j in range(ncols) if j not in idx]
        pnames = [names[j] for j in pidx]
        body_start = first_lineno  # index of the line after the header
    else:
        if ncols < 3:
            raise ReadError(f"{name}, line {first_lineno}: expected 3 numeric columns x,y,z, "
                            f"got {ncols}")
        idx = [ncols - 3, ncols - 2, ncols - 1]
        pidx = list(range(ncols - 3))
        pnames = [f"col{j + 1}" for j in pidx]
        body_start = first_lineno - 1
    points, rows = [], []
    lines = text.split("\n")
    at = body_start
    while at < len(lines):  # the first row that breaks a rule is the one reported
        n, line = at + 1, lines[at]
        at += 1
        if not line.strip() or line.strip()[0] == "#":
            continue
        while True:  # a quoted field holding line ends: the row goes on on the next lines
            try:
                cells = fields(line, sep)
                break
            except Unclosed as exc:
                if at == len(lines):
                    raise ReadError(f"{name}, line {n}: {exc}") from None
                line = line + "\n" + lines[at]
                at += 1
            except QuoteError as exc:
                raise ReadError(f"{name}, line {n}: {exc}") from None
        if len(cells) != ncols:
            raise ReadError(f"{name}, line {n}: expected {ncols} {sep_name} separated columns "
                            f"(as on line {first_lineno}), got {len(cells)}")
        for j, axis in zip(idx, "xyz"):
            if "_" in cells[j][0] or not is_number(cells[j][0]):  # 1_000 is no CSV number
                shown = cells[j][0] if cells[j][1] else cells[j][0].strip()
                raise ReadError(f"{name}, line {n}: expected a number for {axis}, "
                                f"got {shown!r}")
        points.append([float(cells[j][0]) for j in idx])
        rows.append([t if q else t.strip() for t, q in (cells[j] for j in pidx)])
    if not points:
        raise ReadError(f"{name}: no data rows after the header, expected CSV lines x,y,z")
    return np.array(points, dtype=np.float64).reshape(-1, 3), pnames, rows
