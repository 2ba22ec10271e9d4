# cython: language_level=3
"""The local frame [§3] of a support, written once (`cdef inline`): its in-plane axis and the
right-handed axes from the normal e3 (mls/frame.py's `in_plane_axis`), and whether more than
a row of nodes fixes it (`frame_fixed`, which lets the reduced bases vary across). The frame's
normal itself is the weighted PCA of the support search (`_support.pxd`)."""
from libc.math cimport sqrt, fabs
from libc.stdint cimport int64_t

from ._projection cimport TargetC, Options, Result


cdef inline void frame_e1(const Options *op, const double *e3, double *out) noexcept nogil:
    """frame.in_plane_axis: a fixed direction projected on the plane normal to e3."""
    cdef const double *g = op.e1_guide
    cdef double dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    cdef double norm = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    cdef int e
    if not (fabs(dot) < 0.9 * norm):
        g = op.e1_guide_alt
    dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    for e in range(3):
        out[e] = g[e] - dot * e3[e]


cdef inline void right_handed(double *e1, const double *e3, double *axes) noexcept nogil:
    """Rows e1 (orthogonalised, unit), e2 = e3 x e1, e3 into axes (3x3)."""
    cdef double dot = e1[0] * e3[0] + e1[1] * e3[1] + e1[2] * e3[2], norm
    cdef int e
    for e in range(3):
        e1[e] -= dot * e3[e]
    norm = sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    for e in range(3):
        axes[e] = e1[e] / norm
        axes[6 + e] = e3[e]
    axes[3] = e3[1] * axes[2] - e3[2] * axes[1]
    axes[4] = e3[2] * axes[0] - e3[0] * axes[2]
    axes[5] = e3[0] * axes[1] - e3[1] * axes[0]


cdef inline bint frame_fixed(const TargetC *tg, const Options *op, const Result *res,
                             const int64_t *nodes, int64_t count) noexcept nogil:
    """Whether more than a row of nodes fixes the frame of res (tol.RULED_SPREAD): the
    whole target for the global frame, else the in-plane spread of the frame's ball (the
    support's `count` nodes), both of its variances."""
    cdef double n = 0.0, m0 = 0.0, m1 = 0.0, c00 = 0.0, c01 = 0.0, c11 = 0.0, x0, x1, d
    cdef double half, root
    cdef int64_t j
    cdef int col
    if tg.global_frame:
        return op.ruled_global
    for j in range(count):
        x0 = 0.0
        x1 = 0.0
        for col in range(3):
            d = tg.nodes[3 * nodes[j] + col] - res.origin[col]
            x0 += res.axes[col] * d
            x1 += res.axes[3 + col] * d
        n += 1.0
        m0 += x0
        m1 += x1
        c00 += x0 * x0
        c01 += x0 * x1
        c11 += x1 * x1
    if count < 3:
        return False
    c00 -= m0 * m0 / n
    c01 -= m0 * m1 / n
    c11 -= m1 * m1 / n
    half = 0.5 * (c00 + c11)
    root = sqrt(0.25 * (c00 - c11) * (c00 - c11) + c01 * c01)
    return half - root >= op.ruled_spread * (half + root) and half + root > 0
