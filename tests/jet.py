"""Second-order forward-mode automatic differentiation ("jets") for the contact element.

A `Jet` carries, for an array of scalars, their values, gradients and Hessians with respect to
m independent variables: ``val`` (S), ``grad`` (S + (m,)), ``hess`` (S + (m, m)). Arithmetic
follows the chain rule exactly, so derivatives are exact to round-off (no step size), which is
what the paper's 𝒩 and ℳ [42]-[53] need; finite differences only verify them (Taylor tests).
"""
from __future__ import annotations

import numpy as np


class Jet:
    __slots__ = ("val", "grad", "hess")
    __array_priority__ = 100  # so ndarray * Jet defers to Jet.__rmul__

    def __init__(self, val, grad, hess):
        self.val, self.grad, self.hess = val, grad, hess

    @classmethod
    def variables(cls, values) -> Jet:
        """Independent variables: a flat vector of m values with identity gradients."""
        values = np.asarray(values, dtype=np.float64).ravel()
        m = len(values)
        return cls(values, np.eye(m), np.zeros((m, m, m)))

    @classmethod
    def constant(cls, values, m: int) -> Jet:
        values = np.asarray(values, dtype=np.float64)
        return cls(values, np.zeros(values.shape + (m,)), np.zeros(values.shape + (m, m)))

    @property
    def shape(self):
        return self.val.shape

    @property
    def nvars(self) -> int:
        return self.grad.shape[-1]

    def __getitem__(self, key):
        if not isinstance(key, tuple):
            key = (key,)
        return Jet(self.val[key], self.grad[key + (Ellipsis,)] if Ellipsis not in key
                   else self.grad[key], self.hess[key + (Ellipsis,)])

    def _lift(self, other):
        if isinstance(other, Jet):
            return other
        other = np.asarray(other, dtype=np.float64)
        return Jet(other, np.zeros(other.shape + (self.nvars,)),
                   np.zeros(other.shape + (self.nvars, self.nvars)))

    # -- arithmetic -----------------------------------------------------------------------
    def __add__(self, other):
        if not isinstance(other, Jet):
            other = np.asarray(other, dtype=np.float64)
            val = self.val + other
            return Jet(val, np.broadcast_to(self.grad, val.shape + self.grad.shape[-1:]).copy(),
                       np.broadcast_to(self.hess, val.shape + self.hess.shape[-2:]).copy())
        return Jet(self.val + other.val, self.grad + other.grad, self.hess + other.hess)

    __radd__ = __add__

    def __neg__(self):
        return Jet(-self.val, -self.grad, -self.hess)

    def __sub__(self, other):
        return self + (-other)

    def __rsub__(self, other):
        return (-self) + other

    def __mul__(self, other):
        if not isinstance(other, Jet):
            c = np.asarray(other, dtype=np.float64)
            return Jet(self.val * c, self.grad * c[..., None], self.hess * c[..., None, None])
        a, b = self, other
        gg = a.grad[..., :, None] * b.grad[..., None, :]
        return Jet(a.val * b.val,
                   a.val[..., None] * b.grad + b.val[..., None] * a.grad,
                   a.val[..., None, None] * b.hess + b.val[..., None, None] * a.hess
                   + gg + np.swapaxes(gg, -1, -2))

    __rmul__ = __mul__

    def apply(self, f, f1, f2) -> Jet:
        """g(self) given g's value f, first derivative f1 and second f2 at self.val."""
        f, f1, f2 = (np.asarray(x, dtype=np.float64) for x in (f, f1, f2))
        return Jet(f, f1[..., None] * self.grad,
                   f1[..., None, None] * self.hess
                   + f2[..., None, None] * self.grad[..., :, None] * self.grad[..., None, :])

    def reciprocal(self) -> Jet:
        v = self.val
        return self.apply(1.0 / v, -1.0 / v**2, 2.0 / v**3)

    def __truediv__(self, other):
        if not isinstance(other, Jet):
            return self * (1.0 / np.asarray(other, dtype=np.float64))
        return self * other.reciprocal()

    def __rtruediv__(self, other):
        return self.reciprocal() * other

    def sqrt(self) -> Jet:
        r = np.sqrt(self.val)
        return self.apply(r, 0.5 / r, -0.25 / (r * self.val))

    def sum(self, axis: int = 0) -> Jet:
        axis = axis % self.val.ndim
        return Jet(self.val.sum(axis), self.grad.sum(axis), self.hess.sum(axis))


def stack(jets, axis: int = 0) -> Jet:
    """Stack jets of equal shape along a new value axis."""
    nd = jets[0].val.ndim + 1
    axis = axis % nd
    return Jet(np.stack([j.val for j in jets], axis),
               np.stack([j.grad for j in jets], axis),
               np.stack([j.hess for j in jets], axis))


def dot(a: Jet, b: Jet) -> Jet:
    """Σ_i a_i b_i over the last value axis."""
    return (a * b).sum(-1)


def matvec(A: Jet, x: Jet) -> Jet:
    """A @ x for jets A (k, k) and x (k,)."""
    return (A * Jet(x.val[None, :], x.grad[None], x.hess[None])).sum(-1)


def solve(A: Jet, b: Jet) -> Jet:
    """x = A⁻¹ b with exact first and second derivatives.

    From A x = b: ∂x = A⁻¹(∂b - ∂A x) and
    ∂²x = A⁻¹(∂²b - ∂²A x - ∂A ∂x - (∂A ∂x)ᵀ), the transpose over the two variable slots.
    This is the ∂α of the paper's [41], which it leaves out.
    """
    A0inv = np.linalg.inv(A.val)
    x = A0inv @ b.val
    dAx = np.einsum("ijp,j->ip", A.grad, x)
    dx = A0inv @ (b.grad - dAx)
    dAdx = np.einsum("ijp,jq->ipq", A.grad, dx)
    rhs = b.hess - np.einsum("ijpq,j->ipq", A.hess, x) - dAdx - np.swapaxes(dAdx, -1, -2)
    ddx = np.einsum("ij,jpq->ipq", A0inv, rhs)
    return Jet(x, dx, ddx)
