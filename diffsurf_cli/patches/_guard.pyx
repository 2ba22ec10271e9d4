"""The guard's tables in one compiled pass each (`surface.corner_normals`, `surface.guard_bounds`;
issue 36): the corner normals of each facet's smooth region, its edges' lengths and bends, and
the largest sags, turns and normal cosines over each facet's ring, with O(F) outputs and no
ring-sized temporaries.

Every value is bit for bit what the former numpy code gave (tests/reference_guard.py is that
code, tests/test_guard_fast.py the comparison): the guard's bounds decide which answers it
takes, so no bit may move. Hence the orders below, which are numpy's, not ours:

- a norm is sqrt((x0² + x1²) + x2²) (`np.linalg.norm`'s add.reduce of the squares);
- a dot product of 3-vectors is (p0 + p2) + p1 (`np.einsum`'s SIMD sum of the products on
  numpy 2 with AVX2 or AVX-512: lanes 0 and 2, then 1), made +0 where every product is a
  zero (a numpy summing (p0 + p1) + p2 would have differed from this in the last bit);
- the spread's angle is np.arccos of the least cosine (`surface.guard_bounds`), the largest
  of the angles numpy took (arccos decreases);
- a cross product is numpy's: each component a product minus a product, rounded apart;
- the largest of two, `mx`, is `np.maximum`'s and `np.maximum.at`'s: the second where they
  are equal (-0 against +0), a NaN wherever either is one;
- a sum of corner normals runs in corner order (`np.add.at` over the corners, facet by facet).
Products and sums are never fused (no FMA: setup.py builds without -march).
"""
from libc.math cimport fabs, sqrt

import numpy as np

ctypedef fused index_t:
    int
    long long


cdef inline double mx(double a, double b) noexcept nogil:
    """np.maximum(a, b): b where equal, NaN propagated."""
    return a if (a > b or a != a) else b


cdef inline double dot3(const double *u, const double *v) noexcept nogil:
    """np.einsum('ij,ij->i') of one row: (p0 + p2) + p1, +0 for a sum of zeros."""
    return ((u[0] * v[0] + u[2] * v[2]) + u[1] * v[1]) + 0.0


cdef inline double norm3(double x, double y, double z) noexcept nogil:
    """np.linalg.norm of one row."""
    return sqrt((x * x + y * y) + z * z)


cdef inline double clip1(double c) noexcept nogil:
    """np.clip(c, -1, 1)."""
    if c < -1.0:
        return -1.0
    if c > 1.0:
        return 1.0
    return c


cdef inline double facet_sag(long long kind, double s0, double s1, double s2,
                             double s3) noexcept nogil:
    """The largest departure of a surface from a facet interpolating it, from the sags of its
    edges: edge j, corner j to j + 1, departs by s_j at its middle.

    Over a triangle, a quadratic surface departs from the plane of its corners by
    4 Σ_{i<j} λ_i λ_j s_ij at barycentric coordinates λ; its largest value on the triangle is
    4 s_a s_b s_c / (2 (s_a s_b + s_b s_c + s_c s_a) - s_a² - s_b² - s_c²) when the three sags
    obey the triangle inequality (a sphere: 4/3 of an edge's), else the largest edge's (a
    cylinder: the edge across the axis). Over a quad, the bilinear facet departs by the sum
    of the two directions' sags at its middle (a paraboloid; a cylinder: one direction's).
    The former numpy's expressions, in its order (a = s_01, c = s_12, b = s_20)."""
    cdef double a = s0, c = s1, b = s2
    cdef double edges, d, middle, triangle
    if kind == 4:
        return mx(s0, s2) + mx(s1, s3)
    edges = mx(mx(a, b), c)
    d = ((2 * ((a * b + b * c) + c * a) - a * a) - b * b) - c * c
    middle = 0.0
    if (a + b > c) and (b + c > a) and (c + a > b) and d > 0:
        middle = 4 * a * b * c / d
    triangle = mx(edges, middle)
    return triangle


def corner_tables(const long long[:, ::1] corners, const long long[::1] kind,
                  const double[:, ::1] nodes, const long long[::1] key,
                  const long long[::1] region, const double[:, ::1] facet_normal,
                  double[:, :, ::1] normal, double[:, ::1] length, double[:, ::1] bend):
    """Fill normal (F, 4, 3), length (F, 4) and bend (F, 4), zeroed by the caller
    (`surface.corner_normals`): each node's normal in each smooth region is the area-weighted
    sum of its facets' normals there, in corner order, then made unit."""
    cdef Py_ssize_t F = corners.shape[0], n = nodes.shape[0]
    cdef Py_ssize_t f, j, k, s, t, g, nx, R = 0
    cdef long long c, r
    cdef double ax, ay, az, bx, by, bz, ux, uy, uz, vx, vy, vz, wx, wy, wz, w, nrm
    cdef double d[3]
    cdef double al[3]
    cdef double area_f
    for f in range(F):
        if region[f] + 1 > R:
            R = region[f] + 1
    area_a = np.empty(F)
    start_a = np.zeros(n + 1, np.int64)
    slots_a = np.empty(4 * F, np.int64)
    stamp_a = np.full(max(R, 1), -1, np.int64)
    leader_a = np.empty(max(R, 1), np.int64)
    cdef double[::1] area = area_a
    cdef long long[::1] start = start_a, slots = slots_a, stamp = stamp_a, leader = leader_a
    cdef const double *x0
    cdef const double *x1
    cdef const double *x2
    cdef const double *x3
    with nogil:
        # each facet's area (`_facet_areas`: a quad's as two triangles)
        for f in range(F):
            x0 = &nodes[corners[f, 0] if corners[f, 0] > 0 else 0, 0]
            x1 = &nodes[corners[f, 1] if corners[f, 1] > 0 else 0, 0]
            x2 = &nodes[corners[f, 2] if corners[f, 2] > 0 else 0, 0]
            ux, uy, uz = x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2]
            vx, vy, vz = x2[0] - x0[0], x2[1] - x0[1], x2[2] - x0[2]
            ax = uy * vz - uz * vy
            ay = uz * vx - ux * vz
            az = ux * vy - uy * vx
            if kind[f] == 4:
                x3 = &nodes[corners[f, 3] if corners[f, 3] > 0 else 0, 0]
                wx, wy, wz = x3[0] - x0[0], x3[1] - x0[1], x3[2] - x0[2]
                bx = vy * wz - vz * wy
                by = vz * wx - vx * wz
                bz = vx * wy - vy * wx
            else:
                bx = by = bz = 0.0
            area[f] = 0.5 * norm3(ax + bx, ay + by, az + bz)
        # the real corners at each node (by identity), in corner order: a counting sort
        for f in range(F):
            for j in range(4):
                if corners[f, j] >= 0:
                    start[key[corners[f, j]] + 1] += 1
        for k in range(n):
            start[k + 1] += start[k]
        for f in range(F):
            for j in range(4):
                if corners[f, j] >= 0:
                    k = key[corners[f, j]]
                    slots[start[k]] = 4 * f + j
                    start[k] += 1
        for k in range(n - 1, -1, -1):
            start[k + 1] = start[k]
        start[0] = 0
        # at each node, one sum per smooth region, kept in its first corner (the leader)
        for k in range(n):
            for t in range(start[k], start[k + 1]):
                s = slots[t]
                f = s // 4
                r = region[f]
                if stamp[r] != k:
                    stamp[r] = k
                    leader[r] = s
                g = leader[r]
                w = area[f]
                normal[g // 4, g % 4, 0] += w * facet_normal[f, 0]
                normal[g // 4, g % 4, 1] += w * facet_normal[f, 1]
                normal[g // 4, g % 4, 2] += w * facet_normal[f, 2]
            for t in range(start[k], start[k + 1]):
                s = slots[t]
                g = leader[region[s // 4]]
                if g == s:  # first of its group: made unit before its followers copy it
                    ax = normal[g // 4, g % 4, 0]
                    ay = normal[g // 4, g % 4, 1]
                    az = normal[g // 4, g % 4, 2]
                    nrm = norm3(ax, ay, az)
                    if nrm > 0:
                        normal[g // 4, g % 4, 0] = ax / nrm
                        normal[g // 4, g % 4, 1] = ay / nrm
                        normal[g // 4, g % 4, 2] = az / nrm
                    else:
                        normal[g // 4, g % 4, 0] = 0.0
                        normal[g // 4, g % 4, 1] = 0.0
                        normal[g // 4, g % 4, 2] = 0.0
                else:
                    normal[s // 4, s % 4, 0] = normal[g // 4, g % 4, 0]
                    normal[s // 4, s % 4, 1] = normal[g // 4, g % 4, 1]
                    normal[s // 4, s % 4, 2] = normal[g // 4, g % 4, 2]
        # each edge's length and bend: its ends' normals' difference along it
        for f in range(F):
            for j in range(4):
                if corners[f, j] < 0:
                    length[f, j] = 0.0
                    bend[f, j] = 0.0
                    continue
                nx = j + 1 if j + 1 < kind[f] else 0
                c = corners[f, nx]
                x1 = &nodes[c if c > 0 else 0, 0]
                x0 = &nodes[corners[f, j], 0]
                ux, uy, uz = x1[0] - x0[0], x1[1] - x0[1], x1[2] - x0[2]
                area_f = norm3(ux, uy, uz)
                length[f, j] = area_f
                if area_f > 0:
                    al[0], al[1], al[2] = ux / area_f, uy / area_f, uz / area_f
                else:
                    al[0] = al[1] = al[2] = 0.0
                d[0] = normal[f, nx, 0] - normal[f, j, 0]
                d[1] = normal[f, nx, 1] - normal[f, j, 1]
                d[2] = normal[f, nx, 2] - normal[f, j, 2]
                bend[f, j] = dot3(d, al)


def ring_tables(const index_t[::1] ring_ptr, const index_t[::1] ring,
                const long long[:, ::1] corners, const long long[::1] kind,
                const long long[::1] label, const signed char[:, ::1] edge_class,
                const double[:, ::1] edge_sag, const double[:, ::1] length,
                const double[:, ::1] bend, const double[:, :, ::1] corner_normal,
                const double[:, ::1] facet_normal, const long long[::1] tags,
                bint smooth_tags, double cos_limit, const long long[::1] key,
                int open_edge):
    """The guard's ring maxima (`surface.guard_bounds`), one pass over each facet's ring
    (ring_ptr, ring: CSR, the facet itself included):

    envelope (F,)   the largest facet_sag(|edge sag|) over the ring
    bulge, hollow (F,)  ... of the positive, negative edge sags (zero on open and sharp
                    edges) over the ring's facets of the facet's own patch
    turn (F,)       the largest |bend| / length of an edge over the ring
    cos_min (F,)    the least cosine between the facet's normal and a corner normal of a
                    smooth neighbour (2 where none: no spread)
    at_open (F,)    uint8: a corner of the facet is on an open edge
    """
    cdef Py_ssize_t F = corners.shape[0], n = key.shape[0]
    cdef Py_ssize_t f, j, i, t, nx
    cdef long long c
    cdef index_t g
    cdef double es, a0, a1, a2, a3, b0, b1, b2, b3, h0, h1, h2, h3, cur, cf, cn
    cdef double q[4]
    cdef double e[4]
    env_a, bul_a, hol_a, turn_a = np.empty(F), np.empty(F), np.empty(F), np.empty(F)
    out_a = np.zeros((4, F))
    cos_a = np.full(F, 2.0)
    open_a = np.zeros(F, np.uint8)
    node_a = np.zeros(n, np.uint8)
    cdef double[::1] env = env_a, bul = bul_a, hol = hol_a, turn = turn_a, cmin = cos_a
    cdef double[:, ::1] out = out_a
    cdef unsigned char[::1] at_open = open_a, open_node = node_a
    with nogil:
        # each facet's own sags (`facet_sag`) and largest turn, before the rings
        for f in range(F):
            for j in range(4):
                es = edge_sag[f, j]
                e[j] = fabs(es)
                if edge_class[f, j] >= open_edge:  # a crease's or open edge's bend: none
                    es = 0.0
                q[j] = es
            env[f] = facet_sag(kind[f], e[0], e[1], e[2], e[3])
            a0, a1, a2, a3 = mx(q[0], 0.0), mx(q[1], 0.0), mx(q[2], 0.0), mx(q[3], 0.0)
            bul[f] = facet_sag(kind[f], a0, a1, a2, a3)
            b0, b1, b2, b3 = mx(-q[0], 0.0), mx(-q[1], 0.0), mx(-q[2], 0.0), mx(-q[3], 0.0)
            hol[f] = facet_sag(kind[f], b0, b1, b2, b3)
            for j in range(4):
                e[j] = fabs(bend[f, j]) / length[f, j] if length[f, j] > 0 else 0.0
            turn[f] = mx(mx(e[0], e[1]), mx(e[2], e[3]))
            # the nodes of open edges (numpy's indexing: a corner -1 is the last node)
            for j in range(4):
                if edge_class[f, j] == open_edge:
                    nx = j + 1 if j + 1 < kind[f] else 0
                    c = corners[f, j]
                    open_node[key[c if c >= 0 else c + n]] = 1
                    c = corners[f, nx]
                    open_node[key[c if c >= 0 else c + n]] = 1
        for f in range(F):
            for j in range(4):
                c = corners[f, j]
                if c >= 0 and open_node[key[c]]:
                    at_open[f] = 1
            h0 = h1 = h2 = h3 = 0.0
            cur = 2.0
            for t in range(ring_ptr[f], ring_ptr[f + 1]):
                g = ring[t]
                h0 = mx(h0, env[g])
                if label[g] == label[f]:
                    h1 = mx(h1, bul[g])
                    h2 = mx(h2, hol[g])
                h3 = mx(h3, turn[g])
                cf = clip1(dot3(&facet_normal[f, 0], &facet_normal[g, 0]))
                if cf >= cos_limit or (smooth_tags and tags[g] == tags[f]):
                    for i in range(4):
                        if corners[g, i] >= 0:
                            cn = clip1(dot3(&facet_normal[f, 0], &corner_normal[g, i, 0]))
                            if cn < cur:
                                cur = cn
            out[0, f] = h0
            out[1, f] = h1
            out[2, f] = h2
            out[3, f] = h3
            cmin[f] = cur
    return out_a[0], out_a[1], out_a[2], out_a[3], cos_a, open_a
