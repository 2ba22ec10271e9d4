# cython: language_level=3
"""The projection onto the diffuse surface [§3-§4.1], one contactor at a time: the data its
steps share (the target `TargetC`, the call's `Options`, a contactor's `Result`, the per-thread
`Scratch`) and the pass's entry points, cimported by every compiled pass that projects
(`project_one`: support, fit, Newton, normal [29], gap [32], status [33], the on-target tests,
the retry with a wider support and the re-centring loop; `solve` with a frozen pairing [§4.2]).
`_projection.pyx` composes the steps and is the Python face (`Target`); each step is written
once (`cdef inline`) in the file of its subject, as mls/ lays out the method: `_support.pxd`
(node spacing, support and frame), `_frame.pxd` (the frame's axes), `_fit.pxd` (the weighted
least squares [15]-[17] and the reduced bases of strips), `_newton.pxd` (the proximal point
[30]), `_weight.pxd` (the weight [15]), `_steps.pxd` (basis, local approximation, hull test),
`_linalg.pxd` (small dense linear algebra) and `_search.pxd` (the searches)."""
from libc.stdint cimport int64_t, int8_t, uint8_t

from ._linalg cimport NTERMS_MAX
from ._weight cimport WeightParams
from ._search cimport Grid, GridArrays

cdef enum:
    NREDUCED_MAX = 12            # reduced bases of a basis (basis.REDUCED)

cdef struct TargetC:
    const double *nodes          # (n, 3)
    const double *normals        # (n, 3) nodal normals (zero rows without facets)
    const double *node_spacing   # (n,)
    const int64_t *first         # (n,) first node at the same position
    const double *fold_normals   # (n, 3)
    const uint8_t *is_signed     # (n,) whether fold_normals is oriented
    const uint8_t *steep         # (n,)
    const int64_t *perm          # (n,) the caller's number of each node
    const int64_t *inv           # (n,) the engine's number of each of the caller's nodes
    Grid grid                    # the nodes
    Grid plane                   # the nodes' in-plane coordinates in the global frame
    double frame_origin[3]
    double frame_axes[9]         # rows e1, e2, e3
    bint has_faces, duplicates, global_frame
    int64_t n

cdef struct Options:
    int nterms
    int ea[10]
    int eb[10]
    int nreduced                 # the reduced bases (basis.REDUCED), largest first:
    int rsize[12]                # basis r has rsize[r] terms a^ra b^rb,
    int ra[120]                  # ra[NTERMS_MAX * r + j], rb[...] (a along the support)
    int rb[120]
    bint across[12]              # whether reduced basis r has a term in b
    bint ruled_global            # the global frame is fixed by more than a row of nodes
    double ruled_spread, row_variance, strip_rank
    bint plane_only[12]          # reduced basis r is complete (basis.complete: no direction)
    WeightParams wp              # the weight [15] (kind: WEIGHT_CODES) and its constants
    bint knn                     # support: k nearest (else radius)
    int64_t k[2]                 # k nearest, first try and enlarged retry
    double radius[2]             # support radius in spacings, first try and retry
    int64_t spacing_neighbours   # k + 1 nearest nodes weigh the spacing (tie-free)
    double frame_ball, knn_factor, sheet_cos, cos_fold, rcond_min, contact_tol
    double outside_spacings, hull_spacings
    double equilibration_floor
    double newton_step
    int newton_max_iter
    double e1_guide[3]
    double e1_guide_alt[3]
    bint recentre
    int recentre_max_iter
    double recentre_step, recentre_stall
    bint keep                    # store each support's node indices (the pairing)

cdef struct Result:
    double gap
    double normal[3]
    double proximal[3]
    double rcond
    double curvature[2]
    int8_t status, reason, terms
    int8_t reduced               # the reduced basis fitted (basis.REDUCED), -1 the full one
    double direction             # its a axis's angle in the frame (NaN: none)
    int64_t support, iterations
    double origin[3]
    double axes[9]
    double R, h
    double alpha[NTERMS_MAX]     # the fit [17] (op.keep: the pairing's)
    int64_t count                # support nodes in index
    int64_t *index               # (cap,) scratch
    bint overflow

cdef struct Record:
    # what every pass writes, one row per contactor (`projection.RECORD`, the Projection's
    # fields and the overflow flags), as raw pointers into C-contiguous arrays: no
    # memoryview reference counting per point; `record_of` points it at a pass's arrays
    double *gap
    double *normal               # (m, 3)
    double *proximal             # (m, 3)
    int8_t *status
    int8_t *reason
    int64_t *support
    int64_t *iterations
    double *rcond
    double *curvature            # (m, 2)
    int8_t *terms
    uint8_t *overflow


cdef struct Scratch:
    int64_t cap
    int64_t *cand_i
    int64_t *near_i
    int64_t *live_i              # the support nodes inside the domain of influence
    double *cand_d2
    double *near_d2
    double *s
    double *t
    double *z
    double *w
    double *geo
    double *arc_start
    double *arc_end
    double *a                    # (max(cap, n), row_stride(n)): [W^½P | W^½z]
    double *rfac                 # (n, n)
    double *work                 # (n, n)
    double *sig                  # (n,)
    double *scale                # (n,)
    double *alpha                # (n,)
    double nbar[3]               # weighted normal of the spacing neighbours
    double foot[3]               # foot of the reference point on the target
    double knn_d2                # squared distance of the k-th nearest ('knn' support)
    double h_min                 # the local spacing's floor (0: none; the patched pass's)
    Result res[2]
    void *mem


# the projection of one contactor and what a pass over contactors needs around it
# (`_projection.pyx`)
cdef Scratch *scratch_new(int64_t cap, int nterms, int64_t near) noexcept nogil
cdef void scratch_free(Scratch *sc) noexcept nogil
cdef void blank(Result *res) noexcept nogil
cdef void solve(const TargetC *tg, const Options *op, const double *x, bint centred,
                int64_t count, Scratch *sc, Result *res, bint frozen) noexcept nogil
cdef void select_solve(const TargetC *tg, const Options *op, const double *x,
                       const double *ref, bint centred, int attempt, Scratch *sc,
                       Result *res, double h) noexcept nogil
cdef void flag_bad_point(Result *res) noexcept nogil
cdef Result *project_one(const TargetC *tg, const Options *op, const double *x,
                         Scratch *sc) noexcept nogil


cdef class Target:
    cdef const double[:, ::1] nodes
    cdef const double[:, ::1] normals
    cdef const double[::1] node_spacing
    cdef const int64_t[::1] first
    cdef const double[:, ::1] fold_normals
    cdef const uint8_t[::1] signed_
    cdef const uint8_t[::1] steep
    cdef const int64_t[::1] perm
    cdef const int64_t[::1] inv
    cdef GridArrays grid
    cdef GridArrays plane
    cdef TargetC c


cdef Options make_options(dict o, bint keep) except *
cdef int record_of(dict out, Py_ssize_t m, Record *o) except -1
