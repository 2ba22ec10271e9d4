"""The weight functions w(ρ/R) of the weighted least squares [15], by name. They are declared
once, in the compiled layer (`_weight.pxd`: codes, constants, values and derivatives;
`_weight.pyx`: their names, read here); the tests' numpy reference is tests/reference_steps.py.

Every weight is written as a function of q = (ρ/R)², ρ the in-plane distance between a support
node and the reference point, so it is smooth at ρ = 0 where that matters for the contact
element's derivatives: w(q) and, for the element, dw/dq and d²w/dq².

- 'wendland': Wendland's C2 function (1 - r)^4 (4r + 1), compact, approximant (the surface does
  not pass through the nodes, the paper's "décollement" §5).
- 'gauss': truncated Gaussian exp(-q/c²), shifted to vanish at r = 1 (C0 there), approximant.
- 'singular': Wendland divided by q, singular at the nodes, so the surface interpolates them
  [§3.2]; q is floored at `tol.SINGULAR_FLOOR` so a point exactly on a node stays finite.
"""
from __future__ import annotations

from ._weight import WEIGHTS


def check(name: str) -> str:
    """`name` if it is a weight's, else a ValueError naming them."""
    if name not in WEIGHTS:
        raise ValueError(f"unknown weight {name!r}: expected one of {', '.join(WEIGHTS)}")
    return name
