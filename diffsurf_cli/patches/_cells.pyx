"""The curved cells' geometry (`surface.cell_coefficients`, `surface.hermite_midsides`) in one
compiled pass over the facets (issue 36): no (F, 4, 3) temporaries, each facet's mid-side
nodes and monomial coefficients computed in registers and written once.

A first-order facet is curved through its corners' normals: each edge x0 -> x1 gets the
mid-side node of the cubic Hermite curve whose end tangents are the edge's projection on each
end's tangent plane, as long as the edge (`hermite_midside`); its cell is that of its corners
and these mid-side nodes (a triangle6 or quad8), where one of them departs from its edge's
middle (`facet_cell`). A second-order cell is its own nodes' (`node_cell`).

The arithmetic is numpy's, operation for operation, so that the tables are bit for bit those
of the former numpy code (`tests/reference_cells_setup.py`): a sum of squares over x, y, z
(`np.linalg.norm`'s add.reduce) left to right, the dot product of `einsum("fkj,fkj->fk")` as
numpy's SIMD loop adds it ((x + z) + y), a monomial coefficient (`einsum("mk,fkj->fmj")`) the
nodes' terms left to right from 0. Built without contracting a * b + c into one rounding
(setup.py's flags on x86-64 emit no FMA).
"""
import numpy as np

from libc.math cimport sqrt
from libc.stdint cimport int64_t, int8_t

#: The monomials (i, j) of a^i b^j of a curved cell's geometry, in its coefficients' order
#: (`_cells.pxd`: the pass's own table).
CELL_MONOMIALS = tuple((CELL_I[k], CELL_J[k]) for k in range(9))


cdef inline double norm3(const double *v) noexcept nogil:
    """|v| as np.linalg.norm(axis=-1) sums it: x² + y², then + z²."""
    return sqrt((v[0] * v[0] + v[1] * v[1]) + v[2] * v[2])


cdef inline void tangent(const double *edge, double length, const double *n,
                         double *t) noexcept nogil:
    """The edge on the plane normal to n, as long as the edge; the edge itself where its
    projection vanishes (n along the edge: a degenerate corner normal)."""
    cdef double d = (edge[0] * n[0] + edge[2] * n[2]) + edge[1] * n[1]
    cdef double norm, ratio
    cdef int e
    for e in range(3):
        t[e] = edge[e] - d * n[e]
    norm = norm3(t)
    if norm > 1e-12 * length:
        ratio = length / norm
        for e in range(3):
            t[e] = t[e] * ratio
    else:
        for e in range(3):
            t[e] = edge[e]


cdef void hermite_midside(const double *x0, const double *x1, const double *n0,
                          const double *n1, double *mid) noexcept nogil:
    """The mid-side node of the cubic Hermite curve from x0 to x1 with end normals n0, n1:
    (x0 + x1) / 2 + (T0 - T1) / 8, T the edge on each end's tangent plane (`tangent`)."""
    cdef double edge[3]
    cdef double t0[3]
    cdef double t1[3]
    cdef double length
    cdef int e
    for e in range(3):
        edge[e] = x1[e] - x0[e]
    length = norm3(edge)
    tangent(edge, length, n0, t0)
    tangent(edge, length, n1, t1)
    for e in range(3):
        mid[e] = 0.5 * (x0[e] + x1[e]) + (t0[e] - t1[e]) / 8.0


cdef void node_cell(const double *nodes, const int64_t *cell, int k, const double *W,
                    double *coef) noexcept nogil:
    """coef (9, 3) = W (9, k) times the cell's k nodes: its monomial coefficients."""
    cdef int m, i, e
    cdef const double *x
    cdef double acc
    for m in range(9):
        for e in range(3):
            acc = 0.0
            for i in range(k):
                x = nodes + 3 * cell[i]
                acc = acc + W[m * k + i] * x[e]
            coef[3 * m + e] = acc


cdef bint facet_cell(const double *nodes, const int64_t *corners, int k,
                     const double *normals, const double *edge_length, const double *W,
                     double *coef) noexcept nogil:
    """A first-order facet's curved cell (k corners, their normals (k, 3), its edges'
    lengths (k,), W (9, 2k) the shape of its corners and mid-side nodes): True and coef
    (9, 3) where one of its edges' Hermite mid-side nodes departs from the edge's middle by
    more than 1e-9 of the edge; False (coef untouched) where all are straight (a flat face:
    its facets answer, as exactly)."""
    cdef double pts[8][3]
    cdef double off[3]
    cdef const double *x0
    cdef const double *x1
    cdef bint curved = False
    cdef int j, nxt, e, m, i
    cdef double acc
    for j in range(k):
        nxt = j + 1 if j + 1 < k else 0
        x0 = nodes + 3 * corners[j]
        x1 = nodes + 3 * corners[nxt]
        hermite_midside(x0, x1, normals + 3 * j, normals + 3 * nxt, pts[k + j])
        for e in range(3):
            pts[j][e] = x0[e]
            off[e] = pts[k + j][e] - 0.5 * (x0[e] + x1[e])
        if norm3(off) > 1e-9 * edge_length[j]:
            curved = True
    if not curved:
        return False
    for m in range(9):
        for e in range(3):
            acc = 0.0
            for i in range(2 * k):
                acc = acc + W[m * 2 * k + i] * pts[i][e]
            coef[3 * m + e] = acc
    return True


def midsides(const double[:, ::1] nodes, const int64_t[:, ::1] corners,
             const int64_t[::1] kind, const double[:, :, ::1] normals):
    """(F, 4, 3) the Hermite mid-side node of every facet edge j (corner j to j + 1, the
    last to corner 0), a triangle's fourth slot as the former numpy code filled it (from
    node 0 to its corner 0, with a zero normal there): `surface.hermite_midsides`."""
    cdef Py_ssize_t F = corners.shape[0], f
    cdef int j, nxt
    out = np.empty((F, 4, 3))
    cdef double[:, :, ::1] mid = out
    cdef int64_t a, b
    if F == 0:
        return out
    with nogil:
        for f in range(F):
            for j in range(4):
                nxt = j + 1 if j + 1 < kind[f] else 0
                a = corners[f, j] if corners[f, j] >= 0 else 0
                b = corners[f, nxt] if corners[f, nxt] >= 0 else 0
                hermite_midside(&nodes[a, 0], &nodes[b, 0], &normals[f, j, 0],
                                &normals[f, nxt, 0], &mid[f, j, 0])
    return out


def facet_cells(const double[:, ::1] nodes, const int64_t[:, ::1] corners, int k,
                const double[:, :, ::1] normals, const double[:, ::1] edge_length,
                const double[:, ::1] W, Py_ssize_t start, Py_ssize_t stop,
                int8_t[::1] has, double[:, :, ::1] coef):
    """The curved cells of the first-order facets start..stop (k corners each) into has,
    coef (`facet_cell`); the number of curved ones."""
    cdef Py_ssize_t f, n = 0
    if not (W.shape[0] == 9 and W.shape[1] == 2 * k and corners.shape[1] == 4
            and normals.shape[1] == 4 and normals.shape[2] == 3
            and edge_length.shape[1] == 4 and coef.shape[1] == 9 and coef.shape[2] == 3
            and 0 <= start <= stop <= corners.shape[0] and stop <= normals.shape[0]
            and stop <= edge_length.shape[0] and stop <= has.shape[0]
            and stop <= coef.shape[0] and k in (3, 4)):
        raise ValueError("curved cells: arrays disagree in shape")
    with nogil:
        for f in range(start, stop):
            if facet_cell(&nodes[0, 0], &corners[f, 0], k, &normals[f, 0, 0],
                          &edge_length[f, 0], &W[0, 0], &coef[f, 0, 0]):
                has[f] = 1
                n += 1
    return n


def facet_curved(const double[:, ::1] nodes, const int64_t[:, ::1] corners, int k,
                 const double[:, :, ::1] normals, const double[:, ::1] edge_length,
                 Py_ssize_t start, Py_ssize_t stop, int8_t[::1] has):
    """Which first-order facets start..stop (k corners each) have a curved cell: has[f] = 1
    where `facet_cell` would return True, by its own test edge by edge (an edge's Hermite
    mid-side node more than 1e-9 of its length off its middle), stopping at the first
    curved edge and computing no coefficients (`surface.cell_tables`: a first-order target
    keeps no table, only which facets are curved); the number of curved ones."""
    cdef Py_ssize_t f, n = 0
    cdef double mid[3]
    cdef double off[3]
    cdef const double *x0
    cdef const double *x1
    cdef const int64_t *c
    cdef const double *nrm
    cdef int j, nxt, e
    if not (corners.shape[1] == 4 and normals.shape[1] == 4 and normals.shape[2] == 3
            and edge_length.shape[1] == 4 and 0 <= start <= stop <= corners.shape[0]
            and stop <= normals.shape[0] and stop <= edge_length.shape[0]
            and stop <= has.shape[0] and k in (3, 4)):
        raise ValueError("curved cells: arrays disagree in shape")
    with nogil:
        for f in range(start, stop):
            c = &corners[f, 0]
            nrm = &normals[f, 0, 0]
            for j in range(k):
                nxt = j + 1 if j + 1 < k else 0
                x0 = &nodes[0, 0] + 3 * c[j]
                x1 = &nodes[0, 0] + 3 * c[nxt]
                hermite_midside(x0, x1, nrm + 3 * j, nrm + 3 * nxt, mid)
                for e in range(3):
                    off[e] = mid[e] - 0.5 * (x0[e] + x1[e])
                if norm3(off) > 1e-9 * edge_length[f, j]:
                    has[f] = 1
                    n += 1
                    break
    return n


def node_cells(const double[:, ::1] nodes, const int64_t[:, ::1] cells,
               const double[:, ::1] W, Py_ssize_t start, int8_t[::1] has,
               double[:, :, ::1] coef):
    """The second-order cells `cells` (c, k) into has, coef from row `start` (`node_cell`)."""
    cdef Py_ssize_t c = cells.shape[0], k = cells.shape[1], i
    if not (W.shape[0] == 9 and W.shape[1] == k and 0 <= start
            and start + c <= has.shape[0] and start + c <= coef.shape[0]
            and coef.shape[1] == 9 and coef.shape[2] == 3 and k <= 9):
        raise ValueError("curved cells: arrays disagree in shape")
    with nogil:
        for i in range(c):
            node_cell(&nodes[0, 0], &cells[i, 0], <int>k, &W[0, 0], &coef[start + i, 0, 0])
            has[start + i] = 1
    return c
