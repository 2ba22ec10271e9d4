"""Weight functions w(ρ/R) of the weighted least squares [15].

Every weight is written as a function of q = (ρ/R)², ρ the in-plane distance between a support
node and the reference point, so it is smooth at ρ = 0 where that matters for the contact
element's derivatives. Each function returns w(q) and, on request, dw/dq and d²w/dq².

- 'wendland': Wendland's C2 function (1 - r)^4 (4r + 1), compact, approximant (the surface does
  not pass through the nodes, the paper's "décollement" §5).
- 'gauss': truncated Gaussian exp(-q/c²), shifted to vanish at r = 1 (C0 there), approximant.
- 'singular': Wendland divided by q, singular at the nodes, so the surface interpolates them
  [§3.2]; q is floored at `tol.SINGULAR_FLOOR` so a point exactly on a node stays finite.
"""
from __future__ import annotations

import numpy as np

from .. import tol

WEIGHTS = ("wendland", "gauss", "singular")
_GAUSS_C2 = tol.GAUSS_WIDTH**2  # squared Gaussian width, in units of R
_GAUSS_TAIL = np.exp(-1.0 / _GAUSS_C2)


def _wendland(q, order):
    q = np.minimum(q, 1.0)
    r = np.sqrt(q)
    u = 1.0 - r
    w = u**4 * (4.0 * r + 1.0)
    if order == 0:
        return (w,)
    w1 = -10.0 * u**3
    # d²w/dq² = 15 (1-r)² / r is unbounded at r = 0, but it always multiplies (∂q)² = O(r²) there,
    # so its limit contribution is zero; the 0 at r = 0 is that limit, not an approximation.
    with np.errstate(divide="ignore", invalid="ignore"):
        w2 = np.where(r > 0.0, 15.0 * u**2 / np.where(r > 0.0, r, 1.0), 0.0)
    w2 = np.where(q < 1.0, w2, 0.0)
    return w, w1, w2


def _gauss(q, order):
    inside = q < 1.0
    e = np.exp(-np.minimum(q, 1.0) / _GAUSS_C2)
    scale = 1.0 / (1.0 - _GAUSS_TAIL)
    w = np.where(inside, (e - _GAUSS_TAIL) * scale, 0.0)
    if order == 0:
        return (w,)
    w1 = np.where(inside, -e / _GAUSS_C2 * scale, 0.0)
    w2 = np.where(inside, e / _GAUSS_C2**2 * scale, 0.0)
    return w, w1, w2


def _singular(q, order):
    qf = np.maximum(q, tol.SINGULAR_FLOOR)
    ww = _wendland(q, order)
    w = ww[0] / qf
    if order == 0:
        return (w,)
    # where q is floored the weight is held constant, so its derivatives vanish there
    live = q > tol.SINGULAR_FLOOR
    w1 = np.where(live, ww[1] / qf - ww[0] / qf**2, 0.0)
    w2 = np.where(live, ww[2] / qf - 2.0 * ww[1] / qf**2 + 2.0 * ww[0] / qf**3, 0.0)
    return w, w1, w2


_FUNCTIONS = {"wendland": _wendland, "gauss": _gauss, "singular": _singular}


def check(name: str) -> str:
    if name not in _FUNCTIONS:
        raise ValueError(f"unknown weight {name!r}: expected one of {', '.join(WEIGHTS)}")
    return name


def evaluate(name: str, q, order: int = 0):
    """Weight `name` at q = (ρ/R)², with its q-derivatives up to `order` (0 or 2).

    Returns a tuple ``(w,)`` or ``(w, dw/dq, d²w/dq²)`` of arrays shaped like `q`; all vanish
    for q ≥ 1 (outside the domain of influence).
    """
    q = np.asarray(q, dtype=np.float64)
    return _FUNCTIONS[check(name)](q, order)
