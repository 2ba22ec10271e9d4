# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The facet tables' passes over every facet (`facet.surface._tables`), compiled and linear:
each facet's box and centroid, its corners in hierarchy order, and the edges (the same pair
of nodes is one edge) by a counting sort of their smaller node instead of a sort of every
edge's key. Bit for bit the numpy they replace (tests/reference_facet_setup.py: the
oracle): the same operations in the same order (a facet's centroid sums 0 and its corners
0 to 3, then divides by 4; a box's min and max keep numpy's choice between equal values, the
later corner)."""
import numpy as np

from libc.stdint cimport int64_t


def facet_boxes(const double[:, ::1] X, const int64_t[:, ::1] facets):
    """(bounds (F, 6), centroid (F, 3)) of facets (F, 4) over the nodes' coordinates X (n, 3):
    their corners' box (min then max) and mean (a triangle's 4th corner (-1) repeats its
    first), as numpy's ``min``/``max``/``mean(axis=1)`` of ``facet_corners``."""
    cdef Py_ssize_t F = facets.shape[0], f, j, c
    cdef int64_t node
    bounds_arr = np.empty((F, 6))
    centroid_arr = np.empty((F, 3))
    cdef double[:, ::1] bounds = bounds_arr
    cdef double[:, ::1] centroid = centroid_arr
    cdef double v, lo, hi, s
    with nogil:
        for f in range(F):
            for c in range(3):
                lo = X[facets[f, 0], c]
                hi = lo
                s = 0.0 + lo                      # numpy's sum starts at 0: -0.0 is +0.0
                for j in range(1, 4):
                    node = facets[f, j]
                    v = X[node if node >= 0 else facets[f, 0], c]
                    lo = lo if lo < v else v      # numpy's minimum: the later of equals
                    hi = hi if hi > v else v
                    s = s + v
                bounds[f, c] = lo
                bounds[f, 3 + c] = hi
                centroid[f, c] = s / 4.0
    return bounds_arr, centroid_arr


def facet_corners(const double[:, ::1] X, const int64_t[:, ::1] facets,
                  const int64_t[::1] order):
    """(F, 4, 3) the corners of facets order[0], order[1], ... (a triangle's 4th (-1) repeats
    its first): numpy's ``X[...][order]`` without the table in the facets' own order."""
    cdef Py_ssize_t F = order.shape[0], f, j, c
    cdef int64_t node, g
    corner_arr = np.empty((F, 4, 3))
    cdef double[:, :, ::1] corner = corner_arr
    with nogil:
        for f in range(F):
            g = order[f]
            for j in range(4):
                node = facets[g, j]
                if node < 0:
                    node = facets[g, 0]
                for c in range(3):
                    corner[f, j, c] = X[node, c]
    return corner_arr


def facet_edges(const int64_t[:, ::1] fnode, const int64_t[::1] kind, int64_t n):
    """The edges of facets whose corners are the nodes fnode (F, 4) (node identity; -1 past a
    triangle's 3rd), edge j from corner j to corner j + 1 (the last back to corner 0): the
    same pair of nodes is one edge. Returns (fedge (F, 4) the edge of each facet edge, -1
    for none; edge_ptr (e + 1,) and edge_inc: edge e's incidences 4 f + j, in
    edge_inc[edge_ptr[e]:edge_ptr[e + 1]]), edges numbered by (smaller node, larger node)
    and incidences in increasing order within an edge: a stable sort of the key
    smaller * n + larger, by counting the smaller node then sorting each node's few
    incidences by the larger (insertion, stable)."""
    cdef Py_ssize_t F = fnode.shape[0], f, j, k, i, m = 0, lo, hi, pos
    cdef int64_t a, b, t, key_b, e
    count_arr = np.zeros(n + 1, dtype=np.int64)
    cdef int64_t[::1] count = count_arr
    for f in range(F):
        m += kind[f]
    inc_arr = np.empty(m, dtype=np.int64)
    other_arr = np.empty(m, dtype=np.int64)
    fedge_arr = np.full((F, 4), -1, dtype=np.int64)
    cdef int64_t[::1] inc = inc_arr
    cdef int64_t[::1] other = other_arr
    cdef int64_t[:, ::1] fedge = fedge_arr
    cdef int64_t[::1] edge_ptr
    with nogil:
        for f in range(F):                      # incidences per smaller node
            for j in range(kind[f]):
                k = j + 1 if j + 1 < kind[f] else 0
                a, b = fnode[f, j], fnode[f, k]
                count[(a if a < b else b) + 1] += 1
        for i in range(n):
            count[i + 1] += count[i]
        for f in range(F):                      # placed in increasing 4 f + j: stable
            for j in range(kind[f]):
                k = j + 1 if j + 1 < kind[f] else 0
                a, b = fnode[f, j], fnode[f, k]
                if b < a:
                    a, b = b, a
                pos = count[a]
                count[a] += 1
                inc[pos] = 4 * f + j
                other[pos] = b
        # count[a] is now the end of node a's incidences; each run sorted by the larger
        # node, stably (a node's incidences are its few edges, twice each)
        lo = 0
        for i in range(n):
            hi = count[i]
            for pos in range(lo + 1, hi):
                key_b = other[pos]
                t = inc[pos]
                k = pos - 1
                while k >= lo and other[k] > key_b:
                    other[k + 1] = other[k]
                    inc[k + 1] = inc[k]
                    k -= 1
                other[k + 1] = key_b
                inc[k + 1] = t
            lo = hi
    # a new edge wherever (smaller, larger) changes; runs never straddle two smaller nodes'
    new = np.ones(m, dtype=bool)
    if m > 1:
        bounds = np.zeros(m, dtype=bool)
        ends = count_arr[:n]
        bounds[ends[(ends > 0) & (ends < m)]] = True
        new[1:] = (other_arr[1:] != other_arr[:m - 1]) | bounds[1:]
    edge_ptr_arr = np.append(np.flatnonzero(new), m).astype(np.int64)
    edge_ptr = edge_ptr_arr
    with nogil:
        for e in range(edge_ptr.shape[0] - 1):
            for pos in range(edge_ptr[e], edge_ptr[e + 1]):
                fedge[inc[pos] // 4, inc[pos] % 4] = e
    return fedge_arr, edge_ptr_arr, inc_arr
