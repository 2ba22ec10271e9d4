"""Coulomb friction on a rigid target, measured on the smooth surface (issue 23).

A contactor x in contact with a rigid target has its gap g, normal ν = ∂g/∂x and proximal
point y = x − g ν on the target's surface (the diffuse surface of `element.rigid`, or the
facets), and H = ∂²g/∂x² (`Contact.M`). Its tangential traction follows the proximal point's
motion on that surface since the last converged state (the history: its proximal point y_n and
tangential residual τ_n), by a penalty-regularised stick and a return mapping onto Coulomb's
cone (Wriggers, Computational Contact Mechanics, §5.2; Laursen and Simo):

    a = τ_n + ε_T (y − y_n)          the last traction plus the stick spring's stretch
    T* = P a,  P = I − ν νᵀ          the trial, in the current tangent plane [§4.1.2]
    stick where |T*| <= μ ε |g|:     T = T*
    slip otherwise:                  T = μ ε |g| T* / |T*|

T is the tangential part of the contactor's residual R = ε g ν + T (the energy's gradient, as
the normal part: the force on the contactor is −R, so −T opposes the slip). Its derivative, for
the consistent tangent (exact, from the surface's curvature through H; no numerical
differentiation), with ∂y/∂x = P − g H (y = x − g ν):

    ∂T*/∂x = ε_T P (P − g H) − (ν·a) H − ν (H a)ᵀ
    stick:  ∂T/∂x = ∂T*/∂x
    slip:   ∂T/∂x = −μ ε t νᵀ (sign of g < 0) + μ ε |g| / |T*| (I − t tᵀ) ∂T*/∂x,  t = T*/|T*|

which is not symmetric in slip. Everything here is per contactor, on numpy arrays.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Coulomb:
    """Coulomb's law with a penalty-regularised stick.

    mu : float
        The friction coefficient μ >= 0.
    penalty_t : float, (m,) float or None
        ε_T, the stick's tangential penalty (one, or one per contactor, in the normal
        penalty's units: force per length); None: the normal penalty ε itself.
    """

    mu: float
    penalty_t: object = None

    def __post_init__(self):
        if not (np.isfinite(self.mu) and self.mu >= 0):
            raise ValueError(f"Coulomb: mu must be a finite number >= 0, got {self.mu!r}")
        if self.penalty_t is not None:
            eps_t = np.asarray(self.penalty_t, dtype=np.float64)
            if not np.all(np.isfinite(eps_t) & (eps_t > 0)):
                raise ValueError("Coulomb: penalty_t must be positive and finite")


@dataclass
class History:
    """The last converged state of every contactor (m rows), what a step's friction starts
    from; `Contact.history` after a converged call, None before the first one.

    proximal_point : (m, 3) float   y_n, the proximal point (NaN: the contactor had none)
    traction : (m, 3) float         τ_n, the tangential part of its residual (0: none)
    """

    proximal_point: np.ndarray
    traction: np.ndarray

    def check(self, m: int) -> None:
        for name in ("proximal_point", "traction"):
            value = getattr(self, name)
            if np.shape(value) != (m, 3):
                raise ValueError(f"history.{name}: expected shape ({m}, 3), got "
                                 f"{np.shape(value)}")


@dataclass
class Tractions:
    """What friction gives each contactor (m rows), as forces on the contactor (−R).

    normal : (m,) float        ε |g| where it penetrates (an element), 0 elsewhere; with
                               multipliers, −p = −min(0, λ + ε g) of each element
    tangential : (m, 3) float  −T, in the tangent plane, opposing the slip; 0 elsewhere
    stick : (m,) bool          True where an element sticks (|T| below μ times the normal)
    """

    normal: np.ndarray
    tangential: np.ndarray
    stick: np.ndarray


def coulomb(gap, normal, hessian, proximal_point, start_point, start_traction, mu, eps,
            eps_t, second: bool = True, force=None, dforce=None):
    """The tangential residual T (e, 3) of e penetrating contactors, its derivative ∂T/∂x
    (e, 3, 3; None without `second`) and whether each sticks (module docstring).

    gap (e,) < 0, normal (e, 3) ν, hessian (e, 3, 3) H = ∂²g/∂x², proximal_point (e, 3) y;
    start_point (e, 3) y_n and start_traction (e, 3) τ_n (the history); eps, eps_t (e,) the
    normal and tangential penalties. A contactor whose y_n is NaN (no converged state) has no
    traction and no stiffness from friction this step.

    force (e,), dforce (e, 3): the normal force's magnitude |p| and its gradient ∂|p|/∂x, the
    cone's radius being μ |p| (an augmented Lagrangian's p = min(0, λ_N + ε g), `Contact`);
    None: the penalty's ε |g| and ε sign(g) ν. With an augmented Lagrangian, start_traction
    is the tangential multiplier λ (its normal part is dropped by P).
    """
    gap = np.asarray(gap, dtype=np.float64)
    nu = np.asarray(normal, dtype=np.float64)
    known = np.all(np.isfinite(start_point), axis=1)
    y_n = np.where(known[:, None], start_point, proximal_point)
    tau_n = np.where(known[:, None], start_traction, 0.0)
    eps_t = np.where(known, eps_t, 0.0)
    a = tau_n + eps_t[:, None] * (proximal_point - y_n)
    na = np.einsum("ei,ei->e", nu, a)
    trial = a - na[:, None] * nu                                         # T* = P a
    size = np.sqrt(np.einsum("ei,ei->e", trial, trial))
    if force is None:
        force = eps * np.abs(gap)                                        # ε |g|
    limit = mu * force                                                   # μ |p|
    stick = size <= limit
    scale = np.where(stick, 1.0, limit / np.where(stick, 1.0, size))
    T = scale[:, None] * trial
    if not second:
        return T, None, stick
    H = np.asarray(hessian, dtype=np.float64)
    P = np.eye(3)[None] - nu[:, :, None] * nu[:, None, :]
    dy = P - gap[:, None, None] * H                                      # ∂y/∂x
    Ha = np.einsum("eij,ej->ei", H, a)
    dtrial = (eps_t[:, None, None] * np.einsum("eij,ejk->eik", P, dy)
              - na[:, None, None] * H - nu[:, :, None] * Ha[:, None, :])
    slip = ~stick
    dT = dtrial.copy()
    if slip.any():
        t = trial[slip] / size[slip, None]
        proj = np.eye(3)[None] - t[:, :, None] * t[:, None, :]
        if dforce is None:
            dlimit = (mu * eps[slip] * np.sign(gap[slip]))[:, None] * nu[slip]  # ∂(μ ε |g|)/∂x
        else:
            dlimit = mu * np.asarray(dforce, dtype=np.float64)[slip]        # ∂(μ |p|)/∂x
        dT[slip] = (t[:, :, None] * dlimit[:, None, :]
                    + scale[slip, None, None] * np.einsum("eij,ejk->eik", proj, dtrial[slip]))
    return T, dT, stick
