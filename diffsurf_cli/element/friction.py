"""Coulomb friction, measured on the smooth surface (issue 23 on a rigid target, issue 33 on a
deformable one).

A contactor x in contact has its gap g, normal ν = ∂g/∂x and proximal point y = x − g ν on the
target's surface (the diffuse surface, its patches or cells, or the facets), and H = ∂²g/∂x²
(the contactor's block of ℳ). Its tangential traction follows the contactor's motion
relative to the target since the last converged state (the history: its proximal point y_n
and tangential residual τ_n), by a penalty-regularised stick and a return mapping onto
Coulomb's cone (Wriggers, Computational Contact Mechanics, §5.2; Laursen and Simo):

    a = τ_n + ε_T r                  the last traction plus the stick spring's stretch r
    T* = P a,  P = I − ν νᵀ          the trial, in the current tangent plane [§4.1.2]
    stick where |T*| <= μ |p|:       T = T*
    slip otherwise:                  T = μ |p| T* / |T*|

with |p| = ε |g| (or an augmented Lagrangian's |min(0, λ_N + ε g)|). T is the tangential
part of the contactor's residual R = ε g ν + T (the force on the contactor is −R, so −T
opposes the slip).

The stretch r. On a rigid target, r = y − y_n: the proximal point's motion on the fixed
surface. On a deformable target the history point must move with the target's material
(a convected description): it rides on the nodes that carried the contactor's element at
the converged state, with the weights φ_j = −𝒩_j·ν / Σ_k(−𝒩_k·ν) of its gap's derivative
(Σ_j 𝒩_j = −ν, the gap being unchanged by a translation of the scene: the weights sum to
one and are, on a flat region, the surface's own shape functions at y_n), offset to y_n:

    A(u) = y_n + Σ_j φ_j^n (x_j − x_j^n)          the anchor, where the history point is now
    r = x − A(u),   ∂r/∂u = [I, −φ_1^n I, ..., −φ_n^n I]

(P r = P (y − A): the same trial as the proximal point's.) The tangential residual acts on
the contactor and, opposite, where the contact is now: T on x, −φ_j T on the nodes of the
element, φ_j from its 𝒩 as above, ρ = [1, −φ_1, ..., −φ_K]; its parts sum to zero (Σ φ_j =
1): the forces balance. On a rigid target (x_j = x_j^n) A = y_n: the same law.

Derivatives, for the consistent tangent (exact, from ℳ; no numerical differentiation), over
the element's unknowns u, with D = ∂ν/∂u (the contactor's rows of ℳ; H on a rigid target):

    ∂T*/∂u = ε_T P ∂r/∂u − (ν·a) D − ν (Dᵀ a)ᵀ
    stick:  ∂T/∂u = ∂T*/∂u
    slip:   ∂T/∂u = t (μ ∂|p|/∂u)ᵀ + μ |p| / |T*| (I − t tᵀ) ∂T*/∂u,  t = T*/|T*|

with ∂r/∂x = P − g H on a rigid target (r = y − y_n, ∂y/∂x = P − g H); on a deformable one
K_T = ρ ⊗ ∂T/∂u − [0, T ⊗ ∂φ_1/∂u, ...] (`reaction_derivative`, from ℳ: φ moves with 𝒩). Not
symmetric in slip. Everything here is per contactor, on numpy arrays.
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

    On a deformable target, also where the history point rides (module docstring), None on
    a rigid one:
    nodes : (m, k) int              the target nodes of each contactor's element, -1 padded
                                    (a row of -1: no element, no history point)
    weights : (m, k) float          their weights φ_j (sum 1 on each row with nodes)
    positions : (m, k, 3) float     those nodes' positions x_j^n at the converged state
    """

    proximal_point: np.ndarray
    traction: np.ndarray
    nodes: np.ndarray | None = None
    weights: np.ndarray | None = None
    positions: np.ndarray | None = None

    def check(self, m: int) -> None:
        for name in ("proximal_point", "traction"):
            value = getattr(self, name)
            if np.shape(value) != (m, 3):
                raise ValueError(f"history.{name}: expected shape ({m}, 3), got "
                                 f"{np.shape(value)}")
        anchored = [getattr(self, name) is not None
                    for name in ("nodes", "weights", "positions")]
        if any(anchored) and not all(anchored):
            raise ValueError("history: nodes, weights and positions go together (a "
                             "deformable target's history), or none of them (a rigid one)")
        if all(anchored):
            k = np.shape(self.nodes)[1] if np.ndim(self.nodes) == 2 else -1
            for name, shape in (("nodes", (m, k)), ("weights", (m, k)),
                                ("positions", (m, k, 3))):
                if np.shape(getattr(self, name)) != shape or k < 0:
                    raise ValueError(f"history.{name}: expected shape "
                                     f"{shape if k >= 0 else (m, 'k')}, got "
                                     f"{np.shape(getattr(self, name))}")

    @property
    def anchored(self) -> bool:
        """Taken on a deformable target: the history point rides on nodes."""
        return self.nodes is not None


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


def cone(normal, stretch, start_traction, known, mu, force, eps_t, second: bool = True,
         d_stretch=None, d_normal=None, d_force=None):
    """Coulomb's law on e contactors (module docstring): the tangential residual T (e, 3),
    its derivative ∂T/∂u (e, 3, w; None without `second`) over w unknowns, and whether each
    sticks.

    normal (e, 3) ν; stretch (e, 3) r; start_traction (e, 3) τ_n (or the multiplier λ);
    known (e,) bool: the contactor has a history point (False: no traction and no stiffness
    from friction this step); mu μ; force (e,) |p|, the cone's radius being μ |p|; eps_t
    (e,) ε_T. With `second`: d_stretch (e, 3, w) ∂r/∂u, d_normal (e, 3, w) D = ∂ν/∂u,
    d_force (e, w) ∂|p|/∂u.
    """
    nu = np.asarray(normal, dtype=np.float64)
    eps_t = np.where(known, eps_t, 0.0)
    a = (np.where(known[:, None], start_traction, 0.0)
         + eps_t[:, None] * np.where(known[:, None], stretch, 0.0))
    na = np.einsum("ei,ei->e", nu, a)
    trial = a - na[:, None] * nu                                         # T* = P a
    size = np.sqrt(np.einsum("ei,ei->e", trial, trial))
    limit = mu * force                                                   # μ |p|
    stick = size <= limit
    scale = np.where(stick, 1.0, limit / np.where(stick, 1.0, size))
    T = scale[:, None] * trial
    if not second:
        return T, None, stick
    D = np.asarray(d_normal, dtype=np.float64)
    P = np.eye(3)[None] - nu[:, :, None] * nu[:, None, :]
    Da = np.einsum("eiw,ei->ew", D, a)                                   # Dᵀ a
    dtrial = (eps_t[:, None, None] * np.einsum("eij,ejw->eiw", P, d_stretch)
              - na[:, None, None] * D - nu[:, :, None] * Da[:, None, :])
    slip = ~stick
    dT = dtrial.copy()
    if slip.any():
        t = trial[slip] / size[slip, None]
        proj = np.eye(3)[None] - t[:, :, None] * t[:, None, :]
        dlimit = mu * np.asarray(d_force, dtype=np.float64)[slip]        # μ ∂|p|/∂u
        dT[slip] = (t[:, :, None] * dlimit[:, None, :]
                    + scale[slip, None, None] * np.einsum("eij,ejw->eiw", proj, dtrial[slip]))
    return T, dT, stick


def coulomb(gap, normal, hessian, proximal_point, start_point, start_traction, mu, eps,
            eps_t, second: bool = True, force=None, dforce=None):
    """The rigid target's law (`cone` with r = y − y_n, ∂r/∂x = P − g H, D = H): the
    tangential residual T (e, 3) of e penetrating contactors, its derivative ∂T/∂x (e, 3, 3;
    None without `second`) and whether each sticks.

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
    stretch = proximal_point - np.where(known[:, None], start_point, proximal_point)
    if force is None:
        force = eps * np.abs(gap)                                        # ε |g|
    if not second:
        return cone(nu, stretch, start_traction, known, mu, force, eps_t, False)
    H = np.asarray(hessian, dtype=np.float64)
    P = np.eye(3)[None] - nu[:, :, None] * nu[:, None, :]
    if dforce is None:
        dforce = (eps * np.sign(gap))[:, None] * nu                      # ∂(ε |g|)/∂x
    return cone(nu, stretch, start_traction, known, mu, force, eps_t, True,
                d_stretch=P - gap[:, None, None] * H, d_normal=H, d_force=dforce)


def anchor_weights(N) -> np.ndarray:
    """(e, k) φ_j = −𝒩_j·ν / Σ_l(−𝒩_l·ν) of each element's k target nodes (module
    docstring), from its 𝒩 (e, 3(k+1)) over u = [x^c, x^1, ..., x^k] (padding: 𝒩_j = 0, so
    φ_j = 0). A row whose sum vanishes (no target node moves its gap) gets NaN."""
    N = np.asarray(N, dtype=np.float64)
    nu = N[:, :3]
    raw = -np.einsum("ekj,ej->ek", N[:, 3:].reshape(len(N), N.shape[1] // 3 - 1, 3), nu)
    total = raw.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return raw / np.where(total != 0.0, total, np.nan)[:, None]


def anchors(history, contactor, target_points):
    """Where each element's history point is now, on a deformable target: (nodes (e, k)
    of the anchor, -1 padded; weights (e, k); A (e, 3) = y_n + Σ φ_j^n (x_j − x_j^n), NaN where
    the contactor has no history point), for elements of contactors `contactor` (e,), with
    the target's nodes now at `target_points` (n, 3)."""
    e = len(contactor)
    if history is None:
        return np.full((e, 0), -1, np.int64), np.zeros((e, 0)), np.full((e, 3), np.nan)
    nodes = np.asarray(history.nodes, dtype=np.int64)[contactor]
    weights = np.asarray(history.weights, dtype=np.float64)[contactor]
    then = np.asarray(history.positions, dtype=np.float64)[contactor]
    y_n = np.asarray(history.proximal_point, dtype=np.float64)[contactor]
    on = nodes >= 0
    if (nodes >= len(target_points)).any():
        raise ValueError(f"history.nodes: node {int(nodes.max())} is not a target node (the "
                         f"target has {len(target_points)})")
    now = np.asarray(target_points, dtype=np.float64)[np.maximum(nodes, 0)]
    moved = np.where(on[:, :, None], now - then, 0.0)
    point = y_n + np.einsum("ek,eki->ei", np.where(on, weights, 0.0), moved)
    point[~on.any(axis=1) | ~np.isfinite(point).all(axis=1)] = np.nan
    return np.where(on, nodes, -1), np.where(on, weights, 0.0), point


@dataclass
class Anchor:
    """A deformable target's friction data on a `Contact`'s e elements (module docstring).

    nodes : (e, k) int            the target nodes the history point rides on, -1 padded
    weights : (e, k) float        their weights φ_j
    point : (e, 3) float          A, where the history point is now (NaN: none)
    target_points : (n, 3) float  the target's nodes now (the next history's x_j^n)
    """

    nodes: np.ndarray
    weights: np.ndarray
    point: np.ndarray
    target_points: np.ndarray


def reaction_derivative(N, M) -> np.ndarray:
    """(e, k, 3(k+1)) ∂φ_j/∂u of the weights φ_j = q_j / S (`anchor_weights`) of e elements
    over u = [x^c, x^1, ..., x^k], from their 𝒩 (e, w) and ℳ (e, w, w): q_j = −𝒩_j·ν,
    ∂q_j/∂u = −(ℳ_jᵀ ν + Dᵀ 𝒩_j) (ℳ_j the rows of node j, D those of the contactor: ∂ν/∂u),
    S = Σ_l q_l, ∂φ_j = (∂q_j − φ_j ∂S) / S."""
    N = np.asarray(N, dtype=np.float64)
    M = np.asarray(M, dtype=np.float64)
    e, w = N.shape
    nu = N[:, :3]
    Nj = N[:, 3:].reshape(e, w // 3 - 1, 3)
    Mj = M[:, 3:, :].reshape(e, Nj.shape[1], 3, w)
    dq = -(np.einsum("ejiw,ei->ejw", Mj, nu) + np.einsum("eiw,eji->ejw", M[:, :3, :], Nj))
    q = -np.einsum("eji,ei->ej", Nj, nu)
    S = q.sum(axis=1)
    phi = q / S[:, None]
    return (dq - phi[:, :, None] * dq.sum(axis=1)[:, None, :]) / S[:, None, None]
