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


cdef int _check_nodes(const int64_t[:, :] f, Py_ssize_t k, Py_ssize_t n) noexcept nogil:
    """1 where a corner of f's first k columns is outside [-n, n) (numpy's IndexError)."""
    cdef Py_ssize_t i, j
    for i in range(f.shape[0]):
        for j in range(k):
            if f[i, j] < -n or f[i, j] >= n:
                return 1
    return 0


cdef inline Py_ssize_t _wrap(int64_t node, Py_ssize_t n) noexcept nogil:
    """A corner index as numpy's indexing takes it (-1: the last node)."""
    return node + n if node < 0 else node


def area_vectors(const double[:, ::1] X, const int64_t[:, :] f, double[:, ::1] out):
    """Each facet's area vector into out (F, 3) (`mls.frame.facet_area_vectors`): half the
    cross product of edges 0-1 and 0-2 (f of 3 columns, triangles) or of the diagonals 0-2
    and 1-3 (4 columns, quads). Bit for bit numpy's ``0.5 * np.cross(b - a, c - a)``: each
    component the same two products less one another, no fused multiply-add (the build does
    not target FMA), then times 0.5 (tests/reference_frame.py)."""
    cdef Py_ssize_t F = f.shape[0], k = f.shape[1], n = X.shape[0], i
    cdef Py_ssize_t a, b, c, d
    cdef double u0, u1, u2, v0, v1, v2
    if k != 3 and k != 4:
        raise ValueError(f"facets of {k} corners: expected 3 or 4")
    if out.shape[0] != F or out.shape[1] != 3:
        raise ValueError("out must have shape (F, 3)")
    if _check_nodes(f, k, n):
        raise IndexError(f"a facet corner outside the {n} nodes")
    with nogil:
        for i in range(F):
            a = _wrap(f[i, 0], n)
            b = _wrap(f[i, 1], n)
            c = _wrap(f[i, 2], n)
            if k == 3:      # edges a-b and a-c
                u0, u1, u2 = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
                v0, v1, v2 = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
            else:           # diagonals a-c and b-d
                d = _wrap(f[i, 3], n)
                u0, u1, u2 = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
                v0, v1, v2 = X[d, 0] - X[b, 0], X[d, 1] - X[b, 1], X[d, 2] - X[b, 2]
            out[i, 0] = 0.5 * (u1 * v2 - u2 * v1)
            out[i, 1] = 0.5 * (u2 * v0 - u0 * v2)
            out[i, 2] = 0.5 * (u0 * v1 - u1 * v0)


def facet_volumes(const double[:, ::1] x, const int64_t[:, :] f):
    """(F,) six times the volume each facet of f (3 or 4 corner columns, valid node
    indices) spans with the origin of x (`projection.inside_out`, the divergence theorem):
    x0 . (x1 x x2), plus x0 . (x2 x x3) for a quad. Bit for bit numpy's
    ``einsum("fi,fi->f", c0, np.cross(c1, c2))`` (the products summed first to last) and
    its quads' ``+=`` (tests/reference_frame.py)."""
    cdef Py_ssize_t F = f.shape[0], k = f.shape[1], n = x.shape[0], i
    cdef Py_ssize_t a, b, c, d
    cdef double q0, q1, q2, v
    if k != 3 and k != 4:
        raise ValueError(f"facets of {k} corners: expected 3 or 4")
    if _check_nodes(f, k, n):
        raise IndexError(f"a facet corner outside the {n} nodes")
    out = np.empty(F)
    cdef double[::1] vol = out
    with nogil:
        for i in range(F):
            a = _wrap(f[i, 0], n)
            b = _wrap(f[i, 1], n)
            c = _wrap(f[i, 2], n)
            q0 = x[b, 1] * x[c, 2] - x[b, 2] * x[c, 1]
            q1 = x[b, 2] * x[c, 0] - x[b, 0] * x[c, 2]
            q2 = x[b, 0] * x[c, 1] - x[b, 1] * x[c, 0]
            v = 0.0 + ((x[a, 0] * q0 + x[a, 2] * q2) + x[a, 1] * q1)
            if k == 4:
                d = _wrap(f[i, 3], n)
                q0 = x[c, 1] * x[d, 2] - x[c, 2] * x[d, 1]
                q1 = x[c, 2] * x[d, 0] - x[c, 0] * x[d, 2]
                q2 = x[c, 0] * x[d, 1] - x[c, 1] * x[d, 0]
                v = v + ((x[a, 0] * q0 + x[a, 2] * q2) + x[a, 1] * q1)
            vol[i] = v
    return out


def add_facet_rows(double[:, ::1] out, const int64_t[:, :] f, const double[:, :] values):
    """out[f[i, j]] += values[i] for every column j, then every facet i (`mls.frame.
    node_normals`: each facet's area vector onto each of its nodes): the order of numpy's
    ``np.add.at(out, f[:, j], values)`` column after column, so the same sums bit for bit,
    without a (facets x columns) table of indices or weights. Corners outside [-n, n) are
    refused (IndexError), negative ones wrap as numpy's."""
    cdef Py_ssize_t F = f.shape[0], k = f.shape[1], n = out.shape[0], i, j, node
    if values.shape[0] != F or values.shape[1] != out.shape[1] or out.shape[1] != 3:
        raise ValueError("values must have shape (F, 3), out (n, 3)")
    if _check_nodes(f, k, n):
        raise IndexError(f"a facet node outside the {n} nodes")
    with nogil:
        for j in range(k):
            for i in range(F):
                node = _wrap(f[i, j], n)
                out[node, 0] += values[i, 0]
                out[node, 1] += values[i, 1]
                out[node, 2] += values[i, 2]


def ordered_nodes(const int64_t[:, ::1] facets, const int64_t[::1] canon,
                  const int64_t[::1] order):
    """(kind (F,), fnode (F, 4)) of facets order[0], order[1], ...: their corner count (3
    where the 4th corner is -1, else 4) and their corners' node identity canon[node] (-1
    past a triangle's third): numpy's ``kind[order]`` and ``np.where(f >= 0,
    canon[np.maximum(f, 0)], -1)`` of ``f = facets[order]``, without the reordered copy."""
    cdef Py_ssize_t F = order.shape[0], f, j
    cdef int64_t g, node
    if facets.shape[1] != 4:
        raise ValueError("facets must have 4 columns")
    kind_arr = np.empty(F, dtype=np.int64)
    fnode_arr = np.empty((F, 4), dtype=np.int64)
    cdef int64_t[::1] kind = kind_arr
    cdef int64_t[:, ::1] fnode = fnode_arr
    with nogil:
        for f in range(F):
            g = order[f]
            kind[f] = 3 if facets[g, 3] < 0 else 4
            for j in range(4):
                node = facets[g, j]
                fnode[f, j] = canon[node] if node >= 0 else -1
    return kind_arr, fnode_arr
