from libc.stdint cimport int64_t, int8_t

cdef void hermite_midside(const double *x0, const double *x1, const double *n0,
                          const double *n1, double *mid) noexcept nogil
cdef bint facet_cell(const double *nodes, const int64_t *corners, int k,
                     const double *normals, const double *edge_length, const double *W,
                     double *coef) noexcept nogil
cdef void node_cell(const double *nodes, const int64_t *cell, int k, const double *W,
                    double *coef) noexcept nogil
