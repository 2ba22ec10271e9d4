# cython: language_level=3
"""The steps of the method every compiled module shares, written once (`cdef inline`): the
weight [15] and its derivatives, the basis [14] and its derivatives, the local approximation
[13] and its derivatives, and the on-target hull test. mls/weight.py and mls/basis.py hold
their names and tables; their only second copy is the tests' numpy reference
(tests/reference_steps.py)."""
from libc.math cimport sqrt, exp, hypot, atan2, asin, fmod, M_PI
from libc.stdint cimport int64_t

from ._linalg cimport dmin, dmax

# weight functions [15] (weight.WEIGHTS, in that order)
cdef enum:
    WENDLAND = 0
    GAUSS = 1
    SINGULAR = 2


cdef struct WeightParams:
    int kind                     # WENDLAND, GAUSS or SINGULAR
    double gauss_c2              # the truncated Gaussian's width², in units of R²
    double gauss_tail            # its value at q = 1 (subtracted: w(1) = 0)
    double singular_floor        # floor of q = (ρ/R)² for the singular weight


cdef inline double weight_value(int kind, double q, const WeightParams *wp) noexcept nogil:
    """w(q), q = (ρ/R)² [15], of weight `kind` (0 outside the domain of influence)."""
    if q >= 1.0:
        return 0.0
    if kind == GAUSS:
        return (exp(-q / wp.gauss_c2) - wp.gauss_tail) / (1.0 - wp.gauss_tail)
    cdef double r = sqrt(q)
    cdef double u = 1.0 - r
    cdef double w = u * u * u * u * (4.0 * r + 1.0)
    if kind == SINGULAR:
        return w / dmax(q, wp.singular_floor)
    return w


cdef inline void weight_derivatives(const WeightParams *wp, double q,
                                    double *out) noexcept nogil:
    """w, dw/dq, d²w/dq² at q (weight.py's evaluate(kind, q, 2)); w is `weight_value`'s."""
    cdef double e, w0, w1, w2, r, u
    out[0] = weight_value(wp.kind, q, wp)
    if not (q < 1.0):
        out[1] = 0.0
        out[2] = 0.0
        return
    if wp.kind == GAUSS:
        e = exp(-q / wp.gauss_c2) / (1.0 - wp.gauss_tail)
        out[1] = -e / wp.gauss_c2
        out[2] = e / (wp.gauss_c2 * wp.gauss_c2)
        return
    # Wendland's C2 function of q and its q-derivatives; 15 (1-r)²/r is unbounded at r = 0
    # but always multiplies (∂q)² = O(r²): its limit there is 0
    r = sqrt(q)
    u = 1.0 - r
    w1 = -10.0 * u * u * u
    w2 = 15.0 * u * u / r if r > 0.0 else 0.0
    if wp.kind != SINGULAR:
        out[1] = w1
        out[2] = w2
    elif q > wp.singular_floor:  # w / q; floored below: the weight is held constant there
        w0 = u * u * u * u * (4.0 * r + 1.0)
        out[1] = w1 / q - w0 / (q * q)
        out[2] = w2 / q - 2.0 * w1 / (q * q) + 2.0 * w0 / (q * q * q)
    else:
        out[1] = 0.0
        out[2] = 0.0


cdef inline void basis_derivatives(int k, const int *ea, const int *eb, double s, double t,
                                   double *out) noexcept nogil:
    """The basis [14] p_j = s^ea[j] t^eb[j] (k terms) and its derivatives at (s, t):
    p, p,s, p,t, p,ss, p,st, p,tt into out[d k + j] (d in that order)."""
    cdef int j, a, b
    cdef double sp[4]
    cdef double tp[4]
    sp[0] = 1.0
    tp[0] = 1.0
    for j in range(1, 4):
        sp[j] = sp[j - 1] * s
        tp[j] = tp[j - 1] * t
    for j in range(k):
        a = ea[j]
        b = eb[j]
        out[j] = sp[a] * tp[b]
        out[k + j] = a * sp[a - 1] * tp[b] if a >= 1 else 0.0
        out[2 * k + j] = b * sp[a] * tp[b - 1] if b >= 1 else 0.0
        out[3 * k + j] = a * (a - 1) * sp[a - 2] * tp[b] if a >= 2 else 0.0
        out[4 * k + j] = a * b * sp[a - 1] * tp[b - 1] if (a >= 1 and b >= 1) else 0.0
        out[5 * k + j] = b * (b - 1) * sp[a] * tp[b - 2] if b >= 2 else 0.0


cdef inline double py_mod(double x, double y) noexcept nogil:
    """Python's float x % y: the remainder has the sign of y."""
    cdef double mod = fmod(x, y)
    if mod != 0.0:
        if (y < 0) != (mod < 0):
            mod += y
    else:
        mod = -0.0 if y < 0.0 else 0.0
    return mod


cdef inline void surface_derivatives(int n, const int *ea, const int *eb, const double *alpha,
                                     double s, double t, double *out) noexcept nogil:
    """f, f,s, f,t, f,ss, f,st, f,tt of the local approximation [13] p(s, t)ᵀα at (s, t) into
    out[6]; the n terms s^ea t^eb in basis.EXPONENTS order (the quadratic written out)."""
    cdef int d, j, a, b
    cdef double sa, tb, sa1, tb1, sa2, tb2
    cdef double sp[4]
    cdef double tp[4]
    if n == 6:  # the quadratic basis written out (the same products and sums)
        out[0] = (alpha[0] + alpha[1] * s + alpha[2] * t + alpha[3] * (s * s)
                  + alpha[4] * s * t + alpha[5] * (t * t))
        out[1] = alpha[1] + alpha[3] * (2.0 * s) + alpha[4] * t
        out[2] = alpha[2] + alpha[4] * s + alpha[5] * (2.0 * t)
        out[3] = alpha[3] * 2.0
        out[4] = alpha[4]
        out[5] = alpha[5] * 2.0
        return
    sp[0] = 1.0
    tp[0] = 1.0
    for d in range(1, 4):
        sp[d] = sp[d - 1] * s
        tp[d] = tp[d - 1] * t
    for d in range(6):
        out[d] = 0.0
    for j in range(n):
        a = ea[j]
        b = eb[j]
        sa = sp[a]
        tb = tp[b]
        sa1 = a * sp[a - 1] if a >= 1 else 0.0
        tb1 = b * tp[b - 1] if b >= 1 else 0.0
        sa2 = a * (a - 1) * sp[a - 2] if a >= 2 else 0.0
        tb2 = b * (b - 1) * tp[b - 2] if b >= 2 else 0.0
        out[0] += alpha[j] * sa * tb
        out[1] += alpha[j] * sa1 * tb
        out[2] += alpha[j] * sa * tb1
        out[3] += alpha[j] * sa2 * tb
        out[4] += alpha[j] * sa1 * tb1
        out[5] += alpha[j] * sa * tb2


cdef inline bint beyond_hull(const double *s, const double *t, const double *w, int64_t count,
                             double s0, double t0, double slack, double *start,
                             double *end) noexcept nogil:
    """Whether (s0, t0) is farther than `slack` from the in-plane convex hull of the support
    nodes with w > 0: iff the arcs of directions the discs of radius `slack` around the nodes
    cover leave a free arc of at least π (arcs swept in order of their start angle)."""
    cdef int quadrants = 0
    cdef int64_t j, live = 0, pos
    cdef double ds, dt, r, half, a, two_pi = 2.0 * M_PI, wrapped, free_arc
    # quick accept: a live node in each open quadrant around the point puts it inside the hull
    # (done as soon as the fourth is seen)
    for j in range(count):
        if w[j] > 0:
            ds = s[j] - s0
            dt = t[j] - t0
            if ds > 0 and dt > 0:
                quadrants |= 1
            elif ds < 0 and dt > 0:
                quadrants |= 2
            elif ds < 0 and dt < 0:
                quadrants |= 4
            elif ds > 0 and dt < 0:
                quadrants |= 8
            if quadrants == 15:
                return False
    for j in range(count):
        if w[j] <= 0:
            continue
        ds = s[j] - s0
        dt = t[j] - t0
        r = hypot(ds, dt)
        if r <= slack:
            return False  # within the slack of a node
        half = asin(dmin(slack / r, 1.0))
        a = py_mod(atan2(dt, ds) - half, two_pi)
        pos = live
        while pos > 0 and start[pos - 1] > a:
            start[pos] = start[pos - 1]
            end[pos] = end[pos - 1]
            pos -= 1
        start[pos] = a
        end[pos] = a + 2.0 * half
        live += 1
    if live == 0:
        return False
    for j in range(1, live):
        end[j] = dmax(end[j], end[j - 1])  # the farthest end so far
    wrapped = end[live - 1] - two_pi
    free_arc = start[0] - wrapped
    for j in range(1, live):
        free_arc = dmax(free_arc, start[j] - dmax(end[j - 1], wrapped))
    return free_arc >= M_PI
