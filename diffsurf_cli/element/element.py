"""The contact element: gap, 𝒩 = ∂g/∂u and ℳ = ∂²g/∂u², residual and tangent [§4.2-4.3], [§2].

Unknowns of one element are u = [x^c, x^1, ..., x^n] [22] (3(n+1) numbers): the contactor and
the nodes its gap depends on (the support of its local approximation for the diffuse element,
the facet's nodes for node-to-facet). With the penalty method [3], the residual and tangent are
R = ε g 𝒩 [45] and K = ε (g ℳ + 𝒩 𝒩ᵀ) [54], the gradient and Hessian of ε g²/2.

Both elements are written once, generically: a surface point x(X, u) with in-plane parameters X
and unit normal ν(X, u); the proximal point X̄(u) is stationary for D = ½‖x^c - x‖² ([30], or
the facet's closest point [1]); the gap is G(X̄, u) with G = (x^c - x)·ν [32]. Then, because
∂G/∂X = 0 at X̄ (x^c - x^d is parallel to ν and ⊥ τ_k),

    𝒩 = ∂G/∂u                                   (the paper's [42]-[44]: no ∂X̄ needed)
    ℳ = ∂²G/∂u² + ∂²G/∂u∂X · ∂X̄/∂u,  ∂X̄/∂u = -(∂²D/∂X²)⁻¹ ∂²D/∂X∂u   (implicit function theorem)

which gathers the paper's 𝒮_l, 𝒯_l, 𝒰 and 𝒟_τ terms [48]-[53]. The diffuse element is
computed by the compiled engine (`diffuse.diffuse_elements`), the node-to-facet one by the
same engine (`facet.facet_elements`), both with analytic derivatives; their jet-based
(forward-mode automatic differentiation) oracles are in tests/oracle_element.py. The frame,
the support set and the radius R are held fixed, as in the paper.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..facet.surface import FacetSurface
from ..mls.quadric import QuadricSurface
from ..mls.surface import DiffuseSurface
from ..patches.segment import FEATURE_ANGLE_DEG, creases, edge_table, node_identity
from ..patches.surface import CELLS, FACETS, PatchedSurface
from ..projection import (
    BAD_POINT,
    CONTACT,
    FAILED,
    GUARD,
    ILL_CONDITIONED,
    NO_CONVERGENCE,
    OFF_TARGET,
    OPEN,
    OUTSIDE,
    PENETRATION,
    Pairing,
    Patch,
    Projection,
    allocate,
    as_points,
    mark_far,
    recorded,
)
from . import _assembly, blocks
from .blocks import Hessians
from .cell import cell_part, frozen_part
from .diffuse import diffuse_elements, diffuse_tangent
from .facet import facet_element  # noqa: F401  (the one-element API)
from .facet import facet_elements as facet_elements_kernel
from .friction import (
    Anchor,
    History,
    Tractions,
    anchor_weights,
    anchors,
    cone,
    coulomb,
    reaction_derivative,
)
from .penalty import check_penalty
from .quadric import quadric_elements
from .rigid import RigidTarget

# --------------------------------------------------------------------------------------------
# The API for FE codes: `contact` returns a `Contact` of per-element arrays (contactor, nodes,
# gap, N, M) and per-contactor statuses; `Contact.residual` / `Contact.tangent` assemble them
# at the caller's DOFs with a per-contactor penalty; `assemble` does it chunk by chunk for big
# clouds. The batched diffuse element is `diffuse.diffuse_elements`, the rigid-target one
# `rigid.RigidTarget`.
# --------------------------------------------------------------------------------------------


def facet_elements(surface, points, proj, rows, second=True, rigid_target=False):
    """The node-to-facet elements of the contactors `rows` as padded arrays [§2], computed by
    the compiled engine (`facet.facet_elements`).

    u = [x^c, x^corners...] with 4 corners (a triangle's 4th is -1 and its block of 𝒩, ℳ is
    zero). With `rigid_target`, only the contactor's block: N[:3] and M[:3, :3].

    Returns gap (e,), nodes (e, 4) or (e, 0), N (e, 15) or (e, 3), M or None.
    """
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    corners = surface.facets[proj.facet[rows]]
    d = points[rows] - proj.proximal_point[rows]
    side = np.where(np.einsum("ij,ij->i", d, proj.normal[rows]) >= 0, 1.0, -1.0)
    gap, N, M = facet_elements_kernel(surface.nodes, corners, points[rows], proj.param[rows],
                                      side, surface.sign, second)
    if rigid_target:
        N = np.ascontiguousarray(N[:, :3])
        M = None if M is None else np.ascontiguousarray(M[:, :3, :3])
        return gap, np.zeros((len(rows), 0), np.int64), N, M
    return gap, corners.astype(np.int64), N, M


@dataclass
class Element:
    """One contact element (a view of one row of `Contact`'s arrays, padding removed).

    contactor : int          index of the contactor x^c
    nodes : (n,) int         target node indices in u = [x^c, x^nodes[0], ...] order (n = 0
                             for a rigid target)
    gap : float              g [32]
    N : (3(n+1),) float      ∂g/∂u (the paper's 𝒩 [42])
    M : (3(n+1), 3(n+1)) float or None   ∂²g/∂u² (the paper's ℳ [53]), when asked for
    """

    contactor: int
    nodes: np.ndarray
    gap: float
    N: np.ndarray
    M: np.ndarray | None

    def residual(self, penalty: float) -> np.ndarray:
        """R = ε g 𝒩 [45]."""
        return float(check_penalty(penalty)) * self.gap * self.N

    def tangent(self, penalty: float, *, gauss_newton: bool = False) -> np.ndarray:
        """K = ε (g ℳ + 𝒩 𝒩ᵀ) [54]; with `gauss_newton`, ε 𝒩 𝒩ᵀ (no ℳ)."""
        penalty = float(check_penalty(penalty))
        if gauss_newton:
            return penalty * np.outer(self.N, self.N)
        return penalty * (self.gap * self.M + np.outer(self.N, self.N))


@dataclass
class Contact:
    """The contact elements of a scene, as arrays, and their assembly.

    One element per closed contact (g <= 0: status penetration, or contact within its
    tolerance at or below zero), in contactor order; K is the
    widest element's number of target nodes (0 with a rigid target). With `contact(near=d)`
    (an augmented Lagrangian's), also one per contactor answered open or in contact with
    g < d: its normal force p = min(0, λ + ε g) may be nonzero (`residual`).

    contactor : (e,) int            the element's contactor (row of `points`)
    nodes : (e, K) int              target node indices of u = [x^c, x^nodes...], -1 padded
    gap : (e,) float                g [32]
    N : (e, 3(K+1)) float           𝒩 = ∂g/∂u [42]-[44], zero on the padding
    M : (e, 3(K+1), 3(K+1)) float   ℳ = ∂²g/∂u² [53], or None (contact(..., second=False));
                                    beyond `blocks.HESSIAN_BYTES`, a `Hessians` that builds it a
                                    block at a time (`tangent` then never holds it whole;
                                    np.asarray(c.M) does)
    projection : Projection         gap, normal, proximal point, status, reason of every
                                    contactor (with `patch` or `facet`: its pairing)
    n_target : int                  the number of target nodes (rows of `target_dofs`)
    rigid_target : bool             elements of the contactors only (K = 0)
    lost : (k,) int                 contactors with no answer (outside or failed, not a NaN
                                    contactor) that may be penetrating: the target's facets
                                    find them penetrating (every unanswered one, on a target
                                    without facets). A solver must not take them for open.
    friction : Coulomb or None      Coulomb friction (`element.friction`): `residual` and
                                    `tangent` then hold its tangential part
    start : History or None         the state friction starts from (`contact(history=)`)
    anchor : Anchor or None         friction on a deformable target: where each element's
                                    history point is now, on which target nodes it rides
                                    (`friction.Anchor`); None on a rigid target

    `status` and `reason` (m,) are the projection's: a contactor has an element exactly when
    it penetrates or touches, g <= 0 (status penetration, or contact with g <= 0: at g = 0
    its force is 0 and its stiffness ε 𝒩𝒩ᵀ, what a flat start needs), or, with `near`, it
    is open or in contact within it; open ones (g > 0) need none under the penalty;
    outside and failed ones have none, and `reason` says why (docs/solver.md, "Statuses and
    what to do with each").
    """

    contactor: np.ndarray
    nodes: np.ndarray
    gap: np.ndarray
    N: np.ndarray
    M: np.ndarray | None
    projection: object
    n_target: int
    rigid_target: bool = False
    lost: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    friction: object = None
    start: object = None
    anchor: object = None
    _penalty_used: object = field(default=None, init=False, repr=False)
    _multipliers_used: object = field(default=None, init=False, repr=False)
    _convected: object = field(default=None, init=False, repr=False)

    @property
    def status(self) -> np.ndarray:
        return self.projection.status

    @property
    def reason(self) -> np.ndarray:
        return self.projection.reason

    @property
    def pairing(self):
        """What the elements hold fixed (`projection.Pairing`), to pass back as
        `contact(..., pairing=...)` within a step, on any surface; None for a rigid target
        (its gap needs none)."""
        return self.projection.pairing

    def __len__(self) -> int:
        return len(self.contactor)

    def __getitem__(self, k: int) -> Element:
        keep = self.nodes[k] >= 0
        block = np.repeat(np.concatenate([[True], keep]), 3)
        M = None if self.M is None else self.M[k][np.ix_(block, block)]
        return Element(int(self.contactor[k]), self.nodes[k][keep], float(self.gap[k]),
                       self.N[k][block], M)

    def __iter__(self):
        return (self[k] for k in range(len(self)))

    @property
    def elements(self) -> list:
        """Every element as an `Element` record (padding removed)."""
        return list(self)

    # ---------------------------------------------------------------------------- assembly

    def _penalty(self, penalty) -> np.ndarray:
        """ε of each element, from a scalar or one value per contactor (each finite, > 0)."""
        penalty = check_penalty(penalty)
        if penalty.ndim == 0:
            return np.full(len(self), float(penalty))
        if penalty.shape != self.status.shape:
            raise ValueError(f"penalty: expected a number or one per contactor "
                             f"({len(self.status)},), got shape {penalty.shape}")
        return penalty[self.contactor]

    def dofs(self, contactor_dofs, target_dofs=None) -> np.ndarray:
        """Global DOFs (e, 3(K+1)) of each element's unknowns u; -1 = no DOF (a fixed or rigid
        node, a padding node, or every target node when `target_dofs` is None)."""
        return self._dofs_of(self.nodes, contactor_dofs, target_dofs)

    @staticmethod
    def _size(n_dofs, contactor_dofs, target_dofs) -> int:
        top = int(np.max(contactor_dofs, initial=-1))
        if target_dofs is not None:
            top = max(top, int(np.max(target_dofs, initial=-1)))
        if n_dofs is None:
            return top + 1
        if top >= n_dofs:
            raise ValueError(f"n_dofs = {n_dofs}, but the DOF map holds DOF {top}")
        return int(n_dofs)

    def residual(self, penalty, contactor_dofs, target_dofs=None, n_dofs=None, *,
                 multipliers=None) -> np.ndarray:
        """Assembled residual Σ p 𝒩 over the elements, at the caller's DOFs, with each
        element's normal force p = min(0, λ + ε g) (the penalty's ε g [45] without
        multipliers); with friction, plus each contactor's tangential part T
        (`element.friction`).

        Parameters
        ----------
        penalty : float or (m,) float
            ε, one for all or one per contactor.
        contactor_dofs : (m, 3) int
            Global DOF of each contactor's x, y, z; -1: none (fixed: its rows are dropped).
        target_dofs : (n_target, 3) int, optional
            The same for the target nodes; None: the target has no DOF (rigid or fixed).
        n_dofs : int, optional
            Length of the vector; the largest DOF + 1 by default.
        multipliers : (m,) float or (m, 3) float, optional
            An augmented Lagrangian's multipliers λ of the last augmentation (`multipliers`;
            docs/solver.md): one per contactor, <= 0 (0: none); with friction, a traction
            vector per contactor, λ_N = λ·ν its normal part and λ the tangential trial's
            start in place of the history's τ_n. None: the penalty alone.

        Returns
        -------
        (n_dofs,) float
        """
        out = np.zeros(self._size(n_dofs, contactor_dofs, target_dofs))
        self._add_residual(out, penalty, contactor_dofs, target_dofs, multipliers)
        return out

    def _add_residual(self, out: np.ndarray, penalty, contactor_dofs, target_dofs,
                      multipliers=None) -> None:
        _, p, _ = self._normal(penalty, multipliers)
        vals = p[:, None] * self.N
        if self.friction is not None:
            T = self._tangential(penalty, second=False, multipliers=multipliers)[0]
            if self.anchor is None:  # a rigid target: the contactor's block only
                vals[:, :3] += T
            else:  # on the contactor, and opposite at the proximal point (`_reaction`)
                vals += (self._reaction()[:, :, None] * T[:, None, :]).reshape(vals.shape)
        _scatter_add(out, self, contactor_dofs, target_dofs, vals)

    def _reaction(self) -> np.ndarray:
        """(e, 1 + K) the tangential residual's weights on a deformable target: R_T = T on
        the contactor and −φ_j T on the element's target nodes, φ_j = −𝒩_j·ν / Σ(−𝒩_l·ν)
        (`friction.anchor_weights`), the proximal point's share: the target's reaction acts
        where the contact is, and Σ R_T = 0 (the forces balance)."""
        return np.concatenate([np.ones((len(self), 1)),
                               -np.nan_to_num(anchor_weights(self.N))], axis=1)

    def _hessians_of(self, idx) -> np.ndarray:
        """ℳ (k, w, w) of elements `idx`, built now where it is built on demand."""
        if isinstance(self.M, Hessians):
            return self.M.take(idx, out=np.empty((len(idx),) + self.N.shape[1:] * 2))
        return np.asarray(self.M[idx], dtype=np.float64)

    def _convected_nodes(self):
        """(nodes (e, K + k), B (e, 1 + K + k)) on a deformable target with friction: the
        element's target nodes, then the anchor's that are not among them (-1 where they
        are), and B = ∂r/∂u's weights per node of u = [x^c, nodes]: 1 on the contactor, −φ_j
        on the anchor's nodes (`friction` module docstring)."""
        if self._convected is None:
            a, K, e = self.anchor, self.nodes.shape[1], len(self)
            on = a.nodes >= 0
            same = on[:, :, None] & (a.nodes[:, :, None] == self.nodes[:, None, :])
            extra = on & ~same.any(axis=2)
            # the extra nodes first in each row, as many columns as the most any row has
            first = np.argsort(~extra, axis=1, kind="stable")
            k = int(extra.sum(axis=1).max(initial=0))
            extra, first = np.take_along_axis(extra, first, 1)[:, :k], first[:, :k]
            B = np.zeros((e, 1 + K + k))
            B[:, 0] = 1.0
            B[:, 1:1 + K] = -np.einsum("ek,ekj->ej", a.weights, same)
            B[:, 1 + K:] = -np.where(extra, np.take_along_axis(a.weights, first, 1), 0.0)
            nodes = np.concatenate(
                [self.nodes, np.where(extra, np.take_along_axis(a.nodes, first, 1), -1)], axis=1)
            self._convected = (nodes, B)
        return self._convected

    def _dofs_of(self, nodes, contactor_dofs, target_dofs) -> np.ndarray:
        """(e, 3(1 + k)) global DOFs of u = [x^c, nodes (e, k)], as `dofs`."""
        return _element_dofs(self.contactor, nodes, len(self.status), self.n_target,
                             contactor_dofs, target_dofs)

    # ---------------------------------------------------------------- augmented Lagrangian

    def _multipliers_of(self, multipliers):
        """The multipliers, checked: None, (m,) <= 0, or (m, 3) with friction."""
        if multipliers is None:
            return None
        lam = np.asarray(multipliers, dtype=np.float64)
        m = len(self.status)
        if self.friction is not None and lam.shape != (m, 3):
            raise ValueError(f"multipliers: with friction, expected a traction vector per "
                             f"contactor ({m}, 3), got shape {lam.shape}")
        if self.friction is None and lam.shape != (m,):
            raise ValueError(f"multipliers: expected one per contactor ({m},), got shape "
                             f"{lam.shape}")
        if not np.isfinite(lam).all():
            raise ValueError("multipliers must be finite")
        if self.friction is None and (lam > 0).any():
            raise ValueError("multipliers must be <= 0 (a contact force pushes, it never "
                             "pulls)")
        return lam

    def _normal(self, penalty, multipliers):
        """(ε, p, λ) of the elements: p = min(0, λ_N + ε g), the normal force (< 0 where the
        element is active), and λ (e, 3) the multiplier vectors with friction (else None).
        Refuses (ValueError) multipliers that give a force to a contactor answered open or in
        contact that has no element (the contact was built with too small a `near`)."""
        eps = self._penalty(penalty)
        lam = self._multipliers_of(multipliers)
        if lam is None:
            return eps, np.minimum(0.0 + eps * self.gap, 0.0), None
        proj = self.projection
        answered = (self.status == OPEN) | (self.status == CONTACT)
        answered[self.contactor] = False
        if answered.any():
            every = np.broadcast_to(check_penalty(penalty), self.status.shape)
            lam_n = (lam if lam.ndim == 1
                     else np.einsum("mi,mi->m", lam, np.asarray(proj.normal, np.float64)))
            force = lam_n + every * np.nan_to_num(np.asarray(proj.gap, np.float64),
                                                  nan=np.inf)
            missing = np.flatnonzero(answered & (force < 0))
            if len(missing):
                raise ValueError(f"multipliers: {len(missing)} contactors without an element "
                                 f"carry a force (λ + ε g < 0), e.g. contactor {missing[0]}: "
                                 f"build the contact with near=Contact.reach(penalty, "
                                 f"multipliers)")
        own = lam[self.contactor]
        if lam.ndim == 1:
            return eps, np.minimum(own + eps * self.gap, 0.0), None
        lam_n = np.einsum("ei,ei->e", own, self.N[:, :3])  # λ·ν: 𝒩's contactor block is ν
        return eps, np.minimum(lam_n + eps * self.gap, 0.0), own

    @staticmethod
    def reach(penalty, multipliers) -> float:
        """The `near` of `contact(..., near=)` that gives an element to every contactor that
        can carry a force with these multipliers: max over contactors of -λ_N / ε (|λ| / ε
        for traction vectors, with friction), where λ_N + ε g < 0 needs g < -λ_N / ε."""
        lam = np.asarray(multipliers, dtype=np.float64)
        eps = np.asarray(check_penalty(penalty), dtype=np.float64)
        size = -lam if lam.ndim == 1 else np.linalg.norm(lam.reshape(len(lam), -1), axis=1)
        if eps.ndim and eps.shape != size.shape:
            raise ValueError(f"penalty: expected a number or one per contactor "
                             f"({len(size)},), got shape {eps.shape}")
        return float(np.max(np.maximum(size / eps, 0.0), initial=0.0))

    def multipliers(self, penalty, multipliers=None) -> np.ndarray:
        """The next augmentation's multipliers (Uzawa, after Alart-Curnier): λ ← min(0, λ +
        ε g) = p on every contactor with an element, 0 elsewhere (no element: no force);
        with friction, the traction vector p ν + T (the contactor's block of R: its normal
        part p and its tangential part T, the trial projected on Coulomb's cone). Call it at
        positions where Newton converged with these `multipliers` (None: the penalty's
        first solve). Shape (m,), or (m, 3) with friction."""
        _, p, _ = self._normal(penalty, multipliers)
        m = len(self.status)
        if self.friction is None:
            out = np.zeros(m)
            out[self.contactor] = p
            return out
        T = self._tangential(penalty, second=False, multipliers=multipliers)[0]
        out = np.zeros((m, 3))
        out[self.contactor] = p[:, None] * self.N[:, :3] + T
        return out

    # ---------------------------------------------------------------------------- friction

    def _tangential(self, penalty, second: bool = True, curvature: bool = True,
                    multipliers=None):
        """(T (e, 3), ∂T/∂x (e, 3, 3) or None, stick (e,)) of the elements under `friction`
        (`friction.coulomb`), with the normal penalty `penalty`; without `curvature` (the
        Gauss-Newton tangent), ∂T/∂x with H = 0. With `multipliers`, the cone's radius is
        μ |p| and the trial starts from the multiplier λ instead of the history's τ_n; an
        inactive element (p = 0) has no friction. On a deformable target, ∂T/∂u (e, 3,
        3(1 + K + k)) over u = [x^c, `_convected_nodes`] (`_convected_law`)."""
        eps, p, lam, eps_t = self._friction_terms(penalty, multipliers)
        if self.anchor is not None:
            D = self._normal_derivative() if second and curvature else None
            return self._convected_law((eps, p, lam, eps_t), second, np.arange(len(self)), D)
        if self.start is None:
            y_n, tau_n = np.full((len(self), 3), np.nan), np.zeros((len(self), 3))
        else:
            y_n = np.asarray(self.start.proximal_point, np.float64)[self.contactor]
            tau_n = np.asarray(self.start.traction, np.float64)[self.contactor]
        y = np.asarray(self.projection.proximal_point, np.float64)[self.contactor]
        H = None
        if second:
            H = np.asarray(self.M) if curvature else np.zeros((len(self), 3, 3))
        if lam is None:
            return coulomb(self.gap, self.N, H, y, y_n, tau_n, float(self.friction.mu), eps,
                           eps_t, second)
        active = p < 0
        dforce = None
        if second:  # ∂|p|/∂x = −(ε ν + H λ) where active: λ_N = λ·ν moves with ν
            dforce = -np.where(active[:, None], eps[:, None] * self.N[:, :3]
                               + np.einsum("eij,ej->ei", H, lam), 0.0)
        T, dT, stick = coulomb(self.gap, self.N, H, y, y_n, lam, float(self.friction.mu), eps,
                               eps_t, second, force=-p, dforce=dforce)
        T = np.where(active[:, None], T, 0.0)
        if dT is not None:
            dT = np.where(active[:, None, None], dT, 0.0)
        return T, dT, stick & active

    def _friction_terms(self, penalty, multipliers):
        """(ε, p, λ, ε_T) of the elements (`_normal`, and friction's tangential penalty),
        remembered for `history`."""
        self._penalty_used, self._multipliers_used = penalty, multipliers
        eps, p, lam = self._normal(penalty, multipliers)
        try:
            eps_t = eps if self.friction.penalty_t is None else self._penalty(
                self.friction.penalty_t)
        except ValueError as exc:
            raise ValueError(f"Coulomb.penalty_t: {exc}".replace("penalty: ", "")) from None
        return eps, p, lam, eps_t

    def _convected_law(self, terms, second, idx, D):
        """Coulomb's law on a deformable target (`friction.cone`) for elements `idx`, with
        `terms` (`_friction_terms`) of all elements: r = x^c − A with A the history point
        where it is now (`anchor.point`), ∂r/∂u = B ⊗ I, D (k, 3, 3(K+1)) ℳ's contactor rows
        (None: 0, the Gauss-Newton tangent), over u = [x^c, `_convected_nodes`]. With
        multipliers, an inactive element (p = 0) has no friction."""
        eps, p, lam, eps_t = (None if t is None else t[idx] for t in terms)
        known = np.isfinite(self.anchor.point[idx]).all(axis=1)
        x = np.asarray(self.projection.points, np.float64)[self.contactor[idx]]
        stretch = x - np.where(known[:, None], self.anchor.point[idx], x)
        gap, N = self.gap[idx], self.N[idx]
        if lam is None:
            start = (np.zeros((len(idx), 3)) if self.start is None else
                     np.asarray(self.start.traction, np.float64)[self.contactor[idx]])
            force = eps * np.abs(gap)                                     # ε |g|
        else:
            start, force = lam, -p
        nu, mu = N[:, :3], float(self.friction.mu)
        if not second:
            T, dT, stick = cone(nu, stretch, start, known, mu, force, eps_t, False)
        else:
            B = self._convected_nodes()[1][idx]
            k, w, W = len(idx), N.shape[1], 3 * B.shape[1]
            d_stretch = np.einsum("es,ij->eisj", B, np.eye(3)).reshape(k, 3, W)
            Dw = np.zeros((k, 3, W))
            if D is not None:
                Dw[:, :, :w] = D
            d_force = np.zeros((k, W))
            if lam is None:  # ∂(ε |g|)/∂u
                d_force[:, :w] = (eps * np.sign(gap))[:, None] * N
            else:  # ∂|p|/∂u = −(ε 𝒩 + Dᵀ λ) where active: λ_N = λ·ν moves with ν
                d_force[:, :w] = -np.where((p < 0)[:, None], eps[:, None] * N, 0.0)
                d_force -= np.where((p < 0)[:, None], np.einsum("eiw,ei->ew", Dw, lam), 0.0)
            T, dT, stick = cone(nu, stretch, start, known, mu, force, eps_t, True,
                                d_stretch=d_stretch, d_normal=Dw, d_force=d_force)
        if lam is None:
            return T, dT, stick
        active = p < 0
        return (np.where(active[:, None], T, 0.0),
                None if dT is None else np.where(active[:, None, None], dT, 0.0),
                stick & active)

    def _normal_derivative(self) -> np.ndarray:
        """(e, 3, 3(K+1)) D = ∂ν/∂u, ℳ's contactor rows (ν = ∂g/∂x^c), ℳ built a chunk at a
        time where it is built on demand."""
        if not isinstance(self.M, Hessians):
            return np.array(np.asarray(self.M)[:, :3, :], dtype=np.float64)
        D = np.empty((len(self), 3, self.N.shape[1]))
        for idx, M in self._hessian_chunks(False, np.arange(len(self))):
            D[idx] = M[:, :3, :]
        return D

    def tractions(self, penalty, multipliers=None):
        """The normal and tangential forces on each contactor (m rows) with the normal
        penalty `penalty` and `multipliers` (as `residual`): `friction.Tractions`, normal
        −p = ε |g| without multipliers; tangential 0 without friction."""
        m = len(self.status)
        normal, tangential, stick = np.zeros(m), np.zeros((m, 3)), np.zeros(m, bool)
        normal[self.contactor] = -self._normal(penalty, multipliers)[1]
        if self.friction is not None:
            T, _, sticks = self._tangential(penalty, second=False, multipliers=multipliers)
            tangential[self.contactor] = -T
            stick[self.contactor] = sticks
        return Tractions(normal, tangential, stick)

    @property
    def history(self):
        """The state friction starts from at the next step (`friction.History`), for when
        this call's positions are the converged ones: every contactor's proximal point (NaN
        where it has none) and the tangential part τ of its residual (0 where it has no
        element), with the normal penalty and multipliers of the last `residual`, `tangent`
        or `tractions` call. On a deformable target, also the nodes each history point rides
        on, their weights and positions (`friction.History`); a contactor without an element
        then has no history point (NaN): its friction starts where it next touches."""
        if self.friction is None:
            raise ValueError("history: this contact has no friction (contact(..., "
                             "friction=Coulomb(mu)))")
        if self._penalty_used is None:
            raise ValueError("history needs the normal penalty: call residual, tangent or "
                             "tractions first")
        tau = np.zeros((len(self.status), 3))
        tau[self.contactor] = self._tangential(self._penalty_used, second=False,
                                               multipliers=self._multipliers_used)[0]
        y = np.array(self.projection.proximal_point, dtype=np.float64)
        y[~np.all(np.isfinite(y), axis=1)] = np.nan
        if self.anchor is None:
            return History(y, tau)
        m, K = len(self.status), self.nodes.shape[1]
        weights = anchor_weights(self.N)
        ok = np.isfinite(weights).all(axis=1)
        nodes = np.full((m, K), -1, np.int64)
        nodes[self.contactor[ok]] = self.nodes[ok]
        phi = np.zeros((m, K))
        phi[self.contactor[ok]] = np.where(self.nodes[ok] >= 0, weights[ok], 0.0)
        held = np.zeros(m, bool)
        held[self.contactor[ok]] = True
        y[~held] = np.nan
        positions = np.where((nodes >= 0)[:, :, None],
                             self.anchor.target_points[np.maximum(nodes, 0)], 0.0)
        return History(y, tau, nodes, phi, positions)

    def tangent(self, penalty, contactor_dofs, target_dofs=None, n_dofs=None, *,
                gauss_newton: bool = False, multipliers=None) -> sp.csr_matrix:
        """Assembled tangent Σ ε 𝒩 𝒩ᵀ + p ℳ over the active elements (p < 0; the penalty's
        ε (g ℳ + 𝒩 𝒩ᵀ) [54] without multipliers), sparse and symmetric, same arguments and
        DOFs as `residual`; with friction, plus ∂T/∂x on each contactor's block (not
        symmetric in slip), and with multiplier vectors 𝒩 (ℳ[:3]ᵀ λ)ᵀ (λ_N = λ·ν moves
        with ν).

        Summed in compiled code (`_assembly`): the CSR pattern once (every element's nodes,
        inactive ones too: the pattern is the same while the elements are), then each
        element's block added at its place, ℳ built `blocks.TANGENT_BATCH` entries at a time
        (never whole). Canonical CSR (sorted, no duplicates).

        gauss_newton : bool
            Σ ε 𝒩 𝒩ᵀ only: positive semi-definite whatever the gap and the curvature, and
            needs no ℳ (`contact(..., second=False)` is enough), at the price of Newton's
            quadratic convergence (linear, fast while penetrations are small).
        multipliers : as `residual`."""
        size = self._size(n_dofs, contactor_dofs, target_dofs)
        ids = _node_ids(self, 0, len(self.status))
        wide = ids if self.anchor is None else self._convected_ids(0)
        total = _CompiledSum(size, _node_dofs(contactor_dofs, target_dofs, len(self.status),
                                              self.n_target), wide)
        self._add_tangent(total, penalty, ids, gauss_newton, multipliers)
        if self.anchor is not None:
            self._add_convected(total, penalty, wide, gauss_newton, multipliers)
        return total.result()

    def _convected_ids(self, first: int) -> np.ndarray:
        """`_node_ids` over u = [x^c, `_convected_nodes`]: friction's on a deformable
        target."""
        nodes, _ = self._convected_nodes()
        m = len(self.status)
        return np.concatenate([first + np.asarray(self.contactor, np.int64)[:, None],
                               np.where(nodes >= 0, m + nodes, -1)], axis=1)

    def _convected_blocks(self, penalty, gauss_newton: bool, multipliers, chunk: int):
        """(elements, K_T (k, W, W), R_T (k, W)) chunk by chunk, friction's part on a
        deformable target, over u = [x^c, `_convected_nodes`] (W = 3(1 + K + k)): R_T = ρ ⊗ T
        on the contactor and the element's nodes (ρ = `_reaction`), K_T = ρ ⊗ ∂T/∂u − T ⊗
        ∂φ/∂u on their rows (without ∂φ/∂u for the Gauss-Newton tangent)."""
        terms = self._friction_terms(penalty, multipliers)
        rho = self._reaction()
        e, w, W = len(self), self.N.shape[1], 3 * self._convected_nodes()[1].shape[1]
        for lo in range(0, e, chunk):  # each chunk's ℳ built once, for D and ∂φ/∂u
            idx = np.arange(lo, min(lo + chunk, e))
            k = len(idx)
            M = None if gauss_newton else self._hessians_of(idx)
            T, dT, _ = self._convected_law(terms, True, idx, None if M is None else M[:, :3])
            K = np.zeros((k, W // 3, 3, W))
            K[:, :w // 3] = rho[idx, :, None, None] * dT[:, None]
            if M is not None:  # rows of node j: −T ⊗ ∂φ_j/∂u
                dphi = reaction_derivative(self.N[idx], M)
                K[:, 1:w // 3, :, :w] -= T[:, None, :, None] * dphi[:, :, None, :]
            R = np.zeros((k, W))
            R[:, :w] = (rho[idx, :, None] * T[:, None, :]).reshape(k, w)
            yield idx, K.reshape(k, W, W), R

    def _add_convected(self, total, penalty, wide, gauss_newton: bool, multipliers) -> None:
        """Adds friction's K_T on a deformable target into `total` (its pattern holds
        `wide`, `_convected_ids`), as dense blocks (`_assembly.add` with p = 1)."""
        none3, none33 = np.zeros((0, 3)), np.zeros((0, 3, 3))
        for idx, K, _ in self._convected_blocks(penalty, gauss_newton, multipliers, 64):
            k = len(idx)
            total.add(wide[idx], np.zeros((k, K.shape[1])), np.ascontiguousarray(K),
                      np.zeros(k), np.ones(k), none3, none33)

    def _element_terms(self, penalty, gauss_newton: bool, multipliers):
        """(ε where active else 0, p, λ (e, 3) or None, ∂T/∂x (e, 3, 3) or None): what each
        element's tangent block is made of (`tangent`)."""
        if self.M is None and not gauss_newton:
            raise ValueError("the tangent needs ℳ: build the contact with second=True (or "
                             "ask for the Gauss-Newton tangent)")
        eps, p, lam = self._normal(penalty, multipliers)
        # active: λ_N + ε g <= 0, a force or a touch (g = 0 at a flat start: its stiffness
        # ε 𝒩𝒩ᵀ, no force); an open element (g > 0, p = 0: `contact(near=)`) adds nothing
        eps = np.where((p < 0) | (self.gap <= 0), eps, 0.0)
        dT = (self._tangential(penalty, curvature=not gauss_newton,
                               multipliers=multipliers)[1]
              if self.friction is not None and self.anchor is None else None)
        return eps, p, lam, dT

    def _hessian_chunks(self, gauss_newton: bool, order):
        """(elements, ℳ of those elements or an empty (0, w, w)) over the elements in
        `order`, ℳ built `blocks.TANGENT_BATCH` entries at a time into one reused buffer (a
        `Hessians`; never whole)."""
        width = self.N.shape[1]
        step = max(1, blocks.TANGENT_BATCH // (width * width))
        empty = np.zeros((0, width, width))
        buffer = None
        for lo in range(0, len(self), step):
            idx = order[lo:lo + step]
            if gauss_newton:
                yield idx, empty
            elif isinstance(self.M, Hessians):
                if buffer is None:
                    buffer = np.empty((min(step, len(self)), width, width))
                yield idx, self.M.take(idx, out=buffer[:len(idx)])
            else:
                yield idx, np.ascontiguousarray(self.M[idx], dtype=np.float64)

    def _add_tangent(self, total: _CompiledSum, penalty, ids, gauss_newton: bool = False,
                     multipliers=None) -> None:
        """Adds the elements' tangent blocks into `total` (its pattern holds `ids`, this
        contact's node ids: `_node_ids`), in order of their first target node (neighbours
        one after another: the rows they add to stay in the cache; the order changes the sum
        in round-off only)."""
        eps, p, lam, dT = self._element_terms(penalty, gauss_newton, multipliers)
        none3, none33 = np.zeros((0, 3)), np.zeros((0, 3, 3))
        order = np.argsort(np.where(self.nodes >= 0, self.nodes, len(self.status) + self.n_target)
                           .min(axis=1, initial=len(self.status) + self.n_target),
                           kind="stable")
        fused = None if gauss_newton else getattr(self.M, "tangent", None)
        if fused is not None:  # each ℳ built and added at once (`Hessians.tangent`)
            lam = None if lam is None else lam[order]
            dT = None if dT is None else dT[order]
            step = max(1, blocks.TANGENT_BATCH // (4 * self.N.shape[1]))
            for lo in range(0, len(self), step):
                idx, at = order[lo:lo + step], slice(lo, lo + step)
                fused(idx, self.nodes[idx], ids[idx], self.N[idx], eps[idx], p[idx],
                      None if lam is None else lam[at], None if dT is None else dT[at],
                      total.places())
            return
        for idx, M in self._hessian_chunks(gauss_newton, order):
            total.add(ids[idx], self.N[idx], M, eps[idx], p[idx],
                      none3 if lam is None or gauss_newton else lam[idx],
                      none33 if dT is None else np.ascontiguousarray(dT[idx]))

    def blocks(self, penalty, contactor_dofs, target_dofs=None, *, chunk: int = 1024,
               gauss_newton: bool = False, multipliers=None):
        """Each element's dense tangent and residual blocks with their DOFs, chunk by chunk:
        for FE codes that assemble themselves. Yields (elements (k,) int, dofs (k, w) int,
        K (k, w, w) float, R (k, w) float), w = 3(K+1), `chunk` elements at a time, where
        K[i] = ε 𝒩𝒩ᵀ + p ℳ (+ friction's and the multipliers' terms, as `tangent`) and
        R[i] = p 𝒩 (+ friction's T, as `residual`) of element elements[i], at its unknowns
        u = [x^c, x^nodes...]; dofs -1 where the unknown has no DOF (its rows and columns are
        the caller's to drop). Σ over the blocks of K[i] at (dofs[i], dofs[i]) is `tangent`,
        of R[i] at dofs[i] is `residual`; inactive elements (p = 0) give zero blocks. With
        friction on a deformable target, u also holds the nodes the history point rides on
        that are not the element's (w = 3(1 + K + k): `friction` module docstring)."""
        if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
            raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
        dofs = self.dofs(contactor_dofs, target_dofs)
        eps, p, lam, dT = self._element_terms(penalty, gauss_newton, multipliers)
        T = (self._tangential(penalty, second=False, multipliers=multipliers)[0]
             if dT is not None else None)
        if self.anchor is not None:
            wide = self._dofs_of(self._convected_nodes()[0], contactor_dofs, target_dofs)
            convected = self._convected_blocks(penalty, gauss_newton, multipliers, chunk)
        for lo in range(0, len(self), chunk):
            hi = min(lo + chunk, len(self))
            N = self.N[lo:hi]
            K = eps[lo:hi, None, None] * N[:, :, None] * N[:, None, :]
            if not gauss_newton:
                M = self.M[lo:hi]
                K += p[lo:hi, None, None] * M
                if lam is not None:  # ∂(λ·ν)/∂u = ℳ[:3]ᵀ λ, where active
                    grad = np.einsum("eij,ei->ej", M[:, :3, :], lam[lo:hi])
                    K += (eps[lo:hi] > 0)[:, None, None] * N[:, :, None] * grad[:, None, :]
            R = p[lo:hi, None] * N
            if dT is not None:  # the contactor's block
                K[:, :3, :3] += dT[lo:hi]
                R[:, :3] += T[lo:hi]
            if self.anchor is None:
                yield np.arange(lo, hi), dofs[lo:hi], K, R
                continue
            _, K_T, R_T = next(convected)  # the same elements, over the wider u
            w = N.shape[1]
            K_T[:, :w, :w] += K
            R_T[:, :w] += R
            yield np.arange(lo, hi), wide[lo:hi], K_T, R_T

    def energy(self, penalty) -> float:
        """Σ ε g²/2 over the elements: R and K are its gradient and Hessian (without friction,
        which dissipates: it has no potential). The open elements of `contact(near=)` add
        nothing (g > 0: no penalty force)."""
        return float(np.sum(0.5 * self._penalty(penalty) * np.minimum(self.gap, 0.0)**2))


class _SparseSum:
    """A sum of sparse (row, column, value) entries: each part summed into a CSR matrix by
    scipy (duplicates added), parts of similar size added in pairs (a binary counter: a few
    live parts, each entry merged O(log) times, in compiled code), one CSR at the end. Memory:
    about 12 bytes an entry, twice that during the last addition, and a row pointer per live
    part (parts are `blocks.TANGENT_BATCH` entries or more: few)."""

    def __init__(self, shape):
        self.shape = shape
        big = max(shape) >= 2**31 - 1
        self.index = np.int64 if big else np.int32
        self.parts: list = []  # CSR matrices, canonical (sorted, summed)

    def add(self, rows, cols, values) -> None:
        part = sp.coo_matrix((np.asarray(values, dtype=np.float64),
                              (np.asarray(rows).astype(self.index),
                               np.asarray(cols).astype(self.index))), shape=self.shape).tocsr()
        self.parts.append(part)
        while len(self.parts) > 1 and self.parts[-1].nnz * 2 >= self.parts[-2].nnz:
            self._merge_last()

    def _merge_last(self) -> None:
        b = self.parts.pop()
        a = self.parts.pop()
        self.parts.append(a + b)

    def result(self) -> sp.csr_matrix:
        while len(self.parts) > 1:
            self._merge_last()
        if not self.parts:
            return sp.csr_matrix(self.shape)
        out = self.parts.pop()
        out.sum_duplicates()  # canonical: sorted column indices, no duplicates
        return out


class _CompiledSum:
    """A tangent summed in compiled code (`_assembly`): the CSR pattern of every element that
    will add (`ids`, node ids: a contactor i, a target node m + j), then each chunk's blocks
    added in place. Memory: the CSR itself (12 bytes an entry with int32 indices) and the
    node pattern (about a ninth of its entries, 8 bytes each) while it is built."""

    def __init__(self, size: int, id_dofs: np.ndarray, ids: np.ndarray):
        self.shape = (int(size), int(size))
        self.id_dofs = id_dofs
        valid = np.where(id_dofs >= 0, id_dofs, np.iinfo(np.int64).max)
        order = np.argsort(valid.min(axis=1), kind="stable").astype(np.int64)
        ids = np.ascontiguousarray(ids, dtype=np.int64)
        pattern = None
        if size < 2**31 - 1:
            try:
                pattern = _assembly.pattern(ids, id_dofs, size, order, np.empty(0, np.int32))
            except OverflowError:  # more entries than int32 indices hold
                pattern = None
        if pattern is None:
            pattern = _assembly.pattern(ids, id_dofs, size, order, np.empty(0, np.int64))
        (self.indptr, self.indices, self.base, self.pat_ptr, self.pat_col, self.pat_off,
         self.canonical) = pattern
        self.data = np.zeros(len(self.indices))

    def add(self, ids, N, M, eps, p, lam, dT) -> None:
        _assembly.add(self.base, self.pat_ptr, self.pat_col, self.pat_off,
                      np.ascontiguousarray(ids, dtype=np.int64), self.id_dofs, N, M,
                      np.ascontiguousarray(eps, dtype=np.float64),
                      np.ascontiguousarray(p, dtype=np.float64),
                      np.ascontiguousarray(lam, dtype=np.float64), dT, self.data)

    def places(self) -> tuple:
        """The pattern and its values, as `diffuse.diffuse_tangent` takes them."""
        return (self.base, self.pat_ptr, self.pat_col, self.pat_off, self.id_dofs, self.data)

    def result(self) -> sp.csr_matrix:
        indptr = (self.indptr.astype(np.int32) if self.indices.dtype == np.int32
                  else self.indptr)
        out = sp.csr_matrix((self.data, self.indices, indptr), shape=self.shape, copy=False)
        self.data = self.indices = None
        if self.canonical:
            out.has_sorted_indices = True
            out.has_canonical_format = True
        else:  # a DOF shared by two nodes, or DOFs numbered out of node order
            out.sum_duplicates()
        return out


def _node_ids(c, first: int, m: int) -> np.ndarray:
    """(e, K+1) node ids of a contact's elements' unknowns: contactor first + i, target node
    m + j, -1 padding (`_CompiledSum`)."""
    ids = np.empty((len(c), c.nodes.shape[1] + 1), np.int64)
    ids[:, 0] = first + np.asarray(c.contactor, np.int64)
    ids[:, 1:] = np.where(c.nodes >= 0, m + c.nodes, -1)
    return ids


def _node_dofs(contactor_dofs, target_dofs, m: int, n_target: int) -> np.ndarray:
    """(m + n_target, 3) DOFs of the node ids (`_node_ids`), checked as `Contact.dofs`."""
    contactor_dofs = np.asarray(contactor_dofs)
    if contactor_dofs.shape != (m, 3):
        raise ValueError(f"contactor_dofs: expected shape ({m}, 3), got "
                         f"{contactor_dofs.shape}")
    out = np.full((m + n_target, 3), -1, np.int64)
    out[:m] = contactor_dofs
    if target_dofs is not None:
        target_dofs = np.asarray(target_dofs)
        if target_dofs.shape != (n_target, 3):
            raise ValueError(f"target_dofs: expected shape ({n_target}, 3), got "
                             f"{target_dofs.shape}")
        out[m:] = target_dofs
    return np.maximum(out, -1)


def _scatter_add(out: np.ndarray, c, contactor_dofs, target_dofs, vals) -> None:
    """out += each element's vals (e, 3(K+1)) at its unknowns' DOFs (`Contact.dofs`; -1:
    none, dropped), in compiled code (`_assembly.scatter`): the residual's sum, in the order
    of `np.add.at(out, dofs[keep], vals[keep])` (bitwise its numbers), without building the
    (e, 3(K+1)) DOF array (most of that path's time). The DOF maps checked as `Contact.dofs`
    checks them (`_node_dofs`)."""
    m = len(c.status)
    id_dofs = _node_dofs(contactor_dofs, target_dofs, m, c.n_target)
    _assembly.scatter(out, np.ascontiguousarray(c.contactor, dtype=np.int64),
                      np.ascontiguousarray(c.nodes, dtype=np.int64), id_dofs, m,
                      np.ascontiguousarray(vals, dtype=np.float64))


def _element_dofs(contactor, nodes, m: int, n_target: int, contactor_dofs,
                  target_dofs) -> np.ndarray:
    """(e, 3(k+1)) global DOFs of the unknowns u = [x^c, nodes (e, k)] of elements of
    contactors `contactor` (e,), of m, on a target of n_target nodes (`Contact.dofs`)."""
    contactor_dofs = np.asarray(contactor_dofs)
    if contactor_dofs.shape != (m, 3):
        raise ValueError(f"contactor_dofs: expected shape ({m}, 3), got "
                         f"{contactor_dofs.shape}")
    e, k = nodes.shape
    own = contactor_dofs[contactor].astype(np.int64)[:, None, :]
    if target_dofs is None:
        other = np.full((e, k, 3), -1, dtype=np.int64)
    else:
        target_dofs = np.asarray(target_dofs)
        if target_dofs.shape != (n_target, 3):
            raise ValueError(f"target_dofs: expected shape ({n_target}, 3), got "
                             f"{target_dofs.shape}")
        other = np.where(nodes[:, :, None] >= 0,
                         target_dofs[np.maximum(nodes, 0)], -1).astype(np.int64)
    return np.concatenate([own, other], axis=1).reshape(e, 3 * (k + 1))


def _unanswered(points, **fields) -> Projection:
    """A Projection of nothing yet (NaN, status failed, reason ok) for the parts of a frozen
    pairing to fill; `fields`: its other declared fields (source, pairing)."""
    record = recorded(allocate(len(points)))  # the passes' own fills: NaN, failed, ok
    return Projection(points, **{**record, "terms": None, **fields})


def _as_projection(res, points) -> Projection:
    """The rigid-target kernel's result (`rigid.RigidResult`) as a `Projection`: its fields,
    no support (0) and no rcond (NaN), which it does not measure."""
    m = len(points)
    return Projection(points, np.asarray(res.gap), np.asarray(res.normal),
                      np.asarray(res.proximal_point), np.asarray(res.status),
                      np.zeros(m, np.int64), np.asarray(res.iterations), np.full(m, np.nan),
                      np.asarray(res.curvature), np.asarray(res.reason))


def _far_and_open(surface, points, proj) -> None:
    """A contactor the rigid surface cannot answer (past the target's edge, or farther than
    the focal distance on a concave side, where no closest point is a minimum): ask the
    projection; where it finds it open (on the target's outer side), it is open, with the
    projection's gap, normal and proximal point (it needs no element). One it finds
    penetrating stays unanswered: no element, never a plausible wrong one (`Contact.lost`
    counts it)."""
    far = np.flatnonzero((proj.status == OUTSIDE)
                         | ((proj.status == FAILED) & (proj.reason == NO_CONVERGENCE)))
    if not len(far):
        return
    seen = surface.project(points[far])
    opened = far[seen.status == OPEN]
    keep = seen.status == OPEN
    for name in ("gap", "normal", "proximal_point", "status", "reason", "support",
                 "iterations", "rcond", "curvature"):
        getattr(proj, name)[opened] = getattr(seen, name)[keep]


def contact(surface, points, *, rigid_target: bool = False, pairing=None,
            second: bool = True, friction=None, history=None, near: float = 0.0) -> Contact:
    """Project `points` and build the contact element of every closed contact (g <= 0).

    Parameters
    ----------
    surface : DiffuseSurface, FacetSurface, PatchedSurface or QuadricSurface
        The target. On a PatchedSurface each contactor's element is that of what answered it
        (`patched_contact`): its patch's diffuse element, or the node-to-facet element where
        the facets answered (a sharp edge, a patch that cannot answer, the guard). On a
        QuadricSurface, the quadric element (`quadric_contact`, `element.quadric`: its
        target nodes are the support and the support nodes' rings, whose positions make the
        nodal normals), rigid or not the derivatives of its frozen pairing's gap: within a
        step pass `pairing=` back, as with the diffuse element; no friction.
    points : (m, 3) float
        The contactors x^c.
    rigid_target : bool
        The target does not move: elements of the contactors only (K = 0, N (e, 3),
        M (e, 3, 3)). Diffuse: the gradient and Hessian of the signed distance to the diffuse
        surface (`element.rigid`), which needs no pairing; facet: the contactor's block of the
        node-to-facet element.
    pairing : Pairing, optional
        A frozen pairing to reuse instead of searching again: the `Contact.pairing` of an
        earlier call on this surface (or on one `moved` from it), on any surface: each
        contactor's frame, support nodes and radius R, what the element holds fixed [§4.2],
        or its facet; on a PatchedSurface also what answered it (its patch or the facets; no
        guard then). A DiffuseSurface also takes a `Patch` (`projection.patch`), a
        FacetSurface the facet index of each contactor (`projection.facet`).
    second : bool
        Build ℳ (the tangent needs it; the residual does not).
    friction : Coulomb, optional
        Coulomb friction (`element.friction`): the slip is the contactor's motion relative to
        the target's surface since `history` (on a deformable target, relative to the target
        material it touched: its history point moves with the nodes it rides on, and the
        tangential force acts on them too).
    history : History, optional
        The last converged state (`Contact.history` of that call); None at the first step
        (no tangential traction until a converged state exists).
    near : float
        Also build the element of every contactor answered open or in contact with g < near
        (an augmented Lagrangian's: a contactor with λ + ε g < 0 still carries a force; pass
        `Contact.reach(penalty, multipliers)`); 0: the penetrating ones only. Not on a
        PatchedSurface's curved cells (their contactors have elements where they penetrate).

    Returns
    -------
    Contact
    """
    points = np.asarray(points, dtype=np.float64)
    near = _check_near(near)
    if friction is not None and rigid_target and getattr(surface, "deformed", False):
        raise ValueError("friction with rigid_target=True on a moved target: a moved target "
                         "deforms, and a rigid target's friction would give it no reaction: "
                         "drop rigid_target (the full element's friction acts on both)")
    if friction is not None and isinstance(surface, QuadricSurface):
        raise ValueError("friction on a QuadricSurface is not built yet (its element is a "
                         "frozen pairing's, and friction's tangent is not verified on it): use "
                         "the default surface (build_surface) for friction")
    if history is not None:
        if friction is None:
            raise ValueError("history is friction's: pass friction=Coulomb(mu) too")
        history.check(len(points))
        if not rigid_target and not history.anchored:
            raise ValueError("history: taken on a rigid target (no nodes); a deformable "
                             "target's friction needs the history of its own contact "
                             "(Contact.history), which says where each point rides")
    # the one dispatch: the surfaces answer geometric questions (project, project_with,
    # moved); which element each kind of target takes is decided here
    if isinstance(surface, PatchedSurface):
        build = patched_contact
    elif isinstance(surface, DiffuseSurface):
        build = diffuse_contact
    elif isinstance(surface, FacetSurface):
        build = facet_contact
    elif isinstance(surface, QuadricSurface):
        build = quadric_contact
    else:
        raise TypeError(f"{type(surface).__name__} is not a surface: expected a DiffuseSurface, "
                        f"FacetSurface, PatchedSurface or QuadricSurface (projection.Surface)")
    c = build(surface, points, rigid_target=rigid_target, pairing=pairing, second=second,
              near=near)
    c.lost = lost_contactors(surface, points, c.projection)
    c.friction, c.start = friction, history
    if friction is not None and not rigid_target:
        target_points = np.asarray(surface.nodes, dtype=np.float64)
        c.anchor = Anchor(*anchors(history, c.contactor, target_points), target_points)
    return c


def facets_of(surface):
    """The faceted target under any surface: a FacetSurface itself, a PatchedSurface's
    facets, a DiffuseSurface's own (`DiffuseSurface.facet_surface`); None without facets."""
    if isinstance(surface, (FacetSurface, PatchedSurface, DiffuseSurface, QuadricSurface)):
        return surface.facet_surface()  # a FacetSurface's is itself
    return None


def lost_contactors(surface, points, proj) -> np.ndarray:
    """Contactors with no answer (status outside or failed; not a NaN contactor) that the
    target's facets find penetrating: a solver must not take them for open. On a target
    without facets (a point cloud) every unanswered contactor counts. Past an open edge of
    the facets (`past_open_edge`) nothing penetrates: the facets' sign there is only the side
    of the edge's facet's plane."""
    rows = np.flatnonzero(((proj.status == OUTSIDE) | (proj.status == FAILED))
                          & (proj.reason != BAD_POINT))
    facets = facets_of(surface) if len(rows) else None
    if facets is None:
        return rows.astype(np.int64)
    seen = facets.project(points[rows])
    inside = seen.status == PENETRATION
    inside[inside] = ~past_open_edge(facets, points[rows[inside]], seen.facet[inside],
                                     seen.proximal_point[inside])
    return rows[inside].astype(np.int64)


#: A contactor whose faceted foot is on an open edge is past it where its direction from the
#: foot leaves the plane's normal by more than this (radians; round-off is ~1e-16).
PAST_EDGE = 1e-9


def past_open_edge(facets, points, facet, foot) -> np.ndarray:
    """(k,) bool: whether each contactor lies past an open edge of the facets (an edge of one
    facet only): its faceted foot on such an edge (or at
    its ends) and its direction from the foot off that facet's normal, i.e. beside the
    facet, not above or below it. `facet`, `foot`: their faceted answer's facet and proximal
    point (`facets.project(points)`)."""
    k = len(points)
    past = np.zeros(k, bool)
    f = np.asarray(facet, dtype=np.int64)
    if not k or not (f >= 0).any():
        return past
    t = facets._tables  # the search's own edge table: edge j from corner j to corner j + 1
    slot = t["slot"][np.maximum(f, 0)]
    edge = t["fedge"][slot].astype(np.int64)
    ptr = t["edge_ptr"].astype(np.int64)
    one = (edge >= 0) & (ptr[np.maximum(edge, 0) + 1] - ptr[np.maximum(edge, 0)] == 1)
    one &= (f >= 0)[:, None]
    corner = facets.facets[np.maximum(f, 0)]
    kind = np.where(corner[:, 3] >= 0, 4, 3)
    xyz = facets.nodes[np.maximum(corner, 0)]
    foot = np.asarray(foot, dtype=np.float64)
    tiny = np.finfo(np.float64).tiny
    on = np.zeros(k, bool)
    for j in range(4):
        a = xyz[:, j]
        b = xyz[np.arange(k), (j + 1) % kind]
        ab = b - a
        s = np.clip(np.einsum("ij,ij->i", foot - a, ab)
                    / np.maximum(np.einsum("ij,ij->i", ab, ab), tiny), 0.0, 1.0)
        off = np.linalg.norm(foot - (a + s[:, None] * ab), axis=1)
        on |= one[:, j] & (off <= PAST_EDGE * np.linalg.norm(ab, axis=1))
    normal = np.cross(xyz[:, 2] - xyz[:, 0], xyz[np.arange(k), kind - 1] - xyz[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), tiny)
    d = np.asarray(points, dtype=np.float64) - foot
    beside = d - np.einsum("ij,ij->i", d, normal)[:, None] * normal
    past = on & (np.linalg.norm(beside, axis=1) > PAST_EDGE * np.linalg.norm(d, axis=1))
    return past


def pairing_count(pairing) -> int:
    """The number of contactors a pairing is for: a `Pairing`, a `Patch` or facet indices."""
    if isinstance(pairing, Pairing):
        return len(pairing)
    if isinstance(pairing, Patch):
        return len(np.asarray(pairing.origin))
    return int(np.asarray(pairing).size)


def check_pairing(surface, pairing, m: int) -> None:
    """Refuse (ValueError) a pairing not made for `surface` and m contactors: a `Pairing` made
    on another type of surface (its fields mean other things there: a facet's pairing would be
    ignored by a diffuse surface), a `Patch` (diffuse frames and supports) given to a
    FacetSurface, facet indices given to a DiffuseSurface, or another count of contactors."""
    if pairing is None:
        return
    kind = type(surface).__name__
    if isinstance(pairing, Pairing):
        made = pairing.made_on
        if made is not None and made not in {c.__name__ for c in type(surface).__mro__}:
            raise ValueError(f"the pairing was made on a {made}, not on this {kind}: pass the "
                             f"Contact.pairing of this surface (or of one moved from it)")
        if isinstance(surface, (DiffuseSurface, QuadricSurface)) and pairing.patch is None:
            raise ValueError(f"the pairing holds no frames and supports (a FacetSurface's?), "
                             f"not a {kind}'s")
        if isinstance(surface, FacetSurface) and pairing.facet is None:
            raise ValueError(f"the pairing holds no facets (a DiffuseSurface's?), not a "
                             f"{kind}'s")
    elif isinstance(pairing, Patch):
        if isinstance(surface, FacetSurface):
            raise ValueError(f"a Patch (the frames and supports of a DiffuseSurface) is no "
                             f"pairing for a {kind}: pass the Contact.pairing of this surface")
    elif isinstance(surface, (DiffuseSurface, QuadricSurface)):
        raise ValueError(f"facet indices (a FacetSurface's pairing) are no pairing for a "
                         f"{kind}: pass the Contact.pairing of this surface, or a Patch")
    count = pairing_count(pairing)
    if count != m:
        raise ValueError(f"the pairing is for {count} contactors, got {m}")


def facet_contact(surface, points, *, rigid_target=False, pairing=None,
                  second=True, near=0.0) -> Contact:
    """`contact` on a FacetSurface: the node-to-facet element [§2]."""
    check_pairing(surface, pairing, len(as_points(points)))
    if isinstance(pairing, Pairing):
        pairing = pairing.facet
    proj = surface.project(points) if pairing is None else surface.project_with(points, pairing)
    if not rigid_target:
        proj.pairing = Pairing(np.where(proj.facet >= 0, -1, -2).astype(np.int64), None,
                               proj.facet.copy(), type(surface).__name__)
    rows = _closed(proj, near)
    width = 3 if rigid_target else 15
    lazy = blocks.on_demand(len(rows), width, second)
    gap, nodes, N, M = facet_elements(surface, points, proj, rows, second and not lazy,
                                      rigid_target)

    def hessians(r, out):  # a block of its own (Hessians.take copies it into out)
        return facet_elements(surface, points, proj, r, True, rigid_target)[3]

    return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target,
                   hessians if lazy else None)


def diffuse_contact(surface, points, *, rigid_target=False, pairing=None,
                    second=True, near=0.0, own_edges=True, h_min=None) -> Contact:
    """`contact` on a DiffuseSurface: the diffuse element of the contactor's own local
    approximation [§4.2-4.3], or the rigid target's (`element.rigid`). With `own_edges` (a
    surface on its own, not a PatchedSurface's patch, whose edges the patches keep), a
    contactor the surface answers open but its facets find penetrating has no answer
    (`_rounded_edges`). `h_min` (m,): the local spacing's floor of each contactor, as the
    patched pass gave it (`DiffuseSurface.project`)."""
    if rigid_target:
        if pairing is not None:
            raise ValueError("a rigid target's gap is the signed distance to the diffuse "
                             "surface: it needs no pairing")
        res = RigidTarget.for_surface(surface).evaluate(points, second=second)
        proj = _as_projection(res, points)
        _far_and_open(surface, points, proj)
        if own_edges:
            _rounded_edges(surface, points, proj)
        rows = _closed(proj, near)
        rows = rows[np.isfinite(res.gap[rows])]  # open by the projection: no rigid gap
        gap = np.asarray(res.gap, dtype=np.float64)[rows]
        nodes = np.zeros((len(rows), 0), dtype=np.int64)
        N = np.asarray(res.normal, dtype=np.float64)[rows]
        M = np.asarray(res.hessian, dtype=np.float64)[rows] if second else None
        return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target)
    if surface.recentre:
        raise ValueError("the contact element is defined on the contactor's own local "
                         "approximation: use it without re-centring")
    check_pairing(surface, pairing, len(as_points(points)))
    if isinstance(pairing, Pairing):
        pairing = pairing.patch
    proj = (surface.project(points, keep_patch=True, h_min=h_min)
            if pairing is None or not len(points)
            else surface.project_with(points, pairing))  # 0 contactors: nothing to pair
    if pairing is not None:  # far from every node: off the target, as `project` says it
        mark_far(proj, surface.nearest_node)
    proj.pairing = Pairing(np.zeros(len(points), np.int64), proj.patch, None,
                           type(surface).__name__)
    if own_edges:
        _rounded_edges(surface, points, proj)
    rows = _closed(proj, near)
    # the widest support among the elements bounds their width (nodes of zero weight drop)
    index = np.asarray(proj.patch.index)
    count = ((index.reshape(len(points), -1) >= 0).sum(axis=1) if len(points)  # (0, -1): none
             else np.zeros(0, np.int64))
    K = int(count[rows].max(initial=0))
    lazy = blocks.on_demand(len(rows), 3 * (K + 1), second)
    gap, nodes, N, M = _diffuse_in_chunks(surface, points, proj, rows, K, second and not lazy)

    def hessians(r, out):
        return diffuse_elements(surface, points, proj.patch, proj.proximal_point, r, True,
                                width=(out.shape[1] // 3 - 1), out=out)[3]

    def tangent(r, *args):
        diffuse_tangent(surface, points, proj.patch, proj.proximal_point, r, *args)

    return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target,
                   hessians if lazy else None, tangent if lazy else None)


def quadric_contact(surface, points, *, rigid_target=False, pairing=None, second=True,
                    near=0.0) -> Contact:
    """`contact` on a QuadricSurface: the element of each contactor's frozen quadric fit, with
    the nodal normals' derivatives (`element.quadric`); on a rigid target, the contactor's
    block (the gradient and Hessian of the signed distance to the frozen fit)."""
    check_pairing(surface, pairing, len(as_points(points)))
    if isinstance(pairing, Pairing):
        pairing = pairing.patch
    proj = (surface.project(points, keep_patch=True) if pairing is None or not len(points)
            else surface.project_with(points, pairing))
    if pairing is not None:  # far from every node: off the target, as `project` says it
        mark_far(proj, surface.nearest_node)
    proj.pairing = Pairing(np.zeros(len(points), np.int64), proj.patch, None,
                           type(surface).__name__)
    rows = _closed(proj, near)
    gap, nodes, N, M = quadric_elements(surface, np.asarray(points, np.float64), proj.patch,
                                        rows, second, rigid_target)
    return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target)


def _rounded_edges(surface, points, proj) -> None:
    """A DiffuseSurface on its own rounds the target's sharp edges and corners (its fits
    span them): a contactor just inside a box's edge can lie outside that rounding, and be
    answered open with a plausible gap. Where the surface answers a contactor open (not in
    contact: |g| within tolerance is at the surface) within its reach of the facets (the
    support radius R of its widest node spacing: no rounding departs farther), the
    target's facets find it penetrating, and its faceted foot is within the support radius
    of a sharp edge's node (`sharp_nodes`: there the surface is no resolved smooth one,
    whose departure from the facets, a chordal sag, may leave a contactor just inside a
    concave region's facets open), the two contradict each other: no answer ('failed',
    reason 'guard', NaN), and `Contact.lost` lists it. A `PatchedSurface` keeps sharp
    edges sharp (docs/element.md)."""
    facets = surface.facet_surface()
    if facets is None:
        return
    reach = surface.radius * float(surface.node_spacing.max())
    # open only: a contactor in contact (|g| within tolerance: where a penalty or an augmented
    # Lagrangian converges) is at the surface, not open by a plausible gap
    rows = np.flatnonzero((proj.status == OPEN) & (proj.gap <= reach))
    if not len(rows):
        return
    seen = facets.project(points[rows])
    inside = seen.status == PENETRATION
    rows, foot = rows[inside], seen.proximal_point[inside]
    if not len(rows):
        return
    node = sharp_nodes(facets)
    if not len(node):
        return
    from scipy.spatial import cKDTree

    dist, near = cKDTree(facets.nodes[node]).query(foot)
    rows = rows[dist <= surface.radius * surface.node_spacing[node[near]]]
    proj.status[rows], proj.reason[rows] = FAILED, GUARD
    for name in ("gap", "normal", "proximal_point", "curvature"):
        getattr(proj, name)[rows] = np.nan


def sharp_nodes(facets, angle: float = FEATURE_ANGLE_DEG) -> np.ndarray:
    """The nodes (first of each position) on the facets' creases: edges of two facets whose
    normals differ by more than `angle` degrees (a PatchedSurface's feature angle) and that
    are no bend of a coarse smooth curve (`segment.creases`, the patches' own rule: a tube of
    8 facets around is no crease). Found once per facets and angle (a solver's every
    iteration on a rigid target asks again)."""
    held = _SHARP.setdefault(facets, {})
    if angle not in held:
        held[angle] = _sharp_nodes(facets, angle)
        held[angle].setflags(write=False)  # shared by every call
    return held[angle]


#: `sharp_nodes` of each FacetSurface, by angle, while that surface lives.
_SHARP: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _sharp_nodes(facets, angle: float) -> np.ndarray:
    corners = np.asarray(facets.facets, dtype=np.int64)
    quad = corners[:, 3] >= 0
    blocks = [b for b in (corners[~quad, :3], corners[quad]) if len(b)]
    if not blocks:
        return np.zeros(0, np.int64)
    key = node_identity(facets.nodes)
    edges = edge_table(blocks, key)
    crease = creases(facets.nodes, blocks, angle, key=key, edges=edges)
    return np.unique(edges.ends[crease])


def _diffuse_in_chunks(surface, points, proj, rows, K, second):
    """`diffuse_elements` of `rows`, `CHUNK_FULL` at a time, joined into arrays as wide as
    the widest element (at most K support nodes; narrower chunks padded: nodes -1, 𝒩 and ℳ
    0): the engine's per-call copies of the pairing stay one chunk's, whatever the count,
    and nothing is allocated K wide (the projection's supports, nodes of zero weight
    included, are twice the elements' width or more)."""
    parts = [diffuse_elements(surface, points, proj.patch, proj.proximal_point,
                              rows[lo:lo + CHUNK_FULL], second)
             for lo in range(0, len(rows), CHUNK_FULL)]
    widest = max((nd.shape[1] for _, nd, _, _ in parts), default=0)  # <= K
    size = 3 * (widest + 1)
    e = len(rows)
    gap = np.empty(e)
    nodes = np.empty((e, widest), np.int64)
    N = np.empty((e, size))
    M = np.empty((e, size, size)) if second else None
    lo = 0
    for g, nd, n, mm in parts:
        hi, w = lo + len(g), n.shape[1]
        gap[lo:hi], nodes[lo:hi, :nd.shape[1]], N[lo:hi, :w] = g, nd, n
        nodes[lo:hi, nd.shape[1]:], N[lo:hi, w:] = -1, 0.0
        if second:
            M[lo:hi, :w, :w], M[lo:hi, :w, w:], M[lo:hi, w:] = mm, 0.0, 0.0
        lo = hi
    return gap, nodes, N, M


def _check_near(near) -> float:
    """`contact(near=)`: one finite number >= 0."""
    try:
        value = float(near)
    except (TypeError, ValueError):
        raise ValueError(f"near must be a number >= 0, got {near!r}") from None
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"near must be a finite number >= 0, got {near!r}")
    return value


def _closed(proj, near: float) -> np.ndarray:
    """The contactors that get an element, by the gap's sign: every one that penetrates or
    touches, g <= 0 (status penetration, or contact: |g| within `tol.CONTACT` spacings,
    where a large penalty's equilibrium lies; without its element its force would vanish,
    and Newton cycle between it and the penetration that brings the element back; at g = 0
    its force is 0 but its stiffness ε 𝒩𝒩ᵀ is what lets Newton start from bodies that just
    touch, a flat start), and with `near` > 0 those answered open or in contact with g <
    near (`contact(near=)`)."""
    closed = (proj.status == PENETRATION) | ((proj.status == CONTACT) & (proj.gap <= 0))
    if near > 0:
        answered = (proj.status == OPEN) | (proj.status == CONTACT)
        closed |= answered & (np.nan_to_num(proj.gap, nan=np.inf) < near)
    return np.flatnonzero(closed)


def _finish(surface, proj, rows, gap, nodes, N, M, rigid_target, hessians=None,
            tangent=None) -> Contact:
    """The Contact of the elements of `rows`; an element the kernel could not compute (a
    singular fit or proximal-point system: NaN) is no element: its contactor fails, and says
    so. `hessians(contactor rows, out)`: their ℳ (into `out` where it can, as `Hessians`'
    build), for a Contact whose ℳ is built on demand (`Hessians`; M None here)."""
    bad = ~np.isfinite(gap) | ~np.isfinite(N).all(axis=1)
    if M is not None:
        bad |= ~np.isfinite(M).all(axis=(1, 2))
    if bad.any():
        failed = rows[bad][proj.status[rows[bad]] == PENETRATION]  # (`near`'s open ones: none)
        proj.status[failed] = FAILED
        proj.reason[failed] = ILL_CONDITIONED
        keep = ~bad
        rows, gap, nodes, N = rows[keep], gap[keep], nodes[keep], N[keep]
        M = None if M is None else M[keep]
    rows = rows.astype(np.int64)
    if hessians is not None:
        M = Hessians(lambda idx, out: hessians(rows[idx], out), len(rows), N.shape[1],
                     None if tangent is None else
                     lambda idx, *args: tangent(rows[idx], *args))
    return Contact(rows, np.asarray(nodes, dtype=np.int64), gap, N, M, proj,
                   len(surface.nodes), bool(rigid_target))


#: Projection fields a part's own answer replaces in the merged projection of
#: `_patched_contact` (those every part has: diffuse, facet and rigid-target answers).
_MERGED = ("gap", "normal", "proximal_point", "status", "reason")


def patched_contact(surface, points, *, rigid_target=False, pairing=None,
                    second=True, near=0.0) -> Contact:
    """`contact` on a PatchedSurface.

    `pairing`: a `projection.Pairing` (`Contact.pairing` of an earlier call on this surface,
    or on one `moved` from it): each contactor is answered by what answered it then, with the
    frame, support and radius (or the facet, or the cell) held then: its patch's diffuse
    element, the node-to-facet element, or the node-to-cell one; no search, no guard (they
    are the step's start's). A `Patch` (or facet indices) of one diffuse surface is taken by
    a PatchedSurface of one patch only.

    The PatchedSurface's projection decides, from x^c alone, what answers each contactor
    (`Projection.source`); each part then builds its contactors' elements as `contact` does on
    one surface: patch p's DiffuseSurface (its node indices mapped to the target's nodes by
    `patch_nodes`; rigid: that surface's RigidTarget), or the node-to-facet element on the
    target's facets (source -1; rigid: its contactor block). Those answers replace the
    projection's fields of their rows (the same numbers for the full element: the patch's
    engine on the same points; the rigid gap for a rigid target), and the elements are merged
    in contactor order, K padded to the widest. A rigid target's gap is guarded as the
    projection's is (`PatchedSurface.within_guard`): where the facets bound rejects it, the
    contactor's element is the node-to-facet one, with reason 'guard'; where the patch's
    rigid surface finds no closest point for a contactor the patch answered (deep behind a
    narrow patch, past the blend's reach), the node-to-facet one too (source -1, as where a
    patch cannot answer the projection), not none. Where a target's
    curved cells answered the projection (`patches.surface.CELLS`), the element is that
    cell's node-to-cell element (`element.cell`), so that its gap is the projection's: on a
    rigid target every curved cell's, on a deformable one a second-order cell's (its pairing
    holds the cell, in `Pairing.facet`); a first-order facet curved through its corner
    normals has the node-to-facet element of the facet there (its cell's derivatives would
    need its normals')."""
    if isinstance(pairing, Pairing):
        check_pairing(surface, pairing, len(as_points(points)))
    if pairing is not None and not isinstance(pairing, Pairing):
        if surface.npatches > 1 or surface.surfaces[0] is None:
            raise ValueError("a Patch (or facet indices) pairs one diffuse surface, not one "
                             "per patch: pass the Contact.pairing of this surface")
        return diffuse_contact(surface.surfaces[0], points, rigid_target=rigid_target,
                               pairing=pairing, second=second, near=near, own_edges=False)
    if pairing is not None:
        if rigid_target:
            raise ValueError("a rigid target's gap is the signed distance to its surface: it "
                             "needs no pairing")
        return _patched_frozen(surface, points, pairing, second, near)
    proj = surface.project(points)
    source = proj.source.copy()
    parts = []  # (contactor rows, nodes (global), gap, N, M) of each part
    held = []   # (rows, Patch) of each patch's contactors: the pairing
    for p in np.unique(source[source >= 0]):
        rows = np.flatnonzero(source == p)
        # the support the pass took (its floor: `Projection.support_floor`)
        c = diffuse_contact(surface.surfaces[p], points[rows], rigid_target=rigid_target,
                            second=second, near=near, own_edges=False,
                            h_min=proj.support_floor[rows])
        if not rigid_target:
            held.append((rows, c.projection.patch))
        keep = np.ones(len(rows), bool)
        if rigid_target:  # the rigid surface's gap, guarded against the facets
            q = c.projection
            answered = q.status <= PENETRATION
            # the faceted foot: x - g_f n_f (the facets' normal at their foot)
            foot = points[rows] - proj.facet_gap[rows, None] * proj.facet_normal[rows]
            apart = np.linalg.norm(q.proximal_point - foot, axis=1)
            guarded = answered & ~surface.within_guard(
                q.gap, q.normal, proj.facet[rows], proj.guard_gap[rows], np.nan_to_num(apart))
            # a contactor the patch answered but its rigid surface cannot (no closest point
            # within the blend's reach: deep behind a narrow patch): the facets, as where a
            # patch cannot answer the projection (reason 'ok'), rather than no element
            lost = ~answered & (proj.status[rows] <= PENETRATION) & (proj.facet[rows] >= 0)
            keep = ~(guarded | lost)
            source[rows[~keep]] = FACETS
            proj.reason[rows[guarded]] = GUARD
        nodes = np.where(c.nodes >= 0, surface.patch_nodes[p][np.maximum(c.nodes, 0)], -1)
        for name in _MERGED:
            getattr(proj, name)[rows[keep]] = getattr(c.projection, name)[keep]
        mine = keep[c.contactor]
        parts.append((rows[c.contactor[mine]], nodes[mine], c.gap[mine], c.N[mine],
                      blocks.rows_of(c.M, mine)))
    # the curved cells: their node-to-cell element (`element.cell`), on a rigid target or a
    # second-order cell; a first-order facet curved through its normals: its node-to-facet one
    facet = np.full(len(points), -1, np.int64)
    rows = np.flatnonzero(source == CELLS)
    if len(rows):
        taken, cell, part = cell_part(surface, points, proj, rows, rigid_target, second)
        source[rows[~taken]] = FACETS
        facet[rows[taken]] = cell[taken]
        parts.append(part)
    rows = np.flatnonzero(source == FACETS)
    if len(rows):
        c = facet_contact(surface.facet_surface(), points[rows], rigid_target=rigid_target,
                          second=second, near=near)
        guarded = proj.reason[rows] == GUARD
        for name in _MERGED:
            getattr(proj, name)[rows] = getattr(c.projection, name)
        proj.reason[rows[guarded]] = GUARD
        facet[rows] = c.projection.facet
        parts.append((rows[c.contactor], c.nodes, c.gap, c.N, c.M))
    proj.source = source
    if not rigid_target:
        proj.pairing = Pairing(source.copy(), _merged_patch(len(points), held), facet,
                               type(surface).__name__)
    return _merged_contact(surface, proj, parts, second, rigid_target)


def _merged_patch(m: int, held: list):
    """One `Patch` of m rows from each patch's (rows, Patch): support indices are those of
    the answering patch's surface, -1 padded to the widest; rows no patch answered are NaN
    and -1."""
    K = max([pa.index.shape[1] for _, pa in held], default=1)
    out = Patch(np.full((m, 3), np.nan), np.full((m, 3, 3), np.nan), np.full(m, np.nan),
                np.full(m, np.nan), np.full((m, K), -1, np.int64), np.full(m, -1, np.int8),
                np.full(m, np.nan))
    for rows, pa in held:
        out.origin[rows], out.axes[rows] = pa.origin, pa.axes
        out.radius[rows], out.spacing[rows] = pa.radius, pa.spacing
        out.index[rows, :pa.index.shape[1]] = pa.index
        if pa.reduced is not None:
            out.reduced[rows] = pa.reduced
        if pa.direction is not None:
            out.direction[rows] = pa.direction
    return out


def _patched_frozen(surface, points, pairing, second, near=0.0) -> Contact:
    """`patched_contact` with a frozen `Pairing`: each part on its rows, as paired."""
    m = len(points)
    source = np.asarray(pairing.source, dtype=np.int64).reshape(-1)
    if len(source) != m:
        raise ValueError(f"the pairing holds {len(source)} contactors, not {m}")
    if source.max(initial=-1) >= surface.npatches:
        raise ValueError("the pairing names patches this surface does not have: pass the "
                         "Contact.pairing of this surface (or of one moved from it)")
    proj = _unanswered(points, source=source.copy(), pairing=pairing)
    nothing = (source < FACETS) & (source != CELLS)
    proj.status[nothing], proj.reason[nothing] = OUTSIDE, OFF_TARGET
    parts = []
    for p in np.unique(source[source >= 0]):
        rows = np.flatnonzero(source == p)
        c = diffuse_contact(surface.surfaces[p], points[rows],
                            pairing=pairing.patch.take(rows), second=second, near=near,
                            own_edges=False)
        nodes = np.where(c.nodes >= 0, surface.patch_nodes[p][np.maximum(c.nodes, 0)], -1)
        for name in _MERGED:
            getattr(proj, name)[rows] = getattr(c.projection, name)
        parts.append((rows[c.contactor], nodes, c.gap, c.N, c.M))
    rows = np.flatnonzero(source == FACETS)
    if len(rows):
        c = facet_contact(surface.facet_surface(), points[rows],
                          pairing=np.asarray(pairing.facet)[rows], second=second, near=near)
        for name in _MERGED:
            getattr(proj, name)[rows] = getattr(c.projection, name)
        parts.append((rows[c.contactor], c.nodes, c.gap, c.N, c.M))
    rows = np.flatnonzero(source == CELLS)
    if len(rows):  # the paired cell (a second-order cell: a node-to-cell element)
        parts.append(frozen_part(surface, points, rows, np.asarray(pairing.facet)[rows], proj,
                                 second))
    return _merged_contact(surface, proj, parts, second, False)


def _merged_contact(surface, proj, parts, second, rigid_target) -> Contact:
    """The Contact of the parts' elements (contactor rows, global nodes, gap, N, M), in
    contactor order, K padded to the widest."""
    K = max([part[1].shape[1] for part in parts], default=0)
    if len(parts) == 1 and parts[0][1].shape[1] == K:  # one part: its arrays as they are
        contactor, nodes, gap, N, M = parts[0]
        return Contact(contactor, nodes, gap, N, M, proj, len(surface.nodes), bool(rigid_target))
    contactor = np.concatenate([part[0] for part in parts] + [np.zeros(0, np.int64)])
    # each element straight to its place in contactor order (ℳ is the bulk: copied once)
    place = np.empty(len(contactor), np.int64)
    place[np.argsort(contactor, kind="stable")] = np.arange(len(contactor))
    e = len(contactor)
    width = 3 * (K + 1)
    lazy = blocks.on_demand(e, width, second)
    nodes = np.full((e, K), -1, np.int64)
    gap = np.empty(e)
    N = np.zeros((e, width))
    M = np.zeros((e, width, width)) if second and not lazy else None
    part_of, index_in = np.empty(e, np.int64), np.empty(e, np.int64)
    at = 0
    for p, (rows, nd, g, n, mm) in enumerate(parts):  # u = [x^c, x^nodes...]: padding last
        pos = place[at:at + len(rows)]
        w = n.shape[1]
        nodes[pos, :nd.shape[1]], gap[pos], N[pos, :w] = nd, g, n
        part_of[pos], index_in[pos] = p, np.arange(len(rows))
        if M is not None:
            M[pos, :w, :w] = mm[:]
        at += len(rows)
    if lazy:  # each part's ℳ (whole, or itself built on demand), never one merged copy
        def hessians(idx, out):
            out[:] = 0.0
            for p in np.unique(part_of[idx]):
                sel = np.flatnonzero(part_of[idx] == p)
                block = parts[p][4][index_in[idx[sel]]]
                out[sel, :block.shape[1], :block.shape[2]] = block
            return out

        M = Hessians(hessians, e, width)
    return Contact(np.sort(contactor), nodes, gap, N, M, proj, len(surface.nodes),
                   bool(rigid_target))


#: Contactors per chunk of `assemble` (rigid target, full element), and of the diffuse
#: elements `contact` builds at a time. The full element's ℳ is built on demand in
#: `assemble`'s second pass (`blocks.always_on_demand`): no chunk's ℳ is ever whole.
CHUNK_RIGID = 65536
CHUNK_FULL = 1024


def _pairing_rows(pairing, lo, hi):
    if pairing is None:
        return None
    if isinstance(pairing, (Pairing, Patch)):
        return pairing.take(slice(lo, hi))
    return np.asarray(pairing)[lo:hi]


def assemble(surface, points, penalty, contactor_dofs, target_dofs=None, *, n_dofs=None,
             rigid_target=False, pairing=None, chunk=None, gauss_newton=False,
             multipliers=None):
    """Residual and tangent of a large contactor cloud, in bounded memory.

    Projects and builds the elements `chunk` contactors at a time (as `contact`), twice: a
    first pass (no ℳ) keeps each element's nodes for K's CSR pattern (`_CompiledSum`), a
    second builds the same elements with ℳ and adds each chunk's residual and tangent (as
    `Contact.residual` and `Contact.tangent`) into R and K in place: only one chunk's
    elements are alive at once, and K is allocated once, at its size. Arguments as `contact`
    and `Contact.tangent`; `penalty` and `contactor_dofs` have a row per contactor of
    `points`, `pairing` too. `multipliers` (m,): an augmented Lagrangian's
    (`Contact.residual`), each chunk's contact built with `near=Contact.reach` of its own, so
    that every contactor that carries a force has its element.

    Returns
    -------
    R : (n_dofs,) float
    K : (n_dofs, n_dofs) scipy.sparse.csr_matrix
    status : (m,) int8     each contactor's status (index into STATUS); elements exist for
                           those that penetrate or touch (g <= 0: status penetration,
                           or contact at or below zero)
    """
    points = np.asarray(points, dtype=np.float64)
    m = len(points)
    contactor_dofs = np.asarray(contactor_dofs)
    if contactor_dofs.shape != (m, 3):
        raise ValueError(f"contactor_dofs: expected shape ({m}, 3), got {contactor_dofs.shape}")
    penalty = check_penalty(penalty)
    if penalty.ndim and penalty.shape != (m,):
        raise ValueError(f"penalty: expected a number or one per contactor ({m},), got shape "
                         f"{penalty.shape}")
    size = Contact._size(n_dofs, contactor_dofs, target_dofs)
    if chunk is None:
        chunk = CHUNK_RIGID if rigid_target else CHUNK_FULL
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    check_pairing(surface, pairing, m)  # here, whole: each chunk takes its rows of it
    if multipliers is not None:
        multipliers = np.asarray(multipliers, dtype=np.float64)
        if multipliers.shape != (m,):
            raise ValueError(f"multipliers: expected one per contactor ({m},), got shape "
                             f"{multipliers.shape}")
    def chunk_contact(lo, hi, second):
        eps = penalty if not penalty.ndim else penalty[lo:hi]
        lam = None if multipliers is None else multipliers[lo:hi]
        c = contact(surface, points[lo:hi], rigid_target=rigid_target,
                    pairing=_pairing_rows(pairing, lo, hi), second=second,
                    near=0.0 if lam is None else Contact.reach(eps, lam))
        return c, eps, lam

    # pass 1: the elements' nodes (no ℳ), for the tangent's pattern, built once
    ids, n_target = [np.zeros((0, 1), np.int64)], len(getattr(surface, "nodes", ()))
    for lo in range(0, m, chunk):
        c = chunk_contact(lo, min(lo + chunk, m), False)[0]
        ids.append(_node_ids(c, lo, m))
        n_target = c.n_target
        del c
    width = max(i.shape[1] for i in ids)
    ids = [np.pad(i, ((0, 0), (0, width - i.shape[1])), constant_values=-1) for i in ids]
    K = _CompiledSum(size, _node_dofs(contactor_dofs, target_dofs, m, n_target),
                     np.concatenate(ids))
    del ids  # `add` refuses a node pair the pattern does not hold: no need to keep them
    # pass 2: the same elements again, with ℳ, summed into it
    R = np.zeros(size)
    status = np.empty(m, dtype=np.int8)
    for lo in range(0, m, chunk):
        hi = min(lo + chunk, m)
        with blocks.always_on_demand():  # each element's ℳ added as it is built
            c, eps, lam = chunk_contact(lo, hi, not gauss_newton)
        status[lo:hi] = c.status
        c._add_residual(R, eps, contactor_dofs[lo:hi], target_dofs, lam)
        c._add_tangent(K, eps, _node_ids(c, lo, m), gauss_newton, lam)
        del c
    return R, K.result(), status
