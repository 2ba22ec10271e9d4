# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The rigid target's closest point, one contactor at a time, in parallel (OpenMP `prange`).

Φ(y) = Σ_j w_j φ_j / Σ_j w_j, the blend of the node fits [12]-[17] described in `rigid.py`,
with its gradient and Hessian; the closest point y* of {Φ = 0} to x^c by Newton on the
Lagrange system (y − x^c + λ∇Φ = 0, Φ = 0). Candidate nodes come from a grid of cells of the
largest blending radius (sorted cell keys, binary search), gathered once per contactor in a
ball around x^c wide enough for every Newton iterate (a contactor whose iterates leave it is
solved again with a wider ball). Everything a contactor's answer depends on is a function of
x^c alone: it is bitwise the same in any batch. The gap, normal and Hessian of g are then
assembled from y*, ∇Φ and ∇²Φ in `rigid.py`.
"""
import numpy as np

from libc.math cimport sqrt, fabs, floor, isfinite, INFINITY, NAN
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t, int8_t
from cython.parallel cimport prange, parallel

# outcome of one contactor (rigid.py maps them onto STATUS/REASONS)
cdef enum:
    DONE = 0          # Newton converged
    NOT_CONVERGED = 1
    BEYOND = 2        # Σ w = 0 at x^c: beyond the surface's reach
    LOST = 3          # an iterate left the reach, or the Newton matrix was singular
    OVERFLOW = 4      # more candidates than the scratch holds: run again with more room
    FAR = 5           # the iterates kept leaving every ball tried


cdef struct Blend:
    const double *pos
    const double *origin
    const double *axes
    const double *radius
    const double *alpha
    const double *reach
    const double *spacing
    const int64_t *ea
    const int64_t *eb
    int nt
    const int64_t *keys
    const int64_t *order
    int64_t n
    double lo[3]
    double cell
    int64_t dims[3]
    double reach_max
    double step_tol
    int max_iter


cdef struct Field:
    double S
    double Phi
    double h
    double dmin
    double g[3]
    double H[9]


cdef inline int64_t lower_bound(const int64_t *a, int64_t n, int64_t key) noexcept nogil:
    cdef int64_t lo = 0, hi = n, mid
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


cdef inline int64_t cell_of(const Blend *b, double v, int e) noexcept nogil:
    cdef double c = floor((v - b.lo[e]) / b.cell)
    if c < 0:
        return 0
    if c > b.dims[e] - 1:
        return b.dims[e] - 1
    return <int64_t>c


cdef int64_t gather(const Blend *b, const double *x, double rad, int64_t *out,
                    int64_t cap) noexcept nogil:
    """Nodes within `rad` of x, in cell order then node order; -1 when more than `cap`."""
    cdef int64_t c0[3]
    cdef int64_t c1[3]
    cdef int64_t i, j, k, key, p, node, count = 0
    cdef double d, d2, r2 = rad * rad
    cdef int e
    for e in range(3):
        if x[e] + rad < b.lo[e] or x[e] - rad > b.lo[e] + b.cell * b.dims[e]:
            return 0
        c0[e] = cell_of(b, x[e] - rad, e)
        c1[e] = cell_of(b, x[e] + rad, e)
    for i in range(c0[0], c1[0] + 1):
        for j in range(c0[1], c1[1] + 1):
            for k in range(c0[2], c1[2] + 1):
                key = (i * b.dims[1] + j) * b.dims[2] + k
                p = lower_bound(b.keys, b.n, key)
                while p < b.n and b.keys[p] == key:
                    node = b.order[p]
                    d2 = 0.0
                    for e in range(3):
                        d = x[e] - b.pos[3 * node + e]
                        d2 += d * d
                    if d2 < r2:
                        if count >= cap:
                            return -1
                        out[count] = node
                        count += 1
                    p += 1
    return count


cdef void field(const Blend *b, const double *y, const int64_t *cand, int64_t count,
                Field *f) noexcept nogil:
    """Φ, ∇Φ, ∇²Φ at y over the candidates; S = Σ w (0: beyond the reach)."""
    cdef double S = 0.0, T = 0.0, hw = 0.0, dmin = INFINITY
    cdef double gS[3]
    cdef double gT[3]
    cdef double HS[9]
    cdef double HT[9]
    cdef double d[3]
    cdef double Z[3]
    cdef double gw[3]
    cdef double gphi[3]
    cdef double sp[4]
    cdef double tp[4]
    cdef double dist2, dist, rho, r, u, u2, w, cw, cross, R, fv, fs, ft, fss, fst, ftt, c
    cdef double phi, hw_ab, hphi_ab, Sd
    cdef const double *A
    cdef const double *al
    cdef int64_t idx, j
    cdef int e, a, bb, n, ea, eb
    for e in range(3):
        gS[e] = 0.0
        gT[e] = 0.0
    for e in range(9):
        HS[e] = 0.0
        HT[e] = 0.0
    for idx in range(count):
        j = cand[idx]
        dist2 = 0.0
        for e in range(3):
            d[e] = y[e] - b.pos[3 * j + e]
            dist2 += d[e] * d[e]
        dist = sqrt(dist2)
        if dist < dmin:
            dmin = dist
        rho = b.reach[j]
        if dist >= rho:
            continue
        # Wendland C² weight of r = |y − x_j| / ρ_j, its gradient and Hessian in y
        r = dist / rho
        u = 1.0 - r
        u2 = u * u
        w = u2 * u2 * (4.0 * r + 1.0)
        cw = -20.0 * u2 * u / (rho * rho)
        cross = 60.0 * u2 / (rho * rho * rho * dist) if dist > 0 else 0.0
        for e in range(3):
            gw[e] = cw * d[e]
        # φ_j = R (Z3 − f(Z1, Z2)), Z = axes (y − o) / R: the local approximation [12]-[13]
        A = b.axes + 9 * j
        R = b.radius[j]
        for e in range(3):
            Z[e] = (A[3 * e] * (y[0] - b.origin[3 * j]) + A[3 * e + 1] * (y[1] - b.origin[3 * j + 1])
                    + A[3 * e + 2] * (y[2] - b.origin[3 * j + 2])) / R
        sp[0] = 1.0
        tp[0] = 1.0
        for e in range(1, 4):
            sp[e] = sp[e - 1] * Z[0]
            tp[e] = tp[e - 1] * Z[1]
        fv = 0.0
        fs = 0.0
        ft = 0.0
        fss = 0.0
        fst = 0.0
        ftt = 0.0
        al = b.alpha + b.nt * j
        for n in range(b.nt):
            c = al[n]
            ea = b.ea[n]
            eb = b.eb[n]
            fv += c * sp[ea] * tp[eb]
            if ea >= 1:
                fs += c * ea * sp[ea - 1] * tp[eb]
            if eb >= 1:
                ft += c * eb * sp[ea] * tp[eb - 1]
            if ea >= 2:
                fss += c * (ea * (ea - 1)) * sp[ea - 2] * tp[eb]
            if ea >= 1 and eb >= 1:
                fst += c * (ea * eb) * sp[ea - 1] * tp[eb - 1]
            if eb >= 2:
                ftt += c * (eb * (eb - 1)) * sp[ea] * tp[eb - 2]
        phi = R * (Z[2] - fv)
        for e in range(3):
            gphi[e] = A[6 + e] - fs * A[e] - ft * A[3 + e]
        S += w
        T += w * phi
        hw += w * b.spacing[j]
        for e in range(3):
            gS[e] += gw[e]
            gT[e] += gw[e] * phi + w * gphi[e]
        for a in range(3):
            for bb in range(3):
                hw_ab = cross * d[a] * d[bb]
                if a == bb:
                    hw_ab += cw
                # ∇²φ = −(1/R) [fss e1e1ᵀ + fst (e1e2ᵀ + e2e1ᵀ) + ftt e2e2ᵀ]
                hphi_ab = -(fss * A[a] * A[bb] + fst * (A[a] * A[3 + bb] + A[3 + a] * A[bb])
                            + ftt * A[3 + a] * A[3 + bb]) / R
                HS[3 * a + bb] += hw_ab
                HT[3 * a + bb] += (hw_ab * phi + gw[a] * gphi[bb] + gphi[a] * gw[bb]
                                   + w * hphi_ab)
    f.S = S
    f.dmin = dmin
    if S <= 0.0:
        f.Phi = NAN
        f.h = NAN
        return
    Sd = 1.0 / S
    f.Phi = T * Sd
    f.h = hw * Sd
    for e in range(3):
        f.g[e] = (gT[e] - f.Phi * gS[e]) * Sd
    for a in range(3):
        for bb in range(3):
            f.H[3 * a + bb] = (HT[3 * a + bb] - f.Phi * HS[3 * a + bb] - f.g[a] * gS[bb]
                               - gS[a] * f.g[bb]) * Sd


cdef bint solve4(double *J, double *F) noexcept nogil:
    """J z = F in place (F becomes z), Gaussian elimination with partial pivoting."""
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


cdef int closest(const Blend *b, const double *x, int64_t *cand, int64_t cap, double *y,
                 Field *f, int64_t *its) noexcept nogil:
    """y* of one contactor; returns its outcome (DONE...) with the field at y in f."""
    cdef double J[16]
    cdef double F[4]
    cdef double y0[3]
    cdef double gg, lam, lam0, margin, step2, dz2, dx2, dd, h
    cdef int64_t count
    cdef int e, a, it, attempt
    cdef bint far
    its[0] = 0
    count = gather(b, x, b.reach_max, cand, cap)
    if count < 0:
        return OVERFLOW
    field(b, x, cand, count, f)
    if f.S <= 0.0:
        return BEYOND
    h = f.h
    gg = f.g[0] * f.g[0] + f.g[1] * f.g[1] + f.g[2] * f.g[2]
    lam0 = f.Phi / gg
    step2 = 0.0
    for e in range(3):
        y0[e] = x[e] - lam0 * f.g[e]  # one projection step onto {Φ = 0}
        step2 += (lam0 * f.g[e]) ** 2
    margin = 2.0 * sqrt(step2) + 0.5 * h
    for attempt in range(6):
        count = gather(b, x, b.reach_max + margin, cand, cap)
        if count < 0:
            return OVERFLOW
        for e in range(3):
            y[e] = y0[e]
        lam = lam0
        far = False
        for it in range(b.max_iter):
            field(b, y, cand, count, f)
            if f.S <= 0.0:
                return LOST
            # [[I + λ∇²Φ, ∇Φ], [∇Φᵀ, 0]] Δ = [y − x + λ∇Φ, Φ]
            for a in range(3):
                for e in range(3):
                    J[4 * a + e] = lam * f.H[3 * a + e] + (1.0 if a == e else 0.0)
                J[4 * a + 3] = f.g[a]
                J[12 + a] = f.g[a]
                F[a] = y[a] - x[a] + lam * f.g[a]
            J[15] = 0.0
            F[3] = f.Phi
            if not solve4(J, F):
                return LOST
            dz2 = 0.0
            dx2 = 0.0
            for e in range(3):
                y[e] -= F[e]
                dz2 += F[e] * F[e]
                dd = y[e] - x[e]
                dx2 += dd * dd
            lam -= F[3]
            its[0] += 1
            if dx2 > margin * margin:
                far = True
                break
            if dz2 <= (b.step_tol * h) ** 2:
                field(b, y, cand, count, f)
                if f.S <= 0.0:
                    return LOST
                return DONE
        if not far:
            return NOT_CONVERGED
        margin *= 4.0
    return FAR


def closest_points(dict blend, const double[:, ::1] points, const int64_t[::1] rows,
                   double[:, ::1] y, double[:, ::1] grad, double[:, ::1] hess,
                   double[::1] phi, double[::1] spacing, double[::1] dmin, int64_t[::1] its,
                   int8_t[::1] outcome, int64_t cap):
    """Closest points of `points[rows]` on {Φ = 0}, written at those rows of the outputs:
    y*, ∇Φ(y*), ∇²Φ(y*) (flattened 3x3), Φ(y*), blended spacing h at y*, distance to the
    nearest candidate node, Newton iterations, outcome (DONE ... FAR)."""
    cdef Blend b
    cdef const double[:, ::1] pos = blend["position"]
    cdef const double[:, ::1] origin = blend["origin"]
    cdef const double[:, :, ::1] axes = blend["axes"]
    cdef const double[::1] radius = blend["radius"]
    cdef const double[:, ::1] alpha = blend["alpha"]
    cdef const double[::1] reach = blend["reach"]
    cdef const double[::1] nspacing = blend["spacing"]
    cdef const int64_t[::1] ea = blend["ea"]
    cdef const int64_t[::1] eb = blend["eb"]
    cdef const int64_t[::1] keys = blend["keys"]
    cdef const int64_t[::1] order = blend["order"]
    cdef const double[::1] lo = blend["lo"]
    cdef const int64_t[::1] dims = blend["dims"]
    cdef int64_t m = rows.shape[0], i, r
    cdef int e
    cdef int64_t *cand
    cdef Field *f
    if m == 0 or pos.shape[0] == 0:
        return
    b.pos = &pos[0, 0]
    b.origin = &origin[0, 0]
    b.axes = &axes[0, 0, 0]
    b.radius = &radius[0]
    b.alpha = &alpha[0, 0]
    b.reach = &reach[0]
    b.spacing = &nspacing[0]
    b.ea = &ea[0]
    b.eb = &eb[0]
    b.nt = ea.shape[0]
    b.keys = &keys[0]
    b.order = &order[0]
    b.n = pos.shape[0]
    for e in range(3):
        b.lo[e] = lo[e]
        b.dims[e] = dims[e]
    b.cell = blend["cell"]
    b.reach_max = blend["reach_max"]
    b.step_tol = blend["step_tol"]
    b.max_iter = blend["max_iter"]
    with nogil, parallel():
        cand = <int64_t *>malloc(cap * sizeof(int64_t))
        f = <Field *>malloc(sizeof(Field))
        for i in prange(m, schedule="dynamic", chunksize=64):
            r = rows[i]
            outcome[r] = closest(&b, &points[r, 0], cand, cap, &y[r, 0], f, &its[r])
            phi[r] = f.Phi
            spacing[r] = f.h
            dmin[r] = f.dmin
            for e in range(3):
                grad[r, e] = f.g[e]
            for e in range(9):
                hess[r, e] = f.H[e]
        free(f)
        free(cand)
