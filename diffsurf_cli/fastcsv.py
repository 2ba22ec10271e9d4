"""Fast, exact CSV text: a byte tokeniser with a correctly rounded float parser, and a
shortest round-trip float formatter (plain C in ``_ccsv.c``, called through ctypes).

Reading gives what Python's ``str.strip`` / ``str.split(",")`` / ``float()`` give on the
decoded text, bit for bit, without building a Python object per field:

- lines end at ``\\n`` only; blank lines and lines whose first non-blank character is ``#``
  are skipped; whitespace is Unicode whitespace (``str.isspace``), stripped from lines and
  from pass-through fields;
- a coordinate token follows ``float()``'s grammar (sign, digits with single underscores
  between digits, ``.``, exponent, ``inf``/``infinity``/``nan`` in any case) and is
  converted by Clinger's exact fast path or the Eisel-Lemire algorithm (a truncated 128-bit
  table of powers of ten); the rare tokens neither settles (subnormals, overflow, more than
  19 digits near a rounding boundary, any non-ASCII byte) are marked *hard* and the caller
  converts them with ``float()`` itself.

Writing gives ``repr(float)`` exactly: Grisu3 (Loitsch 2010, as in double-conversion) finds
the shortest digits for about 99.5 % of doubles and reports the others, which the wrapper
formats with ``repr``. Both cached-power tables are computed at import with Python integers
and handed to the C code once.

The C code is built by ``pip install`` (see setup.py and :mod:`diffsurf_cli._native`);
nothing is compiled at run time. The reader runs in parallel (OpenMP) over blocks of about
1 MiB of lines (a counting pass, then a filling pass), the writer over blocks of rows; neither
holds more than the text, the numbers and 8 bytes per pass-through field. ctypes releases the
GIL during the calls. Nothing here knows about files, click or meshio: the functions take and
return arrays.
"""
from __future__ import annotations

import ctypes
import struct

import numpy as np

from ._native import F64, I8, I64, U8, U64, library

__all__ = [
    "TextColumns",
    "Column",
    "first_data_line",
    "read_rows",
    "parse_tokens",
    "format_floats",
    "format_rows",
]

#: rows per block: the unit of parallel work of the writer.
BLOCK = 4096
#: bytes of a formatted float: '-' + 17 digits + '.' + 'e-308' is 24.
FLOAT_WIDTH = 24
#: bytes of a formatted int64: '-9223372036854775808'.
INT_WIDTH = 20

# parse status of one token
OK, INVALID, HARD = 0, 1, 2


# --------------------------------------------------------------------------------------------
# tables, computed exactly with Python integers
# --------------------------------------------------------------------------------------------


def grisu_cached_powers():
    """Normalised 64-bit approximations of 10^k, k = -348, -340, ..., 340 (Grisu).

    Returns
    -------
    f : (87,) uint64
        Significands in [2^63, 2^64), rounded to nearest.
    e : (87,) int64
        Binary exponents: 10^k ~ f * 2^e.
    k : (87,) int64
        The decimal exponents.
    """
    ks = list(range(-348, 341, 8))
    f = np.empty(len(ks), np.uint64)
    e = np.empty(len(ks), np.int64)
    for i, k in enumerate(ks):
        num, den = (10**k, 1) if k >= 0 else (1, 10**-k)
        # f = num / (den * 2^e) in [2^63, 2^64)
        exp = num.bit_length() - den.bit_length() - 63
        while True:
            n, d = (num, den << exp) if exp >= 0 else (num << -exp, den)
            if n < d << 63:
                exp -= 1
            elif n >= d << 64:
                exp += 1
            else:
                break
        q = (2 * n + d) // (2 * d)
        if q == 1 << 64:
            q, exp = q >> 1, exp + 1
        f[i], e[i] = q, exp
    return f, e, np.array(ks, dtype=np.int64)


#: decimal exponents of the Eisel-Lemire table.
_LEMIRE_MIN, _LEMIRE_MAX = -348, 347


def lemire_powers():
    """128-bit truncated significands of 10^q, q = -348..347 (Eisel-Lemire).

    Returns
    -------
    hi, lo : (696,) uint64
        floor(10^q * 2^s) for the s that puts it in [2^127, 2^128), high and low words.
    """
    n = _LEMIRE_MAX - _LEMIRE_MIN + 1
    hi = np.empty(n, np.uint64)
    lo = np.empty(n, np.uint64)
    mask = (1 << 64) - 1
    for i, q in enumerate(range(_LEMIRE_MIN, _LEMIRE_MAX + 1)):
        if q >= 0:
            v = 10**q
            b = v.bit_length()
            m = v << (128 - b) if b <= 128 else v >> (b - 128)
        else:
            d = 10**-q
            m = (1 << (127 + d.bit_length())) // d
        hi[i], lo[i] = m >> 64, m & mask
    return hi, lo


# --------------------------------------------------------------------------------------------
# the compiled library
# --------------------------------------------------------------------------------------------

_N = ctypes.c_int64
_SIGNATURES = {
    "ccsv_init": (None, [U64, I64, I64, U64, U64, U64]),
    "ccsv_table_sizes": (ctypes.c_int, [I64]),
    "ccsv_first_data_line": (None, [U8, _N, _N, I64]),
    "ccsv_strip": (None, [U8, I64, I64, _N, I64, I64]),
    "ccsv_line_blocks": (_N, [U8, _N, _N, _N, I64]),
    "ccsv_parse_tokens": (None, [U8, I64, I64, _N, F64, U8]),
    "ccsv_count": (None, [U8, _N, I64, _N, _N, I8, I64, I64, I64, I64, I64]),
    "ccsv_fill": (None, [U8, _N, I64, _N, I64, I64, I8, _N, F64, U8, I64, U8, I64]),
    "ccsv_locate": (None, [U8, _N, I64, _N, I64, I64, I64, _N, I64]),
    "ccsv_grisu3": (None, [U64, _N, U8, U64, I64, I64]),
    "ccsv_format_floats": (None, [U64, _N, U8, U8, _N]),
    "ccsv_format_slots": (None, [U64, I64, _N, I64, _N, U8, _N, I64, U8, _N, I64, _N]),
    "ccsv_put_texts": (None, [U8, _N, I64, _N, I64, I64, I64, _N, U8, I64]),
    "ccsv_join_slots": (None, [U8, I64, _N, U8, I64, _N, U8, _N, I64, I64, _N, _N]),
}


def _load():
    lib = library("_ccsv")
    for name, (restype, argtypes) in _SIGNATURES.items():
        fn = getattr(lib, name)
        fn.restype = restype
        fn.argtypes = argtypes
    sizes = np.zeros(3, np.int64)
    lib.ccsv_table_sizes(sizes)
    if sizes.tolist() != [len(_GRISU_F), len(_LEMIRE_HI), _LEMIRE_MIN]:
        raise ImportError(f"diffsurf's compiled _ccsv does not match fastcsv.py (tables "
                          f"{sizes.tolist()}): reinstall diffsurf with pip")
    # set once, before any other call: afterwards the C code only reads them (thread-safe)
    lib.ccsv_init(_GRISU_F, _GRISU_E, _GRISU_K, _LEMIRE_HI, _LEMIRE_LO, _NAN_BITS)
    return lib


_GRISU_F, _GRISU_E, _GRISU_K = grisu_cached_powers()
_LEMIRE_HI, _LEMIRE_LO = lemire_powers()
#: NaN bit patterns float() gives for 'nan' and '-nan' on this platform.
_NAN_BITS = np.array([struct.unpack("<Q", struct.pack("<d", float(s)))[0]
                      for s in ("nan", "-nan")], dtype=np.uint64)
_C = _load()


def _u8(buf) -> np.ndarray:
    return np.ascontiguousarray(buf, dtype=np.uint8)


def _i64(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.int64)


# --------------------------------------------------------------------------------------------
# lines and tokens
# --------------------------------------------------------------------------------------------


def first_data_line(buf, pos):
    """The first non-blank, non-comment line at or after byte ``pos``.

    Returns
    -------
    start, end : int
        Its stripped extent; (-1, -1) if there is none.
    lineno : int
        Its 1-based line number counted from ``pos``.
    after : int
        The position of the next line.
    """
    buf = _u8(buf)
    out = np.empty(4, np.int64)
    _C.ccsv_first_data_line(buf, len(buf), int(pos), out)
    start, end, lineno, after = out.tolist()
    return start, end, lineno, after


def strip_extents(buf, starts, ends):
    """(starts, ends) of the spans ``buf[starts[k]:ends[k]]`` with Unicode whitespace
    stripped from both ends, as ``str.strip()`` strips the decoded text."""
    buf, starts, ends = _u8(buf), _i64(starts), _i64(ends)
    s = np.empty(len(starts), np.int64)
    e = np.empty(len(starts), np.int64)
    _C.ccsv_strip(buf, starts, ends, len(starts), s, e)
    return s, e


def parse_tokens(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray):
    """Parse the tokens ``buf[starts[k]:ends[k]]`` as ``float()``.

    Returns
    -------
    values : (m,) float64
    status : (m,) uint8
        OK, INVALID (``float()`` would raise) or HARD (left to ``float()``: value is 0).
    """
    buf, starts, ends = _u8(buf), _i64(starts), _i64(ends)
    m = len(starts)
    out = np.empty(m, np.float64)
    status = np.empty(m, np.uint8)
    _C.ccsv_parse_tokens(buf, starts, ends, m, out, status)
    return out, status


# --------------------------------------------------------------------------------------------
# reading rows
# --------------------------------------------------------------------------------------------

#: bytes per block of lines, the unit of parallel work of the reader.
READ_BLOCK = 1 << 20


def _line_blocks(buf, pos: int, size: int) -> np.ndarray:
    """Byte bounds of blocks of about ``size`` bytes from ``pos``, each starting a line."""
    bounds = np.empty(max(len(buf) - pos, 0) // size + 2, np.int64)
    k = _C.ccsv_line_blocks(buf, len(buf), pos, size, bounds)
    return bounds[:k].copy()


class RowsRead:
    """What :func:`read_rows` found.

    Attributes
    ----------
    points : (p, 3) float64
        Coordinates; hard ones (see ``hard``) are 0 until the caller fills them in.
    text : TextColumns
        The pass-through fields.
    bad_columns : (int, int) or None
        (line number from the start, field count) of the first row with a wrong field count;
        ``points`` and ``text`` are then empty.
    bad_number : int
        row * 3 + axis of the first invalid coordinate (row order, then x, y, z), -1 if none.
    hard : (h,) int64
        row * 3 + axis of the coordinates left to ``float()``, in the same order.
    """

    def __init__(self, buf, bounds, row0, line0, points, text, bad_columns, bad_number, hard):
        self._buf = buf
        self._bounds = bounds
        self._row0 = row0
        self._line0 = line0
        self.points = points
        self.text = text
        self.bad_columns = bad_columns
        self.bad_number = bad_number
        self.hard = hard

    def lines(self, rows):
        """(line number from the start, stripped start, end) of each data row in ``rows``
        (sorted, unique), as an (m, 3) int64 array."""
        rows = _i64(rows)
        out = np.zeros((len(rows), 3), np.int64)
        if len(rows):
            _C.ccsv_locate(self._buf, len(self._buf), self._bounds, len(self._bounds) - 1,
                           self._row0, self._line0, rows, len(rows), out)
        return out


def read_rows(buf: np.ndarray, pos: int, ncols: int, xyz, passthrough,
              block: int = READ_BLOCK) -> RowsRead:
    """Tokenise and convert the data rows of ``buf`` (uint8) from byte ``pos`` on.

    Parameters
    ----------
    buf : (n,) uint8
        The whole text, valid UTF-8 (BOM removed).
    pos : int
        Where the rows start (after the header line, if any); line 1 is the line there.
    ncols : int
        Fields every row must have.
    xyz : 3 ints
        Field indices of x, y and z.
    passthrough : sequence of int
        Field indices carried through as text, in output order (ascending).
    block : int
        Bytes per block of lines (the unit of parallel work).

    Returns
    -------
    RowsRead
    """
    buf = _u8(buf)
    pos, ncols = int(pos), int(ncols)
    block = max(int(block), 1)  # the blocks change the parallel work only, not the result
    role = np.full(ncols, -1, np.int8)
    role[list(passthrough)] = 3
    for axis, j in enumerate(xyz):
        role[j] = axis
    if (role < 0).any():
        raise ValueError("every field must be x, y, z or pass-through")
    npass = len(passthrough)
    n = len(buf)
    bounds = _line_blocks(buf, pos, block)
    nblk = len(bounds) - 1
    rows = np.zeros(nblk, np.int64)
    ntext = np.zeros(nblk, np.int64)
    lines = np.zeros(nblk, np.int64)
    bad_line = np.zeros(nblk, np.int64)
    bad_count = np.zeros(nblk, np.int64)
    if nblk:
        _C.ccsv_count(buf, n, bounds, nblk, ncols, role, rows, ntext, lines, bad_line,
                      bad_count)
    row0 = np.concatenate([[0], np.cumsum(rows)]).astype(np.int64)
    line0 = np.concatenate([[0], np.cumsum(lines)]).astype(np.int64)
    text0 = np.concatenate([[0], np.cumsum(ntext)]).astype(np.int64)
    nrows = int(row0[-1])
    bad = np.flatnonzero(bad_line)
    if len(bad):
        b = bad[0]
        return RowsRead(buf, bounds, row0, line0, np.zeros((0, 3)), TextColumns.empty(0, npass),
                        (int(line0[b] + bad_line[b]), int(bad_count[b])), -1,
                        np.zeros(0, np.int64))
    points = np.empty((nrows, 3), np.float64)
    text = np.empty(int(text0[-1]), np.uint8)
    offsets = np.empty(nrows * npass + 1, np.int64)
    offsets[-1] = len(text)
    hard = np.empty(nrows, np.uint8)
    blk_bad = np.empty(nblk, np.int64)
    if nrows:
        _C.ccsv_fill(buf, n, bounds, nblk, row0, text0, role, npass, points, text, offsets,
                     hard, blk_bad)
    else:
        blk_bad[:] = -1  # (no rows: nothing is invalid)
    bad = blk_bad[blk_bad >= 0]
    bad_number = int(bad[0]) if len(bad) else -1
    hrows = np.flatnonzero(hard)
    if len(hrows):
        flags = hard[hrows]
        hard_idx = np.concatenate([hrows[(flags >> a) & 1 == 1] * 3 + a for a in range(3)])
        hard_idx.sort()
    else:
        hard_idx = np.zeros(0, np.int64)
    return RowsRead(buf, bounds, row0, line0, points, TextColumns(text, offsets, nrows, npass),
                    None, bad_number, hard_idx)


# --------------------------------------------------------------------------------------------
# pass-through text
# --------------------------------------------------------------------------------------------


class TextColumns:
    """Text columns carried through unchanged: one UTF-8 byte buffer and field offsets.

    Field j of row i is ``data[offsets[i * ncols + j]:offsets[i * ncols + j + 1]]``; the
    memory is the text itself plus 8 bytes a field, instead of a Python list per row.

    Attributes
    ----------
    data : (b,) uint8
    offsets : (nrows * ncols + 1,) int64
    nrows, ncols : int
    """

    __slots__ = ("data", "offsets", "nrows", "ncols")

    def __init__(self, data, offsets, nrows, ncols):
        self.data = data
        self.offsets = offsets
        self.nrows = int(nrows)
        self.ncols = int(ncols)

    @classmethod
    def empty(cls, nrows: int, ncols: int = 0) -> "TextColumns":
        """``nrows`` rows of ``ncols`` empty fields."""
        return cls(np.zeros(0, np.uint8), np.zeros(nrows * ncols + 1, np.int64), nrows, ncols)

    @classmethod
    def from_rows(cls, rows, ncols: int | None = None) -> "TextColumns":
        """From a sequence of rows, each a sequence of ``ncols`` str."""
        rows = list(rows)
        if ncols is None:
            ncols = len(rows[0]) if rows else 0
        fields = []
        for i, row in enumerate(rows):
            if len(row) != ncols:
                raise ValueError(f"row {i} has {len(row)} fields, expected {ncols}")
            fields.extend(str(f).encode("utf-8") for f in row)
        lengths = np.fromiter(map(len, fields), np.int64, len(fields))
        offsets = np.zeros(len(fields) + 1, np.int64)
        np.cumsum(lengths, out=offsets[1:])
        data = np.frombuffer(b"".join(fields), np.uint8).copy()
        return cls(data, offsets, len(rows), ncols)

    def __len__(self) -> int:
        return self.nrows

    def __getitem__(self, i):
        """Row ``i`` as a list of str; a slice gives a TextColumns view."""
        if isinstance(i, slice):
            start, stop, step = i.indices(self.nrows)
            if step != 1:
                raise ValueError("TextColumns slices take no step")
            return self.rows(start, max(start, stop))
        i = int(i)
        if i < 0:
            i += self.nrows
        if not 0 <= i < self.nrows:
            raise IndexError("row index out of range")
        return self.row(i)

    def __iter__(self):
        for i in range(self.nrows):
            yield self.row(i)

    def __eq__(self, other):
        if isinstance(other, TextColumns):
            return self.ncols == other.ncols and self.tolist() == other.tolist()
        if isinstance(other, (list, tuple)):
            return self.tolist() == [list(r) for r in other]
        return NotImplemented

    __hash__ = None

    def __repr__(self) -> str:
        return f"TextColumns({self.nrows} rows x {self.ncols} columns, {len(self.data)} bytes)"

    def field(self, i: int, j: int) -> str:
        k = i * self.ncols + j
        return self.data[self.offsets[k]:self.offsets[k + 1]].tobytes().decode("utf-8")

    def row(self, i: int) -> list[str]:
        return [self.field(i, j) for j in range(self.ncols)]

    def column(self, j: int) -> list[str]:
        """Field ``j`` of every row."""
        raw = self.data.tobytes()
        off = self.offsets[j::self.ncols].tolist() if self.ncols else []
        end = self.offsets[j + 1::self.ncols].tolist() if self.ncols else []
        return [raw[a:b].decode("utf-8") for a, b in zip(off, end)]

    def tolist(self) -> list[list[str]]:
        return [self.row(i) for i in range(self.nrows)]

    def rows(self, start: int, stop: int) -> "TextColumns":
        """Rows ``start:stop`` (a view sharing ``data``)."""
        stop = min(stop, self.nrows)
        k = self.ncols
        return TextColumns(self.data, self.offsets[start * k:stop * k + 1], stop - start, k)

    def numbers(self, j: int):
        """Field ``j`` of every row as float64 (``float()`` semantics), None if any field is
        not a number."""
        k = self.ncols
        starts = self.offsets[j:self.nrows * k:k]
        ends = self.offsets[j + 1:self.nrows * k + 1:k]
        values, status = parse_tokens(self.data, starts, ends)
        if (status == INVALID).any():
            return None
        for i in np.flatnonzero(status == HARD):
            try:
                values[i] = float(self.field(int(i), j))
            except ValueError:
                return None
        return values


# --------------------------------------------------------------------------------------------
# float64 -> shortest text (Grisu3)
# --------------------------------------------------------------------------------------------


def grisu3_digits(bits):
    """Grisu3 of finite, positive doubles given by their bits.

    Returns
    -------
    ok : (n,) bool
        False where Grisu3 cannot prove the digits shortest and closest (about 0.5 %).
    digits : (n,) uint64
    ndigits, exponent : (n,) int64
        value = digits * 10^exponent, digits an integer of ndigits <= 17 decimal digits.
    """
    bits = np.ascontiguousarray(np.atleast_1d(bits), dtype=np.uint64)
    n = len(bits)
    ok = np.empty(n, np.uint8)
    digits = np.empty(n, np.uint64)
    ndigits = np.empty(n, np.int64)
    exponent = np.empty(n, np.int64)
    _C.ccsv_grisu3(bits, n, ok, digits, ndigits, exponent)
    return ok.astype(bool), digits, ndigits, exponent


def format_floats(values: np.ndarray):
    """repr() of every float64 value, as fixed-width byte slots.

    Returns
    -------
    slots : (n, 24) uint8
        Row i holds the text in its first ``lens[i]`` bytes.
    lens : (n,) uint8
    """
    values = np.ascontiguousarray(values, dtype=np.float64)
    n = len(values)
    slots = np.empty((n, FLOAT_WIDTH), np.uint8)
    lens = np.empty(n, np.uint8)
    if n:
        _C.ccsv_format_floats(values.view(np.uint64), n, slots, lens, BLOCK)
        for i in np.flatnonzero(lens == 0).tolist():
            text = repr(float(values[i])).encode("ascii")
            slots[i, :len(text)] = np.frombuffer(text, np.uint8)
            lens[i] = len(text)
    return slots, lens


# --------------------------------------------------------------------------------------------
# rows of text
# --------------------------------------------------------------------------------------------

#: column kinds of :class:`Column`.
FLOAT, INT, LABEL = 0, 1, 2


class Column:
    """One output column, ready for :func:`format_rows`.

    Attributes
    ----------
    kind : FLOAT, INT or LABEL
    values : (p,) float64 or int64
        The numbers, or the label codes.
    table : (w, width) uint8 and lens (w,) : the UTF-8 words of a LABEL column.
    """

    __slots__ = ("kind", "values", "table", "lens")

    def __init__(self, values, words=None):
        arr = np.asarray(values)
        self.table = self.lens = None
        if words is not None:
            self.kind = LABEL
            self.values = arr.astype(np.int64, copy=False)
            encoded = [str(w).encode("utf-8") for w in words]
            width = max([len(w) for w in encoded] + [1])
            self.table = np.zeros((len(encoded), width), np.uint8)
            for k, w in enumerate(encoded):
                self.table[k, :len(w)] = np.frombuffer(w, np.uint8)
            self.lens = np.array([len(w) for w in encoded], np.int64)
        elif arr.dtype.kind == "f":
            self.kind = FLOAT
            self.values = arr.astype(np.float64, copy=False)
        else:
            self.kind = INT
            self.values = arr.astype(np.int64, copy=False)

    @property
    def width(self) -> int:
        return (FLOAT_WIDTH, INT_WIDTH, self.table.shape[1] if self.table is not None else 0)[
            self.kind]


def format_rows(text: TextColumns | None, columns, start: int, stop: int) -> np.ndarray:
    """CSV text of rows ``start:stop``: the fields of ``text`` then the columns, comma
    separated, each row ending in a newline (an empty line for a row without fields).

    Parameters
    ----------
    text : TextColumns or None
        Leading (pass-through) fields.
    columns : list of Column
        Floats are spelled as ``repr`` spells them, ints as plain decimals, labels as words.
    start, stop : int
        The rows.

    Returns
    -------
    (b,) uint8
        UTF-8 text.
    """
    n = stop - start
    ncol = len(columns)
    layout = np.zeros((max(ncol, 1), 4), np.int64)[:ncol]
    nf = sum(c.kind == FLOAT for c in columns)
    fbits = np.empty((max(nf, 1), n), np.uint64)
    ints = np.empty((max(ncol - nf, 1), n), np.int64)
    tables = [np.zeros((0, 1), np.uint8)]
    wlens = [np.zeros(0, np.int64)]
    nwords = 0
    off = fi = ii = 0
    for k, c in enumerate(columns):
        if c.kind == FLOAT:
            fbits[fi] = c.values[start:stop].view(np.uint64)
            layout[k] = (FLOAT, fi, off, 0)
            fi += 1
        else:
            ints[ii] = c.values[start:stop]
            layout[k] = (c.kind, ii, off, nwords)
            ii += 1
            if c.kind == LABEL:
                tables.append(c.table)
                wlens.append(c.lens)
                nwords += len(c.table)
        off += c.width
    wmax = max(t.shape[1] for t in tables)
    words = np.zeros((max(nwords, 1), wmax), np.uint8)
    row = 0
    for t in tables:
        words[row:row + len(t), :t.shape[1]] = t
        row += len(t)
    wlen = np.concatenate(wlens) if nwords else np.zeros(1, np.int64)
    width = max(off, 1)
    slots = np.empty((n, width), np.uint8)
    lens = np.zeros((n, ncol), np.int64)
    if ncol and n:
        _C.ccsv_format_slots(fbits, ints, n, layout, ncol, words, wmax, wlen, slots, width,
                             lens, BLOCK)
        # the floats Grisu3 left undecided (about 0.5 %): repr, in one batch
        floats = np.flatnonzero(layout[:, 0] == FLOAT)
        rows, kf = np.nonzero(lens[:, floats] == 0)
        if len(rows):
            cols = floats[kf]
            values = fbits[layout[cols, 1], rows].view(np.float64)
            texts = [repr(v).encode("ascii") for v in values.tolist()]
            starts = np.zeros(len(texts) + 1, np.int64)
            np.cumsum([len(t) for t in texts], out=starts[1:])
            _C.ccsv_put_texts(slots, width, lens, ncol, _i64(rows), _i64(cols),
                              _i64(layout[cols, 2]), len(rows),
                              np.frombuffer(b"".join(texts), np.uint8), starts)

    k = text.ncols if text is not None else 0
    row_len = lens.sum(axis=1) + max(k + ncol, 1)
    data = np.zeros(1, np.uint8)
    offsets = np.zeros(1, np.int64)
    if k:
        part = text.rows(start, stop)
        data, offsets = _u8(part.data), _i64(part.offsets)
        row_len += offsets[k::k] - offsets[:-1:k]
    bounds = np.zeros(n + 1, np.int64)
    np.cumsum(row_len, out=bounds[1:])
    out = np.empty(int(bounds[-1]) + FLOAT_WIDTH, np.uint8)
    if n:
        _C.ccsv_join_slots(out, bounds, n, data, offsets, k, slots, width, lens, layout, ncol,
                           BLOCK)
    return out[:bounds[-1]]
