"""The guard's rule as numpy computed it (`PatchedSurface.within_guard` before issue 31), kept
as the oracle of the compiled rule (`_pass.guard_holds`), which the projection and the rigid
element now both run (tests/test_guard_once.py)."""
import numpy as np


def within_guard(surf, gap, normal, facet, facet_gap, apart, plane=None):
    """Whether answers pass the guard of PatchedSurface `surf` (its bounds `guard_bounds`)."""
    ok = facet >= 0
    f = np.maximum(facet, 0)
    sign = -1.0 if surf.flip else 1.0
    cos = np.einsum("ij,ij->i", normal, sign * surf.facet_normal[f])
    d = gap - facet_gap
    limit = np.minimum(surf.normal_angle[f] + surf.normal_turn[f] * apart, np.pi)
    inside = (d >= surf.gap_lo[f]) & (d <= surf.gap_hi[f]) & (cos >= np.cos(limit))
    if plane is not None:  # a plane fit explains no bend (the compiled guard's rule)
        inside &= ~np.asarray(plane, bool)
    return ~(surf.guard & ok) | inside
