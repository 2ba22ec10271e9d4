"""Polynomial bases p of the local approximation [13]-[14].

The basis is centred at the reference point and written in coordinates scaled by the support
radius, s = (X1 - X1^r) / R and t = (X2 - X2^r) / R, so the moment matrix stays well
conditioned whatever the units of the mesh. Terms are monomials s^a t^b; the quadratic basis is
the paper's [14]: [1, s, t, s², st, t²]. The compiled layer evaluates them (`_steps.pxd`);
the tests' numpy reference is tests/reference_steps.py.
"""
from __future__ import annotations

#: Exponents (a, b) of the monomials s^a t^b of each basis, in the paper's order for [14].
EXPONENTS = {
    "linear": ((0, 0), (1, 0), (0, 1)),
    "quadratic": ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)),
    "cubic": ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2), (3, 0), (2, 1), (1, 2), (0, 3)),
}
BASES = tuple(EXPONENTS)


def complete(exponents) -> bool:
    """Whether `exponents` are all the monomials of their degree (a span that turning (s, t)
    leaves unchanged: such a reduced basis needs no direction)."""
    d = max(a + b for a, b in exponents)
    return set(exponents) == {(a, b) for a in range(d + 1) for b in range(d + 1 - a)}

#: The reduced bases of each basis, largest first: monomials a^i b^j in coordinates (a, b)
#: turned along and across the support's in-plane principal direction. Where a support cannot
#: determine the full basis (a strip two nodes wide, a row of nodes: the reciprocal condition
#: number below `tol.RCOND_MIN`, or fewer nodes than terms), the first of these it can
#: determine is fitted instead: polynomial along the strip, linear (with its twist ab) or
#: constant across (a ruled extrusion), down to a line [1, a]; complete bases of a lower degree
#: (the plane, and the quadratic for the cubic: three rows determine it) need no direction.
#: Every term is a polynomial of the full basis's degree in (s, t), so the fit is rotated back
#: into the full basis.
REDUCED = {
    "linear": (((0, 0), (1, 0)),),
    "quadratic": (((0, 0), (1, 0), (0, 1), (2, 0), (1, 1)),
                  ((0, 0), (1, 0), (0, 1), (2, 0)),
                  ((0, 0), (1, 0), (2, 0)),
                  ((0, 0), (1, 0), (0, 1)),
                  ((0, 0), (1, 0))),
    "cubic": (((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (3, 0), (2, 1)),
              ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)),  # the quadratic (3 rows)
              ((0, 0), (1, 0), (0, 1), (2, 0), (3, 0)),
              ((0, 0), (1, 0), (2, 0), (3, 0)),
              ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1)),
              ((0, 0), (1, 0), (0, 1), (2, 0)),
              ((0, 0), (1, 0), (2, 0)),
              ((0, 0), (1, 0), (0, 1)),
              ((0, 0), (1, 0))),
}


def size(name: str) -> int:
    """Number of terms of basis `name` (3, 6 or 10)."""
    try:
        return len(EXPONENTS[name])
    except KeyError:
        raise ValueError(f"unknown basis {name!r}: expected one of {', '.join(BASES)}") from None


def smallest_fitting(n: int) -> str | None:
    """The largest basis that `n` distinct nodes can determine (linear from 3, quadratic from
    6, cubic from 10), None below 3."""
    fits = [b for b in BASES if size(b) <= n]
    return fits[-1] if fits else None
