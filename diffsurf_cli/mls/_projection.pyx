# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The projection's pass and its Python face: `Target`, the target as the compiled projection
sees it (node arrays and their grids, built once), projecting whole clouds in one parallel
loop (OpenMP `prange`, per-thread scratch allocated once per call). One contactor is
`project_one` (select, solve, retry, re-centre, bad points), composed of the steps written
once in the files of their subjects (`_projection.pxd` lists them): the support and frame
(`_support.pxd`, `_frame.pxd`), the fit (`_fit.pxd`), Newton (`_newton.pxd`), then here the
normal [29], gap [32], status [33] and the on-target tests. Linear algebra is textbook (Golub
& Van Loan): the normal equations [16]-[17] by Cholesky where the fit is well conditioned
(the equilibrated Gram's R is then QR's, `normal_fit`), else Householder QR of W^½P, the 3x3
frame's normal by powers of the covariance's adjugate (a cyclic Jacobi where its eigenvalues
are too close for them), one-sided Jacobi for the exact σmin/σmax where the cheap bound
cannot decide (`triangular_rcond`). Instructions a point: `benchmarks/engine_speed.py
--callgrind`.

Tolerances and constants are read from `diffsurf_cli.tol` into the `Options` struct at call
time; nothing here is a hand-kept copy of a Python value.
"""
import numpy as np

from libc.math cimport sqrt, fabs, isfinite, isnan, cos, sin, INFINITY, NAN
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t, int8_t, uint8_t, uint64_t
from cython.parallel cimport prange, parallel

from .. import tol
from ..threads import chunk_size, threads_for
from . import basis as _basis
from ._search import build_grid
from .._codes cimport (OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED, R_OK, R_BAD_POINT,
                       R_FEW_NODES, R_ILL, R_OFF_TARGET, R_NO_CONVERGENCE, R_NOT_SETTLED,
                       R_STEEP)
from ._linalg cimport NTERMS_MAX, dmin, dmax, imax, row_stride
from ._search cimport Grid, cell_index, spread_bits
from ._weight cimport WENDLAND, SINGULAR, weight_value, weight_params
from ._steps cimport surface_derivatives, beyond_hull
from ._support cimport local_spacing, select_support
from ._frame cimport frame_fixed
from ._fit cimport fit, fit_reduced
from ._newton cimport newton

MAX_TERMS = NTERMS_MAX


cdef Scratch *scratch_new(int64_t cap, int nterms, int64_t near) noexcept nogil:
    cdef int64_t rows = imax(cap, nterms)
    cdef size_t doubles = <size_t>(8 * cap + near + rows * row_stride(nterms)
                                   + 2 * nterms * nterms + 3 * nterms)
    cdef size_t ints = <size_t>(4 * cap + near)
    cdef Scratch *sc = <Scratch *>malloc(sizeof(Scratch))
    if sc == NULL:
        return NULL
    cdef char *mem = <char *>malloc(doubles * sizeof(double) + ints * sizeof(int64_t))
    if mem == NULL:
        free(sc)
        return NULL
    sc.mem = mem
    sc.cap = cap
    cdef double *d = <double *>mem
    sc.cand_d2 = d
    d += cap
    sc.s = d
    d += cap
    sc.t = d
    d += cap
    sc.z = d
    d += cap
    sc.w = d
    d += cap
    sc.geo = d
    d += cap
    sc.arc_start = d
    d += cap
    sc.arc_end = d
    d += cap
    sc.near_d2 = d
    d += near
    sc.a = d
    d += rows * row_stride(nterms)
    sc.rfac = d
    d += nterms * nterms
    sc.work = d
    d += nterms * nterms
    sc.sig = d
    d += nterms
    sc.scale = d
    d += nterms
    sc.alpha = d
    d += nterms
    cdef int64_t *ip = <int64_t *>d
    sc.cand_i = ip
    ip += cap
    sc.near_i = ip
    ip += near
    sc.live_i = ip
    ip += cap
    sc.res[0].index = ip
    ip += cap
    sc.res[1].index = ip
    sc.h_min = 0.0
    return sc


cdef void scratch_free(Scratch *sc) noexcept nogil:
    if sc != NULL:
        free(sc.mem)
        free(sc)


cdef void blank(Result *res) noexcept nogil:
    """NaN out the geometry of a row without a trustworthy answer."""
    res.gap = NAN
    cdef int e
    for e in range(3):
        res.normal[e] = NAN
        res.proximal[e] = NAN
    res.curvature[0] = NAN
    res.curvature[1] = NAN


cdef inline int64_t first_positions(const TargetC *tg, int64_t *cand_i,
                                    int64_t count) noexcept nogil:
    """The support cand_i[:count] with each position once, as its first occurrence (a target
    with duplicate nodes); returns its count."""
    cdef int64_t j, jj, node, kept = 0
    cdef bint seen
    for j in range(count):
        node = tg.first[cand_i[j]]
        seen = False
        for jj in range(kept):
            if cand_i[jj] == node:
                seen = True
                break
        if not seen:
            cand_i[kept] = node
            kept += 1
    return kept


cdef inline int64_t weigh_support(const TargetC *tg, const Options *op, Result *res,
                                  int64_t count, double c0, double c1, Scratch *sc,
                                  int64_t *positive) noexcept nogil:
    """The support nodes cand_i[:count] inside the domain of influence (q < 1), in support
    order, the only ones with a weight [15]: their scaled coordinates s, t (centred at
    (c0, c1) [14]) and z, their weights w (and the smooth geo with the singular weight) and
    their nodes live_i; returns how many (`live`), those of positive weight into `positive`.
    Every later step reads those alone."""
    cdef const double *axes = res.axes
    cdef const double *ref = res.origin
    cdef double inv_r = 1.0 / res.R, X0, X1, X2, q
    cdef int64_t j, node, live = 0
    # (the frame's axes divided by R, in scalars: read once, where through res they would be
    # reloaded a node)
    cdef double r0 = ref[0], r1 = ref[1], r2 = ref[2], d0, d1, d2
    cdef double a00 = axes[0] * inv_r, a01 = axes[1] * inv_r, a02 = axes[2] * inv_r
    cdef double a10 = axes[3] * inv_r, a11 = axes[4] * inv_r, a12 = axes[5] * inv_r
    cdef double a20 = axes[6] * inv_r, a21 = axes[7] * inv_r, a22 = axes[8] * inv_r
    cdef const double *xn
    cdef double *s = sc.s
    cdef double *t = sc.t
    cdef double *w = sc.w
    for j in range(count):
        node = sc.cand_i[j]
        xn = tg.nodes + 3 * node
        d0 = xn[0] - r0
        d1 = xn[1] - r1
        d2 = xn[2] - r2
        X0 = (a00 * d0 + a01 * d1) + a02 * d2 - c0
        X1 = (a10 * d0 + a11 * d1) + a12 * d2 - c1
        q = X0 * X0 + X1 * X1
        if q >= 1.0:  # outside the domain of influence
            continue
        X2 = (a20 * d0 + a21 * d1) + a22 * d2
        s[live] = X0
        t[live] = X1
        sc.z[live] = X2
        sc.live_i[live] = node
        w[live] = weight_value(op.wp.kind, q, &op.wp)  # [15]
        if op.wp.kind == SINGULAR:
            sc.geo[live] = weight_value(WENDLAND, q, &op.wp)
        if w[live] > 0:
            positive[0] += 1
        live += 1
    return live


cdef inline bint off_target(const Options *op, const Scratch *sc, int64_t live, int terms,
                            double direction, const double *st, double R,
                            double h) noexcept nogil:
    """Whether the proximal point st (scaled, in the frame) is off the target: farther than
    outside_spacings from every support node of positive weight (along a strip or a row, for a
    reduced basis with a direction: across, the hull bounds it, and elements may be much wider
    than long), outside the domain of influence, or farther than hull_spacings from the
    in-plane convex hull of the support (past an open edge, where the fit only
    extrapolates)."""
    cdef const double *s = sc.s
    cdef const double *t = sc.t
    cdef const double *w = sc.w
    cdef double d2min = INFINITY, d, ca, sa
    cdef int64_t j
    if 0 < terms < op.nterms and isfinite(direction):
        ca = cos(direction)
        sa = sin(direction)
        for j in range(live):
            if w[j] > 0:
                d = ca * (s[j] - st[0]) + sa * (t[j] - st[1])
                d2min = dmin(d2min, d * d)
    else:
        for j in range(live):
            if w[j] > 0:
                d2min = dmin(d2min, (s[j] - st[0]) * (s[j] - st[0])
                             + (t[j] - st[1]) * (t[j] - st[1]))
    return (sqrt(d2min) * R > op.outside_spacings * h or st[0] * st[0] + st[1] * st[1] > 1.0
            or beyond_hull(s, t, w, live, st[0], st[1], op.hull_spacings * h / R,
                           sc.arc_start, sc.arc_end))


cdef inline bint steep_support(const TargetC *tg, const Options *op, const Scratch *sc,
                               int64_t live, const double *axes) noexcept nogil:
    """Whether a support node of positive weight is where the target turns vertical or folds
    over the frame (normal e3 = axes[6:9])."""
    cdef const double *fn
    cdef double facing
    cdef int64_t j, node
    for j in range(live):
        if sc.w[j] <= 0:
            continue
        node = sc.live_i[j]
        fn = tg.fold_normals + 3 * node
        facing = fn[0] * axes[6] + fn[1] * axes[7] + fn[2] * axes[8]
        if not tg.is_signed[node]:
            facing = fabs(facing)
        if facing < op.cos_fold or tg.steep[node]:
            return True
    return False


cdef inline void principal_curvatures(const double *f, double R, Result *res) noexcept nogil:
    """The principal curvatures at the proximal point (f, f,s, f,t, f,ss, f,st, f,tt there):
    the eigenvalues of the shape operator I⁻¹ II, divided by R, into res.curvature."""
    cdef double fs = f[1], ft = f[2], E, F, G, root, L, M, N, det, mean, gauss, disc
    E = 1 + fs * fs
    F = fs * ft
    G = 1 + ft * ft
    root = sqrt(1 + fs * fs + ft * ft)
    L = -f[3] / root
    M = -f[4] / root
    N = -f[5] / root
    det = E * G - F * F
    mean = (E * N + G * L - 2 * F * M) / (2 * det)
    gauss = (L * N - M * M) / det
    disc = sqrt(dmax(mean * mean - gauss, 0.0))
    res.curvature[0] = (mean + disc) / R
    res.curvature[1] = (mean - disc) / R


cdef void solve(const TargetC *tg, const Options *op, const double *x, bint centred,
                int64_t count, Scratch *sc, Result *res, bint frozen) noexcept nogil:
    """Fit and project x with the pairing in res (origin, axes, R, h) and the support
    cand_i[:count]: DiffuseSurface's `_solve` for one contactor. The basis and the weights
    are centred at the contactor's in-plane position [14], [15] (`centred`), as the paper
    does, or at the origin (the previous proximal point, when re-centring). `frozen`: res
    holds the reduced basis and direction of a frozen pairing (res.reduced >= 0: fit that)."""
    cdef const double *axes = res.axes
    cdef const double *ref = res.origin
    cdef double R = res.R, h = res.h
    cdef double c[3]
    cdef double f[6]
    cdef double st[2]
    cdef double c0, c1, rc, nrm, nu0, nu1, nu2, g
    cdef int64_t j, its, live, positive = 0
    cdef int e, col, code, why, terms, which = -1
    cdef bint ok
    cdef double direction = NAN
    if tg.duplicates:  # each position once, as its first occurrence
        count = first_positions(tg, sc.cand_i, count)
    for e in range(3):
        c[e] = 0.0
        for col in range(3):
            c[e] += axes[3 * e + col] * (x[col] - ref[col])
        c[e] /= R
    c0 = c[0] if centred else 0.0
    c1 = c[1] if centred else 0.0
    live = weigh_support(tg, op, res, count, c0, c1, sc, &positive)
    rc = fit(op, sc, live)
    terms = op.nterms
    if frozen and res.reduced >= 0:  # the pairing's reduced basis, at its direction
        which = res.reduced
        direction = res.direction
        terms = fit_reduced(op, sc, live, positive, True, &direction, &which)
    elif not (rc >= op.rcond_min) or positive < op.nterms:
        # the support cannot determine the full basis: the terms it can (a strip, a row)
        terms = fit_reduced(op, sc, live, positive, frame_fixed(tg, op, res, sc.cand_i, count),
                            &direction, &which)
    c[0] -= c0
    c[1] -= c1
    its = newton(op, sc.alpha, c, f, st, &ok)
    surface_derivatives(op.nterms, op.ea, op.eb, sc.alpha, st[0], st[1], f)
    # [29]: ν = (-f,1, -f,2, 1)/‖·‖ in the frame (the scaling by R cancels in the slopes)
    nrm = sqrt(f[1] * f[1] + f[2] * f[2] + 1.0)
    nu0 = -f[1] / nrm
    nu1 = -f[2] / nrm
    nu2 = 1.0 / nrm
    g = 0.0
    for col in range(3):
        res.normal[col] = axes[col] * nu0 + axes[3 + col] * nu1 + axes[6 + col] * nu2
        res.proximal[col] = ref[col] + R * (axes[col] * (st[0] + c0)
                                            + axes[3 + col] * (st[1] + c1)
                                            + axes[6 + col] * f[0])
        g += (x[col] - res.proximal[col]) * res.normal[col]
    res.gap = g  # [32]
    code = OPEN if g > 0 else PENETRATION  # [33]
    if fabs(g) <= op.contact_tol * h:
        code = CONTACT
    why = R_OK
    # the proximal point must lie on the target: near a support node, inside the domain of
    # influence, and within hull_spacings of the in-plane convex hull of the support
    if off_target(op, sc, live, terms, direction, st, R, h):
        code = OUTSIDE
        why = R_OFF_TARGET
    if not ok:
        code = FAILED
        why = R_NO_CONVERGENCE
    # too few nodes, or nodes that cannot determine the basis (collinear, as past an open edge),
    # nor even a line of it
    if terms == 0:
        if not (rc >= op.rcond_min):
            code = OUTSIDE
            why = R_ILL
        if positive < op.nterms:
            code = OUTSIDE
            why = R_FEW_NODES
    # a support reaching where the target turns vertical or folds over the frame: the root
    # cause of whatever else went wrong
    if steep_support(tg, op, sc, live, axes):
        code = OUTSIDE
        why = R_STEEP
    res.status = <int8_t>code
    res.reason = <int8_t>why
    res.support = positive
    res.iterations = its
    res.rcond = rc
    res.terms = <int8_t>terms
    res.reduced = <int8_t>which
    res.direction = direction if which >= 0 else NAN
    principal_curvatures(f, R, res)
    if code >= OUTSIDE:
        blank(res)
    if op.keep:
        res.count = count
        for j in range(count):
            res.index[j] = tg.perm[sc.cand_i[j]]
        for e in range(op.nterms):  # the fit [17], in the full basis (NaN: none)
            res.alpha[e] = sc.alpha[e]


cdef void select_solve(const TargetC *tg, const Options *op, const double *x,
                       const double *ref, bint centred, int attempt, Scratch *sc,
                       Result *res, double h) noexcept nogil:
    """Support and frame around `ref`, then the fit and projection of x. `h`: the local
    spacing at ref when known (sc.nbar and sc.foot then still hold ref's: the retry), else NaN
    (its nearest nodes' spacing, at least sc.h_min: the size of the facets there, where the
    caller knows it)."""
    cdef int e
    res.overflow = False
    res.count = 0
    res.h = h if not isnan(h) else dmax(local_spacing(tg, op, ref, sc), sc.h_min)
    for e in range(3):
        res.origin[e] = ref[e]
    cdef int64_t count = select_support(tg, op, ref, attempt, sc, res)
    solve(tg, op, x, centred, count, sc, res, False)


cdef inline bint thin_or_off(const Result *res) noexcept nogil:
    return res.reason == R_FEW_NODES or res.reason == R_ILL or res.reason == R_OFF_TARGET


cdef void flag_bad_point(Result *res) noexcept nogil:
    """A contactor with NaN or inf: 'failed' (bad-point), no support, no iterations, no
    condition number, NaN geometry (its pairing is that of a harmless stand-in)."""
    res.status = FAILED
    res.reason = R_BAD_POINT
    res.support = 0
    res.iterations = 0
    res.rcond = NAN
    res.terms = 0
    res.reduced = -1
    res.direction = NAN
    blank(res)


cdef Result *project_one(const TargetC *tg, const Options *op, const double *x,
                         Scratch *sc) noexcept nogil:
    """One contactor, from its support to its status: DiffuseSurface.project's rules."""
    cdef Result *a = &sc.res[0]
    cdef Result *b = &sc.res[1]
    cdef Result *tmp
    cdef bint finite = isfinite(x[0]) and isfinite(x[1]) and isfinite(x[2]), live, stalled
    cdef const double *xs = x if finite else tg.frame_origin
    cdef bint overflow
    cdef int64_t its
    cdef int _it, e
    cdef double move, previous, dd
    select_solve(tg, op, xs, xs, True, 0, sc, a, NAN)
    overflow = a.overflow
    # a support too thin for the basis (an open edge or corner, a coarse mesh), or one so
    # one-sided that the fit carries the proximal point off the target, is tried once more
    # with a wider support; the retry is kept only where it is on the target, and where the
    # first was on the target with a reduced basis, only where it fits the full basis (a wider
    # support with more reduced terms was measured worse than a narrow one: a row's)
    if finite and (thin_or_off(a) or a.terms < op.nterms):
        select_solve(tg, op, xs, xs, True, 1, sc, b, a.h)  # (the same reference point)
        overflow = overflow or b.overflow
        if b.status <= PENETRATION and (a.status > PENETRATION or b.terms == op.nterms):
            tmp = a
            a = b
            b = tmp
    if not finite:
        flag_bad_point(a)
    if op.recentre and a.status <= PENETRATION:
        # re-centre the fit on the proximal point until it stops moving: the fixed point is
        # the projection onto S_g^d itself rather than onto the contactor's own local fit
        its = a.iterations
        live = True
        previous = INFINITY
        for _it in range(op.recentre_max_iter):
            select_solve(tg, op, x, a.proximal, False, 0, sc, b, NAN)
            overflow = overflow or b.overflow
            move = 0.0
            for e in range(3):
                dd = b.proximal[e] - a.proximal[e]
                move += dd * dd
            move = sqrt(move)
            its += b.iterations
            tmp = a
            a = b
            b = tmp
            stalled = move >= 0.5 * previous and move < op.recentre_stall * a.h
            previous = move
            if not (move > op.recentre_step * a.h) or stalled:  # NaN (failed) counts as done
                live = False
                break
        if live:
            a.status = FAILED
            a.reason = R_NOT_SETTLED
            blank(a)
        a.iterations = its
    a.overflow = overflow
    return a


cdef inline void store(const Result *res, Py_ssize_t r, const Record *o) noexcept nogil:
    """One contactor's Projection fields into row r of a pass's record (`record_of`)."""
    cdef int e
    o.gap[r] = res.gap
    for e in range(3):
        o.normal[3 * r + e] = res.normal[e]
        o.proximal[3 * r + e] = res.proximal[e]
    o.status[r] = res.status
    o.reason[r] = res.reason
    o.support[r] = res.support
    o.iterations[r] = res.iterations
    o.rcond[r] = res.rcond
    o.curvature[2 * r] = res.curvature[0]
    o.curvature[2 * r + 1] = res.curvature[1]
    o.terms[r] = res.terms


cdef int record_of(dict out, Py_ssize_t m, Record *o) except -1:
    """Point the record o at the arrays of `out` (`projection.allocate`: `RECORD`'s names),
    each checked: its dtype and C order (the typed views refuse others) and m rows of its
    shape. The arrays must outlive the record's use (the caller holds `out`)."""
    cdef double[::1] gap = _named(out, "gap")
    cdef double[:, ::1] normal = _named(out, "normal")
    cdef double[:, ::1] proximal = _named(out, "proximal_point")
    cdef int8_t[::1] status = _named(out, "status")
    cdef int8_t[::1] reason = _named(out, "reason")
    cdef int64_t[::1] support = _named(out, "support")
    cdef int64_t[::1] iterations = _named(out, "iterations")
    cdef double[::1] rcond = _named(out, "rcond")
    cdef double[:, ::1] curvature = _named(out, "curvature")
    cdef int8_t[::1] terms = _named(out, "terms")
    cdef uint8_t[::1] overflow = _named(out, "overflow")
    _rows(m, gap=gap, normal=normal, proximal_point=proximal, status=status, reason=reason,
          support=support, iterations=iterations, rcond=rcond, curvature=curvature,
          terms=terms, overflow=overflow)
    if normal.shape[1] != 3 or proximal.shape[1] != 3 or curvature.shape[1] != 2:
        raise ValueError("normal and proximal_point must have 3 columns, curvature 2")
    if m == 0:
        return 0
    o.gap, o.normal, o.proximal = &gap[0], &normal[0, 0], &proximal[0, 0]
    o.status, o.reason, o.support, o.iterations = &status[0], &reason[0], &support[0], \
        &iterations[0]
    o.rcond, o.curvature, o.terms, o.overflow = &rcond[0], &curvature[0, 0], &terms[0], \
        &overflow[0]
    return 0


def _named(dict out, str name):
    """The array `name` of a pass's outputs, or a one-line error naming it."""
    try:
        return out[name]
    except KeyError:
        raise ValueError(f"the pass's outputs lack '{name}' (projection.allocate)") from None


def _rows(Py_ssize_t m, **arrays):
    """Each of `arrays` (typed views) has m rows, or a one-line error naming it."""
    for name, arr in arrays.items():
        if arr.shape[0] != m:
            raise ValueError(f"output {name} of shape {tuple(arr.shape)}: expected {m} rows")


cdef struct ProjectOut:
    # the outputs of `Target.project` (C-contiguous), as raw pointers: the record every
    # pass writes, and the pairing (`projection.PAIRING_RECORD`)
    Record rec
    double *origin
    double *axes
    double *radius
    double *spacing
    double *direction
    int8_t *reduced
    int64_t *index               # (m, width): row i gets rows[i]'s support
    int64_t *count               # (points,): how many of index's row are written
    int64_t width
    double *alpha                # (points, alpha_width) or NULL
    int64_t alpha_width
    const double *h_min          # (points,) the local spacing's floor of each, or NULL: none


cdef inline void project_row(const TargetC *tg, const Options *op, const double *points,
                             int64_t r, Py_ssize_t i, Scratch *sc,
                             const ProjectOut *o) noexcept nogil:
    """`Target.project`'s work for one contactor (row r of the points, i of the batch), the
    same from the serial loop and the parallel one."""
    cdef Result *res
    sc.h_min = o.h_min[r] if o.h_min != NULL else 0.0
    res = project_one(tg, op, points + 3 * r, sc)
    cdef int e
    cdef int64_t j
    store(res, r, &o.rec)
    for e in range(3):
        o.origin[3 * r + e] = res.origin[e]
    for e in range(9):
        o.axes[9 * r + e] = res.axes[e]
    o.radius[r] = res.R
    o.spacing[r] = res.h
    o.direction[r] = res.direction
    o.reduced[r] = res.reduced
    o.rec.overflow[r] = res.overflow
    if o.width > 0:  # the support only: the caller pads (wider rows, written, cost time)
        o.count[r] = res.count
        for j in range(min(res.count, o.width)):
            o.index[i * o.width + j] = res.index[j]
        if o.alpha != NULL:
            for j in range(op.nterms):
                o.alpha[r * o.alpha_width + j] = (res.alpha[j] if res.status <= PENETRATION
                                                  else NAN)


cdef struct FrozenIn:
    # the frozen pairing of `Target.project_with` (C-contiguous), as raw pointers
    const double *points
    const double *origin
    const double *axes
    const double *radius
    const double *spacing
    const int64_t *index         # (m, K), -1 holes
    int64_t K
    const int8_t *frozen_reduced     # NULL: not frozen
    const double *frozen_direction


cdef inline void project_with_row(const TargetC *tg, const Options *op, Py_ssize_t i,
                                  const FrozenIn *f, Scratch *sc,
                                  const ProjectOut *o) noexcept nogil:
    """`Target.project_with`'s work for contactor i, the same from the serial loop and the
    parallel one."""
    cdef Result *res = &sc.res[0]
    cdef int64_t j, count = 0, node
    cdef int e
    cdef const double *x = f.points + 3 * i
    cdef bint finite
    for j in range(f.K):
        node = f.index[i * f.K + j]
        if node >= 0:
            sc.cand_i[count] = tg.inv[node]
            count = count + 1
    for e in range(3):
        res.origin[e] = f.origin[3 * i + e]
    for e in range(9):
        res.axes[e] = f.axes[9 * i + e]
    res.R = f.radius[i]
    res.h = f.spacing[i]
    finite = isfinite(x[0]) and isfinite(x[1]) and isfinite(x[2])
    if f.frozen_reduced != NULL:
        res.reduced = f.frozen_reduced[i]
        res.direction = f.frozen_direction[i]
    solve(tg, op, x if finite else f.origin + 3 * i, True, count, sc, res,
          f.frozen_reduced != NULL)
    if not finite:
        flag_bad_point(res)
    store(res, i, &o.rec)
    o.direction[i] = res.direction
    o.reduced[i] = res.reduced


cdef class Target:
    """The target as the engine sees it: node arrays and their grids, built once.

    Parameters
    ----------
    nodes, normals, fold_normals : (n, 3) float
    node_spacing : (n,) float
    first : (n,) int       first node at the same position (duplicates merged)
    signed, steep : (n,) bool
    origin : (3,) float, axes : (3, 3) float   the global frame (rows e1, e2, e3)
    has_faces, global_frame : bool
    cell : float           grid cell size
    """

    def __init__(self, nodes, normals, node_spacing, first, fold_normals, is_signed, steep,
                 origin, axes, bint has_faces, bint global_frame, double cell):
        cdef int e
        nodes = np.ascontiguousarray(nodes, dtype=np.float64)
        n = nodes.shape[0]
        if nodes.ndim != 2 or nodes.shape[1] != 3 or n == 0:
            raise ValueError(f"nodes must have shape (n, 3), n > 0, got {nodes.shape}")
        # the nodes renumbered in the order of their grid cells, so that the nodes of a cell,
        # and of neighbouring cells, are neighbours in memory (a search then reads few cache
        # lines); `perm` maps the engine's numbers to the caller's, `inv` back
        lo, grid_cell, dims, start, perm = build_grid(nodes, cell)
        inv = np.empty(n, dtype=np.int64)
        inv[perm] = np.arange(n)
        self.perm = perm
        self.inv = inv
        self.nodes = np.ascontiguousarray(nodes[perm])
        self.normals = _checked(normals, np.float64, (n, 3))[perm]
        self.node_spacing = _checked(node_spacing, np.float64, (n,))[perm]
        self.first = inv[_checked(first, np.int64, (n,))[perm]]
        # a target with facets folds on its own normals (`DiffuseSurface.fold_normals` is
        # its normals): one renumbered copy of them
        self.fold_normals = (self.normals if fold_normals is normals
                             else _checked(fold_normals, np.float64, (n, 3))[perm])
        self.signed_ = _checked(is_signed, np.bool_, (n,)).view(np.uint8)[perm]
        self.steep = _checked(steep, np.bool_, (n,)).view(np.uint8)[perm]
        origin = _checked(origin, np.float64, (3,))
        axes = _checked(axes, np.float64, (3, 3)).ravel()
        # the grid of the renumbered nodes is the one just built, with its nodes in order
        # (their cells' counts the same, a stable sort of sorted cells the identity), where
        # its box does not depend on the nodes' order: no bound is zero (where one is, which
        # of -0.0 and 0.0 `build_grid` keeps may), so it is not built twice (issue 36)
        hi = [nodes[:, e].max() for e in range(3)]
        if all(lo[e] != 0 and hi[e] != 0 for e in range(3)):
            tables = (lo, grid_cell, dims, start, np.arange(n, dtype=np.int64))
        else:
            tables = None
        self.grid = GridArrays(self.nodes, cell, tree=True, tables=tables)
        if global_frame:
            plane = np.zeros((n, 3))
            plane[:, :2] = (np.asarray(self.nodes) - origin) @ axes.reshape(3, 3)[:2].T
            self.plane = GridArrays(plane, cell)
        else:
            self.plane = GridArrays(np.zeros((1, 3)), 1.0)
        self.c.nodes = &self.nodes[0, 0]
        self.c.normals = &self.normals[0, 0]
        self.c.node_spacing = &self.node_spacing[0]
        self.c.first = &self.first[0]
        self.c.fold_normals = &self.fold_normals[0, 0]
        self.c.is_signed = &self.signed_[0]
        self.c.steep = &self.steep[0]
        self.c.perm = &self.perm[0]
        self.c.inv = &self.inv[0]
        self.c.grid = self.grid.grid
        self.c.plane = self.plane.grid
        for e in range(3):
            self.c.frame_origin[e] = origin[e]
        for e in range(9):
            self.c.frame_axes[e] = axes[e]
        self.c.has_faces = has_faces
        self.c.duplicates = bool(np.any(np.asarray(self.first) != np.arange(n)))
        assert np.all(np.asarray(self.grid.order) == np.arange(n))  # already in cell order
        self.c.global_frame = global_frame
        self.c.n = n

    def cell_keys(self, const double[:, ::1] points):
        """Morton (Z-order) key of the grid cell of each point (m,): sorting contactors by it
        makes contactors that follow each other search neighbouring cells, in all three
        directions (fewer cache misses on a large target)."""
        cdef Py_ssize_t i, m = points.shape[0]
        out = np.empty(m, dtype=np.int64)
        cdef int64_t[::1] key = out
        cdef const Grid *g = &self.c.grid
        with nogil:
            for i in range(m):
                key[i] = <int64_t>(
                    spread_bits(<uint64_t>cell_index(points[i, 0], g.lo[0], g.cell, g.dims[0]))
                    | (spread_bits(<uint64_t>cell_index(points[i, 1], g.lo[1], g.cell,
                                                        g.dims[1])) << 1)
                    | (spread_bits(<uint64_t>cell_index(points[i, 2], g.lo[2], g.cell,
                                                        g.dims[2])) << 2))
        return out

    def project(self, dict options, const double[:, ::1] points, const int64_t[::1] rows,
                dict out, int64_t[:, ::1] index, int64_t cap, double[:, ::1] alpha=None,
                int threads=0, const double[::1] h_min=None):
        """Project the contactors points[rows] (select, solve, retry, re-centre, bad points).

        `out`: the arrays of `projection.allocate(len(points), PAIRING_RECORD)`. Row rows[i]'s
        results go to row rows[i] of each of them, and its support to the first count[rows[i]]
        entries of row i of `index` (when index has columns; `out`'s "count"; the rest of the
        row is not written), and to row rows[i] of `alpha` (m, nterms), when given
        with `index`, the fit's coefficients [17] in the full basis, centred at the contactor
        in its frame (NaN where it was not answered). overflow[rows[i]] is set where a
        support had more than `cap` nodes (run those rows again with a larger cap).
        `threads`: OpenMP threads of the loop (0: `threads_for`'s; 1: a plain loop, no
        parallel region). `h_min` (points,): each contactor's floor of the local spacing
        (the patched pass's `facet_size` where its patch answers it: the element then takes
        the support the projection took); None: none.
        """
        cdef Options op = make_options(options, index.shape[1] > 0)
        cdef Py_ssize_t m = rows.shape[0], i
        cdef int64_t width = index.shape[1]
        cdef bint keep_alpha = alpha is not None and width > 0
        if keep_alpha and (alpha.shape[0] != points.shape[0] or alpha.shape[1] < op.nterms):
            raise ValueError("alpha must have shape (m, nterms)")
        cdef Scratch *sc
        cdef int failed = 0
        cdef int *failedp = &failed
        cdef ProjectOut o
        _check_rows(points, rows)
        record_of(out, points.shape[0], &o.rec)
        cdef double[:, ::1] origin = _named(out, "origin")
        cdef double[:, :, ::1] axes = _named(out, "axes")
        cdef double[::1] radius = _named(out, "radius")
        cdef double[::1] spacing = _named(out, "spacing")
        cdef double[::1] direction = _named(out, "direction")
        cdef int8_t[::1] reduced = _named(out, "reduced")
        _rows(points.shape[0], origin=origin, axes=axes, radius=radius, spacing=spacing,
              direction=direction, reduced=reduced)
        if index.shape[0] < m and width > 0:
            raise ValueError("index has fewer rows than rows")
        if op.knn and op.k[1] > cap:
            raise ValueError("cap is below k")
        if m == 0:
            return
        o.origin, o.axes, o.radius, o.spacing = &origin[0, 0], &axes[0, 0, 0], &radius[0], \
            &spacing[0]
        o.direction, o.reduced = &direction[0], &reduced[0]
        o.width = width
        o.index = &index[0, 0] if width > 0 else NULL
        cdef int64_t[::1] count
        o.count = NULL
        if width > 0:
            count = _named(out, "count")
            _rows(points.shape[0], count=count)
            o.count = &count[0]
        o.alpha = &alpha[0, 0] if keep_alpha else NULL
        o.alpha_width = alpha.shape[1] if keep_alpha else 0
        if h_min is not None and h_min.shape[0] != points.shape[0]:
            raise ValueError("h_min must have one entry a point")
        o.h_min = &h_min[0] if h_min is not None else NULL
        cdef const double *pts = &points[0, 0]
        cdef const int64_t *rw = &rows[0]
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "project")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                sc = scratch_new(cap, op.nterms, op.spacing_neighbours)
                if sc != NULL:
                    for i in range(m):
                        project_row(&self.c, &op, pts, rw[i], i, sc, &o)
                    scratch_free(sc)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 64)
            with nogil, parallel(num_threads=threads):
                sc = scratch_new(cap, op.nterms, op.spacing_neighbours)
                if sc == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if sc != NULL:
                        project_row(&self.c, &op, pts, rw[i], i, sc, &o)
                scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")

    def project_with(self, dict options, const double[:, ::1] points,
                     const double[:, ::1] origin, const double[:, :, ::1] axes,
                     const double[::1] radius, const double[::1] spacing,
                     const int64_t[:, ::1] index, dict out,
                     const int8_t[::1] frozen_reduced=None,
                     const double[::1] frozen_direction=None, int threads=0):
        """Fit and project each contactor with a frozen pairing (origin, axes, R, h, support
        index with -1 holes): the same per-point code as `project` after the selection, into
        `out` (`projection.allocate(m, PAIRING_RECORD)`: the record, and the pairing's
        direction and reduced basis). Contactors with NaN or inf are solved at their origin,
        then flagged 'failed'. With `frozen_reduced` and `frozen_direction` (the pairing's), a
        row whose pairing fitted a reduced basis (>= 0) fits that one at that direction (held
        fixed, as the frame). `threads`: as `project`'s."""
        cdef Options op = make_options(options, False)
        cdef Py_ssize_t m = points.shape[0], i
        cdef int64_t K = index.shape[1]
        cdef Scratch *sc
        cdef int failed = 0
        cdef int *failedp = &failed
        cdef ProjectOut o
        record_of(out, m, &o.rec)
        cdef double[::1] direction = _named(out, "direction")
        cdef int8_t[::1] reduced = _named(out, "reduced")
        _rows(m, origin=origin, radius=radius, spacing=spacing, direction=direction,
              reduced=reduced)
        if origin.shape[1] != 3:
            raise ValueError("origin must have shape (m, 3)")
        if points.shape[1] != 3 or axes.shape[0] != m or axes.shape[1] != 3 or axes.shape[2] != 3 \
                or index.shape[0] != m:
            raise ValueError("points, axes and index must have m rows")
        if m == 0:
            return
        if K and np.asarray(index).max() >= self.c.n:
            raise ValueError("a support index past the target's nodes")
        cdef bint freeze = frozen_reduced is not None and frozen_direction is not None
        if freeze and (frozen_reduced.shape[0] != m or frozen_direction.shape[0] != m):
            raise ValueError("frozen_reduced and frozen_direction must have m rows")
        cdef FrozenIn f
        f.points, f.origin, f.axes = &points[0, 0], &origin[0, 0], &axes[0, 0, 0]
        f.radius, f.spacing = &radius[0], &spacing[0]
        f.index = &index[0, 0] if K > 0 else NULL
        f.K = K
        f.frozen_reduced = &frozen_reduced[0] if freeze else NULL
        f.frozen_direction = &frozen_direction[0] if freeze else NULL
        o.direction, o.reduced = &direction[0], &reduced[0]
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "project_with")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                sc = scratch_new(imax(K, 1), op.nterms, op.spacing_neighbours)
                if sc != NULL:
                    for i in range(m):
                        project_with_row(&self.c, &op, i, &f, sc, &o)
                    scratch_free(sc)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 64)
            with nogil, parallel(num_threads=threads):
                sc = scratch_new(imax(K, 1), op.nterms, op.spacing_neighbours)
                if sc == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if sc != NULL:
                        project_with_row(&self.c, &op, i, &f, sc, &o)
                scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")


def _checked(a, dtype, shape):
    arr = np.ascontiguousarray(a, dtype=dtype)
    if arr.shape != tuple(shape):
        raise ValueError(f"an array of shape {arr.shape}, expected {tuple(shape)}")
    return arr


def _check_rows(points, rows):
    m = points.shape[0]
    if points.shape[1] != 3:
        raise ValueError("points must have shape (m, 3)")
    r = np.asarray(rows)
    if len(r) and (r.min() < 0 or r.max() >= m):
        raise ValueError("rows index past the points")


cdef Options make_options(dict o, bint keep) except *:
    """The options of one call: the surface's settings (`o`) and diffsurf_cli.tol."""
    cdef Options op
    cdef int j
    exps = _basis.EXPONENTS[o["basis"]]
    op.nterms = len(exps)
    for j in range(op.nterms):
        op.ea[j] = exps[j][0]
        op.eb[j] = exps[j][1]
    reduced = _basis.REDUCED[o["basis"]]
    op.nreduced = len(reduced)
    assert op.nreduced <= NREDUCED_MAX
    quadratic = tuple(_basis.EXPONENTS["quadratic"])
    # `basis_rows` writes a basis of 6 terms as the quadratic
    assert all(tuple(e) == quadratic for e in [exps, *reduced] if len(e) == 6)
    for r, exps in enumerate(reduced):
        op.rsize[r] = len(exps)
        op.across[r] = any(b > 0 for _, b in exps)
        op.plane_only[r] = _basis.complete(exps)
        for j in range(len(exps)):
            op.ra[NTERMS_MAX * r + j] = exps[j][0]
            op.rb[NTERMS_MAX * r + j] = exps[j][1]
    op.wp = weight_params(o["weight"])
    op.knn = o["support"] == "knn"
    n = o["nodes"]
    op.k[0] = min(int(o["k"]), n)
    op.k[1] = min(int(np.ceil(o["k"] * tol.ENLARGE**2)), n)
    op.radius[0] = o["radius"]
    op.radius[1] = o["radius"] * tol.ENLARGE
    op.spacing_neighbours = min(tol.SPACING_NEIGHBOURS + 1, n)
    op.frame_ball = tol.FRAME_BALL
    op.knn_factor = tol.KNN_RADIUS_FACTOR
    op.sheet_cos = np.cos(np.radians(tol.SHEET_ANGLE_DEG))
    op.cos_fold = np.cos(np.radians(tol.FOLD_SLOPE_DEG))
    op.rcond_min = tol.RCOND_MIN[o["basis"]]
    op.ruled_global = o["ruled"]
    op.ruled_spread = tol.RULED_SPREAD
    op.row_variance = tol.ROW_VARIANCE
    op.strip_rank = tol.STRIP_RANK
    op.contact_tol = tol.CONTACT
    op.outside_spacings = o["outside_spacings"]
    op.hull_spacings = tol.HULL_SPACINGS
    op.equilibration_floor = tol.EQUILIBRATION_FLOOR
    op.newton_step = tol.NEWTON_STEP
    op.newton_max_iter = tol.NEWTON_MAX_ITER
    for j in range(3):
        op.e1_guide[j] = tol.E1_GUIDE[j]
        op.e1_guide_alt[j] = tol.E1_GUIDE_ALT[j]
    op.recentre = o["recentre"]
    op.recentre_max_iter = tol.RECENTRE_MAX_ITER
    op.recentre_step = tol.RECENTRE_STEP
    op.recentre_stall = tol.RECENTRE_STALL
    op.keep = keep
    return op
