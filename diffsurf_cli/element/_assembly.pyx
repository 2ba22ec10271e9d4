# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The contact tangent summed into CSR in compiled code: Σ ε 𝒩 𝒩ᵀ + p ℳ [54] over elements.

Two passes, as a sparse FE assembly does them.

`pattern` (symbolic, once per call): an element's unknowns u = [x^c, x^nodes...] are nodes
(ids: a contactor i, or a target node j as m + j), each with up to 3 DOFs (-1: none). The
node pattern is the union of each element's node set squared, found with a marker per row
(no sort of all triplets); its rows come out ordered by the nodes' smallest DOF through one
transposition (the pattern is symmetric: A sees B exactly when B sees A). Each DOF row r of a
node A's component k then holds A's node row expanded to DOFs (B's valid components in
order): entry ((A, k), (B, l)) sits at base[A, k] + off[A, B] + rank(B, l), a formula, no
search of DOF columns. A DOF shared by two nodes (or numbered out of node order) gives a row
with repeated or unsorted columns: the caller sums them (`canonical` says whether needed).

`add` (numeric, chunk after chunk of elements): each element's block eps 𝒩𝒩ᵀ + p ℳ (+ the
multipliers' 𝒩 (ℳ[:3]ᵀλ)ᵀ and friction's ∂T/∂x on the contactor's block, as
`Contact.tangent` defines them) formed entry by entry and added at its place; the node
pairs are found by a merge of the element's nodes (sorted by smallest DOF) with the row.
One thread: the sum is order-dependent in round-off only, and atomic-free by construction.
"""
import numpy as np

from libc.stdint cimport int32_t, int64_t
from libc.stdlib cimport malloc, free
from libc.string cimport memcpy

cdef extern from *:
    """
    /* a row of an element's block over u: t = ni N + pp m (+ li g): restrict (no aliasing)
       lets the compiler vectorise it; each entry summed in the same order as written */
    static inline void ds_row(double *restrict t, const double *restrict N, double ni,
                              const double *restrict m, double pp,
                              const double *restrict g, double li, long n) {
        if (m == 0) {
            for (long c = 0; c < n; c++) t[c] = ni * N[c];
        } else if (g == 0) {
            for (long c = 0; c < n; c++) t[c] = ni * N[c] + pp * m[c];
        } else {
            for (long c = 0; c < n; c++) t[c] = ni * N[c] + pp * m[c] + li * g[c];
        }
    }

    /* ds_row then add_row at once, every node with its 3 DOFs, no multipliers: each entry
       ni N + pp m formed as ds_row does (the same sum, bitwise) and added at its place */
    #if defined(__SSE2__) && defined(__GNUC__)
    #include <emmintrin.h>
    #endif
    static inline void ds_add_row3(double *restrict row, const int64_t *off,
                                   const int64_t *slot, long n, const double *restrict N,
                                   double ni, const double *restrict m, double pp) {
    #if defined(__SSE2__) && defined(__GNUC__)
        /* two entries a product and a sum: IEEE's, the scalar loop's numbers */
        const __m128d vn = _mm_set1_pd(ni), vp = _mm_set1_pd(pp);
        for (long y = 0; y < n; y++) {
            double *d = row + off[y];
            const long c = 3 * slot[y];
            __m128d t01 = _mm_add_pd(_mm_mul_pd(vn, _mm_loadu_pd(N + c)),
                                     _mm_mul_pd(vp, _mm_loadu_pd(m + c)));
            double t2 = ni * N[c + 2] + pp * m[c + 2];
            _mm_storeu_pd(d, _mm_add_pd(_mm_loadu_pd(d), t01));
            d[2] += t2;
        }
        return;
    #endif
        for (long y = 0; y < n; y++) {
            double *d = row + off[y];
            const long c = 3 * slot[y];
            double t0 = ni * N[c] + pp * m[c];
            double t1 = ni * N[c + 1] + pp * m[c + 1];
            double t2 = ni * N[c + 2] + pp * m[c + 2];
            d[0] += t0;
            d[1] += t1;
            d[2] += t2;
        }
    }

    /* the first j in [j, end) with col[j] == v, else end: 4 columns a compare with SSE2 */
    static inline Py_ssize_t ds_find(const int32_t *col, Py_ssize_t j, Py_ssize_t end,
                                     int32_t v) {
    #if defined(__SSE2__) && defined(__GNUC__)
        const __m128i key = _mm_set1_epi32(v);
        while (j + 4 <= end) {
            int hit = _mm_movemask_epi8(_mm_cmpeq_epi32(
                _mm_loadu_si128((const __m128i *)(col + j)), key));
            if (hit)
                return j + (__builtin_ctz(hit) >> 2);
            j += 4;
        }
    #endif
        while (j < end && col[j] != v)
            j++;
        return j;
    }
    """
    void ds_row(double *t, const double *N, double ni, const double *m, double pp,
                const double *g, double li, long n) noexcept nogil
    void ds_add_row3(double *row, const int64_t *off, const int64_t *slot, long n,
                     const double *N, double ni, const double *m, double pp) noexcept nogil
    Py_ssize_t ds_find(const int32_t *col, Py_ssize_t j, Py_ssize_t end,
                       int32_t v) noexcept nogil


ctypedef fused index_t:
    int32_t
    int64_t


def pattern(const int64_t[:, ::1] ids, const int64_t[:, ::1] id_dofs, int64_t n_dofs,
            const int64_t[::1] order, index_t[::1] indices_type):
    """The CSR pattern of the elements `ids` (e, K+1) (node ids, -1 padding) at the DOFs
    `id_dofs` (n_ids, 3) (-1: none), `order` the node ids sorted by smallest DOF.

    Returns indptr (n_dofs + 1,) int64, indices (nnz,) of `indices_type`'s dtype,
    base (n_ids, 3) int64 (the start of node A's component k's segment in its DOF row, -1
    without DOF), pat_ptr (n_ids + 1,) int64, pat_col (nnzb,) int32 (node rows, by smallest
    DOF), pat_off (nnzb,) int32 (the DOF offset of each node column in its row), canonical
    (each DOF row strictly increasing: scipy's canonical CSR)."""
    cdef Py_ssize_t e = ids.shape[0], w = ids.shape[1], n_ids = id_dofs.shape[0]
    cdef Py_ssize_t i, s, t, a, b, j, k, q
    if n_ids >= 2**31 - 1:
        raise ValueError("pattern: more than 2^31 nodes")
    nv_arr = np.zeros(n_ids, np.int32)
    cdef int32_t[::1] nv = nv_arr
    for a in range(n_ids):
        for k in range(3):
            if id_dofs[a, k] >= n_dofs:
                raise ValueError(f"n_dofs = {n_dofs}, but the DOF map holds DOF "
                                 f"{id_dofs[a, k]}")
            nv[a] += id_dofs[a, k] >= 0
    for i in range(e):
        for s in range(w):
            if ids[i, s] >= n_ids:
                raise IndexError("pattern: a node id past the DOF map")
    # each element's nodes with DOFs, compacted (elem_ptr), and the elements of each node
    # (incidence): the symbolic pass below then reads only nodes that make entries
    elem_ptr_arr = np.zeros(e + 1, np.int64)
    cdef int64_t[::1] elem_ptr = elem_ptr_arr
    elem_arr = np.empty(e * w, np.int32)
    cdef int32_t[::1] elem = elem_arr
    inc_ptr_arr = np.zeros(n_ids + 1, np.int64)
    cdef int64_t[::1] inc_ptr = inc_ptr_arr
    cdef int64_t bound = 0, cnt
    with nogil:
        j = 0
        for i in range(e):
            for s in range(w):
                a = ids[i, s]
                if a >= 0 and nv[a] > 0:
                    elem[j] = <int32_t>a
                    j += 1
                    inc_ptr[a + 1] += 1
            elem_ptr[i + 1] = j
            cnt = j - elem_ptr[i]
            bound += cnt * cnt  # each of its nodes' rows gets at most its nodes
        for a in range(n_ids):
            inc_ptr[a + 1] += inc_ptr[a]
    inc_arr = np.empty(inc_ptr[n_ids], np.int64)
    cdef int64_t[::1] inc = inc_arr
    fill_arr = inc_ptr_arr[:n_ids].copy()
    cdef int64_t[::1] fill = fill_arr
    with nogil:
        for i in range(e):
            for t in range(elem_ptr[i], elem_ptr[i + 1]):
                a = elem[t]
                inc[fill[a]] = i
                fill[a] += 1
    # node rows, unordered, in one pass: a marker per row (the row's id) dedupes the union
    # of the cliques; written one after another into a buffer of the cliques' total size
    # (only the rows' own length is touched)
    marker_arr = np.full(n_ids, -1, np.int32)
    cdef int32_t[::1] marker = marker_arr
    row_ptr_arr = np.zeros(n_ids + 1, np.int64)
    cdef int64_t[::1] row_ptr = row_ptr_arr
    cdef int32_t *unordered = <int32_t *> malloc(max(bound, 1) * sizeof(int32_t))
    if unordered == NULL:
        raise MemoryError("pattern: no memory for the node rows")
    cdef int32_t b32
    with nogil:
        j = 0
        for a in range(n_ids):
            for t in range(inc_ptr[a], inc_ptr[a + 1]):
                i = inc[t]
                for s in range(elem_ptr[i], elem_ptr[i + 1]):
                    b32 = elem[s]
                    if marker[b32] != a:
                        marker[b32] = <int32_t>a
                        unordered[j] = b32
                        j += 1
            row_ptr[a + 1] = j
    del inc_arr, marker_arr, elem_arr, elem_ptr_arr
    # ordered rows: B appended to each row that holds it, B in order of smallest DOF
    pat_col_arr = np.empty(row_ptr[n_ids], np.int32)
    cdef int32_t[::1] pat_col = pat_col_arr
    fill_arr[:] = row_ptr_arr[:n_ids]
    with nogil:
        for t in range(n_ids):
            b = order[t]
            for j in range(row_ptr[b], row_ptr[b + 1]):
                a = unordered[j]
                pat_col[fill[a]] = <int32_t>b
                fill[a] += 1
    free(unordered)
    # DOF offsets of the node columns, and each node row's DOF length
    pat_off_arr = np.empty(row_ptr[n_ids], np.int32)
    cdef int32_t[::1] pat_off = pat_off_arr
    length_arr = np.zeros(n_ids, np.int64)
    cdef int64_t[::1] length = length_arr
    cdef int64_t run
    with nogil:
        for a in range(n_ids):
            run = 0
            for j in range(row_ptr[a], row_ptr[a + 1]):
                pat_off[j] = <int32_t>run
                run += nv[pat_col[j]]
            length[a] = run
    # DOF rows: each (A, k) adds A's segment to row id_dofs[A, k]; a row with two segments
    # holds its own DOF twice (each segment holds its node's DOFs): not canonical
    indptr_arr = np.zeros(n_dofs + 1, np.int64)
    cdef int64_t[::1] indptr = indptr_arr
    cdef int64_t r
    cdef bint canonical = True
    for a in range(n_ids):
        if length[a]:
            for k in range(3):
                r = id_dofs[a, k]
                if r >= 0:
                    if indptr[r + 1]:
                        canonical = False
                    indptr[r + 1] += length[a]
    for r in range(n_dofs):
        indptr[r + 1] += indptr[r]
    if index_t is int32_t and indptr[n_dofs] >= 2**31 - 1:
        raise OverflowError("pattern: int32 indices cannot hold this many entries")
    indices_arr = np.empty(indptr[n_dofs], np.asarray(indices_type).dtype)
    cdef index_t[::1] indices = indices_arr
    base_arr = np.full((n_ids, 3), -1, np.int64)
    cdef int64_t[:, ::1] base = base_arr
    dfill_arr = indptr_arr[:n_dofs].copy()
    cdef int64_t[::1] dfill = dfill_arr
    cdef int64_t d, at, first, prev
    with nogil:
        for a in range(n_ids):
            if not length[a]:
                continue
            first = -1  # the node row expanded to DOFs once, into its first DOF row ...
            for k in range(3):
                r = id_dofs[a, k]
                if r < 0:
                    continue
                base[a, k] = dfill[r]
                if first < 0:
                    first = dfill[r]
                    at, prev = first, -1
                    for j in range(row_ptr[a], row_ptr[a + 1]):
                        b = pat_col[j]
                        for q in range(3):
                            d = id_dofs[b, q]
                            if d >= 0:
                                indices[at] = <index_t>d
                                at += 1
                                if d <= prev:  # a segment not strictly increasing
                                    canonical = False
                                prev = d
                else:  # ... then copied into the others (the same segment)
                    memcpy(&indices[dfill[r]], &indices[first], length[a] * sizeof(index_t))
                dfill[r] += length[a]
    return indptr_arr, indices_arr, base_arr, row_ptr_arr, pat_col_arr, pat_off_arr, canonical


cdef inline Py_ssize_t sort_slots(const int64_t *ids, Py_ssize_t w, const int64_t *id_dofs,
                                  int64_t *slot, int64_t *key) noexcept nogil:
    """The element's slots with a node that has DOFs, by its smallest DOF (insertion sort:
    a few tens of slots). Returns their count."""
    cdef Py_ssize_t s, n = 0, q
    cdef int64_t a, kk, best, d
    cdef int k
    for s in range(w):
        a = ids[s]
        if a < 0:
            continue
        best = -1
        for k in range(3):
            d = id_dofs[3 * a + k]
            if d >= 0 and (best < 0 or d < best):
                best = d
        kk = best
        if kk < 0:
            continue
        q = n
        while q > 0 and key[q - 1] > kk:
            key[q] = key[q - 1]
            slot[q] = slot[q - 1]
            q -= 1
        key[q] = kk
        slot[q] = s
        n += 1
    return n


cdef BlockScratch *block_scratch_new(Py_ssize_t w) noexcept nogil:
    cdef BlockScratch *bs = <BlockScratch *> malloc(sizeof(BlockScratch))
    if bs == NULL:
        return NULL
    bs.slot = <int64_t *> malloc(max(w, 1) * 9 * sizeof(int64_t))
    bs.grad = <double *> malloc(max(w, 1) * 6 * sizeof(double))  # grad, then a row
    if bs.slot == NULL or bs.grad == NULL:
        block_scratch_free(bs)
        return NULL
    bs.key = bs.slot + w
    bs.node = bs.key + w
    bs.off = bs.node + w
    bs.count = bs.off + w
    bs.col = bs.count + w
    return bs


cdef void block_scratch_free(BlockScratch *bs) noexcept nogil:
    if bs != NULL:
        free(bs.slot)
        free(bs.grad)
        free(bs)


cdef inline void add_row(double *row, const int64_t *off, const int64_t *col,
                         const int64_t *count, const int64_t *slot, Py_ssize_t n,
                         const double *t) noexcept nogil:
    """One DOF row of the block, t (the row over u), added at the node columns' offsets: a
    node with its 3 DOFs (the usual case) takes 3 contiguous entries of t and of the row."""
    cdef Py_ssize_t y, q
    cdef const double *src
    cdef double *dst
    for y in range(n):
        dst = row + off[y]
        if count[y] == 3:
            src = t + 3 * slot[y]
            dst[0] += src[0]
            dst[1] += src[1]
            dst[2] += src[2]
        else:
            for q in range(count[y]):
                dst[q] += t[col[3 * y + q]]


cdef bint add_block(const Places *pl, const int64_t *ids, Py_ssize_t w, const double *N,
                    const double *M, double ep, double pp, const double *lam,
                    const double *dT, BlockScratch *bs) noexcept nogil:
    """data += one element's block eps 𝒩𝒩ᵀ + p ℳ (M NULL: the Gauss-Newton eps 𝒩𝒩ᵀ),
    + [eps > 0] 𝒩 (ℳ[:3]ᵀ λ)ᵀ (lam not NULL, with M), + ∂T/∂x on the contactor's 3x3 block
    (dT not NULL, 3x3), at the places of `pattern`; ids (w,) its node ids, N (3w,), M
    (3w, 3w) row-major. False: a node pair is not in the pattern (nothing more added)."""
    cdef Py_ssize_t W = 3 * w, n, x, y, k, q, c, ri, used
    cdef int64_t A, j, end, d
    cdef double ni, li
    cdef bint full
    cdef double *t = bs.grad + W
    cdef double *row
    cdef const double *Mrow = NULL
    cdef const double *gp = NULL
    n = sort_slots(ids, w, pl.id_dofs, bs.slot, bs.key)
    # each slot's node and the columns of its DOFs in u (3 slot + component)
    used = 0  # the columns of u up to the last slot with DOFs: the rest is padding
    full = True  # every node with its 3 DOFs: `ds_add_row3`
    for x in range(n):
        used = max(used, 3 * bs.slot[x] + 3)
        bs.node[x] = ids[bs.slot[x]]
        bs.count[x] = 0
        for k in range(3):
            if pl.id_dofs[3 * bs.node[x] + k] >= 0:
                bs.col[3 * x + bs.count[x]] = 3 * bs.slot[x] + k
                bs.count[x] += 1
        full = full and bs.count[x] == 3
    if M != NULL and lam != NULL:  # ∂(λ·ν)/∂u = ℳ[:3]ᵀ λ, where active
        gp = bs.grad
        for c in range(used):
            bs.grad[c] = 0.0
            if ep > 0:
                for q in range(3):
                    bs.grad[c] += M[q * W + c] * lam[q]
    for x in range(n):
        A = bs.node[x]
        j, end = pl.pat_ptr[A], pl.pat_ptr[A + 1]
        for y in range(n):  # the row's node columns: a merge (both by smallest DOF)
            j = ds_find(pl.pat_col, j, end, <int32_t>bs.node[y])
            if j == end:  # not in the pattern: it was built for other elements
                return False
            bs.off[y] = pl.pat_off[j]
        for k in range(3):
            d = pl.id_dofs[3 * A + k]
            if d < 0:
                continue
            ri = 3 * bs.slot[x] + k
            row = &pl.data[pl.base[3 * A + k]]
            # the block's row over u, contiguous (it vectorises), then added at its places
            ni, li = ep * N[ri], N[ri]
            Mrow = NULL
            if M != NULL:
                Mrow = M + ri * W
            if full and Mrow != NULL and gp == NULL:
                ds_add_row3(row, bs.off, bs.slot, n, N, ni, Mrow, pp)
            else:
                ds_row(t, N, ni, Mrow, pp, gp, li, used)
                add_row(row, bs.off, bs.col, bs.count, bs.slot, n, t)
            if dT != NULL and bs.slot[x] == 0:  # ∂T/∂x: the contactor's block
                for y in range(n):
                    if bs.slot[y] == 0:
                        for q in range(bs.count[y]):
                            row[bs.off[y] + q] += dT[3 * k + bs.col[3 * y + q]]
    return True


def add(const int64_t[:, ::1] base, const int64_t[::1] pat_ptr, const int32_t[::1] pat_col,
        const int32_t[::1] pat_off, const int64_t[:, ::1] ids, const int64_t[:, ::1] id_dofs,
        const double[:, ::1] N, const double[:, :, ::1] M, const double[::1] eps,
        const double[::1] p, const double[:, ::1] lam, const double[:, :, ::1] dT,
        double[::1] data):
    """data += each element's block eps 𝒩𝒩ᵀ + p ℳ (ℳ empty: the Gauss-Newton eps 𝒩𝒩ᵀ),
    + [eps > 0] 𝒩 (ℳ[:3]ᵀ λ)ᵀ where `lam` has rows, + ∂T/∂x on the contactor's 3x3 block
    where `dT` has rows, at the places of `pattern` (built for these elements or more)."""
    cdef Py_ssize_t e = ids.shape[0], w = ids.shape[1], W = 3 * w, i
    cdef bint second = M.shape[0] > 0, multiplied = lam.shape[0] > 0
    cdef bint friction = dT.shape[0] > 0
    if N.shape[0] != e or N.shape[1] != W or eps.shape[0] != e or p.shape[0] != e:
        raise ValueError("add: N must be (e, 3(K+1)), eps and p (e,)")
    if second and (M.shape[0] != e or M.shape[1] != W or M.shape[2] != W):
        raise ValueError("add: M must be (e, 3(K+1), 3(K+1)) or empty")
    if multiplied and (not second or lam.shape[0] != e or lam.shape[1] != 3):
        raise ValueError("add: lam must be (e, 3) with M, or empty")
    if friction and (dT.shape[0] != e or dT.shape[1] != 3 or dT.shape[2] != 3):
        raise ValueError("add: dT must be (e, 3, 3) or empty")
    if e == 0:
        return
    cdef Places pl
    pl.base, pl.pat_ptr, pl.pat_col = &base[0, 0], &pat_ptr[0], &pat_col[0]
    pl.pat_off, pl.id_dofs, pl.data = &pat_off[0], &id_dofs[0, 0], &data[0]
    cdef BlockScratch *bs = block_scratch_new(w)
    if bs == NULL:
        raise MemoryError("add: no memory for the scratch")
    cdef bint ok = True
    with nogil:
        for i in range(e):
            ok = add_block(&pl, &ids[i, 0], w, &N[i, 0], &M[i, 0, 0] if second else NULL,
                           eps[i], p[i], &lam[i, 0] if multiplied else NULL,
                           &dT[i, 0, 0] if friction else NULL, bs)
            if not ok:
                break
    block_scratch_free(bs)
    if not ok:
        raise ValueError("add: an element's node pair is not in the pattern")


def scatter(double[::1] out, const int64_t[::1] contactor, const int64_t[:, ::1] nodes,
            const int64_t[:, ::1] id_dofs, int64_t m, const double[:, ::1] vals):
    """out[d] += vals[i, 3 s + k] for each element i's unknown s (its contactor
    contactor[i], then its support nodes nodes[i, :], -1 padding) and component k, d the
    DOF of that node id in `id_dofs` (m + n_target, 3) (contactor j: id j; target node j: id
    m + j; d < 0: none, skipped): the residual's sum. Elements one after another, each in
    u's order: the order of `np.add.at(out, dofs[keep], vals[keep])` over `Contact.dofs`,
    so the same sums, bitwise, without the (e, 3(K+1)) DOF array."""
    cdef Py_ssize_t e = vals.shape[0], K = nodes.shape[1], i, s, k
    cdef int64_t n_ids = id_dofs.shape[0], size = out.shape[0], a, d
    if contactor.shape[0] != e or nodes.shape[0] != e or vals.shape[1] != 3 * (K + 1):
        raise ValueError("scatter: contactor (e,), nodes (e, K) and vals (e, 3(K+1)) "
                         "must agree")
    if id_dofs.shape[1] != 3 or not 0 <= m <= n_ids:
        raise ValueError("scatter: id_dofs must be (m + n_target, 3)")
    for i in range(e):
        if not 0 <= contactor[i] < m:
            raise IndexError(f"scatter: contactor {contactor[i]} past the {m} contactors")
        for s in range(K):
            if nodes[i, s] >= n_ids - m:
                raise IndexError(f"scatter: node {nodes[i, s]} past the {n_ids - m} "
                                 f"target nodes")
    for a in range(n_ids):
        for k in range(3):
            if id_dofs[a, k] >= size:
                raise IndexError(f"scatter: DOF {id_dofs[a, k]} past the vector of {size}")
    with nogil:
        for i in range(e):
            for s in range(K + 1):
                if s == 0:
                    a = contactor[i]
                elif nodes[i, s - 1] < 0:
                    continue
                else:
                    a = m + nodes[i, s - 1]
                for k in range(3):
                    d = id_dofs[a, k]
                    if d >= 0:
                        out[d] += vals[i, 3 * s + k]
