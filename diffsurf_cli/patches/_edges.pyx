"""The facet edges' cosines, classes and flat faces in one compiled pass each (issue 36:
`segment.segment`, `segment._flat_faces`, `PatchedSurface._classify_edges`), linear in the
edges, with no temporaries of more than one entry an edge or a node.

Every value is bit for bit what the former numpy code gave (tests/reference_topology.py is
that code, tests/test_setup3_fast.py the comparison): the segmentation and the edges' classes
decide the patches and where the facets answer, so no bit may move. Hence numpy's orders:

- a facet's unit normal for the segmentation is its area vector divided by its largest
  component's magnitude (`np.maximum` of the three, NaN propagated), then by its norm
  sqrt((x0² + x1²) + x2²), each division only where the divisor is > 0, else 0;
- a dot product of 3-vectors is (p0 + p2) + p1, +0 for a sum of zeros (`np.einsum`'s SIMD
  order: see `_guard.pyx`);
- a node's class is the highest of its edges' (the former writes, class by class, lowest
  first).
Products and sums are never fused (no FMA: setup.py builds without -march).
"""
from libc.math cimport fabs, sqrt
from libc.stdint cimport int8_t, int32_t, int64_t

import numpy as np


cdef inline double dot3(const double *u, const double *v) noexcept nogil:
    """np.einsum('ij,ij->i') of one row: (p0 + p2) + p1, +0 for a sum of zeros."""
    return ((u[0] * v[0] + u[2] * v[2]) + u[1] * v[1]) + 0.0


cdef inline double mx(double a, double b) noexcept nogil:
    """np.maximum(a, b): b where equal, NaN propagated."""
    return a if (a > b or a != a) else b


def two_facets(const int64_t[::1] start, const int64_t[::1] order, const int64_t[::1] fac):
    """(fa, fb) int64: the facets of each manifold edge (exactly two half-edges), by edge: its
    first and second half-edge's (`segment._two_facets`)."""
    cdef Py_ssize_t ne = start.shape[0] - 1, i, m = 0
    with nogil:
        for i in range(ne):
            if start[i + 1] - start[i] == 2:
                m += 1
    fa_a = np.empty(m, np.int64)
    fb_a = np.empty(m, np.int64)
    cdef int64_t[::1] fa = fa_a, fb = fb_a
    with nogil:
        m = 0
        for i in range(ne):
            if start[i + 1] - start[i] == 2:
                fa[m] = fac[order[start[i]]]
                fb[m] = fac[order[start[i] + 1]]
                m += 1
    return fa_a, fb_a


def closed_pairs(const int64_t[::1] start, const int64_t[::1] order,
                 const int64_t[::1] fac, const int8_t[::1] forward, Py_ssize_t F):
    """The edges that close a surface (`projection.inside_out`): (a, b, open_facet), a and b
    int64 the facets of each edge of exactly two half-edges run opposite ways (`forward`
    differs), its first and second half-edge's, in edge order; open_facet (F,) uint8: 1 at
    a facet of any other edge (open, non-manifold, or run the same way twice), which leaves
    its surface unclosed. One pass over the edges: numpy's former masks and gathers, the
    same arrays (tests/test_inside_out_fast.py)."""
    cdef Py_ssize_t ne = start.shape[0] - 1, i, t, m = 0
    if not (order.shape[0] == fac.shape[0] == forward.shape[0] and ne >= 0
            and (ne == 0 or start[ne] <= order.shape[0])):
        raise ValueError("closed edges: arrays disagree in shape")
    with nogil:
        for i in range(ne):
            if (start[i + 1] - start[i] == 2
                    and forward[order[start[i]]] != forward[order[start[i] + 1]]):
                m += 1
    a_a = np.empty(m, np.int64)
    b_a = np.empty(m, np.int64)
    open_a = np.zeros(F, np.uint8)
    cdef int64_t[::1] a = a_a, b = b_a
    cdef unsigned char[::1] open_facet = open_a
    with nogil:
        m = 0
        for i in range(ne):
            if (start[i + 1] - start[i] == 2
                    and forward[order[start[i]]] != forward[order[start[i] + 1]]):
                a[m] = fac[order[start[i]]]
                b[m] = fac[order[start[i] + 1]]
                m += 1
            else:
                for t in range(start[i], start[i + 1]):
                    open_facet[fac[order[t]]] = 1
    return a_a, b_a, open_a


def segment_cosines(const double[:, ::1] area, const int64_t[::1] fa, const int64_t[::1] fb):
    """(m,) the cosine across each manifold edge (facets fa, fb) of the facets' unit normals,
    those of `segment.segment`: area / max|area_i|, then / its norm (0 where a divisor is not
    > 0), dotted in np.einsum's order."""
    cdef Py_ssize_t F = area.shape[0], f, i, m = fa.shape[0]
    cdef double top, x, y, z, nrm
    unit_a = np.empty((F, 3), np.float64)
    cos_a = np.empty(m, np.float64)
    cdef double[:, ::1] unit = unit_a
    cdef double[::1] cos = cos_a
    with nogil:
        for f in range(F):
            x, y, z = area[f, 0], area[f, 1], area[f, 2]
            top = mx(mx(fabs(x), fabs(y)), fabs(z))
            if top > 0:
                x, y, z = x / top, y / top, z / top
            else:
                x = y = z = 0.0
            nrm = sqrt((x * x + y * y) + z * z)
            if nrm > 0:
                unit[f, 0], unit[f, 1], unit[f, 2] = x / nrm, y / nrm, z / nrm
            else:
                unit[f, 0] = unit[f, 1] = unit[f, 2] = 0.0
        for i in range(m):
            cos[i] = dot3(&unit[fa[i], 0], &unit[fb[i], 0])
    return cos_a


def flat_faces(list blocks, const int64_t[::1] key, Py_ssize_t n,
               const int64_t[::1] comp, const int64_t[::1] start,
               const int64_t[:, ::1] ends):
    """(F,) int64 the flat face of each facet (`segment._flat_faces`), -1 for none: its
    coplanar group `comp` where the group has more than one facet and a node all of whose
    facets are in it, not on an open edge (an edge of one half-edge: `start`, `ends`).
    `blocks`: the facets' corner blocks ((f_b, k) int64), facets numbered block after block;
    `key`: the node identity, n nodes."""
    cdef Py_ssize_t F = comp.shape[0], base = 0, r, j, k, m, f, i, ne = ends.shape[0]
    cdef int64_t node, c
    cdef const int64_t[:, ::1] cb
    some_a = np.full(n, -1, np.int64)
    state_a = np.zeros(n, np.int8)  # 0: no facet, 1: all of one group, 2: mixed or open
    has_a = np.zeros(F, np.int8)
    size_a = np.zeros(F, np.int64)
    out_a = np.empty(F, np.int64)
    cdef int64_t[::1] some = some_a, size = size_a, out = out_a
    cdef int8_t[::1] state = state_a, has = has_a
    for blk in blocks:
        cb = blk
        m, k = cb.shape[0], cb.shape[1]
        with nogil:
            for r in range(m):
                c = comp[base + r]
                for j in range(k):
                    node = key[cb[r, j]]
                    if state[node] == 0:
                        state[node] = 1
                        some[node] = c
                    elif some[node] != c:
                        state[node] = 2
        base += m
    with nogil:
        for i in range(ne):  # the nodes on an open edge are never inside a face
            if start[i + 1] - start[i] == 1:
                state[ends[i, 0]] = 2
                state[ends[i, 1]] = 2
        for i in range(n):
            if state[i] == 1:
                has[some[i]] = 1
        for f in range(F):
            size[comp[f]] += 1
        for f in range(F):
            c = comp[f]
            out[f] = c if (has[c] and size[c] > 1) else -1
    return out_a


def classify(const int64_t[::1] start, const int64_t[::1] order, const int64_t[::1] fac,
             const int64_t[::1] loc, const int64_t[::1] edge, const int64_t[:, ::1] ends,
             const double[:, ::1] normal, const int64_t[::1] label, same_tag,
             double sharp_cos, Py_ssize_t F, Py_ssize_t n, const int64_t[::1] key,
             int inside_c, int smooth_c, int open_c, int sharp_c):
    """`PatchedSurface._classify_edges`' tables in one pass over the edges: edge_class (F, 4)
    int8 of each facet edge, vertex_class (n,) int8 of each node (the highest class of its
    edges, by identity `key`), edge_facets (m, 2) int32 (each manifold edge's two facets,
    smallest first), edge_sharp (m,) bool. An edge is sharp where the cosine of its facets'
    `normal`s is below `sharp_cos` and, with `same_tag` ((m,) bool, or None), they differ
    in tag; open where it has not exactly two half-edges; inside where both facets are in
    one patch (`label`); smooth otherwise."""
    cdef Py_ssize_t ne = start.shape[0] - 1, i, h, m = 0, e = fac.shape[0]
    cdef int64_t f1, f2, flo, fhi
    cdef double cs
    cdef bint sharp
    cdef int8_t cl
    cdef const int8_t[::1] tag
    cdef bint tagged = same_tag is not None
    if tagged:
        tag = np.ascontiguousarray(same_tag).view(np.int8)
    with nogil:
        for i in range(ne):
            if start[i + 1] - start[i] == 2:
                m += 1
    cls_a = np.empty(ne, np.int8)
    vc_a = np.zeros(n, np.int8)
    ec_a = np.zeros((F, 4), np.int8)
    pairs_a = np.empty((m, 2), np.int32)
    esharp_a = np.empty(m, bool)
    cdef int8_t[::1] cls = cls_a, vc = vc_a
    cdef int8_t[:, ::1] ec = ec_a
    cdef int32_t[:, ::1] pairs = pairs_a
    cdef int8_t[::1] esharp = esharp_a.view(np.int8)
    with nogil:
        m = 0
        for i in range(ne):
            if start[i + 1] - start[i] == 2:
                f1, f2 = fac[order[start[i]]], fac[order[start[i] + 1]]
                flo = f1 if f1 < f2 else f2
                fhi = f2 if f1 < f2 else f1
                cs = dot3(&normal[flo, 0], &normal[fhi, 0])
                sharp = cs < sharp_cos
                if tagged and tag[m]:
                    sharp = False
                if sharp:
                    cl = sharp_c
                elif label[flo] == label[fhi]:
                    cl = inside_c
                else:
                    cl = smooth_c
                pairs[m, 0], pairs[m, 1] = <int32_t>flo, <int32_t>fhi
                esharp[m] = sharp
                m += 1
            else:
                cl = open_c
            cls[i] = cl
            if cl > vc[ends[i, 0]]:
                vc[ends[i, 0]] = cl
            if cl > vc[ends[i, 1]]:
                vc[ends[i, 1]] = cl
        for h in range(e):
            ec[fac[h], loc[h]] = cls[edge[h]]
    vertex_a = np.empty(len(key), np.int8)
    cdef int8_t[::1] vertex = vertex_a
    with nogil:
        for i in range(key.shape[0]):
            vertex[i] = vc[key[i]]
    return ec_a, vertex_a, pairs_a, esharp_a
