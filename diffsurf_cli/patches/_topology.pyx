"""The target's topology tables in linear compiled passes (issue 36): node identity, facet
edges, connected groups of facets, facet vertex rings and their candidate patches
(`patches.segment`, `PatchedSurface._classify_edges`, `PatchedSurface._rings`,
`projection.inside_out`).

Each table is the one the former numpy code built (np.unique, argsort, a sparse product),
entry for entry: edges numbered in the order of their (smaller, larger) node identities,
groups in the order of their first facet, rings sorted within rows. Hashing and counting
sorts replace the sorts, so the cost is linear in the facets and nodes, and no temporary is
larger than a few arrays of one entry a half-edge or a ring entry.
"""
from libc.stdint cimport int8_t, int32_t, int64_t, uint64_t
from libc.string cimport memcpy

import numpy as np


cdef inline uint64_t _mix(uint64_t h) noexcept nogil:
    # splitmix64's finaliser: coordinates on a grid differ in a few mantissa bits only
    h ^= h >> 30
    h *= <uint64_t>0xbf58476d1ce4e5b9ULL
    h ^= h >> 27
    h *= <uint64_t>0x94d049bb133111ebULL
    h ^= h >> 31
    return h


cdef inline uint64_t _bits(double x) noexcept nogil:
    cdef uint64_t b
    x = x + 0.0  # -0.0 is 0.0: the same position (np.unique compares values)
    memcpy(&b, &x, 8)
    return b


def node_identity(const double[:, ::1] nodes):
    """(n,) int64 the first node at each node's position (coincident nodes are one node): the
    least index of the nodes of equal coordinates, as np.unique(axis=0, return_index) gave; a
    node with a NaN coordinate is its own. One pass over the nodes, open-addressing hash."""
    cdef Py_ssize_t n = nodes.shape[0], i, j
    cdef uint64_t size = 2, mask, h
    while size < 2 * <uint64_t>n:
        size <<= 1
    mask = size - 1
    out = np.empty(n, np.int64)
    table = np.full(size, -1, np.int64)
    cdef int64_t[::1] o = out
    cdef int64_t[::1] t = table
    cdef double x, y, z
    with nogil:
        for i in range(n):
            x, y, z = nodes[i, 0], nodes[i, 1], nodes[i, 2]
            if x != x or y != y or z != z:
                o[i] = i
                continue
            h = _mix(_mix(_mix(_bits(x)) ^ _bits(y)) ^ _bits(z)) & mask
            while True:
                j = t[h]
                if j < 0:
                    t[h] = i
                    o[i] = i
                    break
                if nodes[j, 0] == x and nodes[j, 1] == y and nodes[j, 2] == z:
                    o[i] = j
                    break
                h = (h + 1) & mask
    return out


def edge_table(list blocks, const int64_t[::1] key):
    """Every corner edge of every facet of the corner blocks `blocks` ((f_b, k) int64, k 3 or
    4), facets numbered block after block; `key` the node identity.

    Half-edges in the order block, local edge j (corner j to j + 1), facet; an edge is the pair
    of its ends' identities, numbered in the order of (smaller, larger) identity.

    Returns fac (e,), loc (e,), edge (e,), ne, order (e,): the half-edges by edge (stable:
    argsort(edge, kind="stable")), start (ne + 1,): edge i's half-edges are
    order[start[i]:start[i + 1]], ends (ne, 2): its smaller and larger identity, forward (e,)
    int8: the half-edge runs from the smaller identity to the larger."""
    cdef Py_ssize_t e = 0, pos = 0, base = 0, r, m, j, jn, k, i, ne, nb = 0
    cdef int64_t u, v, last_lo, last_hi, eid
    cdef const int64_t[:, ::1] c
    for blk in blocks:
        e += blk.shape[0] * blk.shape[1]
    fac_a = np.empty(e, np.int64)
    loc_a = np.empty(e, np.int64)
    lo_a = np.empty(e, np.int64)
    hi_a = np.empty(e, np.int64)
    fwd_a = np.empty(e, np.int8)
    cdef int64_t[::1] fac = fac_a, loc = loc_a, lo = lo_a, hi = hi_a
    cdef int8_t[::1] fwd = fwd_a
    for blk in blocks:
        c = blk
        m, k = c.shape[0], c.shape[1]
        for j in range(k):
            jn = (j + 1) % k
            for r in range(m):
                u, v = key[c[r, j]], key[c[r, jn]]
                fac[pos] = base + r
                loc[pos] = j
                fwd[pos] = u < v
                if u <= v:
                    lo[pos], hi[pos] = u, v
                else:
                    lo[pos], hi[pos] = v, u
                if hi[pos] >= nb:
                    nb = hi[pos] + 1
                pos += 1
        base += m
    # two stable counting sorts (by the larger identity, then by the smaller): the
    # half-edges in the order of their edges' (smaller, larger) pair, ties in their own order
    count_a = np.zeros(nb + 1, np.int64)
    tmp_a = np.empty(e, np.int64)
    order_a = np.empty(e, np.int64)
    cdef int64_t[::1] count = count_a, tmp = tmp_a, order = order_a
    with nogil:
        for i in range(e):
            count[hi[i] + 1] += 1
        for i in range(nb):
            count[i + 1] += count[i]
        for i in range(e):
            tmp[count[hi[i]]] = i
            count[hi[i]] += 1
        for i in range(nb + 1):
            count[i] = 0
        for i in range(e):
            count[lo[i] + 1] += 1
        for i in range(nb):
            count[i + 1] += count[i]
        for i in range(e):
            r = tmp[i]
            order[count[lo[r]]] = r
            count[lo[r]] += 1
        ne = 0
        last_lo = last_hi = -1
        for i in range(e):
            r = order[i]
            if lo[r] != last_lo or hi[r] != last_hi:
                ne += 1
                last_lo, last_hi = lo[r], hi[r]
    edge_a = np.empty(e, np.int64)
    start_a = np.empty(ne + 1, np.int64)
    ends_a = np.empty((ne, 2), np.int64)
    cdef int64_t[::1] edge = edge_a, start = start_a
    cdef int64_t[:, ::1] ends = ends_a
    with nogil:
        eid = -1
        last_lo = last_hi = -1
        for i in range(e):
            r = order[i]
            if lo[r] != last_lo or hi[r] != last_hi:
                eid += 1
                last_lo, last_hi = lo[r], hi[r]
                start[eid] = i
                ends[eid, 0], ends[eid, 1] = last_lo, last_hi
            edge[r] = eid
        start[ne] = e
    return fac_a, loc_a, edge_a, ne, order_a, start_a, ends_a, fwd_a


cdef inline int64_t _find(int64_t[::1] parent, int64_t f) noexcept nogil:
    while parent[f] != f:
        parent[f] = parent[parent[f]]  # path halving
        f = parent[f]
    return f


def components(Py_ssize_t F, const int64_t[::1] a, const int64_t[::1] b):
    """(F,) int64 the connected groups of F facets joined across the pairs (a[i], b[i]),
    numbered in the order of their first facet (as scipy's connected_components numbers an
    undirected graph's). Union-find, each group's root its least facet."""
    parent_a = np.arange(F, dtype=np.int64)
    label_a = np.empty(F, np.int64)
    cdef int64_t[::1] parent = parent_a, label = label_a
    cdef Py_ssize_t i
    cdef int64_t ra, rb, nlab = 0
    with nogil:
        for i in range(a.shape[0]):
            ra, rb = _find(parent, a[i]), _find(parent, b[i])
            if ra < rb:
                parent[rb] = ra
            elif rb < ra:
                parent[ra] = rb
        for i in range(F):
            ra = _find(parent, i)
            if ra == i:
                label[i] = nlab
                nlab += 1
            else:
                label[i] = label[ra]
    return label_a


cdef void _merge(const int64_t *ptr, const int32_t *items, const int64_t *nodes, int k,
                 int32_t *out) noexcept nogil:
    # the union of up to 4 sorted lists (the facets of each of a facet's corner nodes), sorted
    # and without repeats, into out (its size counted before: `rings`)
    cdef int64_t head[4]
    cdef int64_t stop[4]
    cdef int32_t best, last = -1
    cdef int q, pick
    cdef Py_ssize_t count = 0
    for q in range(k):
        head[q], stop[q] = ptr[nodes[q]], ptr[nodes[q] + 1]
    while True:
        pick = -1
        best = 0
        for q in range(k):
            if head[q] < stop[q] and (pick < 0 or items[head[q]] < best):
                pick, best = q, items[head[q]]
        if pick < 0:
            return
        head[pick] += 1
        if best != last:
            out[count] = best
            count += 1
            last = best


def rings(const int64_t[:, ::1] corners, const int64_t[::1] key, Py_ssize_t n,
          const int64_t[::1] label, Py_ssize_t npatches):
    """The vertex ring of each facet (the facets sharing a node with it by identity `key`,
    itself included; the facet ring), CSR indptr (F + 1,), indices sorted within rows, and the
    distinct patches (`label`) of each ring, sorted, CSR ring_ptr (F + 1,), ring_patches; all
    int32, as the compiled passes read them (issue 36: no int64 copy to convert; ValueError
    where a table exceeds int32). corners (F, 4), -1 past a triangle's third; n the number of
    nodes.

    Each ring's size and its patches' count come from one pass of stamps (a facet, a patch
    seen for this facet yet?), so that the merge of its corners' sorted facet lists runs once,
    into its own place."""
    cdef Py_ssize_t F = corners.shape[0], f, q, i, s, t, dp, nring, npatch
    cdef int64_t g, h, p
    cdef int k
    cdef int64_t nodes[4]
    if F >= 2 ** 31 or npatches >= 2 ** 31:
        raise ValueError("the target's tables exceed int32 indices")
    nptr_a = np.zeros(n + 1, np.int64)
    cdef int64_t[::1] nptr = nptr_a
    # each node's facets (a node -> facet CSR by identity), in facet order: sorted lists
    with nogil:
        for f in range(F):
            for q in range(4):
                if corners[f, q] >= 0:
                    nptr[key[corners[f, q]] + 1] += 1
        for i in range(n):
            nptr[i + 1] += nptr[i]
    nfac_a = np.empty(nptr[n], np.int32)
    fill_a = nptr_a[:n].copy()
    fstamp_a = np.full(F, -1, np.int32)
    pstamp_a = np.full(max(npatches, 1), -1, np.int32)
    indptr_a = np.empty(F + 1, np.int32)
    ring_ptr_a = np.empty(F + 1, np.int32)
    cdef int32_t[::1] nfac = nfac_a, fstamp = fstamp_a, pstamp = pstamp_a
    cdef int32_t[::1] indptr = indptr_a, ring_ptr = ring_ptr_a
    cdef int64_t[::1] fill = fill_a
    with nogil:
        for f in range(F):
            for q in range(4):
                if corners[f, q] >= 0:
                    g = key[corners[f, q]]
                    nfac[fill[g]] = <int32_t>f
                    fill[g] += 1
        # the sizes: each facet's ring (distinct facets of its corners' lists) and its patches
        nring = npatch = 0
        indptr[0] = ring_ptr[0] = 0
        for f in range(F):
            for q in range(4):
                if corners[f, q] >= 0:
                    g = key[corners[f, q]]
                    for i in range(nptr[g], nptr[g + 1]):
                        h = nfac[i]
                        if fstamp[h] != f:
                            fstamp[h] = <int32_t>f
                            nring += 1
                            p = label[h]
                            if pstamp[p] != f:
                                pstamp[p] = <int32_t>f
                                npatch += 1
            # ends wrap past int32 only where the totals do: checked below
            indptr[f + 1] = <int32_t>nring
            ring_ptr[f + 1] = <int32_t>npatch
    if nring >= 2 ** 31 or npatch >= 2 ** 31:
        raise ValueError("the target's tables exceed int32 indices")
    indices_a = np.empty(nring, np.int32)
    patches_a = np.empty(npatch, np.int32)
    cdef int32_t[::1] indices = indices_a, patches = patches_a
    with nogil:
        for i in range(pstamp.shape[0]):
            pstamp[i] = -1
        for f in range(F):
            k = 0
            for q in range(4):
                if corners[f, q] >= 0:
                    nodes[k] = key[corners[f, q]]
                    k += 1
            if indptr[f + 1] > indptr[f]:
                _merge(&nptr[0], &nfac[0], nodes, k, &indices[indptr[f]])
            s = ring_ptr[f]
            dp = 0
            for i in range(indptr[f], indptr[f + 1]):
                p = label[indices[i]]
                if pstamp[p] != f:
                    pstamp[p] = <int32_t>f
                    # insertion into the sorted distinct patches so far (a few a facet)
                    t = s + dp
                    while t > s and patches[t - 1] > p:
                        patches[t] = patches[t - 1]
                        t -= 1
                    patches[t] = <int32_t>p
                    dp += 1
    return indptr_a, indices_a, ring_ptr_a, patches_a
