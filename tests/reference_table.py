"""The CSV rules of diffsurf_cli.io.table.read_csv in slow, obvious Python: the oracle the
polars reader is checked against (str.strip, str.split, float() on the decoded text)."""
from __future__ import annotations

import numpy as np

from diffsurf_cli.io import ReadError

#: separators in order of preference, as the reader's docstring gives them.
SEPARATORS = ((",", "comma"), (";", "semicolon"), ("\t", "tab"), (None, "whitespace"))


#: whitespace but the tab: a line split at tabs is stripped of these only.
SPACE_BUT_TAB = "".join(chr(c) for c in range(0x110000) if chr(c).isspace() and c != 9)


def split(line: str, sep):
    """The fields of a data line (unstripped): a tab at either end of it ends an empty field,
    other whitespace there is no field."""
    if sep is None:
        return line.split()
    return line.strip(SPACE_BUT_TAB if sep == "\t" else None).split(sep)


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
    data = [(n, s) for n, s in enumerate(text.split("\n"), 1)
            if s.strip() and s.strip()[0] != "#"]
    if not data:
        raise ReadError(f"{name}: no data rows, expected CSV lines x,y,z")
    sep, sep_name = sniff([s for _, s in data[:21]])
    first_lineno, first = data[0]
    fields = split(first, sep)
    ncols = len(fields)
    if not all(is_number(f) for f in fields):
        names = [f.strip().strip('"').strip() for f in fields]
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
        body = data[1:]
    else:
        if ncols < 3:
            raise ReadError(f"{name}, line {first_lineno}: expected 3 numeric columns x,y,z, "
                            f"got {ncols}")
        idx = [ncols - 3, ncols - 2, ncols - 1]
        pidx = list(range(ncols - 3))
        pnames = [f"col{j + 1}" for j in pidx]
        body = data
    if not body:
        raise ReadError(f"{name}: no data rows after the header, expected CSV lines x,y,z")
    points, rows = [], []
    for n, line in body:  # the first line that breaks a rule is the one reported
        r = split(line, sep)
        if len(r) != ncols:
            raise ReadError(f"{name}, line {n}: expected {ncols} {sep_name} separated columns "
                            f"(as on line {first_lineno}), got {len(r)}")
        for j, axis in zip(idx, "xyz"):
            if not is_number(r[j]):
                raise ReadError(f"{name}, line {n}: expected a number for {axis}, "
                                f"got {r[j].strip()!r}")
        points.append([float(r[j]) for j in idx])
        rows.append([r[j].strip() for j in pidx])
    return np.array(points, dtype=np.float64).reshape(-1, 3), pnames, rows
