# cython: language_level=3
"""The support of one reference point, written once (`cdef inline`): the local node spacing
at it (`local_spacing`, with the target's normal there and the point's foot on it), the k
nearest nodes with their ties (`knn_ties`), and the support and frame of its local
approximation (`select_support`: the nodes of one sheet, their weighted PCA, +e3 out of the
target, the support radius R). The searches are `_search.pxd`'s, the frame's axes
`_frame.pxd`'s."""
from libc.math cimport sqrt
from libc.stdint cimport int64_t

from ._linalg cimport dmax, smallest_eigenvector, smallest_eigenvector_psd
from ._weight cimport WENDLAND, weight_value
from ._search cimport Grid, ball, knn, nearest, cell_index, distance2
from ._frame cimport frame_e1, right_handed
from ._projection cimport TargetC, Options, Result, Scratch


cdef inline double local_spacing(const TargetC *tg, const Options *op, const double *x,
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


cdef inline int64_t knn_ties(const Grid *g, const double *p, int64_t k, Scratch *sc,
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


cdef inline int64_t select_support(const TargetC *tg, const Options *op, const double *ref,
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
        wj = weight_value(WENDLAND, cand_d2[j] * inv_b2, &op.wp)
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
    pp[0] = p0
    pp[1] = p1
    pp[2] = p2
    nsum[0] = n0
    nsum[1] = n1
    nsum[2] = n2
    cov[0] = c00
    cov[1] = c01
    cov[2] = c02
    cov[4] = c11
    cov[5] = c12
    cov[8] = c22
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
