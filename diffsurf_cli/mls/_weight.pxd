# cython: language_level=3
"""The weight functions w(q), q = (ρ/R)², of the weighted least squares [15], declared once
for every compiled module (cimported): their codes, their constants (`WeightParams`, filled by
`weight_params` from diffsurf_cli.tol) and their values and q-derivatives (`cdef inline`).
`_weight.pyx` holds their names in code order (WEIGHTS), which mls/weight.py reads; the only
second copy is the tests' numpy reference (tests/reference_steps.py). A new weight is a code
here, its formulas below and its name (and constants, if any) in `_weight.pyx`."""
from libc.math cimport sqrt, exp

from ._linalg cimport dmax

# weight functions [15], by code (their names: `_weight.WEIGHTS`, in this order)
cdef enum:
    WENDLAND = 0
    GAUSS = 1
    SINGULAR = 2


cdef struct WeightParams:
    int kind                     # WENDLAND, GAUSS or SINGULAR
    double gauss_c2              # the truncated Gaussian's width², in units of R²
    double gauss_tail            # its value at q = 1 (subtracted: w(1) = 0)
    double singular_floor        # floor of q = (ρ/R)² for the singular weight


# the weight of a name and its constants (`_weight.pyx`)
cdef WeightParams weight_params(str name) except *


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
