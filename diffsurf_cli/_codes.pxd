# cython: language_level=3
"""The status [33] and reason codes of every answer, for every compiled module (cimported);
Python reads their names from `diffsurf_cli._codes` (STATUS, REASONS), in code order."""

# status [33]
cdef enum:
    OPEN = 0
    CONTACT = 1
    PENETRATION = 2
    OUTSIDE = 3
    FAILED = 4

# why a point is 'outside' or 'failed', or why the facets answered it ('guard')
cdef enum:
    R_OK = 0
    R_BAD_POINT = 1
    R_FEW_NODES = 2
    R_ILL = 3
    R_OFF_TARGET = 4
    R_NO_CONVERGENCE = 5
    R_NOT_SETTLED = 6
    R_STEEP = 7
    R_GUARD = 8
