# cython: language_level=3
"""The faceted target's closest point (`_engine.pyx`) as other compiled passes see it: the
facet tables, one contactor's search (`facet_query`, `facet_search`) and answer
(`facet_answer`), and where a point of a facet lies (`facet_feature`: inside, on an edge, at a
corner)."""
from libc.stdint cimport int64_t, int32_t, int8_t


cdef struct Tables:
    # facets in hierarchy order ("slots"); corners relative to the centre, (F, 4, 3); the
    # index tables int32 (`index_tables`: half int64's memory, a target of up to 2^29 facets)
    const double* corner
    const int8_t* kind           # 3 or 4 corners
    const double* fnormal     # unit normal of a triangle (F, 3), zero for quads
    const int32_t* fnode         # corner node ids (F, 4), -1 padded, duplicates merged
    const int32_t* fedge         # edge id of each local edge (F, 4)
    const int32_t* edge_ptr      # (E + 1,) CSR of the edge's incident (slot * 4 + local edge)
    const int32_t* edge_inc
    const double* vnormal     # angle-weighted vertex pseudonormal (n, 3)
    const double* box         # hierarchy boxes (N, 6): lo xyz, hi xyz
    const int32_t* link          # (N, 2): internal (right child, 0), leaf (first slot, count)
    const double* ctol        # contact tolerance of each node: tol.CONTACT x its spacing
    const int32_t* original      # slot -> facet index as given
    const int32_t* slot          # facet index as given -> slot
    double cx, cy, cz         # the centre
    double radius             # the target's radius about its centre
    double sign               # -1 with flipped orientation
    int64_t quad_iterations   # projected-Newton iteration limit on a quad
    double quad_step          # ... and the step on [0, 1]² it stops below
    double edge_eps           # ξ this close to a bound is on the edge or vertex
    double far                # far ranking beyond this many radii from the centre
    double proxy              # a stand-in for the search beyond this many
    # each hierarchy node's oriented bound (N, 8): a cylinder, centre xyz, unit axis xyz,
    # radius, half height, holding its facets (`oriented_bounds`); NULL: boxes alone
    const double* cyl


cdef struct Hit:
    int64_t slot
    double a, b               # ξ
    double x, y, z            # proximal point, relative to the centre
    int64_t iterations


cdef struct Out:
    double* gap
    double* normal
    double* prox
    signed char* status
    signed char* reason
    int64_t* facet
    double* param
    int64_t* support
    int64_t* iterations


cdef class FacetTables:
    cdef dict arrays              # the arrays `Tables` points into (kept alive)
    cdef Tables t


cdef bint facet_query(const Tables* T, const double* p, double* P, double* q,
                      bint* far) noexcept nogil
cdef void facet_search(const Tables* T, double px, double py, double pz, bint far,
                       Hit* best) noexcept nogil
cdef void facet_answer(const Tables* T, double Px, double Py, double Pz, const Hit* h,
                       int64_t row, const Out* o) noexcept nogil
cdef int64_t facet_feature(int64_t kind, double a, double b, double eps,
                           double* t) noexcept nogil
cdef void facet_normal(const Tables* T, int64_t f, double a, double b, double* n) noexcept nogil
