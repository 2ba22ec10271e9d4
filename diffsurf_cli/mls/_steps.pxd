# cython: language_level=3
"""The steps of the method every compiled module shares, written once (`cdef inline`): the
basis [14] and its derivatives, the local approximation [13] and its derivatives, and the
on-target hull test; the weight [15] is `_weight.pxd`'s. mls/basis.py holds the bases'
tables; their only second copy is the tests' numpy reference (tests/reference_steps.py)."""
from libc.math cimport hypot, atan2, asin, fmod, M_PI
from libc.stdint cimport int64_t

from ._linalg cimport dmin, dmax


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
