# cython: language_level=3
"""Searches over the target's nodes, written once (`cdef inline`): a uniform grid of cells
(the k nearest nodes `knn`, the nodes in a ball `ball`) and its k-d tree (`tree_knn`), and
`nearest`, the local spacing's search. Built by `_search.pyx` (`build_grid`, `build_tree`,
`empty_rings`, the `GridArrays` that keep a grid's arrays alive)."""
from libc.math cimport sqrt, fabs, isnan, INFINITY
from libc.stdint cimport int64_t, uint8_t, uint64_t

from ._linalg cimport dmin, dmax, imin, imax


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
    double near_reach      # cells: the first box `nearest` searches (tol.NEAR_REACH_CELLS)
    double cell_margin     # relative round-off margin of cell bounds (tol.SEARCH_MARGIN)
    double box_margin      # ... and of the tree's boxes (tol.TREE_MARGIN)


#: Tree nodes the k-d tree search keeps pending at most: two a level (depth <= 60).
cdef enum:
    TREE_STACK = 128


cdef class GridArrays:
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


cdef inline double box_gap2(const double *box, const double *p, double margin) noexcept nogil:
    """The squared distance from p to a box (lo xyz, hi xyz), less `margin` along each axis."""
    cdef double d, d2 = 0.0
    cdef int e
    for e in range(3):
        d = dmax(dmax(box[e] - p[e], p[e] - box[3 + e]) - margin, 0.0)
        d2 += d * d
    return d2


# the searches (`_search.pyx`)
cdef int64_t knn(const Grid *g, const double *p, int64_t k, int64_t *best_i,
                 double *best_d2) noexcept nogil
cdef int64_t ball(const Grid *g, const double *p, double r2, int64_t cap, int64_t *out_i,
                  double *out_d2) noexcept nogil
cdef int64_t tree_knn(const Tree *tr, const double *p, int64_t k, int64_t *best_i,
                      double *best_d2, double tr_margin) noexcept nogil
cdef int64_t nearest(const Grid *g, const double *p, int64_t k, int64_t cap, int64_t *pool_i,
                     double *pool_d2, int64_t *best_i, double *best_d2) noexcept nogil
