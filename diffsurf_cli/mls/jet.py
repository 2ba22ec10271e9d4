"""Second-order jets: exact values, gradients and Hessians of small functions, batched.

A `Jet` holds a value v (...,), its gradient g (..., P) and its Hessian H (..., P, P) with
respect to P variables, for a batch of leading shape (...). Sums, products and square roots
propagate all three exactly (forward-mode automatic differentiation to second order). The
algebraic-quadric element (`element.quadric`) uses them on functions of a few variables (the
closest point's 17: y, λ, q, θ; a support node's 6: its position and normal), where writing
each second derivative by hand would be the error-prone part; the chain to the target's nodes
is written out.
"""
from __future__ import annotations

import numpy as np


class Jet:
    """A batch of scalars with exact gradient and Hessian (see the module's docstring)."""

    __slots__ = ("v", "g", "H")
    __array_priority__ = 100  # numpy scalars and arrays defer to Jet's operators

    def __init__(self, v, g, H):
        self.v, self.g, self.H = v, g, H

    @classmethod
    def variables(cls, values: np.ndarray, P: int, first: int = 0) -> list[Jet]:
        """Jets of the independent variables values[..., k], numbered first + k of P."""
        values = np.asarray(values, dtype=np.float64)
        shape = values.shape[:-1]
        out = []
        for k in range(values.shape[-1]):
            g = np.zeros((*shape, P))
            g[..., first + k] = 1.0
            out.append(cls(values[..., k], g, np.zeros((*shape, P, P))))
        return out

    @classmethod
    def constant(cls, value, like: Jet) -> Jet:
        value = np.broadcast_to(np.asarray(value, dtype=np.float64), like.v.shape)
        return cls(value.copy(), np.zeros_like(like.g), np.zeros_like(like.H))

    @classmethod
    def lift(cls, value, grad, hess) -> Jet:
        """A jet given its value, gradient and Hessian outright (a closed form's)."""
        return cls(value, grad, hess)

    def __add__(self, other):
        if isinstance(other, Jet):
            return Jet(self.v + other.v, self.g + other.g, self.H + other.H)
        return Jet(self.v + other, self.g, self.H)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.v, -self.g, -self.H)

    def __sub__(self, other):
        return self + (-other)

    def __rsub__(self, other):
        return (-self) + other

    def __mul__(self, other):
        if isinstance(other, Jet):
            a, b = self, other
            outer = a.g[..., :, None] * b.g[..., None, :]
            return Jet(a.v * b.v, a.g * b.v[..., None] + b.g * a.v[..., None],
                       a.H * b.v[..., None, None] + b.H * a.v[..., None, None]
                       + outer + np.swapaxes(outer, -1, -2))
        other = np.asarray(other, dtype=np.float64)
        return Jet(self.v * other, self.g * other[..., None], self.H * other[..., None, None])

    __rmul__ = __mul__

    def sqrt(self) -> Jet:
        s = np.sqrt(self.v)
        d1 = 0.5 / s
        d2 = -0.25 / (s * self.v)
        return Jet(s, self.g * d1[..., None],
                   self.H * d1[..., None, None]
                   + d2[..., None, None] * self.g[..., :, None] * self.g[..., None, :])

    def reciprocal(self) -> Jet:
        r = 1.0 / self.v
        return Jet(r, -self.g * (r * r)[..., None],
                   -self.H * (r * r)[..., None, None]
                   + 2 * (r * r * r)[..., None, None] * self.g[..., :, None] * self.g[..., None, :])


def atan2(s: Jet, c: Jet) -> Jet:
    """The angle atan2(s, c) of two jets, exactly to second order."""
    rho2 = s.v * s.v + c.v * c.v
    fs, fc = c.v / rho2, -s.v / rho2
    fss = -2 * s.v * c.v / (rho2 * rho2)
    fsc = (s.v * s.v - c.v * c.v) / (rho2 * rho2)
    e = (..., None, None)
    gs, gc = s.g[..., :, None], c.g[..., :, None]
    gsT, gcT = s.g[..., None, :], c.g[..., None, :]
    H = (s.H * fs[e] + c.H * fc[e] + fss[e] * (gs * gsT - gc * gcT)
         + fsc[e] * (gs * gcT + gc * gsT))
    return Jet(np.arctan2(s.v, c.v), s.g * fs[..., None] + c.g * fc[..., None], H)


def dot(a, b):
    """Σ_k a_k b_k of two sequences (jets or arrays)."""
    out = a[0] * b[0]
    for x, y in zip(a[1:], b[1:]):
        out = out + x * y
    return out
