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

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from ..facet.surface import FacetSurface
from ..mls.surface import DiffuseSurface
from ..patches.surface import CELLS, FACETS, PatchedSurface
from ..projection import (
    BAD_POINT,
    FAILED,
    GUARD,
    ILL_CONDITIONED,
    NO_CONVERGENCE,
    OFF_TARGET,
    OK,
    OPEN,
    OUTSIDE,
    PENETRATION,
    Pairing,
    Patch,
    Projection,
    as_points,
)
from . import blocks
from .blocks import Hessians
from .cell import cell_part, frozen_part
from .diffuse import diffuse_elements
from .facet import facet_element  # noqa: F401  (the one-element API)
from .facet import facet_elements as facet_elements_kernel
from .friction import History, Tractions, coulomb
from .penalty import check_penalty
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

    One element per closed contact (status penetration, g < 0), in contactor order; K is the
    widest element's number of target nodes (0 with a rigid target).

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
    friction : Coulomb or None      friction on a rigid target (`element.friction`):
                                    `residual` and `tangent` then hold its tangential part
    start : History or None         the state friction starts from (`contact(history=)`)

    `status` and `reason` (m,) are the projection's: a contactor has an element exactly when
    its status is penetration; open and contact (|g| within tolerance) ones need none;
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
    _penalty_used: object = field(default=None, init=False, repr=False)

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
        contactor_dofs = np.asarray(contactor_dofs)
        if contactor_dofs.shape != (len(self.status), 3):
            raise ValueError(f"contactor_dofs: expected shape ({len(self.status)}, 3), got "
                             f"{contactor_dofs.shape}")
        own = contactor_dofs[self.contactor].astype(np.int64)[:, None, :]
        K = self.nodes.shape[1]
        if target_dofs is None:
            other = np.full((len(self), K, 3), -1, dtype=np.int64)
        else:
            target_dofs = np.asarray(target_dofs)
            if target_dofs.shape != (self.n_target, 3):
                raise ValueError(f"target_dofs: expected shape ({self.n_target}, 3), got "
                                 f"{target_dofs.shape}")
            other = np.where(self.nodes[:, :, None] >= 0,
                             target_dofs[np.maximum(self.nodes, 0)], -1).astype(np.int64)
        return np.concatenate([own, other], axis=1).reshape(len(self), 3 * (K + 1))

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

    def residual(self, penalty, contactor_dofs, target_dofs=None, n_dofs=None) -> np.ndarray:
        """Assembled residual Σ ε g 𝒩 [45] over the elements, at the caller's DOFs; with
        friction, plus each contactor's tangential part T (`element.friction`).

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

        Returns
        -------
        (n_dofs,) float
        """
        out = np.zeros(self._size(n_dofs, contactor_dofs, target_dofs))
        self._add_residual(out, penalty, contactor_dofs, target_dofs)
        return out

    def _add_residual(self, out: np.ndarray, penalty, contactor_dofs, target_dofs) -> None:
        dofs = self.dofs(contactor_dofs, target_dofs)
        vals = (self._penalty(penalty) * self.gap)[:, None] * self.N
        if self.friction is not None:
            vals[:, :3] += self._tangential(penalty, second=False)[0]
        keep = dofs >= 0
        np.add.at(out, dofs[keep], vals[keep])

    # ---------------------------------------------------------------------------- friction

    def _tangential(self, penalty, second: bool = True, curvature: bool = True):
        """(T (e, 3), ∂T/∂x (e, 3, 3) or None, stick (e,)) of the elements under `friction`
        (`friction.coulomb`), with the normal penalty `penalty`; without `curvature` (the
        Gauss-Newton tangent), ∂T/∂x with H = 0."""
        self._penalty_used = penalty
        eps = self._penalty(penalty)
        try:
            eps_t = eps if self.friction.penalty_t is None else self._penalty(
                self.friction.penalty_t)
        except ValueError as exc:
            raise ValueError(f"Coulomb.penalty_t: {exc}".replace("penalty: ", "")) from None
        if self.start is None:
            y_n, tau_n = np.full((len(self), 3), np.nan), np.zeros((len(self), 3))
        else:
            y_n = np.asarray(self.start.proximal_point, np.float64)[self.contactor]
            tau_n = np.asarray(self.start.traction, np.float64)[self.contactor]
        y = np.asarray(self.projection.proximal_point, np.float64)[self.contactor]
        H = None
        if second:
            H = np.asarray(self.M) if curvature else np.zeros((len(self), 3, 3))
        return coulomb(self.gap, self.N, H, y, y_n, tau_n, float(self.friction.mu), eps,
                       eps_t, second)

    def tractions(self, penalty):
        """The normal and tangential forces on each contactor (m rows) with the normal
        penalty `penalty` (`friction.Tractions`; tangential 0 without friction)."""
        m = len(self.status)
        normal, tangential, stick = np.zeros(m), np.zeros((m, 3)), np.zeros(m, bool)
        normal[self.contactor] = self._penalty(penalty) * np.abs(self.gap)
        if self.friction is not None:
            T, _, sticks = self._tangential(penalty, second=False)
            tangential[self.contactor] = -T
            stick[self.contactor] = sticks
        return Tractions(normal, tangential, stick)

    @property
    def history(self):
        """The state friction starts from at the next step (`friction.History`), for when
        this call's positions are the converged ones: every contactor's proximal point (NaN
        where it has none) and the tangential part τ of its residual (0 where it has no
        element), with the normal penalty of the last `residual`, `tangent` or `tractions`
        call."""
        if self.friction is None:
            raise ValueError("history: this contact has no friction (contact(..., "
                             "rigid_target=True, friction=Coulomb(mu)))")
        if self._penalty_used is None:
            raise ValueError("history needs the normal penalty: call residual, tangent or "
                             "tractions first")
        tau = np.zeros((len(self.status), 3))
        tau[self.contactor] = self._tangential(self._penalty_used, second=False)[0]
        y = np.array(self.projection.proximal_point, dtype=np.float64)
        y[~np.all(np.isfinite(y), axis=1)] = np.nan
        return History(y, tau)

    def tangent(self, penalty, contactor_dofs, target_dofs=None, n_dofs=None, *,
                gauss_newton: bool = False) -> sp.csr_matrix:
        """Assembled tangent Σ ε (g ℳ + 𝒩 𝒩ᵀ) [54], sparse and symmetric, same arguments and
        DOFs as `residual`; with friction, plus ∂T/∂x on each contactor's block (not
        symmetric in slip).

        gauss_newton : bool
            Σ ε 𝒩 𝒩ᵀ only: positive semi-definite whatever the gap and the curvature, and
            needs no ℳ (`contact(..., second=False)` is enough), at the price of Newton's
            quadratic convergence (linear, fast while penetrations are small)."""
        size = self._size(n_dofs, contactor_dofs, target_dofs)
        total = _SparseSum((size, size))
        self._add_tangent(total, penalty, contactor_dofs, target_dofs, gauss_newton)
        return total.result()

    def _add_tangent(self, total: _SparseSum, penalty, contactor_dofs, target_dofs,
                     gauss_newton: bool = False) -> None:
        if self.M is None and not gauss_newton:
            raise ValueError("the tangent needs ℳ: build the contact with second=True (or "
                             "ask for the Gauss-Newton tangent)")
        dofs = self.dofs(contactor_dofs, target_dofs)
        eps = self._penalty(penalty)
        width = dofs.shape[1]
        step = max(1, blocks.TANGENT_BATCH // (width * width))
        dT = (self._tangential(penalty, curvature=not gauss_newton)[1]
              if self.friction is not None else None)
        for lo in range(0, len(self), step):  # a batch of elements at once (bounded memory)
            hi = min(lo + step, len(self))
            N, d = self.N[lo:hi], dofs[lo:hi]
            vals = eps[lo:hi, None, None] * N[:, :, None] * N[:, None, :]
            if not gauss_newton:
                vals += (eps[lo:hi] * self.gap[lo:hi])[:, None, None] * self.M[lo:hi]
            if dT is not None:  # the contactor's block: a rigid target's only one
                vals[:, :3, :3] += dT[lo:hi]
            rows = np.broadcast_to(d[:, :, None], vals.shape)
            cols = np.broadcast_to(d[:, None, :], vals.shape)
            keep = (rows >= 0) & (cols >= 0)
            total.add(rows[keep], cols[keep], vals[keep])

    def energy(self, penalty) -> float:
        """Σ ε g²/2 over the elements: R and K are its gradient and Hessian (without friction,
        which dissipates: it has no potential)."""
        return float(np.sum(0.5 * self._penalty(penalty) * self.gap**2))


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


def _unanswered(points, **fields) -> Projection:
    """A Projection of nothing yet (NaN, status failed, reason ok) for the parts of a frozen
    pairing to fill; `fields`: its other declared fields (source, pairing)."""
    m = len(points)
    return Projection(points, np.full(m, np.nan), np.full((m, 3), np.nan),
                      np.full((m, 3), np.nan), np.full(m, FAILED, np.int8),
                      np.zeros(m, np.int64), np.zeros(m, np.int64), np.full(m, np.nan),
                      np.full((m, 2), np.nan), np.full(m, OK, np.int8), **fields)


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
            second: bool = True, friction=None, history=None) -> Contact:
    """Project `points` and build the contact element of every closed contact (g < 0).

    Parameters
    ----------
    surface : DiffuseSurface, FacetSurface or PatchedSurface
        The target. On a PatchedSurface each contactor's element is that of what answered it
        (`patched_contact`): its patch's diffuse element, or the node-to-facet element where
        the facets answered (a sharp edge, a patch that cannot answer, the guard).
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
        Coulomb friction, on a rigid target only (`element.friction`): the slip is the
        proximal point's motion on the target's surface since `history`.
    history : History, optional
        The last converged state (`Contact.history` of that call); None at the first step
        (no tangential traction until a converged state exists).

    Returns
    -------
    Contact
    """
    points = np.asarray(points, dtype=np.float64)
    if friction is not None and not rigid_target:
        raise ValueError("friction is built for a rigid target (rigid_target=True); the "
                         "full element with friction is not")
    if history is not None:
        if friction is None:
            raise ValueError("history is friction's: pass friction=Coulomb(mu) too")
        history.check(len(points))
    # the one dispatch: the surfaces answer geometric questions (project, project_with,
    # moved); which element each kind of target takes is decided here
    if isinstance(surface, PatchedSurface):
        build = patched_contact
    elif isinstance(surface, DiffuseSurface):
        build = diffuse_contact
    elif isinstance(surface, FacetSurface):
        build = facet_contact
    else:
        raise TypeError(f"{type(surface).__name__} is not a surface: expected a DiffuseSurface, "
                        f"FacetSurface or PatchedSurface (projection.Surface)")
    c = build(surface, points, rigid_target=rigid_target, pairing=pairing, second=second)
    c.lost = lost_contactors(surface, points, c.projection)
    c.friction, c.start = friction, history
    return c


def facets_of(surface):
    """The faceted target under any surface: a FacetSurface itself, a PatchedSurface's
    facets, a DiffuseSurface's own (`DiffuseSurface.facet_surface`); None without facets."""
    if isinstance(surface, FacetSurface):
        return surface
    if isinstance(surface, PatchedSurface):
        return surface.facet_surface()
    if isinstance(surface, DiffuseSurface):
        return surface.facet_surface()
    return None


def lost_contactors(surface, points, proj) -> np.ndarray:
    """Contactors with no answer (status outside or failed; not a NaN contactor) that the
    target's facets find penetrating: a solver must not take them for open. On a target
    without facets (a point cloud) every unanswered contactor counts."""
    rows = np.flatnonzero(((proj.status == OUTSIDE) | (proj.status == FAILED))
                          & (proj.reason != BAD_POINT))
    facets = facets_of(surface) if len(rows) else None
    if facets is None:
        return rows.astype(np.int64)
    return rows[facets.project(points[rows]).status == PENETRATION].astype(np.int64)


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
        if isinstance(surface, DiffuseSurface) and pairing.patch is None:
            raise ValueError(f"the pairing holds no frames and supports (a FacetSurface's?), "
                             f"not a {kind}'s")
        if isinstance(surface, FacetSurface) and pairing.facet is None:
            raise ValueError(f"the pairing holds no facets (a DiffuseSurface's?), not a "
                             f"{kind}'s")
    elif isinstance(pairing, Patch):
        if isinstance(surface, FacetSurface):
            raise ValueError(f"a Patch (the frames and supports of a DiffuseSurface) is no "
                             f"pairing for a {kind}: pass the Contact.pairing of this surface")
    elif isinstance(surface, DiffuseSurface):
        raise ValueError(f"facet indices (a FacetSurface's pairing) are no pairing for a "
                         f"{kind}: pass the Contact.pairing of this surface, or a Patch")
    count = pairing_count(pairing)
    if count != m:
        raise ValueError(f"the pairing is for {count} contactors, got {m}")


def facet_contact(surface, points, *, rigid_target=False, pairing=None,
                  second=True) -> Contact:
    """`contact` on a FacetSurface: the node-to-facet element [§2]."""
    check_pairing(surface, pairing, len(as_points(points)))
    if isinstance(pairing, Pairing):
        pairing = pairing.facet
    proj = surface.project(points) if pairing is None else surface.project_with(points, pairing)
    if not rigid_target:
        proj.pairing = Pairing(np.where(proj.facet >= 0, -1, -2).astype(np.int64), None,
                               proj.facet.copy(), type(surface).__name__)
    rows = np.flatnonzero(proj.status == PENETRATION)
    width = 3 if rigid_target else 15
    lazy = blocks.on_demand(len(rows), width, second)
    gap, nodes, N, M = facet_elements(surface, points, proj, rows, second and not lazy,
                                      rigid_target)

    def hessians(r, out):  # a block of its own (Hessians.take copies it into out)
        return facet_elements(surface, points, proj, r, True, rigid_target)[3]

    return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target,
                   hessians if lazy else None)


def diffuse_contact(surface, points, *, rigid_target=False, pairing=None,
                    second=True) -> Contact:
    """`contact` on a DiffuseSurface: the diffuse element of the contactor's own local
    approximation [§4.2-4.3], or the rigid target's (`element.rigid`)."""
    if rigid_target:
        if pairing is not None:
            raise ValueError("a rigid target's gap is the signed distance to the diffuse "
                             "surface: it needs no pairing")
        res = RigidTarget.for_surface(surface).evaluate(points, second=second)
        proj = _as_projection(res, points)
        _far_and_open(surface, points, proj)
        rows = np.flatnonzero(proj.status == PENETRATION)
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
    proj = (surface.project(points, keep_patch=True) if pairing is None
            else surface.project_with(points, pairing))
    proj.pairing = Pairing(np.zeros(len(points), np.int64), proj.patch, None,
                           type(surface).__name__)
    rows = np.flatnonzero(proj.status == PENETRATION)
    # the widest support among the elements bounds their width (nodes of zero weight drop)
    count = (np.asarray(proj.patch.index).reshape(len(points), -1) >= 0).sum(axis=1)
    K = int(count[rows].max(initial=0))
    lazy = blocks.on_demand(len(rows), 3 * (K + 1), second)
    gap, nodes, N, M = _diffuse_in_chunks(surface, points, proj, rows, K, second and not lazy)

    def hessians(r, out):
        return diffuse_elements(surface, points, proj.patch, proj.proximal_point, r, True,
                                width=(out.shape[1] // 3 - 1), out=out)[3]

    return _finish(surface, proj, rows, gap, nodes, N, M, rigid_target,
                   hessians if lazy else None)


def _diffuse_in_chunks(surface, points, proj, rows, K, second):
    """`diffuse_elements` of `rows`, `CHUNK_FULL` at a time into arrays of K support nodes
    (the widest support: narrowed to the widest element at the end, a view): the engine's
    per-call copies of the pairing stay one chunk's, whatever the count."""
    e, size = len(rows), 3 * (K + 1)
    gap = np.empty(e)
    nodes = np.full((e, K), -1, np.int64)
    N = np.zeros((e, size))
    M = np.zeros((e, size, size)) if second else None
    widest = 0
    for lo in range(0, e, CHUNK_FULL):
        hi = min(lo + CHUNK_FULL, e)
        g, nd, n, mm = diffuse_elements(surface, points, proj.patch, proj.proximal_point,
                                        rows[lo:hi], second)
        w = n.shape[1]
        gap[lo:hi], nodes[lo:hi, :nd.shape[1]], N[lo:hi, :w] = g, nd, n
        if second:
            M[lo:hi, :w, :w] = mm
        widest = max(widest, nd.shape[1])
    size = 3 * (widest + 1)
    return gap, nodes[:, :widest], N[:, :size], (M[:, :size, :size] if second else None)


def _finish(surface, proj, rows, gap, nodes, N, M, rigid_target, hessians=None) -> Contact:
    """The Contact of the elements of `rows`; an element the kernel could not compute (a
    singular fit or proximal-point system: NaN) is no element: its contactor fails, and says
    so. `hessians(contactor rows, out)`: their ℳ (into `out` where it can, as `Hessians`'
    build), for a Contact whose ℳ is built on demand (`Hessians`; M None here)."""
    bad = ~np.isfinite(gap) | ~np.isfinite(N).all(axis=1)
    if M is not None:
        bad |= ~np.isfinite(M).all(axis=(1, 2))
    if bad.any():
        proj.status[rows[bad]] = FAILED
        proj.reason[rows[bad]] = ILL_CONDITIONED
        keep = ~bad
        rows, gap, nodes, N = rows[keep], gap[keep], nodes[keep], N[keep]
        M = None if M is None else M[keep]
    rows = rows.astype(np.int64)
    if hessians is not None:
        M = Hessians(lambda idx, out: hessians(rows[idx], out), len(rows), N.shape[1])
    return Contact(rows, np.asarray(nodes, dtype=np.int64), gap, N, M, proj,
                   len(surface.nodes), bool(rigid_target))


#: Projection fields a part's own answer replaces in the merged projection of
#: `_patched_contact` (those every part has: diffuse, facet and rigid-target answers).
_MERGED = ("gap", "normal", "proximal_point", "status", "reason")


def patched_contact(surface, points, *, rigid_target=False, pairing=None,
                    second=True) -> Contact:
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
                               pairing=pairing, second=second)
    if pairing is not None:
        if rigid_target:
            raise ValueError("a rigid target's gap is the signed distance to its surface: it "
                             "needs no pairing")
        return _patched_frozen(surface, points, pairing, second)
    proj = surface.project(points)
    source = proj.source.copy()
    parts = []  # (contactor rows, nodes (global), gap, N, M) of each part
    held = []   # (rows, Patch) of each patch's contactors: the pairing
    for p in np.unique(source[source >= 0]):
        rows = np.flatnonzero(source == p)
        c = diffuse_contact(surface.surfaces[p], points[rows], rigid_target=rigid_target,
                            second=second)
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
                q.gap, q.normal, proj.facet[rows], proj.facet_gap[rows], np.nan_to_num(apart))
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
                          second=second)
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


def _patched_frozen(surface, points, pairing, second) -> Contact:
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
                            pairing=pairing.patch.take(rows), second=second)
        nodes = np.where(c.nodes >= 0, surface.patch_nodes[p][np.maximum(c.nodes, 0)], -1)
        for name in _MERGED:
            getattr(proj, name)[rows] = getattr(c.projection, name)
        parts.append((rows[c.contactor], nodes, c.gap, c.N, c.M))
    rows = np.flatnonzero(source == FACETS)
    if len(rows):
        c = facet_contact(surface.facet_surface(), points[rows],
                          pairing=np.asarray(pairing.facet)[rows], second=second)
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


#: Contactors per chunk of `assemble` (full element: each holds an ℳ of (3(K+1))² numbers),
#: and of the diffuse elements `contact` builds at a time.
CHUNK_RIGID = 65536
CHUNK_FULL = 1024


def _pairing_rows(pairing, lo, hi):
    if pairing is None:
        return None
    if isinstance(pairing, (Pairing, Patch)):
        return pairing.take(slice(lo, hi))
    return np.asarray(pairing)[lo:hi]


def assemble(surface, points, penalty, contactor_dofs, target_dofs=None, *, n_dofs=None,
             rigid_target=False, pairing=None, chunk=None, gauss_newton=False):
    """Residual and tangent of a large contactor cloud, in bounded memory.

    Projects and builds the elements `chunk` contactors at a time (as `contact`), assembles
    each chunk (as `Contact.residual` and `Contact.tangent`) and sums: only one chunk's
    elements are alive at once. Arguments as `contact` and `Contact.tangent`; `penalty` and
    `contactor_dofs` have a row per contactor of `points`, `pairing` too.

    Returns
    -------
    R : (n_dofs,) float
    K : (n_dofs, n_dofs) scipy.sparse.csr_matrix
    status : (m,) int8     each contactor's status (index into STATUS); elements exist for
                           those with status penetration
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
    R = np.zeros(size)
    K = _SparseSum((size, size))
    status = np.empty(m, dtype=np.int8)
    for lo in range(0, m, chunk):
        hi = min(lo + chunk, m)
        c = contact(surface, points[lo:hi], rigid_target=rigid_target,
                    pairing=_pairing_rows(pairing, lo, hi), second=not gauss_newton)
        status[lo:hi] = c.status
        eps = penalty if not penalty.ndim else penalty[lo:hi]
        c._add_residual(R, eps, contactor_dofs[lo:hi], target_dofs)
        c._add_tangent(K, eps, contactor_dofs[lo:hi], target_dofs, gauss_newton)
        del c
    return R, K.result(), status
