# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""One pass per contactor over a target of smooth patches (`surface.PatchedSurface`), compiled.

For each contactor, in one parallel loop (OpenMP `prange`, per-thread scratch allocated once
per call; no parallel region at all for a batch too small to gain from one):

1. the faceted closest point over the whole target (the facets' hierarchy, [1]-[2]): its
   facet f0, gap g_f and normal, and the class of the feature holding its foot (inside a
   facet, a smooth edge between patches, an open edge, a sharp edge or corner);
2. the candidate patches: those of the facets around f0 (its vertex ring, precomputed),
   then, where another patch's smooth surface may come nearer than the faceted foot and the
   best answer of those (a lower bound precomputed per facet, `clearance.foreign_clearance`:
   the far side of a thin wall, whose facets lie up to their sag farther than the foot's),
   the patches with a facet g within that distance plus gap_bound[g] (a range search of the
   facets' hierarchy), whose answer counts (tier 0) only if nearer than both and of the
   facets' sign;
3. each candidate's diffuse answer (`project_one`: support, frame, fit, proximal point [30],
   gap [32]), valid where the engine answers it and its proximal point lies on that patch:
   its closest point on the patch's own facets is not past a sharp edge, nor more than a
   tenth of a spacing past a smooth one (tier 1: kept only where no patch answers inside
   its own boundary); that search is skipped where it cannot find a feature: on f0's own
   patch, a proximal point closer to the faceted foot than half of f0's clearance from every
   sharp or smooth edge (`clearance.py`) has its closest point on none;
4. the choice: the valid answer of lowest tier, then closest to the contactor; the facets
   answer where their foot is on a sharp edge or corner (the diffuse surfaces cannot reach
   it) and no diffuse answer is closer, and where the home patch (f0's) has no valid answer
   and the foot is not on an open edge; nothing valid: the home patch's own verdict
   ('outside', with its reason);
5. the guard (method.md, "The facets bound the smooth surface"): a diffuse answer whose gap
   departs from g_f by more than a multiple of the chordal sag of the facets around f0, or
   to the side their bend does not explain (`gap_lo[f0]`, `gap_hi[f0]`), or whose normal
   is farther from f0's normal than `normal_angle[f0]` allows (the spread of the smooth
   facet normals around f0, with a margin, plus `normal_turn[f0]` times the distance from
   its proximal point to the faceted foot) is not smoothing: the facets
   answer, with reason 'guard'. An answer of a patch found beyond f0's ring is checked
   against that patch's own facets around its own faceted foot;
6. wherever step 4 or 5 gives the facets and f0's foot is not on a sharp edge or corner:
   the target's curved cells (its second-order cells, or its first-order facets curved
   through their corner normals) (`cells_answer`: Newton on each cell
   of f0's vertex ring, from f0's foot on f0 itself; the nearest minimum inside its cell,
   no farther than f0's cell point over the foot, whose gap departs from g_f by at most
   gap_bound[f0]), `Projection.source` CELLS.

A target of one patch runs the same pass: its diffuse answers are those of its
`DiffuseSurface` bit for bit wherever the guard accepts them.
"""
import numpy as np

from libc.math cimport sqrt, cos, fabs, NAN, INFINITY, M_PI
from libc.stdlib cimport malloc, free
from libc.string cimport memcmp
from libc.stdint cimport int64_t, int32_t, int8_t
from cython.parallel cimport prange, parallel

from .._codes cimport (OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED, R_OK, R_BAD_POINT,
                       R_FEW_NODES, R_GUARD)
from ..facet._engine cimport (Tables, Hit, Out, FacetTables, facet_query, facet_search,
                              facet_answer, facet_feature)
from ._cells cimport facet_cell, CELL_I, CELL_J
from ..mls._linalg cimport dot
from ..mls._projection cimport (Options, TargetC, Result, Record, Scratch, Target,
                                scratch_new, scratch_free, project_one, make_options,
                                record_of)
from ..threads import chunk_size, threads_for
from .clearance import feature_clearance, foreign_clearance

cdef enum:
    PSTACK = 96         # the range search's stack (the hierarchy's depth is far less)
    MAX_FOREIGN = 8     # patches beyond the foot's ring tried for one contactor


# the class of a feature of the facets (an edge, a vertex), by priority
cdef enum:
    INSIDE = 0          # within a patch
    SMOOTH = 1          # between two patches split by their tags only (below the feature angle)
    OPEN_EDGE = 2       # an open or non-manifold edge
    SHARP = 3           # a feature edge

#: The classes of facet edges and vertices, in code order (`surface.PatchedSurface`).
EDGE_CLASSES = ("inside", "smooth", "open", "sharp")

# sources of an answer (`Projection.source`) other than a patch: the facets, nothing
cdef enum:
    BY_FACETS = -1
    BY_NOTHING = -2
    BY_CELLS = -3

#: Sources of an answer (`Projection.source`) other than a patch: the facets, nothing, the
#: target's curved cells (`surface.cell_coefficients`).
FACETS = BY_FACETS
NOTHING = BY_NOTHING
CELLS = BY_CELLS

# how far outside a cell's parameters x's projection on its facet may lie for the cell to be
# tried (`flat_seed`)
cdef double CELL_SEED_OUT = 0.5

cdef enum:
    CELL_ITERATIONS = 16    # Newton on one curved cell (quadratic: 3-5 from a facet's foot)
    CELL_TERMS = 9          # the monomials a^i b^j, i, j <= 2, of a curved cell


cdef struct Answer:
    double gap
    double normal[3]
    double proximal[3]
    double rcond
    double curvature[2]
    int8_t status, reason, terms
    int64_t support, iterations
    int64_t source
    bint plane                   # fitted with the plane [1, s, t], a reduced basis
    int64_t cell                 # a curved cell's answer (source BY_CELLS): its cell and
    double cell_param[2]         # the closest point's parameters on it


cdef struct FacetAnswer:
    double gap
    double normal[3]
    double proximal[3]
    int8_t status, reason
    int64_t facet, support, iterations
    double param[2]
    bint ok
    int8_t where    # the foot's feature class (`feature_class`), set by `pass_one`


cdef struct PassC:
    int npatches
    TargetC **target             # (npatches,) NULL where a patch has no diffuse surface
    Options *options             # (npatches,)
    Tables **tables              # (npatches,) each patch's own facets
    const int64_t *patch_ptr     # (npatches + 1,) CSR: the global facet of each patch facet
    const int32_t *patch_facet
    const double *box            # (npatches, 6) each patch's bounding box
    Tables *facets               # the whole target's facets
    const int64_t *label         # (F,) the patch of each facet
    const int64_t *corners       # (F, 4) corner nodes, -1 padded
    const int64_t *kind          # (F,) 3 or 4
    const int8_t *edge_class     # (F, 4) class of each local edge
    const int8_t *vertex_class   # (n,) class of each node (the highest of its edges')
    const double *facet_normal   # (F, 3) unit, oriented as the target
    const double *spacing        # (F,) node spacing at the facet
    const int32_t *ring_ptr      # (F + 1,) CSR: the candidate patches of each facet
    const int32_t *ring
    const double *gap_bound      # (F,) the guard's bound on |g - g_f| (its envelope)
    const double *gap_lo         # (F,) ... the least g - g_f, on the side of the bend
    const double *gap_hi         # (F,) ... the largest
    const double *normal_angle   # (F,) ... and on the normal: the largest angle
    const double *normal_turn    # (F,) ... plus this times the distance between the feet
    const double *facet_size     # (F,) floor of the local spacing of its patch over it
    const double *clearance      # (F,) lower bound of its distance to any feature (clearance.py)
    const double *foreign        # (F,) clearance.foreign_clearance
    double bound_max             # the largest gap_bound
    bint guard
    # curved cells (method.md "The facets bound the smooth surface"): where the facets would
    # answer, the target's curved cells do if they can (its second-order cells, or its
    # first-order facets curved through their corner normals: `surface.cell_coefficients`)
    bint cells                   # the target has curved cells
    const int8_t *has_cell       # (F,) facet f has a curved cell
    # its geometry (F, 9, 3): x(a, b) = sum_k a^i b^j coef[k]; NULL on a first-order target,
    # each cell computed where it is needed (`cell_of`) from nodes, cell_index, cell_table
    const double *cell_coef
    const double *nodes          # (n, 3) the target's nodes
    const int32_t *cell_index    # (F, 4) the corner normals the cells follow, compacted
    const double *cell_table     # (m, 3) (`compact_normals`): corner j's is row index[f, j]
    const double *shape3         # (9, 6) a triangle's cell shape (`surface.cell_shape`)
    const double *shape4         # (9, 8) a quad's
    const int32_t *fring_ptr     # (F + 1,) CSR: the facets sharing a node with each facet
    const int32_t *fring
    double contact_tol           # |g| <= contact_tol spacings: contact
    double candidate_spacings, overshoot, smooth_overshoot, edge_eps


cdef inline double dist3(const double *a, const double *b) noexcept nogil:
    cdef double d0 = a[0] - b[0], d1 = a[1] - b[1], d2 = a[2] - b[2]
    return sqrt(d0 * d0 + d1 * d1 + d2 * d2)


cdef inline int8_t feature_class(const PassC *P, int64_t f, double a, double b) noexcept nogil:
    """The class of the feature of facet f holding ξ = (a, b): INSIDE within the facet, else
    that of its edge or vertex."""
    cdef double t = 0.0
    cdef int64_t where = facet_feature(P.kind[f], a, b, P.edge_eps, &t)
    if where < 0:
        return INSIDE
    if where >= 4:
        return P.vertex_class[P.corners[4 * f + where - 4]]
    return P.edge_class[4 * f + where]


cdef void take_result(const Result *r, int64_t source, const Options *op,
                      Answer *a) noexcept nogil:
    cdef int e
    a.gap = r.gap
    for e in range(3):
        a.normal[e] = r.normal[e]
        a.proximal[e] = r.proximal[e]
    a.rcond = r.rcond
    a.curvature[0] = r.curvature[0]
    a.curvature[1] = r.curvature[1]
    a.status = r.status
    a.reason = r.reason
    a.terms = r.terms
    a.plane = r.reduced >= 0 and r.terms == 3 and op.plane_only[r.reduced]
    a.support = r.support
    a.iterations = r.iterations
    a.source = source


cdef void take_facets(const FacetAnswer *fa, int8_t reason, Answer *a) noexcept nogil:
    """The facets' answer [1]-[2]: flat facets (curvature 0, rcond 1, no basis terms)."""
    cdef int e
    a.gap = fa.gap
    for e in range(3):
        a.normal[e] = fa.normal[e]
        a.proximal[e] = fa.proximal[e]
    a.status = fa.status
    a.reason = reason if fa.status <= PENETRATION else fa.reason
    a.rcond = 1.0 if fa.status <= PENETRATION else NAN
    a.curvature[0] = 0.0 if fa.status <= PENETRATION else NAN
    a.curvature[1] = a.curvature[0]
    a.terms = 0
    a.support = fa.support
    a.iterations = fa.iterations
    a.source = BY_FACETS


cdef void nothing(int8_t status, int8_t reason, Answer *a) noexcept nogil:
    cdef int e
    a.gap = NAN
    for e in range(3):
        a.normal[e] = NAN
        a.proximal[e] = NAN
    a.rcond = NAN
    a.curvature[0] = NAN
    a.curvature[1] = NAN
    a.status = status
    a.reason = reason
    a.terms = 0
    a.support = 0
    a.iterations = 0
    a.source = BY_NOTHING


cdef bint closest_facet(const Tables *T, const double *x, FacetAnswer *fa) noexcept nogil:
    """The faceted closest point of x over the facets of T, into fa (facet: T's own index);
    False where x is not a usable point or T answers nothing."""
    cdef double Pc[3]
    cdef double q[3]
    cdef bint far
    cdef Hit h
    cdef Out o
    fa.ok = False
    if not facet_query(T, x, Pc, q, &far):
        return False
    facet_search(T, q[0], q[1], q[2], far, &h)
    if h.slot < 0:
        return False
    o.gap = &fa.gap
    o.normal = fa.normal
    o.prox = fa.proximal
    o.status = <signed char *>&fa.status
    o.reason = <signed char *>&fa.reason
    o.facet = &fa.facet
    o.param = fa.param
    o.support = &fa.support
    o.iterations = &fa.iterations
    facet_answer(T, Pc[0], Pc[1], Pc[2], &h, 0, &o)
    fa.ok = fa.status <= PENETRATION
    return True


cdef bint facets_of(const PassC *P, const double *x, FacetAnswer *fa) noexcept nogil:
    """The faceted closest point of x over the whole target, into fa; False where x is not a
    usable point (NaN, inf)."""
    return closest_facet(P.facets, x, fa)


cdef int on_patch(const PassC *P, int p, const double *xd) noexcept nogil:
    """Whether the proximal point xd of patch p lies on that patch: 0 on it, 1 past a smooth
    edge of it by at most `smooth_overshoot` spacings (valid, but an answer on its own patch
    elsewhere is preferred: the next patch holds that point), -1 past its boundary (invalid).
    Measured from xd's closest point on the patch's own facets: its offset along the facet
    (across the facet normal) where that point is on a sharp or smooth edge or corner."""
    cdef const Tables *T = P.tables[p]
    cdef double Pc[3]
    cdef double q[3]
    cdef double d[3]
    cdef double dn, along, h
    cdef bint far
    cdef Hit hit
    cdef int64_t f
    cdef int8_t cls
    cdef const double *n
    cdef int e
    if not facet_query(T, xd, Pc, q, &far):
        return -1
    facet_search(T, q[0], q[1], q[2], far, &hit)
    if hit.slot < 0:
        return -1
    f = P.patch_facet[P.patch_ptr[p] + T.original[hit.slot]]
    cls = feature_class(P, f, hit.a, hit.b)
    if cls != SHARP and cls != SMOOTH:
        return 0
    d[0] = Pc[0] - hit.x
    d[1] = Pc[1] - hit.y
    d[2] = Pc[2] - hit.z
    n = P.facet_normal + 3 * f
    dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2]
    along = 0.0
    for e in range(3):
        along += (d[e] - dn * n[e]) * (d[e] - dn * n[e])
    along = sqrt(along)
    h = P.spacing[f]
    if not (along > P.overshoot * h):
        return 0
    if cls == SMOOTH and along <= P.smooth_overshoot * h:
        return 1
    return -1


cdef inline double box_gap(const double *box, const double *x) noexcept nogil:
    """Distance from x to an axis-aligned box (lo xyz, hi xyz)."""
    cdef double d, d2 = 0.0
    cdef int e
    for e in range(3):
        d = box[e] - x[e]
        if x[e] - box[3 + e] > d:
            d = x[e] - box[3 + e]
        if d > 0:
            d2 += d * d
    return sqrt(d2)


cdef inline bint guard_holds(const PassC *P, int64_t f, bint plane, double d,
                             const double *normal, double apart) noexcept nogil:
    """The guard (method.md, "The facets bound the smooth surface"), the one copy the
    projection (`within_guard`) and the rigid element (`PatchedPass.within_guard`) both run:
    whether an answer of normal `normal`, whose gap departs from the faceted gap on facet f
    by d and whose proximal point lies `apart` from the faceted foot, is what smoothing the
    facets around the foot can explain: d within their sag, on the side their bend puts the
    surface (gap_lo, gap_hi), and the normal within the spread of their normals, widened by
    the surface's turn over that distance (normal_turn times it). A plane fit (`plane`: the
    reduced basis of a support too thin for curvature) explains no bend: the facets, planes
    themselves that follow every bend, answer."""
    cdef const double *n = P.facet_normal + 3 * f
    cdef double limit
    if plane:
        return False
    if not (d >= P.gap_lo[f] and d <= P.gap_hi[f]):  # and not NaN
        return False
    limit = P.normal_angle[f] + P.normal_turn[f] * apart
    if limit >= M_PI:
        return True
    return normal[0] * n[0] + normal[1] * n[1] + normal[2] * n[2] >= cos(limit)


cdef inline double facet_height(const PassC *P, const FacetAnswer *fa, const double *x,
                                bint open_foot) noexcept nogil:
    """The faceted gap the guard measures a diffuse gap from: the facets' own (fa.gap), but
    where their foot is on an open edge (`open_foot`: x overhangs the target's boundary),
    x's height over the foot facet's plane. Past the boundary the facets' gap is the
    distance to its edge, which no smoothing explains; the height is the gap the facets give
    a point just inside it."""
    cdef const double *n = P.facet_normal + 3 * fa.facet
    cdef double h = 0.0
    cdef int k
    if not open_foot:
        return fa.gap
    for k in range(3):
        h += (x[k] - fa.proximal[k]) * n[k]
    return h


cdef bint within_guard(const PassC *P, const Answer *a, const FacetAnswer *fa,
                       const double *x, bint open_foot) noexcept nogil:
    """Whether a diffuse answer passes the guard (`guard_holds`) against the faceted answer
    fa: its gap's departure from the facets' (`facet_height`) and its proximal point's
    distance from their foot."""
    cdef double apart = 0.0, e
    cdef int k
    for k in range(3):
        e = a.proximal[k] - fa.proximal[k]
        apart += e * e
    return guard_holds(P, fa.facet, a.plane, a.gap - facet_height(P, fa, x, open_foot),
                       a.normal, sqrt(apart))


cdef void cell_eval(const double *coef, double a, double b, double *X) noexcept nogil:
    """A curved cell's point and derivatives at (a, b), into X (18): x, x_a, x_b, x_aa,
    x_ab, x_bb, 3 each, from its monomial coefficients (`surface.cell_coefficients`)."""
    cdef double pa[3]
    cdef double pb[3]
    cdef double m, ma, mb, maa, mab, mbb
    cdef int k, e, i, j
    pa[0] = 1.0
    pa[1] = a
    pa[2] = a * a
    pb[0] = 1.0
    pb[1] = b
    pb[2] = b * b
    for e in range(18):
        X[e] = 0.0
    for k in range(CELL_TERMS):
        i = CELL_I[k]
        j = CELL_J[k]
        m = pa[i] * pb[j]
        ma = i * pa[i - 1] * pb[j] if i > 0 else 0.0
        mb = j * pa[i] * pb[j - 1] if j > 0 else 0.0
        maa = 2.0 * pb[j] if i == 2 else 0.0
        mab = i * j * pa[i - 1] * pb[j - 1] if i > 0 and j > 0 else 0.0
        mbb = 2.0 * pa[i] if j == 2 else 0.0
        for e in range(3):
            X[e] += m * coef[3 * k + e]
            X[3 + e] += ma * coef[3 * k + e]
            X[6 + e] += mb * coef[3 * k + e]
            X[9 + e] += maa * coef[3 * k + e]
            X[12 + e] += mab * coef[3 * k + e]
            X[15 + e] += mbb * coef[3 * k + e]


cdef int cell_newton(const double *coef, const double *x, double *a, double *b,
                     double reach) noexcept nogil:
    """Newton on |x(a, b) - x|² over the curved cell of monomial coefficients `coef` (27),
    from (a, b) updated in place: its iterations where it converges (the step below 1e-12),
    -1 where it fails (no descent, or off the cell's parameters by more than `reach`)."""
    cdef double X[18]
    cdef double r[3]
    cdef double E, F, G, ga, gb, h00, h01, h11, det, da, db
    cdef int its = 0, e
    while its < CELL_ITERATIONS:
        its += 1
        cell_eval(coef, a[0], b[0], X)
        for e in range(3):
            r[e] = X[e] - x[e]
        E = dot(X + 3, X + 3, 3)
        F = dot(X + 3, X + 6, 3)
        G = dot(X + 6, X + 6, 3)
        ga = dot(X + 3, r, 3)
        gb = dot(X + 6, r, 3)
        h00 = E + dot(X + 9, r, 3)
        h01 = F + dot(X + 12, r, 3)
        h11 = G + dot(X + 15, r, 3)
        det = h00 * h11 - h01 * h01
        if not (det > 1e-3 * (E * G - F * F) and h00 > 0):  # far from a minimum: Gauss-Newton
            h00, h01, h11 = E, F, G
            det = E * G - F * F
        if not (det > 0):
            return -1
        da = -(h11 * ga - h01 * gb) / det
        db = -(h00 * gb - h01 * ga) / det
        a[0] += da
        b[0] += db
        if not (a[0] > -reach and a[0] < 1.0 + reach and b[0] > -reach
                and b[0] < 1.0 + reach):  # far off the cell
            return -1
        if fabs(da) + fabs(db) < 1e-12:
            return its
    return -1


cdef const double *cell_of(const PassC *P, int64_t g, double *buf) noexcept nogil:
    """Facet g's curved cell, its 27 monomial coefficients (`surface.cell_coefficients`):
    its row of the target's table where it keeps one (second-order cells), else computed
    here into buf (27) from g's corners and their normals (`_cells.facet_cell`, the very
    routine that filled the table, with the edges' lengths as `corner_normals` measures
    them: the same bits). A first-order target keeps no (F, 9, 3) table (issue 36): only the
    cells of the foot's vertex ring are needed, and only where the facets would answer."""
    cdef int64_t c[4]
    cdef double length[4]
    cdef double normal[12]
    cdef double d0, d1, d2
    cdef const double *x0
    cdef const double *x1
    cdef int k, j, nxt
    if P.cell_coef != NULL:
        return P.cell_coef + 27 * g
    k = <int>P.kind[g]
    for j in range(k):
        c[j] = P.corners[4 * g + j]
        for nxt in range(3):
            normal[3 * j + nxt] = P.cell_table[3 * P.cell_index[4 * g + j] + nxt]
    for j in range(k):
        nxt = j + 1 if j + 1 < k else 0
        x0 = P.nodes + 3 * c[j]
        x1 = P.nodes + 3 * c[nxt]
        d0 = x1[0] - x0[0]
        d1 = x1[1] - x0[1]
        d2 = x1[2] - x0[2]
        length[j] = sqrt((d0 * d0 + d1 * d1) + d2 * d2)  # np.linalg.norm's order
    if not facet_cell(P.nodes, c, k, normal, length,
                      P.shape3 if k == 3 else P.shape4, buf):
        for j in range(27):  # a straight facet has no cell (has_cell says so): none here
            buf[j] = 0.0
    return buf


cdef bint cell_closest(const PassC *P, int64_t g, const double *coef, const double *x,
                       double a, double b, Answer *out) noexcept nogil:
    """The closest point of x on facet g's curved cell (coefficients `coef`, `cell_of`), by
    Newton on |x(a, b) - x|² from (a, b) (`cell_newton`): True where it converges to a
    minimum inside the cell (a, b >= 0, a + b <= 1 on a triangle, [0, 1]² on a quad, as the
    facets' own parameters), with out's gap, normal (the cell's, oriented as the facet),
    proximal point, principal curvatures and iterations."""
    cdef double X[18]
    cdef double r[3]
    cdef double n[3]
    cdef double E, F, G, det, s, L, M, N, H, K, disc
    cdef double lo = -1e-9, hi = 1.0 + 1e-9
    cdef int its = cell_newton(coef, x, &a, &b, 1.0), e
    if its < 0:
        return False
    if P.kind[g] == 3:
        if not (a >= lo and b >= lo and a + b <= hi):
            return False
    elif not (a >= lo and b >= lo and a <= hi and b <= hi):
        return False
    cell_eval(coef, a, b, X)
    n[0] = X[4] * X[8] - X[5] * X[7]
    n[1] = X[5] * X[6] - X[3] * X[8]
    n[2] = X[3] * X[7] - X[4] * X[6]
    s = sqrt(dot(n, n, 3))
    if not (s > 0):
        return False
    if dot(n, P.facet_normal + 3 * g, 3) < 0:  # oriented as the facet (and the target)
        s = -s
    for e in range(3):
        n[e] /= s
        out.normal[e] = n[e]
        out.proximal[e] = X[e]
        r[e] = x[e] - X[e]
    out.gap = dot(r, n, 3)
    # principal curvatures from the fundamental forms, > 0 where the cell bends away from
    # its normal (convex), as every answer's
    E = dot(X + 3, X + 3, 3)
    F = dot(X + 3, X + 6, 3)
    G = dot(X + 6, X + 6, 3)
    L = dot(X + 9, n, 3)
    M = dot(X + 12, n, 3)
    N = dot(X + 15, n, 3)
    det = E * G - F * F
    H = -(E * N + G * L - 2.0 * F * M) / (2.0 * det)
    K = (L * N - M * M) / det
    disc = sqrt(H * H - K) if H * H > K else 0.0
    out.curvature[0] = H + disc
    out.curvature[1] = H - disc
    out.iterations = its
    out.cell = g
    out.cell_param[0] = a
    out.cell_param[1] = b
    return True


cdef bint corner_plane(const double *coef, const double *x, double *a,
                       double *b) noexcept nogil:
    """x's projection on the plane of the corners 0, 1 and the last of the curved cell of
    coefficients `coef` (27), in the cell's parameters (a parallelogram's for a quad); False
    where those corners are collinear."""
    cdef double e1[3]
    cdef double e2[3]
    cdef double r[3]
    cdef double g11, g12, g22, r1, r2, det
    cdef int e
    for e in range(3):  # the corners (1, 0) and (0, 1) of the cell, less (0, 0)
        e1[e] = coef[3 + e] + coef[9 + e]          # a, a^2
        e2[e] = coef[6 + e] + coef[15 + e]         # b, b^2
        r[e] = x[e] - coef[e]
    g11 = dot(e1, e1, 3)
    g12 = dot(e1, e2, 3)
    g22 = dot(e2, e2, 3)
    det = g11 * g22 - g12 * g12
    if not (det > 0):
        return False
    r1 = dot(r, e1, 3)
    r2 = dot(r, e2, 3)
    a[0] = (g22 * r1 - g12 * r2) / det
    b[0] = (g11 * r2 - g12 * r1) / det
    return True


cdef bint flat_seed(const PassC *P, int64_t g, const double *coef, const double *x, double *a,
                    double *b) noexcept nogil:
    """Newton's start on cell g (coefficients `coef`): x's projection on the plane of its
    corners (`corner_plane`). False where it lies more than `CELL_SEED_OUT` outside the
    cell's parameters: a curved cell bends a few percent of its size off its facet, so its
    closest point to x is not inside it then."""
    if not corner_plane(coef, x, a, b):
        return False
    if a[0] < -CELL_SEED_OUT or b[0] < -CELL_SEED_OUT:
        return False
    if P.kind[g] == 3:
        return a[0] + b[0] <= 1.0 + CELL_SEED_OUT
    return a[0] <= 1.0 + CELL_SEED_OUT and b[0] <= 1.0 + CELL_SEED_OUT


def frozen_cells(coef, points):
    """A frozen pairing's closest points on its cells: for each contactor (points (e, 3)) and
    its paired cell (coef (e, 9, 3), monomial coefficients, `surface.cell_coefficients`),
    Newton from its projection on the cell's corner plane (`corner_plane`, `cell_newton`),
    past the cell's edges as far as two cells (a frozen cell extends as its polynomial
    does). Returns the parameters ξ (e, 2) and converged (e,) bool."""
    cdef double[:, :, ::1] C = np.ascontiguousarray(coef, dtype=np.float64).reshape(-1, 9, 3)
    cdef double[:, ::1] X = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    cdef Py_ssize_t n = C.shape[0], i
    if X.shape[0] != n:
        raise ValueError("one cell per contactor")
    xi = np.full((n, 2), np.nan)
    ok = np.zeros(n, dtype=np.uint8)
    cdef double[:, ::1] XI = xi
    cdef unsigned char[::1] OK = ok
    cdef double a, b
    with nogil:
        for i in range(n):
            if corner_plane(&C[i, 0, 0], &X[i, 0], &a, &b) and \
                    cell_newton(&C[i, 0, 0], &X[i, 0], &a, &b, 2.0) > 0:
                XI[i, 0] = a
                XI[i, 1] = b
                OK[i] = 1
    return xi, ok.astype(bool)


cdef bint cells_answer(const PassC *P, const double *x, const FacetAnswer *fa,
                       int8_t reason, Answer *out) noexcept nogil:
    """Where the facets would answer x: the target's curved cells instead (their
    closest point over the cells of the facets sharing a node with the faceted foot's), where
    one is found inside its cell, no farther from x than the foot's own cell at the foot's
    parameters, and its gap departs from the facets' by no more than the guard's envelope
    (`gap_bound`: the cells' own sag, from their mid-side nodes, with its margin). False:
    the facets answer."""
    cdef Answer c
    cdef double X[18]
    cdef double buf[27]
    cdef const double *coef
    cdef int64_t f0 = fa.facet, idx, g
    cdef double a, b, dist, best = INFINITY
    cdef bint found = False
    if not (P.cells and fa.ok):
        return False
    for idx in range(P.fring_ptr[f0], P.fring_ptr[f0 + 1]):
        g = P.fring[idx]
        if not P.has_cell[g]:
            continue
        coef = cell_of(P, g, buf)
        if g == f0:
            a = fa.param[0]
            b = fa.param[1]
        elif not flat_seed(P, g, coef, x, &a, &b):
            continue  # x is not over g: its minimum, if any, is in another cell
        if not cell_closest(P, g, coef, x, a, b, &c):
            continue
        dist = fabs(c.gap)
        if dist < best:
            best = dist
            c.support = P.kind[g]
            out[0] = c
            found = True
    if not found or not (fabs(out.gap - fa.gap) <= P.gap_bound[f0]):
        return False
    if P.has_cell[f0]:
        # a minimum no nearer than f0's cell's own point over the faceted foot is not the
        # closest (that lies on an edge between cells, where no cell has a minimum inside)
        cell_eval(cell_of(P, f0, buf), fa.param[0], fa.param[1], X)
        if best > (1.0 + 1e-9) * dist3(x, X) + 1e-12 * P.spacing[f0]:
            return False
    out.status = PENETRATION if out.gap < 0 else OPEN
    if fabs(out.gap) <= P.contact_tol * P.spacing[f0]:
        out.status = CONTACT
    out.reason = reason
    out.rcond = 1.0
    out.terms = 0
    out.source = BY_CELLS
    out.plane = False
    return True


cdef void facets_answer(const PassC *P, const double *x, const FacetAnswer *fa,
                        int8_t reason, Answer *out) noexcept nogil:
    """The mesh's own answer where no diffuse one stands: its curved cells where they
    answer (`cells_answer`), else its facets [1]-[2]."""
    if not cells_answer(P, x, fa, reason, out):
        take_facets(fa, reason, out)


cdef int try_patch(const PassC *P, int64_t p, bint home, const double *x,
                   const FacetAnswer *fa, Scratch *sc, Result **res,
                   bint *overflow) noexcept nogil:
    """Patch p's answer for x (step 3) into res[0]; its tier: 0 on the patch, 1 past a smooth
    edge of it by a little, -1 not valid."""
    cdef int64_t f0 = fa.facet
    cdef Result *r
    # the support follows the mesh: on its own patch, at least as wide as the facets under
    # the contactor (a coarse face next to a fine band, elongated cells)
    sc.h_min = P.facet_size[f0] if home else 0.0
    r = project_one(P.target[p], &P.options[p], x, sc)
    res[0] = r
    if r.overflow:
        overflow[0] = True
    if not r.status <= PENETRATION:
        return -1
    if home and P.kind[f0] == 3 and 2.0 * dist3(r.proximal, fa.proximal) < P.clearance[f0]:
        # x^d is closer to f0's point fa.proximal than to any feature (clearance.py): its
        # closest point on its patch's facets is on none, on the patch (tier 0)
        return 0
    return on_patch(P, <int>p, r.proximal)


cdef inline bint in_ring(const PassC *P, int64_t f0, int64_t p) noexcept nogil:
    cdef int64_t idx
    for idx in range(P.ring_ptr[f0], P.ring_ptr[f0 + 1]):
        if P.ring[idx] == p:
            return True
    return False


cdef int foreign_patches(const PassC *P, const double *x, int64_t f0, double D,
                         int64_t *found) noexcept nogil:
    """The patches other than f0's candidates (its vertex ring's) whose smooth surface may
    come nearer x than D: those with a facet g whose box is within D + gap_bound[g] of x (the
    surface lies within gap_bound[g] of its facets). A range search of the target's facet
    hierarchy; at most MAX_FOREIGN patches, into found; returns their number."""
    cdef const Tables *T = P.facets
    cdef int64_t stack[PSTACK]
    cdef int64_t sp = 1, node, s, first, count, g, q
    cdef int n = 0, k, j, e
    cdef double xr[3]
    cdef double b[6]
    cdef double lim = D + P.bound_max
    cdef const double *c
    cdef bint seen
    xr[0] = x[0] - T.cx
    xr[1] = x[1] - T.cy
    xr[2] = x[2] - T.cz
    stack[0] = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if box_gap(T.box + 6 * node, xr) > lim:
            continue
        count = T.link[2 * node + 1]
        if count == 0:
            if sp + 2 <= PSTACK:
                stack[sp] = node + 1
                stack[sp + 1] = T.link[2 * node]
                sp += 2
            continue
        first = T.link[2 * node]
        for s in range(first, first + count):
            g = T.original[s]
            q = P.label[g]
            if P.target[q] == NULL or in_ring(P, f0, q):
                continue
            seen = False
            for k in range(n):
                if found[k] == q:
                    seen = True
            if seen:
                continue
            c = T.corner + 12 * s
            for e in range(3):
                b[e] = c[e]
                b[3 + e] = c[e]
                for j in range(1, T.kind[s]):
                    if c[3 * j + e] < b[e]:
                        b[e] = c[3 * j + e]
                    if c[3 * j + e] > b[3 + e]:
                        b[3 + e] = c[3 * j + e]
            if box_gap(b, xr) > D + P.gap_bound[g]:
                continue
            found[n] = q
            n += 1
            if n == MAX_FOREIGN:
                return n
    return n


cdef bint patch_facets_of(const PassC *P, int64_t p, const double *x,
                          FacetAnswer *fa) noexcept nogil:
    """The faceted closest point of x over patch p's own facets, into fa (facet: its index
    over the whole target)."""
    if not closest_facet(P.tables[p], x, fa):
        return False
    fa.facet = P.patch_facet[P.patch_ptr[p] + fa.facet]
    return True


cdef void pass_one(const PassC *P, const double *x, Scratch *sc, Answer *out,
                   FacetAnswer *fa, bint *overflow) noexcept nogil:
    """One contactor: steps 1-5 of the module docstring."""
    cdef Answer home
    cdef Result *res
    cdef FacetAnswer fq
    cdef int64_t f0, idx, p, hp, foreign_source = -1
    cdef int64_t found[MAX_FOREIGN]
    cdef int8_t where0
    cdef int tier, best_tier = 2, nf, k
    cdef double d0, reach, dist, best = INFINITY, D
    cdef bint have_home = False, home_valid = False, valid
    overflow[0] = False
    if not facets_of(P, x, fa):  # NaN or inf
        nothing(FAILED, R_BAD_POINT, out)
        fa.facet = -1
        return
    nothing(FAILED, R_FEW_NODES, out)
    f0 = fa.facet
    hp = P.label[f0]
    d0 = dist3(x, fa.proximal)
    reach = d0 + P.candidate_spacings * P.spacing[f0]
    where0 = feature_class(P, f0, fa.param[0], fa.param[1])
    fa.where = where0
    for idx in range(P.ring_ptr[f0], P.ring_ptr[f0 + 1]):
        p = P.ring[idx]
        if P.target[p] == NULL:
            continue
        if p != hp and box_gap(P.box + 6 * p, x) > reach:
            continue
        tier = try_patch(P, p, p == hp, x, fa, sc, &res, overflow)
        valid = tier >= 0
        if valid:
            dist = dist3(x, res.proximal)
            if tier < best_tier or tier == best_tier and dist < best:
                take_result(res, p, &P.options[p], out)
                best_tier = tier
                best = dist
        if p == hp:
            have_home = True
            home_valid = valid
            if not valid:
                take_result(res, p, &P.options[p], &home)
    # a patch beyond the foot's ring whose surface is nearer than the facets' foot and every
    # answer so far (the far side of a thin wall: its facets lie up to their sag farther
    # than the foot's), on that patch (tier 0)
    D = best if best < d0 else d0
    if P.foreign[f0] < D + d0:
        nf = foreign_patches(P, x, f0, D, found)
        for k in range(nf):
            p = found[k]
            if try_patch(P, p, False, x, fa, sc, &res, overflow) == 0:
                dist = dist3(x, res.proximal)
                # nearer, and on the side of it the facets put x (their sign is the mesh's:
                # a sheet's far face, as near as the foot, is not the one x faces)
                if dist < D and (res.gap > 0) == (fa.gap > 0):
                    take_result(res, p, &P.options[p], out)
                    best_tier = 0
                    best = dist
                    D = dist
                    foreign_source = p
    # the facets: at a sharp edge or corner, or where the home patch cannot answer (and the
    # foot is not on an open edge: past it is off the target)
    if fa.ok and (where0 == SHARP or not home_valid and where0 != OPEN_EDGE) \
            and (best_tier > 0 or d0 < best):
        if where0 == SHARP:  # the facets are the edge itself
            take_facets(fa, R_OK, out)
        else:
            facets_answer(P, x, fa, R_OK, out)
        return
    if out.source == BY_NOTHING:
        if have_home:  # the home patch's own verdict ('outside' past an open boundary)
            out[0] = home
            out.source = BY_NOTHING
        else:  # a home patch without a diffuse surface, on an open boundary
            nothing(OUTSIDE, R_FEW_NODES, out)
        return
    if not P.guard or out.source < 0:
        return
    if out.source == foreign_source:
        # the guard against the answering patch's own facets around its own foot
        if not (patch_facets_of(P, foreign_source, x, &fq) and fq.ok
                and within_guard(P, out, &fq, x, False)):
            guarded(P, x, fa, where0, out)
    elif fa.ok and not within_guard(P, out, fa, x, where0 == OPEN_EDGE):
        guarded(P, x, fa, where0, out)


cdef inline void guarded(const PassC *P, const double *x, const FacetAnswer *fa,
                         int8_t where0, Answer *out) noexcept nogil:
    """A diffuse answer the guard rejects: the mesh's own, with reason 'guard'."""
    if where0 == SHARP:
        take_facets(fa, R_GUARD, out)
    else:
        facets_answer(P, x, fa, R_GUARD, out)


cdef struct PassOut:
    # the outputs of `PatchedPass.project` (C-contiguous), as raw pointers: the record every
    # pass writes, and the pass's own (`projection.PASS_RECORD`)
    Record rec
    int64_t *source
    int64_t *facet
    double *facet_gap
    double *facet_normal
    double *guard_gap
    double *support_floor
    int64_t *cell
    double *cell_param


cdef struct PassScratch:
    # one thread's: the projection's scratch, the answer, the facets' answer
    Scratch *sc
    Answer a
    FacetAnswer fa


cdef inline void pass_row(const PassC *P, const double *x, int64_t r, PassScratch *t,
                          const PassOut *o) noexcept nogil:
    """`PatchedPass.project`'s work for one contactor (row r), the same from the serial loop
    and the parallel one."""
    cdef bint over
    cdef int e
    cdef const Answer *a = &t.a
    cdef const FacetAnswer *fa = &t.fa
    pass_one(P, x, t.sc, &t.a, &t.fa, &over)
    o.rec.gap[r] = a.gap
    for e in range(3):
        o.rec.normal[3 * r + e] = a.normal[e]
        o.rec.proximal[3 * r + e] = a.proximal[e]
    o.rec.status[r] = a.status
    o.rec.reason[r] = a.reason
    o.rec.support[r] = a.support
    o.rec.iterations[r] = a.iterations
    o.rec.rcond[r] = a.rcond
    o.rec.curvature[2 * r] = a.curvature[0]
    o.rec.curvature[2 * r + 1] = a.curvature[1]
    o.rec.terms[r] = a.terms
    o.source[r] = a.source
    o.facet[r] = fa.facet
    o.facet_gap[r] = fa.gap if fa.facet >= 0 else NAN
    for e in range(3):
        o.facet_normal[3 * r + e] = fa.normal[e] if fa.facet >= 0 else NAN
    # what an answer found elsewhere (the rigid element's) is guarded and supported by:
    # the faceted gap the guard measures from, and the floor of the answering patch's
    # support (its home patch's: `try_patch`)
    o.guard_gap[r] = NAN
    o.support_floor[r] = 0.0
    if fa.facet >= 0:
        o.guard_gap[r] = facet_height(P, fa, x, fa.where == OPEN_EDGE)
        if a.source >= 0 and a.source == P.label[fa.facet]:
            o.support_floor[r] = P.facet_size[fa.facet]
    o.cell[r] = a.cell if a.source == BY_CELLS else -1
    for e in range(2):
        o.cell_param[2 * r + e] = a.cell_param[e] if a.source == BY_CELLS else NAN
    o.rec.overflow[r] = over


cdef PassScratch *pass_scratch(int64_t cap, int nterms, int64_t near) noexcept nogil:
    """One thread's scratch (NULL: no memory)."""
    cdef PassScratch *t = <PassScratch *>malloc(sizeof(PassScratch))
    if t == NULL:
        return NULL
    t.sc = scratch_new(cap, nterms, near)
    if t.sc == NULL:
        free(t)
        return NULL
    return t


cdef void pass_scratch_free(PassScratch *t) noexcept nogil:
    if t != NULL:
        scratch_free(t.sc)
        free(t)


cdef class PatchedPass:
    """The compiled pass over a PatchedSurface's patches (module docstring), built once.

    Parameters
    ----------
    targets : list of mls._projection.Target or None
        Each patch's engine (None: a patch without a diffuse surface).
    options : list of dict or None
        Each patch's engine options (`DiffuseSurface._options()`).
    tables : list of facet._engine.FacetTables or None
        Each patch's own facets.
    patch_facets : list of (f_p,) int
        The global facet of each of a patch's facets.
    boxes : (P, 6) float
    facets : facet._engine.FacetTables
        The whole target's facets.
    arrays : dict
        label (F,), corners (F, 4), kind (F,), edge_class (F, 4) int8, vertex_class (n,)
        int8, facet_normal (F, 3), spacing (F,), ring_ptr (F + 1,), ring, gap_bound (F,),
        gap_lo (F,), gap_hi (F,), normal_angle (F,), normal_turn (F,), facet_size (F,),
        has_cell (F,) int8, cell_coef (F, 9, 3) or None (no table: the cells of the
        first-order facets computed where needed from nodes (n, 3), cell_normal (F, 4, 3),
        cell_shape3 (9, 6) and cell_shape4 (9, 8); (1, 9, 3): no curved cells),
        fring_ptr (F + 1,), fring (the facets' vertex rings), and the floats
        candidate_spacings, overshoot, smooth_overshoot, edge_eps, contact_tol, the flag
        guard.
    """
    cdef PassC c
    cdef list keep                 # every object the C arrays point into
    cdef int64_t nterms, near, nfacets

    def __init__(self, list targets, list options, list tables, list patch_facets, boxes,
                 FacetTables facets, dict arrays):
        cdef int npatches = len(targets)
        cdef int p
        cdef Target tg
        cdef FacetTables ft
        if not (len(options) == len(tables) == len(patch_facets) == npatches) or npatches == 0:
            raise ValueError("one engine, option set, facet table and facet list per patch")
        self.keep = [targets, tables, facets, arrays]
        self.c.npatches = npatches
        self.c.target = <TargetC **>malloc(npatches * sizeof(TargetC *))
        self.c.options = <Options *>malloc(npatches * sizeof(Options))
        self.c.tables = <Tables **>malloc(npatches * sizeof(Tables *))
        if self.c.target == NULL or self.c.options == NULL or self.c.tables == NULL:
            raise MemoryError("no memory for the patched pass")
        self.nterms = 0
        self.near = 1
        for p in range(npatches):
            self.c.target[p] = NULL
            self.c.tables[p] = NULL
            if targets[p] is None:
                continue
            tg = targets[p]
            ft = tables[p]
            self.c.target[p] = &tg.c
            self.c.tables[p] = &ft.t
            self.c.options[p] = make_options(options[p], False)
            self.nterms = max(self.nterms, self.c.options[p].nterms)
            self.near = max(self.near, self.c.options[p].spacing_neighbours)
        ptr = np.zeros(npatches + 1, np.int64)
        ptr[1:] = np.cumsum([len(f) for f in patch_facets])
        if ptr[npatches] >= 2 ** 31:
            raise ValueError("the patched pass indexes facets in int32: too many facets")
        # int32 (a facet index), and the one patch's own list itself where it is one
        flat = (np.ascontiguousarray(patch_facets[0], np.int32) if npatches == 1
                else np.concatenate([np.asarray(f, np.int32) for f in patch_facets])
                if ptr[npatches] else np.zeros(1, np.int32))
        if len(flat) == 0:
            flat = np.zeros(1, np.int32)
        box = np.ascontiguousarray(boxes, dtype=np.float64).reshape(npatches, 6)
        self.keep += [ptr, flat, box]
        cdef const int64_t[::1] ptr_v = ptr
        cdef const int32_t[::1] flat_v = flat
        cdef const double[:, ::1] box_v = box
        self.c.patch_ptr = &ptr_v[0]
        self.c.patch_facet = &flat_v[0]
        self.c.box = &box_v[0, 0]
        self.c.facets = &facets.t
        cdef const int64_t[::1] label = _array(arrays, "label", np.int64, self.keep)
        cdef const int64_t[:, ::1] corners = _array(arrays, "corners", np.int64, self.keep)
        cdef const int64_t[::1] kind = _array(arrays, "kind", np.int64, self.keep)
        cdef const int8_t[:, ::1] edge_class = _array(arrays, "edge_class", np.int8, self.keep)
        cdef const int8_t[::1] vertex_class = _array(arrays, "vertex_class", np.int8, self.keep)
        cdef const double[:, ::1] facet_normal = _array(arrays, "facet_normal", np.float64,
                                                        self.keep)
        cdef const double[::1] spacing = _array(arrays, "spacing", np.float64, self.keep)
        cdef const int32_t[::1] ring_ptr = _array(arrays, "ring_ptr", np.int32, self.keep)
        cdef const int32_t[::1] ring = _array(arrays, "ring", np.int32, self.keep)
        cdef const double[::1] gap_bound = _array(arrays, "gap_bound", np.float64, self.keep)
        cdef const double[::1] gap_lo = _array(arrays, "gap_lo", np.float64, self.keep)
        cdef const double[::1] gap_hi = _array(arrays, "gap_hi", np.float64, self.keep)
        cdef const double[::1] normal_angle = _array(arrays, "normal_angle", np.float64,
                                                     self.keep)
        cdef const double[::1] normal_turn = _array(arrays, "normal_turn", np.float64,
                                                    self.keep)
        cdef const double[::1] facet_size = _array(arrays, "facet_size", np.float64, self.keep)
        F = label.shape[0]
        self.nfacets = F
        if not (corners.shape[0] == kind.shape[0] == edge_class.shape[0] == spacing.shape[0]
                == facet_normal.shape[0] == gap_bound.shape[0] == normal_angle.shape[0]
                == normal_turn.shape[0]
                == gap_lo.shape[0] == gap_hi.shape[0]
                == facet_size.shape[0] == F
                and ring_ptr.shape[0] == F + 1 and F > 0 and ring.shape[0] > 0):
            raise ValueError("the patched pass's facet arrays disagree in length")
        self.c.label = &label[0]
        self.c.corners = &corners[0, 0]
        self.c.kind = &kind[0]
        self.c.edge_class = &edge_class[0, 0]
        self.c.vertex_class = &vertex_class[0]
        self.c.facet_normal = &facet_normal[0, 0]
        self.c.spacing = &spacing[0]
        self.c.ring_ptr = &ring_ptr[0]
        self.c.ring = &ring[0]
        self.c.gap_bound = &gap_bound[0]
        self.c.gap_lo = &gap_lo[0]
        self.c.gap_hi = &gap_hi[0]
        self.c.normal_angle = &normal_angle[0]
        self.c.normal_turn = &normal_turn[0]
        self.c.facet_size = &facet_size[0]
        cdef const int8_t[::1] has_cell = _array(arrays, "has_cell", np.int8, self.keep)
        cdef const int32_t[::1] fring_ptr = _array(arrays, "fring_ptr", np.int32, self.keep)
        cdef const int32_t[::1] fring = _array(arrays, "fring", np.int32, self.keep)
        if not (has_cell.shape[0] == F and fring_ptr.shape[0] == F + 1 and fring.shape[0] > 0):
            raise ValueError("the patched pass's cell arrays disagree in length")
        self.c.has_cell = &has_cell[0]
        self._cells(arrays, F, bool(np.any(np.asarray(has_cell))))
        self.c.fring_ptr = &fring_ptr[0]
        self.c.fring = &fring[0]
        self.c.contact_tol = arrays["contact_tol"]
        # the facets' coordinates in their own order (the tables hold them in search order),
        # an (F, 4, 3) temporary made only where a clearance needs it: a feature edge, or
        # another patch (both are +inf without one: `clearance.py`)
        classes = np.asarray(edge_class)
        if npatches > 1 or bool(np.isin(classes, (SHARP, SMOOTH)).any()):
            corner = np.asarray(facets.arrays["corner"])[np.asarray(facets.arrays["slot"])]
        else:
            corner = np.empty((0, 4, 3))  # never read: both clearances are +inf
        clear = np.ascontiguousarray(feature_clearance(
            corner, np.asarray(kind), classes, (SHARP, SMOOTH),
            float(facets.arrays["edge_eps"])), dtype=np.float64)
        self.keep.append(clear)
        cdef const double[::1] clearance = clear
        self.c.clearance = &clearance[0]
        far = np.ascontiguousarray(foreign_clearance(
            corner, np.asarray(kind), np.asarray(label), np.asarray(ring_ptr), np.asarray(ring),
            np.asarray(gap_bound)), dtype=np.float64)
        self.keep.append(far)
        cdef const double[::1] foreign = far
        self.c.foreign = &foreign[0]
        del corner
        self.c.bound_max = float(np.max(np.asarray(gap_bound)))
        self.c.guard = bool(arrays["guard"])
        self.c.candidate_spacings = arrays["candidate_spacings"]
        self.c.overshoot = arrays["overshoot"]
        self.c.smooth_overshoot = arrays["smooth_overshoot"]
        self.c.edge_eps = arrays["edge_eps"]

    def _cells(self, dict arrays, Py_ssize_t F, bint any_cell):
        """The curved cells' geometry: the table where the arrays give one (F, 9, 3), else
        what `cell_of` computes each first-order facet's cell from."""
        cdef const double[:, :, ::1] coef_v
        cdef const double[:, ::1] nodes, shape3, shape4, table
        cdef const int32_t[:, ::1] index
        coef = arrays.get("cell_coef")
        self.c.cell_coef = NULL
        self.c.nodes = self.c.cell_table = self.c.shape3 = self.c.shape4 = NULL
        self.c.cell_index = NULL
        if coef is not None:
            coef_v = _array(arrays, "cell_coef", np.float64, self.keep)
            if not (coef_v.shape[1] == 9 and coef_v.shape[2] == 3
                    and coef_v.shape[0] in (1, F)):
                raise ValueError("the patched pass's cell table disagrees in shape")
            self.c.cells = coef_v.shape[0] == F and any_cell
            self.c.cell_coef = &coef_v[0, 0, 0]
            return
        self.c.cells = any_cell
        if not any_cell:
            return
        nodes = _array(arrays, "nodes", np.float64, self.keep)
        index = _array(arrays, "cell_index", np.int32, self.keep)
        table = _array(arrays, "cell_table", np.float64, self.keep)
        shape3 = _array(arrays, "cell_shape3", np.float64, self.keep)
        shape4 = _array(arrays, "cell_shape4", np.float64, self.keep)
        if not (nodes.shape[1] == 3 and index.shape[0] == F and index.shape[1] == 4
                and table.shape[0] > 0 and table.shape[1] == 3 and shape3.shape[0] == 9
                and shape3.shape[1] == 6 and shape4.shape[0] == 9 and shape4.shape[1] == 8
                and np.asarray(index).max() < table.shape[0]):
            raise ValueError("the patched pass's cell arrays disagree in shape")
        self.c.nodes = &nodes[0, 0]
        self.c.cell_index = &index[0, 0]
        self.c.cell_table = &table[0, 0]
        self.c.shape3 = &shape3[0, 0]
        self.c.shape4 = &shape4[0, 0]

    def __dealloc__(self):
        free(self.c.target)
        free(self.c.options)
        free(self.c.tables)

    def project(self, const double[:, ::1] points, const int64_t[::1] rows, dict out,
                int64_t cap, int threads=0):
        """Answer the contactors points[rows] (module docstring), each into its own row of
        the arrays of `out` (`projection.allocate(len(points), PASS_RECORD)`): the record
        every pass writes, and `facet`, `facet_gap` and `facet_normal` the faceted answer
        (facet -1 where there is none), `guard_gap` the faceted gap the guard measured from
        (`facet_height`) and `support_floor` the answering patch's support floor (0: none),
        `cell` and `cell_param` the curved cell and its
        parameters (a, b) of a curved-cell answer (-1 and NaN elsewhere), `source` what
        answered. overflow[r] is set where a support had more than `cap` nodes (run those
        rows again with a larger cap). `threads`: OpenMP threads of the loop (0:
        `threads.threads_for`'s; 1: a plain loop, no parallel region)."""
        cdef Py_ssize_t m = rows.shape[0], i, n = points.shape[0]
        cdef PassScratch *t
        cdef PassOut o
        cdef int failed = 0
        cdef int *failedp = &failed
        _check(np.asarray(points), np.asarray(rows))
        record_of(out, n, &o.rec)
        cdef int64_t[::1] source = _output(out, "source", n)
        cdef int64_t[::1] facet = _output(out, "facet", n)
        cdef double[::1] facet_gap = _output(out, "facet_gap", n)
        cdef double[:, ::1] facet_normal = _output(out, "facet_normal", n)
        cdef double[::1] guard_gap = _output(out, "guard_gap", n)
        cdef double[::1] support_floor = _output(out, "support_floor", n)
        cdef int64_t[::1] cell = _output(out, "cell", n)
        cdef double[:, ::1] cell_param = _output(out, "cell_param", n)
        if facet_normal.shape[1] != 3 or cell_param.shape[1] != 2:
            raise ValueError("facet_normal must have 3 columns, cell_param 2")
        if m == 0:
            return
        o.source, o.facet, o.facet_gap = &source[0], &facet[0], &facet_gap[0]
        o.facet_normal, o.cell, o.cell_param = &facet_normal[0, 0], &cell[0], \
            &cell_param[0, 0]
        o.guard_gap, o.support_floor = &guard_gap[0], &support_floor[0]
        cdef const double *pts = &points[0, 0]
        cdef const int64_t *rw = &rows[0]
        cdef int chunk
        if threads <= 0:
            threads = threads_for(m, "pass")
        if threads == 1:  # no parallel region (threads.py)
            with nogil:
                t = pass_scratch(cap, <int>self.nterms, self.near)
                if t != NULL:
                    for i in range(m):
                        pass_row(&self.c, pts + 3 * rw[i], rw[i], t, &o)
                    pass_scratch_free(t)
                else:
                    failed = 1
        else:
            chunk = chunk_size(m, threads, 32)
            with nogil, parallel(num_threads=threads):
                t = pass_scratch(cap, <int>self.nterms, self.near)
                if t == NULL:
                    failedp[0] = 1
                for i in prange(m, schedule="dynamic", chunksize=chunk):
                    if t != NULL:
                        pass_row(&self.c, pts + 3 * rw[i], rw[i], t, &o)
                pass_scratch_free(t)
        if failed:
            raise MemoryError("no memory for the projection's scratch")

    def within_guard(self, const double[::1] gap, const double[:, ::1] normal,
                     const int64_t[::1] facet, const double[::1] guard_gap,
                     const double[::1] apart, plane=None):
        """(m,) bool: whether answers found elsewhere than by this pass (a rigid target's
        gap, `element.patched_contact`) pass the projection's own guard (`guard_holds`):
        gap (m,) and normal (m, 3) at contactors whose faceted answer is on `facet` (m,),
        `guard_gap` the faceted gap the projection's guard measured from (its output of
        that name: `facet_height`), their proximal points `apart` (m,) from the faceted
        feet; `plane` (m,) bool: fitted with the plane (None: none was). True where the
        guard is off or there is no faceted answer (facet -1)."""
        cdef Py_ssize_t m = gap.shape[0], i
        if normal.shape[0] != m or normal.shape[1] != 3 or facet.shape[0] != m \
                or guard_gap.shape[0] != m or apart.shape[0] != m:
            raise ValueError("within_guard: the arrays' lengths differ")
        flat = np.zeros(m, np.uint8) if plane is None \
            else np.ascontiguousarray(plane, dtype=bool).view(np.uint8)
        if flat.shape[0] != m:
            raise ValueError("within_guard: the arrays' lengths differ")
        holds = np.ones(m, np.uint8)
        cdef const unsigned char[::1] pl = flat
        cdef unsigned char[::1] out = holds
        cdef int64_t F = self.nfacets
        for i in range(m):
            if facet[i] >= F:
                raise ValueError(f"within_guard: facet {facet[i]} of a target of {F} facets")
        if not self.c.guard:
            return holds.view(bool)
        with nogil:
            for i in range(m):
                if facet[i] >= 0:
                    out[i] = guard_holds(&self.c, facet[i], pl[i], gap[i] - guard_gap[i],
                                         &normal[i, 0], apart[i])
        return holds.view(bool)


def compact_normals(const double[:, :, ::1] normal, const int64_t[:, ::1] corners,
                    const int64_t[::1] key):
    """Corner normals (F, 4, 3) as (index (F, 4) int32, table (m, 3)): corner j of facet f
    has normal table[index[f, j]] (-1: no corner, a triangle's fourth), bit for bit. The
    corners at one node (by identity `key`) with the same normal bits share a row: a node's
    normal in each of its smooth regions, once (a smooth closed target: one row a node, 56
    bytes a node instead of 192). One pass over the corners, each compared with the rows
    of its node (a chain per node)."""
    cdef Py_ssize_t F = corners.shape[0], n = key.shape[0], f, j, m = 0
    cdef int64_t c, k, s
    cdef int32_t e
    if not (normal.shape[0] == F and normal.shape[1] == 4 and normal.shape[2] == 3
            and corners.shape[1] == 4):
        raise ValueError("corner normals: arrays disagree in shape")
    if 4 * F >= 2 ** 31:
        raise ValueError("corner normals: too many facets for int32 indices")
    index_a = np.full((F, 4), -1, np.int32)
    head_a = np.full(max(n, 1), -1, np.int32)      # each node's last row
    chain_a = np.empty(max(4 * F, 1), np.int32)    # each row's previous row at its node
    rep_a = np.empty(max(4 * F, 1), np.int64)      # each row's first corner, 4 f + j
    cdef int32_t[:, ::1] index = index_a
    cdef int32_t[::1] head = head_a, chain = chain_a
    cdef int64_t[::1] rep = rep_a
    with nogil:
        for f in range(F):
            for j in range(4):
                c = corners[f, j]
                if c < 0:
                    continue
                k = key[c]
                e = head[k]
                while e >= 0:
                    s = rep[e]
                    if memcmp(&normal[s // 4, s % 4, 0], &normal[f, j, 0],
                              3 * sizeof(double)) == 0:
                        break
                    e = chain[e]
                if e < 0:
                    e = <int32_t>m
                    rep[m] = 4 * f + j
                    chain[m] = head[k]
                    head[k] = e
                    m += 1
                index[f, j] = e
    del head_a, chain_a
    table_a = np.empty((max(m, 1), 3))
    cdef double[:, ::1] table = table_a
    table[0, 0] = table[0, 1] = table[0, 2] = 0.0
    for e in range(m):
        s = rep[e]
        table[e, 0] = normal[s // 4, s % 4, 0]
        table[e, 1] = normal[s // 4, s % 4, 1]
        table[e, 2] = normal[s // 4, s % 4, 2]
    return index_a, table_a


def _check(points, rows):
    n = len(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError("points must have shape (m, 3)")
    if len(rows) and (rows.min() < 0 or rows.max() >= n):
        raise ValueError("rows index past the points")


def _output(dict out, str name, Py_ssize_t n):
    """The pass's own output `name` (`projection.PASS_RECORD`), with n rows; else one line
    naming it."""
    if name not in out:
        raise ValueError(f"the pass's outputs lack '{name}' (projection.allocate)")
    arr = out[name]
    if arr.shape[0] != n:
        raise ValueError(f"output {name} of shape {arr.shape}: expected {n} rows")
    return arr


def _array(dict arrays, str name, dtype, list keep):
    arr = np.ascontiguousarray(arrays[name], dtype=dtype)
    keep.append(arr)
    return arr
