"""Fast, exact CSV text: a byte tokeniser with a correctly rounded float parser, and a
shortest round-trip float formatter (numba, compiled on first use and cached on disk).

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
formats with ``repr``. Both cached-power tables are computed at import with Python integers.

The reader runs in parallel over blocks of about 1 MiB of lines (a counting pass, then a
filling pass), the writer over blocks of rows; neither holds more than the text, the numbers
and 8 bytes per pass-through field. Nothing here knows about files, click or meshio: the
functions take and return arrays.
"""
from __future__ import annotations

import struct

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ._jit import numba as nb

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

_U0 = np.uint64(0)
_U1 = np.uint64(1)
_U2 = np.uint64(2)
_U4 = np.uint64(4)
_U9 = np.uint64(9)
_U10 = np.uint64(10)
_U32 = np.uint64(32)
_U52 = np.uint64(52)
_U53 = np.uint64(53)
_U63 = np.uint64(63)
_U100 = np.uint64(100)
_U1E8 = np.uint64(10**8)
_U64_M32 = np.uint64(0xFFFFFFFF)
_U64_1FF = np.uint64(0x1FF)
_FRAC_MASK = np.uint64((1 << 52) - 1)
_HIDDEN = np.uint64(1 << 52)
_SIGN = np.uint64(1 << 63)


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


# The kernels read these tables as globals, which numba freezes into the compiled code (and
# its disk cache): they are pure functions of this file, and passing arrays instead would
# cost reference counting on every call of the small per-number functions (2x slower).
_GRISU_F, _GRISU_E, _GRISU_K = grisu_cached_powers()
_LEMIRE_HI, _LEMIRE_LO = lemire_powers()
#: the exactly representable powers of ten (Clinger's fast path).
_POW10 = np.array([float(10**i) for i in range(23)])
#: 10^0 .. 10^19 as uint64 (Grisu digit generation).
_POW10_U64 = np.array([10**i for i in range(20)], dtype=np.uint64)
#: "00" "01" ... "99" as 200 ASCII bytes.
_DIGIT_PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()
#: NaN bit patterns float() gives for 'nan' and '-nan' on this platform.
_NAN_BITS = np.array([struct.unpack("<Q", struct.pack("<d", float(s)))[0]
                      for s in ("nan", "-nan")], dtype=np.uint64)


# --------------------------------------------------------------------------------------------
# bit-level helpers
# --------------------------------------------------------------------------------------------


@intrinsic
def _f64_from_bits(typingctx, bits):
    if bits != types.uint64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.uint64), codegen


@intrinsic
def _clz64(typingctx, value):
    if value != types.uint64:
        return None

    def codegen(context, builder, sig, args):
        return builder.ctlz(args[0], ir.Constant(ir.IntType(1), 0))

    return types.uint64(types.uint64), codegen


@nb.njit(cache=True)
def _mul128(a, b):
    """(high, low) 64-bit words of the 128-bit product of two uint64."""
    a0 = a & _U64_M32
    a1 = a >> _U32
    b0 = b & _U64_M32
    b1 = b >> _U32
    p00 = a0 * b0
    p01 = a0 * b1
    p10 = a1 * b0
    p11 = a1 * b1
    mid = (p00 >> _U32) + (p01 & _U64_M32) + (p10 & _U64_M32)
    hi = p11 + (p01 >> _U32) + (p10 >> _U32) + (mid >> _U32)
    lo = (mid << _U32) | (p00 & _U64_M32)
    return hi, lo


# --------------------------------------------------------------------------------------------
# whitespace
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _space_at(buf, i, end):
    """Byte length of the Unicode whitespace character starting at ``buf[i]``, 0 if none.

    The set is ``str.isspace``: ASCII 9-13, 28-32 and U+0085, U+00A0, U+1680, U+2000-U+200A,
    U+2028, U+2029, U+202F, U+205F, U+3000 in UTF-8.
    """
    b = buf[i]
    if b < 0x80:
        return 1 if (9 <= b <= 13) or (28 <= b <= 32) else 0
    if b == 0xC2:
        if i + 1 < end and (buf[i + 1] == 0x85 or buf[i + 1] == 0xA0):
            return 2
        return 0
    if i + 2 >= end:
        return 0
    b1 = buf[i + 1]
    b2 = buf[i + 2]
    if b == 0xE1:
        return 3 if b1 == 0x9A and b2 == 0x80 else 0
    if b == 0xE2:
        if b1 == 0x80 and (b2 <= 0x8A or b2 == 0xA8 or b2 == 0xA9 or b2 == 0xAF):
            return 3
        return 3 if b1 == 0x81 and b2 == 0x9F else 0
    if b == 0xE3:
        return 3 if b1 == 0x80 and b2 == 0x80 else 0
    return 0


@nb.njit(cache=True)
def _space_before(buf, start, j):
    """Byte length of the Unicode whitespace character ending just before ``buf[j]``."""
    b = buf[j - 1]
    if b < 0x80:
        return 1 if (9 <= b <= 13) or (28 <= b <= 32) else 0
    if j - 2 >= start and buf[j - 2] == 0xC2 and (b == 0x85 or b == 0xA0):
        return 2
    if j - 3 >= start and _space_at(buf, j - 3, j) == 3:
        return 3
    return 0


@nb.njit(cache=True)
def _ascii_space(b):
    return (9 <= b <= 13) or (28 <= b <= 32)


@nb.njit(cache=True)
def _strip(buf, s, e):
    """(s, e) with Unicode whitespace stripped from both ends, as ``str.strip()``."""
    while s < e:
        b = buf[s]
        if b < 0x80:
            if not _ascii_space(b):
                break
            s += 1
        else:
            n = _space_at(buf, s, e)
            if n == 0:
                break
            s += n
    while e > s:
        b = buf[e - 1]
        if b < 0x80:
            if not _ascii_space(b):
                break
            e -= 1
        else:
            n = _space_before(buf, s, e)
            if n == 0:
                break
            e -= n
    return s, e


@nb.njit(cache=True)
def _line_end(buf, i, n):
    """Index of the first newline at or after ``i``; ``n`` if there is none."""
    u = np.uint64(i)
    un = np.uint64(n)
    while u < un and buf[u] != 10:
        u += _U1
    return np.int64(u)


@nb.njit(cache=True)
def _data_extent(buf, pos, e):
    """Stripped extent (s, e) of the line buf[pos:e]; s == e for a blank or comment line."""
    s, e = _strip(buf, pos, e)
    if s < e and buf[s] == 35:  # '#'
        e = s
    return s, e


@nb.njit(cache=True)
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
    n = len(buf)
    lineno = 0
    while pos <= n:
        lineno += 1
        e = _line_end(buf, pos, n)
        s, d = _data_extent(buf, pos, e)
        if s < d:
            return s, d, lineno, e + 1
        pos = e + 1
    return -1, -1, lineno, pos


# --------------------------------------------------------------------------------------------
# decimal text -> float64
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _eisel_lemire(man, exp10, neg):
    """(ok, bits) of man * 10^exp10 correctly rounded; ok False when undecided or out of the
    normal range (Lemire 2021, as in Go's strconv)."""
    if exp10 < _LEMIRE_MIN or exp10 > _LEMIRE_MAX:
        return False, _U0
    clz = _clz64(man)
    man = man << clz
    ret_exp2 = ((217706 * exp10) >> 16) + 64 + 1023 - np.int64(clz)
    idx = exp10 - _LEMIRE_MIN
    x_hi, x_lo = _mul128(man, _LEMIRE_HI[idx])
    if (x_hi & _U64_1FF) == _U64_1FF and x_lo + man < man:
        y_hi, y_lo = _mul128(man, _LEMIRE_LO[idx])
        m_hi = x_hi
        m_lo = x_lo + y_hi
        if m_lo < x_lo:
            m_hi += _U1
        if (m_hi & _U64_1FF) == _U64_1FF and m_lo + _U1 == _U0 and y_lo + man < man:
            return False, _U0
        x_hi = m_hi
        x_lo = m_lo
    msb = x_hi >> _U63
    mant = x_hi >> (msb + _U9)
    ret_exp2 -= 1 - np.int64(msb)
    if x_lo == _U0 and (x_hi & _U64_1FF) == _U0 and (mant & np.uint64(3)) == _U1:
        return False, _U0
    mant += mant & _U1
    mant >>= _U1
    if (mant >> _U53) > _U0:
        mant >>= _U1
        ret_exp2 += 1
    if ret_exp2 <= 0 or ret_exp2 >= 0x7FF:
        return False, _U0
    bits = (np.uint64(ret_exp2) << _U52) | (mant & _FRAC_MASK)
    if neg:
        bits |= _SIGN
    return True, bits


@nb.njit(cache=True)
def _is_digit(b):
    return 48 <= b <= 57


@nb.njit(cache=True)
def _parse_float(buf, s, e):
    """Parse ``buf[s:e]`` as ``float()`` does: (status, value), status OK, INVALID or HARD.

    HARD means left to ``float()``: a token with a non-ASCII byte that is not plain ASCII
    grammar (Unicode digits and spaces are float()'s business), subnormal or overflowing
    results, and long mantissas the fast paths cannot settle.
    """
    st, v = _parse_ascii(buf, s, e)
    if st == INVALID:
        for k in range(s, e):
            if buf[k] >= 0x80:
                return HARD, 0.0
    return st, v


@nb.njit(cache=True)
def _parse_ascii(buf, s, e):
    # float() strips ASCII 9-13 and 32 (not 28-31) and, as Unicode, the rest: see HARD
    while s < e and (buf[s] == 32 or 9 <= buf[s] <= 13):
        s += 1
    while e > s and (buf[e - 1] == 32 or 9 <= buf[e - 1] <= 13):
        e -= 1
    if s >= e:
        return INVALID, 0.0
    i = s
    neg = False
    if buf[i] == 43 or buf[i] == 45:  # '+' '-'
        neg = buf[i] == 45
        i += 1
        if i >= e:
            return INVALID, 0.0
    c = buf[i] | 0x20
    if c == 105 or c == 110:  # 'i', 'n': inf, infinity, nan in any case
        if e - i > 8:
            return INVALID, 0.0
        word = np.uint64(0)
        for k in range(i, e):
            word = (word << np.uint64(8)) | np.uint64(buf[k] | 0x20)
        if word == np.uint64(0x696E66) or word == np.uint64(0x696E66696E697479):
            return OK, -np.inf if neg else np.inf
        if word == np.uint64(0x6E616E):
            return OK, _f64_from_bits(_NAN_BITS[1] if neg else _NAN_BITS[0])
        return INVALID, 0.0

    man = _U0
    nd = 0  # significant digits kept in man
    exp10 = 0
    truncated = False
    ndigits = 0
    for part in range(2):
        if part == 1:
            if i < e and buf[i] == 46:  # '.'
                i += 1
            else:
                break
        while i < e:
            b = buf[i]
            if _is_digit(b):
                d = np.uint64(b - 48)
                ndigits += 1
                if nd == 0 and d == _U0:
                    if part == 1:
                        exp10 -= 1
                elif nd < 19:
                    man = man * _U10 + d
                    nd += 1
                    if part == 1:
                        exp10 -= 1
                else:
                    if part == 0:
                        exp10 += 1
                    if d != _U0:
                        truncated = True
            elif b == 95:  # '_' only between two digits
                if i == s or not _is_digit(buf[i - 1]) or i + 1 >= e or not _is_digit(buf[i + 1]):
                    return INVALID, 0.0
            else:
                break
            i += 1
    if ndigits == 0:
        return INVALID, 0.0
    if i < e and (buf[i] | 0x20) == 101:  # 'e'
        i += 1
        eneg = False
        if i < e and (buf[i] == 43 or buf[i] == 45):
            eneg = buf[i] == 45
            i += 1
        ev = 0
        edigits = 0
        while i < e:
            b = buf[i]
            if _is_digit(b):
                edigits += 1
                if ev < 100000000:
                    ev = ev * 10 + (b - 48)
            elif b == 95:
                if not _is_digit(buf[i - 1]) or i + 1 >= e or not _is_digit(buf[i + 1]):
                    return INVALID, 0.0
            else:
                break
            i += 1
        if edigits == 0:
            return INVALID, 0.0
        exp10 += -ev if eneg else ev
    if i != e:
        return INVALID, 0.0

    if man == _U0:
        return OK, -0.0 if neg else 0.0
    if not truncated and man <= np.uint64(1 << 53) and -22 <= exp10 <= 22:
        # Clinger: man and 10^|exp10| are exact doubles, so one rounding gives the answer
        v = np.float64(man)
        v = v * _POW10[exp10] if exp10 >= 0 else v / _POW10[-exp10]
        return OK, -v if neg else v
    ok, bits = _eisel_lemire(man, exp10, neg)
    if not ok:
        return HARD, 0.0
    if truncated:
        # the true value lies in [man, man + 1) * 10^exp10: settled if both ends agree
        ok2, bits2 = _eisel_lemire(man + _U1, exp10, neg)
        if not ok2 or bits2 != bits:
            return HARD, 0.0
    return OK, _f64_from_bits(bits)


@nb.njit(cache=True)
def _parse_tokens(buf, starts, ends, out, status):
    for k in range(len(starts)):
        st, v = _parse_float(buf, starts[k], ends[k])
        status[k] = st
        out[k] = v


def parse_tokens(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray):
    """Parse the tokens ``buf[starts[k]:ends[k]]`` as ``float()``.

    Returns
    -------
    values : (m,) float64
    status : (m,) uint8
        OK, INVALID (``float()`` would raise) or HARD (left to ``float()``: value is 0).
    """
    m = len(starts)
    out = np.empty(m, np.float64)
    status = np.empty(m, np.uint8)
    _parse_tokens(buf, np.asarray(starts, np.int64), np.asarray(ends, np.int64), out, status)
    return out, status


# --------------------------------------------------------------------------------------------
# reading rows
# --------------------------------------------------------------------------------------------

#: bytes per block of lines, the unit of parallel work of the reader.
READ_BLOCK = 1 << 20


@nb.njit(cache=True, parallel=True)
def _count(buf, bounds, ncols, role, rows, text, lines, bad_line, bad_count):
    """First pass, in parallel over blocks of lines: per block the data rows, the bytes of
    pass-through text, the lines, and the first line (1-based in the block, 0 if none) whose
    field count is not ``ncols``, with that count."""
    n = len(buf)
    for b in nb.prange(len(bounds) - 1):
        pos = bounds[b]
        end = bounds[b + 1]
        r = 0
        t = 0
        ln = 0
        bl = 0
        bc = 0
        while pos < end:
            ln += 1
            e = _line_end(buf, pos, n)
            s, d = _data_extent(buf, pos, e)
            if s < d:
                j = 0
                fs = s
                for k in range(s, d + 1):
                    if k == d or buf[k] == 44:  # ','
                        if j < ncols and role[j] == 3:
                            a, c = _strip(buf, fs, k)
                            t += c - a
                        j += 1
                        fs = k + 1
                if j != ncols and bl == 0:
                    bl = ln
                    bc = j
                r += 1
            pos = e + 1
        rows[b] = r
        text[b] = t
        lines[b] = ln
        bad_line[b] = bl
        bad_count[b] = bc


@nb.njit(cache=True, parallel=True)
def _fill(buf, bounds, row0, text0, role, npass, points, text, offsets, hard, blk_bad):
    """Second pass, in parallel over blocks: coordinates into ``points``, pass-through fields
    into ``text``/``offsets``; ``hard`` gets bit a for a coordinate left to ``float()``;
    ``blk_bad`` the first row * 3 + axis of an invalid coordinate per block (-1 if none).
    Every data row has len(role) fields (checked by :func:`_count`)."""
    n = len(buf)
    for b in nb.prange(len(bounds) - 1):
        pos = bounds[b]
        end = bounds[b + 1]
        r = row0[b]
        tpos = text0[b]
        blk_bad[b] = -1
        while pos < end:
            e = _line_end(buf, pos, n)
            s, d = _data_extent(buf, pos, e)
            pos = e + 1
            if s >= d:
                continue
            j = 0
            fs = s
            flags = 0
            bad = -1
            p = 0
            for k in range(s, d + 1):
                if k == d or buf[k] == 44:
                    ro = role[j]
                    if ro == 3:
                        a, c = _strip(buf, fs, k)
                        offsets[r * npass + p] = tpos
                        _copy(text, tpos, buf, a, c - a)
                        tpos += c - a
                        p += 1
                    else:
                        st, v = _parse_float(buf, fs, k)
                        points[r, ro] = v
                        if st == HARD:
                            flags |= 1 << ro
                        elif st == INVALID and (bad < 0 or ro < bad):
                            bad = ro
                    j += 1
                    fs = k + 1
            hard[r] = flags
            if bad >= 0 and blk_bad[b] < 0:
                blk_bad[b] = r * 3 + bad
            r += 1


@nb.njit(cache=True)
def _locate(buf, bounds, row0, line0, rows, out):
    """out[k] = (line number from the reading start, stripped line start, end) of data row
    rows[k]; ``rows`` sorted."""
    n = len(buf)
    k = 0
    m = len(rows)
    while k < m:
        b = np.searchsorted(row0, rows[k], side="right") - 1
        pos = bounds[b]
        ln = line0[b]
        r = row0[b]
        while k < m and pos < bounds[b + 1]:
            ln += 1
            e = _line_end(buf, pos, n)
            s, d = _data_extent(buf, pos, e)
            pos = e + 1
            if s < d:
                while k < m and rows[k] == r:
                    out[k, 0] = ln
                    out[k, 1] = s
                    out[k, 2] = d
                    k += 1
                r += 1


def _line_blocks(buf, pos: int, size: int) -> np.ndarray:
    """Byte bounds of blocks of about ``size`` bytes from ``pos``, each starting a line."""
    n = len(buf)
    bounds = [pos]
    while bounds[-1] < n:
        cut = bounds[-1] + size
        bounds.append(n if cut >= n else min(int(_line_end(buf, cut, n)) + 1, n))
    return np.array(bounds, np.int64)


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
        rows = np.asarray(rows, np.int64)
        out = np.zeros((len(rows), 3), np.int64)
        if len(rows):
            _locate(self._buf, self._bounds, self._row0, self._line0, rows, out)
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
    role = np.full(ncols, -1, np.int8)
    role[list(passthrough)] = 3
    for axis, j in enumerate(xyz):
        role[j] = axis
    if (role < 0).any():
        raise ValueError("every field must be x, y, z or pass-through")
    npass = len(passthrough)
    bounds = _line_blocks(buf, pos, block)
    nblk = len(bounds) - 1
    rows = np.zeros(nblk, np.int64)
    ntext = np.zeros(nblk, np.int64)
    lines = np.zeros(nblk, np.int64)
    bad_line = np.zeros(nblk, np.int64)
    bad_count = np.zeros(nblk, np.int64)
    if nblk:
        _count(buf, bounds, ncols, role, rows, ntext, lines, bad_line, bad_count)
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
        _fill(buf, bounds, row0, text0, role, npass, points, text, offsets, hard, blk_bad)
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


@nb.njit(cache=True)
def _times(af, bf):
    """High 64 bits of af * bf, rounded (DiyFp multiplication)."""
    a = af >> _U32
    b = af & _U64_M32
    c = bf >> _U32
    d = bf & _U64_M32
    ac = a * c
    bc = b * c
    ad = a * d
    bd = b * d
    tmp = (bd >> _U32) + (ad & _U64_M32) + (bc & _U64_M32)
    tmp += np.uint64(1 << 31)
    return ac + (ad >> _U32) + (bc >> _U32) + (tmp >> _U32)


@nb.njit(cache=True)
def _round_weed(digits, dist_high_w, unsafe, rest, ten_kappa, unit):
    """Grisu3's RoundWeed on the digits held as an integer: (ok, digits)."""
    small = dist_high_w - unit
    big = dist_high_w + unit
    while (rest < small and unsafe - rest >= ten_kappa
           and (rest + ten_kappa < small or small - rest >= rest + ten_kappa - small)):
        digits -= _U1  # the last digit, one down
        rest += ten_kappa
    if (rest < big and unsafe - rest >= ten_kappa
            and (rest + ten_kappa < big or big - rest > rest + ten_kappa - big)):
        return False, digits
    return _U2 * unit <= rest and rest <= unsafe - _U4 * unit, digits


@nb.njit(cache=True)
def _grisu3(bits):
    """Shortest digits of the finite, positive double with ``bits`` (Grisu3).

    Returns (ok, digits, ndigits, decimal exponent): value = digits * 10^exponent, digits
    an integer of ndigits <= 17 decimal digits; ok is False when Grisu3 cannot prove them
    shortest and closest (about 0.5 % of doubles).
    """
    frac = bits & _FRAC_MASK
    biased = np.int64(bits >> _U52)
    if biased == 0:
        f = frac
        e = -1074
    else:
        f = frac | _HIDDEN
        e = biased - 1075
    # boundaries m- and m+, normalised to the exponent of m+
    pf = (f << _U1) + _U1
    pe = e - 1
    s = _clz64(pf)
    pf <<= s
    pe -= np.int64(s)
    if frac == _U0 and biased > 1:
        mf = (f << _U2) - _U1
        me = e - 2
    else:
        mf = (f << _U1) - _U1
        me = e - 1
    mf <<= np.uint64(me - pe)
    # w normalised: same exponent as m+
    wf = f << _clz64(f)
    # cached power c = 10^-mk with the scaled exponent in [-60, -32]; the index is
    # ceil((-60 - (pe + 64) + 63) * log10(2)) in integer arithmetic (exact for every pe)
    k = ((-61 - pe) * 78913 + (1 << 18) - 1) >> 18
    idx = (347 + k) // 8 + 1
    cf = _GRISU_F[idx]
    one_e = pe + _GRISU_E[idx] + 64
    mk = _GRISU_K[idx]
    w = _times(wf, cf)
    low = _times(mf, cf)
    high = _times(pf, cf)

    unit = _U1
    too_low = low - unit
    too_high = high + unit
    unsafe = too_high - too_low
    shift = np.uint64(-one_e)
    one_f = _U1 << shift
    integrals = too_high >> shift
    fractionals = too_high & (one_f - _U1)
    kappa = 1
    while kappa < 20 and _POW10_U64[kappa] <= integrals:
        kappa += 1
    # Grisu emits the digits of `integrals` from the top and stops after the first digit
    # where rest = (integrals mod 10^m) * 2^shift + fractionals < unsafe, m the digits left.
    # That rest grows with m, so the stopping m is the largest with integrals mod 10^m <= r_max:
    # found from the bottom with divisions by the constant 10 only.
    if unsafe > fractionals:
        r_max = (unsafe - fractionals - _U1) >> shift
        m = 0
        x = integrals
        r = _U0
        p = _U1
        while m < kappa - 1:
            q = x // _U10
            r2 = r + (x - q * _U10) * p
            if r2 > r_max:
                break
            r = r2
            x = q
            p *= _U10
            m += 1
        ok, digits = _round_weed(x, too_high - w, unsafe, (r << shift) + fractionals,
                                 p << shift, unit)
        return ok, digits, kappa - m, m - mk
    digits = integrals
    length = kappa
    kappa = 0
    while True:
        fractionals *= _U10
        unit *= _U10
        unsafe *= _U10
        digits = digits * _U10 + (fractionals >> shift)
        length += 1
        fractionals &= one_f - _U1
        kappa -= 1
        if fractionals < unsafe:
            ok, digits = _round_weed(digits, (too_high - w) * unit, unsafe, fractionals, one_f,
                                     unit)
            return ok, digits, length, kappa - mk


@nb.njit(cache=True)
def _put_small(out, p, digits, n):
    """Write the n <= 9 decimal digits of ``digits`` (zero padded) at out[p:p + n], two at
    a time."""
    q = np.uint64(p + n)
    while n >= 2:
        t = digits // _U100
        r = (digits - t * _U100) * _U2
        out[q - _U2] = _DIGIT_PAIRS[r]
        out[q - _U1] = _DIGIT_PAIRS[r + _U1]
        q -= _U2
        digits = t
        n -= 2
    if n == 1:
        out[q - _U1] = np.uint8(digits) + 48


@nb.njit(cache=True)
def _put_digits(out, p, digits, n):
    """Write the n <= 19 decimal digits of ``digits`` (zero padded) at out[p:p + n]; the low
    eight and the rest are two independent chains of divisions."""
    if n > 8:
        hi = digits // _U1E8
        _put_small(out, p + n - 8, digits - hi * _U1E8, 8)
        _put_small(out, p, hi, n - 8)
    else:
        _put_small(out, p, digits, n)


@nb.njit(cache=True)
def _format_one(bits, out, o):
    """Write repr() of the double with ``bits`` at ``out[o:]``; return its length, 0 if
    Grisu3 gave up."""
    p = o
    mag = bits & ~_SIGN
    if mag > np.uint64(0x7FF0000000000000):
        out[p] = 110  # nan: repr drops the sign
        out[p + 1] = 97
        out[p + 2] = 110
        return 3
    if bits != mag:
        out[p] = 45
        p += 1
    if mag == np.uint64(0x7FF0000000000000):
        out[p] = 105  # inf
        out[p + 1] = 110
        out[p + 2] = 102
        return p + 3 - o
    if mag == _U0:
        out[p] = 48  # 0.0
        out[p + 1] = 46
        out[p + 2] = 48
        return p + 3 - o
    ok, digits, n, k = _grisu3(mag)
    if not ok:
        return 0
    decpt = n + k
    # repr: positional notation for 1e-4 <= |v| < 1e16, else d.ddde+XX
    if -4 < decpt <= 16:
        if decpt <= 0:
            out[p] = 48
            out[p + 1] = 46
            p += 2
            for _ in range(-decpt):
                out[p] = 48
                p += 1
            _put_digits(out, p, digits, n)
            return p + n - o
        if decpt >= n:
            _put_digits(out, p, digits, n)
            p += n
            for _ in range(decpt - n):
                out[p] = 48
                p += 1
            out[p] = 46
            out[p + 1] = 48
            return p + 2 - o
        scale = _POW10_U64[n - decpt]
        whole = digits // scale
        _put_digits(out, p, whole, decpt)
        out[p + decpt] = 46
        _put_digits(out, p + decpt + 1, digits - whole * scale, n - decpt)
        return p + n + 1 - o
    if n > 1:
        scale = _POW10_U64[n - 1]
        lead = digits // scale
        out[p] = np.uint8(lead) + 48
        out[p + 1] = 46
        _put_digits(out, p + 2, digits - lead * scale, n - 1)
        p += n + 1
    else:
        out[p] = np.uint8(digits) + 48
        p += 1
    x = decpt - 1
    out[p] = 101  # e
    out[p + 1] = 45 if x < 0 else 43
    p += 2
    x = -x if x < 0 else x
    if x >= 100:
        out[p] = 48 + x // 100
        p += 1
        x %= 100
    out[p] = 48 + x // 10
    out[p + 1] = 48 + x % 10
    return p + 2 - o


@nb.njit(cache=True, parallel=True)
def _format_floats(bits, slots, lens, block):
    n = len(bits)
    nblk = (n + block - 1) // block
    for bi in nb.prange(nblk):
        for i in range(bi * block, min(n, (bi + 1) * block)):
            lens[i] = _format_one(bits[i], slots, i * FLOAT_WIDTH)


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
        _format_floats(values.view(np.uint64), slots.reshape(-1), lens, BLOCK)
        for i in np.flatnonzero(lens == 0).tolist():
            text = repr(float(values[i])).encode("ascii")
            slots[i, :len(text)] = np.frombuffer(text, np.uint8)
            lens[i] = len(text)
    return slots, lens


@nb.njit(cache=True)
def _format_int(v, out, o):
    """Write the decimal text of the int64 ``v`` at ``out[o:]``; return its length."""
    # the magnitude as uint64, so that int64 min needs no special case
    m = np.uint64(-(v + 1)) + _U1 if v < 0 else np.uint64(v)
    n = 1
    t = m // _U10
    while t != _U0:
        n += 1
        t //= _U10
    if v < 0:
        out[o] = 45
        o += 1
        n += 1
    q = o + n - (1 if v < 0 else 0)
    while True:
        q -= 1
        t = m // _U10
        out[q] = np.uint8(m - t * _U10) + 48
        m = t
        if m == _U0:
            break
    return n


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


@nb.njit(cache=True, parallel=True)
def _format_slots(fbits, ints, layout, words, wlens, slots, lens, block):
    """Format row i's columns into slots[i, off_k:off_k + w_k], lengths into lens[i, k].

    layout[k] = (kind, row of fbits/ints holding column k, byte offset, word base); a LABEL
    column's code c is words row base + c. A float Grisu3 gives up on gets length 0.
    """
    n, width = slots.shape
    ncol = len(layout)
    nblk = (n + block - 1) // block
    flat = slots.reshape(-1)
    wwidth = words.shape[1]
    words_flat = words.reshape(-1)
    for bi in nb.prange(nblk):
        for i in range(bi * block, min(n, (bi + 1) * block)):
            base = i * width
            for k in range(ncol):
                kind = layout[k, 0]
                src = layout[k, 1]
                o = base + layout[k, 2]
                if kind == 0:
                    lens[i, k] = _format_one(fbits[src, i], flat, o)
                elif kind == 1:
                    lens[i, k] = _format_int(ints[src, i], flat, o)
                else:
                    w = layout[k, 3] + ints[src, i]
                    _copy(flat, o, words_flat, w * wwidth, wlens[w])
                    lens[i, k] = wlens[w]


@nb.njit(cache=True)
def _put_texts(slots, lens, rows, cols, offs, blob, starts):
    """slots/lens of item (rows[m], cols[m]) at byte offs[m] := blob[starts[m]:starts[m+1]]."""
    width = slots.shape[1]
    flat = slots.reshape(-1)
    for m in range(len(rows)):
        a = starts[m]
        b = starts[m + 1]
        _copy(flat, rows[m] * width + offs[m], blob, a, b - a)
        lens[rows[m], cols[m]] = b - a


@nb.njit(cache=True)
def _copy(dst, d, src, s, n):
    """dst[d:d + n] = src[s:s + n]. Unsigned indices: numba's wraparound test on signed ones
    keeps LLVM from turning the loop into a block copy (3x slower here)."""
    ud = np.uint64(d)
    us = np.uint64(s)
    for q in range(np.uint64(n)):
        dst[ud + q] = src[us + q]


@nb.njit(cache=True, parallel=True)
def _join_slots(out, start, data, offsets, k, slots, lens, layout, block):
    """Row i of the output at out[start[i]:start[i + 1]]: the k text fields, then the slots,
    comma separated, newline terminated.

    Float and int slots are copied whole (a constant-size copy) and the position advanced by
    the text's length: the surplus is overwritten by what follows, within the row or by the
    next row, which the same thread writes later; the last row of a block is copied exactly.
    ``out`` needs FLOAT_WIDTH bytes of slack at the end.
    """
    n = len(start) - 1
    ncol = len(layout)
    width = slots.shape[1]
    flat = slots.reshape(-1)
    nblk = (n + block - 1) // block
    for bi in nb.prange(nblk):
        last = min(n, (bi + 1) * block)
        for i in range(bi * block, last):
            exact = i == last - 1
            p = start[i]
            for j in range(k):
                a = offsets[i * k + j]
                m = offsets[i * k + j + 1] - a
                _copy(out, p, data, a, m)
                p += m
                out[p] = 44
                p += 1
            base = i * width
            for c in range(ncol):
                o = base + layout[c, 2]
                m = lens[i, c]
                kind = layout[c, 0]
                if kind == 0 and not exact:
                    _copy(out, p, flat, o, FLOAT_WIDTH)
                elif kind == 1 and not exact:
                    _copy(out, p, flat, o, INT_WIDTH)
                else:
                    _copy(out, p, flat, o, m)
                p += m
                out[p] = 44
                p += 1
            out[start[i + 1] - 1] = 10


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
    slots = np.empty((n, max(off, 1)), np.uint8)
    lens = np.zeros((n, ncol), np.int64)
    if ncol and n:
        _format_slots(fbits, ints, layout, words, wlen, slots, lens, BLOCK)
        # the floats Grisu3 left undecided (about 0.5 %): repr, in one batch
        floats = np.flatnonzero(layout[:, 0] == FLOAT)
        rows, kf = np.nonzero(lens[:, floats] == 0)
        if len(rows):
            cols = floats[kf]
            values = fbits[layout[cols, 1], rows].view(np.float64)
            texts = [repr(v).encode("ascii") for v in values.tolist()]
            starts = np.zeros(len(texts) + 1, np.int64)
            np.cumsum([len(t) for t in texts], out=starts[1:])
            _put_texts(slots, lens, rows, cols, layout[cols, 2],
                       np.frombuffer(b"".join(texts), np.uint8), starts)

    k = text.ncols if text is not None else 0
    row_len = lens.sum(axis=1) + max(k + ncol, 1)
    data = np.zeros(1, np.uint8)
    offsets = np.zeros(1, np.int64)
    if k:
        part = text.rows(start, stop)
        data, offsets = part.data, part.offsets
        row_len += offsets[k::k] - offsets[:-1:k]
    bounds = np.zeros(n + 1, np.int64)
    np.cumsum(row_len, out=bounds[1:])
    out = np.empty(int(bounds[-1]) + FLOAT_WIDTH, np.uint8)
    if n:
        _join_slots(out, bounds, data, offsets, k, slots, lens, layout, BLOCK)
    return out[:bounds[-1]]
