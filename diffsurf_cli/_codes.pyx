# cython: language_level=3
"""The names of the status and reason codes (`_codes.pxd`), in code order: what Python reads."""

#: Status codes [33], by code.
STATUS = tuple(name for _, name in sorted({
    OPEN: "open", CONTACT: "contact", PENETRATION: "penetration", OUTSIDE: "outside",
    FAILED: "failed"}.items()))
#: Reason codes, by code.
REASONS = tuple(name for _, name in sorted({
    R_OK: "ok", R_BAD_POINT: "bad-point", R_FEW_NODES: "few-nodes", R_ILL: "ill-conditioned",
    R_OFF_TARGET: "off-target", R_NO_CONVERGENCE: "no-convergence", R_NOT_SETTLED: "recentre",
    R_STEEP: "steep", R_GUARD: "guard"}.items()))

cdef extern from *:
    """
    #ifdef _OPENMP
    #include <omp.h>
    static int ds_max_threads(void) { return omp_get_max_threads(); }
    #else
    static int ds_max_threads(void) { return 1; }
    #endif
    """
    int ds_max_threads() noexcept nogil


def max_threads():
    """The threads of an OpenMP parallel region (`omp_get_max_threads`: OMP_NUM_THREADS, else
    the CPUs; 1 where the engine was built without OpenMP)."""
    return ds_max_threads()
