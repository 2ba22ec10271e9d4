from libc.stdint cimport int64_t, int8_t

# The monomials a^i b^j (i, j <= 2) of a curved cell's geometry x(a, b) = sum_k a^i b^j c_k,
# in the order of its coefficients c_k: declared here once, for the pass (`_pass.cell_eval`)
# and, through `_cells.CELL_MONOMIALS`, for Python (`surface.cell_shape`, `element.cell`).
cdef extern from *:
    """
    static const int DIFFSURF_CELL_I[9] = {0, 1, 0, 2, 1, 0, 2, 1, 2};
    static const int DIFFSURF_CELL_J[9] = {0, 0, 1, 0, 1, 2, 1, 2, 2};
    """
    const int CELL_I "DIFFSURF_CELL_I"[9]
    const int CELL_J "DIFFSURF_CELL_J"[9]

cdef void hermite_midside(const double *x0, const double *x1, const double *n0,
                          const double *n1, double *mid) noexcept nogil
cdef bint facet_cell(const double *nodes, const int64_t *corners, int k,
                     const double *normals, const double *edge_length, const double *W,
                     double *coef) noexcept nogil
cdef void node_cell(const double *nodes, const int64_t *cell, int k, const double *W,
                    double *coef) noexcept nogil
