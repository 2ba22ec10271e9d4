# cython: language_level=3
"""The per-element sum of `_assembly.add`, shared with `_element.tangent_elements` (which
builds each element's ℳ and adds it at once, never writing a batch of ℳ)."""
from libc.stdint cimport int32_t, int64_t


cdef struct Places:
    # a CSR pattern of `_assembly.pattern` and its values, as raw pointers
    const int64_t *base          # (n_ids, 3)
    const int64_t *pat_ptr       # (n_ids + 1,)
    const int32_t *pat_col
    const int32_t *pat_off
    const int64_t *id_dofs       # (n_ids, 3)
    double *data


cdef struct BlockScratch:
    # per element, w = K + 1 slots: allocated once per call (`block_scratch_new`)
    int64_t *slot
    int64_t *key
    int64_t *node
    int64_t *off
    int64_t *col                 # (3w,)
    int64_t *count
    double *grad                 # (6w,): ℳ[:3]ᵀλ, then a row of the block


cdef BlockScratch *block_scratch_new(Py_ssize_t w) noexcept nogil
cdef void block_scratch_free(BlockScratch *bs) noexcept nogil
cdef bint add_block(const Places *pl, const int64_t *ids, Py_ssize_t w, const double *N,
                    const double *M, double ep, double pp, const double *lam,
                    const double *dT, BlockScratch *bs) noexcept nogil
