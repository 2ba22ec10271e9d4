"""The steps of the method in numpy, the tests' reference for the compiled layer
(`diffsurf_cli/mls/_weight.pxd`: the weights w(q) of [15] with their q-derivatives;
`diffsurf_cli/mls/_steps.pxd`: the polynomial bases p of [13]-[14] with their
derivatives). The package holds their names (`mls.weight.WEIGHTS`, `mls.basis.EXPONENTS`)
and the compiled code; this is the only second copy."""
from __future__ import annotations

import numpy as np

from diffsurf_cli import tol
from diffsurf_cli.mls.basis import EXPONENTS
from diffsurf_cli.mls.weight import check

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


_WEIGHTS = {"wendland": _wendland, "gauss": _gauss, "singular": _singular}


def weight(name: str, q, order: int = 0):
    """Weight `name` at q = (ρ/R)², with its q-derivatives up to `order` (0 or 2).

    Returns a tuple ``(w,)`` or ``(w, dw/dq, d²w/dq²)`` of arrays shaped like `q`; all vanish
    for q ≥ 1 (outside the domain of influence).
    """
    q = np.asarray(q, dtype=np.float64)
    return _WEIGHTS[check(name)](q, order)


def _power(x, n, one):
    out = one
    for _ in range(n):
        out = out * x
    return out


def terms(name: str, s, t, ds: int = 0, dt: int = 0) -> list:
    """The terms of ∂^(ds+dt) p / ∂s^ds ∂t^dt at (s, t), as a list (one entry per term).

    Works for numpy arrays and for any type with ``*`` and scalar ``*`` (the `jet` type of the
    contact element), which is why it returns a list rather than a stacked array.

    Parameters
    ----------
    name : str
        'linear', 'quadratic' or 'cubic'.
    s, t : (...) float or jet
        Scaled in-plane coordinates relative to the basis centre.
    ds, dt : int
        Derivative orders.
    """
    return monomials(EXPONENTS[name], s, t, ds, dt)


def monomials(exponents, s, t, ds: int = 0, dt: int = 0) -> list:
    """`terms` of the monomials s^a t^b of `exponents` (a basis's or a reduced basis's)."""
    one = s * 0.0 + 1.0
    out = []
    for a, b in exponents:
        if a < ds or b < dt:
            out.append(s * 0.0)
            continue
        c = float(np.prod(range(a - ds + 1, a + 1)) * np.prod(range(b - dt + 1, b + 1)))
        out.append(_power(s, a - ds, one) * _power(t, b - dt, one) * c)
    return out


def basis(name: str, s, t, ds: int = 0, dt: int = 0) -> np.ndarray:
    """∂^(ds+dt) p / ∂s^ds ∂t^dt at (s, t) as an array of shape s.shape + (k,)."""
    s = np.asarray(s, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    return np.stack(terms(name, s, t, ds, dt), axis=-1)
