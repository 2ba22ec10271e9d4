# cython: language_level=3
"""The proximal point [30] on the local approximation [13], written once (`cdef inline`):
Newton on the squared distance in the support's scaled frame, the projection's step between
the fit (`_fit.pxd`) and the normal [29] and gap [32]."""
from libc.math cimport sqrt, hypot, isfinite, INFINITY
from libc.stdint cimport int64_t

from ._steps cimport surface_derivatives
from ._projection cimport Options


cdef inline int64_t newton(const Options *op, const double *alpha, const double *c, double *f,
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
