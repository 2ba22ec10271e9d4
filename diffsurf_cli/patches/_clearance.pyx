# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The clearances of a patched target's facets (`clearance.py`), compiled: a k-d tree
(`Tree`) and one query a facet, with no (F, K) table.

The foreign clearance (`foreign_bound`, `clearance.foreign_clearance`): the tree of the
facets' centroids, each centroid's K nearest.

For facet f, with d_K its K-th nearest centroid distance (f itself counted, as the tree query
of the numpy version counted it), the bound is

    min(min over foreign g nearer than d_K of  d(f, g) - reach[f] - reach[g] - bound[g],
        d_K - reach[f] - max(reach) - max(bound))

(foreign: g's patch is not in f's vertex ring's patches). A foreign g at d_K or beyond
gives a term at least the second's (floating-point subtraction is monotone), so the min may
take every foreign facet the search meets and none of those it prunes: the search keeps only
the K smallest squared distances (a max-heap), not which facets they are, and the answer is
that of the numpy version bit for bit whatever the order of ties. The distances are those of
scipy's cKDTree (squared differences summed x, y, z, then the square root); a box's squared
distance is summed likewise, so it is never more than that of a point inside it.

The feature clearance (`nearest_distance`, `clearance.feature_clearance`): the tree of the
samples of the features, each centroid's nearest, the centroids taken in the order of a tree
of their own, each search bounded from the start by its distance to the previous one's
nearest sample (close by: most of the tree is pruned at once; a centroid far from every
feature made cKDTree's query 5 us). The distance is cKDTree's, the least one.
"""
import numpy as np

from libc.math cimport sqrt, INFINITY
from libc.stdlib cimport malloc, free
from libc.stdint cimport int64_t

cdef enum:
    LEAF = 16           # points in a leaf of the tree
    STACK = 256         # the search's stack (twice the tree's depth suffices)


cdef inline double sq3(const double *a, const double *b) noexcept nogil:
    """|a - b|^2 summed as cKDTree sums it (x, y, then z)."""
    cdef double d = a[0] - b[0]
    cdef double s = d * d
    d = a[1] - b[1]
    s = s + d * d
    d = a[2] - b[2]
    return s + d * d


cdef inline double box_sq(const double *box, const double *q) noexcept nogil:
    """Squared distance from q to an axis-aligned box (lo[3], hi[3]), no more than that of
    any point inside it (each gap no more than the point's, each step monotone)."""
    cdef double s = 0.0, d
    cdef int e
    for e in range(3):
        if q[e] < box[e]:
            d = box[e] - q[e]
        elif q[e] > box[3 + e]:
            d = q[e] - box[3 + e]
        else:
            d = 0.0
        s = s + d * d
    return s


cdef void select_nth(int64_t *idx, const double *pts, int64_t lo, int64_t hi, int64_t nth,
                     int dim) noexcept nogil:
    """Reorder idx[lo:hi] so that idx[nth] has the nth smallest coordinate dim, none after
    it smaller, none before it larger (quickselect)."""
    cdef int64_t i, j, t
    cdef double pivot
    hi -= 1
    while hi > lo:
        pivot = pts[3 * idx[(lo + hi) // 2] + dim]
        i = lo
        j = hi
        while i <= j:
            while pts[3 * idx[i] + dim] < pivot:
                i += 1
            while pts[3 * idx[j] + dim] > pivot:
                j -= 1
            if i <= j:
                t = idx[i]
                idx[i] = idx[j]
                idx[j] = t
                i += 1
                j -= 1
        if nth <= j:
            hi = j
        elif nth >= i:
            lo = i
        else:
            return


cdef inline void heap_replace(double *heap, int n, double v) noexcept nogil:
    """Put v at the top of the max-heap heap[:n] and sift it down."""
    cdef int i = 0, c
    while True:
        c = 2 * i + 1
        if c >= n:
            break
        if c + 1 < n and heap[c + 1] > heap[c]:
            c += 1
        if heap[c] <= v:
            break
        heap[i] = heap[c]
        i = c
    heap[i] = v


cdef inline void heap_push(double *heap, int n, double v) noexcept nogil:
    """Add v to the max-heap heap[:n] (now n + 1 long)."""
    cdef int i = n, p
    while i > 0:
        p = (i - 1) // 2
        if heap[p] >= v:
            break
        heap[i] = heap[p]
        i = p
    heap[i] = v


cdef class Tree:
    """A k-d tree of n points (n, 3): node i holds the points order[start[i]:start[i] +
    count[i]], its children child[i] and child[i] + 1 (-1: a leaf), its box box[6i:6i + 6]
    (lo, hi) the points' own; split at the median of the box's widest side, so its depth is
    log2(n / LEAF) whatever the points. at: the points in that order, a leaf's side by
    side."""
    cdef int64_t n, nodes
    cdef int64_t *order
    cdef int64_t *start
    cdef int64_t *count
    cdef int64_t *child
    cdef double *box
    cdef double *at

    def __cinit__(self, const double[:, ::1] points):
        cdef int64_t n = points.shape[0]
        cdef int64_t most = 2 * (n // (LEAF // 2) + 1) + 1
        if points.shape[1] != 3 or n == 0:
            raise ValueError("a tree of (n > 0, 3) points")
        self.n = n
        self.order = <int64_t *> malloc((n + 1) * sizeof(int64_t))
        self.start = <int64_t *> malloc(most * sizeof(int64_t))
        self.count = <int64_t *> malloc(most * sizeof(int64_t))
        self.child = <int64_t *> malloc(most * sizeof(int64_t))
        self.box = <double *> malloc(6 * most * sizeof(double))
        self.at = <double *> malloc(3 * (n + 1) * sizeof(double))
        if not (self.order and self.start and self.count and self.child and self.box
                and self.at):
            raise MemoryError()
        with nogil:
            self.nodes = build(&points[0, 0], n, self.order, self.start, self.count,
                               self.child, self.box, self.at)

    def __dealloc__(self):
        free(self.order)
        free(self.start)
        free(self.count)
        free(self.child)
        free(self.box)
        free(self.at)


cdef int64_t build(const double *pts, int64_t n, int64_t *idx, int64_t *start,
                   int64_t *count, int64_t *child, double *box, double *at) noexcept nogil:
    """Fill a `Tree`'s arrays; returns its number of nodes."""
    cdef int64_t stack[STACK]
    cdef int64_t sp, node, n_nodes, lo, hi, mid, s
    cdef int e, dim
    cdef double w, wmax
    cdef double *c
    for s in range(n):
        idx[s] = s
    n_nodes = 1
    start[0] = 0
    count[0] = n
    sp = 1
    stack[0] = 0
    while sp > 0:
        sp -= 1
        node = stack[sp]
        lo = start[node]
        hi = lo + count[node]
        c = box + 6 * node
        for e in range(3):
            c[e] = pts[3 * idx[lo] + e]
            c[3 + e] = pts[3 * idx[lo] + e]
        for s in range(lo + 1, hi):
            for e in range(3):
                w = pts[3 * idx[s] + e]
                if w < c[e]:
                    c[e] = w
                if w > c[3 + e]:
                    c[3 + e] = w
        if hi - lo <= LEAF:
            child[node] = -1
            continue
        dim = 0
        wmax = c[3] - c[0]
        for e in range(1, 3):
            if c[3 + e] - c[e] > wmax:
                wmax = c[3 + e] - c[e]
                dim = e
        mid = (lo + hi) // 2
        select_nth(idx, pts, lo, hi, mid, dim)
        child[node] = n_nodes
        start[n_nodes] = lo
        count[n_nodes] = mid - lo
        start[n_nodes + 1] = mid
        count[n_nodes + 1] = hi - mid
        stack[sp] = n_nodes
        stack[sp + 1] = n_nodes + 1
        sp += 2
        n_nodes += 2
    for s in range(n):
        for e in range(3):
            at[3 * s + e] = pts[3 * idx[s] + e]
    return n_nodes


cdef inline int push_children(Tree T, int64_t node, const double *q, int64_t *stack,
                              double *stack_d2, int sp) noexcept nogil:
    """Push node's children, the nearer last (searched first), with their boxes' squared
    distances; returns the new stack size."""
    cdef int64_t a = T.child[node]
    cdef double near_d2 = box_sq(T.box + 6 * a, q)
    cdef double far_d2 = box_sq(T.box + 6 * (a + 1), q)
    if near_d2 <= far_d2:
        stack[sp] = a + 1
        stack_d2[sp] = far_d2
        stack[sp + 1] = a
        stack_d2[sp + 1] = near_d2
    else:
        stack[sp] = a
        stack_d2[sp] = near_d2
        stack[sp + 1] = a + 1
        stack_d2[sp + 1] = far_d2
    return sp + 2


def foreign_bound(const double[:, ::1] centroid, const double[::1] reach,
                  const int64_t[::1] label, const int64_t[::1] ring_ptr,
                  const int64_t[::1] ring, const double[::1] bound, int k,
                  double[::1] out):
    """out[f]: the bound of the module docstring before its round-off margin, for the K = k
    nearest centroids (k <= F; k == F: no second term). reach and bound: (F,), their maxima
    taken here."""
    cdef int64_t F = centroid.shape[0]
    if not (reach.shape[0] == label.shape[0] == bound.shape[0] == out.shape[0] == F
            and ring_ptr.shape[0] == F + 1 and 0 < k <= F):
        raise ValueError("foreign_bound's arrays disagree in length")
    cdef Tree T = Tree(centroid)
    cdef double *heap = <double *> malloc(k * sizeof(double))
    if not heap:
        raise MemoryError()
    cdef int64_t stack[STACK]
    cdef double stack_d2[STACK]
    cdef int64_t node, s, t, f, g, j
    cdef int n, sp
    cdef double d2, best, lower, rmax = 0.0, bmax = -INFINITY
    cdef const double *q
    cdef bint mine, home
    try:
        with nogil:
            for f in range(F):
                if reach[f] > rmax:
                    rmax = reach[f]
                if bound[f] > bmax:
                    bmax = bound[f]
            # the queries, in the tree's order (neighbours in turn: the same nodes in cache),
            # each a depth-first search, nearer child first, of the nodes nearer than the
            # K-th nearest so far
            for t in range(F):
                f = T.order[t]
                q = T.at + 3 * t
                n = 0
                best = INFINITY
                home = False  # f's own patch among its ring's (a vertex ring holds f)
                for j in range(ring_ptr[f], ring_ptr[f + 1]):
                    if ring[j] == label[f]:
                        home = True
                sp = 1
                stack[0] = 0
                stack_d2[0] = box_sq(T.box, q)
                while sp > 0:
                    sp -= 1
                    node = stack[sp]
                    if n == k and stack_d2[sp] >= heap[0]:
                        continue
                    if T.child[node] >= 0:
                        sp = push_children(T, node, q, stack, stack_d2, sp)
                        continue
                    for s in range(T.start[node], T.start[node] + T.count[node]):
                        d2 = sq3(q, T.at + 3 * s)
                        if n < k:
                            heap_push(heap, n, d2)
                            n += 1
                        elif d2 < heap[0]:
                            heap_replace(heap, n, d2)
                        else:
                            continue  # at or past d_K: dominated by the second term
                        g = T.order[s]
                        if home and label[g] == label[f]:
                            continue
                        mine = False
                        for j in range(ring_ptr[f], ring_ptr[f + 1]):
                            if ring[j] == label[g]:
                                mine = True
                                break
                        if not mine:
                            lower = sqrt(d2) - reach[f] - reach[g] - bound[g]
                            if lower < best:
                                best = lower
                if k < F:  # every facet past the K-th nearest centroid
                    lower = sqrt(heap[0]) - reach[f] - rmax - bmax
                    if lower < best:
                        best = lower
                out[f] = best
    finally:
        free(heap)
    return np.asarray(out)


def nearest_distance(const double[:, ::1] samples, const double[:, ::1] points,
                     double[::1] out):
    """out[i]: the distance from points[i] to its nearest sample (as cKDTree's query)."""
    cdef int64_t m = points.shape[0]
    if out.shape[0] != m or samples.shape[0] == 0:
        raise ValueError("nearest_distance: samples and points disagree")
    if m == 0:
        return np.asarray(out)
    cdef Tree S = Tree(samples)
    cdef Tree P = Tree(points)
    cdef int64_t stack[STACK]
    cdef double stack_d2[STACK]
    cdef int64_t node, s, t, near = 0
    cdef int sp
    cdef double d2, best
    cdef const double *q
    with nogil:
        for t in range(m):
            q = P.at + 3 * t
            # bounded from the start by the previous point's nearest (any sample bounds it)
            best = sq3(q, S.at + 3 * near)
            sp = 1
            stack[0] = 0
            stack_d2[0] = box_sq(S.box, q)
            while sp > 0:
                sp -= 1
                node = stack[sp]
                if stack_d2[sp] >= best:
                    continue
                if S.child[node] >= 0:
                    sp = push_children(S, node, q, stack, stack_d2, sp)
                    continue
                for s in range(S.start[node], S.start[node] + S.count[node]):
                    d2 = sq3(q, S.at + 3 * s)
                    if d2 < best:
                        best = d2
                        near = s
            out[P.order[t]] = sqrt(best)
    return np.asarray(out)
