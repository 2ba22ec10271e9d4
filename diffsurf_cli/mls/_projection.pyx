# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The projection's Python face: `Target`, the target as the compiled projection sees it
(node arrays and their grids, built once), projecting whole clouds in one parallel loop
(OpenMP `prange`, per-thread scratch allocated once per call). The per-contactor code is
`_projection.pxd`'s. Linear algebra is textbook (Golub & Van Loan): the normal equations
[16]-[17] by Cholesky where the fit is well conditioned (the equilibrated Gram's R is then
QR's, `normal_fit`), else Householder QR of W^½P, the 3x3 frame's normal by powers of the
covariance's adjugate (a cyclic Jacobi where its eigenvalues are too close for them),
one-sided Jacobi for the exact σmin/σmax where the cheap bound cannot decide
(`triangular_rcond`). Instructions a point: `benchmarks/engine_speed.py --callgrind`.

Tolerances and constants are read from `diffsurf_cli.tol` into the `Options` struct at call
time; nothing here is a hand-kept copy of a Python value.
"""
import numpy as np

from libc.math cimport (sqrt, fabs, hypot, atan2, isfinite, isnan, cos, sin, INFINITY, NAN,
                        M_PI)
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t, int8_t, uint8_t, uint64_t
from cython.parallel cimport prange, parallel

from .. import tol
from ..threads import chunk_size, threads_for
from . import basis as _basis
from ._search import build_grid
from ._search cimport cell_index, spread_bits

WEIGHT_CODES = {"wendland": WENDLAND, "gauss": GAUSS, "singular": SINGULAR}
MAX_TERMS = NTERMS_MAX


cdef Scratch *scratch_new(int64_t cap, int nterms, int64_t near) noexcept nogil:
    cdef int64_t rows = imax(cap, nterms)
    cdef size_t doubles = <size_t>(8 * cap + near + rows * row_stride(nterms)
                                   + 2 * nterms * nterms + 3 * nterms)
    cdef size_t ints = <size_t>(4 * cap + near)
    cdef Scratch *sc = <Scratch *>malloc(sizeof(Scratch))
    if sc == NULL:
        return NULL
    cdef char *mem = <char *>malloc(doubles * sizeof(double) + ints * sizeof(int64_t))
    if mem == NULL:
        free(sc)
        return NULL
    sc.mem = mem
    sc.cap = cap
    cdef double *d = <double *>mem
    sc.cand_d2 = d
    d += cap
    sc.s = d
    d += cap
    sc.t = d
    d += cap
    sc.z = d
    d += cap
    sc.w = d
    d += cap
    sc.geo = d
    d += cap
    sc.arc_start = d
    d += cap
    sc.arc_end = d
    d += cap
    sc.near_d2 = d
    d += near
    sc.a = d
    d += rows * row_stride(nterms)
    sc.rfac = d
    d += nterms * nterms
    sc.work = d
    d += nterms * nterms
    sc.sig = d
    d += nterms
    sc.scale = d
    d += nterms
    sc.alpha = d
    d += nterms
    cdef int64_t *ip = <int64_t *>d
    sc.cand_i = ip
    ip += cap
    sc.near_i = ip
    ip += near
    sc.live_i = ip
    ip += cap
    sc.res[0].index = ip
    ip += cap
    sc.res[1].index = ip
    sc.h_min = 0.0
    return sc


cdef void scratch_free(Scratch *sc) noexcept nogil:
    if sc != NULL:
        free(sc.mem)
        free(sc)


cdef inline int64_t basis_rows(int n, const int *ea, const int *eb, const double *s,
                               const double *t, const double *z, const double *w,
                               int64_t count, double floor, double *a,
                               double *scale) noexcept nogil:
    """The rows sqrt(w/w_max) [p(s, t) | z] [16] of the support nodes with w > 0 into `a`
    (row stride `row_stride(n)`: the basis s^ea t^eb in columns :n, z in column n, zeros
    after), the norms of the basis columns (floored) into `scale`; returns the number of rows.

    The columns are not divided by their norms: Householder QR is column-scaling invariant
    (its backward error is columnwise), so R of the equilibrated matrix, on which rcond is
    judged, is R with its columns divided by `scale` (n(n+1)/2 divisions instead of n per
    row), and α solves the unscaled R directly. Inlined with n a constant (3, 6 or 10): the
    loops over the basis unroll; the 6 terms of a quadratic (`make_options` checks that
    every basis of 6 terms is [1, s, t, s², st, t²]) are written out."""
    cdef int j, ld = row_stride(n)
    cdef double wmax = 0.0, root, sr, tr
    cdef double sp[4]
    cdef double tp[4]
    cdef double *row
    cdef int64_t r, rows = 0
    sp[0] = 1.0
    tp[0] = 1.0
    for j in range(n):
        scale[j] = 0.0
    for r in range(count):
        wmax = dmax(wmax, w[r])
    for r in range(count):
        if w[r] <= 0.0:
            continue
        root = sqrt(w[r] / wmax)
        row = a + rows * ld
        sr = s[r]
        tr = t[r]
        if n == 6:
            row[0] = root
            row[1] = root * sr
            row[2] = root * tr
            row[3] = root * (sr * sr)
            row[4] = (root * sr) * tr
            row[5] = root * (tr * tr)
        else:
            sp[1] = sr
            tp[1] = tr
            for j in range(2, 4):
                sp[j] = sp[j - 1] * sr
                tp[j] = tp[j - 1] * tr
            for j in range(n):
                row[j] = root * (sp[ea[j]] * tp[eb[j]])
        for j in range(n):  # the column norms, summed in row order
            scale[j] += row[j] * row[j]
        row[n] = root * z[r]
        for j in range(n + 1, ld):
            row[j] = 0.0
        rows += 1
    column_scales(scale, n, floor)
    return rows


cdef inline int64_t weighted_system(const Options *op, int n, const double *s,
                                    const double *t, const double *z, const double *w,
                                    int64_t count, double *a, double *scale) noexcept nogil:
    """`basis_rows` of the basis (op.ea, op.eb) in (s, t)."""
    return basis_rows(n, op.ea, op.eb, s, t, z, w, count, op.equilibration_floor, a, scale)


cdef inline int64_t normal_system(const Options *op, int n, const double *s,
                                  const double *t, const double *z, const double *w,
                                  int64_t count, double *g, double *b,
                                  double *scale) noexcept nogil:
    """The normal equations [16]-[17] of the support nodes with w > 0: PᵀWP into the upper
    triangle of g (row stride n), PᵀWZ into b, the norms of W^½P's columns (floored, as
    `weighted_system`'s) into `scale`; returns the number of those nodes.

    Inlined with n a constant. The quadratic basis's Gram entries are the 15 weighted moments
    Σ w s^a t^b, a + b ≤ 4 (its 21 entries repeat some), summed in node order."""
    cdef int i, j
    cdef int64_t r, rows = 0
    cdef double wr, sr, tr, zr, ws, wt, ws2, wst, wt2, ws3, ws2t, wst2, wt3, wz, wzs, wzt
    cdef double m00 = 0.0, m10 = 0.0, m01 = 0.0, m20 = 0.0, m11 = 0.0, m02 = 0.0
    cdef double m30 = 0.0, m21 = 0.0, m12 = 0.0, m03 = 0.0
    cdef double m40 = 0.0, m31 = 0.0, m22 = 0.0, m13 = 0.0, m04 = 0.0
    cdef double b0 = 0.0, b1 = 0.0, b2 = 0.0, b3 = 0.0, b4 = 0.0, b5 = 0.0
    cdef double sp[4]
    cdef double tp[4]
    cdef double p[NTERMS_MAX]
    if n == 6:
        for r in range(count):
            wr = w[r]
            if wr <= 0.0:
                continue
            sr = s[r]
            tr = t[r]
            zr = z[r]
            ws = wr * sr
            wt = wr * tr
            ws2 = ws * sr
            wst = ws * tr
            wt2 = wt * tr
            ws3 = ws2 * sr
            ws2t = ws2 * tr
            wst2 = wst * tr
            wt3 = wt2 * tr
            m00 += wr
            m10 += ws
            m01 += wt
            m20 += ws2
            m11 += wst
            m02 += wt2
            m30 += ws3
            m21 += ws2t
            m12 += wst2
            m03 += wt3
            m40 += ws3 * sr
            m31 += ws3 * tr
            m22 += ws2t * tr
            m13 += wst2 * tr
            m04 += wt3 * tr
            wz = wr * zr
            wzs = wz * sr
            wzt = wz * tr
            b0 += wz
            b1 += wzs
            b2 += wzt
            b3 += wzs * sr
            b4 += wzs * tr
            b5 += wzt * tr
            rows += 1
        g[0] = m00
        g[1] = m10
        g[2] = m01
        g[3] = m20
        g[4] = m11
        g[5] = m02
        g[7] = m20
        g[8] = m11
        g[9] = m30
        g[10] = m21
        g[11] = m12
        g[14] = m02
        g[15] = m21
        g[16] = m12
        g[17] = m03
        g[21] = m40
        g[22] = m31
        g[23] = m22
        g[28] = m22
        g[29] = m13
        g[35] = m04
        b[0] = b0
        b[1] = b1
        b[2] = b2
        b[3] = b3
        b[4] = b4
        b[5] = b5
    else:
        for i in range(n):
            b[i] = 0.0
            for j in range(i, n):
                g[i * n + j] = 0.0
        sp[0] = 1.0
        tp[0] = 1.0
        for r in range(count):
            wr = w[r]
            if wr <= 0.0:
                continue
            sp[1] = s[r]
            tp[1] = t[r]
            for j in range(2, 4):
                sp[j] = sp[j - 1] * sp[1]
                tp[j] = tp[j - 1] * tp[1]
            for j in range(n):
                p[j] = sp[op.ea[j]] * tp[op.eb[j]]
            for i in range(n):
                ws = wr * p[i]
                for j in range(i, n):
                    g[i * n + j] += ws * p[j]
                b[i] += ws * z[r]
            rows += 1
    for j in range(n):
        scale[j] = g[j * n + j]
    column_scales(scale, n, op.equilibration_floor)
    return rows


cdef inline bint normal_fit(const Options *op, Scratch *sc, const double *w, int64_t count,
                            int n, bint solve_alpha, double *rcond) noexcept nogil:
    """The fit [16]-[17] by the normal equations where they settle it: the support's
    equilibrated Gram matrix D⁻¹PᵀWPD⁻¹ (D = diag(scale)) factored RᵀR by Cholesky. R is then
    (to round-off, and up to the signs of its rows) the R of W^½PD⁻¹'s Householder QR, whose
    rcond `fit` judges, so where rcond_F(R) >= rcond_min (`triangular_rcond` accepts on the
    bound alone) it is returned in rcond and, with `solve_alpha`, α = D⁻¹R⁻¹R⁻ᵀD⁻¹PᵀWZ into
    sc.alpha; True. False (nothing settled) where the support has fewer than n weighted
    nodes, a pivot is not positive, rcond_F < rcond_min or α is not finite: the caller then
    takes the QR path, which decides those cases exactly as before.

    Cost: the moments are ~n²/2 flops a node against Householder's ~2n² (and no square root
    a node); accepted fits have σmin/σmax >= rcond_min, so the Gram's conditioning, at most
    1/rcond_min², loses no more than ~1e-10 relative (the tests' reference is an SVD)."""
    cdef double *g = sc.rfac
    cdef double *b = sc.sig  # (free: only the exact branch of triangular_rcond uses it)
    cdef double *scale = sc.scale
    cdef double inv[NTERMS_MAX]
    cdef double d[NTERMS_MAX]
    cdef double rc
    cdef int i, j
    if normal_system(op, n, sc.s, sc.t, sc.z, w, count, g, b, scale) < n:
        return False
    for j in range(n):
        inv[j] = 1.0 / scale[j]
    # Cholesky (Golub & Van Loan §4.2) of the equilibrated Gram, row by row of R, in place,
    # with the forward substitution Rᵀu = D⁻¹PᵀWZ (into b)
    # (each row expected to succeed: the compiler then inlines all of them, rows unrolled)
    if n == 6:
        if not (likely(cholesky_row(g, 6, 0, inv, d, b))
                and likely(cholesky_row(g, 6, 1, inv, d, b))
                and likely(cholesky_row(g, 6, 2, inv, d, b))
                and likely(cholesky_row(g, 6, 3, inv, d, b))
                and likely(cholesky_row(g, 6, 4, inv, d, b))
                and likely(cholesky_row(g, 6, 5, inv, d, b))):
            return False
    elif n == 3:
        if not (likely(cholesky_row(g, 3, 0, inv, d, b))
                and likely(cholesky_row(g, 3, 1, inv, d, b))
                and likely(cholesky_row(g, 3, 2, inv, d, b))):
            return False
    else:
        for i in range(n):
            if not cholesky_row(g, n, i, inv, d, b):
                return False
    rc = frobenius_rcond(g, n, sc.work)
    if not (rc >= op.rcond_min):
        return False
    if solve_alpha:
        if n == 6:  # R y = u, α = D⁻¹ y
            back_row(g, 6, 5, d, b)
            back_row(g, 6, 4, d, b)
            back_row(g, 6, 3, d, b)
            back_row(g, 6, 2, d, b)
            back_row(g, 6, 1, d, b)
            back_row(g, 6, 0, d, b)
        elif n == 3:
            back_row(g, 3, 2, d, b)
            back_row(g, 3, 1, d, b)
            back_row(g, 3, 0, d, b)
        else:
            for i in range(n - 1, -1, -1):
                back_row(g, n, i, d, b)
        for i in range(n):
            sc.alpha[i] = b[i] * inv[i]
            if not isfinite(sc.alpha[i]):
                return False
    rcond[0] = rc
    return True


cdef inline double qr_rcond(Scratch *sc, int64_t rows, int n, bint invertible_only,
                            double rcond_min) noexcept nogil:
    """Householder QR of the `rows` rows in sc.a (R into sc.rfac and over sc.a's upper
    triangle, Qᵀ z into column n); returns R's rcond (`triangular_rcond`), or, where only
    whether R is invertible matters (the singular weight, stiff by design), INFINITY or 0."""
    cdef int j
    householder_qr(sc.a, rows, n, sc.scale, sc.rfac)
    if invertible_only:
        for j in range(n):
            if not (sc.rfac[j * n + j] != 0.0):
                return 0.0
        return INFINITY
    return triangular_rcond(sc.rfac, n, sc.work, sc.sig, rcond_min)


cdef inline bint back_substitute(const double *a, int n, double *x) noexcept nogil:
    """x solving R x = Qᵀ z after `qr_rcond` (R over a's upper triangle, row stride
    `row_stride(n)`, Qᵀ z in column n); False where x is not finite."""
    cdef int j, c, ld = row_stride(n)
    cdef double acc
    for j in range(n - 1, -1, -1):
        acc = a[j * ld + n]
        for c in range(j + 1, n):
            acc -= a[j * ld + c] * x[c]
        x[j] = acc / a[j * ld + j]
    for j in range(n):
        if not isfinite(x[j]):
            return False
    return True


cdef inline double fit_n(const Options *op, Scratch *sc, int64_t count,
                         int n) noexcept nogil:
    """`fit` with n = op.nterms (inlined with n a constant)."""
    cdef int j
    cdef double rcond = 0.0, rc
    cdef bint solvable, singular = op.wp.kind == SINGULAR
    if not singular and normal_fit(op, sc, sc.w, count, n, True, &rcond):
        return rcond
    cdef int64_t rows = weighted_system(op, n, sc.s, sc.t, sc.z, sc.w, count, sc.a, sc.scale)
    solvable = rows >= n
    if solvable:
        rc = qr_rcond(sc, rows, n, singular, op.rcond_min)
        solvable = rc > 0.0
        if not singular:
            rcond = rc
    if solvable:
        solvable = back_substitute(sc.a, n, sc.alpha)
    if not solvable:
        for j in range(n):
            sc.alpha[j] = NAN
    if singular:
        # judge the support's geometry on the smooth weight with the same support
        if normal_fit(op, sc, sc.geo, count, n, False, &rcond):
            return rcond
        rows = weighted_system(op, n, sc.s, sc.t, sc.z, sc.geo, count, sc.a, sc.scale)
        rcond = qr_rcond(sc, rows, n, False, op.rcond_min) if rows >= n else 0.0
    return rcond


cdef double fit(const Options *op, Scratch *sc, int64_t count) noexcept nogil:
    """Weighted least squares [17] of the support (the first `count` entries of s, t, z, w):
    α into sc.alpha (NaN when impossible); returns rcond (on the smooth weights sc.geo with
    the singular weight, which is stiff by design). One copy per basis size, so that the
    compiler unrolls the small loops."""
    if op.nterms == 6:
        return fit_n(op, sc, count, 6)
    if op.nterms == 3:
        return fit_n(op, sc, count, 3)
    return fit_n(op, sc, count, 10)


cdef inline int64_t reduced_system(const Options *op, int r, const double *ua,
                                   const double *ub, const double *z, const double *w,
                                   int64_t count, double *a, double *scale) noexcept nogil:
    """`basis_rows` of the reduced basis r (op.ra, op.rb) in the turned coordinates
    (ua, ub) = (a, b)."""
    return basis_rows(op.rsize[r], op.ra + NTERMS_MAX * r, op.rb + NTERMS_MAX * r, ua, ub, z,
                      w, count, op.equilibration_floor, a, scale)


cdef void rotate_back(const Options *op, int r, const double *beta, double c, double sn,
                      double *alpha) noexcept nogil:
    """α of the full basis in (s, t) from β of the reduced basis r in (a, b) = (c s + sn t,
    c t - sn s): each a^i b^j expanded by the binomial theorem (a polynomial of the full
    basis's degree)."""
    cdef int j, i, jb, p, q, k, ps, pt
    cdef double ca, cb
    for k in range(op.nterms):
        alpha[k] = 0.0
    for j in range(op.rsize[r]):
        i = op.ra[NTERMS_MAX * r + j]
        jb = op.rb[NTERMS_MAX * r + j]
        for p in range(i + 1):  # a^i = Σ_p C(i, p) (c s)^p (sn t)^(i-p)
            ca = binomial(i, p) * ipow(c, p) * ipow(sn, i - p)
            for q in range(jb + 1):  # b^jb = Σ_q C(jb, q) (-sn s)^q (c t)^(jb-q)
                cb = binomial(jb, q) * ipow(-sn, q) * ipow(c, jb - q)
                ps = p + q
                pt = i + jb - p - q
                for k in range(op.nterms):
                    if op.ea[k] == ps and op.eb[k] == pt:
                        alpha[k] += beta[j] * (ca * cb)
                        break


cdef bint strip_direction(const Options *op, Scratch *sc, int64_t count, const double *pw,
                          double *angle) noexcept nogil:
    """The angle of the a axis of the reduced bases (tol.ROW_VARIANCE, tol.STRIP_RANK): along
    a row (weighted PCA of the support's (s, t)), else along two rows (the null direction of
    the quadratic part of the polynomial that vanishes on the support); False without one."""
    cdef double wsum = 0.0, ms = 0.0, mt = 0.0, css = 0.0, cst = 0.0, ctt = 0.0, ds, dt
    cdef double half, root, q11, q12, q22, big, small
    cdef double x[6]
    cdef int64_t i, rows
    for i in range(count):
        if pw[i] > 0:
            wsum += pw[i]
            ms += pw[i] * sc.s[i]
            mt += pw[i] * sc.t[i]
    if not (wsum > 0):
        return False
    ms /= wsum
    mt /= wsum
    for i in range(count):
        if pw[i] > 0:
            ds = sc.s[i] - ms
            dt = sc.t[i] - mt
            css += pw[i] * ds * ds
            cst += pw[i] * ds * dt
            ctt += pw[i] * dt * dt
    half = 0.5 * (css + ctt)
    root = sqrt(0.25 * (css - ctt) * (css - ctt) + cst * cst)
    if half - root <= op.row_variance * (half + root):  # a row: its principal direction
        angle[0] = 0.5 * atan2(2.0 * cst, css - ctt)
        return True
    rows = weighted_system(op, 6, sc.s, sc.t, sc.z, pw, count, sc.a, sc.scale)
    if rows < 6:
        return False
    householder_qr(sc.a, rows, 6, sc.scale, sc.rfac)
    smallest_right_vector(sc.rfac, 6, sc.work, x)
    # the quadratic part of Σ x_j p_j / scale_j: [[q11, q12], [q12, q22]]
    q11 = x[3] / sc.scale[3]
    q12 = 0.5 * x[4] / sc.scale[4]
    q22 = x[5] / sc.scale[5]
    half = 0.5 * (q11 + q22)
    root = sqrt(0.25 * (q11 - q22) * (q11 - q22) + q12 * q12)
    big = fabs(half) + root
    small = fabs(fabs(half) - root)
    if not (small <= op.strip_rank * big and big > 0):
        return False
    # the eigenvector of the eigenvalue of larger magnitude is across the rows
    angle[0] = 0.5 * atan2(2.0 * q12, q11 - q22)  # that of half + root
    if half >= 0:
        angle[0] += 0.5 * M_PI
    return True


cdef bint frame_fixed(const TargetC *tg, const Options *op, const Result *res,
                      const int64_t *nodes, int64_t count) noexcept nogil:
    """Whether more than a row of nodes fixes the frame of res (tol.RULED_SPREAD): the
    whole target for the global frame, else the in-plane spread of the frame's ball (the
    support's `count` nodes), both of its variances."""
    cdef double n = 0.0, m0 = 0.0, m1 = 0.0, c00 = 0.0, c01 = 0.0, c11 = 0.0, x0, x1, d
    cdef double half, root
    cdef int64_t j
    cdef int col
    if tg.global_frame:
        return op.ruled_global
    for j in range(count):
        x0 = 0.0
        x1 = 0.0
        for col in range(3):
            d = tg.nodes[3 * nodes[j] + col] - res.origin[col]
            x0 += res.axes[col] * d
            x1 += res.axes[3 + col] * d
        n += 1.0
        m0 += x0
        m1 += x1
        c00 += x0 * x0
        c01 += x0 * x1
        c11 += x1 * x1
    if count < 3:
        return False
    c00 -= m0 * m0 / n
    c01 -= m0 * m1 / n
    c11 -= m1 * m1 / n
    half = 0.5 * (c00 + c11)
    root = sqrt(0.25 * (c00 - c11) * (c00 - c11) + c01 * c01)
    return half - root >= op.ruled_spread * (half + root) and half + root > 0


cdef bint fit_one(const Options *op, Scratch *sc, int64_t count, int r, const double *ua,
                  const double *ub, double c, double sn) noexcept nogil:
    """The reduced basis r in (ua, ub) = (a, b), fitted [17] where its rcond passes the full
    basis's rule (on the smooth weight with the singular one) and rotated back into sc.alpha
    (a = c s + sn t); False (sc.alpha untouched) where it does not."""
    cdef int n = op.rsize[r]
    cdef int64_t rows
    cdef bint singular = op.wp.kind == SINGULAR
    cdef double beta[NTERMS_MAX]
    rows = reduced_system(op, r, ua, ub, sc.z, sc.w, count, sc.a, sc.scale)
    if rows < n or not (qr_rcond(sc, rows, n, singular, op.rcond_min) >= op.rcond_min):
        return False
    if not back_substitute(sc.a, n, beta):
        return False
    if singular:  # the geometry judged on the smooth weight
        rows = reduced_system(op, r, ua, ub, sc.z, sc.geo, count, sc.a, sc.scale)
        if rows < n or not (qr_rcond(sc, rows, n, False, op.rcond_min) >= op.rcond_min):
            return False
    rotate_back(op, r, beta, c, sn, sc.alpha)
    return True


cdef int fit_reduced(const Options *op, Scratch *sc, int64_t count, int64_t positive,
                     bint ruled, double *direction, int *which) noexcept nogil:
    """The terms the support can determine, where it cannot determine the full basis (a strip
    two nodes wide, a row of nodes): (a, b) are (s, t) turned along and across the support's
    direction (`strip_direction`, on the fit's weights; the smooth ones with the singular
    weight), and the first reduced basis (basis.REDUCED, largest first) with enough nodes and
    rcond >= rcond_min (the full basis's rule) is fitted [17] and rotated back into sc.alpha
    (`fit_one`); those constant across only where `ruled` (`frame_fixed`), those other than
    complete ones (the plane, the cubic's quadratic) only where the support has a direction (its
    angle into `direction`, else NaN); the index of the basis fitted into `which` (-1: none).

    A frozen pairing (which[0] >= 0 on entry: `project_with`) fits that basis at that
    direction, held fixed as the frame is [§4.2].

    Returns its number of terms, 0 (α NaN) when even [1, a] cannot be fitted. sc.arc_start
    and sc.arc_end (the hull test's scratch, free until then) hold a and b."""
    cdef const double *pw = sc.geo if op.wp.kind == SINGULAR else sc.w
    cdef double *ua = sc.arc_start
    cdef double *ub = sc.arc_end
    cdef double theta = 0.0, c, sn
    cdef int r, j, frozen = which[0]
    cdef int64_t i
    cdef bint directed
    if frozen >= 0:
        directed = isfinite(direction[0])
        theta = direction[0] if directed else 0.0
    else:
        directed = strip_direction(op, sc, count, pw, &theta)
        direction[0] = theta if directed else NAN
    which[0] = -1
    if positive > 0:
        c = cos(theta)
        sn = sin(theta)
        for i in range(count):
            ua[i] = c * sc.s[i] + sn * sc.t[i]
            ub[i] = c * sc.t[i] - sn * sc.s[i]
        for r in range(op.nreduced):
            if frozen >= 0:
                if r != frozen or positive < op.rsize[r]:
                    continue
            elif (positive < op.rsize[r] or not (ruled or op.across[r])
                    or not (directed or op.plane_only[r])):
                continue
            if fit_one(op, sc, count, r, ua, ub, c, sn):
                which[0] = r
                return op.rsize[r]
    for j in range(op.nterms):
        sc.alpha[j] = NAN
    return 0


cdef int64_t newton(const Options *op, const double *alpha, const double *c, double *f,
                    double *st, bint *converged) noexcept nogil:
    """The proximal point [30] on the local approximation, c the contactor in the scaled
    frame: Newton on D = ½‖(s, t, f) - c‖², whose gradient is (x^c - x^d)·τ_k [28], full
    Newton while ∇²D is positive definite, Gauss-Newton beyond a focal point, steps capped at
    half the support radius. (s̄, t̄) into st; returns the iterations."""
    cdef int64_t its = 0, _it
    cdef int j
    cdef double r, fs, ft, g1, g2, h11, h12, h22, det, d1, d2, step, cap
    cdef bint gn
    st[0] = c[0]
    st[1] = c[1]
    converged[0] = False
    for j in range(op.nterms):
        if not isfinite(alpha[j]):
            return 0
    for _it in range(op.newton_max_iter):
        surface_derivatives(op.nterms, op.ea, op.eb, alpha, st[0], st[1], f)
        r = f[0] - c[2]
        fs = f[1]
        ft = f[2]
        g1 = st[0] - c[0] + r * fs
        g2 = st[1] - c[1] + r * ft
        h11 = 1 + fs * fs + r * f[3]
        h12 = fs * ft + r * f[4]
        h22 = 1 + ft * ft + r * f[5]
        det = h11 * h22 - h12 * h12
        gn = not (det > 0 and h11 > 0)
        if gn:
            h11 = 1 + fs * fs
            h12 = fs * ft
            h22 = 1 + ft * ft
            det = h11 * h22 - h12 * h12
        d1 = -(h22 * g1 - h12 * g2) / det
        d2 = -(h11 * g2 - h12 * g1) / det
        step = d1 * d1 + d2 * d2
        # hypot's care for overflow only where the squares overflow (a call costs ~2% of
        # the time; the two agree to an ulp)
        step = sqrt(step) if step < INFINITY else hypot(d1, d2)
        cap = 0.5 / step if step > 0.5 else 1.0
        st[0] += cap * d1
        st[1] += cap * d2
        its += 1
        if step < op.newton_step and not gn:
            converged[0] = True
            return its
        if not isfinite(step):
            return its
    return its


cdef void frame_e1(const Options *op, const double *e3, double *out) noexcept nogil:
    """frame.in_plane_axis: a fixed direction projected on the plane normal to e3."""
    cdef const double *g = op.e1_guide
    cdef double dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    cdef double norm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    cdef int e
    if not (fabs(dot) < 0.9 * norm):
        g = op.e1_guide_alt
    dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    for e in range(3):
        out[e] = g[e] - dot * e3[e]


cdef void right_handed(double *e1, const double *e3, double *axes) noexcept nogil:
    """Rows e1 (orthogonalised, unit), e2 = e3 x e1, e3 into axes (3x3)."""
    cdef double dot = e1[0] * e3[0] + e1[1] * e3[1] + e1[2] * e3[2], norm
    cdef int e
    for e in range(3):
        e1[e] -= dot * e3[e]
    norm = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    for e in range(3):
        axes[e] = e1[e] / norm
        axes[6 + e] = e3[e]
    axes[3] = e3[1] * axes[2] - e3[2] * axes[1]
    axes[4] = e3[2] * axes[0] - e3[0] * axes[2]
    axes[5] = e3[0] * axes[1] - e3[1] * axes[0]


cdef double local_spacing(const TargetC *tg, const Options *op, const double *x,
                          Scratch *sc) noexcept nogil:
    """The local node spacing h at x, and (into sc.nbar, sc.foot) the weighted normal of the
    target near x and x's foot on the target.

    A function of the geometry alone, whatever the search order or tie-break: of the k + 1
    nearest nodes (k = tol.SPACING_NEIGHBOURS), d the (k+1)-th distance (a value, the same
    whichever node a tie picks), each node j weighs w_j = (1 - d_j²/d²)², zero for every node
    at distance d; h = Σ w_j h_j / Σ w_j, n̄ = Σ w_j n_j normalised, x̄ = Σ w_j x_j / Σ w_j.
    If all k + 1 are equidistant, every node within d counts once. The foot is x's
    projection on the plane through x̄ normal to n̄ (x̄ itself without facets)."""
    cdef int64_t got = nearest(&tg.grid, x, op.spacing_neighbours, sc.cap, sc.cand_i,
                               sc.cand_d2, sc.near_i, sc.near_d2)
    cdef double d2max = sc.near_d2[got - 1], wj, q, wsum = 0.0, h = 0.0, nn, dn, d2, r
    cdef double xb[3]
    cdef int64_t j, node, i0, i1, j0, j1, k0, k1, i, jj, c, a
    cdef int e
    cdef const Grid *g = &tg.grid
    for e in range(3):
        xb[e] = 0.0
        sc.nbar[e] = 0.0
    for j in range(got):
        if not (sc.near_d2[j] < d2max):
            continue
        q = 1.0 - sc.near_d2[j] / d2max
        wj = q * q
        node = sc.near_i[j]
        wsum += wj
        h += wj * tg.node_spacing[node]
        for e in range(3):
            xb[e] += wj * tg.nodes[3 * node + e]
            sc.nbar[e] += wj * tg.normals[3 * node + e]
    if not (wsum > 0.0):  # all equidistant: every node within d, once each
        r = sqrt(d2max)
        i0 = cell_index(x[0] - r, g.lo[0], g.cell, g.dims[0])
        i1 = cell_index(x[0] + r, g.lo[0], g.cell, g.dims[0])
        j0 = cell_index(x[1] - r, g.lo[1], g.cell, g.dims[1])
        j1 = cell_index(x[1] + r, g.lo[1], g.cell, g.dims[1])
        k0 = cell_index(x[2] - r, g.lo[2], g.cell, g.dims[2])
        k1 = cell_index(x[2] + r, g.lo[2], g.cell, g.dims[2])
        for i in range(i0, i1 + 1):
            for jj in range(j0, j1 + 1):
                c = (i * g.dims[1] + jj) * g.dims[2]
                for a in range(g.start[c + k0], g.start[c + k1 + 1]):
                    node = g.order[a]
                    d2 = distance2(tg.nodes, node, x)
                    if d2 <= d2max:
                        wsum += 1.0
                        h += tg.node_spacing[node]
                        for e in range(3):
                            xb[e] += tg.nodes[3 * node + e]
                            sc.nbar[e] += tg.normals[3 * node + e]
    for e in range(3):
        xb[e] /= wsum
    nn = dmax(sqrt(sc.nbar[0] * sc.nbar[0] + sc.nbar[1] * sc.nbar[1]
                   + sc.nbar[2] * sc.nbar[2]), 1e-300)
    dn = 0.0
    for e in range(3):
        sc.nbar[e] /= nn
        dn += (x[e] - xb[e]) * sc.nbar[e]
    for e in range(3):
        sc.foot[e] = x[e] - dn * sc.nbar[e] if tg.has_faces else xb[e]
    return h / wsum


cdef int64_t knn_ties(const Grid *g, const double *p, int64_t k, Scratch *sc,
                      Result *res) noexcept nogil:
    """The k nearest nodes of p and every node tied with the k-th (all within its distance,
    a value: no tie-break decides which nodes a 'knn' support holds), into cand_i; the k-th
    squared distance into sc.knn_d2."""
    cdef int64_t count = knn(g, p, k, sc.cand_i, sc.cand_d2)
    sc.knn_d2 = sc.cand_d2[count - 1]
    count = ball(g, p, sc.knn_d2, sc.cap, sc.cand_i, sc.cand_d2)
    if count > sc.cap:
        res.overflow = True
        count = sc.cap
    return count


cdef int64_t select_support(const TargetC *tg, const Options *op, const double *ref,
                            int attempt, Scratch *sc, Result *res) noexcept nogil:
    """Support and frame of the local approximation centred at `ref` (res.h already set):
    the support nodes in cand_i[:count], res.axes, res.R; res.overflow when the scratch was
    too small."""
    cdef int64_t *cand_i = sc.cand_i
    cdef double *cand_d2 = sc.cand_d2
    cdef double *geo = sc.geo
    cdef double *axes = res.axes
    cdef double pp[3]
    cdef double e1[3]
    cdef double e3[3]
    cdef double cov[9]
    cdef double R = 0.0, ballr, facing, wsum, wj, dr, dot, u0, u1, d
    cdef int64_t count = 0, kept, j, node
    cdef int e, col, rr
    cdef const double *x
    cdef const double *nv
    cdef double h = res.h
    if tg.global_frame:
        for e in range(9):
            axes[e] = tg.frame_axes[e]
        for e in range(2):
            pp[e] = 0.0
            for col in range(3):
                pp[e] += tg.frame_axes[3 * e + col] * (ref[col] - tg.frame_origin[col])
        pp[2] = 0.0
        if op.knn:
            count = knn_ties(&tg.plane, pp, op.k[attempt], sc, res)
            R = op.knn_factor * sqrt(sc.knn_d2)
        else:
            R = op.radius[attempt] * h
            count = ball(&tg.plane, pp, R * R, sc.cap, cand_i, cand_d2)
            if count > sc.cap:
                res.overflow = True
                count = sc.cap
        res.R = R
        return count
    # search around the reference point's foot on the target, not around the point itself:
    # a contactor several spacings off the surface must still find the nodes under it
    if op.knn:
        count = knn_ties(&tg.grid, sc.foot, op.k[attempt], sc, res)
        ballr = 1.0001 * sqrt(sc.knn_d2)
    else:
        R = op.radius[attempt] * h
        ballr = op.frame_ball * R
        count = ball(&tg.grid, sc.foot, ballr * ballr, sc.cap, cand_i, cand_d2)
        if count > sc.cap:
            res.overflow = True
            count = sc.cap
    # in one pass: drop the nodes of another sheet (the far side of a thin tube or plate),
    # those facing away from the target's normal near the reference point (with facets), and
    # take the weighted moments of the offsets of the others from the first of them (a few
    # spacings: Σw d dᵀ - (Σw d)(Σw d)ᵀ/Σw loses nothing to cancellation there, unlike offsets
    # from a foot far off the target) for a weighted PCA over the ball, and their weighted
    # normal (which orients e3)
    cdef double nsum[3]
    cdef double inv_b2 = 1.0 / (ballr * ballr)
    # (the sums in scalars, and the reference normal and first node read once: the compiler
    # keeps them in registers, where arrays written through pointers it must reload and store)
    cdef double nb0 = sc.nbar[0], nb1 = sc.nbar[1], nb2 = sc.nbar[2], sheet_cos = op.sheet_cos
    cdef double o0 = 0.0, o1 = 0.0, o2 = 0.0, d0, d1, d2, p0 = 0.0, p1 = 0.0, p2 = 0.0
    cdef double n0 = 0.0, n1 = 0.0, n2 = 0.0, c00 = 0.0, c01 = 0.0, c02 = 0.0, c11 = 0.0
    cdef double c12 = 0.0, c22 = 0.0
    cdef bint faces = tg.has_faces
    wsum = 0.0
    kept = 0
    for j in range(count):
        node = cand_i[j]
        nv = tg.normals + 3 * node
        if faces:
            facing = nv[0] * nb0 + nv[1] * nb1 + nv[2] * nb2
            if not (facing >= sheet_cos):
                continue
        x = tg.nodes + 3 * node
        if kept == 0:
            o0 = x[0]
            o1 = x[1]
            o2 = x[2]
        cand_i[kept] = node
        wj = weight_value(WENDLAND, cand_d2[j] * inv_b2, &op.wp)
        geo[kept] = wj
        kept += 1
        if wj <= 0.0:
            continue
        wsum += wj
        d0 = x[0] - o0
        d1 = x[1] - o1
        d2 = x[2] - o2
        p0 += wj * d0
        p1 += wj * d1
        p2 += wj * d2
        n0 += wj * nv[0]
        n1 += wj * nv[1]
        n2 += wj * nv[2]
        dr = wj * d0
        c00 += dr * d0
        c01 += dr * d1
        c02 += dr * d2
        dr = wj * d1
        c11 += dr * d1
        c12 += dr * d2
        dr = wj * d2
        c22 += dr * d2
    count = kept
    pp[0] = p0
    pp[1] = p1
    pp[2] = p2
    nsum[0] = n0
    nsum[1] = n1
    nsum[2] = n2
    cov[0] = c00
    cov[1] = c01
    cov[2] = c02
    cov[4] = c11
    cov[5] = c12
    cov[8] = c22
    if wsum > 0:
        for rr in range(3):
            for col in range(rr, 3):
                cov[3 * rr + col] -= pp[rr] * pp[col] / wsum
    cov[3] = cov[1]
    cov[6] = cov[2]
    cov[7] = cov[5]
    if not smallest_eigenvector_psd(cov, e3):
        smallest_eigenvector(cov, e3)
    # +e3 out of the target as the facets orient it; without facets, as the mean plane's
    dot = 0.0
    for e in range(3):
        dot += (nsum[e] if tg.has_faces else wsum * tg.frame_axes[6 + e]) * e3[e]
    if dot < 0:
        for e in range(3):
            e3[e] = -e3[e]
    frame_e1(op, e3, e1)
    right_handed(e1, e3, axes)
    if op.knn:
        R = 0.0
        for j in range(count):
            u0 = 0.0
            u1 = 0.0
            for col in range(3):
                d = tg.nodes[3 * cand_i[j] + col] - ref[col]
                u0 += axes[col] * d
                u1 += axes[3 + col] * d
            R = dmax(R, sqrt(u0 * u0 + u1 * u1))
        R = op.knn_factor * R if R > 0 else op.radius[attempt] * h  # no support: any finite R
    res.R = R
    return count


cdef void blank(Result *res) noexcept nogil:
    """NaN out the geometry of a row without a trustworthy answer."""
    res.gap = NAN
    cdef int e
    for e in range(3):
        res.normal[e] = NAN
        res.proximal[e] = NAN
    res.curvature[0] = NAN
    res.curvature[1] = NAN


cdef void solve(const TargetC *tg, const Options *op, const double *x, bint centred,
                int64_t count, Scratch *sc, Result *res, bint frozen) noexcept nogil:
    """Fit and project x with the pairing in res (origin, axes, R, h) and the support
    cand_i[:count]: DiffuseSurface's `_solve` for one contactor. The basis and the weights
    are centred at the contactor's in-plane position [14], [15] (`centred`), as the paper
    does, or at the origin (the previous proximal point, when re-centring). `frozen`: res
    holds the reduced basis and direction of a frozen pairing (res.reduced >= 0: fit that)."""
    cdef int64_t *cand_i = sc.cand_i
    cdef double *s = sc.s
    cdef double *t = sc.t
    cdef double *w = sc.w
    cdef const double *axes = res.axes
    cdef const double *ref = res.origin
    cdef double R = res.R, h = res.h
    cdef double c[3]
    cdef double f[6]
    cdef double st[2]
    cdef double c0, c1, X0, X1, X2, d, q, rc, inv_r, nrm, nu0, nu1, nu2, g, d2min, facing
    cdef double fs, ft, E, F, G, root, L, M, N, det, mean, gauss, disc
    cdef int64_t j, jj, node, kept, positive = 0, its, live = 0
    cdef int e, col, code, why, terms, which = -1
    cdef bint seen, ok
    cdef double direction = NAN, ca, sa
    cdef const double *fn
    if tg.duplicates:  # each position once, as its first occurrence
        kept = 0
        for j in range(count):
            node = tg.first[cand_i[j]]
            seen = False
            for jj in range(kept):
                if cand_i[jj] == node:
                    seen = True
                    break
            if not seen:
                cand_i[kept] = node
                kept += 1
        count = kept
    for e in range(3):
        c[e] = 0.0
        for col in range(3):
            c[e] += axes[3 * e + col] * (x[col] - ref[col])
        c[e] /= R
    c0 = c[0] if centred else 0.0
    c1 = c[1] if centred else 0.0
    # the support nodes inside the domain of influence (q < 1), in support order, are the
    # only ones with a weight [15]: s, t, z, w (and geo) hold them alone, `live` of them, and
    # live_i their nodes; every later loop reads those
    inv_r = 1.0 / R
    # (the frame's axes divided by R, in scalars: read once, where through res they would be
    # reloaded a node)
    cdef double r0 = ref[0], r1 = ref[1], r2 = ref[2], d0, d1, d2
    cdef double a00 = axes[0] * inv_r, a01 = axes[1] * inv_r, a02 = axes[2] * inv_r
    cdef double a10 = axes[3] * inv_r, a11 = axes[4] * inv_r, a12 = axes[5] * inv_r
    cdef double a20 = axes[6] * inv_r, a21 = axes[7] * inv_r, a22 = axes[8] * inv_r
    cdef const double *xn
    for j in range(count):
        node = cand_i[j]
        xn = tg.nodes + 3 * node
        d0 = xn[0] - r0
        d1 = xn[1] - r1
        d2 = xn[2] - r2
        X0 = (a00 * d0 + a01 * d1) + a02 * d2 - c0
        X1 = (a10 * d0 + a11 * d1) + a12 * d2 - c1
        q = X0 * X0 + X1 * X1
        if q >= 1.0:  # outside the domain of influence
            continue
        X2 = (a20 * d0 + a21 * d1) + a22 * d2
        s[live] = X0
        t[live] = X1
        sc.z[live] = X2
        sc.live_i[live] = node
        w[live] = weight_value(op.wp.kind, q, &op.wp)  # [15]
        if op.wp.kind == SINGULAR:
            sc.geo[live] = weight_value(WENDLAND, q, &op.wp)
        if w[live] > 0:
            positive += 1
        live += 1
    rc = fit(op, sc, live)
    terms = op.nterms
    if frozen and res.reduced >= 0:  # the pairing's reduced basis, at its direction
        which = res.reduced
        direction = res.direction
        terms = fit_reduced(op, sc, live, positive, True, &direction, &which)
    elif not (rc >= op.rcond_min) or positive < op.nterms:
        # the support cannot determine the full basis: the terms it can (a strip, a row)
        terms = fit_reduced(op, sc, live, positive, frame_fixed(tg, op, res, cand_i, count),
                            &direction, &which)
    c[0] -= c0
    c[1] -= c1
    its = newton(op, sc.alpha, c, f, st, &ok)
    surface_derivatives(op.nterms, op.ea, op.eb, sc.alpha, st[0], st[1], f)
    # [29]: ν = (-f,1, -f,2, 1)/‖·‖ in the frame (the scaling by R cancels in the slopes)
    nrm = sqrt(f[1] * f[1] + f[2] * f[2] + 1.0)
    nu0 = -f[1] / nrm
    nu1 = -f[2] / nrm
    nu2 = 1.0 / nrm
    g = 0.0
    for col in range(3):
        res.normal[col] = axes[col] * nu0 + axes[3 + col] * nu1 + axes[6 + col] * nu2
        res.proximal[col] = ref[col] + R * (axes[col] * (st[0] + c0)
                                            + axes[3 + col] * (st[1] + c1)
                                            + axes[6 + col] * f[0])
        g += (x[col] - res.proximal[col]) * res.normal[col]
    res.gap = g  # [32]
    code = OPEN if g > 0 else PENETRATION  # [33]
    if fabs(g) <= op.contact_tol * h:
        code = CONTACT
    why = R_OK
    # the proximal point must lie on the target: near a support node, inside the domain of
    # influence, and within hull_spacings of the in-plane convex hull of the support (not past
    # an open edge, where the fit only extrapolates)
    d2min = INFINITY
    if 0 < terms < op.nterms and isfinite(direction):
        # a strip or a row: along it (across, the hull bounds it: elements may be much wider
        # than long)
        ca = cos(direction)
        sa = sin(direction)
        for j in range(live):
            if w[j] > 0:
                d = ca * (s[j] - st[0]) + sa * (t[j] - st[1])
                d2min = dmin(d2min, d * d)
    else:
        for j in range(live):
            if w[j] > 0:
                d2min = dmin(d2min, (s[j] - st[0]) * (s[j] - st[0])
                             + (t[j] - st[1]) * (t[j] - st[1]))
    if (sqrt(d2min) * R > op.outside_spacings * h or st[0] * st[0] + st[1] * st[1] > 1.0
            or beyond_hull(s, t, w, live, st[0], st[1], op.hull_spacings * h / R,
                           sc.arc_start, sc.arc_end)):
        code = OUTSIDE
        why = R_OFF_TARGET
    if not ok:
        code = FAILED
        why = R_NO_CONVERGENCE
    # too few nodes, or nodes that cannot determine the basis (collinear, as past an open edge),
    # nor even a line of it
    if terms == 0:
        if not (rc >= op.rcond_min):
            code = OUTSIDE
            why = R_ILL
        if positive < op.nterms:
            code = OUTSIDE
            why = R_FEW_NODES
    # a support reaching where the target turns vertical or folds over the frame: the root
    # cause of whatever else went wrong
    for j in range(live):
        if w[j] <= 0:
            continue
        node = sc.live_i[j]
        fn = tg.fold_normals + 3 * node
        facing = fn[0] * axes[6] + fn[1] * axes[7] + fn[2] * axes[8]
        if not tg.is_signed[node]:
            facing = fabs(facing)
        if facing < op.cos_fold or tg.steep[node]:
            code = OUTSIDE
            why = R_STEEP
            break
    res.status = <int8_t>code
    res.reason = <int8_t>why
    res.support = positive
    res.iterations = its
    res.rcond = rc
    res.terms = <int8_t>terms
    res.reduced = <int8_t>which
    res.direction = direction if which >= 0 else NAN
    # principal curvatures: eigenvalues of the shape operator I⁻¹ II, divided by R
    fs = f[1]
    ft = f[2]
    E = 1 + fs * fs
    F = fs * ft
    G = 1 + ft * ft
    root = sqrt(1 + fs * fs + ft * ft)
    L = -f[3] / root
    M = -f[4] / root
    N = -f[5] / root
    det = E * G - F * F
    mean = (E * N + G * L - 2 * F * M) / (2 * det)
    gauss = (L * N - M * M) / det
    disc = sqrt(dmax(mean * mean - gauss, 0.0))
    res.curvature[0] = (mean + disc) / R
    res.curvature[1] = (mean - disc) / R
    if code >= OUTSIDE:
        blank(res)
    if op.keep:
        res.count = count
        for j in range(count):
            res.index[j] = tg.perm[cand_i[j]]
        for e in range(op.nterms):  # the fit [17], in the full basis (NaN: none)
            res.alpha[e] = sc.alpha[e]


cdef void select_solve(const TargetC *tg, const Options *op, const double *x,
                       const double *ref, bint centred, int attempt, Scratch *sc,
                       Result *res, double h) noexcept nogil:
    """Support and frame around `ref`, then the fit and projection of x. `h`: the local
    spacing at ref when known (sc.nbar and sc.foot then still hold ref's: the retry), else NaN
    (its nearest nodes' spacing, at least sc.h_min: the size of the facets there, where the
    caller knows it)."""
    cdef int e
    res.overflow = False
    res.count = 0
    res.h = h if not isnan(h) else dmax(local_spacing(tg, op, ref, sc), sc.h_min)
    for e in range(3):
        res.origin[e] = ref[e]
    cdef int64_t count = select_support(tg, op, ref, attempt, sc, res)
    solve(tg, op, x, centred, count, sc, res, False)


cdef inline bint thin_or_off(const Result *res) noexcept nogil:
    return res.reason == R_FEW_NODES or res.reason == R_ILL or res.reason == R_OFF_TARGET


cdef void flag_bad_point(Result *res) noexcept nogil:
    """A contactor with NaN or inf: 'failed' (bad-point), no support, no iterations, no
    condition number, NaN geometry (its pairing is that of a harmless stand-in)."""
    res.status = FAILED
    res.reason = R_BAD_POINT
    res.support = 0
    res.iterations = 0
    res.rcond = NAN
    res.terms = 0
    res.reduced = -1
    res.direction = NAN
    blank(res)


cdef Result *project_one(const TargetC *tg, const Options *op, const double *x,
                         Scratch *sc) noexcept nogil:
    """One contactor, from its support to its status: DiffuseSurface.project's rules."""
    cdef Result *a = &sc.res[0]
    cdef Result *b = &sc.res[1]
    cdef Result *tmp
    cdef bint finite = isfinite(x[0]) and isfinite(x[1]) and isfinite(x[2]), live, stalled
    cdef const double *xs = x if finite else tg.frame_origin
    cdef bint overflow
    cdef int64_t its
    cdef int _it, e
    cdef double move, previous, dd
    select_solve(tg, op, xs, xs, True, 0, sc, a, NAN)
    overflow = a.overflow
    # a support too thin for the basis (an open edge or corner, a coarse mesh), or one so
    # one-sided that the fit carries the proximal point off the target, is tried once more
    # with a wider support; the retry is kept only where it is on the target, and where the
    # first was on the target with a reduced basis, only where it fits the full basis (a wider
    # support with more reduced terms was measured worse than a narrow one: a row's)
    if finite and (thin_or_off(a) or a.terms < op.nterms):
        select_solve(tg, op, xs, xs, True, 1, sc, b, a.h)  # (the same reference point)
        overflow = overflow or b.overflow
        if b.status <= PENETRATION and (a.status > PENETRATION or b.terms == op.nterms):
            tmp = a
            a = b
            b = tmp
    if not finite:
        flag_bad_point(a)
    if op.recentre and a.status <= PENETRATION:
        # re-centre the fit on the proximal point until it stops moving: the fixed point is
        # the projection onto S_g^d itself rather than onto the contactor's own local fit
        its = a.iterations
        live = True
        previous = INFINITY
        for _it in range(op.recentre_max_iter):
            select_solve(tg, op, x, a.proximal, False, 0, sc, b, NAN)
            overflow = overflow or b.overflow
            move = 0.0
            for e in range(3):
                dd = b.proximal[e] - a.proximal[e]
                move += dd * dd
            move = sqrt(move)
            its += b.iterations
            tmp = a
            a = b
            b = tmp
            stalled = move >= 0.5 * previous and move < op.recentre_stall * a.h
            previous = move
            if not (move > op.recentre_step * a.h) or stalled:  # NaN (failed) counts as done
                live = False
                break
        if live:
            a.status = FAILED
            a.reason = R_NOT_SETTLED
            blank(a)
        a.iterations = its
    a.overflow = overflow
    return a


cdef inline void store(const Result *res, Py_ssize_t r, double *gap, double *normal,
                       double *proximal, int8_t *status, int8_t *reason, int64_t *support,
                       int64_t *iterations, double *rcond, double *curvature,
                       int8_t *terms) noexcept nogil:
    """One contactor's Projection fields into row r of the (C-contiguous) outputs of
    `project` and `project_with` (raw pointers: no memoryview reference counting per point)."""
    cdef int e
    gap[r] = res.gap
    for e in range(3):
        normal[3 * r + e] = res.normal[e]
        proximal[3 * r + e] = res.proximal[e]
    status[r] = res.status
    reason[r] = res.reason
    support[r] = res.support
    iterations[r] = res.iterations
    rcond[r] = res.rcond
    curvature[2 * r] = res.curvature[0]
    curvature[2 * r + 1] = res.curvature[1]
    terms[r] = res.terms


cdef struct ProjectOut:
    # the outputs of `Target.project` (C-contiguous), as raw pointers
    double *gap
    double *normal
    double *proximal
    int8_t *status
    int8_t *reason
    int64_t *support
    int64_t *iterations
    double *rcond
    double *curvature
    int8_t *terms
    double *origin
    double *axes
    double *radius
    double *spacing
    double *direction
    int8_t *reduced
    uint8_t *overflow
    int64_t *index               # (m, width): row i gets rows[i]'s support
    int64_t width
    double *alpha                # (points, alpha_width) or NULL
    int64_t alpha_width


cdef inline void project_row(const TargetC *tg, const Options *op, const double *points,
                             int64_t r, Py_ssize_t i, Scratch *sc,
                             const ProjectOut *o) noexcept nogil:
    """`Target.project`'s work for one contactor (row r of the points, i of the batch), the
    same from the serial loop and the parallel one."""
    cdef Result *res = project_one(tg, op, points + 3 * r, sc)
    cdef int e
    cdef int64_t j
    store(res, r, o.gap, o.normal, o.proximal, o.status, o.reason, o.support, o.iterations,
          o.rcond, o.curvature, o.terms)
    for e in range(3):
        o.origin[3 * r + e] = res.origin[e]
    for e in range(9):
        o.axes[9 * r + e] = res.axes[e]
    o.radius[r] = res.R
    o.spacing[r] = res.h
    o.direction[r] = res.direction
    o.reduced[r] = res.reduced
    o.overflow[r] = res.overflow
    if o.width > 0:
        for j in range(o.width):
            o.index[i * o.width + j] = res.index[j] if j < res.count else -1
        if o.alpha != NULL:
            for j in range(op.nterms):
                o.alpha[r * o.alpha_width + j] = (res.alpha[j] if res.status <= PENETRATION
                                                  else NAN)


cdef struct FrozenIn:
    # the frozen pairing of `Target.project_with` (C-contiguous), as raw pointers
    const double *points
    const double *origin
    const double *axes
    const double *radius
    const double *spacing
    const int64_t *index         # (m, K), -1 holes
    int64_t K
    const int8_t *frozen_reduced     # NULL: not frozen
    const double *frozen_direction


cdef inline void project_with_row(const TargetC *tg, const Options *op, Py_ssize_t i,
                                  const FrozenIn *f, Scratch *sc,
                                  const ProjectOut *o) noexcept nogil:
    """`Target.project_with`'s work for contactor i, the same from the serial loop and the
    parallel one."""
    cdef Result *res = &sc.res[0]
    cdef int64_t j, count = 0, node
    cdef int e
    cdef const double *x = f.points + 3 * i
    cdef bint finite
    for j in range(f.K):
        node = f.index[i * f.K + j]
        if node >= 0:
            sc.cand_i[count] = tg.inv[node]
            count = count + 1
    for e in range(3):
        res.origin[e] = f.origin[3 * i + e]
    for e in range(9):
        res.axes[e] = f.axes[9 * i + e]
    res.R = f.radius[i]
    res.h = f.spacing[i]
    finite = isfinite(x[0]) and isfinite(x[1]) and isfinite(x[2])
    if f.frozen_reduced != NULL:
        res.reduced = f.frozen_reduced[i]
        res.direction = f.frozen_direction[i]
    solve(tg, op, x if finite else f.origin + 3 * i, True, count, sc, res,
          f.frozen_reduced != NULL)
    if not finite:
        flag_bad_point(res)
    store(res, i, o.gap, o.normal, o.proximal, o.status, o.reason, o.support, o.iterations,
          o.rcond, o.curvature, o.terms)
    o.direction[i] = res.direction
    o.reduced[i] = res.reduced


cdef class Target:
    """The target as the engine sees it: node arrays and their grids, built once.

    Parameters
    ----------
    nodes, normals, fold_normals : (n, 3) float
    node_spacing : (n,) float
    first : (n,) int       first node at the same position (duplicates merged)
    signed, steep : (n,) bool
    origin : (3,) float, axes : (3, 3) float   the global frame (rows e1, e2, e3)
    has_faces, global_frame : bool
    cell : float           grid cell size
    """

    def __init__(self, nodes, normals, node_spacing, first, fold_normals, is_signed, steep,
                 origin, axes, bint has_faces, bint global_frame, double cell):
        cdef int e
        nodes = np.ascontiguousarray(nodes, dtype=np.float64)
        n = nodes.shape[0]
        if nodes.ndim != 2 or nodes.shape[1] != 3 or n == 0:
            raise ValueError(f"nodes must have shape (n, 3), n > 0, got {nodes.shape}")
        # the nodes renumbered in the order of their grid cells, so that the nodes of a cell,
        # and of neighbouring cells, are neighbours in memory (a search then reads few cache
        # lines); `perm` maps the engine's numbers to the caller's, `inv` back
        lo, grid_cell, dims, start, perm = build_grid(nodes, cell)
        inv = np.empty(n, dtype=np.int64)
        inv[perm] = np.arange(n)
        self.perm = perm
        self.inv = inv
        self.nodes = np.ascontiguousarray(nodes[perm])
        self.normals = _checked(normals, np.float64, (n, 3))[perm]
        self.node_spacing = _checked(node_spacing, np.float64, (n,))[perm]
        self.first = inv[_checked(first, np.int64, (n,))[perm]]
        # a target with facets folds on its own normals (`DiffuseSurface.fold_normals` is
        # its normals): one renumbered copy of them
        self.fold_normals = (self.normals if fold_normals is normals
                             else _checked(fold_normals, np.float64, (n, 3))[perm])
        self.signed_ = _checked(is_signed, np.bool_, (n,)).view(np.uint8)[perm]
        self.steep = _checked(steep, np.bool_, (n,)).view(np.uint8)[perm]
        origin = _checked(origin, np.float64, (3,))
        axes = _checked(axes, np.float64, (3, 3)).ravel()
        # the grid of the renumbered nodes is the one just built, with its nodes in order
        # (their cells' counts the same, a stable sort of sorted cells the identity), where
        # its box does not depend on the nodes' order: no bound is zero (where one is, which
        # of -0.0 and 0.0 `build_grid` keeps may), so it is not built twice (issue 36)
        hi = [nodes[:, e].max() for e in range(3)]
        if all(lo[e] != 0 and hi[e] != 0 for e in range(3)):
            tables = (lo, grid_cell, dims, start, np.arange(n, dtype=np.int64))
        else:
            tables = None
        self.grid = GridArrays(self.nodes, cell, tree=True, tables=tables)
        if global_frame:
            plane = np.zeros((n, 3))
            plane[:, :2] = (np.asarray(self.nodes) - origin) @ axes.reshape(3, 3)[:2].T
            self.plane = GridArrays(plane, cell)
        else:
            self.plane = GridArrays(np.zeros((1, 3)), 1.0)
        self.c.nodes = &self.nodes[0, 0]
        self.c.normals = &self.normals[0, 0]
        self.c.node_spacing = &self.node_spacing[0]
        self.c.first = &self.first[0]
        self.c.fold_normals = &self.fold_normals[0, 0]
        self.c.is_signed = &self.signed_[0]
        self.c.steep = &self.steep[0]
        self.c.perm = &self.perm[0]
        self.c.inv = &self.inv[0]
        self.c.grid = self.grid.grid
        self.c.plane = self.plane.grid
        for e in range(3):
            self.c.frame_origin[e] = origin[e]
        for e in range(9):
            self.c.frame_axes[e] = axes[e]
        self.c.has_faces = has_faces
        self.c.duplicates = bool(np.any(np.asarray(self.first) != np.arange(n)))
        assert np.all(np.asarray(self.grid.order) == np.arange(n))  # already in cell order
        self.c.global_frame = global_frame
        self.c.n = n

    def cell_keys(self, const double[:, ::1] points):
        """Morton (Z-order) key of the grid cell of each point (m,): sorting contactors by it
        makes contactors that follow each other search neighbouring cells, in all three
        directions (fewer cache misses on a large target)."""
        cdef Py_ssize_t i, m = points.shape[0]
        out = np.empty(m, dtype=np.int64)
        cdef int64_t[::1] key = out
        cdef const Grid *g = &self.c.grid
        with nogil:
            for i in range(m):
                key[i] = <int64_t>(
                    spread_bits(<uint64_t>cell_index(points[i, 0], g.lo[0], g.cell, g.dims[0]))
                    | (spread_bits(<uint64_t>cell_index(points[i, 1], g.lo[1], g.cell,
                                                        g.dims[1])) << 1)
                    | (spread_bits(<uint64_t>cell_index(points[i, 2], g.lo[2], g.cell,
                                                        g.dims[2])) << 2))
        return out

    def project(self, dict options, const double[:, ::1] points, const int64_t[::1] rows,
                double[::1] gap, double[:, ::1] normal, double[:, ::1] proximal,
                int8_t[::1] status, int8_t[::1] reason, int64_t[::1] support,
                int64_t[::1] iterations, double[::1] rcond, double[:, ::1] curvature,
                int8_t[::1] terms, double[:, ::1] origin, double[:, :, ::1] axes,
                double[::1] radius, double[::1] spacing, double[::1] direction,
                int8_t[::1] reduced, int64_t[:, ::1] index, uint8_t[::1] overflow,
                int64_t cap, double[:, ::1] alpha=None, int threads=0):
        """Project the contactors points[rows] (select, solve, retry, re-centre, bad points).

        Row rows[i]'s results go to row rows[i] of every output but `index`, whose row i
        receives its support (when index has columns; -1 padded), and row rows[i] of `alpha`
        (m, nterms), when given with `index`, the fit's coefficients [17] in the full basis,
        centred at the contactor in its frame (NaN where it was not answered).
        overflow[rows[i]] is set where a support had more than `cap` nodes (run those rows
        again with a larger cap). `threads`: OpenMP threads of the loop (0: `threads_for`'s;
        1: a plain loop, no parallel region).
        """
        cdef Options op = make_options(options, index.shape[1] > 0)
        cdef Py_ssize_t m = rows.shape[0], i
        cdef int64_t width = index.shape[1]
        cdef bint keep_alpha = alpha is not None and width > 0
        if keep_alpha and (alpha.shape[0] != points.shape[0] or alpha.shape[1] < op.nterms):
            raise ValueError("alpha must have shape (m, nterms)")
        cdef Scratch *sc
        cdef int failed = 0
        cdef int *failedp = &failed
        _check_rows(points, rows, gap, normal, proximal, status, reason, support, iterations,
                    rcond, curvature, terms, origin, axes, radius, spacing, direction, reduced,
                    overflow)
        if index.shape[0] < m and width > 0:
            raise ValueError("index has fewer rows than rows")
        if op.knn and op.k[1] > cap:
            raise ValueError("cap is below k")
        if m == 0:
            return
        cdef ProjectOut o
        o.gap, o.normal, o.proximal = &gap[0], &normal[0, 0], &proximal[0, 0]
        o.status, o.reason, o.support, o.iterations = &status[0], &reason[0], &support[0], \
            &iterations[0]
        o.rcond, o.curvature, o.terms = &rcond[0], &curvature[0, 0], &terms[0]
        o.origin, o.axes, o.radius, o.spacing = &origin[0, 0], &axes[0, 0, 0], &radius[0], \
            &spacing[0]
        o.direction, o.reduced, o.overflow = &direction[0], &reduced[0], &overflow[0]
        o.width = width
        o.index = &index[0, 0] if width > 0 else NULL
        o.alpha = &alpha[0, 0] if keep_alpha else NULL
        o.alpha_width = alpha.shape[1] if keep_alpha else 0
        cdef const double *pts = &points[0, 0]
        cdef const int64_t *rw = &rows[0]
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "project")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                sc = scratch_new(cap, op.nterms, op.spacing_neighbours)
                if sc != NULL:
                    for i in range(m):
                        project_row(&self.c, &op, pts, rw[i], i, sc, &o)
                    scratch_free(sc)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 64)
            with nogil, parallel(num_threads=threads):
                sc = scratch_new(cap, op.nterms, op.spacing_neighbours)
                if sc == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if sc != NULL:
                        project_row(&self.c, &op, pts, rw[i], i, sc, &o)
                scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")

    def project_with(self, dict options, const double[:, ::1] points,
                     const double[:, ::1] origin, const double[:, :, ::1] axes,
                     const double[::1] radius, const double[::1] spacing,
                     const int64_t[:, ::1] index, double[::1] gap, double[:, ::1] normal,
                     double[:, ::1] proximal, int8_t[::1] status, int8_t[::1] reason,
                     int64_t[::1] support, int64_t[::1] iterations, double[::1] rcond,
                     double[:, ::1] curvature, int8_t[::1] terms, double[::1] direction,
                     int8_t[::1] reduced, const int8_t[::1] frozen_reduced=None,
                     const double[::1] frozen_direction=None, int threads=0):
        """Fit and project each contactor with a frozen pairing (origin, axes, R, h, support
        index with -1 holes): the same per-point code as `project` after the selection.
        Contactors with NaN or inf are solved at their origin, then flagged 'failed'. With
        `frozen_reduced` and `frozen_direction` (the pairing's), a row whose pairing fitted a
        reduced basis (>= 0) fits that one at that direction (held fixed, as the frame).
        `threads`: as `project`'s."""
        cdef Options op = make_options(options, False)
        cdef Py_ssize_t m = points.shape[0], i
        cdef int64_t K = index.shape[1]
        cdef Scratch *sc
        cdef int failed = 0
        cdef int *failedp = &failed
        for name, arr, shape in (("origin", origin, (m, 3)), ("radius", radius, (m,)),
                                 ("spacing", spacing, (m,)), ("gap", gap, (m,)),
                                 ("normal", normal, (m, 3)), ("proximal", proximal, (m, 3)),
                                 ("status", status, (m,)), ("reason", reason, (m,)),
                                 ("support", support, (m,)), ("iterations", iterations, (m,)),
                                 ("rcond", rcond, (m,)), ("curvature", curvature, (m, 2)),
                                 ("terms", terms, (m,)), ("direction", direction, (m,)),
                                 ("reduced", reduced, (m,))):
            if tuple(arr.shape[:len(shape)]) != shape:
                raise ValueError(f"{name} must have shape {shape}")
        if points.shape[1] != 3 or axes.shape[0] != m or axes.shape[1] != 3 or axes.shape[2] != 3 \
                or index.shape[0] != m:
            raise ValueError("points, axes and index must have m rows")
        if m == 0:
            return
        if K and np.asarray(index).max() >= self.c.n:
            raise ValueError("a support index past the target's nodes")
        cdef bint freeze = frozen_reduced is not None and frozen_direction is not None
        if freeze and (frozen_reduced.shape[0] != m or frozen_direction.shape[0] != m):
            raise ValueError("frozen_reduced and frozen_direction must have m rows")
        cdef FrozenIn f
        f.points, f.origin, f.axes = &points[0, 0], &origin[0, 0], &axes[0, 0, 0]
        f.radius, f.spacing = &radius[0], &spacing[0]
        f.index = &index[0, 0] if K > 0 else NULL
        f.K = K
        f.frozen_reduced = &frozen_reduced[0] if freeze else NULL
        f.frozen_direction = &frozen_direction[0] if freeze else NULL
        cdef ProjectOut o
        o.gap, o.normal, o.proximal = &gap[0], &normal[0, 0], &proximal[0, 0]
        o.status, o.reason, o.support, o.iterations = &status[0], &reason[0], &support[0], \
            &iterations[0]
        o.rcond, o.curvature, o.terms = &rcond[0], &curvature[0, 0], &terms[0]
        o.direction, o.reduced = &direction[0], &reduced[0]
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "project_with")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                sc = scratch_new(imax(K, 1), op.nterms, op.spacing_neighbours)
                if sc != NULL:
                    for i in range(m):
                        project_with_row(&self.c, &op, i, &f, sc, &o)
                    scratch_free(sc)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 64)
            with nogil, parallel(num_threads=threads):
                sc = scratch_new(imax(K, 1), op.nterms, op.spacing_neighbours)
                if sc == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if sc != NULL:
                        project_with_row(&self.c, &op, i, &f, sc, &o)
                scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")


def _checked(a, dtype, shape):
    arr = np.ascontiguousarray(a, dtype=dtype)
    if arr.shape != tuple(shape):
        raise ValueError(f"an array of shape {arr.shape}, expected {tuple(shape)}")
    return arr


def _check_rows(points, rows, *outputs):
    m = points.shape[0]
    if points.shape[1] != 3:
        raise ValueError("points must have shape (m, 3)")
    for out in outputs:
        if out.shape[0] != m:
            raise ValueError(f"an output of shape {tuple(out.shape)}: expected {m} rows")
    r = np.asarray(rows)
    if len(r) and (r.min() < 0 or r.max() >= m):
        raise ValueError("rows index past the points")


cdef Options make_options(dict o, bint keep) except *:
    """The options of one call: the surface's settings (`o`) and diffsurf_cli.tol."""
    cdef Options op
    cdef int j
    exps = _basis.EXPONENTS[o["basis"]]
    op.nterms = len(exps)
    for j in range(op.nterms):
        op.ea[j] = exps[j][0]
        op.eb[j] = exps[j][1]
    reduced = _basis.REDUCED[o["basis"]]
    op.nreduced = len(reduced)
    assert op.nreduced <= NREDUCED_MAX
    quadratic = tuple(_basis.EXPONENTS["quadratic"])
    # `basis_rows` writes a basis of 6 terms as the quadratic
    assert all(tuple(e) == quadratic for e in [exps, *reduced] if len(e) == 6)
    for r, exps in enumerate(reduced):
        op.rsize[r] = len(exps)
        op.across[r] = any(b > 0 for _, b in exps)
        op.plane_only[r] = _basis.complete(exps)
        for j in range(len(exps)):
            op.ra[NTERMS_MAX * r + j] = exps[j][0]
            op.rb[NTERMS_MAX * r + j] = exps[j][1]
    op.wp.kind = WEIGHT_CODES[o["weight"]]
    op.knn = o["support"] == "knn"
    n = o["nodes"]
    op.k[0] = min(int(o["k"]), n)
    op.k[1] = min(int(np.ceil(o["k"] * tol.ENLARGE**2)), n)
    op.radius[0] = o["radius"]
    op.radius[1] = o["radius"] * tol.ENLARGE
    op.spacing_neighbours = min(tol.SPACING_NEIGHBOURS + 1, n)
    op.frame_ball = tol.FRAME_BALL
    op.knn_factor = tol.KNN_RADIUS_FACTOR
    op.sheet_cos = np.cos(np.radians(tol.SHEET_ANGLE_DEG))
    op.cos_fold = np.cos(np.radians(tol.FOLD_SLOPE_DEG))
    op.rcond_min = tol.RCOND_MIN[o["basis"]]
    op.ruled_global = o["ruled"]
    op.ruled_spread = tol.RULED_SPREAD
    op.row_variance = tol.ROW_VARIANCE
    op.strip_rank = tol.STRIP_RANK
    op.contact_tol = tol.CONTACT
    op.outside_spacings = o["outside_spacings"]
    op.hull_spacings = tol.HULL_SPACINGS
    op.wp.gauss_c2 = tol.GAUSS_WIDTH**2
    op.wp.gauss_tail = np.exp(-1.0 / tol.GAUSS_WIDTH**2)
    op.wp.singular_floor = tol.SINGULAR_FLOOR
    op.equilibration_floor = tol.EQUILIBRATION_FLOOR
    op.newton_step = tol.NEWTON_STEP
    op.newton_max_iter = tol.NEWTON_MAX_ITER
    for j in range(3):
        op.e1_guide[j] = tol.E1_GUIDE[j]
        op.e1_guide_alt[j] = tol.E1_GUIDE_ALT[j]
    op.recentre = o["recentre"]
    op.recentre_max_iter = tol.RECENTRE_MAX_ITER
    op.recentre_step = tol.RECENTRE_STEP
    op.recentre_stall = tol.RECENTRE_STALL
    op.keep = keep
    return op
