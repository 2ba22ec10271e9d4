# cython: language_level=3
"""Small dense linear algebra, written once for every compiled module (`cdef inline`: each
module that cimports it compiles its own copy, inlined where the compiler sees fit).

Textbook algorithms (Golub & Van Loan): Householder QR (§5.2) with its rows written out per
step, Cholesky (§4.2) row by row, cyclic (§8.5) and one-sided (§8.6.4) Jacobi, the 3x3
covariance's smallest eigenvector by powers of its adjugate, the reciprocal condition number
of a triangular factor, Gaussian elimination with partial pivoting (§3.4).
"""
from libc.math cimport sqrt, fabs, INFINITY, isfinite
from libc.stdint cimport int64_t

cdef extern from *:
    """
    #if defined(__GNUC__)
    #define ds_likely(x) __builtin_expect(!!(x), 1)
    #else
    #define ds_likely(x) (x)
    #endif
    """
    # a branch hint: the condition is expected true (the compiler lays out and inlines for it)
    bint likely "ds_likely"(bint) noexcept nogil

cdef enum:
    NTERMS_MAX = 10              # the largest basis (cubic): the largest least-squares system

# The linear algebra's own convergence thresholds (relative, near round-off: not the method's
# tolerances, which diffsurf_cli.tol holds).
cdef extern from *:
    """
    #define DS_EIG3_OFF 1e-36
    #define DS_ADJUGATE_RANK 1e-12
    #define DS_ADJUGATE_REST 1e-13
    #define DS_SIGMA_TOL 1e-9
    #define DS_VECTOR_TOL 1e-12
    """
    # cyclic Jacobi of a 3x3: converged when the off-diagonal's squares are below this share
    # of the diagonal's (off-diagonal entries ~1e-18 of the diagonal: round-off)
    const double EIG3_OFF "DS_EIG3_OFF"
    # a 3x3 covariance has rank < 2 when its adjugate's trace is below this share of tr(C)²
    const double ADJUGATE_RANK "DS_ADJUGATE_RANK"
    # powers of the adjugate: stop once the other eigenvalues' share is below this
    const double ADJUGATE_REST "DS_ADJUGATE_REST"
    # one-sided Jacobi: relative accuracy of the singular values (for rcond near rcond_min)
    const double SIGMA_TOL "DS_SIGMA_TOL"
    # ... and of the least singular vector (the strip direction)
    const double VECTOR_TOL "DS_VECTOR_TOL"


cdef inline double dmin(double a, double b) noexcept nogil:
    return b if b < a else a


cdef inline double dmax(double a, double b) noexcept nogil:
    return b if b > a else a


cdef inline int64_t imin(int64_t a, int64_t b) noexcept nogil:
    return b if b < a else a


cdef inline int64_t imax(int64_t a, int64_t b) noexcept nogil:
    return b if b > a else a


cdef inline double ipow(double x, int n) noexcept nogil:
    cdef double out = 1.0
    cdef int _i
    for _i in range(n):
        out *= x
    return out


cdef inline double binomial(int n, int k) noexcept nogil:
    cdef double out = 1.0
    cdef int m
    for m in range(k):
        out = out * (n - m) / (m + 1)
    return out


cdef inline int row_stride(int n) noexcept nogil:
    """Row stride of the least-squares matrix [P | z] with n basis terms: n + 1 columns
    rounded up to an even number (whole 16-byte pairs: the row updates vectorise)."""
    return n + 2 if n % 2 == 0 else n + 1


cdef inline void column_scales(double *scale, int n, double floor) noexcept nogil:
    """The equilibration of the weighted design matrix: scale holds its columns' squared norms
    on entry, their norms on return, floored at `floor` x the largest (a column of round-off,
    as a support on a line gives, must stay negligible) and 1 where all are zero."""
    cdef int j
    cdef double top = 0.0
    for j in range(n):
        scale[j] = sqrt(scale[j])
        top = dmax(top, scale[j])
    for j in range(n):
        scale[j] = dmax(scale[j], floor * top)
        if not (scale[j] > 0):
            scale[j] = 1.0


cdef inline double inverse_column(const double *r, int n, int j, const double *d,
                                  double *work, double *fro) noexcept nogil:
    """Column j of R⁻¹ into work (R: the n x n upper triangular r, row stride n; d: the
    reciprocals of its diagonal) by back substitution; returns its squared norm and adds that
    of R's column j to fro. Inlined with n and j constants: the loops unroll."""
    cdef int i, k
    cdef double acc, sq
    sq = 0.0
    for i in range(j + 1):
        sq += r[i * n + j] * r[i * n + j]
    fro[0] += sq
    work[j * n + j] = d[j]
    sq = d[j] * d[j]
    for i in range(j - 1, -1, -1):
        acc = 0.0
        for k in range(i + 1, j + 1):
            acc += r[i * n + k] * work[k * n + j]
        work[i * n + j] = -acc * d[i]
        sq += work[i * n + j] * work[i * n + j]
    return sq


cdef inline double frobenius_rcond(const double *r, int n, double *work) noexcept nogil:
    """rcond_F = 1 / (‖R‖_F ‖R⁻¹‖_F) of the n x n upper triangular r (row stride n), R⁻¹
    into work (upper triangular); 0 where r is singular or R⁻¹ overflows. Inlined with n a
    constant; the quadratic and linear bases' columns written out."""
    cdef int j
    cdef double fro = 0.0, inv_fro = 0.0, rc
    cdef double d[NTERMS_MAX]
    for j in range(n):
        if not (r[j * n + j] != 0.0):
            return 0.0
        d[j] = 1.0 / r[j * n + j]
    if n == 6:
        inv_fro = (inverse_column(r, 6, 0, d, work, &fro)
                   + inverse_column(r, 6, 1, d, work, &fro)
                   + inverse_column(r, 6, 2, d, work, &fro)
                   + inverse_column(r, 6, 3, d, work, &fro)
                   + inverse_column(r, 6, 4, d, work, &fro)
                   + inverse_column(r, 6, 5, d, work, &fro))
    elif n == 3:
        inv_fro = (inverse_column(r, 3, 0, d, work, &fro)
                   + inverse_column(r, 3, 1, d, work, &fro)
                   + inverse_column(r, 3, 2, d, work, &fro))
    else:
        for j in range(n):
            inv_fro += inverse_column(r, n, j, d, work, &fro)
    rc = 1.0 / sqrt(fro * inv_fro)
    return rc if rc > 0.0 else 0.0  # (R⁻¹ overflowed)


cdef inline bint reflect(double *a, int64_t m, int n, int j, double *nxt,
                         bint have) noexcept nogil:
    """Step j of `householder_qr`: the reflection that zeroes column j below the diagonal,
    applied to columns j+1..n (n: the z column). `nxt` holds the squared norm of column j
    below row j-1 when `have`; returns whether it then holds column j+1's.

    The rows are read twice: once for the products of v with the later columns, once to
    update them and to sum the squares of column j+1 (the next step's norm). Each sum runs
    over the rows in order, as the textbook loops do. Inlined with n and j constants: the
    loops over the columns unroll."""
    cdef int c, ld = row_stride(n)
    cdef int64_t i
    cdef double norm, ajj, alpha, v0, vtv, vi, acc
    cdef double dot[NTERMS_MAX + 1]
    cdef double *row
    if have:
        norm = nxt[0]
    else:
        norm = 0.0
        for i in range(j, m):
            norm += a[i * ld + j] * a[i * ld + j]
    norm = sqrt(norm)
    if norm == 0.0:
        return False
    ajj = a[j * ld + j]
    alpha = -norm if ajj >= 0 else norm
    v0 = ajj - alpha
    # v = (v0, a[j+1:, j]); H = I - 2 v vᵀ / vᵀv
    vtv = v0 * v0 + (norm * norm - ajj * ajj)
    if vtv <= 0.0:
        return False
    a[j * ld + j] = v0
    for c in range(j + 1, n + 1):
        dot[c] = 0.0
    for i in range(j, m):
        row = a + i * ld
        vi = row[j]
        for c in range(j + 1, n + 1):
            dot[c] += vi * row[c]
    vtv = 2.0 / vtv
    for c in range(j + 1, n + 1):
        dot[c] *= vtv
    row = a + j * ld
    for c in range(j + 1, n + 1):
        row[c] -= dot[c] * v0
    acc = 0.0
    for i in range(j + 1, m):
        row = a + i * ld
        vi = row[j]
        for c in range(j + 1, n + 1):
            row[c] -= dot[c] * vi
        if j + 1 < n:
            acc += row[j + 1] * row[j + 1]
    a[j * ld + j] = alpha
    nxt[0] = acc
    return j + 1 < n


cdef inline void householder_qr(double *a, int64_t m, int n, const double *scale,
                                double *rfac) noexcept nogil:
    """Householder QR of the m x n basis block of `a` (row stride `row_stride(n)`, m >= n,
    in place; Golub & Van Loan §5.2), applied to the z column too; R with its columns
    divided by `scale` (R of the equilibrated matrix) into rfac (n x n).
    Inlined with n a constant; the steps of the linear and quadratic bases are written out
    (each with its own constant j)."""
    cdef int j, c, ld = row_stride(n)
    cdef int64_t i
    cdef double nxt = 0.0
    cdef bint have = False
    if n == 6:
        have = reflect(a, m, 6, 0, &nxt, have)
        have = reflect(a, m, 6, 1, &nxt, have)
        have = reflect(a, m, 6, 2, &nxt, have)
        have = reflect(a, m, 6, 3, &nxt, have)
        have = reflect(a, m, 6, 4, &nxt, have)
        have = reflect(a, m, 6, 5, &nxt, have)
    elif n == 3:
        have = reflect(a, m, 3, 0, &nxt, have)
        have = reflect(a, m, 3, 1, &nxt, have)
        have = reflect(a, m, 3, 2, &nxt, have)
    else:
        for j in range(n):
            have = reflect(a, m, n, j, &nxt, have)
    for i in range(n):
        for c in range(n):
            rfac[i * n + c] = a[i * ld + c] / scale[c] if c >= i else 0.0


cdef inline bint cholesky_row(double *g, int n, int i, const double *inv, double *d,
                              double *b) noexcept nogil:
    """Row i of R (Cholesky, Golub & Van Loan §4.2) in place of the Gram g's upper triangle,
    equilibrated on the fly (inv: 1/scale), rows < i already done; 1/R_ii into d[i]; and
    u_i of Rᵀu = D⁻¹b in place of b_i. False where the pivot is not positive. Inlined with
    n and i constants: the loops unroll."""
    cdef int j, k
    cdef double acc = g[i * n + i] * (inv[i] * inv[i]), piv
    for k in range(i):
        acc -= g[k * n + i] * g[k * n + i]
    if not (acc > 0.0):
        return False
    piv = sqrt(acc)
    g[i * n + i] = piv
    d[i] = 1.0 / piv
    for j in range(i + 1, n):
        acc = g[i * n + j] * (inv[i] * inv[j])
        for k in range(i):
            acc -= g[k * n + i] * g[k * n + j]
        g[i * n + j] = acc * d[i]
    acc = b[i] * inv[i]
    for k in range(i):
        acc -= g[k * n + i] * b[k]
    b[i] = acc * d[i]
    return True


cdef inline void forward_row(const double *r, int n, int i, const double *d, double *b,
                             double scale) noexcept nogil:
    """u_i of Rᵀu = scale b in place of b_i, rows < i already done (R upper triangular, row
    stride n; d: 1/R_ii)."""
    cdef int k
    cdef double acc = b[i] * scale
    for k in range(i):
        acc -= r[k * n + i] * b[k]
    b[i] = acc * d[i]


cdef inline void back_row(const double *r, int n, int i, const double *d,
                          double *b) noexcept nogil:
    """y_i of R y = u in place of u_i (b), rows > i already done (d: 1/R_ii). Inlined with n
    and i constants."""
    cdef int k
    cdef double acc = b[i]
    for k in range(i + 1, n):
        acc -= r[i * n + k] * b[k]
    b[i] = acc * d[i]


cdef inline void cholesky_solve(const double *r, int n, const double *d,
                                double *x) noexcept nogil:
    """x ← (RᵀR)⁻¹ x with R from `cholesky`."""
    cdef int i
    for i in range(n):
        forward_row(r, n, i, d, x, 1.0)
    for i in range(n - 1, -1, -1):
        back_row(r, n, i, d, x)


cdef inline double dot(const double *a, const double *b, int k) noexcept nogil:
    cdef double acc = 0.0
    cdef int j
    for j in range(k):
        acc += a[j] * b[j]
    return acc


cdef inline bint solve4(double *J, double *F) noexcept nogil:
    """J z = F in place for a 4 x 4 J (F becomes z), Gaussian elimination with partial
    pivoting (Golub & Van Loan §3.4); False where J is singular or z is not finite."""
    cdef int i, k, p, c
    cdef double big, t, piv
    for k in range(4):
        p = k
        big = fabs(J[4 * k + k])
        for i in range(k + 1, 4):
            if fabs(J[4 * i + k]) > big:
                big = fabs(J[4 * i + k])
                p = i
        if not big > 0.0:
            return False
        if p != k:
            for c in range(4):
                t = J[4 * k + c]
                J[4 * k + c] = J[4 * p + c]
                J[4 * p + c] = t
            t = F[k]
            F[k] = F[p]
            F[p] = t
        piv = J[4 * k + k]
        for i in range(k + 1, 4):
            t = J[4 * i + k] / piv
            for c in range(k, 4):
                J[4 * i + c] -= t * J[4 * k + c]
            F[i] -= t * F[k]
    for k in range(3, -1, -1):
        t = F[k]
        for c in range(k + 1, 4):
            t -= J[4 * k + c] * F[c]
        F[k] = t / J[4 * k + k]
    return isfinite(F[0]) and isfinite(F[1]) and isfinite(F[2]) and isfinite(F[3])


# defined in `_linalg.pyx` (called, not inlined: each is large and off the hot path)
cdef bint cholesky(double *g, int n, double *d) noexcept nogil
cdef void smallest_eigenvector(const double *c, double *out) noexcept nogil
cdef bint smallest_eigenvector_psd(const double *c, double *out) noexcept nogil
cdef void jacobi(double *r, int n, double *v, double tol, double *norms) noexcept nogil
cdef void singular_values(double *r, int n, double *sig) noexcept nogil
cdef void smallest_right_vector(double *r, int n, double *v, double *out) noexcept nogil
cdef double triangular_rcond(const double *r, int n, double *work, double *sig,
                             double rcond_min) noexcept nogil
