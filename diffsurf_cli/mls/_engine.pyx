# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The projection onto the diffuse surface [§3-§4.1], written once, in compiled code.

One contactor at a time, in parallel over contactors (OpenMP `prange`, per-thread scratch
allocated once per call): local node spacing, support and frame, weighted least squares
[15]-[17], Newton on [30], normal [29], gap [32], status [33], the on-target tests, and the
pairing (frame, radius, support) the contact element holds fixed [§4.2]. `surface.py`
orchestrates nothing per point: the retry with a wider support and the re-centring loop run
here too, so a whole cloud is one call.

Searches use a uniform grid of cells (`build_grid`), and a k-d tree (`build_tree`) for the
nearest nodes of a contactor more than a cell off the target. Linear algebra is textbook
(Golub & Van Loan): the normal equations [16]-[17] by Cholesky where the fit is well
conditioned (the equilibrated Gram's R is then QR's, `normal_fit`), else Householder QR of
W^½P (written out per step for the linear and quadratic bases), the 3x3 frame's normal by
powers of the covariance's adjugate (a cyclic Jacobi where its eigenvalues are too close for
them), one-sided Jacobi for the exact σmin/σmax where the cheap bound cannot decide (see
`triangular_rcond`). Instructions a point: `benchmarks/engine_speed.py --callgrind`.

Tolerances and constants are read from `diffsurf_cli.tol` into the `Options` struct at call
time; nothing here is a hand-kept copy of a Python value.
"""
import numpy as np

from libc.math cimport (sqrt, fabs, exp, hypot, atan2, asin, fmod, isfinite, isnan, cos, sin,
                        INFINITY, NAN)
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy
from libc.stdint cimport int64_t, int8_t, uint8_t, uint64_t
from cython.parallel cimport prange, parallel

from .. import tol
from . import basis as _basis

cdef extern from *:
    """
    #ifdef _OPENMP
    #include <omp.h>
    static int ds_max_threads(void) { return omp_get_max_threads(); }
    #else
    static int ds_max_threads(void) { return 1; }
    #endif
    """
    int ds_max_threads() noexcept nogil

cdef double PI = 3.141592653589793

# status [33] and reason codes (surface.STATUS, surface.REASONS)
cdef enum:
    OPEN = 0
    CONTACT = 1
    PENETRATION = 2
    OUTSIDE = 3
    FAILED = 4
cdef enum:
    R_OK = 0
    R_BAD_POINT = 1
    R_FEW_NODES = 2
    R_ILL = 3
    R_OFF_TARGET = 4
    R_NO_CONVERGENCE = 5
    R_NOT_SETTLED = 6
    R_STEEP = 7
cdef enum:
    WENDLAND = 0
    GAUSS = 1
    SINGULAR = 2

cdef enum:
    NTERMS_MAX = 10              # the cubic basis
    NREDUCED_MAX = 12            # reduced bases of a basis (basis.REDUCED)

WEIGHT_CODES = {"wendland": WENDLAND, "gauss": GAUSS, "singular": SINGULAR}
MAX_TERMS = NTERMS_MAX


def threads():
    """Threads the compiled loops use (OpenMP's, capped by OMP_NUM_THREADS)."""
    return ds_max_threads()


# --------------------------------------------------------------------------------------------
# the grid of cells
# --------------------------------------------------------------------------------------------

#: Grid cells per node at most (a dense grid over the bounding box of a sparse, elongated
#: target could otherwise be huge); the cell grows until the grid fits.
MAX_CELLS_PER_NODE = 8


def build_grid(coords, double cell):
    """A uniform grid over `coords` (n, 3): (lo, cell, dims, start, order).

    Nodes of cell c are ``order[start[c]:start[c + 1]]``; cell indices are
    (i * dims[1] + j) * dims[2] + k.
    """
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    n = len(coords)
    lo = coords.min(axis=0) if n else np.zeros(3)
    span = coords.max(axis=0) - lo if n else np.zeros(3)
    if not cell > 0:
        cell = 1.0
    limit = max(MAX_CELLS_PER_NODE * n, 64)
    while True:
        dims = np.maximum(np.floor(span / cell).astype(np.int64) + 1, 1)
        if np.prod(dims.astype(np.float64)) <= limit:
            break
        cell *= 1.25
    ijk = np.minimum(((coords - lo) / cell).astype(np.int64), dims - 1)
    lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(lin, kind="stable").astype(np.int64)
    start = np.searchsorted(lin[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
    return lo, float(cell), dims, start, order


#: The largest ring `empty_rings` stores (a uint8 a cell); farther rings store this bound.
MAX_RING = 255


def empty_rings(dims, const int64_t[::1] start):
    """Per cell of a grid (`build_grid`'s dims and start), its Chebyshev distance in cells to
    the nearest cell holding a node, capped at MAX_RING (MAX_RING too when the grid is
    empty): the layers of cells 0 .. ring - 1 around that cell hold no node, so a search
    from it (`knn`) starts at layer `ring`. Two raster passes of the 3x3x3 chamfer mask with
    unit weights, exact for the chessboard distance (Rosenfeld & Pfaltz 1966)."""
    cdef int64_t d0 = int(dims[0]), d1 = int(dims[1]), d2 = int(dims[2])
    cdef int64_t ncell = d0 * d1 * d2
    if start.shape[0] != ncell + 1:
        raise ValueError("start must have prod(dims) + 1 entries")
    out = np.empty(ncell, dtype=np.uint8)
    cdef uint8_t[::1] ring = out
    cdef int64_t i, j, k, c, t, a, b, e, ii, jj, kk, best, sweep, step
    cdef int64_t top = MAX_RING
    with nogil:
        for c in range(ncell):
            ring[c] = 0 if start[c + 1] > start[c] else <uint8_t>top
        # forward: the 13 neighbours before a cell in raster order; backward: the 13 after
        for sweep in range(2):
            step = 1 if sweep == 0 else -1
            for t in range(ncell):
                c = t if sweep == 0 else ncell - 1 - t
                if ring[c] == 0:
                    continue
                i = c // (d1 * d2)
                j = (c // d2) % d1
                k = c % d2
                best = ring[c]
                for a in range(-1, 2):
                    for b in range(-1, 2):
                        for e in range(-1, 2):
                            # (a, b, e) precedes (0, 0, 0) in raster order, in `step`'s sense
                            if step * (a * 9 + b * 3 + e) >= 0:
                                continue
                            ii = i + a
                            jj = j + b
                            kk = k + e
                            if ii < 0 or ii >= d0 or jj < 0 or jj >= d1 or kk < 0 or kk >= d2:
                                continue
                            best = imin(best, <int64_t>ring[(ii * d1 + jj) * d2 + kk] + 1)
                ring[c] = <uint8_t>best
    return out


#: The most nodes a leaf of a grid's k-d tree (`build_tree`) holds.
TREE_LEAF = 8


def build_tree(coords, int64_t leaf=TREE_LEAF):
    """A balanced k-d tree over `coords` (n, 3), n >= 1: (box (T, 6), span (T, 2), perm (n,)).

    Tree node t (t = 0 the root) has children 2t + 1 and 2t + 2 and holds the nodes
    perm[span[t, 0]:span[t, 1]], in box[t] = (lo xyz, hi xyz), their bounding box; a node
    splits its nodes at their median along the box's longest side, halves differing by at most
    one, down to leaves of at most `leaf` nodes, all at the same depth (T = 2^(depth+1) - 1).
    Built by quickselect (Hoare), O(n log n)."""
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    cdef int64_t n = len(coords), depth = 0, t, level, lo, hi, mid, i, j, a, b, e, ax, tmp
    cdef int64_t first, count
    if n == 0:
        raise ValueError("a k-d tree needs nodes")
    while (n + (1 << depth) - 1) >> depth > leaf:
        depth += 1
    count = (2 << depth) - 1
    box_ = np.empty((count, 6))
    span_ = np.empty((count, 2), dtype=np.int64)
    perm_ = np.arange(n, dtype=np.int64)
    cdef double[:, ::1] box = box_
    cdef int64_t[:, ::1] span = span_
    cdef int64_t[::1] perm = perm_
    cdef const double[:, ::1] x = coords
    cdef double v, pivot, ext
    with nogil:
        span[0, 0] = 0
        span[0, 1] = n
        for level in range(depth + 1):
            first = (1 << level) - 1
            for t in range(first, 2 * first + 1):
                lo = span[t, 0]
                hi = span[t, 1]
                for e in range(3):
                    box[t, e] = INFINITY
                    box[t, 3 + e] = -INFINITY
                for i in range(lo, hi):
                    for e in range(3):
                        v = x[perm[i], e]
                        box[t, e] = dmin(box[t, e], v)
                        box[t, 3 + e] = dmax(box[t, 3 + e], v)
                if level == depth:
                    continue
                ax = 0
                ext = box[t, 3] - box[t, 0]
                for e in range(1, 3):
                    if box[t, 3 + e] - box[t, e] > ext:
                        ext = box[t, 3 + e] - box[t, e]
                        ax = e
                # quickselect: perm[lo:mid] <= perm[mid] <= perm[mid + 1:hi] along ax
                mid = lo + (hi - lo) // 2
                a = lo
                b = hi - 1
                while a < b:
                    pivot = x[perm[(a + b) // 2], ax]
                    i = a
                    j = b
                    while i <= j:
                        while x[perm[i], ax] < pivot:
                            i += 1
                        while x[perm[j], ax] > pivot:
                            j -= 1
                        if i <= j:
                            tmp = perm[i]
                            perm[i] = perm[j]
                            perm[j] = tmp
                            i += 1
                            j -= 1
                    if mid <= j:
                        b = j
                    elif mid >= i:
                        a = i
                    else:
                        break
                span[2 * t + 1, 0] = lo
                span[2 * t + 1, 1] = mid
                span[2 * t + 2, 0] = mid
                span[2 * t + 2, 1] = hi
    return box_, span_, perm_


cdef struct Tree:
    const double *box      # (count, 6) `build_tree`
    const int64_t *span    # (count, 2)
    const int64_t *perm    # (n,) node of each tree position
    const double *coords   # (n, 3) the nodes in tree order
    int64_t count, leaves  # tree nodes; the first leaf is count - leaves


cdef struct Grid:
    const double *coords   # (n, 3)
    double lo[3]
    double cell
    int64_t dims[3]
    const int64_t *start   # (prod(dims) + 1,)
    const int64_t *order   # (n,) nodes sorted by cell
    const uint8_t *ring    # (prod(dims),) per cell: the layers around it known empty
    bint sorted            # order is the identity (the nodes are numbered in cell order)
    Tree tree              # count 0: none (`knn` only)


cdef class _GridArrays:
    """The arrays of one grid, kept alive while its `Grid` struct points into them."""
    cdef const double[:, ::1] coords
    cdef const int64_t[::1] start
    cdef const int64_t[::1] order
    cdef const uint8_t[::1] ring
    cdef const double[:, ::1] tree_box
    cdef const int64_t[:, ::1] tree_span
    cdef const int64_t[::1] tree_perm
    cdef const double[:, ::1] tree_coords
    cdef Grid grid

    def __init__(self, coords, double cell, bint tree=False):
        lo, cell, dims, start, order = build_grid(coords, cell)
        self.coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
        self.start = start
        self.order = order
        self.ring = empty_rings(dims, start)
        self.grid.coords = &self.coords[0, 0]
        self.grid.start = &self.start[0]
        self.grid.order = &self.order[0]
        self.grid.ring = &self.ring[0]
        self.grid.sorted = bool(np.all(np.asarray(order) == np.arange(len(order))))
        self.grid.cell = cell
        for e in range(3):
            self.grid.lo[e] = lo[e]
            self.grid.dims[e] = dims[e]
        self.grid.tree.count = 0
        if tree and len(self.coords):
            box, span, perm = build_tree(self.coords)
            self.tree_box = box
            self.tree_span = span
            self.tree_perm = perm
            self.tree_coords = np.ascontiguousarray(np.asarray(self.coords)[perm])
            self.grid.tree.box = &self.tree_box[0, 0]
            self.grid.tree.span = &self.tree_span[0, 0]
            self.grid.tree.perm = &self.tree_perm[0]
            self.grid.tree.coords = &self.tree_coords[0, 0]
            self.grid.tree.count = len(box)
            self.grid.tree.leaves = (len(box) + 1) // 2


cdef inline double dmin(double a, double b) noexcept nogil:
    return b if b < a else a


cdef inline double dmax(double a, double b) noexcept nogil:
    return b if b > a else a


cdef inline int64_t imin(int64_t a, int64_t b) noexcept nogil:
    return b if b < a else a


cdef inline int64_t imax(int64_t a, int64_t b) noexcept nogil:
    return b if b > a else a


cdef inline int64_t cell_index(double x, double lo, double cell, int64_t dim) noexcept nogil:
    """Cell of x along one axis, clamped to the grid (as a float first: far points stay
    finite ints); NaN gives cell 0 (callers never pass NaN)."""
    cdef double c = (x - lo) / cell
    c = dmin(dmax(c, 0.0), <double>dim - 1.0)
    if isnan(c):
        return 0
    return <int64_t>c


cdef inline uint64_t spread_bits(uint64_t x) noexcept nogil:
    """The low 21 bits of x, two zero bits after each (one coordinate of a Morton key)."""
    x &= <uint64_t>0x1fffffULL
    x = (x | (x << 32)) & <uint64_t>0x1f00000000ffffULL
    x = (x | (x << 16)) & <uint64_t>0x1f0000ff0000ffULL
    x = (x | (x << 8)) & <uint64_t>0x100f00f00f00f00fULL
    x = (x | (x << 4)) & <uint64_t>0x10c30c30c30c30c3ULL
    x = (x | (x << 2)) & <uint64_t>0x1249249249249249ULL
    return x


cdef inline double distance2(const double *coords, int64_t node, const double *p) noexcept nogil:
    cdef const double *x = coords + 3 * node
    cdef double d = x[0] - p[0], d2
    d2 = d * d
    d = x[1] - p[1]
    d2 += d * d
    d = x[2] - p[2]
    return d2 + d * d


cdef inline void insert_sorted(int64_t *idx, double *d2s, int64_t pos, int64_t node,
                               double d2) noexcept nogil:
    """Insert (node, d2) into the list sorted by d2 whose first `pos` entries are filled."""
    while pos > 0 and d2s[pos - 1] > d2:
        d2s[pos] = d2s[pos - 1]
        idx[pos] = idx[pos - 1]
        pos -= 1
    d2s[pos] = d2
    idx[pos] = node


cdef inline int64_t offer(int64_t *best_i, double *best_d2, int64_t k, int64_t count,
                          int64_t node, double d2) noexcept nogil:
    """Offer (node, d2) to the k nearest so far (`count` of them, sorted); the new count."""
    if count == k and d2 >= best_d2[k - 1]:
        return count
    insert_sorted(best_i, best_d2, imin(count, k - 1), node, d2)
    return count + 1 if count < k else count


cdef inline double slab_distance(double x, double lo, double cell, int64_t i,
                                 double margin) noexcept nogil:
    """The distance from x to the slab of cells i along one axis, less `margin` (a node sits
    in the cell of its rounded (x - lo) / cell), at least 0."""
    cdef double a = lo + <double>i * cell
    return dmax(dmax(a - x, x - (a + cell)) - margin, 0.0)


cdef inline int64_t scan_range(const Grid *g, const double *p, int64_t k, int64_t a0,
                               int64_t a1, int64_t count, int64_t *best_i,
                               double *best_d2) noexcept nogil:
    """The nodes order[a0:a1] offered to the k nearest so far (`count` of them)."""
    cdef int64_t a, node
    for a in range(a0, a1):
        node = a if g.sorted else g.order[a]
        count = offer(best_i, best_d2, k, count, node, distance2(g.coords, node, p))
    return count


cdef int64_t knn(const Grid *g, const double *p, int64_t k, int64_t *best_i,
                 double *best_d2) noexcept nogil:
    """The k nearest nodes of p, nearest first; returns how many (<= k). Layers of cells
    around p's cell, until the k-th nearest is nearer than any cell of the next layer.

    The layers the grid's rings (`empty_rings`) know empty are skipped at once (a contactor
    several cells off the target). A layer's cells are read column by column (i, j): a
    column on the layer's rim is one range of nodes (its cells are adjacent in the node
    order), an inner column two cells, top and bottom. Once k nodes are in hand, only the
    columns within the k-th distance are visited, and the inner ones only when their top or
    bottom cell is (the tests per column and per cell then skip the same ones as over the
    whole layer: the same nodes, read in the same order). The next layer is at least as far
    as the nearest face of the box of cells read so far, faces on the grid's boundary
    excepted (nothing lies beyond them)."""
    cdef int64_t ci = cell_index(p[0], g.lo[0], g.cell, g.dims[0])
    cdef int64_t cj = cell_index(p[1], g.lo[1], g.cell, g.dims[1])
    cdef int64_t ck = cell_index(p[2], g.lo[2], g.cell, g.dims[2])
    cdef int64_t cc[3]
    cdef int64_t count = 0, layer, i, j, di, dj, c, k0, k1, kk, di0, di1, dj0, dj1
    cdef int64_t last = imax(g.dims[0], imax(g.dims[1], g.dims[2]))
    cdef int e
    cdef double reach, face, dx, dy, dz, dxy2, rz, r
    cdef double margin3[3]
    cdef int64_t lo_k, hi_k
    cdef bint rim_i, inner
    cc[0] = ci
    cc[1] = cj
    cc[2] = ck
    for e in range(3):
        margin3[e] = 1e-9 * (fabs(p[e]) + fabs(g.lo[e]) + <double>(g.dims[e] + 1) * g.cell)
    # layers 0 .. ring - 1 around p's cell hold no node
    layer = imin(<int64_t>g.ring[(ci * g.dims[1] + cj) * g.dims[2] + ck], last)
    while True:
        k0 = imax(ck - layer, 0)
        k1 = imin(ck + layer, g.dims[2] - 1)
        di0 = -layer
        di1 = layer
        dj0 = -layer
        dj1 = layer
        inner = True
        if count == k:
            # the columns within the k-th distance so far (less two margins: a superset of
            # those the column test below reads), and whether an inner column's top or bottom
            # cell can be
            r = sqrt(best_d2[k - 1])
            di0 = imax(di0, cell_index(p[0] - r - 2.0 * margin3[0], g.lo[0], g.cell,
                                       g.dims[0]) - ci)
            di1 = imin(di1, cell_index(p[0] + r + 2.0 * margin3[0], g.lo[0], g.cell,
                                       g.dims[0]) - ci)
            dj0 = imax(dj0, cell_index(p[1] - r - 2.0 * margin3[1], g.lo[1], g.cell,
                                       g.dims[1]) - cj)
            dj1 = imin(dj1, cell_index(p[1] + r + 2.0 * margin3[1], g.lo[1], g.cell,
                                       g.dims[1]) - cj)
            inner = False
            kk = ck - layer
            if kk >= 0:
                dz = slab_distance(p[2], g.lo[2], g.cell, kk, margin3[2])
                inner = dz * dz < best_d2[k - 1]
            kk = ck + layer
            if not inner and layer > 0 and kk < g.dims[2]:
                dz = slab_distance(p[2], g.lo[2], g.cell, kk, margin3[2])
                inner = dz * dz < best_d2[k - 1]
        for di in range(di0, di1 + 1):
            i = ci + di
            if i < 0 or i >= g.dims[0]:
                continue
            dx = slab_distance(p[0], g.lo[0], g.cell, i, margin3[0])
            rim_i = di == layer or di == -layer
            dj = dj0 - 1
            while dj < dj1:
                dj += 1
                if not (rim_i or inner) and -layer < dj < layer:
                    dj = layer - 1  # this row's inner columns read nothing: on to its rim
                    continue
                j = cj + dj
                if j < 0 or j >= g.dims[1]:
                    continue
                # columns and cells wholly beyond the k-th nearest so far are skipped (a far
                # contactor's box holds many nodes, few near it)
                dxy2 = dx * dx
                dy = slab_distance(p[1], g.lo[1], g.cell, j, margin3[1])
                dxy2 += dy * dy
                if count == k and dxy2 >= best_d2[k - 1]:
                    continue
                c = (i * g.dims[1] + j) * g.dims[2]
                if rim_i or dj == layer or dj == -layer:
                    lo_k = k0
                    hi_k = k1
                    if count == k:
                        rz = sqrt(best_d2[k - 1] - dxy2) + margin3[2]
                        lo_k = imax(lo_k, cell_index(p[2] - rz, g.lo[2], g.cell, g.dims[2]))
                        hi_k = imin(hi_k, cell_index(p[2] + rz, g.lo[2], g.cell, g.dims[2]))
                    if lo_k <= hi_k:
                        count = scan_range(g, p, k, g.start[c + lo_k], g.start[c + hi_k + 1],
                                           count, best_i, best_d2)
                    continue
                kk = ck - layer
                if kk >= 0:
                    dz = slab_distance(p[2], g.lo[2], g.cell, kk, margin3[2])
                    if not (count == k and dxy2 + dz * dz >= best_d2[k - 1]):
                        count = scan_range(g, p, k, g.start[c + kk], g.start[c + kk + 1], count,
                                           best_i, best_d2)
                kk = ck + layer
                if layer > 0 and kk < g.dims[2]:
                    dz = slab_distance(p[2], g.lo[2], g.cell, kk, margin3[2])
                    if not (count == k and dxy2 + dz * dz >= best_d2[k - 1]):
                        count = scan_range(g, p, k, g.start[c + kk], g.start[c + kk + 1], count,
                                           best_i, best_d2)
        # every node not read yet lies beyond a face of the box of cells read so far
        # (less a margin far above the rounding of a node's cell (x - lo) / cell)
        reach = INFINITY
        for e in range(3):
            if cc[e] - layer > 0:
                face = p[e] - (g.lo[e] + <double>(cc[e] - layer) * g.cell)
                reach = dmin(reach, face - margin3[e])
            if cc[e] + layer < g.dims[e] - 1:
                face = g.lo[e] + <double>(cc[e] + layer + 1) * g.cell - p[e]
                reach = dmin(reach, face - margin3[e])
        if count == k and (reach == INFINITY or (reach > 0 and best_d2[k - 1] <= reach * reach)):
            break
        if layer >= last:
            break
        layer += 1
    return count


cdef int64_t ball(const Grid *g, const double *p, double r2, int64_t cap, int64_t *out_i,
                  double *out_d2) noexcept nogil:
    """All nodes at squared distance <= r2 from p, in grid order (the support is a set);
    returns their number (only the first `cap` are stored: a larger return value means the
    scratch was too small)."""
    cdef double r = sqrt(r2)
    cdef int64_t i0 = cell_index(p[0] - r, g.lo[0], g.cell, g.dims[0])
    cdef int64_t i1 = cell_index(p[0] + r, g.lo[0], g.cell, g.dims[0])
    cdef int64_t j0 = cell_index(p[1] - r, g.lo[1], g.cell, g.dims[1])
    cdef int64_t j1 = cell_index(p[1] + r, g.lo[1], g.cell, g.dims[1])
    cdef int64_t k0 = cell_index(p[2] - r, g.lo[2], g.cell, g.dims[2])
    cdef int64_t k1 = cell_index(p[2] + r, g.lo[2], g.cell, g.dims[2])
    cdef double d2
    cdef int64_t count = 0, i, j, kk, c, a, node
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            c = (i * g.dims[1] + j) * g.dims[2]
            if g.sorted:  # node a is the a-th in cell order: no indirection
                for a in range(g.start[c + k0], g.start[c + k1 + 1]):  # cells k0..k1 adjacent
                    d2 = distance2(g.coords, a, p)
                    if d2 <= r2:
                        if count < cap:
                            out_i[count] = a
                            out_d2[count] = d2
                        count += 1
                continue
            for a in range(g.start[c + k0], g.start[c + k1 + 1]):
                node = g.order[a]
                d2 = distance2(g.coords, node, p)
                if d2 <= r2:
                    if count < cap:
                        out_i[count] = node
                        out_d2[count] = d2
                    count += 1
    return count


cdef inline double box_gap2(const double *box, const double *p, double margin) noexcept nogil:
    """The squared distance from p to a box (lo xyz, hi xyz), less `margin` along each axis."""
    cdef double d, d2 = 0.0
    cdef int e
    for e in range(3):
        d = dmax(dmax(box[e] - p[e], p[e] - box[3 + e]) - margin, 0.0)
        d2 += d * d
    return d2


#: Tree nodes the k-d tree search keeps pending at most: two a level (depth <= 60).
cdef enum:
    TREE_STACK = 128


cdef int64_t tree_knn(const Tree *tr, const double *p, int64_t k, int64_t *best_i,
                      double *best_d2) noexcept nogil:
    """The k nearest nodes of p, nearest first (as `knn`), by the grid's k-d tree: depth
    first, the nearer child first, skipping every tree node whose box is beyond the k-th
    nearest so far. For a contactor several cells off the target, where a search over cells
    visits every cell its k-th distance reaches (a box of them, mostly empty), the tree's
    boxes hug the target: it reads a few leaves."""
    cdef int64_t stack_t[TREE_STACK]
    cdef double stack_d2[TREE_STACK]
    cdef int64_t sp = 1, t, a, count = 0, l, r, first_leaf = tr.count - tr.leaves
    cdef double dl, dr, margin = 0.0
    cdef int e
    for e in range(3):
        margin = dmax(margin, 1e-12 * (fabs(p[e]) + fabs(tr.box[e]) + fabs(tr.box[3 + e])))
    stack_t[0] = 0
    stack_d2[0] = box_gap2(tr.box, p, margin)
    while sp > 0:
        sp -= 1
        t = stack_t[sp]
        if count == k and stack_d2[sp] >= best_d2[k - 1]:
            continue
        if t >= first_leaf:
            for a in range(tr.span[2 * t], tr.span[2 * t + 1]):
                count = offer(best_i, best_d2, k, count, tr.perm[a], distance2(tr.coords, a, p))
            continue
        l = 2 * t + 1
        dl = box_gap2(tr.box + 6 * l, p, margin)
        dr = box_gap2(tr.box + 6 * (l + 1), p, margin)
        # the farther child first on the stack, the nearer searched first; a child beyond the
        # k-th nearest so far is not stacked at all
        if dr < dl:
            dl, dr = dr, dl
            l += 1
            r = l - 1
        else:
            r = l + 1
        if not (count == k and dr >= best_d2[k - 1]):
            stack_t[sp] = r
            stack_d2[sp] = dr
            sp += 1
        if not (count == k and dl >= best_d2[k - 1]):
            stack_t[sp] = l
            stack_d2[sp] = dl
            sp += 1
    return count


cdef double NEAR_REACH = 0.75  # cells: the first box `nearest` searches


cdef int64_t nearest(const Grid *g, const double *p, int64_t k, int64_t cap, int64_t *pool_i,
                     double *pool_d2, int64_t *best_i, double *best_d2) noexcept nogil:
    """The k nearest nodes of p, nearest first, as `knn` (ties in another order): first among
    the nodes within NEAR_REACH cells of p (a box of usually 2x2x2 cells, where `knn` always
    reads 3x3x3), which hold them whenever there are k of them; else by the grid's k-d tree
    (`tree_knn`) if it has one, by `knn` if not. A contactor whose cell's ring (`empty_rings`)
    is 2 or more has no node within a cell: it goes to the tree at once. pool_i and pool_d2
    (`cap` entries) are scratch."""
    cdef double r = NEAR_REACH * g.cell
    cdef int64_t found = 0, j, count = 0
    cdef int64_t ci = cell_index(p[0], g.lo[0], g.cell, g.dims[0])
    cdef int64_t cj = cell_index(p[1], g.lo[1], g.cell, g.dims[1])
    cdef int64_t ck = cell_index(p[2], g.lo[2], g.cell, g.dims[2])
    if g.ring[(ci * g.dims[1] + cj) * g.dims[2] + ck] < 2:
        found = ball(g, p, r * r, cap, pool_i, pool_d2)
    if found < k or found > cap:
        if g.tree.count:
            return tree_knn(&g.tree, p, k, best_i, best_d2)
        return knn(g, p, k, best_i, best_d2)
    for j in range(found):
        count = offer(best_i, best_d2, k, count, pool_i[j], pool_d2[j])
    return count


# --------------------------------------------------------------------------------------------
# the target, the options, the per-thread scratch
# --------------------------------------------------------------------------------------------

cdef struct TargetC:
    const double *nodes          # (n, 3)
    const double *normals        # (n, 3) nodal normals (zero rows without facets)
    const double *node_spacing   # (n,)
    const int64_t *first         # (n,) first node at the same position
    const double *fold_normals   # (n, 3)
    const uint8_t *is_signed     # (n,) whether fold_normals is oriented
    const uint8_t *steep         # (n,)
    const int64_t *perm          # (n,) the caller's number of each node
    const int64_t *inv           # (n,) the engine's number of each of the caller's nodes
    Grid grid                    # the nodes
    Grid plane                   # the nodes' in-plane coordinates in the global frame
    double frame_origin[3]
    double frame_axes[9]         # rows e1, e2, e3
    bint has_faces, duplicates, global_frame
    int64_t n


cdef struct Options:
    int nterms
    int ea[10]
    int eb[10]
    int nreduced                 # the reduced bases (basis.REDUCED), largest first:
    int rsize[12]                # basis r has rsize[r] terms a^ra b^rb,
    int ra[120]                  # ra[NTERMS_MAX * r + j], rb[...] (a along the support)
    int rb[120]
    bint across[12]              # whether reduced basis r has a term in b
    bint ruled_global            # the global frame is fixed by more than a row of nodes
    double ruled_spread, row_variance, strip_rank
    bint plane_only[12]          # reduced basis r is complete (basis.complete: no direction)
    int weight                   # WEIGHT_CODES
    bint knn                     # support: k nearest (else radius)
    int64_t k[2]                 # k nearest, first try and enlarged retry
    double radius[2]             # support radius in spacings, first try and retry
    int64_t spacing_neighbours   # k + 1 nearest nodes weigh the spacing (tie-free)
    double frame_ball, knn_factor, sheet_cos, cos_fold, rcond_min, contact_tol
    double outside_spacings, hull_spacings
    double gauss_c2, gauss_tail, singular_floor, equilibration_floor
    double newton_step
    int newton_max_iter
    double e1_guide[3]
    double e1_guide_alt[3]
    bint recentre
    int recentre_max_iter
    double recentre_step, recentre_stall
    bint keep                    # store each support's node indices (the pairing)


cdef struct Result:
    double gap
    double normal[3]
    double proximal[3]
    double rcond
    double curvature[2]
    int8_t status, reason, terms
    int8_t reduced               # the reduced basis fitted (basis.REDUCED), -1 the full one
    double direction             # its a axis's angle in the frame (NaN: none)
    int64_t support, iterations
    double origin[3]
    double axes[9]
    double R, h
    int64_t count                # support nodes in index
    int64_t *index               # (cap,) scratch
    bint overflow


cdef struct Scratch:
    int64_t cap
    int64_t *cand_i
    int64_t *near_i
    int64_t *live_i              # the support nodes inside the domain of influence
    double *cand_d2
    double *near_d2
    double *s
    double *t
    double *z
    double *w
    double *geo
    double *arc_start
    double *arc_end
    double *a                    # (max(cap, n), row_stride(n)): [W^½P | W^½z]
    double *rfac                 # (n, n)
    double *work                 # (n, n)
    double *sig                  # (n,)
    double *scale                # (n,)
    double *alpha                # (n,)
    double nbar[3]               # weighted normal of the spacing neighbours
    double foot[3]               # foot of the reference point on the target
    double knn_d2                # squared distance of the k-th nearest ('knn' support)
    Result res[2]
    void *mem


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
    sc.cand_d2 = d; d += cap
    sc.s = d; d += cap
    sc.t = d; d += cap
    sc.z = d; d += cap
    sc.w = d; d += cap
    sc.geo = d; d += cap
    sc.arc_start = d; d += cap
    sc.arc_end = d; d += cap
    sc.near_d2 = d; d += near
    sc.a = d; d += rows * row_stride(nterms)
    sc.rfac = d; d += nterms * nterms
    sc.work = d; d += nterms * nterms
    sc.sig = d; d += nterms
    sc.scale = d; d += nterms
    sc.alpha = d; d += nterms
    cdef int64_t *ip = <int64_t *>d
    sc.cand_i = ip; ip += cap
    sc.near_i = ip; ip += near
    sc.live_i = ip; ip += cap
    sc.res[0].index = ip; ip += cap
    sc.res[1].index = ip
    return sc


cdef void scratch_free(Scratch *sc) noexcept nogil:
    if sc != NULL:
        free(sc.mem)
        free(sc)


# --------------------------------------------------------------------------------------------
# weights, basis, small dense linear algebra
# --------------------------------------------------------------------------------------------

cdef inline double weight(int code, double q, const Options *op) noexcept nogil:
    """w(q), q = (ρ/R)² [15], as weight.py (0 outside the domain of influence)."""
    if q >= 1.0:
        return 0.0
    if code == GAUSS:
        return (exp(-q / op.gauss_c2) - op.gauss_tail) / (1.0 - op.gauss_tail)
    cdef double r = sqrt(q)
    cdef double u = 1.0 - r
    cdef double w = u * u * u * u * (4.0 * r + 1.0)
    if code == SINGULAR:
        return w / dmax(q, op.singular_floor)
    return w


cdef inline double ipow(double x, int n) noexcept nogil:
    cdef double out = 1.0
    cdef int i
    for i in range(n):
        out *= x
    return out


cdef void smallest_eigenvector(const double *c, double *out) noexcept nogil:
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 `c` (cyclic Jacobi,
    Golub & Van Loan §8.5)."""
    cdef double a[9]
    cdef double v[9]
    cdef int P[3]
    cdef int Q[3]
    P[0] = 0; P[1] = 0; P[2] = 1
    Q[0] = 1; Q[1] = 2; Q[2] = 2
    cdef int sweep, pq, p, q, k, i, j
    cdef double off, scale, theta, t, cs, sn, x, y
    for i in range(9):
        a[i] = c[i]
        v[i] = 0.0
    v[0] = 1.0; v[4] = 1.0; v[8] = 1.0
    for sweep in range(50):
        off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5]
        scale = a[0] * a[0] + a[4] * a[4] + a[8] * a[8]
        if off <= 1e-36 * scale or off == 0.0:
            break
        for pq in range(3):
            p = P[pq]
            q = Q[pq]
            if a[3 * p + q] == 0.0:
                continue
            theta = (a[3 * q + q] - a[3 * p + p]) / (2.0 * a[3 * p + q])
            t = (1.0 if theta >= 0 else -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0))
            cs = 1.0 / sqrt(t * t + 1.0)
            sn = t * cs
            for k in range(3):  # a <- Jᵀ a J
                x = a[3 * k + p]; y = a[3 * k + q]
                a[3 * k + p] = cs * x - sn * y
                a[3 * k + q] = sn * x + cs * y
            for k in range(3):
                x = a[3 * p + k]; y = a[3 * q + k]
                a[3 * p + k] = cs * x - sn * y
                a[3 * q + k] = sn * x + cs * y
            for k in range(3):
                x = v[3 * k + p]; y = v[3 * k + q]
                v[3 * k + p] = cs * x - sn * y
                v[3 * k + q] = sn * x + cs * y
    j = 0
    for i in range(1, 3):
        if a[3 * i + i] < a[3 * j + j]:
            j = i
    for k in range(3):
        out[k] = v[3 * k + j]


cdef bint smallest_eigenvector_psd(const double *c, double *out) noexcept nogil:
    """Unit eigenvector of the smallest eigenvalue of the symmetric positive semi-definite
    3x3 `c` (a covariance), when it is well separated; returns False (out untouched) when it
    is not, or when c has rank < 2.

    The adjugate of c has c's eigenvectors, the smallest eigenvalue λ1 of c going with its
    largest, λ2λ3, and the next with λ1λ3: squaring it (normalised to unit trace) raises the
    ratio λ1/λ2 to the power 2, 4, 8..., until the other eigenvalues are below 1e-13 of the
    largest (then once more: 1e-26), and any column is the eigenvector; a few dozen flops a
    step where the cyclic Jacobi takes several sweeps. Stops, False, after 8 squarings
    (λ1/λ2 above ~0.9: the plane of the nodes is ill-defined; `smallest_eigenvector`
    decides)."""
    cdef double a00 = c[4] * c[8] - c[5] * c[5], a01 = c[2] * c[5] - c[1] * c[8]
    cdef double a02 = c[1] * c[5] - c[2] * c[4], a11 = c[0] * c[8] - c[2] * c[2]
    cdef double a12 = c[1] * c[2] - c[0] * c[5], a22 = c[0] * c[4] - c[1] * c[1]
    cdef double b00, b01, b02, b11, b12, b22, tr, f, rest, norm
    cdef double tc = c[0] + c[4] + c[8]
    cdef int it
    cdef bint done = False
    tr = a00 + a11 + a22
    if not (tr > 1e-12 * tc * tc):  # rank < 2 (or NaN)
        return False
    for it in range(8):
        f = 1.0 / tr
        a00 *= f; a01 *= f; a02 *= f; a11 *= f; a12 *= f; a22 *= f
        b00 = a00 * a00 + a01 * a01 + a02 * a02
        b01 = a00 * a01 + a01 * a11 + a02 * a12
        b02 = a00 * a02 + a01 * a12 + a02 * a22
        b11 = a01 * a01 + a11 * a11 + a12 * a12
        b12 = a01 * a02 + a11 * a12 + a12 * a22
        b22 = a02 * a02 + a12 * a12 + a22 * a22
        a00 = b00; a01 = b01; a02 = b02; a11 = b11; a12 = b12; a22 = b22
        tr = a00 + a11 + a22
        if done:
            break
        # 1 - ‖A‖²/tr(A)² = 2 Σ_{i<j} μiμj / tr²: twice the second eigenvalue's share
        rest = 1.0 - (a00 * a00 + a11 * a11 + a22 * a22
                      + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / (tr * tr)
        done = rest < 1e-13
    if not done:
        return False
    # the column of the largest diagonal entry
    if a00 >= a11 and a00 >= a22:
        out[0] = a00; out[1] = a01; out[2] = a02
    elif a11 >= a22:
        out[0] = a01; out[1] = a11; out[2] = a12
    else:
        out[0] = a02; out[1] = a12; out[2] = a22
    norm = sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    out[0] /= norm
    out[1] /= norm
    out[2] /= norm
    return True


cdef void jacobi(double *r, int n, double *v, double tol, double *norms) noexcept nogil:
    """One-sided Jacobi (Hestenes; Golub & Van Loan §8.6.4) on the n x n matrix r (destroyed):
    columns rotated pairwise until orthogonal to `tol` (relative), their squared norms kept in
    norms (n); the rotations accumulated in v (n x n, set to the identity first) unless NULL."""
    cdef int i, j, k, sweep
    cdef bint rotated
    cdef double acc, al, be, ga, zeta, t, cs, sn, x, y
    for i in range(n):
        if v != NULL:
            for j in range(n):
                v[i * n + j] = 1.0 if i == j else 0.0
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        norms[i] = acc
    for sweep in range(60):
        rotated = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                al = norms[i]
                be = norms[j]
                ga = 0.0
                for k in range(n):
                    ga += r[k * n + i] * r[k * n + j]
                if ga == 0.0 or fabs(ga) <= tol * sqrt(al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = (1.0 if zeta >= 0 else -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta))
                cs = 1.0 / sqrt(1.0 + t * t)
                sn = cs * t
                for k in range(n):
                    x = r[k * n + i]; y = r[k * n + j]
                    r[k * n + i] = cs * x - sn * y
                    r[k * n + j] = sn * x + cs * y
                    if v != NULL:
                        x = v[k * n + i]; y = v[k * n + j]
                        v[k * n + i] = cs * x - sn * y
                        v[k * n + j] = sn * x + cs * y
                norms[i] = al - t * ga
                norms[j] = be + t * ga
        if not rotated:
            break


cdef void singular_values(double *r, int n, double *sig) noexcept nogil:
    """Singular values of the n x n matrix r (destroyed) by one-sided `jacobi` to 1e-9
    (relative), then the columns' norms (accurate far beyond that: the error is second order)."""
    cdef int i, k
    cdef double acc
    jacobi(r, n, NULL, 1e-9, sig)
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        sig[i] = sqrt(acc)


cdef inline double inverse_column(const double *r, int n, int j, const double *d,
                                  double *work, double *fro) noexcept nogil:
    """Column j of R⁻¹ into work (R: the n x n upper triangular r, row stride n; d: the
    reciprocals of its diagonal) by back substitution; returns its squared norm and adds that
    of R's column j to fro. Inlined with n and j constants: the loops unroll."""
    cdef int i, k
    cdef double acc, sq
    sq = 0.0
    for i in range(j + 1):
        sq += r[i * n + j] * r[i * n + j]
    fro[0] += sq
    work[j * n + j] = d[j]
    sq = d[j] * d[j]
    for i in range(j - 1, -1, -1):
        acc = 0.0
        for k in range(i + 1, j + 1):
            acc += r[i * n + k] * work[k * n + j]
        work[i * n + j] = -acc * d[i]
        sq += work[i * n + j] * work[i * n + j]
    return sq


cdef inline double frobenius_rcond(const double *r, int n, double *work) noexcept nogil:
    """rcond_F = 1 / (‖R‖_F ‖R⁻¹‖_F) of the n x n upper triangular r (row stride n), R⁻¹
    into work (upper triangular); 0 where r is singular or R⁻¹ overflows. Inlined with n a
    constant; the quadratic and linear bases' columns written out."""
    cdef int j
    cdef double fro = 0.0, inv_fro = 0.0, rc
    cdef double d[NTERMS_MAX]
    for j in range(n):
        if not (r[j * n + j] != 0.0):
            return 0.0
        d[j] = 1.0 / r[j * n + j]
    if n == 6:
        inv_fro = (inverse_column(r, 6, 0, d, work, &fro)
                   + inverse_column(r, 6, 1, d, work, &fro)
                   + inverse_column(r, 6, 2, d, work, &fro)
                   + inverse_column(r, 6, 3, d, work, &fro)
                   + inverse_column(r, 6, 4, d, work, &fro)
                   + inverse_column(r, 6, 5, d, work, &fro))
    elif n == 3:
        inv_fro = (inverse_column(r, 3, 0, d, work, &fro)
                   + inverse_column(r, 3, 1, d, work, &fro)
                   + inverse_column(r, 3, 2, d, work, &fro))
    else:
        for j in range(n):
            inv_fro += inverse_column(r, n, j, d, work, &fro)
    rc = 1.0 / sqrt(fro * inv_fro)
    return rc if rc > 0.0 else 0.0  # (R⁻¹ overflowed)


cdef double triangular_rcond(const double *r, int n, double *work, double *sig,
                             double rcond_min) noexcept nogil:
    """The reciprocal condition number of the n x n upper triangular r (row stride n), as
    `Projection.rcond` documents it.

    rcond_F = 1 / (‖R‖_F ‖R⁻¹‖_F) satisfies rcond_F ≤ σmin/σmax ≤ n rcond_F (each Frobenius
    norm is within √n of the matching 2-norm), and costs ~n³/6 flops for R⁻¹. It decides
    alone when rcond_F ≥ rcond_min (accepted) or n rcond_F < rcond_min (refused); between
    the two the exact σmin/σmax (one-sided Jacobi) decides and is returned. So the value
    returned is ≥ rcond_min exactly when σmin/σmax is.
    """
    cdef int i, j
    cdef double rc = frobenius_rcond(r, n, work), top, low
    if rc >= rcond_min or n * rc < rcond_min:
        return rc
    for i in range(n):
        for j in range(n):
            work[i * n + j] = r[i * n + j] if j >= i else 0.0
    singular_values(work, n, sig)
    top = 0.0
    low = INFINITY
    for i in range(n):
        top = dmax(top, sig[i])
        low = dmin(low, sig[i])
    return low / top if top > 0 else 0.0


cdef inline int row_stride(int n) noexcept nogil:
    """Row stride of the least-squares matrix [P | z] with n basis terms: n + 1 columns
    rounded up to an even number (whole 16-byte pairs: the row updates vectorise)."""
    return n + 2 if n % 2 == 0 else n + 1


cdef inline void column_scales(double *scale, int n, double floor) noexcept nogil:
    """The equilibration of the weighted design matrix: scale holds its columns' squared norms
    on entry, their norms on return, floored at `floor` x the largest (a column of round-off,
    as a support on a line gives, must stay negligible) and 1 where all are zero."""
    cdef int j
    cdef double top = 0.0
    for j in range(n):
        scale[j] = sqrt(scale[j])
        top = dmax(top, scale[j])
    for j in range(n):
        scale[j] = dmax(scale[j], floor * top)
        if not (scale[j] > 0):
            scale[j] = 1.0


cdef inline int64_t weighted_system(const Options *op, int n, const double *s,
                                    const double *t, const double *z, const double *w,
                                    int64_t count, double *a, double *scale) noexcept nogil:
    """The rows sqrt(w/w_max) [p(s, t) | z] [16] of the support nodes with w > 0 into `a`
    (row stride `row_stride(n)`: the basis in columns :n, z in column n, zeros after), the
    norms of the basis columns (floored) into `scale`; returns the number of rows.

    The columns are not divided by their norms: Householder QR is column-scaling invariant
    (its backward error is columnwise), so R of the equilibrated matrix, on which rcond is
    judged, is R with its columns divided by `scale` (n(n+1)/2 divisions instead of n per
    row), and α solves the unscaled R directly. Inlined with n a constant (3, 6
    or 10): the loops over the basis unroll; the quadratic rows are written out (the same
    products as the table's)."""
    cdef int j, ld = row_stride(n)
    cdef double wmax = 0.0, root, sr, tr
    cdef double sp[4]
    cdef double tp[4]
    cdef double inv[NTERMS_MAX]
    cdef double *row
    cdef int64_t r, rows = 0, i
    sp[0] = 1.0
    tp[0] = 1.0
    for j in range(n):
        scale[j] = 0.0
    for r in range(count):
        wmax = dmax(wmax, w[r])
    for r in range(count):
        if w[r] <= 0.0:
            continue
        root = sqrt(w[r] / wmax)
        row = a + rows * ld
        sr = s[r]
        tr = t[r]
        if n == 6:
            row[0] = root
            row[1] = root * sr
            row[2] = root * tr
            row[3] = root * (sr * sr)
            row[4] = (root * sr) * tr
            row[5] = root * (tr * tr)
        else:
            sp[1] = sr
            tp[1] = tr
            for j in range(2, 4):
                sp[j] = sp[j - 1] * sr
                tp[j] = tp[j - 1] * tr
            for j in range(n):
                row[j] = root * sp[op.ea[j]] * tp[op.eb[j]]
        for j in range(n):  # the column norms, summed in row order
            scale[j] += row[j] * row[j]
        row[n] = root * z[r]
        for j in range(n + 1, ld):
            row[j] = 0.0
        rows += 1
    column_scales(scale, n, op.equilibration_floor)
    return rows


cdef inline bint reflect(double *a, int64_t m, int n, int j, double *nxt,
                         bint have) noexcept nogil:
    """Step j of `householder_qr`: the reflection that zeroes column j below the diagonal,
    applied to columns j+1..n (n: the z column). `nxt` holds the squared norm of column j
    below row j-1 when `have`; returns whether it then holds column j+1's.

    The rows are read twice: once for the products of v with the later columns, once to
    update them and to sum the squares of column j+1 (the next step's norm). Each sum runs
    over the rows in order, as the textbook loops do. Inlined with n and j constants: the
    loops over the columns unroll."""
    cdef int c, ld = row_stride(n)
    cdef int64_t i
    cdef double norm, ajj, alpha, v0, vtv, vi, acc
    cdef double dot[NTERMS_MAX + 1]
    cdef double *row
    if have:
        norm = nxt[0]
    else:
        norm = 0.0
        for i in range(j, m):
            norm += a[i * ld + j] * a[i * ld + j]
    norm = sqrt(norm)
    if norm == 0.0:
        return False
    ajj = a[j * ld + j]
    alpha = -norm if ajj >= 0 else norm
    v0 = ajj - alpha
    # v = (v0, a[j+1:, j]); H = I - 2 v vᵀ / vᵀv
    vtv = v0 * v0 + (norm * norm - ajj * ajj)
    if vtv <= 0.0:
        return False
    a[j * ld + j] = v0
    for c in range(j + 1, n + 1):
        dot[c] = 0.0
    for i in range(j, m):
        row = a + i * ld
        vi = row[j]
        for c in range(j + 1, n + 1):
            dot[c] += vi * row[c]
    vtv = 2.0 / vtv
    for c in range(j + 1, n + 1):
        dot[c] *= vtv
    row = a + j * ld
    for c in range(j + 1, n + 1):
        row[c] -= dot[c] * v0
    acc = 0.0
    for i in range(j + 1, m):
        row = a + i * ld
        vi = row[j]
        for c in range(j + 1, n + 1):
            row[c] -= dot[c] * vi
        if j + 1 < n:
            acc += row[j + 1] * row[j + 1]
    a[j * ld + j] = alpha
    nxt[0] = acc
    return j + 1 < n


cdef inline void householder_qr(double *a, int64_t m, int n, const double *scale,
                                double *rfac) noexcept nogil:
    """Householder QR of the m x n basis block of `a` (row stride `row_stride(n)`, m >= n,
    in place; Golub & Van Loan §5.2), applied to the z column too; R with its columns
    divided by `scale` (R of the equilibrated matrix) into rfac (n x n).
    Inlined with n a constant; the steps of the linear and quadratic bases are written out
    (each with its own constant j)."""
    cdef int j, c, ld = row_stride(n)
    cdef int64_t i
    cdef double nxt = 0.0
    cdef bint have = False
    if n == 6:
        have = reflect(a, m, 6, 0, &nxt, have)
        have = reflect(a, m, 6, 1, &nxt, have)
        have = reflect(a, m, 6, 2, &nxt, have)
        have = reflect(a, m, 6, 3, &nxt, have)
        have = reflect(a, m, 6, 4, &nxt, have)
        have = reflect(a, m, 6, 5, &nxt, have)
    elif n == 3:
        have = reflect(a, m, 3, 0, &nxt, have)
        have = reflect(a, m, 3, 1, &nxt, have)
        have = reflect(a, m, 3, 2, &nxt, have)
    else:
        for j in range(n):
            have = reflect(a, m, n, j, &nxt, have)
    for i in range(n):
        for c in range(n):
            rfac[i * n + c] = a[i * ld + c] / scale[c] if c >= i else 0.0


cdef inline int64_t normal_system(const Options *op, int n, const double *s,
                                  const double *t, const double *z, const double *w,
                                  int64_t count, double *g, double *b,
                                  double *scale) noexcept nogil:
    """The normal equations [16]-[17] of the support nodes with w > 0: PᵀWP into the upper
    triangle of g (row stride n), PᵀWZ into b, the norms of W^½P's columns (floored, as
    `weighted_system`'s) into `scale`; returns the number of those nodes.

    Inlined with n a constant. The quadratic basis's Gram entries are the 15 weighted moments
    Σ w s^a t^b, a + b ≤ 4 (its 21 entries repeat some), summed in node order."""
    cdef int i, j
    cdef int64_t r, rows = 0
    cdef double wr, sr, tr, zr, ws, wt, ws2, wst, wt2, ws3, ws2t, wst2, wt3, wz, wzs, wzt
    cdef double m00 = 0.0, m10 = 0.0, m01 = 0.0, m20 = 0.0, m11 = 0.0, m02 = 0.0
    cdef double m30 = 0.0, m21 = 0.0, m12 = 0.0, m03 = 0.0
    cdef double m40 = 0.0, m31 = 0.0, m22 = 0.0, m13 = 0.0, m04 = 0.0
    cdef double b0 = 0.0, b1 = 0.0, b2 = 0.0, b3 = 0.0, b4 = 0.0, b5 = 0.0
    cdef double sp[4]
    cdef double tp[4]
    cdef double p[NTERMS_MAX]
    if n == 6:
        for r in range(count):
            wr = w[r]
            if wr <= 0.0:
                continue
            sr = s[r]
            tr = t[r]
            zr = z[r]
            ws = wr * sr
            wt = wr * tr
            ws2 = ws * sr
            wst = ws * tr
            wt2 = wt * tr
            ws3 = ws2 * sr
            ws2t = ws2 * tr
            wst2 = wst * tr
            wt3 = wt2 * tr
            m00 += wr
            m10 += ws
            m01 += wt
            m20 += ws2
            m11 += wst
            m02 += wt2
            m30 += ws3
            m21 += ws2t
            m12 += wst2
            m03 += wt3
            m40 += ws3 * sr
            m31 += ws3 * tr
            m22 += ws2t * tr
            m13 += wst2 * tr
            m04 += wt3 * tr
            wz = wr * zr
            wzs = wz * sr
            wzt = wz * tr
            b0 += wz
            b1 += wzs
            b2 += wzt
            b3 += wzs * sr
            b4 += wzs * tr
            b5 += wzt * tr
            rows += 1
        g[0] = m00; g[1] = m10; g[2] = m01; g[3] = m20; g[4] = m11; g[5] = m02
        g[7] = m20; g[8] = m11; g[9] = m30; g[10] = m21; g[11] = m12
        g[14] = m02; g[15] = m21; g[16] = m12; g[17] = m03
        g[21] = m40; g[22] = m31; g[23] = m22
        g[28] = m22; g[29] = m13
        g[35] = m04
        b[0] = b0; b[1] = b1; b[2] = b2; b[3] = b3; b[4] = b4; b[5] = b5
    else:
        for i in range(n):
            b[i] = 0.0
            for j in range(i, n):
                g[i * n + j] = 0.0
        sp[0] = 1.0
        tp[0] = 1.0
        for r in range(count):
            wr = w[r]
            if wr <= 0.0:
                continue
            sp[1] = s[r]
            tp[1] = t[r]
            for j in range(2, 4):
                sp[j] = sp[j - 1] * sp[1]
                tp[j] = tp[j - 1] * tp[1]
            for j in range(n):
                p[j] = sp[op.ea[j]] * tp[op.eb[j]]
            for i in range(n):
                ws = wr * p[i]
                for j in range(i, n):
                    g[i * n + j] += ws * p[j]
                b[i] += ws * z[r]
            rows += 1
    for j in range(n):
        scale[j] = g[j * n + j]
    column_scales(scale, n, op.equilibration_floor)
    return rows


cdef inline bint cholesky_row(double *g, int n, int i, const double *inv, double *d,
                              double *b) noexcept nogil:
    """Row i of R (Cholesky, Golub & Van Loan §4.2) in place of the Gram g's upper triangle,
    equilibrated on the fly (inv: 1/scale), rows < i already done; 1/R_ii into d[i]; and
    u_i of Rᵀu = D⁻¹b in place of b_i. False where the pivot is not positive. Inlined with
    n and i constants: the loops unroll."""
    cdef int j, k
    cdef double acc = g[i * n + i] * (inv[i] * inv[i]), piv
    for k in range(i):
        acc -= g[k * n + i] * g[k * n + i]
    if not (acc > 0.0):
        return False
    piv = sqrt(acc)
    g[i * n + i] = piv
    d[i] = 1.0 / piv
    for j in range(i + 1, n):
        acc = g[i * n + j] * (inv[i] * inv[j])
        for k in range(i):
            acc -= g[k * n + i] * g[k * n + j]
        g[i * n + j] = acc * d[i]
    acc = b[i] * inv[i]
    for k in range(i):
        acc -= g[k * n + i] * b[k]
    b[i] = acc * d[i]
    return True


cdef inline void back_row(const double *r, int n, int i, const double *d,
                          double *b) noexcept nogil:
    """y_i of R y = u in place of u_i (b), rows > i already done (d: 1/R_ii). Inlined with n
    and i constants."""
    cdef int k
    cdef double acc = b[i]
    for k in range(i + 1, n):
        acc -= r[i * n + k] * b[k]
    b[i] = acc * d[i]


cdef inline bint normal_fit(const Options *op, Scratch *sc, const double *w, int64_t count,
                            int n, bint solve_alpha, double *rcond) noexcept nogil:
    """The fit [16]-[17] by the normal equations where they settle it: the support's
    equilibrated Gram matrix D⁻¹PᵀWPD⁻¹ (D = diag(scale)) factored RᵀR by Cholesky. R is then
    (to round-off, and up to the signs of its rows) the R of W^½PD⁻¹'s Householder QR, whose
    rcond `fit` judges, so where rcond_F(R) >= rcond_min (`triangular_rcond` accepts on the
    bound alone) it is returned in rcond and, with `solve_alpha`, α = D⁻¹R⁻¹R⁻ᵀD⁻¹PᵀWZ into
    sc.alpha; True. False (nothing settled) where the support has fewer than n weighted
    nodes, a pivot is not positive, rcond_F < rcond_min or α is not finite: the caller then
    takes the QR path, which decides those cases exactly as before.

    Cost: the moments are ~n²/2 flops a node against Householder's ~2n² (and no square root
    a node); accepted fits have σmin/σmax >= rcond_min, so the Gram's conditioning, at most
    1/rcond_min², loses no more than ~1e-10 relative (the tests' reference is an SVD)."""
    cdef double *g = sc.rfac
    cdef double *b = sc.sig  # (free: only the exact branch of triangular_rcond uses it)
    cdef double *scale = sc.scale
    cdef double inv[NTERMS_MAX]
    cdef double d[NTERMS_MAX]
    cdef double rc
    cdef int i, j
    if normal_system(op, n, sc.s, sc.t, sc.z, w, count, g, b, scale) < n:
        return False
    for j in range(n):
        inv[j] = 1.0 / scale[j]
    # Cholesky (Golub & Van Loan §4.2) of the equilibrated Gram, row by row of R, in place,
    # with the forward substitution Rᵀu = D⁻¹PᵀWZ (into b)
    if n == 6:
        if not (cholesky_row(g, 6, 0, inv, d, b) and cholesky_row(g, 6, 1, inv, d, b)
                and cholesky_row(g, 6, 2, inv, d, b) and cholesky_row(g, 6, 3, inv, d, b)
                and cholesky_row(g, 6, 4, inv, d, b) and cholesky_row(g, 6, 5, inv, d, b)):
            return False
    elif n == 3:
        if not (cholesky_row(g, 3, 0, inv, d, b) and cholesky_row(g, 3, 1, inv, d, b)
                and cholesky_row(g, 3, 2, inv, d, b)):
            return False
    else:
        for i in range(n):
            if not cholesky_row(g, n, i, inv, d, b):
                return False
    rc = frobenius_rcond(g, n, sc.work)
    if not (rc >= op.rcond_min):
        return False
    if solve_alpha:
        if n == 6:  # R y = u, α = D⁻¹ y
            back_row(g, 6, 5, d, b); back_row(g, 6, 4, d, b)
            back_row(g, 6, 3, d, b); back_row(g, 6, 2, d, b)
            back_row(g, 6, 1, d, b); back_row(g, 6, 0, d, b)
        elif n == 3:
            back_row(g, 3, 2, d, b); back_row(g, 3, 1, d, b)
            back_row(g, 3, 0, d, b)
        else:
            for i in range(n - 1, -1, -1):
                back_row(g, n, i, d, b)
        for i in range(n):
            sc.alpha[i] = b[i] * inv[i]
            if not isfinite(sc.alpha[i]):
                return False
    rcond[0] = rc
    return True


cdef inline double fit_n(const Options *op, Scratch *sc, int64_t count,
                         int n) noexcept nogil:
    """`fit` with n = op.nterms (inlined with n a constant)."""
    cdef int j, c, ld = row_stride(n)
    cdef double rcond = 0.0, acc
    cdef bint solvable
    if op.weight != SINGULAR and normal_fit(op, sc, sc.w, count, n, True, &rcond):
        return rcond
    cdef int64_t rows = weighted_system(op, n, sc.s, sc.t, sc.z, sc.w, count, sc.a, sc.scale)
    solvable = rows >= n
    if solvable:
        householder_qr(sc.a, rows, n, sc.scale, sc.rfac)
        if op.weight == SINGULAR:  # only whether R is invertible matters for this fit
            for j in range(n):
                if not (sc.rfac[j * n + j] != 0.0):
                    solvable = False
        else:
            rcond = triangular_rcond(sc.rfac, n, sc.work, sc.sig, op.rcond_min)
            solvable = rcond > 0.0
    if solvable:
        for j in range(n - 1, -1, -1):  # back substitution R y = Qᵀ b
            acc = sc.a[j * ld + n]
            for c in range(j + 1, n):
                acc -= sc.a[j * ld + c] * sc.alpha[c]
            sc.alpha[j] = acc / sc.a[j * ld + j]
        for j in range(n):
            if not isfinite(sc.alpha[j]):
                solvable = False
    if not solvable:
        for j in range(n):
            sc.alpha[j] = NAN
    if op.weight == SINGULAR:
        # judge the support's geometry on the smooth weight with the same support
        if normal_fit(op, sc, sc.geo, count, n, False, &rcond):
            return rcond
        rows = weighted_system(op, n, sc.s, sc.t, sc.z, sc.geo, count, sc.a, sc.scale)
        rcond = 0.0
        if rows >= n:
            householder_qr(sc.a, rows, n, sc.scale, sc.rfac)
            rcond = triangular_rcond(sc.rfac, n, sc.work, sc.sig, op.rcond_min)
    return rcond


cdef double fit(const Options *op, Scratch *sc, int64_t count) noexcept nogil:
    """Weighted least squares [17] of the support (the first `count` entries of s, t, z, w):
    α into sc.alpha (NaN when impossible); returns rcond (on the smooth weights sc.geo with
    the singular weight, which is stiff by design). One copy per basis size, so that the
    compiler unrolls the small loops."""
    if op.nterms == 6:
        return fit_n(op, sc, count, 6)
    if op.nterms == 3:
        return fit_n(op, sc, count, 3)
    return fit_n(op, sc, count, 10)


cdef inline int64_t reduced_system(const Options *op, int r, const double *ua,
                                   const double *ub, const double *z, const double *w,
                                   int64_t count, double *a, double *scale) noexcept nogil:
    """`weighted_system` of the reduced basis r (op.ra, op.rb) in the turned coordinates
    (ua, ub) = (a, b)."""
    cdef int n = op.rsize[r], j, ld = row_stride(n)
    cdef double wmax = 0.0, root
    cdef double ap[4]
    cdef double bp[4]
    cdef double *row
    cdef int64_t i, rows = 0
    ap[0] = 1.0
    bp[0] = 1.0
    for j in range(n):
        scale[j] = 0.0
    for i in range(count):
        wmax = dmax(wmax, w[i])
    for i in range(count):
        if w[i] <= 0.0:
            continue
        root = sqrt(w[i] / wmax)
        row = a + rows * ld
        ap[1] = ua[i]
        ap[2] = ap[1] * ua[i]
        ap[3] = ap[2] * ua[i]
        bp[1] = ub[i]
        bp[2] = bp[1] * ub[i]
        bp[3] = bp[2] * ub[i]
        for j in range(n):
            row[j] = root * (ap[op.ra[NTERMS_MAX * r + j]] * bp[op.rb[NTERMS_MAX * r + j]])
            scale[j] += row[j] * row[j]
        row[n] = root * z[i]
        for j in range(n + 1, ld):
            row[j] = 0.0
        rows += 1
    column_scales(scale, n, op.equilibration_floor)
    return rows


cdef inline double binomial(int n, int k) noexcept nogil:
    cdef double out = 1.0
    cdef int m
    for m in range(k):
        out = out * (n - m) / (m + 1)
    return out


cdef void rotate_back(const Options *op, int r, const double *beta, double c, double sn,
                      double *alpha) noexcept nogil:
    """α of the full basis in (s, t) from β of the reduced basis r in (a, b) = (c s + sn t,
    c t - sn s): each a^i b^j expanded by the binomial theorem (a polynomial of the full
    basis's degree)."""
    cdef int j, i, jb, p, q, k, ps, pt
    cdef double ca, cb
    for k in range(op.nterms):
        alpha[k] = 0.0
    for j in range(op.rsize[r]):
        i = op.ra[NTERMS_MAX * r + j]
        jb = op.rb[NTERMS_MAX * r + j]
        for p in range(i + 1):  # a^i = Σ_p C(i, p) (c s)^p (sn t)^(i-p)
            ca = binomial(i, p) * ipow(c, p) * ipow(sn, i - p)
            for q in range(jb + 1):  # b^jb = Σ_q C(jb, q) (-sn s)^q (c t)^(jb-q)
                cb = binomial(jb, q) * ipow(-sn, q) * ipow(c, jb - q)
                ps = p + q
                pt = i + jb - p - q
                for k in range(op.nterms):
                    if op.ea[k] == ps and op.eb[k] == pt:
                        alpha[k] += beta[j] * (ca * cb)
                        break


cdef void smallest_right_vector(double *r, int n, double *v, double *out) noexcept nogil:
    """The right singular vector of the least singular value of the n x n r (destroyed) into
    out: one-sided `jacobi` to 1e-12, its rotations accumulated in v (n x n)."""
    cdef int i, k, low = 0
    cdef double acc, best = INFINITY
    cdef double norms[NTERMS_MAX]
    jacobi(r, n, v, 1e-12, norms)
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k * n + i] * r[k * n + i]
        if acc < best:
            best = acc
            low = i
    for k in range(n):
        out[k] = v[k * n + low]


cdef bint strip_direction(const Options *op, Scratch *sc, int64_t count, const double *pw,
                          double *angle) noexcept nogil:
    """The angle of the a axis of the reduced bases (tol.ROW_VARIANCE, tol.STRIP_RANK): along
    a row (weighted PCA of the support's (s, t)), else along two rows (the null direction of
    the quadratic part of the polynomial that vanishes on the support); False without one."""
    cdef double wsum = 0.0, ms = 0.0, mt = 0.0, css = 0.0, cst = 0.0, ctt = 0.0, ds, dt
    cdef double half, root, q11, q12, q22, big, small
    cdef double x[6]
    cdef int64_t i, rows
    for i in range(count):
        if pw[i] > 0:
            wsum += pw[i]
            ms += pw[i] * sc.s[i]
            mt += pw[i] * sc.t[i]
    if not (wsum > 0):
        return False
    ms /= wsum
    mt /= wsum
    for i in range(count):
        if pw[i] > 0:
            ds = sc.s[i] - ms
            dt = sc.t[i] - mt
            css += pw[i] * ds * ds
            cst += pw[i] * ds * dt
            ctt += pw[i] * dt * dt
    half = 0.5 * (css + ctt)
    root = sqrt(0.25 * (css - ctt) * (css - ctt) + cst * cst)
    if half - root <= op.row_variance * (half + root):  # a row: its principal direction
        angle[0] = 0.5 * atan2(2.0 * cst, css - ctt)
        return True
    rows = weighted_system(op, 6, sc.s, sc.t, sc.z, pw, count, sc.a, sc.scale)
    if rows < 6:
        return False
    householder_qr(sc.a, rows, 6, sc.scale, sc.rfac)
    smallest_right_vector(sc.rfac, 6, sc.work, x)
    # the quadratic part of Σ x_j p_j / scale_j: [[q11, q12], [q12, q22]]
    q11 = x[3] / sc.scale[3]
    q12 = 0.5 * x[4] / sc.scale[4]
    q22 = x[5] / sc.scale[5]
    half = 0.5 * (q11 + q22)
    root = sqrt(0.25 * (q11 - q22) * (q11 - q22) + q12 * q12)
    big = fabs(half) + root
    small = fabs(fabs(half) - root)
    if not (small <= op.strip_rank * big and big > 0):
        return False
    # the eigenvector of the eigenvalue of larger magnitude is across the rows
    angle[0] = 0.5 * atan2(2.0 * q12, q11 - q22)  # that of half + root
    if half >= 0:
        angle[0] += 0.5 * PI
    return True


cdef bint frame_fixed(const TargetC *tg, const Options *op, const Result *res,
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


cdef bint fit_one(const Options *op, Scratch *sc, int64_t count, int r, const double *ua,
                  const double *ub, double c, double sn) noexcept nogil:
    """The reduced basis r in (ua, ub) = (a, b), fitted [17] where its rcond passes the full
    basis's rule (on the smooth weight with the singular one) and rotated back into sc.alpha
    (a = c s + sn t); False (sc.alpha untouched) where it does not."""
    cdef int n = op.rsize[r], j, k, ld = row_stride(op.rsize[r])
    cdef int64_t rows
    cdef double acc
    cdef double beta[NTERMS_MAX]
    rows = reduced_system(op, r, ua, ub, sc.z, sc.w, count, sc.a, sc.scale)
    if rows < n:
        return False
    householder_qr(sc.a, rows, n, sc.scale, sc.rfac)
    if op.weight == SINGULAR:
        for j in range(n):
            if not (sc.rfac[j * n + j] != 0.0):
                return False
    elif not (triangular_rcond(sc.rfac, n, sc.work, sc.sig, op.rcond_min) >= op.rcond_min):
        return False
    for j in range(n - 1, -1, -1):  # back substitution R β = Qᵀ b
        acc = sc.a[j * ld + n]
        for k in range(j + 1, n):
            acc -= sc.a[j * ld + k] * beta[k]
        beta[j] = acc / sc.a[j * ld + j]
        if not isfinite(beta[j]):
            return False
    if op.weight == SINGULAR:  # the geometry judged on the smooth weight
        rows = reduced_system(op, r, ua, ub, sc.z, sc.geo, count, sc.a, sc.scale)
        if rows < n:
            return False
        householder_qr(sc.a, rows, n, sc.scale, sc.rfac)
        if not (triangular_rcond(sc.rfac, n, sc.work, sc.sig, op.rcond_min) >= op.rcond_min):
            return False
    rotate_back(op, r, beta, c, sn, sc.alpha)
    return True


cdef int fit_reduced(const Options *op, Scratch *sc, int64_t count, int64_t positive,
                     bint ruled, double *direction, int *which) noexcept nogil:
    """The terms the support can determine, where it cannot determine the full basis (a strip
    two nodes wide, a row of nodes): (a, b) are (s, t) turned along and across the support's
    direction (`strip_direction`, on the fit's weights; the smooth ones with the singular
    weight), and the first reduced basis (basis.REDUCED, largest first) with enough nodes and
    rcond >= rcond_min (the full basis's rule) is fitted [17] and rotated back into sc.alpha
    (`fit_one`); those constant across only where `ruled` (`frame_fixed`), those other than
    complete ones (the plane, the cubic's quadratic) only where the support has a direction (its
    angle into `direction`, else NaN); the index of the basis fitted into `which` (-1: none).

    A frozen pairing (which[0] >= 0 on entry: `project_with`) fits that basis at that
    direction, held fixed as the frame is [§4.2].

    Returns its number of terms, 0 (α NaN) when even [1, a] cannot be fitted. sc.arc_start
    and sc.arc_end (the hull test's scratch, free until then) hold a and b."""
    cdef const double *pw = sc.geo if op.weight == SINGULAR else sc.w
    cdef double *ua = sc.arc_start
    cdef double *ub = sc.arc_end
    cdef double theta = 0.0, c, sn
    cdef int r, j, frozen = which[0]
    cdef int64_t i
    cdef bint directed
    if frozen >= 0:
        directed = isfinite(direction[0])
        theta = direction[0] if directed else 0.0
    else:
        directed = strip_direction(op, sc, count, pw, &theta)
        direction[0] = theta if directed else NAN
    which[0] = -1
    if positive > 0:
        c = cos(theta)
        sn = sin(theta)
        for i in range(count):
            ua[i] = c * sc.s[i] + sn * sc.t[i]
            ub[i] = c * sc.t[i] - sn * sc.s[i]
        for r in range(op.nreduced):
            if frozen >= 0:
                if r != frozen or positive < op.rsize[r]:
                    continue
            elif (positive < op.rsize[r] or not (ruled or op.across[r])
                    or not (directed or op.plane_only[r])):
                continue
            if fit_one(op, sc, count, r, ua, ub, c, sn):
                which[0] = r
                return op.rsize[r]
    for j in range(op.nterms):
        sc.alpha[j] = NAN
    return 0


cdef void surface_derivatives(const Options *op, const double *alpha, double s, double t,
                              double *out) noexcept nogil:
    """f, f,s, f,t, f,ss, f,st, f,tt of the local approximation at (s, t) into out[6]."""
    cdef int d, j, a, b
    cdef double sa, tb, sa1, tb1, sa2, tb2
    cdef double sp[4]
    cdef double tp[4]
    if op.nterms == 6:  # the quadratic basis written out (the same products and sums)
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
    for j in range(op.nterms):
        a = op.ea[j]
        b = op.eb[j]
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


cdef int64_t newton(const Options *op, const double *alpha, const double *c, double *f,
                    double *st, bint *converged) noexcept nogil:
    """The proximal point [30] on the local approximation, c the contactor in the scaled
    frame: Newton on D = ½‖(s, t, f) - c‖², whose gradient is (x^c - x^d)·τ_k [28], full
    Newton while ∇²D is positive definite, Gauss-Newton beyond a focal point, steps capped at
    half the support radius. (s̄, t̄) into st; returns the iterations."""
    cdef int64_t its = 0, it
    cdef int j
    cdef double r, fs, ft, g1, g2, h11, h12, h22, det, d1, d2, step, cap
    cdef bint gn
    st[0] = c[0]
    st[1] = c[1]
    converged[0] = False
    for j in range(op.nterms):
        if not isfinite(alpha[j]):
            return 0
    for it in range(op.newton_max_iter):
        surface_derivatives(op, alpha, st[0], st[1], f)
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


cdef inline double py_mod(double x, double y) noexcept nogil:
    """Python's float x % y: the remainder has the sign of y."""
    cdef double mod = fmod(x, y)
    if mod != 0.0:
        if (y < 0) != (mod < 0):
            mod += y
    else:
        mod = -0.0 if y < 0.0 else 0.0
    return mod


cdef bint beyond_hull(const double *s, const double *t, const double *w, int64_t count,
                      double s0, double t0, double slack, double *start,
                      double *end) noexcept nogil:
    """Whether (s0, t0) is farther than `slack` from the in-plane convex hull of the support
    nodes with w > 0: iff the arcs of directions the discs of radius `slack` around the nodes
    cover leave a free arc of at least π (arcs swept in order of their start angle)."""
    cdef int quadrants = 0
    cdef int64_t j, live = 0, pos
    cdef double ds, dt, r, half, a, two_pi = 2.0 * PI, wrapped, free_arc
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
    return free_arc >= PI


# --------------------------------------------------------------------------------------------
# the local frame
# --------------------------------------------------------------------------------------------

cdef void frame_e1(const Options *op, const double *e3, double *out) noexcept nogil:
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


cdef void right_handed(double *e1, const double *e3, double *axes) noexcept nogil:
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


# --------------------------------------------------------------------------------------------
# one contactor
# --------------------------------------------------------------------------------------------

cdef double local_spacing(const TargetC *tg, const Options *op, const double *x,
                          Scratch *sc) noexcept nogil:
    """The local node spacing h at x, and (into sc.nbar, sc.foot) the weighted normal of the
    target near x and x's foot on the target.

    A function of the geometry alone, whatever the search order or tie-break: of the k + 1
    nearest nodes (k = tol.SPACING_NEIGHBOURS), d the (k+1)-th distance (a value, the same
    whichever node a tie picks), each node j weighs w_j = (1 - d_j²/d²)², zero for every node
    at distance d; h = Σ w_j h_j / Σ w_j, n̄ = Σ w_j n_j normalised, x̄ = Σ w_j x_j / Σ w_j.
    If all k + 1 are equidistant, every node within d counts once. The foot is x's
    projection on the plane through x̄ normal to n̄ (x̄ itself without facets)."""
    cdef int64_t got = nearest(&tg.grid, x, op.spacing_neighbours, sc.cap, sc.cand_i,
                               sc.cand_d2, sc.near_i, sc.near_d2)
    cdef double d2max = sc.near_d2[got - 1], wj, q, wsum = 0.0, h = 0.0, nn, dn, d2, r
    cdef double xb[3]
    cdef int64_t j, node, i0, i1, j0, j1, k0, k1, i, jj, c, a
    cdef int e
    cdef const Grid *g = &tg.grid
    for e in range(3):
        xb[e] = 0.0
        sc.nbar[e] = 0.0
    for j in range(got):
        if not (sc.near_d2[j] < d2max):
            continue
        q = 1.0 - sc.near_d2[j] / d2max
        wj = q * q
        node = sc.near_i[j]
        wsum += wj
        h += wj * tg.node_spacing[node]
        for e in range(3):
            xb[e] += wj * tg.nodes[3 * node + e]
            sc.nbar[e] += wj * tg.normals[3 * node + e]
    if not (wsum > 0.0):  # all equidistant: every node within d, once each
        r = sqrt(d2max)
        i0 = cell_index(x[0] - r, g.lo[0], g.cell, g.dims[0])
        i1 = cell_index(x[0] + r, g.lo[0], g.cell, g.dims[0])
        j0 = cell_index(x[1] - r, g.lo[1], g.cell, g.dims[1])
        j1 = cell_index(x[1] + r, g.lo[1], g.cell, g.dims[1])
        k0 = cell_index(x[2] - r, g.lo[2], g.cell, g.dims[2])
        k1 = cell_index(x[2] + r, g.lo[2], g.cell, g.dims[2])
        for i in range(i0, i1 + 1):
            for jj in range(j0, j1 + 1):
                c = (i * g.dims[1] + jj) * g.dims[2]
                for a in range(g.start[c + k0], g.start[c + k1 + 1]):
                    node = g.order[a]
                    d2 = distance2(tg.nodes, node, x)
                    if d2 <= d2max:
                        wsum += 1.0
                        h += tg.node_spacing[node]
                        for e in range(3):
                            xb[e] += tg.nodes[3 * node + e]
                            sc.nbar[e] += tg.normals[3 * node + e]
    for e in range(3):
        xb[e] /= wsum
    nn = dmax(sqrt(sc.nbar[0] * sc.nbar[0] + sc.nbar[1] * sc.nbar[1]
                   + sc.nbar[2] * sc.nbar[2]), 1e-300)
    dn = 0.0
    for e in range(3):
        sc.nbar[e] /= nn
        dn += (x[e] - xb[e]) * sc.nbar[e]
    for e in range(3):
        sc.foot[e] = x[e] - dn * sc.nbar[e] if tg.has_faces else xb[e]
    return h / wsum


cdef int64_t knn_ties(const Grid *g, const double *p, int64_t k, Scratch *sc,
                      Result *res) noexcept nogil:
    """The k nearest nodes of p and every node tied with the k-th (all within its distance,
    a value: no tie-break decides which nodes a 'knn' support holds), into cand_i; the k-th
    squared distance into sc.knn_d2."""
    cdef int64_t count = knn(g, p, k, sc.cand_i, sc.cand_d2)
    sc.knn_d2 = sc.cand_d2[count - 1]
    count = ball(g, p, sc.knn_d2, sc.cap, sc.cand_i, sc.cand_d2)
    if count > sc.cap:
        res.overflow = True
        count = sc.cap
    return count


cdef int64_t select_support(const TargetC *tg, const Options *op, const double *ref,
                            int attempt, Scratch *sc, Result *res) noexcept nogil:
    """Support and frame of the local approximation centred at `ref` (res.h already set):
    the support nodes in cand_i[:count], res.axes, res.R; res.overflow when the scratch was
    too small."""
    cdef int64_t *cand_i = sc.cand_i
    cdef double *cand_d2 = sc.cand_d2
    cdef double *geo = sc.geo
    cdef double *axes = res.axes
    cdef double pp[3]
    cdef double e1[3]
    cdef double e3[3]
    cdef double cov[9]
    cdef double R = 0.0, ballr, facing, wsum, wj, dr, dot, u0, u1, d
    cdef int64_t count = 0, kept, j, node
    cdef int e, col, rr
    cdef const double *x
    cdef const double *nv
    cdef double h = res.h
    if tg.global_frame:
        for e in range(9):
            axes[e] = tg.frame_axes[e]
        for e in range(2):
            pp[e] = 0.0
            for col in range(3):
                pp[e] += tg.frame_axes[3 * e + col] * (ref[col] - tg.frame_origin[col])
        pp[2] = 0.0
        if op.knn:
            count = knn_ties(&tg.plane, pp, op.k[attempt], sc, res)
            R = op.knn_factor * sqrt(sc.knn_d2)
        else:
            R = op.radius[attempt] * h
            count = ball(&tg.plane, pp, R * R, sc.cap, cand_i, cand_d2)
            if count > sc.cap:
                res.overflow = True
                count = sc.cap
        res.R = R
        return count
    # search around the reference point's foot on the target, not around the point itself:
    # a contactor several spacings off the surface must still find the nodes under it
    if op.knn:
        count = knn_ties(&tg.grid, sc.foot, op.k[attempt], sc, res)
        ballr = 1.0001 * sqrt(sc.knn_d2)
    else:
        R = op.radius[attempt] * h
        ballr = op.frame_ball * R
        count = ball(&tg.grid, sc.foot, ballr * ballr, sc.cap, cand_i, cand_d2)
        if count > sc.cap:
            res.overflow = True
            count = sc.cap
    # in one pass: drop the nodes of another sheet (the far side of a thin tube or plate),
    # those facing away from the target's normal near the reference point (with facets), and
    # take the weighted moments of the offsets of the others from the first of them (a few
    # spacings: Σw d dᵀ - (Σw d)(Σw d)ᵀ/Σw loses nothing to cancellation there, unlike offsets
    # from a foot far off the target) for a weighted PCA over the ball, and their weighted
    # normal (which orients e3)
    cdef double nsum[3]
    cdef double inv_b2 = 1.0 / (ballr * ballr)
    # (the sums in scalars, and the reference normal and first node read once: the compiler
    # keeps them in registers, where arrays written through pointers it must reload and store)
    cdef double nb0 = sc.nbar[0], nb1 = sc.nbar[1], nb2 = sc.nbar[2], sheet_cos = op.sheet_cos
    cdef double o0 = 0.0, o1 = 0.0, o2 = 0.0, d0, d1, d2, p0 = 0.0, p1 = 0.0, p2 = 0.0
    cdef double n0 = 0.0, n1 = 0.0, n2 = 0.0, c00 = 0.0, c01 = 0.0, c02 = 0.0, c11 = 0.0
    cdef double c12 = 0.0, c22 = 0.0
    cdef bint faces = tg.has_faces
    wsum = 0.0
    kept = 0
    for j in range(count):
        node = cand_i[j]
        nv = tg.normals + 3 * node
        if faces:
            facing = nv[0] * nb0 + nv[1] * nb1 + nv[2] * nb2
            if not (facing >= sheet_cos):
                continue
        x = tg.nodes + 3 * node
        if kept == 0:
            o0 = x[0]
            o1 = x[1]
            o2 = x[2]
        cand_i[kept] = node
        wj = weight(WENDLAND, cand_d2[j] * inv_b2, op)
        geo[kept] = wj
        kept += 1
        if wj <= 0.0:
            continue
        wsum += wj
        d0 = x[0] - o0
        d1 = x[1] - o1
        d2 = x[2] - o2
        p0 += wj * d0
        p1 += wj * d1
        p2 += wj * d2
        n0 += wj * nv[0]
        n1 += wj * nv[1]
        n2 += wj * nv[2]
        dr = wj * d0
        c00 += dr * d0
        c01 += dr * d1
        c02 += dr * d2
        dr = wj * d1
        c11 += dr * d1
        c12 += dr * d2
        dr = wj * d2
        c22 += dr * d2
    count = kept
    pp[0] = p0; pp[1] = p1; pp[2] = p2
    nsum[0] = n0; nsum[1] = n1; nsum[2] = n2
    cov[0] = c00; cov[1] = c01; cov[2] = c02; cov[4] = c11; cov[5] = c12; cov[8] = c22
    if wsum > 0:
        for rr in range(3):
            for col in range(rr, 3):
                cov[3 * rr + col] -= pp[rr] * pp[col] / wsum
    cov[3] = cov[1]
    cov[6] = cov[2]
    cov[7] = cov[5]
    if not smallest_eigenvector_psd(cov, e3):
        smallest_eigenvector(cov, e3)
    # +e3 out of the target as the facets orient it; without facets, as the mean plane's
    dot = 0.0
    for e in range(3):
        dot += (nsum[e] if tg.has_faces else wsum * tg.frame_axes[6 + e]) * e3[e]
    if dot < 0:
        for e in range(3):
            e3[e] = -e3[e]
    frame_e1(op, e3, e1)
    right_handed(e1, e3, axes)
    if op.knn:
        R = 0.0
        for j in range(count):
            u0 = 0.0
            u1 = 0.0
            for col in range(3):
                d = tg.nodes[3 * cand_i[j] + col] - ref[col]
                u0 += axes[col] * d
                u1 += axes[3 + col] * d
            R = dmax(R, sqrt(u0 * u0 + u1 * u1))
        R = op.knn_factor * R if R > 0 else op.radius[attempt] * h  # no support: any finite R
    res.R = R
    return count


cdef void blank(Result *res) noexcept nogil:
    """NaN out the geometry of a row without a trustworthy answer."""
    res.gap = NAN
    cdef int e
    for e in range(3):
        res.normal[e] = NAN
        res.proximal[e] = NAN
    res.curvature[0] = NAN
    res.curvature[1] = NAN


cdef void solve(const TargetC *tg, const Options *op, const double *x, bint centred,
                int64_t count, Scratch *sc, Result *res, bint frozen=False) noexcept nogil:
    """Fit and project x with the pairing in res (origin, axes, R, h) and the support
    cand_i[:count]: DiffuseSurface's `_solve` for one contactor. The basis and the weights
    are centred at the contactor's in-plane position [14], [15] (`centred`), as the paper
    does, or at the origin (the previous proximal point, when re-centring). `frozen`: res
    holds the reduced basis and direction of a frozen pairing (res.reduced >= 0: fit that)."""
    cdef int64_t *cand_i = sc.cand_i
    cdef double *s = sc.s
    cdef double *t = sc.t
    cdef double *w = sc.w
    cdef const double *axes = res.axes
    cdef const double *ref = res.origin
    cdef double R = res.R, h = res.h
    cdef double c[3]
    cdef double f[6]
    cdef double st[2]
    cdef double c0, c1, X0, X1, X2, d, q, rc, inv_r, nrm, nu0, nu1, nu2, g, d2min, facing
    cdef double fs, ft, E, F, G, root, L, M, N, det, mean, gauss, disc
    cdef int64_t j, jj, node, kept, positive = 0, its, live = 0
    cdef int e, col, code, why, terms, which = -1
    cdef bint seen, ok, beyond
    cdef double direction = NAN, ca, sa
    cdef const double *fn
    if tg.duplicates:  # each position once, as its first occurrence
        kept = 0
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
        count = kept
    for e in range(3):
        c[e] = 0.0
        for col in range(3):
            c[e] += axes[3 * e + col] * (x[col] - ref[col])
        c[e] /= R
    c0 = c[0] if centred else 0.0
    c1 = c[1] if centred else 0.0
    # the support nodes inside the domain of influence (q < 1), in support order, are the
    # only ones with a weight [15]: s, t, z, w (and geo) hold them alone, `live` of them, and
    # live_i their nodes; every later loop reads those
    inv_r = 1.0 / R
    # (the frame's axes divided by R, in scalars: read once, where through res they would be
    # reloaded a node)
    cdef double r0 = ref[0], r1 = ref[1], r2 = ref[2], d0, d1, d2
    cdef double a00 = axes[0] * inv_r, a01 = axes[1] * inv_r, a02 = axes[2] * inv_r
    cdef double a10 = axes[3] * inv_r, a11 = axes[4] * inv_r, a12 = axes[5] * inv_r
    cdef double a20 = axes[6] * inv_r, a21 = axes[7] * inv_r, a22 = axes[8] * inv_r
    cdef const double *xn
    for j in range(count):
        node = cand_i[j]
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
        w[live] = weight(op.weight, q, op)  # [15]
        if op.weight == SINGULAR:
            sc.geo[live] = weight(WENDLAND, q, op)
        if w[live] > 0:
            positive += 1
        live += 1
    rc = fit(op, sc, live)
    terms = op.nterms
    if frozen and res.reduced >= 0:  # the pairing's reduced basis, at its direction
        which = res.reduced
        direction = res.direction
        terms = fit_reduced(op, sc, live, positive, True, &direction, &which)
    elif not (rc >= op.rcond_min) or positive < op.nterms:
        # the support cannot determine the full basis: the terms it can (a strip, a row)
        terms = fit_reduced(op, sc, live, positive, frame_fixed(tg, op, res, cand_i, count),
                            &direction, &which)
    c[0] -= c0
    c[1] -= c1
    its = newton(op, sc.alpha, c, f, st, &ok)
    surface_derivatives(op, sc.alpha, st[0], st[1], f)
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
    # influence, and within hull_spacings of the in-plane convex hull of the support (not past
    # an open edge, where the fit only extrapolates)
    d2min = INFINITY
    if 0 < terms < op.nterms and isfinite(direction):
        # a strip or a row: along it (across, the hull bounds it: elements may be much wider
        # than long)
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
    if (sqrt(d2min) * R > op.outside_spacings * h or st[0] * st[0] + st[1] * st[1] > 1.0
            or beyond_hull(s, t, w, live, st[0], st[1], op.hull_spacings * h / R,
                           sc.arc_start, sc.arc_end)):
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
    for j in range(live):
        if w[j] <= 0:
            continue
        node = sc.live_i[j]
        fn = tg.fold_normals + 3 * node
        facing = fn[0] * axes[6] + fn[1] * axes[7] + fn[2] * axes[8]
        if not tg.is_signed[node]:
            facing = fabs(facing)
        if facing < op.cos_fold or tg.steep[node]:
            code = OUTSIDE
            why = R_STEEP
            break
    res.status = <int8_t>code
    res.reason = <int8_t>why
    res.support = positive
    res.iterations = its
    res.rcond = rc
    res.terms = <int8_t>terms
    res.reduced = <int8_t>which
    res.direction = direction if which >= 0 else NAN
    # principal curvatures: eigenvalues of the shape operator I⁻¹ II, divided by R
    fs = f[1]
    ft = f[2]
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
    if code >= OUTSIDE:
        blank(res)
    if op.keep:
        res.count = count
        for j in range(count):
            res.index[j] = tg.perm[cand_i[j]]


cdef void select_solve(const TargetC *tg, const Options *op, const double *x,
                       const double *ref, bint centred, int attempt, Scratch *sc,
                       Result *res, double h) noexcept nogil:
    """Support and frame around `ref`, then the fit and projection of x. `h`: the local
    spacing at ref when known (sc.nbar and sc.foot then still hold ref's: the retry), else NaN."""
    cdef int e
    res.overflow = False
    res.count = 0
    res.h = h if not isnan(h) else local_spacing(tg, op, ref, sc)
    for e in range(3):
        res.origin[e] = ref[e]
    cdef int64_t count = select_support(tg, op, ref, attempt, sc, res)
    solve(tg, op, x, centred, count, sc, res)


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
    cdef int it, e
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
            tmp = a; a = b; b = tmp
    if not finite:
        flag_bad_point(a)
    if op.recentre and a.status <= PENETRATION:
        # re-centre the fit on the proximal point until it stops moving: the fixed point is
        # the projection onto S_g^d itself rather than onto the contactor's own local fit
        its = a.iterations
        live = True
        previous = INFINITY
        for it in range(op.recentre_max_iter):
            select_solve(tg, op, x, a.proximal, False, 0, sc, b, NAN)
            overflow = overflow or b.overflow
            move = 0.0
            for e in range(3):
                dd = b.proximal[e] - a.proximal[e]
                move += dd * dd
            move = sqrt(move)
            its += b.iterations
            tmp = a; a = b; b = tmp
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


# --------------------------------------------------------------------------------------------
# the Python face
# --------------------------------------------------------------------------------------------

cdef inline void store(const Result *res, Py_ssize_t r, double *gap, double *normal,
                       double *proximal, int8_t *status, int8_t *reason, int64_t *support,
                       int64_t *iterations, double *rcond, double *curvature,
                       int8_t *terms) noexcept nogil:
    """One contactor's Projection fields into row r of the (C-contiguous) outputs of
    `project` and `project_with` (raw pointers: no memoryview reference counting per point)."""
    cdef int e
    gap[r] = res.gap
    for e in range(3):
        normal[3 * r + e] = res.normal[e]
        proximal[3 * r + e] = res.proximal[e]
    status[r] = res.status
    reason[r] = res.reason
    support[r] = res.support
    iterations[r] = res.iterations
    rcond[r] = res.rcond
    curvature[2 * r] = res.curvature[0]
    curvature[2 * r + 1] = res.curvature[1]
    terms[r] = res.terms


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
    cdef const double[:, ::1] nodes
    cdef const double[:, ::1] normals
    cdef const double[::1] node_spacing
    cdef const int64_t[::1] first
    cdef const double[:, ::1] fold_normals
    cdef const uint8_t[::1] signed_
    cdef const uint8_t[::1] steep
    cdef const int64_t[::1] perm
    cdef const int64_t[::1] inv
    cdef _GridArrays grid
    cdef _GridArrays plane
    cdef TargetC c

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
        perm = build_grid(nodes, cell)[4]
        inv = np.empty(n, dtype=np.int64)
        inv[perm] = np.arange(n)
        self.perm = perm
        self.inv = inv
        self.nodes = np.ascontiguousarray(nodes[perm])
        self.normals = _checked(normals, np.float64, (n, 3))[perm]
        self.node_spacing = _checked(node_spacing, np.float64, (n,))[perm]
        self.first = inv[_checked(first, np.int64, (n,))[perm]]
        self.fold_normals = _checked(fold_normals, np.float64, (n, 3))[perm]
        self.signed_ = _checked(is_signed, np.bool_, (n,)).view(np.uint8)[perm]
        self.steep = _checked(steep, np.bool_, (n,)).view(np.uint8)[perm]
        origin = _checked(origin, np.float64, (3,))
        axes = _checked(axes, np.float64, (3, 3)).ravel()
        self.grid = _GridArrays(self.nodes, cell, tree=True)
        if global_frame:
            plane = np.zeros((n, 3))
            plane[:, :2] = (np.asarray(self.nodes) - origin) @ axes.reshape(3, 3)[:2].T
            self.plane = _GridArrays(plane, cell)
        else:
            self.plane = _GridArrays(np.zeros((1, 3)), 1.0)
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
                double[::1] gap, double[:, ::1] normal, double[:, ::1] proximal,
                int8_t[::1] status, int8_t[::1] reason, int64_t[::1] support,
                int64_t[::1] iterations, double[::1] rcond, double[:, ::1] curvature,
                int8_t[::1] terms, double[:, ::1] origin, double[:, :, ::1] axes,
                double[::1] radius, double[::1] spacing, double[::1] direction,
                int8_t[::1] reduced, int64_t[:, ::1] index, uint8_t[::1] overflow,
                int64_t cap):
        """Project the contactors points[rows] (select, solve, retry, re-centre, bad points).

        Row rows[i]'s results go to row rows[i] of every output but `index`, whose row i
        receives its support (when index has columns; -1 padded). overflow[rows[i]] is set
        where a support had more than `cap` nodes (run those rows again with a larger cap).
        """
        cdef Options op = _options(options, index.shape[1] > 0)
        cdef Py_ssize_t m = rows.shape[0], i
        cdef int64_t r, j, width = index.shape[1]
        cdef int e
        cdef Scratch *sc
        cdef Result *res
        cdef int failed = 0
        cdef int *failedp = &failed
        _check_rows(points, rows, gap, normal, proximal, status, reason, support, iterations,
                    rcond, curvature, terms, origin, axes, radius, spacing, direction, reduced,
                    overflow)
        if index.shape[0] < m and width > 0:
            raise ValueError("index has fewer rows than rows")
        if op.knn and op.k[1] > cap:
            raise ValueError("cap is below k")
        if m == 0:
            return
        with nogil, parallel():
            sc = scratch_new(cap, op.nterms, op.spacing_neighbours)
            if sc == NULL:
                failedp[0] = 1
            for i in prange(m, schedule="dynamic", chunksize=64):
                if sc == NULL:
                    continue
                r = rows[i]
                res = project_one(&self.c, &op, &points[r, 0], sc)
                store(res, r, &gap[0], &normal[0, 0], &proximal[0, 0], &status[0], &reason[0],
                      &support[0], &iterations[0], &rcond[0], &curvature[0, 0], &terms[0])
                for e in range(3):
                    origin[r, e] = res.origin[e]
                for e in range(9):
                    axes[r, e // 3, e % 3] = res.axes[e]
                radius[r] = res.R
                spacing[r] = res.h
                direction[r] = res.direction
                reduced[r] = res.reduced
                overflow[r] = res.overflow
                if width > 0:
                    for j in range(width):
                        index[i, j] = res.index[j] if j < res.count else -1
            scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")

    def project_with(self, dict options, const double[:, ::1] points,
                     const double[:, ::1] origin, const double[:, :, ::1] axes,
                     const double[::1] radius, const double[::1] spacing,
                     const int64_t[:, ::1] index, double[::1] gap, double[:, ::1] normal,
                     double[:, ::1] proximal, int8_t[::1] status, int8_t[::1] reason,
                     int64_t[::1] support, int64_t[::1] iterations, double[::1] rcond,
                     double[:, ::1] curvature, int8_t[::1] terms, double[::1] direction,
                     int8_t[::1] reduced, const int8_t[::1] frozen_reduced=None,
                     const double[::1] frozen_direction=None):
        """Fit and project each contactor with a frozen pairing (origin, axes, R, h, support
        index with -1 holes): the same per-point code as `project` after the selection.
        Contactors with NaN or inf are solved at their origin, then flagged 'failed'. With
        `frozen_reduced` and `frozen_direction` (the pairing's), a row whose pairing fitted a
        reduced basis (>= 0) fits that one at that direction (held fixed, as the frame)."""
        cdef Options op = _options(options, False)
        cdef Py_ssize_t m = points.shape[0], i
        cdef int64_t K = index.shape[1], j, count
        cdef int e
        cdef Scratch *sc
        cdef Result *res
        cdef bint finite
        cdef int failed = 0
        cdef int *failedp = &failed
        for name, arr, shape in (("origin", origin, (m, 3)), ("radius", radius, (m,)),
                                 ("spacing", spacing, (m,)), ("gap", gap, (m,)),
                                 ("normal", normal, (m, 3)), ("proximal", proximal, (m, 3)),
                                 ("status", status, (m,)), ("reason", reason, (m,)),
                                 ("support", support, (m,)), ("iterations", iterations, (m,)),
                                 ("rcond", rcond, (m,)), ("curvature", curvature, (m, 2)),
                                 ("terms", terms, (m,)), ("direction", direction, (m,)),
                                 ("reduced", reduced, (m,))):
            if tuple(arr.shape[:len(shape)]) != shape:
                raise ValueError(f"{name} must have shape {shape}")
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
        with nogil, parallel():
            sc = scratch_new(imax(K, 1), op.nterms, op.spacing_neighbours)
            if sc == NULL:
                failedp[0] = 1
            for i in prange(m, schedule="dynamic", chunksize=64):
                if sc == NULL:
                    continue
                res = &sc.res[0]
                count = 0
                for j in range(K):
                    if index[i, j] >= 0:
                        sc.cand_i[count] = self.c.inv[index[i, j]]
                        count = count + 1
                for e in range(3):
                    res.origin[e] = origin[i, e]
                for e in range(9):
                    res.axes[e] = axes[i, e // 3, e % 3]
                res.R = radius[i]
                res.h = spacing[i]
                finite = isfinite(points[i, 0]) and isfinite(points[i, 1]) and isfinite(points[i, 2])
                if freeze:
                    res.reduced = frozen_reduced[i]
                    res.direction = frozen_direction[i]
                solve(&self.c, &op, &points[i, 0] if finite else &origin[i, 0], True, count,
                      sc, res, freeze)
                if not finite:
                    flag_bad_point(res)
                store(res, i, &gap[0], &normal[0, 0], &proximal[0, 0], &status[0], &reason[0],
                      &support[0], &iterations[0], &rcond[0], &curvature[0, 0], &terms[0])
                direction[i] = res.direction
                reduced[i] = res.reduced
            scratch_free(sc)
        if failed:
            raise MemoryError("no memory for the projection's scratch")


def _checked(a, dtype, shape):
    arr = np.ascontiguousarray(a, dtype=dtype)
    if arr.shape != tuple(shape):
        raise ValueError(f"an array of shape {arr.shape}, expected {tuple(shape)}")
    return arr


def _check_rows(points, rows, *outputs):
    m = points.shape[0]
    if points.shape[1] != 3:
        raise ValueError("points must have shape (m, 3)")
    for out in outputs:
        if out.shape[0] != m:
            raise ValueError(f"an output of shape {tuple(out.shape)}: expected {m} rows")
    r = np.asarray(rows)
    if len(r) and (r.min() < 0 or r.max() >= m):
        raise ValueError("rows index past the points")


cdef Options _options(dict o, bint keep) except *:
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
    for r, exps in enumerate(reduced):
        op.rsize[r] = len(exps)
        op.across[r] = any(b > 0 for _, b in exps)
        op.plane_only[r] = _basis.complete(exps)
        for j in range(len(exps)):
            op.ra[NTERMS_MAX * r + j] = exps[j][0]
            op.rb[NTERMS_MAX * r + j] = exps[j][1]
    op.weight = WEIGHT_CODES[o["weight"]]
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
    op.gauss_c2 = tol.GAUSS_WIDTH**2
    op.gauss_tail = np.exp(-1.0 / tol.GAUSS_WIDTH**2)
    op.singular_floor = tol.SINGULAR_FLOOR
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


def nearest_distances(coords, int64_t k, points=None, search="grid"):
    """Distances (m, k) from each of `points` (m, 3; default: `coords` itself) to its k
    nearest of `coords` (n, 3), nearest first, inf past the n-th: what scipy's
    ``cKDTree(coords).query(points, k)`` gives. `search` picks the engine's search: "grid"
    (`knn`, the node spacing's), "tree" (`tree_knn`), or "nearest" (`nearest`: the local
    spacing's, a ball of cells then the tree)."""
    codes = {"grid": 0, "tree": 1, "nearest": 2}
    if search not in codes:
        raise ValueError(f"search must be one of {sorted(codes)}, got {search!r}")
    cdef int code = codes[search]
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    cdef Py_ssize_t n = len(coords), i, m
    query = coords if points is None else np.ascontiguousarray(points, dtype=np.float64)
    query = query.reshape(-1, 3)
    m = len(query)
    out = np.empty((m, k))
    if m == 0 or k <= 0:
        return out
    if n == 0:
        out[:] = np.inf
        return out
    span = float(np.ptp(coords, axis=0).max())
    # about k nodes per cell on a surface
    cell = span / max(np.sqrt(n / max(k, 1)), 1.0) if span > 0 else 1.0
    cdef _GridArrays grid = _GridArrays(coords, cell, tree=code > 0)
    cdef double[:, ::1] d = out
    cdef const double[:, ::1] x = query
    cdef int64_t *idx
    cdef double *d2
    cdef int64_t got, j, pool = 64
    cdef int failed = 0
    cdef int *failedp = &failed
    with nogil, parallel():
        idx = <int64_t *>malloc((k + pool) * sizeof(int64_t))
        d2 = <double *>malloc((k + pool) * sizeof(double))
        if idx == NULL or d2 == NULL:
            failedp[0] = 1
        for i in prange(m, schedule="static"):
            if idx == NULL or d2 == NULL:
                continue
            if code == 0:
                got = knn(&grid.grid, &x[i, 0], k, idx, d2)
            elif code == 1:
                got = tree_knn(&grid.grid.tree, &x[i, 0], k, idx, d2)
            else:
                got = nearest(&grid.grid, &x[i, 0], k, pool, idx + k, d2 + k, idx, d2)
            for j in range(k):
                d[i, j] = sqrt(d2[j]) if j < got else INFINITY
        free(idx)
        free(d2)
    if failed:
        raise MemoryError("no memory for the nearest-node search")
    return out
