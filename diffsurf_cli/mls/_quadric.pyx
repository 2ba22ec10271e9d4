# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The quadric method's projection (`mls.quadric`) in compiled code: per contactor, the
support of the centre (the grid's k nearest nodes, `_search.knn`), the fit of the quadric to
positions and normals, its closest point (Newton), and the re-centring until the centre
settles, in parallel over contactors (OpenMP `prange`, per-thread scratch allocated once).

It is `mls.quadric`'s numpy steps written once more per contactor, in the same order:
`centre_spacing`, `QuadricSurface.support`, `fit`, `closest_point`, `answer` and the statuses
of `QuadricSurface._answer`; tests/test_quadric.py checks it against the numpy re-centring
(tests/reference_quadric.py) to round-off. The frozen pairing it returns is what the element
(`element.quadric`, numpy) and `project_with` fit again.
"""
import numpy as np

from libc.math cimport sqrt, fabs, NAN, INFINITY, isfinite, cos, M_PI
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t, int8_t
from cython.parallel cimport prange, parallel

from .. import tol
from .._codes cimport (OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED, R_OK, R_FEW_NODES, R_ILL,
                       R_OFF_TARGET, R_NO_CONVERGENCE, R_NOT_SETTLED)
from ..threads import chunk_size, threads_for
from ._linalg cimport solve4
from ._search cimport Grid, GridArrays, knn

cdef enum:
    NT = 10          # the quadric's terms
    GROW = 8         # the search widens this many times where the radius reaches past it


cdef struct Params:
    double radius, beta, ridge, settle, newton_tol, off, contact, sheet_lo, sheet_hi
    int64_t k_search, min_nodes, few, max_centres, max_newton, n_distinct


cdef struct Data:
    const double *nodes       # (n, 3) by node id
    const int64_t *distinct   # (d,) node id of each of the grid's points (the distinct nodes)
    const double *normals     # (n, 3) by node id
    const double *spacing     # (n,) by node id


cdef struct Scratch:
    int64_t *idx      # (cap,): the search's
    double *d2        # (cap,)
    int64_t cap


cdef Scratch *scratch_new(int64_t cap) noexcept nogil:
    cdef Scratch *sc = <Scratch *> malloc(sizeof(Scratch))
    if sc == NULL:
        return NULL
    sc.cap = cap
    sc.idx = <int64_t *> malloc(cap * sizeof(int64_t))
    sc.d2 = <double *> malloc(cap * sizeof(double))
    if sc.idx == NULL or sc.d2 == NULL:
        free(sc.idx)
        free(sc.d2)
        free(sc)
        return NULL
    return sc


cdef void scratch_free(Scratch *sc) noexcept nogil:
    if sc != NULL:
        free(sc.idx)
        free(sc.d2)
        free(sc)


cdef struct Out:
    double *gap
    double *normal
    double *prox
    double *curv
    double *rcond
    int8_t *status
    int8_t *reason
    int64_t *support
    int64_t *iterations
    int8_t *terms
    double *origin
    double *e3
    double *radius
    double *h
    int64_t *index
    int64_t width


cdef inline double wendland(double r) noexcept nogil:
    if r >= 1.0:
        return 0.0
    cdef double s = 1.0 - r
    return s * s * s * s * (4.0 * r + 1.0)


cdef inline double taper(double c, double lo, double hi) noexcept nogil:
    """`quadric.sheet_taper`: the smootherstep of the cosine between the sheet angles."""
    cdef double t = (c - lo) / (hi - lo)
    if t <= 0.0:
        return 0.0
    if t >= 1.0:
        return 1.0
    return t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)


cdef inline void basis(const double *y, double *b, double *G) noexcept nogil:
    """b (10) and G = ∂b/∂y (3 x 10, row d = ∂/∂y_d) at y: `quadric.basis_arrays`."""
    cdef int i
    b[0] = 1.0
    b[1] = y[0]
    b[2] = y[1]
    b[3] = y[2]
    b[4] = y[0] * y[0]
    b[5] = y[0] * y[1]
    b[6] = y[0] * y[2]
    b[7] = y[1] * y[1]
    b[8] = y[1] * y[2]
    b[9] = y[2] * y[2]
    if G == NULL:
        return
    for i in range(3 * NT):
        G[i] = 0.0
    G[1] = 1.0
    G[NT + 2] = 1.0
    G[2 * NT + 3] = 1.0
    G[4] = 2.0 * y[0]
    G[5] = y[1]
    G[6] = y[2]
    G[NT + 5] = y[0]
    G[NT + 7] = 2.0 * y[1]
    G[NT + 8] = y[2]
    G[2 * NT + 6] = y[0]
    G[2 * NT + 8] = y[1]
    G[2 * NT + 9] = 2.0 * y[2]


cdef inline void value(const double *y, const double *th, double *u, double *g,
                       double *H) noexcept nogil:
    """u(y), ∇u(y) and the (constant) Hessian of u: `quadric.value`."""
    cdef double b[NT]
    cdef double G[3 * NT]
    cdef int d, k
    basis(y, b, G)
    u[0] = 0.0
    for k in range(NT):
        u[0] += b[k] * th[k]
    for d in range(3):
        g[d] = 0.0
        for k in range(NT):
            g[d] += G[d * NT + k] * th[k]
    H[0] = 2.0 * th[4]
    H[1] = th[5]
    H[2] = th[6]
    H[3] = th[5]
    H[4] = 2.0 * th[7]
    H[5] = th[8]
    H[6] = th[6]
    H[7] = th[8]
    H[8] = 2.0 * th[9]


cdef inline bint cholesky(double *a, int n) noexcept nogil:
    """In place: the lower factor L of a (n x n, row-major), a = L Lᵀ; False if not SPD."""
    cdef int i, j, k
    cdef double s
    for j in range(n):
        s = a[j * n + j]
        for k in range(j):
            s -= a[j * n + k] * a[j * n + k]
        if not s > 0.0:
            return False
        a[j * n + j] = sqrt(s)
        for i in range(j + 1, n):
            s = a[i * n + j]
            for k in range(j):
                s -= a[i * n + k] * a[j * n + k]
            a[i * n + j] = s / a[j * n + j]
    return True


cdef inline void chol_solve(const double *L, int n, double *x) noexcept nogil:
    """x <- (L Lᵀ)⁻¹ x."""
    cdef int i, k
    cdef double s
    for i in range(n):
        s = x[i]
        for k in range(i):
            s -= L[i * n + k] * x[k]
        x[i] = s / L[i * n + i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k * n + i] * x[k]
        x[i] = s / L[i * n + i]


cdef inline void line_root(double *y, const double *th) noexcept nogil:
    """`quadric._line_root`: y <- the root of u along ∇u from y nearest y."""
    cdef double u0, nrm, B, A, disc, t
    cdef double g[3]
    cdef double H[9]
    cdef double d[3]
    cdef int e, f
    value(y, th, &u0, g, H)
    nrm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    for e in range(3):
        d[e] = g[e] / nrm
    B = g[0] * d[0] + g[1] * d[1] + g[2] * d[2]
    A = 0.0
    for e in range(3):
        for f in range(3):
            A += d[e] * H[e * 3 + f] * d[f]
    A *= 0.5
    disc = sqrt(B * B - 4.0 * A * u0) if B * B - 4.0 * A * u0 > 0.0 else 0.0
    t = -2.0 * u0 / (B + (disc if B >= 0.0 else -disc))
    for e in range(3):
        y[e] += t * d[e]


cdef inline bint closest(const Params *pa, const double *q, const double *th, double *y,
                         double *lam) noexcept nogil:
    """`quadric.closest_point`: y and λ (q - y = λ∇u(y)); whether Newton converged."""
    cdef double u, nrm, s, size, ymax
    cdef double g[3]
    cdef double H[9]
    cdef double nu[3]
    cdef double J[16]
    cdef double F[4]
    cdef int e, f, _it
    for e in range(3):
        y[e] = q[e]
    line_root(y, th)
    value(y, th, &u, g, H)
    nrm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    s = 0.0
    for e in range(3):
        nu[e] = g[e] / nrm
        s += (q[e] - y[e]) * nu[e]
    for e in range(3):
        y[e] = q[e] - s * nu[e]
    line_root(y, th)
    value(y, th, &u, g, H)
    lam[0] = ((q[0] - y[0]) * g[0] + (q[1] - y[1]) * g[1] + (q[2] - y[2]) * g[2]) / (
        g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    if not (isfinite(lam[0]) and isfinite(y[0]) and isfinite(y[1]) and isfinite(y[2])):
        return False
    for _it in range(pa.max_newton):
        value(y, th, &u, g, H)
        for e in range(3):
            F[e] = -(y[e] - q[e] + lam[0] * g[e])
            for f in range(3):
                J[e * 4 + f] = lam[0] * H[e * 3 + f] + (1.0 if e == f else 0.0)
            J[e * 4 + 3] = g[e]
            J[12 + e] = g[e]
        F[3] = -u
        J[15] = 0.0
        if not solve4(J, F):  # singular, or a step that is not finite
            return False
        ymax = 1.0
        for e in range(3):
            if fabs(y[e]) > ymax:
                ymax = fabs(y[e])
        size = 0.0
        for e in range(3):
            y[e] += F[e]
            if fabs(F[e]) > size:
                size = fabs(F[e])
        lam[0] += F[3]
        if size <= pa.newton_tol * ymax:
            return True
    return False


cdef inline void tangent_basis(const double *n, double *t1, double *t2) noexcept nogil:
    """Two unit vectors completing n to an orthonormal frame."""
    cdef double a[3]
    cdef double s
    cdef int e
    a[0] = 1.0 if fabs(n[0]) < 0.9 else 0.0
    a[1] = 0.0 if fabs(n[0]) < 0.9 else 1.0
    a[2] = 0.0
    s = a[0] * n[0] + a[1] * n[1]
    for e in range(3):
        t1[e] = a[e] - s * n[e]
    s = sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2])
    for e in range(3):
        t1[e] /= s
    t2[0] = n[1] * t1[2] - n[2] * t1[1]
    t2[1] = n[2] * t1[0] - n[0] * t1[2]
    t2[2] = n[0] * t1[1] - n[1] * t1[0]


cdef struct Answer:
    double gap
    double normal[3]
    double prox[3]
    double curv[2]
    double h, R
    double A[NT * NT]     # A + ρI of the fit (NaN diagonal where none was made)
    int64_t support
    int8_t status, reason


cdef double frobenius_rcond(const double *A) noexcept nogil:
    """1/(|As|_F |As⁻¹|_F), As = D⁻¹AD⁻¹ equilibrated by A's diagonal (`quadric.fit`'s
    rcond); 0 where As is not positive definite."""
    cdef double scale[NT]
    cdef double L[NT * NT]
    cdef double col[NT]
    cdef double fro = 0.0, inv_fro = 0.0
    cdef int a, f
    for a in range(NT):
        scale[a] = sqrt(A[a * NT + a])
    for a in range(NT * NT):
        L[a] = A[a] / (scale[a // NT] * scale[a % NT])
        fro += L[a] * L[a]
    if not cholesky(L, NT):
        return 0.0
    for a in range(NT):
        for f in range(NT):
            col[f] = 1.0 if f == a else 0.0
        chol_solve(L, NT, col)
        for f in range(NT):
            inv_fro += col[f] * col[f]
    return 1.0 / sqrt(fro * inv_fro)


cdef void one_centre(const Params *pa, const Data *da, const Grid *gr, Scratch *sc,
                     const double *x, const double *c, const double *e3, Answer *an,
                     int64_t *ids) noexcept nogil:
    """One fit at centre c (sheet normal e3) and x's answer on it, for one contactor:
    `QuadricSurface.support`, `fit_patch` and `_answer`. ids: the support's node ids
    (an.support of them, nearest first)."""
    cdef int64_t k = pa.k_search if pa.k_search < pa.n_distinct else pa.n_distinct
    cdef int64_t got = knn(gr, c, k, sc.idx, sc.d2), j, node, kk, live = 0
    cdef double d, rho, om, h, R, dk, w, ct, u, nrm, s11, s12, s22, mean, dev, bw
    cdef double dmin_, dd
    cdef double wsum = 0.0, hs = 0.0, lam = NAN
    cdef double yv[3]
    cdef double b[NT]
    cdef double G[3 * NT]
    cdef double A[NT * NT]
    cdef double L[NT * NT]
    cdef double r[NT]
    cdef double th[NT]
    cdef double q[3]
    cdef double y[3]
    cdef double g[3]
    cdef double H[9]
    cdef double t1[3]
    cdef double t2[3]
    cdef double Ht1[3]
    cdef double Ht2[3]
    cdef int a, e, f
    cdef bint ok = False, fitted
    an.gap = NAN
    an.A[0] = NAN
    for e in range(3):
        an.normal[e] = NAN
        an.prox[e] = NAN
    an.curv[0] = NAN
    an.curv[1] = NAN
    an.support = 0
    an.h = NAN
    an.R = NAN
    an.status = FAILED
    an.reason = R_FEW_NODES
    if got == 0:
        return
    # h at the centre: its nearest nodes' spacings weighted by W(d / (2 d_4)) (centre_spacing)
    rho = 2.0 * sqrt(sc.d2[3 if got > 3 else got - 1])
    for j in range(got):
        om = wendland(sqrt(sc.d2[j]) / rho)
        wsum += om
        hs += om * da.spacing[da.distinct[sc.idx[j]]]
    h = hs / wsum
    dk = sqrt(sc.d2[(pa.min_nodes if pa.min_nodes < got else got) - 1])
    R = pa.radius * h
    if 1.05 * dk > R:
        R = 1.05 * dk
    if sqrt(sc.d2[got - 1]) < R and k < pa.n_distinct:  # the radius reaches past: widen
        kk = GROW * k if GROW * k < pa.n_distinct else pa.n_distinct
        got = knn(gr, c, kk, sc.idx, sc.d2)
    an.h = h
    an.R = R
    for a in range(NT * NT):
        A[a] = 0.0
    for a in range(NT):
        r[a] = 0.0
    for j in range(got):
        d = sqrt(sc.d2[j])
        if not d < R:
            continue
        node = da.distinct[sc.idx[j]]
        ct = (da.normals[3 * node] * e3[0] + da.normals[3 * node + 1] * e3[1]
              + da.normals[3 * node + 2] * e3[2])
        w = taper(ct, pa.sheet_lo, pa.sheet_hi)
        if not w > 0.0:
            continue
        ids[live] = node
        live += 1
        d = 0.0
        for e in range(3):
            yv[e] = da.nodes[3 * node + e] - c[e]
            d += yv[e] * yv[e]
        w *= wendland(sqrt(d) / R)
        for e in range(3):
            yv[e] /= h
        basis(yv, b, G)
        bw = pa.beta * w
        for a in range(NT):  # the upper triangle (A is symmetric)
            for f in range(a, NT):
                A[a * NT + f] += w * b[a] * b[f] + bw * (
                    G[a] * G[f] + G[NT + a] * G[NT + f] + G[2 * NT + a] * G[2 * NT + f])
            r[a] += bw * (G[a] * da.normals[3 * node] + G[NT + a] * da.normals[3 * node + 1]
                          + G[2 * NT + a] * da.normals[3 * node + 2])
    an.support = live
    for a in range(NT):  # the lower triangle from the upper
        for f in range(a):
            A[a * NT + f] = A[f * NT + a]
    fitted = live > 0
    if fitted:
        for a in range(NT):
            A[a * NT + a] += pa.ridge
        for a in range(NT * NT):
            L[a] = A[a]
        fitted = cholesky(L, NT)
    if fitted:
        for a in range(NT):
            th[a] = r[a]
        chol_solve(L, NT, th)
        for a in range(NT * NT):  # its conditioning is measured once, on the last fit
            an.A[a] = A[a]
    else:  # the numpy steps go on with θ = 0 (no surface: no answer)
        for a in range(NT):
            th[a] = 0.0
    for e in range(3):
        q[e] = (x[e] - c[e]) / h
    ok = closest(pa, q, th, y, &lam)
    value(y, th, &u, g, H)
    nrm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    for e in range(3):
        an.normal[e] = g[e] / nrm
        an.prox[e] = c[e] + h * y[e]
    an.gap = h * lam * nrm
    # the principal curvatures: the shape operator P H P / |∇u| on a tangent basis
    tangent_basis(an.normal, t1, t2)
    for e in range(3):
        Ht1[e] = H[e * 3] * t1[0] + H[e * 3 + 1] * t1[1] + H[e * 3 + 2] * t1[2]
        Ht2[e] = H[e * 3] * t2[0] + H[e * 3 + 1] * t2[1] + H[e * 3 + 2] * t2[2]
    s11 = (t1[0] * Ht1[0] + t1[1] * Ht1[1] + t1[2] * Ht1[2]) / nrm
    s12 = (t1[0] * Ht2[0] + t1[1] * Ht2[1] + t1[2] * Ht2[2]) / nrm
    s22 = (t2[0] * Ht2[0] + t2[1] * Ht2[1] + t2[2] * Ht2[2]) / nrm
    mean = 0.5 * (s11 + s22)
    dev = sqrt(0.25 * (s11 - s22) * (s11 - s22) + s12 * s12)
    an.curv[0] = (mean + dev) / h
    an.curv[1] = (mean - dev) / h
    # the statuses, in `_answer`'s order (each later one wins)
    an.status = OPEN if an.gap > 0.0 else PENETRATION
    if fabs(an.gap) <= pa.contact * h:
        an.status = CONTACT
    an.reason = R_OK
    dmin_ = INFINITY
    for j in range(live):
        dd = 0.0
        for e in range(3):
            dd += (da.nodes[3 * ids[j] + e] - an.prox[e]) ** 2
        if dd < dmin_:
            dmin_ = dd
    if sqrt(dmin_) > pa.off * h:
        an.status = OUTSIDE
        an.reason = R_OFF_TARGET
    if not ok:
        an.status = FAILED
        an.reason = R_NO_CONVERGENCE
    if not fitted:
        an.status = FAILED
        an.reason = R_ILL
    if live < pa.few:
        an.status = FAILED
        an.reason = R_FEW_NODES
    if an.status == OUTSIDE or an.status == FAILED:
        an.gap = NAN
        for e in range(3):
            an.normal[e] = NAN
            an.prox[e] = NAN
        an.curv[0] = NAN
        an.curv[1] = NAN


cdef void project_row(const Params *pa, const Data *da, const Grid *gr, Scratch *sc,
                      const double *x, const double *c0, const double *e30, Out *o,
                      Py_ssize_t i) noexcept nogil:
    """One contactor's re-centring (`QuadricSurface._project`'s loop): centres from c0 (sheet
    normal e30) until the centre moves less than `settle` spacings; the answer, the pairing
    and the centres taken, into row i of `o`."""
    cdef double c[3]
    cdef double e3[3]
    cdef double move
    cdef Answer an
    cdef int64_t it, j
    cdef int64_t *ids = o.index + i * o.width
    cdef int e
    cdef bint settled = False
    for e in range(3):
        c[e] = c0[e]
        e3[e] = e30[e]
    for it in range(pa.max_centres):
        one_centre(pa, da, gr, sc, x, c, e3, &an, ids)
        o.iterations[i] = it + 1
        move = 0.0
        for e in range(3):
            move += (an.prox[e] - c[e]) ** 2
        move = sqrt(move) / an.h
        if not move > pa.settle:  # settled, or NaN: stop here
            settled = True
            break
        for e in range(3):
            c[e] = an.prox[e]
            e3[e] = an.normal[e]
    if not settled:
        o.status[i] = FAILED
        o.reason[i] = R_NOT_SETTLED
        for j in range(o.width):
            ids[j] = -1
        return
    o.gap[i] = an.gap
    o.rcond[i] = frobenius_rcond(an.A) if isfinite(an.A[0]) else NAN
    o.status[i] = an.status
    o.reason[i] = an.reason
    o.support[i] = an.support
    o.terms[i] = 0 if ((an.status == OUTSIDE or an.status == FAILED)
                       and an.reason != R_OFF_TARGET) else NT
    for e in range(3):
        o.normal[3 * i + e] = an.normal[e]
        o.prox[3 * i + e] = an.prox[e]
        o.origin[3 * i + e] = c[e]
        o.e3[3 * i + e] = e3[e]
    o.curv[2 * i] = an.curv[0]
    o.curv[2 * i + 1] = an.curv[1]
    o.radius[i] = an.R
    o.h[i] = an.h
    for j in range(an.support, o.width):
        ids[j] = -1


cdef class Quadrics:
    """The compiled view of a QuadricSurface's nodes (their grid), for `project`."""
    cdef GridArrays grid
    cdef const double[:, ::1] nodes
    cdef const int64_t[::1] distinct
    cdef const double[:, ::1] normals
    cdef const double[::1] spacing
    cdef Data da

    def __init__(self, nodes, distinct, normals, spacing):
        self.nodes = np.ascontiguousarray(nodes, dtype=np.float64)
        self.distinct = np.ascontiguousarray(distinct, dtype=np.int64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        self.spacing = np.ascontiguousarray(spacing, dtype=np.float64)
        coords = np.asarray(self.nodes)[np.asarray(self.distinct)]
        n = len(coords)
        span = float(np.ptp(coords, axis=0).max()) if n else 0.0
        cell = span / max(np.sqrt(n / 16.0), 1.0) if span > 0 else 1.0  # ~16 nodes a cell
        self.grid = GridArrays(coords, cell)
        self.da.nodes = &self.nodes[0, 0]
        self.da.distinct = &self.distinct[0]
        self.da.normals = &self.normals[0, 0]
        self.da.spacing = &self.spacing[0]

    def project(self, dict params, const double[:, ::1] points, const double[:, ::1] centres,
                const double[:, ::1] e3, int threads=0):
        """Every contactor's answer (`project_row`): a dict of the `Projection` fields (gap,
        normal, proximal_point, curvature, rcond, status, reason, support, iterations, terms)
        and the pairing's (origin, e3, radius, spacing, index (m, width) -1 padded)."""
        cdef Params pa
        pa.radius = params["radius"]
        pa.beta = params["beta"]
        pa.ridge = params["ridge"]
        pa.settle = params["settle"]
        pa.newton_tol = params["newton_tol"]
        pa.off = params["off"]
        pa.contact = tol.CONTACT
        pa.sheet_lo = cos(params["sheet_deg"][1] * M_PI / 180.0)
        pa.sheet_hi = cos(params["sheet_deg"][0] * M_PI / 180.0)
        pa.k_search = params["k_search"]
        pa.min_nodes = params["min_nodes"]
        pa.few = params["few"]
        pa.max_centres = params["max_centres"]
        pa.max_newton = params["max_newton"]
        pa.n_distinct = len(self.distinct)
        cdef Py_ssize_t m = points.shape[0], i
        cdef int64_t cap = min(GROW * pa.k_search, pa.n_distinct)
        width = int(cap)
        out = {"gap": np.full(m, np.nan), "normal": np.full((m, 3), np.nan),
               "proximal_point": np.full((m, 3), np.nan), "curvature": np.full((m, 2), np.nan),
               "rcond": np.full(m, np.nan), "status": np.full(m, FAILED, np.int8),
               "reason": np.full(m, R_NOT_SETTLED, np.int8),
               "support": np.zeros(m, np.int64), "iterations": np.zeros(m, np.int64),
               "terms": np.zeros(m, np.int8), "origin": np.full((m, 3), np.nan),
               "e3": np.full((m, 3), np.nan), "radius": np.full(m, np.nan),
               "spacing": np.full(m, np.nan), "index": np.full((m, width), -1, np.int64)}
        if m == 0:
            return out
        cdef double[::1] gap = out["gap"], rc = out["rcond"], rad = out["radius"]
        cdef double[::1] hh = out["spacing"]
        cdef double[:, ::1] nrm = out["normal"], prx = out["proximal_point"]
        cdef double[:, ::1] cur = out["curvature"], org = out["origin"], ee = out["e3"]
        cdef int8_t[::1] st = out["status"], rs = out["reason"], te = out["terms"]
        cdef int64_t[::1] sup = out["support"], its = out["iterations"]
        cdef int64_t[:, ::1] idx = out["index"]
        cdef Out o
        o.gap = &gap[0]
        o.normal = &nrm[0, 0]
        o.prox = &prx[0, 0]
        o.curv = &cur[0, 0]
        o.rcond = &rc[0]
        o.status = &st[0]
        o.reason = &rs[0]
        o.support = &sup[0]
        o.iterations = &its[0]
        o.terms = &te[0]
        o.origin = &org[0, 0]
        o.e3 = &ee[0, 0]
        o.radius = &rad[0]
        o.h = &hh[0]
        o.index = &idx[0, 0]
        o.width = width
        cdef const double *xp = &points[0, 0]
        cdef const double *cp = &centres[0, 0]
        cdef const double *ep = &e3[0, 0]
        cdef Scratch *sc
        cdef int failed = 0
        cdef int *failedp = &failed
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "quadric")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                sc = scratch_new(cap)
                if sc != NULL:
                    for i in range(m):
                        project_row(&pa, &self.da, &self.grid.grid, sc, xp + 3 * i,
                                    cp + 3 * i, ep + 3 * i, &o, i)
                    scratch_free(sc)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 16)
            with nogil, parallel(num_threads=threads):
                sc = scratch_new(cap)
                if sc == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if sc != NULL:
                        project_row(&pa, &self.da, &self.grid.grid, sc, xp + 3 * i,
                                    cp + 3 * i, ep + 3 * i, &o, i)
                scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the quadric projection's scratch")
        return out
