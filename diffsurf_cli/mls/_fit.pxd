# cython: language_level=3
"""The fit [16]-[17] of one support, written once (`cdef inline`, the projection's step
between the support and Newton): the weighted rows or the normal equations of the basis
(mls/basis.py) in the support's (s, t), the fit by Cholesky where it is well conditioned
(`normal_fit`) else Householder QR, and where the support cannot determine the full basis (a
strip two nodes wide, a row of nodes) the reduced bases (`fit_reduced`). Its data are the
projection's `Options` and `Scratch` (`_projection.pxd`); the linear algebra is
`_linalg.pxd`'s."""
from libc.math cimport sqrt, fabs, atan2, isfinite, cos, sin, INFINITY, NAN, M_PI
from libc.stdint cimport int64_t

from ._linalg cimport (NTERMS_MAX, likely, dmax, ipow, binomial, row_stride, column_scales,
                       smallest_right_vector, frobenius_rcond, triangular_rcond,
                       householder_qr, cholesky_row, back_row)
from ._weight cimport SINGULAR
from ._projection cimport Options, Scratch


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


cdef inline double fit(const Options *op, Scratch *sc, int64_t count) noexcept nogil:
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


cdef inline void rotate_back(const Options *op, int r, const double *beta, double c, double sn,
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


cdef inline bint strip_direction(const Options *op, Scratch *sc, int64_t count, const double *pw,
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


cdef inline bint fit_one(const Options *op, Scratch *sc, int64_t count, int r, const double *ua,
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


cdef inline int fit_reduced(const Options *op, Scratch *sc, int64_t count, int64_t positive,
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
