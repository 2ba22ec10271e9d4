# cython: language_level=3
"""Closest point on the facets of a target [1], gap [2] and sign, compiled (node-to-facet, §2).

The facets (linear triangles, bilinear quads) are held in a bounding-volume hierarchy (boxes
split at the median of the facet centroids along their longest extent), searched nearest
child first and pruned by box distance (a leaf also by an oriented bound, a disc along its
facets: `oriented_bounds`), so the closest point is exact over every facet, small or large.
The sign of a gap at an edge or a vertex comes from angle-weighted pseudonormals (Bærentzen &
Aanæs 2005, libigl's 'pseudonormal'): correct for closed and consistently oriented meshes
whichever facet of an edge or vertex is picked.

Coordinates are taken relative to the target's centre. A contactor more than `far` target
radii away ranks candidates by |X|² - 2 P·X (= |P - X|² - |P|², without the |P|² that would
swallow the target's size) and beyond `proxy` radii is replaced by a point in the same
direction at `proxy` radii for the search, so coordinates up to the float range neither
overflow nor tie at random. The tolerances come with the tables (surface.py's constants).
"""
from cython.parallel cimport prange
from libc.math cimport sqrt, fabs, atan2, INFINITY, isfinite, NAN
from libc.stdint cimport int64_t, int32_t, int8_t

from .._codes cimport OPEN, CONTACT, PENETRATION, FAILED, R_OK, R_BAD_POINT

import numpy as np

from ..threads import threads_for

cdef enum:
    # facets per leaf of the hierarchy
    LEAF = 4
    # depth bound of the traversal stack (a median-split tree of 2^60 facets is 60 deep)
    STACK = 96


# -- hierarchy --------------------------------------------------------------------------------

cdef void _select(int64_t* idx, const double* key, int64_t lo, int64_t hi,
                  int64_t k) noexcept nogil:
    """Reorder idx[lo:hi] so that idx[k] holds the element of rank k by key (quickselect)."""
    cdef int64_t i, j, t
    cdef double pivot
    while hi - lo > 1:
        pivot = key[idx[(lo + hi) // 2]]
        i, j = lo, hi - 1
        while i <= j:
            while key[idx[i]] < pivot:
                i += 1
            while key[idx[j]] > pivot:
                j -= 1
            if i <= j:
                t = idx[i]
                idx[i] = idx[j]
                idx[j] = t
                i += 1
                j -= 1
        if k <= j:
            hi = j + 1
        elif k >= i:
            lo = i
        else:
            return


cdef int64_t _build(int64_t node, int64_t lo, int64_t hi, int64_t* idx, const double* fbox,
                    const double* centroid, double* key, double* box,
                    int64_t* link) noexcept nogil:
    """Emit the subtree of idx[lo:hi] at `node` (depth first: left child at node + 1);
    returns the next free node."""
    cdef int64_t i, f, d, axis = 0, mid
    cdef double clo[3]
    cdef double chi[3]
    for d in range(3):
        box[6 * node + d] = INFINITY
        box[6 * node + 3 + d] = -INFINITY
        clo[d] = INFINITY
        chi[d] = -INFINITY
    for i in range(lo, hi):
        f = idx[i]
        for d in range(3):
            if fbox[6 * f + d] < box[6 * node + d]:
                box[6 * node + d] = fbox[6 * f + d]
            if fbox[6 * f + 3 + d] > box[6 * node + 3 + d]:
                box[6 * node + 3 + d] = fbox[6 * f + 3 + d]
            if centroid[3 * f + d] < clo[d]:
                clo[d] = centroid[3 * f + d]
            if centroid[3 * f + d] > chi[d]:
                chi[d] = centroid[3 * f + d]
    if hi - lo <= LEAF:
        link[2 * node] = lo
        link[2 * node + 1] = hi - lo
        return node + 1
    for d in range(1, 3):
        if chi[d] - clo[d] > chi[axis] - clo[axis]:
            axis = d
    for i in range(lo, hi):
        key[idx[i]] = centroid[3 * idx[i] + axis]
    mid = (lo + hi) // 2
    _select(idx, key, lo, hi, mid)
    cdef int64_t right = _build(node + 1, lo, mid, idx, fbox, centroid, key, box, link)
    link[2 * node] = right
    link[2 * node + 1] = 0
    return _build(right, mid, hi, idx, fbox, centroid, key, box, link)


def build_hierarchy(const double[:, ::1] fbox, const double[:, ::1] centroid):
    """Bounding-volume hierarchy of facets with boxes `fbox` (F, 6) and centroids (F, 3).

    Returns (order (F,) the facet in each slot, box (N, 6), link (N, 2)).
    """
    cdef int64_t F = fbox.shape[0]
    order = np.arange(F, dtype=np.int64)
    cdef int64_t nmax = 2 * F + 1  # a binary tree with at most F leaves
    boxes = np.empty((nmax, 6))
    links = np.zeros((nmax, 2), dtype=np.int64)
    key = np.empty(F)
    cdef int64_t[::1] o = order
    cdef double[:, ::1] b = boxes
    cdef int64_t[:, ::1] lk = links
    cdef double[::1] k = key
    cdef int64_t n
    with nogil:
        n = _build(0, 0, F, &o[0], &fbox[0, 0], &centroid[0, 0], &k[0], &b[0, 0], &lk[0, 0])
    return order, boxes[:n].copy(), links[:n].copy()


def oriented_bounds(const double[:, :, ::1] corner, const int8_t[::1] kind,
                    const int64_t[:, ::1] link):
    """(N, 8) an oriented bound of each hierarchy node (`link`'s, slots in `corner`'s order):
    a cylinder (centre xyz, unit axis xyz, radius, half height) holding every corner of its
    facets, hence the facets (a bilinear quad lies in its corners' hull). Its axis is the
    mean normal of the node's facets: along a surface the cylinder is a thin disc, and a
    point off the surface is far from every disc but the one under it, where a box tilted
    to the axes holds a slab of empty space (`_search` rules a leaf out by it once its box
    could not). A leaf's from its corners; an internal node's from its two children's
    cylinders (a cylinder holding both: linear, no pass over the facets per level)."""
    cdef Py_ssize_t N = link.shape[0], n, f, j, k, first, count, ch
    out_a = np.zeros((N, 8))
    area_a = np.zeros((N, 3))
    cdef double[:, ::1] out = out_a
    cdef double[:, ::1] area = area_a
    cdef double m[3]
    cdef double c[3]
    cdef double lo[3]
    cdef double hi[3]
    cdef double d[3]
    cdef double z, zmin, zmax, lat, rho, dot, s, t
    cdef const double* q
    cdef const double* cc
    with nogil:
        for n in range(N - 1, -1, -1):  # children after their parent: bottom-up
            count = link[n, 1]
            if count > 0:
                first = link[n, 0]
                for j in range(3):
                    m[j] = 0.0
                    lo[j] = INFINITY
                    hi[j] = -INFINITY
                for f in range(first, first + count):
                    q = &corner[f, 0, 0]
                    if kind[f] == 3:
                        _cross_add(q, q + 3, q + 6, q, m)
                    else:
                        _cross_add(q, q + 6, q + 9, q + 3, m)
                    for k in range(kind[f]):
                        for j in range(3):
                            if q[3 * k + j] < lo[j]:
                                lo[j] = q[3 * k + j]
                            if q[3 * k + j] > hi[j]:
                                hi[j] = q[3 * k + j]
                for j in range(3):
                    area[n, j] = m[j]
                    c[j] = 0.5 * (lo[j] + hi[j])
                _unit_or_z(m)
                zmin, zmax, rho = INFINITY, -INFINITY, 0.0
                for f in range(first, first + count):
                    for k in range(kind[f]):
                        q = &corner[f, k, 0]
                        z = 0.0
                        for j in range(3):
                            d[j] = q[j] - c[j]
                            z += d[j] * m[j]
                        zmin = z if z < zmin else zmin
                        zmax = z if z > zmax else zmax
                        lat = 0.0
                        for j in range(3):
                            lat += (d[j] - z * m[j]) * (d[j] - z * m[j])
                        rho = lat if lat > rho else rho
                rho = sqrt(rho)
            else:
                for j in range(3):
                    m[j] = area[n + 1, j] + area[link[n, 0], j]
                    area[n, j] = m[j]
                    c[j] = 0.5 * (out[n + 1, j] + out[link[n, 0], j])
                _unit_or_z(m)
                zmin, zmax, rho = INFINITY, -INFINITY, 0.0
                for k in range(2):
                    ch = n + 1 if k == 0 else link[n, 0]
                    cc = &out[ch, 0]
                    dot = m[0] * cc[3] + m[1] * cc[4] + m[2] * cc[5]
                    s = 1.0 - dot * dot
                    s = sqrt(s) if s > 0 else 0.0
                    t = cc[7] * fabs(dot) + cc[6] * s  # the child's reach along m
                    z = 0.0
                    for j in range(3):
                        d[j] = cc[j] - c[j]
                        z += d[j] * m[j]
                    zmin = z - t if z - t < zmin else zmin
                    zmax = z + t if z + t > zmax else zmax
                    lat = 0.0
                    for j in range(3):
                        lat += (d[j] - z * m[j]) * (d[j] - z * m[j])
                    lat = sqrt(lat) + cc[6] + cc[7] * s  # its reach across m
                    rho = lat if lat > rho else rho
            # the centre moved along the axis to the middle of the height (the radius, a
            # distance from the axis, does not change); a margin for round-off
            z = 0.5 * (zmin + zmax)
            for j in range(3):
                out[n, j] = c[j] + z * m[j]
                out[n, 3 + j] = m[j]
            t = 1e-12 * (rho + fabs(zmax - zmin) + fabs(c[0]) + fabs(c[1]) + fabs(c[2]))
            out[n, 6] = rho + t
            out[n, 7] = 0.5 * (zmax - zmin) + t
    return out_a


cdef inline void _cross_add(const double* a, const double* b, const double* c,
                            const double* d, double* m) noexcept nogil:
    """m += (b - a) x (c - d): a triangle's (d = a) or a quad's (diagonals) area vector,
    doubled."""
    cdef double u0 = b[0] - a[0], u1 = b[1] - a[1], u2 = b[2] - a[2]
    cdef double v0 = c[0] - d[0], v1 = c[1] - d[1], v2 = c[2] - d[2]
    m[0] += u1 * v2 - u2 * v1
    m[1] += u2 * v0 - u0 * v2
    m[2] += u0 * v1 - u1 * v0


cdef inline void _unit_or_z(double* m) noexcept nogil:
    """m scaled to unit length; +z where it vanishes (facets facing every way: any axis
    bounds them, loosely)."""
    cdef double norm = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    if norm > 0 and isfinite(norm):
        m[0] /= norm
        m[1] /= norm
        m[2] /= norm
    else:
        m[0] = 0.0
        m[1] = 0.0
        m[2] = 1.0


def corner_normals(const double[:, :, ::1] corner, const int64_t[::1] kind,
                   const int64_t[:, ::1] fnode, double[:, ::1] vnormal,
                   double[:, ::1] fnormal):
    """Accumulate into vnormal[node] the angle-weighted unit normal of every facet corner
    at it (a vertex's pseudonormal, unnormalised) and set each triangle's unit normal in
    fnormal (zero for quads and for degenerate triangles)."""
    cdef int64_t F = kind.shape[0], f, k, j, nj, pj, node
    cdef double e1[3]
    cdef double e2[3]
    cdef double c[3]
    cdef double norm, angle
    cdef int d
    if corner.shape[0] != F or fnode.shape[0] != F or fnormal.shape[0] != F \
            or vnormal.shape[1] != 3 or fnormal.shape[1] != 3:
        raise ValueError("facet tables of different lengths")
    with nogil:
        for f in range(F):
            k = kind[f]
            for d in range(3):
                fnormal[f, d] = 0.0
            for j in range(k):
                nj = j + 1 if j + 1 < k else 0
                pj = j - 1 if j > 0 else k - 1
                for d in range(3):
                    e1[d] = corner[f, nj, d] - corner[f, j, d]
                    e2[d] = corner[f, pj, d] - corner[f, j, d]
                c[0] = e1[1] * e2[2] - e1[2] * e2[1]
                c[1] = e1[2] * e2[0] - e1[0] * e2[2]
                c[2] = e1[0] * e2[1] - e1[1] * e2[0]
                norm = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
                if not (norm > 0 and isfinite(norm)):
                    continue
                angle = atan2(norm, e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2])
                node = fnode[f, j]
                for d in range(3):
                    vnormal[node, d] += angle * c[d] / norm
                    if k == 3 and j == 0:
                        fnormal[f, d] = c[d] / norm


# -- closest point on one facet ---------------------------------------------------------------

cdef inline double _dot(double ax, double ay, double az, double bx, double by, double bz) \
        noexcept nogil:
    return ax * bx + ay * by + az * bz


cdef inline double _ratio(double num, double den) noexcept nogil:
    """num / den clamped to [0, 1]; 0 for a zero-length feature."""
    if not den > 0:
        return 0.0
    num = num / den
    return 0.0 if num < 0 else (1.0 if num > 1 else num)


cdef void _triangle(const double* c, double px, double py, double pz, double* ab) noexcept nogil:
    """ξ = (a, b) of the closest point of the triangle c (3 corners) to p: exact, by the
    Voronoi regions of its vertices, edges and face, tested in that order."""
    cdef double e1x = c[3] - c[0], e1y = c[4] - c[1], e1z = c[5] - c[2]
    cdef double e2x = c[6] - c[0], e2y = c[7] - c[1], e2z = c[8] - c[2]
    cdef double qx = px - c[0], qy = py - c[1], qz = pz - c[2]
    # projections of p - corner on the two edges from corner 0, at corners 0, 1, 2
    cdef double d1 = _dot(e1x, e1y, e1z, qx, qy, qz), d2 = _dot(e2x, e2y, e2z, qx, qy, qz)
    cdef double d3, d4, d5, d6, va, vb, vc, den, t
    if d1 <= 0 and d2 <= 0:
        ab[0] = 0.0
        ab[1] = 0.0
        return
    qx, qy, qz = px - c[3], py - c[4], pz - c[5]
    d3 = _dot(e1x, e1y, e1z, qx, qy, qz)
    d4 = _dot(e2x, e2y, e2z, qx, qy, qz)
    if d3 >= 0 and d4 <= d3:
        ab[0] = 1.0
        ab[1] = 0.0
        return
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        ab[0] = _ratio(d1, d1 - d3)
        ab[1] = 0.0
        return
    qx, qy, qz = px - c[6], py - c[7], pz - c[8]
    d5 = _dot(e1x, e1y, e1z, qx, qy, qz)
    d6 = _dot(e2x, e2y, e2z, qx, qy, qz)
    if d6 >= 0 and d5 <= d6:
        ab[0] = 0.0
        ab[1] = 1.0
        return
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        ab[0] = 0.0
        ab[1] = _ratio(d2, d2 - d6)
        return
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        t = _ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        ab[0] = 1.0 - t
        ab[1] = t
        return
    den = va + vb + vc
    if den > 0 and isfinite(den):
        ab[0] = vb / den
        ab[1] = vc / den
        return
    _triangle_edges(c, px, py, pz, ab)  # a degenerate (flat or overflowing) triangle


cdef void _triangle_edges(const double* c, double px, double py, double pz,
                          double* ab) noexcept nogil:
    """The closest point over the three edges (clamped segment projections)."""
    cdef int k
    cdef double best = INFINITY, t, dx, dy, dz, d2
    cdef const double* s
    cdef const double* e
    ab[0] = 0.0
    ab[1] = 0.0
    for k in range(3):
        s = c + 3 * k
        e = c + 3 * ((k + 1) % 3)
        t = _ratio(_dot(px - s[0], py - s[1], pz - s[2], e[0] - s[0], e[1] - s[1], e[2] - s[2]),
                   _dot(e[0] - s[0], e[1] - s[1], e[2] - s[2], e[0] - s[0], e[1] - s[1],
                        e[2] - s[2]))
        dx = s[0] + t * (e[0] - s[0]) - px
        dy = s[1] + t * (e[1] - s[1]) - py
        dz = s[2] + t * (e[2] - s[2]) - pz
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best:
            best = d2
            if k == 0:
                ab[0] = t
                ab[1] = 0.0
            elif k == 1:
                ab[0] = 1.0 - t
                ab[1] = t
            else:
                ab[0] = 0.0
                ab[1] = 1.0 - t


cdef inline void _quad_point(const double* c, double a, double b, double* x) noexcept nogil:
    cdef int d
    for d in range(3):
        x[d] = ((1 - a) * (1 - b)) * c[d] + (a * (1 - b)) * c[3 + d] + (a * b) * c[6 + d] \
            + ((1 - a) * b) * c[9 + d]


cdef inline void _quad_tangents(const double* c, double a, double b, double* ta,
                                double* tb) noexcept nogil:
    cdef int d
    for d in range(3):
        ta[d] = (1 - b) * (c[3 + d] - c[d]) + b * (c[6 + d] - c[9 + d])
        tb[d] = (1 - a) * (c[9 + d] - c[d]) + a * (c[6 + d] - c[3 + d])


cdef int64_t _quad(const double* c, double px, double py, double pz, int64_t iterations,
                   double stop, double* ab) noexcept nogil:
    """ξ of the closest point of the bilinear quad c (4 corners) to p by projected Newton on
    [0, 1]² from its centre, coordinates on a bound whose gradient pushes outward held (the
    reference's iteration, stopped once the step is below `stop`); returns iterations."""
    cdef double a = 0.5, b = 0.5, g0, g1, h11, h22, h12, det, s0, s1, na, nb
    cdef double x[3]
    cdef double ta[3]
    cdef double tb[3]
    cdef double tab[3]
    cdef double r[3]
    cdef int d
    cdef int64_t it = 0
    cdef bint hold0, hold1
    for d in range(3):
        tab[d] = c[d] - c[3 + d] + c[6 + d] - c[9 + d]
    for it in range(1, iterations + 1):  # no-cython-lint (returned after the loop)
        _quad_point(c, a, b, x)
        _quad_tangents(c, a, b, ta, tb)
        r[0] = x[0] - px
        r[1] = x[1] - py
        r[2] = x[2] - pz
        g0 = _dot(r[0], r[1], r[2], ta[0], ta[1], ta[2])
        g1 = _dot(r[0], r[1], r[2], tb[0], tb[1], tb[2])
        h11 = _dot(ta[0], ta[1], ta[2], ta[0], ta[1], ta[2])
        h22 = _dot(tb[0], tb[1], tb[2], tb[0], tb[1], tb[2])
        h12 = (_dot(ta[0], ta[1], ta[2], tb[0], tb[1], tb[2])
               + _dot(r[0], r[1], r[2], tab[0], tab[1], tab[2]))
        hold0 = (a <= 0 and g0 > 0) or (a >= 1 and g0 < 0)
        hold1 = (b <= 0 and g1 > 0) or (b >= 1 and g1 < 0)
        if hold0 or hold1:
            h12 = 0.0
        if hold0:
            h11 = 1.0
            g0 = 0.0
        if hold1:
            h22 = 1.0
            g1 = 0.0
        det = h11 * h22 - h12 * h12
        if not det > 0:
            det = 1.0
        s0 = -(h22 * g0 - h12 * g1) / det
        s1 = -(h11 * g1 - h12 * g0) / det
        if not (isfinite(s0) and isfinite(s1)):
            break
        na = a + s0
        nb = b + s1
        na = 0.0 if na < 0 else (1.0 if na > 1 else na)
        nb = 0.0 if nb < 0 else (1.0 if nb > 1 else nb)
        s0 = fabs(na - a)
        s1 = fabs(nb - b)
        a, b = na, nb
        if s0 <= stop and s1 <= stop:
            break
    ab[0] = a
    ab[1] = b
    return it


cdef inline void _facet_point(const double* c, int64_t kind, double a, double b,
                              double* x) noexcept nogil:
    cdef int d
    if kind == 3:
        for d in range(3):
            x[d] = c[d] + a * (c[3 + d] - c[d]) + b * (c[6 + d] - c[d])
    else:
        _quad_point(c, a, b, x)


# -- search -----------------------------------------------------------------------------------

cdef inline double _rank(double px, double py, double pz, double x, double y, double z,
                         bint far) noexcept nogil:
    """What candidates are ranked by: |p - x|², or with `far` |x|² - 2 p·x (its value less
    |p|², computed without it)."""
    if far:
        return x * (x - 2 * px) + y * (y - 2 * py) + z * (z - 2 * pz)
    return (px - x) * (px - x) + (py - y) * (py - y) + (pz - z) * (pz - z)


cdef inline double _clamp(double v, double lo, double hi) noexcept nogil:
    return lo if v < lo else (hi if v > hi else v)


cdef inline double _box_rank(const double* b, double px, double py, double pz,
                             bint far) noexcept nogil:
    """The least rank of any point of box b: the rank of p's closest point in it."""
    return _rank(px, py, pz, _clamp(px, b[0], b[3]), _clamp(py, b[1], b[4]),
                 _clamp(pz, b[2], b[5]), far)


cdef inline double _cyl_rank(const double* c, double px, double py, double pz,
                             double rank) noexcept nogil:
    """The larger of `rank` (a box's) and the squared distance from p to cylinder c (centre,
    unit axis, radius, half height): a lower bound of the rank of any facet it holds."""
    cdef double dx = px - c[0], dy = py - c[1], dz = pz - c[2]
    cdef double z = dx * c[3] + dy * c[4] + dz * c[5]
    cdef double lat = dx * dx + dy * dy + dz * dz - z * z
    cdef double a = 0.0, b = fabs(z) - c[7]
    if lat > c[6] * c[6]:  # beyond the radius (the square root only then)
        a = sqrt(lat) - c[6]
    b = b if b > 0 else 0.0
    a = a * a + b * b
    return a if a > rank else rank


cdef inline double _candidate(const Tables* T, int64_t f, double px, double py, double pz,
                              bint far, Hit* h) noexcept nogil:
    """Closest point of facet slot f to p into h; returns its rank."""
    cdef const double* c = T.corner + 12 * f
    cdef double ab[2]
    cdef double x[3]
    cdef int64_t it = 0
    if T.kind[f] == 3:
        _triangle(c, px, py, pz, ab)
    else:
        it = _quad(c, px, py, pz, T.quad_iterations, T.quad_step, ab)
    _facet_point(c, T.kind[f], ab[0], ab[1], x)
    h.slot = f
    h.a = ab[0]
    h.b = ab[1]
    h.x = x[0]
    h.y = x[1]
    h.z = x[2]
    h.iterations = it
    return _rank(px, py, pz, x[0], x[1], x[2], far)


cdef void _search(const Tables* T, double px, double py, double pz, bint far,
                  Hit* best) noexcept nogil:
    """The closest facet over the whole hierarchy: nearest child first, pruned by box rank,
    and a leaf also by its oriented bound (`oriented_bounds`) before its facets are tried.
    Tried on internal nodes too, that bound cost more instructions than it saved (+23% at
    2.5k nodes, -1% at 41k); on leaves alone -4% and -22% (callgrind, points within ±5% of
    unit icospheres), the answers bitwise the same."""
    cdef int64_t stack[STACK]
    cdef double bound[STACK]
    cdef int64_t sp = 1, node, left, right, f, first, count
    cdef double best_rank = INFINITY, r, rl, rr
    cdef Hit h
    best.slot = -1
    stack[0] = 0
    bound[0] = _box_rank(T.box, px, py, pz, far)
    while sp > 0:
        sp -= 1
        node = stack[sp]
        if not bound[sp] < best_rank:
            continue
        while True:
            count = T.link[2 * node + 1]
            if count > 0:
                # a leaf its box cannot rule out: its oriented bound may (a disc along the
                # surface, where a box tilted to the axes holds a slab of empty space: a point
                # off a fine target reaches tens of such boxes, one or two such discs)
                if T.cyl != NULL and not far \
                        and not _cyl_rank(T.cyl + 8 * node, px, py, pz, 0.0) < best_rank:
                    break
                first = T.link[2 * node]
                for f in range(first, first + count):
                    if T.kind[f] == 4 and not _box_of_quad_below(T.corner + 12 * f, px, py, pz,
                                                                 far, best_rank):
                        continue
                    r = _candidate(T, f, px, py, pz, far, &h)
                    if r < best_rank or best.slot < 0 \
                            or r == best_rank and _flat(T, best.slot) and not _flat(T, f):
                        best_rank = r
                        best[0] = h
                break
            left = node + 1
            right = T.link[2 * node]
            rl = _box_rank(T.box + 6 * left, px, py, pz, far)
            rr = _box_rank(T.box + 6 * right, px, py, pz, far)
            if rr < rl:
                left, right = right, left
                rl, rr = rr, rl
            if rr < best_rank and sp < STACK:
                stack[sp] = right
                bound[sp] = rr
                sp += 1
            if not rl < best_rank:
                break
            node = left


cdef inline bint _flat(const Tables* T, int64_t f) noexcept nogil:
    """A zero-area triangle: on a tie, another facet (with a normal) is preferred."""
    return T.kind[f] == 3 and T.fnormal[3 * f] == 0 and T.fnormal[3 * f + 1] == 0 \
        and T.fnormal[3 * f + 2] == 0


cdef inline bint _box_of_quad_below(const double* c, double px, double py, double pz, bint far,
                                    double best_rank) noexcept nogil:
    """Whether the box of quad c could hold a point ranked below best_rank (a bilinear quad
    lies in the convex hull of its corners)."""
    cdef double b[6]
    cdef int d, k
    for d in range(3):
        b[d] = c[d]
        b[3 + d] = c[d]
        for k in range(1, 4):
            if c[3 * k + d] < b[d]:
                b[d] = c[3 * k + d]
            if c[3 * k + d] > b[3 + d]:
                b[3 + d] = c[3 * k + d]
    return _box_rank(b, px, py, pz, far) < best_rank


# -- sign and gap -----------------------------------------------------------------------------

cdef inline void _facet_normal(const Tables* T, int64_t f, double a, double b,
                               double* n) noexcept nogil:
    """Unit normal of facet slot f at ξ = (a, b), in the facets' own orientation (zero if
    the facet is degenerate there)."""
    cdef double ta[3]
    cdef double tb[3]
    cdef double norm
    if T.kind[f] == 3:
        n[0] = T.fnormal[3 * f]
        n[1] = T.fnormal[3 * f + 1]
        n[2] = T.fnormal[3 * f + 2]
        return
    _quad_tangents(T.corner + 12 * f, a, b, ta, tb)
    n[0] = ta[1] * tb[2] - ta[2] * tb[1]
    n[1] = ta[2] * tb[0] - ta[0] * tb[2]
    n[2] = ta[0] * tb[1] - ta[1] * tb[0]
    norm = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    if norm > 0 and isfinite(norm):
        n[0] /= norm
        n[1] /= norm
        n[2] /= norm
    else:
        n[0] = 0.0
        n[1] = 0.0
        n[2] = 0.0


cdef inline void _edge_xi(int64_t kind, int64_t j, double t, double* ab) noexcept nogil:
    """ξ of the point at fraction t along local edge j (from corner j to corner j + 1)."""
    if kind == 3:
        if j == 0:
            ab[0] = t
            ab[1] = 0.0
        elif j == 1:
            ab[0] = 1.0 - t
            ab[1] = t
        else:
            ab[0] = 0.0
            ab[1] = 1.0 - t
    else:
        if j == 0:
            ab[0] = t
            ab[1] = 0.0
        elif j == 1:
            ab[0] = 1.0
            ab[1] = t
        elif j == 2:
            ab[0] = 1.0 - t
            ab[1] = 1.0
        else:
            ab[0] = 0.0
            ab[1] = 1.0 - t


cdef int64_t _feature(int64_t kind, double a, double b, double eps, double* t) noexcept nogil:
    """Where ξ = (a, b) lies: -1 interior, 0..3 on local edge k at fraction *t (from corner k
    to corner k + 1), 4 + k at corner k."""
    cdef bint a0 = a <= eps, b0 = b <= eps
    if kind == 3:
        if a0 and b0:
            return 4
        if a >= 1 - eps:
            return 5
        if b >= 1 - eps:
            return 6
        if b0:
            t[0] = a
            return 0
        if a0:
            t[0] = 1.0 - b
            return 2
        if a + b >= 1 - eps:
            t[0] = b
            return 1
        return -1
    cdef bint a1 = a >= 1 - eps, b1 = b >= 1 - eps
    if (a0 or a1) and (b0 or b1):
        return 4 + (2 if b1 else 0) + (1 if (a1 != b1) else 0)
    if b0:
        t[0] = a
        return 0
    if a1:
        t[0] = b
        return 1
    if b1:
        t[0] = 1.0 - a
        return 2
    if a0:
        t[0] = 1.0 - b
        return 3
    return -1


cdef void _pseudonormal(const Tables* T, const Hit* h, double* n) noexcept nogil:
    """Pseudonormal at the proximal point, in the facets' own orientation: the facet normal
    inside a facet; on an edge the sum of the unit normals there of the facets sharing it;
    at a vertex the angle-weighted sum of its facets' normals."""
    cdef int64_t kind = T.kind[h.slot], where, e, i, inc, g, j, start
    cdef double t = 0.0, tj
    cdef double ab[2]
    cdef double m[3]
    where = _feature(kind, h.a, h.b, T.edge_eps, &t)
    if where < 0:
        _facet_normal(T, h.slot, h.a, h.b, n)
        return
    if where >= 4:
        i = T.fnode[4 * h.slot + where - 4]
        n[0] = T.vnormal[3 * i]
        n[1] = T.vnormal[3 * i + 1]
        n[2] = T.vnormal[3 * i + 2]
        return
    start = T.fnode[4 * h.slot + where]
    e = T.fedge[4 * h.slot + where]
    n[0] = 0.0
    n[1] = 0.0
    n[2] = 0.0
    for i in range(T.edge_ptr[e], T.edge_ptr[e + 1]):
        inc = T.edge_inc[i]
        g = inc // 4
        j = inc % 4
        tj = t if T.fnode[4 * g + j] == start else 1.0 - t
        _edge_xi(T.kind[g], j, tj, ab)
        _facet_normal(T, g, ab[0], ab[1], m)
        n[0] += m[0]
        n[1] += m[1]
        n[2] += m[2]


cdef inline double _norm(double x, double y, double z) noexcept nogil:
    """|(x, y, z)| without overflow or underflow of the squares."""
    cdef double s = fabs(x)
    if fabs(y) > s:
        s = fabs(y)
    if fabs(z) > s:
        s = fabs(z)
    if not s > 0 or not isfinite(s):
        return s
    x /= s
    y /= s
    z /= s
    return s * sqrt(x * x + y * y + z * z)


cdef void _answer(const Tables* T, double Px, double Py, double Pz, const Hit* h, int64_t row,
                  const Out* o) noexcept nogil:
    """Gap [2], normal, status [33] of contactor P (relative to the centre) at hit h."""
    cdef double dx = Px - h.x, dy = Py - h.y, dz = Pz - h.z
    cdef double dist = _norm(dx, dy, dz), s, g
    cdef double n[3]
    cdef double nf[3]
    cdef int64_t where
    cdef double t
    _facet_normal(T, h.slot, h.a, h.b, nf)
    where = _feature(T.kind[h.slot], h.a, h.b, T.edge_eps, &t)
    if where < 0 and (nf[0] != 0 or nf[1] != 0 or nf[2] != 0):
        # inside a facet: ν is the facet normal
        n[0] = T.sign * nf[0]
        n[1] = T.sign * nf[1]
        n[2] = T.sign * nf[2]
        g = dx * n[0] + dy * n[1] + dz * n[2]
    elif dist <= _contact_tolerance(T, h):
        # on the target at an edge or a vertex (or on a degenerate facet): the direction to
        # the contactor is round-off there, ν is the pseudonormal
        _pseudonormal(T, h, n)
        s = _norm(n[0], n[1], n[2])
        if not (s > 0 and isfinite(s)):
            n[0], n[1], n[2], s = nf[0], nf[1], nf[2], 1.0
        n[0] = T.sign * n[0] / s
        n[1] = T.sign * n[1] / s
        n[2] = T.sign * n[2] / s
        g = dx * n[0] + dy * n[1] + dz * n[2]
    else:
        # on an edge or a vertex: ν is the direction to the contactor, signed by the
        # pseudonormal there (by the facet's own side where that is edge-on)
        _pseudonormal(T, h, n)
        s = dx * n[0] + dy * n[1] + dz * n[2]
        if s == 0 or not isfinite(s):
            s = dx * nf[0] + dy * nf[1] + dz * nf[2]
        s = T.sign * (-1.0 if s < 0 else 1.0)
        n[0] = s * dx / dist
        n[1] = s * dy / dist
        n[2] = s * dz / dist
        g = s * dist
    o.gap[row] = g
    o.normal[3 * row] = n[0]
    o.normal[3 * row + 1] = n[1]
    o.normal[3 * row + 2] = n[2]
    o.prox[3 * row] = h.x + T.cx
    o.prox[3 * row + 1] = h.y + T.cy
    o.prox[3 * row + 2] = h.z + T.cz
    o.facet[row] = T.original[h.slot]
    o.param[2 * row] = h.a
    o.param[2 * row + 1] = h.b
    o.support[row] = T.kind[h.slot]
    o.iterations[row] = h.iterations
    o.reason[row] = R_OK
    if not (isfinite(g) and isfinite(n[0]) and isfinite(n[1]) and isfinite(n[2])):
        o.status[row] = FAILED  # a facet degenerate at the proximal point, with p on it
        o.reason[row] = R_BAD_POINT
    elif fabs(g) <= _contact_tolerance(T, h):
        o.status[row] = CONTACT
    elif g > 0:
        o.status[row] = OPEN
    else:
        o.status[row] = PENETRATION


cdef double _contact_tolerance(const Tables* T, const Hit* h) noexcept nogil:
    """Mean contact tolerance of the nodes of the feature holding the proximal point (the
    facet's corners, the edge's ends, or the vertex): the same whichever facet of an edge or
    a vertex the search picked."""
    cdef int64_t kind = T.kind[h.slot], where, j
    cdef double t, total = 0.0
    where = _feature(kind, h.a, h.b, T.edge_eps, &t)
    if where >= 4:
        return T.ctol[T.fnode[4 * h.slot + where - 4]]
    if where >= 0:
        return 0.5 * (T.ctol[T.fnode[4 * h.slot + where]]
                      + T.ctol[T.fnode[4 * h.slot + (where + 1) % kind]])
    for j in range(kind):
        total += T.ctol[T.fnode[4 * h.slot + j]]
    return total / kind


cdef void _fail(int64_t row, const Out* o) noexcept nogil:
    cdef int d
    o.gap[row] = NAN
    for d in range(3):
        o.normal[3 * row + d] = NAN
        o.prox[3 * row + d] = NAN
    o.param[2 * row] = NAN
    o.param[2 * row + 1] = NAN
    o.status[row] = FAILED
    o.reason[row] = R_BAD_POINT
    o.facet[row] = -1
    o.support[row] = 0
    o.iterations[row] = 0


cdef bint _query(const Tables* T, const double* p, double* P, double* q,
                 bint* far) noexcept nogil:
    """The contactor relative to the centre (P) and the stand-in the search uses (q, with
    `far` ranking); False if p is not a usable point."""
    cdef double L, scale
    P[0] = p[0] - T.cx
    P[1] = p[1] - T.cy
    P[2] = p[2] - T.cz
    if not (isfinite(P[0]) and isfinite(P[1]) and isfinite(P[2])):
        return False
    L = _norm(P[0], P[1], P[2])
    far[0] = L > T.far * T.radius
    q[0] = P[0]
    q[1] = P[1]
    q[2] = P[2]
    if L > T.proxy * T.radius:
        scale = T.proxy * T.radius / L
        q[0] = P[0] * scale
        q[1] = P[1] * scale
        q[2] = P[2] * scale
    return True


cdef void _row(const Tables* T, const double* p, int64_t given, int64_t i,
               const Out* o) noexcept nogil:
    """Contactor i: search (given < -1) or the given facet (-1: none)."""
    cdef double P[3]
    cdef double q[3]
    cdef bint far
    cdef Hit h
    if not _query(T, p, P, q, &far) or given == -1:
        _fail(i, o)
        return
    if given >= 0:
        _candidate(T, T.slot[given], q[0], q[1], q[2], far, &h)
    else:
        _search(T, q[0], q[1], q[2], far, &h)
        if h.slot < 0:  # no facet ranked (not reached with finite coordinates)
            _fail(i, o)
            return
    _answer(T, P[0], P[1], P[2], &h, i, o)


#: The index tables of `surface._tables`' dict, stored int32 (`index_tables`); "kind" int8.
INDEX_TABLES = ("fnode", "fedge", "edge_ptr", "edge_inc", "link", "original", "slot")


def index_tables(dict tables):
    """The facet tables' indices as the search reads them, in place: int32 (node, edge, slot
    and facet numbers, and the edges' incidences 4 x slot + j) and the corner counts int8,
    half and an eighth of int64's memory (issue 36: some 130 bytes a node). ValueError for
    a target whose indices do not fit (2^29 facets); the values are unchanged. Returns
    `tables`."""
    for name in INDEX_TABLES:
        a = np.asarray(tables[name])
        if a.dtype != np.int32:
            if a.size and not (-2 ** 31 <= a.min() and a.max() < 2 ** 31):
                raise ValueError("the facet tables exceed int32 indices: too many facets")
            tables[name] = np.ascontiguousarray(a, dtype=np.int32)
    if np.asarray(tables["kind"]).dtype != np.int8:
        tables["kind"] = np.ascontiguousarray(tables["kind"], dtype=np.int8)
    if 4 * len(tables["kind"]) >= 2 ** 31:
        raise ValueError("the facet tables exceed int32 indices: too many facets")
    return tables


cdef class FacetTables:
    """The facet tables (`surface._tables`'s dict) as the compiled search reads them, built
    once: `project` and other compiled passes (the patched projection) search them."""

    def __init__(self, dict tables):
        index_tables(tables)  # int32 and int8, in place (no-op where they are already)
        cdef const double[:, :, ::1] corner = tables["corner"]
        cdef const int8_t[::1] kind = tables["kind"]
        cdef const double[:, ::1] fnormal = tables["fnormal"]
        cdef const int32_t[:, ::1] fnode = tables["fnode"]
        cdef const int32_t[:, ::1] fedge = tables["fedge"]
        cdef const int32_t[::1] edge_ptr = tables["edge_ptr"]
        cdef const int32_t[::1] edge_inc = tables["edge_inc"]
        cdef const double[:, ::1] vnormal = tables["vnormal"]
        cdef const double[:, ::1] box = tables["box"]
        cdef const int32_t[:, ::1] link = tables["link"]
        cdef const double[::1] ctol = tables["ctol"]
        cdef const int32_t[::1] original = tables["original"]
        cdef const int32_t[::1] slot = tables["slot"]
        cdef const double[::1] centre = tables["centre"]
        cdef int64_t F = kind.shape[0]
        if corner.shape[0] != F or corner.shape[1] != 4 or corner.shape[2] != 3 or F == 0 \
                or box.shape[0] == 0 or slot.shape[0] != F or centre.shape[0] != 3:
            raise ValueError("the facet tables are inconsistent")
        self.arrays = tables
        self.t.corner = &corner[0, 0, 0]
        self.t.kind = &kind[0]
        self.t.fnormal = &fnormal[0, 0]
        self.t.fnode = &fnode[0, 0]
        self.t.fedge = &fedge[0, 0]
        self.t.edge_ptr = &edge_ptr[0]
        self.t.edge_inc = &edge_inc[0]
        self.t.vnormal = &vnormal[0, 0]
        self.t.box = &box[0, 0]
        self.t.link = &link[0, 0]
        self.t.ctol = &ctol[0]
        self.t.original = &original[0]
        self.t.slot = &slot[0]
        self.t.cx, self.t.cy, self.t.cz = centre[0], centre[1], centre[2]
        self.t.radius = tables["radius"]
        self.t.sign = tables["sign"]
        self.t.quad_iterations = tables["quad_iterations"]
        self.t.quad_step = tables["quad_step"]
        self.t.edge_eps = tables["edge_eps"]
        self.t.far = tables["far"]
        self.t.proxy = tables["proxy"]
        self.t.cyl = NULL
        cdef const double[:, ::1] cyl
        if tables.get("cyl") is not None:
            cyl = tables["cyl"]
            if cyl.shape[0] != box.shape[0] or cyl.shape[1] != 8:
                raise ValueError("the facet tables are inconsistent")
            self.t.cyl = &cyl[0, 0]


def project(FacetTables tables, const double[:, ::1] points, double[::1] gap,
            double[:, ::1] normal, double[:, ::1] prox, signed char[::1] status,
            signed char[::1] reason, int64_t[::1] facet, double[:, ::1] param,
            int64_t[::1] support, int64_t[::1] iterations, const int64_t[::1] rows,
            const int64_t[::1] given=None, int threads=0):
    """Project contactors points[rows] onto the facets (with `given`: contactor i onto facet
    given[i], -1 none), in the order of `rows` (nearby contactors together share the cache).

    tables : the target's `FacetTables`.
    Outputs (one row per point) are filled at `rows`; rows of unusable points are 'failed'
    'bad-point' with NaNs. `threads`: OpenMP threads of the loop (0: `threads.threads_for`'s;
    1: a plain loop, no parallel region).
    """
    cdef Out o
    cdef int64_t m = points.shape[0], i, k, F = len(tables.arrays["kind"]), nrows = rows.shape[0]
    cdef bint frozen = given is not None
    if gap.shape[0] != m or normal.shape[0] != m or prox.shape[0] != m \
            or status.shape[0] != m or reason.shape[0] != m or facet.shape[0] != m \
            or param.shape[0] != m or support.shape[0] != m or iterations.shape[0] != m \
            or (frozen and given.shape[0] != m) or normal.shape[1] != 3 or prox.shape[1] != 3 \
            or param.shape[1] != 2 or points.shape[1] != 3:
        raise ValueError("the output arrays do not match the contactors")
    for k in range(nrows):
        if rows[k] < 0 or rows[k] >= m:
            raise ValueError(f"row {rows[k]} is not a contactor")
        if frozen and (given[rows[k]] < -1 or given[rows[k]] >= F):
            raise ValueError(f"facet {given[rows[k]]} is not a facet of the target")
    if nrows == 0:
        return
    o.gap = &gap[0]
    o.normal = &normal[0, 0]
    o.prox = &prox[0, 0]
    o.status = &status[0]
    o.reason = &reason[0]
    o.facet = &facet[0]
    o.param = &param[0, 0]
    o.support = &support[0]
    o.iterations = &iterations[0]
    cdef const Tables* T = &tables.t
    cdef const int64_t* giv = &given[0] if frozen else NULL
    cdef const double* p = &points[0, 0]
    cdef const int64_t* order = &rows[0]
    if threads <= 0:
        threads = threads_for(nrows, "facets")
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            for k in range(nrows):
                i = order[k]
                _row(T, p + 3 * i, giv[i] if frozen else -2, i, &o)
    else:
        for k in prange(nrows, nogil=True, schedule="guided", num_threads=threads):
            i = order[k]
            _row(T, p + 3 * i, giv[i] if frozen else -2, i, &o)


# -- what other compiled passes call (`_engine.pxd`) -------------------------------------------

cdef bint facet_query(const Tables* T, const double* p, double* P, double* q,
                      bint* far) noexcept nogil:
    """p relative to the centre (P) and the stand-in the search uses (q, `far` ranking);
    False if p is not a usable point."""
    return _query(T, p, P, q, far)


cdef void facet_search(const Tables* T, double px, double py, double pz, bint far,
                       Hit* best) noexcept nogil:
    """The closest facet of the whole hierarchy to q = (px, py, pz) (`facet_query`'s)."""
    _search(T, px, py, pz, far, best)


cdef void facet_answer(const Tables* T, double Px, double Py, double Pz, const Hit* h,
                       int64_t row, const Out* o) noexcept nogil:
    """Gap [2], normal, proximal point and status of P (relative to the centre) at hit h, into
    row `row` of o."""
    _answer(T, Px, Py, Pz, h, row, o)


cdef int64_t facet_feature(int64_t kind, double a, double b, double eps,
                           double* t) noexcept nogil:
    """Where ξ = (a, b) lies on a facet of `kind` corners: -1 inside, 0..3 on local edge k
    (at fraction *t), 4 + k at corner k."""
    return _feature(kind, a, b, eps, t)


cdef void facet_normal(const Tables* T, int64_t f, double a, double b, double* n) noexcept nogil:
    """Unit normal of facet slot f at ξ = (a, b), in the facets' own orientation."""
    _facet_normal(T, f, a, b, n)
