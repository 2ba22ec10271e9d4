# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The larger routines of `_linalg.pxd` (eigenvectors, Jacobi SVD, the triangular rcond),
compiled once and called by the modules that cimport them."""
from libc.math cimport sqrt, fabs, INFINITY


cdef void smallest_eigenvector(const double *c, double *out) noexcept nogil:
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 `c` (cyclic Jacobi,
    Golub & Van Loan §8.5)."""
    cdef double a[9]
    cdef double v[9]
    cdef int P[3]
    cdef int Q[3]
    P[0] = 0
    P[1] = 0
    P[2] = 1
    Q[0] = 1
    Q[1] = 2
    Q[2] = 2
    cdef int _sweep, pq, p, q, k, i, j
    cdef double off, scale, theta, t, cs, sn, x, y
    for i in range(9):
        a[i] = c[i]
        v[i] = 0.0
    v[0] = 1.0
    v[4] = 1.0
    v[8] = 1.0
    for _sweep in range(50):
        off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5]
        scale = a[0] * a[0] + a[4] * a[4] + a[8] * a[8]
        if off <= EIG3_OFF * scale or off == 0.0:
            break
        for pq in range(3):
            p = P[pq]
            q = Q[pq]
            if a[3 * p + q] == 0.0:
                continue
            theta = (a[3 * q + q] - a[3 * p + p]) / (2.0 * a[3 * p + q])
            t = (1.0 if theta >= 0 else -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0))
            cs = 1.0 / sqrt(t * t + 1.0)
            sn = t * cs
            for k in range(3):  # a <- Jᵀ a J
                x = a[3 * k + p]
                y = a[3 * k + q]
                a[3 * k + p] = cs * x - sn * y
                a[3 * k + q] = sn * x + cs * y
            for k in range(3):
                x = a[3 * p + k]
                y = a[3 * q + k]
                a[3 * p + k] = cs * x - sn * y
                a[3 * q + k] = sn * x + cs * y
            for k in range(3):
                x = v[3 * k + p]
                y = v[3 * k + q]
                v[3 * k + p] = cs * x - sn * y
                v[3 * k + q] = sn * x + cs * y
    j = 0
    for i in range(1, 3):
        if a[3 * i + i] < a[3 * j + j]:
            j = i
    for k in range(3):
        out[k] = v[3 * k + j]


cdef bint smallest_eigenvector_psd(const double *c, double *out) noexcept nogil:
    """Unit eigenvector of the smallest eigenvalue of the symmetric positive semi-definite
    3x3 `c` (a covariance), when it is well separated; returns False (out untouched) when it
    is not, or when c has rank < 2.

    The adjugate of c has c's eigenvectors, the smallest eigenvalue λ1 of c going with its
    largest, λ2λ3, and the next with λ1λ3: squaring it (normalised to unit trace) raises the
    ratio λ1/λ2 to the power 2, 4, 8..., until the other eigenvalues are below
    ADJUGATE_REST (1e-13) of the largest (then once more: 1e-26), and any column is the
    eigenvector; a few dozen flops a step where the cyclic Jacobi takes several sweeps.
    Stops, False, after 8 squarings
    (λ1/λ2 above ~0.9: the plane of the nodes is ill-defined; `smallest_eigenvector`
    decides)."""
    cdef double a00 = c[4] * c[8] - c[5] * c[5], a01 = c[2] * c[5] - c[1] * c[8]
    cdef double a02 = c[1] * c[5] - c[2] * c[4], a11 = c[0] * c[8] - c[2] * c[2]
    cdef double a12 = c[1] * c[2] - c[0] * c[5], a22 = c[0] * c[4] - c[1] * c[1]
    cdef double b00, b01, b02, b11, b12, b22, tr, f, rest, norm
    cdef double tc = c[0] + c[4] + c[8]
    cdef int _it
    cdef bint done = False
    tr = a00 + a11 + a22
    if not (tr > ADJUGATE_RANK * tc * tc):  # rank < 2 (or NaN)
        return False
    for _it in range(8):
        f = 1.0 / tr
        a00 *= f
        a01 *= f
        a02 *= f
        a11 *= f
        a12 *= f
        a22 *= f
        b00 = a00 * a00 + a01 * a01 + a02 * a02
        b01 = a00 * a01 + a01 * a11 + a02 * a12
        b02 = a00 * a02 + a01 * a12 + a02 * a22
        b11 = a01 * a01 + a11 * a11 + a12 * a12
        b12 = a01 * a02 + a11 * a12 + a12 * a22
        b22 = a02 * a02 + a12 * a12 + a22 * a22
        a00 = b00
        a01 = b01
        a02 = b02
        a11 = b11
        a12 = b12
        a22 = b22
        tr = a00 + a11 + a22
        if done:
            break
        # 1 - ‖A‖²/tr(A)² = 2 Σ_{i<j} μiμj / tr²: twice the second eigenvalue's share
        rest = 1.0 - (a00 * a00 + a11 * a11 + a22 * a22
                      + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / (tr * tr)
        done = rest < ADJUGATE_REST
    if not done:
        return False
    # the column of the largest diagonal entry
    if a00 >= a11 and a00 >= a22:
        out[0] = a00
        out[1] = a01
        out[2] = a02
    elif a11 >= a22:
        out[0] = a01
        out[1] = a11
        out[2] = a12
    else:
        out[0] = a02
        out[1] = a12
        out[2] = a22
    norm = sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    out[0] /= norm
    out[1] /= norm
    out[2] /= norm
    return True


cdef void jacobi(double *r, int n, double *v, double tol, double *norms) noexcept nogil:
    """`jacobi_n` (its one copy for any n)."""
    jacobi_n(r, n, v, tol, norms)


cdef inline void jacobi_n(double *r, const int n, double *v, double tol,
                          double *norms) noexcept nogil:
    """One-sided Jacobi (Hestenes; Golub & Van Loan §8.6.4) on the n x n matrix r (destroyed):
    columns rotated pairwise until orthogonal to `tol` (relative), their squared norms kept in
    norms (n); the rotations accumulated in v (n x n, set to the identity first) unless NULL."""
    cdef int i, j, k, _sweep
    cdef bint rotated
    cdef double acc, al, be, ga, zeta, t, cs, sn, x, y
    for i in range(n):
        if v != NULL:
            for j in range(n):
                v[i * n + j] = 1.0 if i == j else 0.0
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        norms[i] = acc
    for _sweep in range(60):
        rotated = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                al = norms[i]
                be = norms[j]
                ga = 0.0
                for k in range(n):
                    ga += r[k * n + i] * r[k * n + j]
                if ga == 0.0 or fabs(ga) <= tol * sqrt(al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = (1.0 if zeta >= 0 else -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta))
                cs = 1.0 / sqrt(1.0 + t * t)
                sn = cs * t
                for k in range(n):
                    x = r[k * n + i]
                    y = r[k * n + j]
                    r[k * n + i] = cs * x - sn * y
                    r[k * n + j] = sn * x + cs * y
                    if v != NULL:
                        x = v[k * n + i]
                        y = v[k * n + j]
                        v[k * n + i] = cs * x - sn * y
                        v[k * n + j] = sn * x + cs * y
                norms[i] = al - t * ga
                norms[j] = be + t * ga
        if not rotated:
            break


cdef void singular_values(double *r, int n, double *sig) noexcept nogil:
    """Singular values of the n x n matrix r (destroyed) by one-sided `jacobi` to SIGMA_TOL
    (relative), then the columns' norms (accurate far beyond that: the error is second order)."""
    cdef int i, k
    cdef double acc
    jacobi(r, n, NULL, SIGMA_TOL, sig)
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        sig[i] = sqrt(acc)


cdef void smallest_right_vector(double *r, int n, double *v, double *out) noexcept nogil:
    """The right singular vector of the least singular value of the n x n r (destroyed) into
    out: one-sided `jacobi` to VECTOR_TOL, its rotations accumulated in v (n x n)."""
    cdef int i, k, low = 0
    cdef double acc, best = INFINITY
    cdef double norms[NTERMS_MAX]
    if n == 6:  # the quadratic's: n a constant here, the loops unrolled (the same operations)
        jacobi_n(r, 6, v, VECTOR_TOL, norms)
    else:
        jacobi_n(r, n, v, VECTOR_TOL, norms)
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        if acc < best:
            best = acc
            low = i
    for k in range(n):
        out[k] = v[k * n + low]


cdef double triangular_rcond(const double *r, int n, double *work, double *sig,
                             double rcond_min) noexcept nogil:
    """The reciprocal condition number of the n x n upper triangular r (row stride n), as
    `Projection.rcond` documents it.

    rcond_F = 1 / (‖R‖_F ‖R⁻¹‖_F) satisfies rcond_F ≤ σmin/σmax ≤ n rcond_F (each Frobenius
    norm is within √n of the matching 2-norm), and costs ~n³/6 flops for R⁻¹. It decides
    alone when rcond_F ≥ rcond_min (accepted) or n rcond_F < rcond_min (refused); between
    the two the exact σmin/σmax (one-sided Jacobi) decides and is returned. So the value
    returned is ≥ rcond_min exactly when σmin/σmax is.
    """
    cdef int i, j
    cdef double rc = frobenius_rcond(r, n, work), top, low
    if rc >= rcond_min or n * rc < rcond_min:
        return rc
    for i in range(n):
        for j in range(n):
            work[i * n + j] = r[i * n + j] if j >= i else 0.0
    singular_values(work, n, sig)
    top = 0.0
    low = INFINITY
    for i in range(n):
        top = dmax(top, sig[i])
        low = dmin(low, sig[i])
    return low / top if top > 0 else 0.0


cdef bint cholesky(double *g, int n, double *d) noexcept nogil:
    """R of the symmetric positive definite g = RᵀR (upper triangle, row stride n) in place,
    1/R_ii into d; False unless g is positive definite (Golub & Van Loan §4.2)."""
    cdef double one[NTERMS_MAX]
    cdef double unused[NTERMS_MAX]
    cdef int i
    for i in range(n):
        one[i] = 1.0
        unused[i] = 0.0
    for i in range(n):
        if not cholesky_row(g, n, i, one, d, unused):
            return False
    return True
