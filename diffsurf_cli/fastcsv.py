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

Nothing here knows about files, click or meshio: the functions take and return arrays.
"""
from __future__ import annotations

import struct

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = [
    "TextColumns",
    "first_data_line",
    "read_rows",
    "locate_rows",
    "format_floats",
    "format_ints",
    "format_labels",
    "join_rows",
    "parse_tokens",
]

#: rows per block: the unit of parallel work of the reader and writer.
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
_U31 = np.uint64(31)
_U32 = np.uint64(32)
_U52 = np.uint64(52)
_U53 = np.uint64(53)
_U63 = np.uint64(63)
_U64_M32 = np.uint64(0xFFFFFFFF)
_U64_1FF = np.uint64(0x1FF)
_U64_MAX = np.uint64(0xFFFFFFFFFFFFFFFF)
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


_GRISU_F, _GRISU_E, _GRISU_K = grisu_cached_powers()
_LEMIRE_HI, _LEMIRE_LO = lemire_powers()
#: the exactly representable powers of ten (Clinger's fast path).
_POW10 = np.array([float(10**i) for i in range(23)])
#: 10^0 .. 10^19 as uint64 (Grisu digit generation).
_POW10_U64 = np.array([10**i for i in range(20)], dtype=np.uint64)
#: NaN bit patterns float() gives for 'nan' and '-nan' on this platform.
_NAN_BITS = np.array([struct.unpack("<Q", struct.pack("<d", float(s)))[0]
                      for s in ("nan", "-nan")], dtype=np.uint64)


def _tables():
    return _LEMIRE_HI, _LEMIRE_LO, _POW10, _NAN_BITS


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
def _bits_from_f64(typingctx, value):
    if value != types.float64:
        return None

    def codegen(context, builder, sig, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.uint64(types.float64), codegen


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
def _strip(buf, s, e):
    """(s, e) with Unicode whitespace stripped from both ends, as ``str.strip()``."""
    while s < e:
        n = _space_at(buf, s, e)
        if n == 0:
            break
        s += n
    while e > s:
        n = _space_before(buf, s, e)
        if n == 0:
            break
        e -= n
    return s, e


@nb.njit(cache=True)
def _next_line(buf, pos, n):
    """(data start, data end, next position) of the line at ``pos``; start == end if the
    line is blank or a comment."""
    e = pos
    while e < n and buf[e] != 10:
        e += 1
    nxt = e + 1
    s, e = _strip(buf, pos, e)
    if s < e and buf[s] == 35:  # '#'
        e = s
    return s, e, nxt


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
        s, e, nxt = _next_line(buf, pos, n)
        if s < e:
            return s, e, lineno, nxt
        pos = nxt
    return -1, -1, lineno, pos


# --------------------------------------------------------------------------------------------
# decimal text -> float64
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _eisel_lemire(man, exp10, neg, hi_t, lo_t):
    """(ok, bits) of man * 10^exp10 correctly rounded; ok False when undecided or out of the
    normal range (Lemire 2021, as in Go's strconv)."""
    if exp10 < _LEMIRE_MIN or exp10 > _LEMIRE_MAX:
        return False, _U0
    clz = _clz64(man)
    man = man << clz
    ret_exp2 = ((217706 * exp10) >> 16) + 64 + 1023 - np.int64(clz)
    idx = exp10 - _LEMIRE_MIN
    x_hi, x_lo = _mul128(man, hi_t[idx])
    if (x_hi & _U64_1FF) == _U64_1FF and x_lo + man < man:
        y_hi, y_lo = _mul128(man, lo_t[idx])
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
def _match_word(buf, i, e, word):
    """Whether buf[i:i + len(word)] equals the lower-case ``word`` in any case."""
    if e - i < len(word):
        return False
    for k in range(len(word)):
        if (buf[i + k] | 0x20) != word[k]:
            return False
    return True


_INF = np.frombuffer(b"inf", np.uint8).copy()
_INITY = np.frombuffer(b"inity", np.uint8).copy()
_NAN = np.frombuffer(b"nan", np.uint8).copy()


@nb.njit(cache=True)
def _parse_float(buf, s, e, hi_t, lo_t, pow10, nan_bits, inf_w, inity_w, nan_w):
    """Parse ``buf[s:e]`` as ``float()`` does: (status, value), status OK, INVALID or HARD.

    HARD means valid-looking but left to ``float()``: any non-ASCII byte, subnormal or
    overflowing results, and long mantissas the fast paths cannot settle.
    """
    for k in range(s, e):
        if buf[k] >= 0x80:
            return HARD, 0.0
    # float() strips ASCII 9-13 and 32 only (28-31 are not blank to it)
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
    if c == 105:  # 'i'
        if not _match_word(buf, i, e, inf_w):
            return INVALID, 0.0
        i += 3
        if i < e:
            if not _match_word(buf, i, e, inity_w):
                return INVALID, 0.0
            i += 5
        if i != e:
            return INVALID, 0.0
        return OK, -np.inf if neg else np.inf
    if c == 110:  # 'n'
        if e - i != 3 or not _match_word(buf, i, e, nan_w):
            return INVALID, 0.0
        return OK, _f64_from_bits(nan_bits[1] if neg else nan_bits[0])

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
        v = np.float64(man)  # exact, and one correctly rounded operation follows
        v = v * pow10[exp10] if exp10 >= 0 else v / pow10[-exp10]
        return OK, -v if neg else v
    ok, bits = _eisel_lemire(man, exp10, neg, hi_t, lo_t)
    if not ok:
        return HARD, 0.0
    if truncated:
        # the true value lies in [man, man + 1) * 10^exp10: settled if both ends agree
        ok2, bits2 = _eisel_lemire(man + _U1, exp10, neg, hi_t, lo_t)
        if not ok2 or bits2 != bits:
            return HARD, 0.0
    return OK, _f64_from_bits(bits)


@nb.njit(cache=True)
def _parse_tokens(buf, starts, ends, out, status, hi_t, lo_t, pow10, nan_bits, inf_w, inity_w,
                  nan_w):
    for k in range(len(starts)):
        st, v = _parse_float(buf, starts[k], ends[k], hi_t, lo_t, pow10, nan_bits, inf_w,
                             inity_w, nan_w)
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
    _parse_tokens(buf, np.asarray(starts, np.int64), np.asarray(ends, np.int64), out, status,
                  *_tables(), _INF, _INITY, _NAN)
    return out, status


# --------------------------------------------------------------------------------------------
# reading rows
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _measure(buf, pos, ncols, role, block, blk_pos, blk_line, blk_text):
    """First pass: count the data rows, check every row has ``ncols`` fields and measure the
    pass-through text; record where each block of ``block`` rows starts.

    Returns (rows, text bytes, blocks, bad line, its field count); bad line is 0 when every
    row has ``ncols`` fields, else the 1-based line number (counted from ``pos``) of the
    first that does not.
    """
    n = len(buf)
    rows = 0
    text = 0
    nblk = 0
    lineno = 0
    while pos <= n:
        lineno += 1
        s, e, nxt = _next_line(buf, pos, n)
        if s < e:
            if rows % block == 0:
                blk_pos[nblk] = pos
                blk_line[nblk] = lineno
                blk_text[nblk] = text
                nblk += 1
            j = 0
            fs = s
            for k in range(s, e + 1):
                if k == e or buf[k] == 44:  # ','
                    if j < ncols and role[j] == 3:
                        a, b = _strip(buf, fs, k)
                        text += b - a
                    j += 1
                    fs = k + 1
            if j != ncols:
                return rows, text, nblk, lineno, j
            rows += 1
        pos = nxt
    return rows, text, nblk, 0, 0


@nb.njit(cache=True, parallel=True)
def _fill(buf, ncols, role, npass, nrows, block, blk_pos, blk_text, points, text, offsets,
          hard, blk_bad, hi_t, lo_t, pow10, nan_bits, inf_w, inity_w, nan_w):
    """Second pass, in parallel over blocks: coordinates into ``points``, pass-through fields
    into ``text``/``offsets``; ``hard`` gets bit a for a coordinate left to ``float()``;
    ``blk_bad`` the first row * 3 + axis of an invalid coordinate per block (-1 if none)."""
    n = len(buf)
    nblk = len(blk_pos)
    for bi in nb.prange(nblk):
        pos = blk_pos[bi]
        r = bi * block
        stop = min(r + block, nrows)
        tpos = blk_text[bi]
        blk_bad[bi] = -1
        while r < stop:
            s, e, nxt = _next_line(buf, pos, n)
            pos = nxt
            if s >= e:
                continue
            j = 0
            fs = s
            flags = 0
            bad = -1
            p = 0
            for k in range(s, e + 1):
                if k == e or buf[k] == 44:
                    ro = role[j]
                    if ro == 3:
                        a, b = _strip(buf, fs, k)
                        offsets[r * npass + p] = tpos
                        for q in range(a, b):
                            text[tpos] = buf[q]
                            tpos += 1
                        p += 1
                    else:
                        st, v = _parse_float(buf, fs, k, hi_t, lo_t, pow10, nan_bits, inf_w,
                                             inity_w, nan_w)
                        points[r, ro] = v
                        if st == HARD:
                            flags |= 1 << ro
                        elif st == INVALID and (bad < 0 or ro < bad):
                            bad = ro
                    j += 1
                    fs = k + 1
            hard[r] = flags
            if bad >= 0 and blk_bad[bi] < 0:
                blk_bad[bi] = r * 3 + bad
            r += 1
    offsets[nrows * npass] = len(text)


@nb.njit(cache=True)
def locate_rows(buf, rows, block, blk_pos, blk_line, out):
    """For the sorted data-row indices ``rows``: out[k] = (line number counted from the
    reading start, line start, line end) of row ``rows[k]``, stripped."""
    n = len(buf)
    k = 0
    m = len(rows)
    while k < m:
        bi = rows[k] // block
        pos = blk_pos[bi]
        lineno = blk_line[bi] - 1
        r = bi * block
        while k < m and rows[k] // block == bi:
            s, e, nxt = _next_line(buf, pos, n)
            lineno += 1
            pos = nxt
            if s >= e:
                continue
            if r == rows[k]:
                out[k, 0] = lineno
                out[k, 1] = s
                out[k, 2] = e
                k += 1
            r += 1


class RowsRead:
    """What :func:`read_rows` found.

    Attributes
    ----------
    points : (p, 3) float64
        Coordinates; hard ones (see ``hard``) are 0 until the caller fills them in.
    text : TextColumns
        The pass-through fields.
    bad_columns : (int, int) or None
        (line number from the start, field count) of the first row with a wrong field count.
    bad_number : int
        row * 3 + axis of the first invalid coordinate (row order, then x, y, z), -1 if none.
    hard : (h,) int64
        row * 3 + axis of the coordinates left to ``float()``, in the same order.
    """

    def __init__(self, points, text, bad_columns, bad_number, hard, buf, block, blk_pos,
                 blk_line):
        self.points = points
        self.text = text
        self.bad_columns = bad_columns
        self.bad_number = bad_number
        self.hard = hard
        self._buf = buf
        self._block = block
        self._blk_pos = blk_pos
        self._blk_line = blk_line

    def lines(self, rows):
        """(line number, start, end) of each data row in ``rows`` (sorted)."""
        rows = np.asarray(rows, np.int64)
        out = np.zeros((len(rows), 3), np.int64)
        if len(rows):
            locate_rows(self._buf, rows, self._block, self._blk_pos, self._blk_line, out)
        return out


def read_rows(buf: np.ndarray, pos: int, ncols: int, xyz, passthrough, block: int = BLOCK):
    """Tokenise and convert the data rows of ``buf`` (uint8) from byte ``pos`` on.

    Parameters
    ----------
    buf : (n,) uint8
        The whole text, valid UTF-8 (BOM removed).
    pos : int
        Where the rows start (after the header line, if any).
    ncols : int
        Fields every row must have.
    xyz : 3 ints
        Field indices of x, y and z.
    passthrough : sequence of int
        Field indices carried through as text, in output order (ascending).

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
    cap = (int(np.count_nonzero(buf[pos:] == 10)) + 1) // block + 2
    blk_pos = np.empty(cap, np.int64)
    blk_line = np.empty(cap, np.int64)
    blk_text = np.empty(cap, np.int64)
    rows, ntext, nblk, bad_line, bad_count = _measure(buf, pos, ncols, role, block, blk_pos,
                                                      blk_line, blk_text)
    blk_pos, blk_line, blk_text = blk_pos[:nblk], blk_line[:nblk], blk_text[:nblk]
    if bad_line:
        empty = TextColumns.empty(0, npass)
        return RowsRead(np.zeros((0, 3)), empty, (bad_line, bad_count), -1,
                        np.zeros(0, np.int64), buf, block, blk_pos, blk_line)
    points = np.empty((rows, 3), np.float64)
    text = np.empty(ntext, np.uint8)
    offsets = np.empty(rows * npass + 1, np.int64)
    hard = np.empty(rows, np.uint8)
    blk_bad = np.empty(nblk, np.int64)
    _fill(buf, ncols, role, npass, rows, block, blk_pos, blk_text, points, text, offsets, hard,
          blk_bad, *_tables(), _INF, _INITY, _NAN)
    bad = blk_bad[blk_bad >= 0]
    bad_number = int(bad[0]) if len(bad) else -1
    hrows = np.flatnonzero(hard)
    if len(hrows):
        bits = hard[hrows]
        hard_idx = np.concatenate([hrows[(bits >> a) & 1 == 1] * 3 + a for a in range(3)])
        hard_idx.sort()
    else:
        hard_idx = np.zeros(0, np.int64)
    return RowsRead(points, TextColumns(text, offsets, rows, npass), None, bad_number, hard_idx,
                    buf, block, blk_pos, blk_line)


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
def _round_weed(buf, length, dist_high_w, unsafe, rest, ten_kappa, unit):
    small = dist_high_w - unit
    big = dist_high_w + unit
    while (rest < small and unsafe - rest >= ten_kappa
           and (rest + ten_kappa < small or small - rest >= rest + ten_kappa - small)):
        buf[length - 1] -= 1
        rest += ten_kappa
    if (rest < big and unsafe - rest >= ten_kappa
            and (rest + ten_kappa < big or big - rest > rest + ten_kappa - big)):
        return False
    return _U2 * unit <= rest and rest <= unsafe - _U4 * unit


@nb.njit(cache=True)
def _grisu3(bits, digits, gf, ge, gk, p10):
    """Shortest digits of the finite, positive double with ``bits`` (Grisu3).

    Returns (ok, ndigits, decimal exponent): value = digits * 10^exponent; ok is False when
    Grisu3 cannot prove the digits shortest and closest (~0.5 % of doubles). ``digits``
    needs 32 bytes.
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
    s = _clz64(f)
    wf = f << s
    # cached power c = 10^-mk with the scaled exponent in [-60, -32]; the index is
    # ceil((-60 - (pe + 64) + 63) * log10(2)) in integer arithmetic (exact for every pe)
    k = ((-61 - pe) * 78913 + (1 << 18) - 1) >> 18
    idx = (347 + k) // 8 + 1
    cf = gf[idx]
    one_e = pe + ge[idx] + 64
    mk = gk[idx]
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
    # the decimal digits of integrals, least significant first, at the end of `digits`
    # (divisions by the constant 10 only)
    x = integrals
    kappa = 0
    while True:
        q = x // _U10
        digits[31 - kappa] = np.uint8(x - q * _U10)
        kappa += 1
        x = q
        if x == _U0:
            break
    length = 0
    rem = integrals
    while kappa > 0:
        d = digits[32 - kappa]
        digits[length] = d + 48
        length += 1
        kappa -= 1
        rem -= np.uint64(d) * p10[kappa]
        rest = (rem << shift) + fractionals
        if rest < unsafe:
            ok = _round_weed(digits, length, too_high - w, unsafe, rest, p10[kappa] << shift,
                             unit)
            return ok, length, kappa - mk
    while True:
        fractionals *= _U10
        unit *= _U10
        unsafe *= _U10
        digit = fractionals >> shift
        digits[length] = np.uint8(digit) + 48
        length += 1
        fractionals &= one_f - _U1
        kappa -= 1
        if fractionals < unsafe:
            ok = _round_weed(digits, length, (too_high - w) * unit, unsafe, fractionals, one_f,
                             unit)
            return ok, length, kappa - mk


@nb.njit(cache=True)
def _put_text(out, pos, word):
    for k in range(len(word)):
        out[pos + k] = word[k]
    return pos + len(word)


@nb.njit(cache=True)
def _format_one(bits, slot, digits, gf, ge, gk, p10):
    """Write repr(value) into ``slot``; return its length, 0 if Grisu3 gave up."""
    neg = (bits & _SIGN) != _U0
    mag = bits & ~_SIGN
    if mag >= np.uint64(0x7FF0000000000000):
        if mag > np.uint64(0x7FF0000000000000):
            slot[0], slot[1], slot[2] = 110, 97, 110  # nan (repr drops the sign)
            return 3
        p = 0
        if neg:
            slot[0] = 45
            p = 1
        slot[p], slot[p + 1], slot[p + 2] = 105, 110, 102  # inf
        return p + 3
    p = 0
    if neg:
        slot[0] = 45
        p = 1
    if mag == _U0:
        slot[p], slot[p + 1], slot[p + 2] = 48, 46, 48  # 0.0
        return p + 3
    ok, n, k = _grisu3(mag, digits, gf, ge, gk, p10)
    if not ok:
        return 0
    decpt = n + k
    if -4 < decpt <= 16:
        if decpt <= 0:
            slot[p] = 48
            slot[p + 1] = 46
            p += 2
            for _ in range(-decpt):
                slot[p] = 48
                p += 1
            for q in range(n):
                slot[p] = digits[q]
                p += 1
        elif decpt >= n:
            for q in range(n):
                slot[p] = digits[q]
                p += 1
            for _ in range(decpt - n):
                slot[p] = 48
                p += 1
            slot[p] = 46
            slot[p + 1] = 48
            p += 2
        else:
            for q in range(decpt):
                slot[p] = digits[q]
                p += 1
            slot[p] = 46
            p += 1
            for q in range(decpt, n):
                slot[p] = digits[q]
                p += 1
        return p
    slot[p] = digits[0]
    p += 1
    if n > 1:
        slot[p] = 46
        p += 1
        for q in range(1, n):
            slot[p] = digits[q]
            p += 1
    x = decpt - 1
    slot[p] = 101  # e
    slot[p + 1] = 45 if x < 0 else 43
    p += 2
    x = -x if x < 0 else x
    if x >= 100:
        slot[p] = 48 + x // 100
        p += 1
        x %= 100
    slot[p] = 48 + x // 10
    slot[p + 1] = 48 + x % 10
    return p + 2


@nb.njit(cache=True, parallel=True)
def _format_floats(bits, slots, lens, gf, ge, gk, p10, block):
    n = len(bits)
    nblk = (n + block - 1) // block
    for bi in nb.prange(nblk):
        digits = np.empty(32, np.uint8)
        for i in range(bi * block, min(n, (bi + 1) * block)):
            lens[i] = _format_one(bits[i], slots[i], digits, gf, ge, gk, p10)


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
        _format_floats(values.view(np.uint64), slots, lens, _GRISU_F, _GRISU_E, _GRISU_K,
                       _POW10_U64, BLOCK)
        for i in np.flatnonzero(lens == 0).tolist():
            text = repr(float(values[i])).encode("ascii")
            slots[i, :len(text)] = np.frombuffer(text, np.uint8)
            lens[i] = len(text)
    return slots, lens


@nb.njit(cache=True)
def _format_ints(values, slots, lens):
    for i in range(len(values)):
        v = values[i]
        slot = slots[i]
        # the magnitude as uint64, so that int64 min needs no special case
        m = np.uint64(-(v + 1)) + _U1 if v < 0 else np.uint64(v)
        t = INT_WIDTH
        while True:
            t -= 1
            q = m // _U10
            slot[t] = np.uint8(m - q * _U10) + 48
            m = q
            if m == _U0:
                break
        if v < 0:
            t -= 1
            slot[t] = 45
        p = 0
        for q in range(t, INT_WIDTH):
            slot[p] = slot[q]
            p += 1
        lens[i] = p


def format_ints(values: np.ndarray):
    """Plain decimal text of every int64 value: (slots (n, 20) uint8, lens (n,) uint8)."""
    values = np.ascontiguousarray(values, dtype=np.int64)
    slots = np.empty((len(values), INT_WIDTH), np.uint8)
    lens = np.empty(len(values), np.uint8)
    _format_ints(values, slots, lens)
    return slots, lens


def format_labels(codes: np.ndarray, words):
    """``words[code]`` for every code: (slots (n, w) uint8, lens (n,) uint8)."""
    encoded = [str(w).encode("utf-8") for w in words]
    width = max([len(w) for w in encoded] + [1])
    if width > 255:
        raise ValueError("label words longer than 255 bytes")
    table = np.zeros((len(encoded), width), np.uint8)
    for k, w in enumerate(encoded):
        table[k, :len(w)] = np.frombuffer(w, np.uint8)
    wlens = np.array([len(w) for w in encoded], np.uint8)
    codes = np.asarray(codes).astype(np.intp, copy=False)
    return table[codes], wlens[codes]


# --------------------------------------------------------------------------------------------
# rows of text
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True)
def _scatter_text(out, pos, data, offsets, k, sep):
    """Append the k fields of each row, comma separated, then ``sep``."""
    for i in range(len(pos)):
        p = pos[i]
        for j in range(k):
            a = offsets[i * k + j]
            b = offsets[i * k + j + 1]
            for q in range(a, b):
                out[p] = data[q]
                p += 1
            out[p] = 44 if j < k - 1 else sep
            p += 1
        pos[i] = p


@nb.njit(cache=True)
def _scatter_slots(out, pos, slots, lens, sep):
    """Append each row's slot text, then ``sep``."""
    for i in range(len(pos)):
        p = pos[i]
        slot = slots[i]
        for q in range(lens[i]):
            out[p + q] = slot[q]
        p += lens[i]
        out[p] = sep
        pos[i] = p + 1


def join_rows(text: TextColumns | None, columns, nrows: int) -> np.ndarray:
    """CSV rows: the fields of ``text`` then each column's text, comma separated, one row a
    line.

    Parameters
    ----------
    text : TextColumns or None
        Leading fields (pass-through), or None.
    columns : list of (slots (n, w) uint8, lens (n,) uint8)
        As returned by :func:`format_floats`, :func:`format_ints`, :func:`format_labels`.
    nrows : int
        n; a row without any field is an empty line.

    Returns
    -------
    (b,) uint8
        The UTF-8 text of the rows, each ending in a newline.
    """
    k = text.ncols if text is not None else 0
    items = k + len(columns)
    row_len = np.full(nrows, max(items, 1), np.int64)
    if k:
        row_len += text.offsets[k::k] - text.offsets[:-1:k]
    for _, lens in columns:
        row_len += lens
    start = np.zeros(nrows + 1, np.int64)
    np.cumsum(row_len, out=start[1:])
    out = np.empty(int(start[-1]), np.uint8)
    pos = start[:-1].copy()
    if k:
        _scatter_text(out, pos, text.data, text.offsets, k, 44 if columns else 10)
    elif not columns:
        out[pos] = 10
    for c, (slots, lens) in enumerate(columns):
        _scatter_slots(out, pos, slots, lens, 10 if c == len(columns) - 1 else 44)
    return out
