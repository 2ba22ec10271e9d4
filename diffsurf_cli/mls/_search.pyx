# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The searches' structures (`_search.pxd`): the uniform grid of cells over the target's nodes,
its rings of empty cells, its k-d tree, and `nearest_distances` (the k nearest distances,
what the node spacing is made of). Searches themselves are `cdef inline` in `_search.pxd`."""
import numpy as np

from libc.math cimport sqrt, fabs, INFINITY
from libc.stdlib cimport malloc, free
from cython.parallel cimport prange, parallel

from .. import tol
from ..threads import threads_for


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
        margin3[e] = g.cell_margin * (fabs(p[e]) + fabs(g.lo[e]) + <double>(g.dims[e] + 1) * g.cell)
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
    cdef int64_t count = 0, i, j, c, a, node
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


cdef int64_t tree_knn(const Tree *tr, const double *p, int64_t k, int64_t *best_i,
                      double *best_d2, double tr_margin) noexcept nogil:
    """The k nearest nodes of p, nearest first (as `knn`), by the grid's k-d tree: depth
    first, the nearer child first, skipping every tree node whose box is beyond the k-th
    nearest so far. For a contactor several cells off the target, where a search over cells
    visits every cell its k-th distance reaches (a box of them, mostly empty), the tree's
    boxes hug the target: it reads a few leaves."""
    cdef int64_t stack_t[TREE_STACK]
    cdef double stack_d2[TREE_STACK]
    cdef int64_t sp = 1, t, a, count = 0, lc, r, first_leaf = tr.count - tr.leaves
    cdef double dl, dr, margin = 0.0
    cdef int e
    for e in range(3):
        margin = dmax(margin, tr_margin * (fabs(p[e]) + fabs(tr.box[e]) + fabs(tr.box[3 + e])))
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
        lc = 2 * t + 1
        dl = box_gap2(tr.box + 6 * lc, p, margin)
        dr = box_gap2(tr.box + 6 * (lc + 1), p, margin)
        # the farther child first on the stack, the nearer searched first; a child beyond the
        # k-th nearest so far is not stacked at all
        if dr < dl:
            dl, dr = dr, dl
            lc += 1
            r = lc - 1
        else:
            r = lc + 1
        if not (count == k and dr >= best_d2[k - 1]):
            stack_t[sp] = r
            stack_d2[sp] = dr
            sp += 1
        if not (count == k and dl >= best_d2[k - 1]):
            stack_t[sp] = lc
            stack_d2[sp] = dl
            sp += 1
    return count


cdef int64_t nearest(const Grid *g, const double *p, int64_t k, int64_t cap, int64_t *pool_i,
                     double *pool_d2, int64_t *best_i, double *best_d2) noexcept nogil:
    """The k nearest nodes of p, nearest first, as `knn` (ties in another order): first among
    the nodes within g.near_reach cells of p (a box of usually 2x2x2 cells, where `knn` always
    reads 3x3x3), which hold them whenever there are k of them; else by the grid's k-d tree
    (`tree_knn`) if it has one, by `knn` if not. A contactor whose cell's ring (`empty_rings`)
    is 2 or more has no node within a cell: it goes to the tree at once. pool_i and pool_d2
    (`cap` entries) are scratch."""
    cdef double r = g.near_reach * g.cell
    cdef int64_t found = 0, j, count = 0
    cdef int64_t ci = cell_index(p[0], g.lo[0], g.cell, g.dims[0])
    cdef int64_t cj = cell_index(p[1], g.lo[1], g.cell, g.dims[1])
    cdef int64_t ck = cell_index(p[2], g.lo[2], g.cell, g.dims[2])
    if g.ring[(ci * g.dims[1] + cj) * g.dims[2] + ck] < 2:
        found = ball(g, p, r * r, cap, pool_i, pool_d2)
    if found < k or found > cap:
        if g.tree.count:
            return tree_knn(&g.tree, p, k, best_i, best_d2, g.box_margin)
        return knn(g, p, k, best_i, best_d2)
    for j in range(found):
        count = offer(best_i, best_d2, k, count, pool_i[j], pool_d2[j])
    return count


#: Grid cells per node at most (a dense grid over the bounding box of a sparse, elongated
#: target could otherwise be huge); the cell grows until the grid fits.
MAX_CELLS_PER_NODE = 8


def build_grid(coords, double cell):
    """A uniform grid over `coords` (n, 3): (lo, cell, dims, start, order).

    Nodes of cell c are ``order[start[c]:start[c + 1]]``; cell indices are
    (i * dims[1] + j) * dims[2] + k. A counting sort of the nodes by cell, linear (stable:
    a cell's nodes in increasing order), the same tables as numpy's stable argsort of the
    cells' indices and its searchsorted of every cell (tests/reference_frame.py).
    """
    coords = np.ascontiguousarray(coords, dtype=np.float64).reshape(-1, 3)
    n = len(coords)
    # the box column by column (numpy's min/max over axis 0 of a (n, 3) array is several
    # times slower; the same values, but for which of -0.0 and 0.0 a tie keeps: the
    # reduction over axis 0 where a bound is zero)
    lo = np.array([coords[:, e].min() for e in range(3)]) if n else np.zeros(3)
    hi = np.array([coords[:, e].max() for e in range(3)]) if n else np.zeros(3)
    if n and not (np.all(lo != 0) and np.all(hi != 0)):
        lo, hi = coords.min(axis=0), coords.max(axis=0)
    span = hi - lo
    if not cell > 0:
        cell = 1.0
    limit = max(MAX_CELLS_PER_NODE * n, 64)
    while True:
        dims = np.maximum(np.floor(span / cell).astype(np.int64) + 1, 1)
        if np.prod(dims.astype(np.float64)) <= limit:
            break
        cell *= 1.25
    start_ = np.zeros(int(np.prod(dims)) + 1, dtype=np.int64)
    order_ = np.empty(n, dtype=np.int64)
    lin_ = np.empty(n, dtype=np.int64)
    cdef const double[:, ::1] x = coords
    cdef int64_t[::1] start = start_
    cdef int64_t[::1] order = order_
    cdef int64_t[::1] lin = lin_
    cdef double lo0 = lo[0], lo1 = lo[1], lo2 = lo[2], c = cell
    cdef int64_t d0 = dims[0], d1 = dims[1], d2 = dims[2], i, ncell = start_.shape[0] - 1
    cdef int64_t a, b, e, m = n
    with nogil:
        for i in range(m):
            # numpy's ((coords - lo) / cell).astype(int64), clipped to the last cell
            a = <int64_t>((x[i, 0] - lo0) / c)
            b = <int64_t>((x[i, 1] - lo1) / c)
            e = <int64_t>((x[i, 2] - lo2) / c)
            a = a if a < d0 - 1 else d0 - 1
            b = b if b < d1 - 1 else d1 - 1
            e = e if e < d2 - 1 else d2 - 1
            lin[i] = (a * d1 + b) * d2 + e
            start[lin[i] + 1] += 1
        for i in range(ncell):
            start[i + 1] += start[i]
        for i in range(m):           # in node order: stable
            order[start[lin[i]]] = i
            start[lin[i]] += 1
        for i in range(ncell, 0, -1):  # each cell's end back to its start
            start[i] = start[i - 1]
        start[0] = 0
    return lo, float(cell), dims, start_, order_


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
    cdef int64_t i, j, k, c, t, b, e, best, sweep, step, plane = d1 * d2
    cdef int64_t b0, b1, e0, e1, i1, j1, k1, q
    cdef int64_t top = MAX_RING
    cdef int64_t ahead[13]         # a cell's 13 neighbours before it, as offsets (forward)
    q = 0
    for b in range(-1, 2):
        for e in range(-1, 2):
            ahead[q] = -plane + b * d2 + e
            q += 1
    for e in range(-1, 2):
        ahead[q] = -d2 + e
        q += 1
    ahead[12] = -1
    with nogil:
        for c in range(ncell):
            ring[c] = 0 if start[c + 1] > start[c] else <uint8_t>top
        # forward: the 13 neighbours before a cell in raster order (the layer i - 1's 9, the
        # row j - 1's 3, the cell k - 1); backward: the 13 after. Cells in raster order, their
        # (i, j, k) from the loops (no division), inner cells' neighbours by fixed offsets,
        # the others' ranges clipped to the grid once a cell: the same minima in the same
        # sweep order as a test per neighbour
        for sweep in range(2):
            step = 1 if sweep == 0 else -1
            for t in range(d0):
                i = t if sweep == 0 else d0 - 1 - t
                i1 = i - step
                for j1 in range(d1):
                    j = j1 if sweep == 0 else d1 - 1 - j1
                    b0 = -1 if j > 0 else 0
                    b1 = 1 if j < d1 - 1 else 0
                    for k1 in range(d2):
                        k = k1 if sweep == 0 else d2 - 1 - k1
                        c = (i * d1 + j) * d2 + k
                        if ring[c] == 0:
                            continue
                        best = ring[c]
                        if 0 < i < d0 - 1 and 0 < j < d1 - 1 and 0 < k < d2 - 1:
                            # inside the grid: the 13 neighbours by fixed offsets
                            for q in range(13):
                                best = imin(best, <int64_t>ring[c + step * ahead[q]] + 1)
                            ring[c] = <uint8_t>best
                            continue
                        e0 = -1 if k > 0 else 0
                        e1 = 1 if k < d2 - 1 else 0
                        if 0 <= i1 < d0:            # the previous layer: 9 cells
                            for b in range(b0, b1 + 1):
                                for e in range(e0, e1 + 1):
                                    best = imin(best, <int64_t>ring[c - step * plane
                                                                    + b * d2 + e] + 1)
                        if 0 <= j - step < d1:      # the previous row of this layer: 3
                            for e in range(e0, e1 + 1):
                                best = imin(best, <int64_t>ring[c - step * d2 + e] + 1)
                        if 0 <= k - step < d2:      # the previous cell of this row
                            best = imin(best, <int64_t>ring[c - step] + 1)
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
    return _build_tree(coords, leaf)[:3]


def _build_tree(coords, int64_t leaf=TREE_LEAF):
    """`build_tree`'s (box, span, perm) and the coordinates in tree order, coords[perm] (the
    tree's own copy, `GridArrays`). The coordinates are permuted with perm as it is (a copy
    of them swapped with it), so that each level reads them in order rather than through
    perm at random (issue 36: half the tree's setup at 163k nodes); the same comparisons and
    swaps, the same tree bit for bit (tests/test_engine.py)."""
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
    xs_ = coords.copy()
    cdef double[:, ::1] box = box_
    cdef int64_t[:, ::1] span = span_
    cdef int64_t[::1] perm = perm_
    cdef double[:, ::1] x = xs_             # x[i] = coords[perm[i]] throughout
    cdef double v, pivot, ext, s0, s1, s2
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
                        v = x[i, e]
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
                    pivot = x[(a + b) // 2, ax]
                    i = a
                    j = b
                    while i <= j:
                        while x[i, ax] < pivot:
                            i += 1
                        while x[j, ax] > pivot:
                            j -= 1
                        if i <= j:
                            tmp = perm[i]
                            perm[i] = perm[j]
                            perm[j] = tmp
                            s0, s1, s2 = x[i, 0], x[i, 1], x[i, 2]
                            x[i, 0], x[i, 1], x[i, 2] = x[j, 0], x[j, 1], x[j, 2]
                            x[j, 0], x[j, 1], x[j, 2] = s0, s1, s2
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
    return box_, span_, perm_, xs_


cdef class GridArrays:
    """The arrays of one grid, kept alive while its `Grid` struct points into them."""

    def __init__(self, coords, double cell, bint tree=False, tables=None):
        # `tables`: `build_grid(coords, cell)`'s own, where the caller has them (`Target`)
        lo, cell, dims, start, order = build_grid(coords, cell) if tables is None else tables
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
        self.grid.near_reach = tol.NEAR_REACH_CELLS
        self.grid.cell_margin = tol.SEARCH_MARGIN
        self.grid.box_margin = tol.TREE_MARGIN
        for e in range(3):
            self.grid.lo[e] = lo[e]
            self.grid.dims[e] = dims[e]
        self.grid.tree.count = 0
        if tree and len(self.coords):
            box, span, perm, tree_coords = _build_tree(self.coords)
            self.tree_box = box
            self.tree_span = span
            self.tree_perm = perm
            self.tree_coords = tree_coords  # coords[perm], the same bits
            self.grid.tree.box = &self.tree_box[0, 0]
            self.grid.tree.span = &self.tree_span[0, 0]
            self.grid.tree.perm = &self.tree_perm[0]
            self.grid.tree.coords = &self.tree_coords[0, 0]
            self.grid.tree.count = len(box)
            self.grid.tree.leaves = (len(box) + 1) // 2


cdef inline void nearest_row(const Grid *g, const double *x, int64_t k, int64_t *idx,
                             double *d2, double *out) noexcept nogil:
    """`nearest_distances`' work for one point x: its k distances into out, the same from the
    serial loop and the parallel one (idx, d2: k scratch)."""
    cdef int64_t got = knn(g, x, k, idx, d2), j
    for j in range(k):
        out[j] = sqrt(d2[j]) if j < got else INFINITY


def nearest_distances(coords, int64_t k, points=None, int threads=0):
    """Distances (m, k) from each of `points` (m, 3; default: `coords` itself) to its k
    nearest of `coords` (n, 3), nearest first, inf past the n-th: what scipy's
    ``cKDTree(coords).query(points, k)`` gives, by the grid's search (`knn`, the node
    spacing's). `threads`: OpenMP threads of the loop (0: `threads.threads_for`'s; 1: a plain
    loop, no parallel region)."""
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
    cdef GridArrays grid = GridArrays(coords, cell)
    cdef double[:, ::1] d = out
    cdef const double[:, ::1] x = query
    cdef int64_t *idx
    cdef int failed = 0
    cdef int *failedp = &failed
    cdef double *dd = &d[0, 0]
    cdef const double *xx = &x[0, 0]
    if threads <= 0:
        threads = threads_for(m, "nearest")
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            idx = <int64_t *>malloc(k * (sizeof(int64_t) + sizeof(double)))
            if idx != NULL:
                for i in range(m):
                    nearest_row(&grid.grid, xx + 3 * i, k, idx, <double *>(idx + k),
                                dd + i * k)
                free(idx)
            else:
                failed = 1
    else:
        with nogil, parallel(num_threads=threads):
            idx = <int64_t *>malloc(k * (sizeof(int64_t) + sizeof(double)))
            if idx == NULL:
                failedp[0] = 1
            for i in prange(m, schedule="static"):
                if idx != NULL:
                    nearest_row(&grid.grid, xx + 3 * i, k, idx, <double *>(idx + k),
                                dd + i * k)
            free(idx)
    if failed:
        raise MemoryError("no memory for the nearest-node search")
    return out
