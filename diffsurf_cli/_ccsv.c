/* diffsurf's CSV text: a byte tokeniser with a correctly rounded float parser, and a shortest
   round-trip float formatter (the algorithms are described in fastcsv.py, which loads this
   file with ctypes and keeps the Python-side fallbacks: float() and repr()).

   C99 + OpenMP. The parallel loops run over blocks of lines (reading) or of rows (writing),
   one block per iteration; every block writes only its own part of the outputs.
   Status of a parsed token: 0 OK, 1 INVALID (float() raises), 2 HARD (left to float()). */
#include <math.h>
#include <stdint.h>
#include <string.h>

#define OK 0
#define INVALID 1
#define HARD 2
#define FLOAT_WIDTH 24
#define INT_WIDTH 20
#define LEMIRE_MIN (-348)
#define LEMIRE_MAX 347
#define GRISU_N 87
#define LEMIRE_N (LEMIRE_MAX - LEMIRE_MIN + 1)

#define FRAC_MASK ((UINT64_C(1) << 52) - 1)
#define HIDDEN (UINT64_C(1) << 52)
#define SIGN (UINT64_C(1) << 63)

typedef uint8_t u8;
typedef int8_t i8;
typedef int64_t i64;
typedef uint64_t u64;

/* ------------------------------------------------------------------------------------------
   tables: computed exactly with Python integers (fastcsv.py) and set once at import
   ------------------------------------------------------------------------------------------ */

static u64 GRISU_F[GRISU_N];
static i64 GRISU_E[GRISU_N];
static i64 GRISU_K[GRISU_N];
static u64 LEMIRE_HI[LEMIRE_N];
static u64 LEMIRE_LO[LEMIRE_N];
static u64 NAN_BITS[2];  /* float('nan'), float('-nan') */

/* the exactly representable powers of ten (Clinger's fast path) */
static const double POW10[23] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                 1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};

static const u64 POW10_U64[20] = {
    UINT64_C(1), UINT64_C(10), UINT64_C(100), UINT64_C(1000), UINT64_C(10000),
    UINT64_C(100000), UINT64_C(1000000), UINT64_C(10000000), UINT64_C(100000000),
    UINT64_C(1000000000), UINT64_C(10000000000), UINT64_C(100000000000),
    UINT64_C(1000000000000), UINT64_C(10000000000000), UINT64_C(100000000000000),
    UINT64_C(1000000000000000), UINT64_C(10000000000000000), UINT64_C(100000000000000000),
    UINT64_C(1000000000000000000), UINT64_C(10000000000000000000)};

static const char DIGIT_PAIRS[201] =
    "00010203040506070809101112131415161718192021222324252627282930313233343536373839"
    "40414243444546474849505152535455565758596061626364656667686970717273747576777879"
    "8081828384858687888990919293949596979899";

/* Set the tables (called once by fastcsv.py at import, before any other function). */
void ccsv_init(const u64 *grisu_f, const i64 *grisu_e, const i64 *grisu_k,
               const u64 *lemire_hi, const u64 *lemire_lo, const u64 *nan_bits) {
    memcpy(GRISU_F, grisu_f, sizeof GRISU_F);
    memcpy(GRISU_E, grisu_e, sizeof GRISU_E);
    memcpy(GRISU_K, grisu_k, sizeof GRISU_K);
    memcpy(LEMIRE_HI, lemire_hi, sizeof LEMIRE_HI);
    memcpy(LEMIRE_LO, lemire_lo, sizeof LEMIRE_LO);
    memcpy(NAN_BITS, nan_bits, sizeof NAN_BITS);
}

/* sizes the Python side checks its tables against */
int ccsv_table_sizes(i64 *out) {
    out[0] = GRISU_N;
    out[1] = LEMIRE_N;
    out[2] = LEMIRE_MIN;
    return 0;
}

/* ------------------------------------------------------------------------------------------
   bit-level helpers
   ------------------------------------------------------------------------------------------ */

static inline double f64_from_bits(u64 bits) {
    double v;
    memcpy(&v, &bits, sizeof v);
    return v;
}

#if defined(__GNUC__)
static inline int clz64(u64 x) { return x ? __builtin_clzll(x) : 64; }
#else
static inline int clz64(u64 x) {
    int n = 0;
    if (!x) return 64;
    while (!(x & SIGN)) {
        x <<= 1;
        n++;
    }
    return n;
}
#endif

/* high and low 64-bit words of a * b */
#if defined(__SIZEOF_INT128__)
__extension__ typedef unsigned __int128 u128;
static inline void mul128(u64 a, u64 b, u64 *hi, u64 *lo) {
    u128 p = (u128)a * b;
    *hi = (u64)(p >> 64);
    *lo = (u64)p;
}
#else
static inline void mul128(u64 a, u64 b, u64 *hi, u64 *lo) {
    u64 a0 = a & 0xFFFFFFFFu, a1 = a >> 32, b0 = b & 0xFFFFFFFFu, b1 = b >> 32;
    u64 p00 = a0 * b0, p01 = a0 * b1, p10 = a1 * b0, p11 = a1 * b1;
    u64 mid = (p00 >> 32) + (p01 & 0xFFFFFFFFu) + (p10 & 0xFFFFFFFFu);
    *hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
    *lo = (mid << 32) | (p00 & 0xFFFFFFFFu);
}
#endif

/* ------------------------------------------------------------------------------------------
   whitespace (str.isspace in UTF-8), lines
   ------------------------------------------------------------------------------------------ */

static inline int ascii_space(u8 b) { return (9 <= b && b <= 13) || (28 <= b && b <= 32); }

/* byte length of the Unicode whitespace character starting at buf[i] (i < end), 0 if none:
   ASCII 9-13, 28-32 and U+0085, U+00A0, U+1680, U+2000-U+200A, U+2028, U+2029, U+202F,
   U+205F, U+3000 */
static inline int space_at(const u8 *buf, i64 i, i64 end) {
    u8 b = buf[i];
    if (b < 0x80) return ascii_space(b);
    if (b == 0xC2) {
        if (i + 1 < end && (buf[i + 1] == 0x85 || buf[i + 1] == 0xA0)) return 2;
        return 0;
    }
    if (i + 2 >= end) return 0;
    u8 b1 = buf[i + 1], b2 = buf[i + 2];
    if (b == 0xE1) return (b1 == 0x9A && b2 == 0x80) ? 3 : 0;
    if (b == 0xE2) {
        if (b1 == 0x80 && (b2 <= 0x8A || b2 == 0xA8 || b2 == 0xA9 || b2 == 0xAF)) return 3;
        return (b1 == 0x81 && b2 == 0x9F) ? 3 : 0;
    }
    if (b == 0xE3) return (b1 == 0x80 && b2 == 0x80) ? 3 : 0;
    return 0;
}

/* byte length of the Unicode whitespace character ending just before buf[j] (j > start) */
static inline int space_before(const u8 *buf, i64 start, i64 j) {
    u8 b = buf[j - 1];
    if (b < 0x80) return ascii_space(b);
    if (j - 2 >= start && buf[j - 2] == 0xC2 && (b == 0x85 || b == 0xA0)) return 2;
    if (j - 3 >= start && space_at(buf, j - 3, j) == 3) return 3;
    return 0;
}

/* [*s, *e) with Unicode whitespace stripped from both ends, as str.strip() */
static inline void strip(const u8 *buf, i64 *ps, i64 *pe) {
    i64 s = *ps, e = *pe;
    while (s < e) {
        u8 b = buf[s];
        if (b < 0x80) {
            if (!ascii_space(b)) break;
            s += 1;
        } else {
            int n = space_at(buf, s, e);
            if (n == 0) break;
            s += n;
        }
    }
    while (e > s) {
        u8 b = buf[e - 1];
        if (b < 0x80) {
            if (!ascii_space(b)) break;
            e -= 1;
        } else {
            int n = space_before(buf, s, e);
            if (n == 0) break;
            e -= n;
        }
    }
    *ps = s;
    *pe = e;
}

/* index of the first newline at or after i; n if there is none */
static inline i64 line_end(const u8 *buf, i64 i, i64 n) {
    if (i >= n) return n;
    const u8 *p = memchr(buf + i, '\n', (size_t)(n - i));
    return p ? (i64)(p - buf) : n;
}

/* stripped extent of the line buf[pos:e]; *s == *d for a blank or comment line */
static inline void data_extent(const u8 *buf, i64 pos, i64 e, i64 *s, i64 *d) {
    *s = pos;
    *d = e;
    strip(buf, s, d);
    if (*s < *d && buf[*s] == '#') *d = *s;
}

/* out = (start, end, 1-based line number, next line) of the first data line at or after pos;
   start = end = -1 if none */
void ccsv_first_data_line(const u8 *buf, i64 n, i64 pos, i64 *out) {
    i64 lineno = 0;
    while (pos <= n) {
        lineno += 1;
        i64 e = line_end(buf, pos, n), s, d;
        data_extent(buf, pos, e, &s, &d);
        if (s < d) {
            out[0] = s;
            out[1] = d;
            out[2] = lineno;
            out[3] = e + 1;
            return;
        }
        pos = e + 1;
    }
    out[0] = -1;
    out[1] = -1;
    out[2] = lineno;
    out[3] = pos;
}

/* stripped extents of the m spans buf[starts[k]:ends[k]] */
void ccsv_strip(const u8 *buf, const i64 *starts, const i64 *ends, i64 m, i64 *out_s,
                i64 *out_e) {
    for (i64 k = 0; k < m; k++) {
        i64 s = starts[k], e = ends[k];
        strip(buf, &s, &e);
        out_s[k] = s;
        out_e[k] = e;
    }
}

/* byte bounds of blocks of about `size` bytes from pos, each starting a line; returns their
   count + 1 (bounds has room for (n - pos) / size + 2 entries) */
i64 ccsv_line_blocks(const u8 *buf, i64 n, i64 pos, i64 size, i64 *bounds) {
    i64 k = 0;
    bounds[k++] = pos;
    while (bounds[k - 1] < n) {
        i64 cut = bounds[k - 1] + size;
        if (cut >= n) {
            bounds[k++] = n;
        } else {
            i64 e = line_end(buf, cut, n) + 1;
            bounds[k++] = e < n ? e : n;
        }
    }
    return k;
}

/* ------------------------------------------------------------------------------------------
   decimal text -> float64
   ------------------------------------------------------------------------------------------ */

/* man * 10^exp10 correctly rounded into *bits; 0 when undecided or out of the normal range
   (Lemire 2021, as in Go's strconv) */
static int eisel_lemire(u64 man, i64 exp10, int neg, u64 *bits) {
    if (exp10 < LEMIRE_MIN || exp10 > LEMIRE_MAX) return 0;
    int clz = clz64(man);
    man <<= clz;
    i64 ret_exp2 = ((217706 * exp10) >> 16) + 64 + 1023 - clz;
    i64 idx = exp10 - LEMIRE_MIN;
    u64 x_hi, x_lo;
    mul128(man, LEMIRE_HI[idx], &x_hi, &x_lo);
    if ((x_hi & 0x1FF) == 0x1FF && x_lo + man < man) {
        u64 y_hi, y_lo;
        mul128(man, LEMIRE_LO[idx], &y_hi, &y_lo);
        u64 m_hi = x_hi, m_lo = x_lo + y_hi;
        if (m_lo < x_lo) m_hi += 1;
        if ((m_hi & 0x1FF) == 0x1FF && m_lo + 1 == 0 && y_lo + man < man) return 0;
        x_hi = m_hi;
        x_lo = m_lo;
    }
    u64 msb = x_hi >> 63;
    u64 mant = x_hi >> (msb + 9);
    ret_exp2 -= 1 - (i64)msb;
    if (x_lo == 0 && (x_hi & 0x1FF) == 0 && (mant & 3) == 1) return 0;
    mant += mant & 1;
    mant >>= 1;
    if ((mant >> 53) > 0) {
        mant >>= 1;
        ret_exp2 += 1;
    }
    if (ret_exp2 <= 0 || ret_exp2 >= 0x7FF) return 0;
    u64 b = ((u64)ret_exp2 << 52) | (mant & FRAC_MASK);
    if (neg) b |= SIGN;
    *bits = b;
    return 1;
}

static inline int is_digit(u8 b) { return 48 <= b && b <= 57; }

static int parse_ascii(const u8 *buf, i64 s, i64 e, double *out) {
    *out = 0.0;
    /* float() strips ASCII 9-13 and 32 (not 28-31) and, as Unicode, the rest: see HARD */
    while (s < e && (buf[s] == 32 || (9 <= buf[s] && buf[s] <= 13))) s++;
    while (e > s && (buf[e - 1] == 32 || (9 <= buf[e - 1] && buf[e - 1] <= 13))) e--;
    if (s >= e) return INVALID;
    i64 i = s;
    int neg = 0;
    if (buf[i] == '+' || buf[i] == '-') {
        neg = buf[i] == '-';
        i++;
        if (i >= e) return INVALID;
    }
    int c = buf[i] | 0x20;
    if (c == 'i' || c == 'n') { /* inf, infinity, nan in any case */
        if (e - i > 8) return INVALID;
        u64 word = 0;
        for (i64 k = i; k < e; k++) word = (word << 8) | (u64)(buf[k] | 0x20);
        if (word == UINT64_C(0x696E66) || word == UINT64_C(0x696E66696E697479)) {
            *out = neg ? -INFINITY : INFINITY;
            return OK;
        }
        if (word == UINT64_C(0x6E616E)) {
            *out = f64_from_bits(NAN_BITS[neg ? 1 : 0]);
            return OK;
        }
        return INVALID;
    }

    u64 man = 0;
    int nd = 0; /* significant digits kept in man */
    i64 exp10 = 0;
    int truncated = 0;
    i64 ndigits = 0;
    for (int part = 0; part < 2; part++) {
        if (part == 1) {
            if (i < e && buf[i] == '.')
                i++;
            else
                break;
        }
        while (i < e) {
            u8 b = buf[i];
            if (is_digit(b)) {
                u64 d = (u64)(b - 48);
                ndigits++;
                if (nd == 0 && d == 0) {
                    if (part == 1) exp10--;
                } else if (nd < 19) {
                    man = man * 10 + d;
                    nd++;
                    if (part == 1) exp10--;
                } else {
                    if (part == 0) exp10++;
                    if (d != 0) truncated = 1;
                }
            } else if (b == '_') { /* only between two digits */
                if (i == s || !is_digit(buf[i - 1]) || i + 1 >= e || !is_digit(buf[i + 1]))
                    return INVALID;
            } else {
                break;
            }
            i++;
        }
    }
    if (ndigits == 0) return INVALID;
    if (i < e && (buf[i] | 0x20) == 'e') {
        i++;
        int eneg = 0;
        if (i < e && (buf[i] == '+' || buf[i] == '-')) {
            eneg = buf[i] == '-';
            i++;
        }
        i64 ev = 0, edigits = 0;
        while (i < e) {
            u8 b = buf[i];
            if (is_digit(b)) {
                edigits++;
                if (ev < 100000000) ev = ev * 10 + (b - 48);
            } else if (b == '_') {
                if (!is_digit(buf[i - 1]) || i + 1 >= e || !is_digit(buf[i + 1])) return INVALID;
            } else {
                break;
            }
            i++;
        }
        if (edigits == 0) return INVALID;
        exp10 += eneg ? -ev : ev;
    }
    if (i != e) return INVALID;

    if (man == 0) {
        *out = neg ? -0.0 : 0.0;
        return OK;
    }
    if (!truncated && man <= (UINT64_C(1) << 53) && -22 <= exp10 && exp10 <= 22) {
        /* Clinger: man and 10^|exp10| are exact doubles, so one rounding gives the answer */
        double v = (double)man;
        v = exp10 >= 0 ? v * POW10[exp10] : v / POW10[-exp10];
        *out = neg ? -v : v;
        return OK;
    }
    u64 bits;
    if (!eisel_lemire(man, exp10, neg, &bits)) return HARD;
    if (truncated) {
        /* the true value lies in [man, man + 1) * 10^exp10: settled if both ends agree */
        u64 bits2;
        if (!eisel_lemire(man + 1, exp10, neg, &bits2) || bits2 != bits) return HARD;
    }
    *out = f64_from_bits(bits);
    return OK;
}

/* buf[s:e] as float() parses it: status OK, INVALID or HARD (a token with a non-ASCII byte
   that is not plain ASCII grammar, subnormal or overflowing results, long mantissas the fast
   paths cannot settle); the value is 0 unless OK */
static inline int parse_float(const u8 *buf, i64 s, i64 e, double *out) {
    int st = parse_ascii(buf, s, e, out);
    if (st == INVALID) {
        for (i64 k = s; k < e; k++)
            if (buf[k] >= 0x80) return HARD;
    }
    return st;
}

void ccsv_parse_tokens(const u8 *buf, const i64 *starts, const i64 *ends, i64 m, double *out,
                       u8 *status) {
    for (i64 k = 0; k < m; k++) status[k] = (u8)parse_float(buf, starts[k], ends[k], &out[k]);
}

/* ------------------------------------------------------------------------------------------
   reading rows
   ------------------------------------------------------------------------------------------ */

/* First pass, in parallel over the nblk blocks of lines: per block the data rows, the bytes
   of pass-through text, the lines, and the first line (1-based in the block, 0 if none) whose
   field count is not ncols, with that count. */
void ccsv_count(const u8 *buf, i64 n, const i64 *bounds, i64 nblk, i64 ncols, const i8 *role,
                i64 *rows, i64 *text, i64 *lines, i64 *bad_line, i64 *bad_count) {
#pragma omp parallel for schedule(dynamic, 1) if (nblk > 1)
    for (i64 b = 0; b < nblk; b++) {
        i64 pos = bounds[b], end = bounds[b + 1];
        i64 r = 0, t = 0, ln = 0, bl = 0, bc = 0;
        while (pos < end) {
            ln++;
            i64 e = line_end(buf, pos, n), s, d;
            data_extent(buf, pos, e, &s, &d);
            if (s < d) {
                i64 j = 0, fs = s;
                for (i64 k = s; k <= d; k++) {
                    if (k == d || buf[k] == ',') {
                        if (j < ncols && role[j] == 3) {
                            i64 a = fs, c = k;
                            strip(buf, &a, &c);
                            t += c - a;
                        }
                        j++;
                        fs = k + 1;
                    }
                }
                if (j != ncols && bl == 0) {
                    bl = ln;
                    bc = j;
                }
                r++;
            }
            pos = e + 1;
        }
        rows[b] = r;
        text[b] = t;
        lines[b] = ln;
        bad_line[b] = bl;
        bad_count[b] = bc;
    }
}

/* Second pass, in parallel over blocks: coordinates into points (rows of 3), pass-through
   fields into text/offsets; hard[r] gets bit a for a coordinate left to float(); blk_bad the
   first row * 3 + axis of an invalid coordinate per block (-1 if none). Every data row has
   the fields of role (checked by ccsv_count). */
void ccsv_fill(const u8 *buf, i64 n, const i64 *bounds, i64 nblk, const i64 *row0,
               const i64 *text0, const i8 *role, i64 npass, double *points, u8 *text,
               i64 *offsets, u8 *hard, i64 *blk_bad) {
#pragma omp parallel for schedule(dynamic, 1) if (nblk > 1)
    for (i64 b = 0; b < nblk; b++) {
        i64 pos = bounds[b], end = bounds[b + 1];
        i64 r = row0[b], tpos = text0[b];
        blk_bad[b] = -1;
        while (pos < end) {
            i64 e = line_end(buf, pos, n), s, d;
            data_extent(buf, pos, e, &s, &d);
            pos = e + 1;
            if (s >= d) continue;
            i64 j = 0, fs = s, p = 0;
            int flags = 0, bad = -1;
            for (i64 k = s; k <= d; k++) {
                if (k == d || buf[k] == ',') {
                    int ro = role[j];
                    if (ro == 3) {
                        i64 a = fs, c = k;
                        strip(buf, &a, &c);
                        offsets[r * npass + p] = tpos;
                        memcpy(text + tpos, buf + a, (size_t)(c - a));
                        tpos += c - a;
                        p++;
                    } else {
                        int st = parse_float(buf, fs, k, &points[r * 3 + ro]);
                        if (st == HARD)
                            flags |= 1 << ro;
                        else if (st == INVALID && (bad < 0 || ro < bad))
                            bad = ro;
                    }
                    j++;
                    fs = k + 1;
                }
            }
            hard[r] = (u8)flags;
            if (bad >= 0 && blk_bad[b] < 0) blk_bad[b] = r * 3 + bad;
            r++;
        }
    }
}

/* out[k] = (line number from the reading start, stripped line start, end) of data row
   rows[k]; rows sorted */
void ccsv_locate(const u8 *buf, i64 n, const i64 *bounds, i64 nblk, const i64 *row0,
                 const i64 *line0, const i64 *rows, i64 m, i64 *out) {
    i64 k = 0;
    while (k < m) {
        /* the last block b with row0[b] <= rows[k] (numpy searchsorted, side right, - 1) */
        i64 lo = 0, hi = nblk + 1;
        while (lo < hi) {
            i64 mid = lo + (hi - lo) / 2;
            if (row0[mid] <= rows[k])
                lo = mid + 1;
            else
                hi = mid;
        }
        i64 b = lo - 1;
        i64 pos = bounds[b], ln = line0[b], r = row0[b];
        while (k < m && pos < bounds[b + 1]) {
            ln++;
            i64 e = line_end(buf, pos, n), s, d;
            data_extent(buf, pos, e, &s, &d);
            pos = e + 1;
            if (s < d) {
                while (k < m && rows[k] == r) {
                    out[3 * k] = ln;
                    out[3 * k + 1] = s;
                    out[3 * k + 2] = d;
                    k++;
                }
                r++;
            }
        }
    }
}

/* ------------------------------------------------------------------------------------------
   float64 -> shortest text (Grisu3)
   ------------------------------------------------------------------------------------------ */

/* high 64 bits of af * bf, rounded (DiyFp multiplication) */
static inline u64 times(u64 af, u64 bf) {
    u64 a = af >> 32, b = af & 0xFFFFFFFFu, c = bf >> 32, d = bf & 0xFFFFFFFFu;
    u64 ac = a * c, bc = b * c, ad = a * d, bd = b * d;
    u64 tmp = (bd >> 32) + (ad & 0xFFFFFFFFu) + (bc & 0xFFFFFFFFu);
    tmp += UINT64_C(1) << 31;
    return ac + (ad >> 32) + (bc >> 32) + (tmp >> 32);
}

/* Grisu3's RoundWeed on the digits held as an integer: ok, and *digits adjusted */
static inline int round_weed(u64 *digits, u64 dist_high_w, u64 unsafe, u64 rest, u64 ten_kappa,
                             u64 unit) {
    u64 small = dist_high_w - unit, big = dist_high_w + unit;
    while (rest < small && unsafe - rest >= ten_kappa &&
           (rest + ten_kappa < small || small - rest >= rest + ten_kappa - small)) {
        *digits -= 1; /* the last digit, one down */
        rest += ten_kappa;
    }
    if (rest < big && unsafe - rest >= ten_kappa &&
        (rest + ten_kappa < big || big - rest > rest + ten_kappa - big))
        return 0;
    return 2 * unit <= rest && rest <= unsafe - 4 * unit;
}

/* Shortest digits of the finite, positive double with `bits`: value = *digits * 10^*exponent,
   *digits an integer of *ndigits <= 17 decimal digits; returns 0 when Grisu3 cannot prove them
   shortest and closest (about 0.5 % of doubles). */
static int grisu3(u64 bits, u64 *digits_out, i64 *ndigits, i64 *exponent) {
    u64 frac = bits & FRAC_MASK;
    i64 biased = (i64)(bits >> 52);
    u64 f;
    i64 e;
    if (biased == 0) {
        f = frac;
        e = -1074;
    } else {
        f = frac | HIDDEN;
        e = biased - 1075;
    }
    /* boundaries m- and m+, normalised to the exponent of m+ */
    u64 pf = (f << 1) + 1;
    i64 pe = e - 1;
    int s = clz64(pf);
    pf <<= s;
    pe -= s;
    u64 mf;
    i64 me;
    if (frac == 0 && biased > 1) {
        mf = (f << 2) - 1;
        me = e - 2;
    } else {
        mf = (f << 1) - 1;
        me = e - 1;
    }
    mf <<= (u64)(me - pe);
    /* w normalised: same exponent as m+ */
    u64 wf = f << clz64(f);
    /* cached power c = 10^-mk with the scaled exponent in [-60, -32]; the index is
       ceil((-60 - (pe + 64) + 63) * log10(2)) in integer arithmetic (exact for every pe);
       >> on a negative int64 is arithmetic with gcc and clang (floor, as numba's was) */
    i64 k = ((-61 - pe) * 78913 + (1 << 18) - 1) >> 18;
    i64 idx = (347 + k) / 8 + 1; /* 347 + k > 0 for every double */
    u64 cf = GRISU_F[idx];
    i64 one_e = pe + GRISU_E[idx] + 64;
    i64 mk = GRISU_K[idx];
    u64 w = times(wf, cf), low = times(mf, cf), high = times(pf, cf);

    u64 unit = 1;
    u64 too_low = low - unit, too_high = high + unit;
    u64 unsafe = too_high - too_low;
    u64 shift = (u64)(-one_e);
    u64 one_f = UINT64_C(1) << shift;
    u64 integrals = too_high >> shift;
    u64 fractionals = too_high & (one_f - 1);
    i64 kappa = 1;
    while (kappa < 20 && POW10_U64[kappa] <= integrals) kappa++;
    /* Grisu emits the digits of `integrals` from the top and stops after the first digit
       where rest = (integrals mod 10^m) * 2^shift + fractionals < unsafe, m the digits left.
       That rest grows with m, so the stopping m is the largest with integrals mod 10^m <=
       r_max: found from the bottom with divisions by the constant 10 only. */
    if (unsafe > fractionals) {
        u64 r_max = (unsafe - fractionals - 1) >> shift;
        i64 m = 0;
        u64 x = integrals, r = 0, p = 1;
        while (m < kappa - 1) {
            u64 q = x / 10;
            u64 r2 = r + (x - q * 10) * p;
            if (r2 > r_max) break;
            r = r2;
            x = q;
            p *= 10;
            m++;
        }
        int ok = round_weed(&x, too_high - w, unsafe, (r << shift) + fractionals, p << shift,
                            unit);
        *digits_out = x;
        *ndigits = kappa - m;
        *exponent = m - mk;
        return ok;
    }
    u64 digits = integrals;
    i64 length = kappa;
    kappa = 0;
    for (;;) {
        fractionals *= 10;
        unit *= 10;
        unsafe *= 10;
        digits = digits * 10 + (fractionals >> shift);
        length++;
        fractionals &= one_f - 1;
        kappa--;
        if (fractionals < unsafe) {
            int ok = round_weed(&digits, (too_high - w) * unit, unsafe, fractionals, one_f, unit);
            *digits_out = digits;
            *ndigits = length;
            *exponent = kappa - mk;
            return ok;
        }
    }
}

/* Grisu3 of each finite, positive double (for the tests) */
void ccsv_grisu3(const u64 *bits, i64 n, u8 *ok, u64 *digits, i64 *ndigits, i64 *exponent) {
    for (i64 i = 0; i < n; i++)
        ok[i] = (u8)grisu3(bits[i], &digits[i], &ndigits[i], &exponent[i]);
}

/* the n <= 9 decimal digits of `digits` (zero padded) at out[p:p + n], two at a time */
static inline void put_small(u8 *out, i64 p, u64 digits, i64 n) {
    i64 q = p + n;
    while (n >= 2) {
        u64 t = digits / 100;
        u64 r = (digits - t * 100) * 2;
        out[q - 2] = (u8)DIGIT_PAIRS[r];
        out[q - 1] = (u8)DIGIT_PAIRS[r + 1];
        q -= 2;
        digits = t;
        n -= 2;
    }
    if (n == 1) out[q - 1] = (u8)(digits + 48);
}

/* the n <= 19 decimal digits of `digits` (zero padded) at out[p:p + n]; the low eight and the
   rest are two independent chains of divisions */
static inline void put_digits(u8 *out, i64 p, u64 digits, i64 n) {
    if (n > 8) {
        u64 hi = digits / 100000000;
        put_small(out, p + n - 8, digits - hi * 100000000, 8);
        put_small(out, p, hi, n - 8);
    } else {
        put_small(out, p, digits, n);
    }
}

/* repr() of the double with `bits` at out[o:]; returns its length, 0 if Grisu3 gave up */
static int format_one(u64 bits, u8 *out, i64 o) {
    i64 p = o;
    u64 mag = bits & ~SIGN;
    if (mag > UINT64_C(0x7FF0000000000000)) { /* nan: repr drops the sign */
        out[p] = 'n';
        out[p + 1] = 'a';
        out[p + 2] = 'n';
        return 3;
    }
    if (bits != mag) out[p++] = '-';
    if (mag == UINT64_C(0x7FF0000000000000)) {
        out[p] = 'i';
        out[p + 1] = 'n';
        out[p + 2] = 'f';
        return (int)(p + 3 - o);
    }
    if (mag == 0) {
        out[p] = '0';
        out[p + 1] = '.';
        out[p + 2] = '0';
        return (int)(p + 3 - o);
    }
    u64 digits;
    i64 n, k;
    if (!grisu3(mag, &digits, &n, &k)) return 0;
    i64 decpt = n + k;
    /* repr: positional notation for 1e-4 <= |v| < 1e16, else d.ddde+XX */
    if (-4 < decpt && decpt <= 16) {
        if (decpt <= 0) {
            out[p] = '0';
            out[p + 1] = '.';
            p += 2;
            for (i64 z = 0; z < -decpt; z++) out[p++] = '0';
            put_digits(out, p, digits, n);
            return (int)(p + n - o);
        }
        if (decpt >= n) {
            put_digits(out, p, digits, n);
            p += n;
            for (i64 z = 0; z < decpt - n; z++) out[p++] = '0';
            out[p] = '.';
            out[p + 1] = '0';
            return (int)(p + 2 - o);
        }
        u64 scale = POW10_U64[n - decpt];
        u64 whole = digits / scale;
        put_digits(out, p, whole, decpt);
        out[p + decpt] = '.';
        put_digits(out, p + decpt + 1, digits - whole * scale, n - decpt);
        return (int)(p + n + 1 - o);
    }
    if (n > 1) {
        u64 scale = POW10_U64[n - 1];
        u64 lead = digits / scale;
        out[p] = (u8)(lead + 48);
        out[p + 1] = '.';
        put_digits(out, p + 2, digits - lead * scale, n - 1);
        p += n + 1;
    } else {
        out[p] = (u8)(digits + 48);
        p += 1;
    }
    i64 x = decpt - 1;
    out[p] = 'e';
    out[p + 1] = x < 0 ? '-' : '+';
    p += 2;
    if (x < 0) x = -x;
    if (x >= 100) {
        out[p++] = (u8)(48 + x / 100);
        x %= 100;
    }
    out[p] = (u8)(48 + x / 10);
    out[p + 1] = (u8)(48 + x % 10);
    return (int)(p + 2 - o);
}

/* repr() of the n doubles with `bits` into slots of FLOAT_WIDTH bytes, lengths into lens (0:
   Grisu3 gave up), in parallel over blocks of rows */
void ccsv_format_floats(const u64 *bits, i64 n, u8 *slots, u8 *lens, i64 block) {
    i64 nblk = (n + block - 1) / block;
#pragma omp parallel for schedule(dynamic, 1) if (nblk > 1)
    for (i64 bi = 0; bi < nblk; bi++) {
        i64 last = (bi + 1) * block < n ? (bi + 1) * block : n;
        for (i64 i = bi * block; i < last; i++)
            lens[i] = (u8)format_one(bits[i], slots, i * FLOAT_WIDTH);
    }
}

/* the decimal text of the int64 v at out[o:]; returns its length */
static inline int format_int(i64 v, u8 *out, i64 o) {
    /* the magnitude as uint64, so that int64 min needs no special case */
    u64 m = v < 0 ? (u64)(-(v + 1)) + 1 : (u64)v;
    int n = 1;
    for (u64 t = m / 10; t != 0; t /= 10) n++;
    if (v < 0) {
        out[o++] = '-';
        n++;
    }
    i64 q = o + n - (v < 0 ? 1 : 0);
    do {
        q--;
        u64 t = m / 10;
        out[q] = (u8)(m - t * 10 + 48);
        m = t;
    } while (m != 0);
    return n;
}

/* ------------------------------------------------------------------------------------------
   rows of text
   ------------------------------------------------------------------------------------------ */

/* Format row i's columns into slots[i, off_k:off_k + w_k] (rows of `width` bytes), lengths
   into lens[i, k]. layout[k] = (kind, row of fbits/ints holding column k, byte offset, word
   base); fbits and ints are rows of n values; a LABEL column's code c is words row base + c
   (rows of wwidth bytes, lengths wlens). A float Grisu3 gives up on gets length 0. */
void ccsv_format_slots(const u64 *fbits, const i64 *ints, i64 n, const i64 *layout, i64 ncol,
                       const u8 *words, i64 wwidth, const i64 *wlens, u8 *slots, i64 width,
                       i64 *lens, i64 block) {
    i64 nblk = (n + block - 1) / block;
#pragma omp parallel for schedule(dynamic, 1) if (nblk > 1)
    for (i64 bi = 0; bi < nblk; bi++) {
        i64 last = (bi + 1) * block < n ? (bi + 1) * block : n;
        for (i64 i = bi * block; i < last; i++) {
            i64 base = i * width;
            for (i64 k = 0; k < ncol; k++) {
                i64 kind = layout[4 * k], src = layout[4 * k + 1], o = base + layout[4 * k + 2];
                if (kind == 0) {
                    lens[i * ncol + k] = format_one(fbits[src * n + i], slots, o);
                } else if (kind == 1) {
                    lens[i * ncol + k] = format_int(ints[src * n + i], slots, o);
                } else {
                    i64 w = layout[4 * k + 3] + ints[src * n + i];
                    memcpy(slots + o, words + w * wwidth, (size_t)wlens[w]);
                    lens[i * ncol + k] = wlens[w];
                }
            }
        }
    }
}

/* slots/lens of item (rows[m], cols[m]) at byte offs[m] := blob[starts[m]:starts[m + 1]] */
void ccsv_put_texts(u8 *slots, i64 width, i64 *lens, i64 ncol, const i64 *rows,
                    const i64 *cols, const i64 *offs, i64 m, const u8 *blob, const i64 *starts) {
    for (i64 k = 0; k < m; k++) {
        i64 a = starts[k], b = starts[k + 1];
        memcpy(slots + rows[k] * width + offs[k], blob + a, (size_t)(b - a));
        lens[rows[k] * ncol + cols[k]] = b - a;
    }
}

/* Row i of the output at out[start[i]:start[i + 1]]: the k text fields, then the slots,
   comma separated, newline terminated.

   Float and int slots are copied whole (a constant-size copy) and the position advanced by
   the text's length: the surplus is overwritten by what follows, within the row or by the
   next rows of the block, which the same thread writes later. A copy that would reach past
   the end of the block's text (into another thread's rows: a narrow row can be shorter than
   the surplus of the row before) is copied exactly. `out` needs FLOAT_WIDTH bytes of slack
   at the end. */
void ccsv_join_slots(u8 *out, const i64 *start, i64 n, const u8 *data, const i64 *offsets,
                     i64 k, const u8 *slots, i64 width, const i64 *lens, const i64 *layout,
                     i64 ncol, i64 block) {
    i64 nblk = (n + block - 1) / block;
#pragma omp parallel for schedule(dynamic, 1) if (nblk > 1)
    for (i64 bi = 0; bi < nblk; bi++) {
        i64 last = (bi + 1) * block < n ? (bi + 1) * block : n;
        i64 block_end = start[last];
        for (i64 i = bi * block; i < last; i++) {
            i64 p = start[i];
            for (i64 j = 0; j < k; j++) {
                i64 a = offsets[i * k + j], m = offsets[i * k + j + 1] - a;
                memcpy(out + p, data + a, (size_t)m);
                p += m;
                out[p++] = ',';
            }
            i64 base = i * width;
            for (i64 c = 0; c < ncol; c++) {
                const u8 *src = slots + base + layout[4 * c + 2];
                i64 m = lens[i * ncol + c], kind = layout[4 * c];
                if (kind == 0 && p + FLOAT_WIDTH <= block_end)
                    memcpy(out + p, src, FLOAT_WIDTH);
                else if (kind == 1 && p + INT_WIDTH <= block_end)
                    memcpy(out + p, src, INT_WIDTH);
                else
                    memcpy(out + p, src, (size_t)m);
                p += m;
                out[p++] = ',';
            }
            out[start[i + 1] - 1] = '\n';
        }
    }
}
