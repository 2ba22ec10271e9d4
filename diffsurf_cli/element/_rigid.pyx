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
from ..threads import chunk_size, threads_for

from libc.math cimport sqrt, fabs, floor, isfinite, INFINITY, NAN
from libc.float cimport DBL_EPSILON
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t, int8_t
from cython.parallel cimport prange, parallel

from .._codes cimport (OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED, R_OK, R_OFF_TARGET,
                       R_NO_CONVERGENCE)
from ..mls._linalg cimport NTERMS_MAX, solve4
from ..mls._steps cimport surface_derivatives, beyond_hull
from ..mls._weight cimport WENDLAND, WeightParams, weight_derivatives

#: The closest point's Newton has converged once its step is within this many ulps of the
#: distance |y − x^c| (the round-off of its equations far from the target), or within
#: tol.NEWTON_STEP node spacings (near it).
cdef double ROUNDOFF_ULPS = 16.0

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
    WeightParams blend           # the blending weight: Wendland's
    int ea[NTERMS_MAX]           # the basis [14] of every node's fit: s^ea t^eb
    int eb[NTERMS_MAX]
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
    double outside
    double contact
    double hull
    double sheet


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
    cdef int64_t i, j, key, last, p, node, count = 0
    cdef double d, d2, r2 = rad * rad
    cdef int e
    for e in range(3):
        if x[e] + rad < b.lo[e] or x[e] - rad > b.lo[e] + b.cell * b.dims[e]:
            return 0
        c0[e] = cell_of(b, x[e] - rad, e)
        c1[e] = cell_of(b, x[e] + rad, e)
    for i in range(c0[0], c1[0] + 1):
        for j in range(c0[1], c1[1] + 1):
            # the cells (i, j, c0[2]..c1[2]) have consecutive keys: one search, one scan
            key = (i * b.dims[1] + j) * b.dims[2]
            last = key + c1[2]
            p = lower_bound(b.keys, b.n, key + c0[2])
            while p < b.n and b.keys[p] <= last:
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


cdef int64_t one_sheet(const Blend *b, const double *x, int64_t *cand,
                       int64_t count) noexcept nogil:
    """Keep the candidates of the sheet of the node nearest x (frame e3 within the
    projection's sheet angle of that node's), in order; returns their number. The far side
    of a thin plate or tube would otherwise blend into the near side's surface."""
    cdef int64_t idx, j, best = -1, kept = 0
    cdef double d2, d, dbest = INFINITY
    cdef const double *ref
    cdef const double *e3
    cdef int e
    for idx in range(count):
        j = cand[idx]
        d2 = 0.0
        for e in range(3):
            d = x[e] - b.pos[3 * j + e]
            d2 += d * d
        if d2 < dbest:
            dbest = d2
            best = j
    if best < 0:
        return 0
    ref = b.axes + 9 * best + 6
    for idx in range(count):
        j = cand[idx]
        e3 = b.axes + 9 * j + 6
        if e3[0] * ref[0] + e3[1] * ref[1] + e3[2] * ref[2] >= b.sheet:
            cand[kept] = j
            kept += 1
    return kept


cdef void field(const Blend *b, const double *x, const double *v, const int64_t *cand,
                int64_t count, Field *f, bint second) noexcept nogil:
    """Φ, ∇Φ (and ∇²Φ if `second`) at y = x + v over the candidates; S = Σ w (0: beyond
    the reach). Positions are taken relative to the contactor x, so the Newton steps on v
    reach round-off of v, not of x's coordinates (a target far from the origin)."""
    cdef double S = 0.0, T = 0.0, hw = 0.0, dmin = INFINITY
    cdef double gS[3]
    cdef double gT[3]
    cdef double HS[9]
    cdef double HT[9]
    cdef double d[3]
    cdef double Z[3]
    cdef double o[3]
    cdef double gw[3]
    cdef double gphi[3]
    cdef double fd[6]
    cdef double dist2, dist, rho, w, cw, cross, R, fv, fs, ft, fss, fst, ftt
    cdef double phi, hw_ab, hphi_ab, Sd
    cdef const double *A
    cdef double wq[3]
    cdef int64_t idx, j
    cdef int e, a, bb
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
            d[e] = v[e] - (b.pos[3 * j + e] - x[e])
            dist2 += d[e] * d[e]
        dist = sqrt(dist2)
        if dist < dmin:
            dmin = dist
        rho = b.reach[j]
        if dist >= rho:
            continue
        # Wendland's C² weight [15] of q = |y − x_j|² / ρ_j², its gradient (cw d) and Hessian
        # (cw I + cross d dᵀ) in y
        weight_derivatives(&b.blend, dist2 / (rho * rho), wq)
        w = wq[0]
        cw = 2.0 * wq[1] / (rho * rho)
        cross = 4.0 * wq[2] / (rho * rho * rho * rho)
        for e in range(3):
            gw[e] = cw * d[e]
        # φ_j = R (Z3 − f(Z1, Z2)), Z = axes (y − o) / R: the local approximation [12]-[13]
        A = b.axes + 9 * j
        R = b.radius[j]
        for e in range(3):
            o[e] = v[e] - (b.origin[3 * j + e] - x[e])
        for e in range(3):
            Z[e] = (A[3 * e] * o[0] + A[3 * e + 1] * o[1] + A[3 * e + 2] * o[2]) / R
        # f and its derivatives at (Z1, Z2) [13]
        surface_derivatives(b.nt, b.ea, b.eb, b.alpha + b.nt * j, Z[0], Z[1], fd)
        fv = fd[0]
        fs = fd[1]
        ft = fd[2]
        fss = fd[3]
        fst = fd[4]
        ftt = fd[5]
        phi = R * (Z[2] - fv)
        for e in range(3):
            gphi[e] = A[6 + e] - fs * A[e] - ft * A[3 + e]
        S += w
        T += w * phi
        hw += w * b.spacing[j]
        for e in range(3):
            gS[e] += gw[e]
            gT[e] += gw[e] * phi + w * gphi[e]
        if not second:
            continue
        for a in range(3):
            for bb in range(a, 3):  # the upper triangle; mirrored below
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
    if not second:
        return
    for a in range(3):
        for bb in range(a, 3):
            f.H[3 * a + bb] = (HT[3 * a + bb] - f.Phi * HS[3 * a + bb] - f.g[a] * gS[bb]
                               - gS[a] * f.g[bb]) * Sd
            f.H[3 * bb + a] = f.H[3 * a + bb]


cdef int closest(const Blend *b, const double *x, const double *seed, int64_t *cand,
                 int64_t cap, double *v, Field *f, int64_t *its,
                 int64_t *ncand) noexcept nogil:
    """v = y* − x^c of one contactor; returns its outcome (DONE...) with the field at y* in
    f. The search starts at x^c, or at `seed` (a point near the surface: the faceted foot of
    a contactor beyond the blend's reach, deep or far) when it is not NULL: its candidates,
    sheet and first projection step are then the seed's, and the Lagrange multiplier starts
    as the one that makes y − x^c + λ∇Φ = 0 hold along ∇Φ."""
    cdef double J[16]
    cdef double F[4]
    cdef double v0[3]
    cdef double c[3]             # the search's centre, relative to x^c (0: x^c itself)
    cdef double xc[3]
    cdef double gg, lam, lam0, margin, step2, dz2, dx2, h, d, vv
    cdef int64_t count
    cdef int e, a, _it, _attempt
    cdef bint far
    its[0] = 0
    for e in range(3):
        c[e] = seed[e] - x[e] if seed != NULL else 0.0
        xc[e] = x[e] + c[e]
    # one ball for Φ at the centre and, mostly, for every iterate too (wider only when the
    # first step needs it)
    cdef double gathered = 1.5 * b.reach_max
    count = gather(b, xc, gathered, cand, cap)
    if count < 0:
        return OVERFLOW
    count = one_sheet(b, xc, cand, count)
    field(b, x, c, cand, count, f, False)
    if f.S <= 0.0:
        return BEYOND
    h = f.h
    gg = f.g[0] * f.g[0] + f.g[1] * f.g[1] + f.g[2] * f.g[2]
    lam0 = f.Phi / gg
    step2 = 0.0
    for e in range(3):
        v0[e] = c[e] - lam0 * f.g[e]  # one projection step onto {Φ = 0}
        step2 += (lam0 * f.g[e]) ** 2
    if seed != NULL:  # λ of y0 − x^c + λ∇Φ = 0 along ∇Φ (x^c is not on the seed's normal)
        lam0 = 0.0
        for e in range(3):
            lam0 -= v0[e] * f.g[e]
        lam0 /= gg
    margin = 2.0 * sqrt(step2) + 0.5 * h
    for _attempt in range(6):
        if b.reach_max + margin > gathered:
            gathered = b.reach_max + margin
            count = gather(b, xc, gathered, cand, cap)
            if count < 0:
                return OVERFLOW
            count = one_sheet(b, xc, cand, count)
        for e in range(3):
            v[e] = v0[e]
        lam = lam0
        far = False
        for _it in range(b.max_iter):
            field(b, x, v, cand, count, f, True)
            if f.S <= 0.0:
                return LOST
            # [[I + λ∇²Φ, ∇Φ], [∇Φᵀ, 0]] Δ = [y − x + λ∇Φ, Φ]
            for a in range(3):
                for e in range(3):
                    J[4 * a + e] = lam * f.H[3 * a + e] + (1.0 if a == e else 0.0)
                J[4 * a + 3] = f.g[a]
                J[12 + a] = f.g[a]
                F[a] = v[a] + lam * f.g[a]
            J[15] = 0.0
            F[3] = f.Phi
            if not solve4(J, F):
                return LOST
            its[0] += 1
            dz2 = F[0] * F[0] + F[1] * F[1] + F[2] * F[2]
            # the step's floor: y − x^c + λ∇Φ sums two terms of the size of |v| (the distance
            # of a far contactor) that cancel, so no step falls below a few ulps of |v|
            vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
            if dz2 <= (b.step_tol * h) ** 2 or dz2 <= (ROUNDOFF_ULPS * DBL_EPSILON) ** 2 * vv:
                # converged: y* is this iterate, within the step (round-off of h), and f is
                # already the field there (no evaluation after a step of round-off)
                ncand[0] = count
                return DONE
            dx2 = 0.0
            for e in range(3):
                v[e] -= F[e]
                d = v[e] - c[e]
                dx2 += d * d
            lam -= F[3]
            if dx2 > (gathered - b.reach_max) ** 2:
                far = True
                break
        if not far:
            return NOT_CONVERGED
        margin = 4.0 * (gathered - b.reach_max)
    return FAR


cdef bint off_hull(const Blend *b, const double *x, const double *v, const double *t1,
                   const double *t2, const int64_t *cand, int64_t count, double slack,
                   double *arcs) noexcept nogil:
    """Whether y = x + v is farther than `slack` from the convex hull of the nodes whose
    weight reaches it, in the tangent plane (t1, t2): the projection's on-target test
    (`beyond_hull`) on those nodes; True where none reaches y. `arcs`: 5 count scratch."""
    cdef double *s = arcs
    cdef double *t = arcs + count
    cdef double *w = arcs + 2 * count
    cdef double d0, d1, d2
    cdef int64_t idx, j, live = 0
    for idx in range(count):
        j = cand[idx]
        d0 = (b.pos[3 * j] - x[0]) - v[0]
        d1 = (b.pos[3 * j + 1] - x[1]) - v[1]
        d2 = (b.pos[3 * j + 2] - x[2]) - v[2]
        if d0 * d0 + d1 * d1 + d2 * d2 >= b.reach[j] * b.reach[j]:
            continue
        s[live] = t1[0] * d0 + t1[1] * d1 + t1[2] * d2
        t[live] = t2[0] * d0 + t2[1] * d1 + t2[2] * d2
        w[live] = 1.0
        live += 1
    if live == 0:
        return True
    return beyond_hull(s, t, w, live, 0.0, 0.0, slack, arcs + 3 * count, arcs + 4 * count)


cdef void assemble(const Blend *b, const double *x, const double *v, const Field *f,
                   const int64_t *cand, int64_t count, double *arcs,
                   double *gap, double *normal, double *proximal, double *hess,
                   double *curvature, int8_t *status, int8_t *reason) noexcept nogil:
    """Gap [32], normal ν = ∇Φ/|∇Φ| = ∂g/∂x^c, principal curvatures of S at y* and
    ∂²g/∂x^c² = L (I + gL)⁻¹ (L = P∇²ΦP/|∇Φ|, the shape operator), status [33]."""
    cdef double nu[3]
    cdef double t1[3]
    cdef double t2[3]
    cdef double nrm, g, dot, tn, L00, L01, L11, mean, disc, k1, k2, a00, a01, a11, det
    cdef double m00, m01, m11
    cdef int e, i
    nrm = sqrt(f.g[0] * f.g[0] + f.g[1] * f.g[1] + f.g[2] * f.g[2])
    g = 0.0
    for e in range(3):
        nu[e] = f.g[e] / nrm
        g -= v[e] * nu[e]  # (x^c − y*)·ν [32]
    # an orthonormal tangent basis, a fixed function of ν
    for e in range(3):
        t1[e] = 0.0
    if fabs(nu[0]) < 0.9:
        t1[0] = 1.0
    else:
        t1[1] = 1.0
    dot = t1[0] * nu[0] + t1[1] * nu[1] + t1[2] * nu[2]
    tn = 0.0
    for e in range(3):
        t1[e] -= dot * nu[e]
        tn += t1[e] * t1[e]
    tn = sqrt(tn)
    for e in range(3):
        t1[e] /= tn
    t2[0] = nu[1] * t1[2] - nu[2] * t1[1]
    t2[1] = nu[2] * t1[0] - nu[0] * t1[2]
    t2[2] = nu[0] * t1[1] - nu[1] * t1[0]
    # L in that basis: Tᵀ ∇²Φ T / |∇Φ|
    L00 = 0.0
    L01 = 0.0
    L11 = 0.0
    for e in range(3):
        for i in range(3):
            L00 += t1[e] * f.H[3 * e + i] * t1[i]
            L01 += 0.5 * (t1[e] * f.H[3 * e + i] * t2[i] + t2[e] * f.H[3 * e + i] * t1[i])
            L11 += t2[e] * f.H[3 * e + i] * t2[i]
    L00 /= nrm
    L01 /= nrm
    L11 /= nrm
    mean = 0.5 * (L00 + L11)
    disc = sqrt(0.25 * (L00 - L11) * (L00 - L11) + L01 * L01)
    k1 = mean + disc
    k2 = mean - disc
    # y* is a closest point (a minimum of the distance) only where 1 + g κ_i > 0
    if not (isfinite(g) and 1.0 + g * k1 > 0.0 and 1.0 + g * k2 > 0.0):
        status[0] = FAILED
        reason[0] = R_NO_CONVERGENCE
        return
    # past the target's edge: farther than `outside` spacings from every node, or beyond the
    # tangent-plane hull of the nodes that reach y* (as the projection decides it)
    if f.dmin > b.outside * f.h or off_hull(b, x, v, t1, t2, cand, count, b.hull * f.h, arcs):
        status[0] = OUTSIDE
        reason[0] = R_OFF_TARGET
        return
    gap[0] = g
    for e in range(3):
        normal[e] = nu[e]
        proximal[e] = x[e] + v[e]
    curvature[0] = k1
    curvature[1] = k2
    reason[0] = R_OK
    if fabs(g) <= b.contact * f.h:
        status[0] = CONTACT
    elif g > 0:
        status[0] = OPEN
    else:
        status[0] = PENETRATION
    if hess == NULL:
        return
    # (I + gL)⁻¹ L, symmetric: both are polynomials in L
    a00 = 1.0 + g * L00
    a01 = g * L01
    a11 = 1.0 + g * L11
    det = a00 * a11 - a01 * a01
    m00 = (a11 * L00 - a01 * L01) / det
    m01 = 0.5 * ((a11 * L01 - a01 * L11) + (a00 * L01 - a01 * L00)) / det
    m11 = (a00 * L11 - a01 * L01) / det
    for e in range(3):
        for i in range(3):
            hess[3 * e + i] = (m00 * t1[e] * t1[i] + m01 * (t1[e] * t2[i] + t2[e] * t1[i])
                               + m11 * t2[e] * t2[i])


cdef struct RigidScratch:
    # one thread's: candidates, the blended field, y* - x^c, arcs
    int64_t *cand
    Field *f
    double *v
    double *arcs
    int64_t count


cdef struct RigidOut:
    # the outputs of `closest_points` (C-contiguous), as raw pointers
    double *gap
    double *normal
    double *proximal
    double *hess                 # (m, 9) or NULL
    double *curvature
    int8_t *status
    int8_t *reason
    int64_t *its
    int8_t *outcome
    const double *seeds          # (m, 3) start points, NaN rows: none; or NULL


cdef inline void rigid_row(const Blend *b, const double *x, int64_t r, int64_t cap,
                           RigidScratch *t, const RigidOut *o) noexcept nogil:
    """`closest_points`' work for contactor x (row r), the same from the serial loop and the
    parallel one."""
    cdef const double *seed = NULL
    if o.seeds != NULL and isfinite(o.seeds[3 * r]):
        seed = o.seeds + 3 * r
    cdef int code = closest(b, x, seed, t.cand, cap, t.v, t.f, &o.its[r], &t.count)
    o.outcome[r] = code
    if code == BEYOND or (code == LOST and seed != NULL):
        # beyond every weight's reach (at x^c, or at its faceted foot); or, from the foot, the
        # closest point of S lies past the surface's reach: past the target's edge
        o.status[r] = OUTSIDE
        o.reason[r] = R_OFF_TARGET
    elif code == DONE:
        assemble(b, x, t.v, t.f, t.cand, t.count, t.arcs, &o.gap[r], o.normal + 3 * r,
                 o.proximal + 3 * r, o.hess + 9 * r if o.hess != NULL else NULL,
                 o.curvature + 2 * r, &o.status[r], &o.reason[r])
    elif code != OVERFLOW:
        o.status[r] = FAILED
        o.reason[r] = R_NO_CONVERGENCE


cdef RigidScratch *rigid_scratch(int64_t cap) noexcept nogil:
    """One thread's scratch (NULL: no memory)."""
    cdef RigidScratch *t = <RigidScratch *>malloc(sizeof(RigidScratch))
    if t == NULL:
        return NULL
    t.cand = <int64_t *>malloc(cap * sizeof(int64_t))
    t.f = <Field *>malloc(sizeof(Field))
    t.v = <double *>malloc(3 * sizeof(double))
    t.arcs = <double *>malloc(5 * cap * sizeof(double))
    t.count = 0
    if t.cand == NULL or t.f == NULL or t.v == NULL or t.arcs == NULL:
        rigid_scratch_free(t)
        return NULL
    return t


cdef void rigid_scratch_free(RigidScratch *t) noexcept nogil:
    if t != NULL:
        free(t.arcs)
        free(t.v)
        free(t.f)
        free(t.cand)
        free(t)


def closest_points(dict blend, const double[:, ::1] points, const int64_t[::1] rows,
                   double[::1] gap, double[:, ::1] normal, double[:, ::1] proximal,
                   double[:, ::1] hess, double[:, ::1] curvature, int8_t[::1] status,
                   int8_t[::1] reason, int64_t[::1] its, int8_t[::1] outcome, bint second,
                   int64_t cap, int threads=0, const double[:, ::1] seeds=None):
    """The rigid-target gap of `points[rows]`, written at those rows of the outputs (rows
    left as they were unless answered: the caller fills them with NaN and 'failed'): gap,
    normal, proximal point, ∂²g/∂x^c² (flattened 3x3, when `second`), curvatures, status,
    reason, Newton iterations and the kernel's outcome (DONE ... FAR; OVERFLOW rows are to be
    run again with a larger `cap`). `threads`: OpenMP threads of the loop (0:
    `threads.threads_for`'s; 1: a plain loop, no parallel region). `seeds` (m, 3), optional:
    where a row is finite, that contactor's search starts there (`closest`)."""
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
    cdef int64_t m = rows.shape[0], i
    cdef int e
    cdef RigidScratch *t
    cdef int failed = 0
    cdef int *failedp = &failed
    if m == 0 or pos.shape[0] == 0:
        return
    b.pos = &pos[0, 0]
    b.origin = &origin[0, 0]
    b.axes = &axes[0, 0, 0]
    b.radius = &radius[0]
    b.alpha = &alpha[0, 0]
    b.reach = &reach[0]
    b.spacing = &nspacing[0]
    b.blend.kind = WENDLAND
    b.nt = ea.shape[0]
    if b.nt > NTERMS_MAX:
        raise ValueError(f"a basis of {b.nt} terms: at most {NTERMS_MAX}")
    for e in range(b.nt):
        b.ea[e] = ea[e]
        b.eb[e] = eb[e]
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
    b.outside = blend["outside"]
    b.contact = blend["contact"]
    b.hull = blend["hull"]
    b.sheet = blend["sheet"]
    cdef RigidOut o
    o.gap, o.normal, o.proximal = &gap[0], &normal[0, 0], &proximal[0, 0]
    o.hess = &hess[0, 0] if second else NULL
    o.curvature, o.status, o.reason = &curvature[0, 0], &status[0], &reason[0]
    o.its, o.outcome = &its[0], &outcome[0]
    o.seeds = NULL
    if seeds is not None:
        if seeds.shape[0] != points.shape[0] or seeds.shape[1] != 3:
            raise ValueError("seeds must have the shape of points")
        o.seeds = &seeds[0, 0]
    cdef const double *pts = &points[0, 0]
    cdef const int64_t *rw = &rows[0]
    if second and (hess.shape[0] != points.shape[0] or hess.shape[1] != 9):
        raise ValueError("hess must have shape (m, 9)")
    cdef int chunk
    if threads <= 0:
        threads = threads_for(m, "rigid")
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            t = rigid_scratch(cap)
            if t != NULL:
                for i in range(m):
                    rigid_row(&b, pts + 3 * rw[i], rw[i], cap, t, &o)
                rigid_scratch_free(t)
            else:
                failed = 1
    else:
        chunk = chunk_size(m, threads, 64)
        with nogil, parallel(num_threads=threads):
            t = rigid_scratch(cap)
            if t == NULL:
                failedp[0] = 1
            for i in prange(m, schedule="dynamic", chunksize=chunk):
                if t != NULL:
                    rigid_row(&b, pts + 3 * rw[i], rw[i], cap, t, &o)
            rigid_scratch_free(t)
    if failed:
        raise MemoryError("no memory for the rigid target's scratch")
