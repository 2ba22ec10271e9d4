"""The rigid-target element: the gap as the signed distance to one fixed smooth surface.

For a rigid target only the contactor's unknowns x^c matter (method.md, "Rigid targets").
The frozen pairing of the full element [§4.2] makes its gap depend on where the pairing was
taken; here instead the target is ONE fixed surface S, built once, and the gap is a smooth
function of x^c alone.

S is the zero set of a partition-of-unity blend of the local approximations [12]-[17], fitted
once at every target node j (its frame, radius and support as the projection would take them
there; polynomial α_j by weighted least squares [16]-[17]):

    φ_j(y) = R_j (Z3 − f_j(Z1, Z2)),   Z = axes_j (y − o_j) / R_j       (an algebraic height)
    Φ(y) = Σ_j ψ_j(y) φ_j(y),   ψ_j = w_j / Σ_k w_k,   w_j = W(|y − x_j| / (β h_j))

W is Wendland's C² (1 − r)^4 (4r + 1), h_j the node spacing. Φ is C² wherever Σ w > 0 (the
surface's reach; beyond it a contactor is 'outside').

The proximal point y* is the closest point of {Φ = 0} to x^c: Newton on the Lagrange system
(y − x^c + λ∇Φ = 0, Φ = 0), started from one projection step x^c − Φ∇Φ/|∇Φ|², run to
round-off. Then ν = ∇Φ/|∇Φ| (out of the target, as the frames' e3), g = (x^c − y*)·ν [32],
∂g/∂x^c = ν, and ∂²g/∂x^c² = L (I + gL)⁻¹ with L = P ∇²Φ P / |∇Φ| (P = I − ννᵀ) the shape
operator of S at y*: Σ κ_i / (1 + g κ_i) t_i t_iᵀ, κ_i > 0 where S bends away from ν.

Where the target has two sheets within reach of each other (a thin plate or tube), a
contactor blends only the nodes of the sheet of its nearest node: those whose frame's e3 is
within the projection's sheet angle (tol.SHEET_ANGLE_DEG) of that node's.

The closest point runs in the compiled kernel `_rigid.pyx`, in parallel over contactors; its
numpy twin is tests/reference_rigid.py. A contactor's candidate nodes, and the order of every
sum over them, are fixed by x^c alone (grid cells, then node order), so its answer is bitwise
the same whatever batch, order or company it is evaluated in.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from .. import tol
from ..mls import basis as _basis
from ..mls.surface import CHUNK as FIT_CHUNK
from ..mls.surface import DiffuseSurface
from ..projection import BAD_POINT, FAILED, OFF_TARGET, OUTSIDE, PENETRATION
from . import _rigid
from .penalty import check_penalty

#: Radius of each node's blending weight, in its node spacings (β; measured in tol.py).
BLEND_SPACINGS = tol.RIGID_BLEND_SPACINGS

_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


@dataclass
class RigidResult:
    """The rigid-target gap of each contactor and its derivatives (one row per contactor).

    gap : (m,) float              g = (x^c − y*)·ν, > 0 open, < 0 penetration [32]
    normal : (m, 3) float         ν = ∂g/∂x^c, unit, out of the target
    proximal_point : (m, 3) float y*, the closest point of S
    hessian : (m, 3, 3) float or None   ∂²g/∂x^c² (None when second=False)
    curvature : (m, 2) float      principal curvatures κ1 ≥ κ2 of S at y*, > 0 convex
    status : (m,) int8            index into projection.STATUS
    reason : (m,) int8            index into projection.REASONS
    iterations : (m,) int         Newton iterations
    """

    gap: np.ndarray
    normal: np.ndarray
    proximal_point: np.ndarray
    hessian: np.ndarray | None
    curvature: np.ndarray
    status: np.ndarray
    reason: np.ndarray
    iterations: np.ndarray

    def residual(self, penalty) -> np.ndarray:
        """R = ε g ν (m, 3) [45], the contactor's block; `penalty` ε a scalar or (m,)."""
        eps = np.broadcast_to(check_penalty(penalty), self.gap.shape)
        return (eps * self.gap)[:, None] * self.normal

    def tangent(self, penalty, *, gauss_newton: bool = False) -> np.ndarray:
        """K = ε (g ∂²g/∂x² + ν νᵀ) (m, 3, 3) [54], the contactor's block (needs second=True);
        with `gauss_newton`, ε ν νᵀ."""
        eps = np.broadcast_to(check_penalty(penalty), self.gap.shape)
        K = eps[:, None, None] * self.normal[:, :, None] * self.normal[:, None, :]
        if gauss_newton:
            return K
        if self.hessian is None:
            raise ValueError("the tangent needs the Hessian of g: evaluate with second=True")
        return K + (eps * self.gap)[:, None, None] * self.hessian


def _fit_nodes(surface: DiffuseSurface, rows: np.ndarray):
    """α_j of the local approximation at nodes `rows`, with the projection's own frame,
    radius, support and fit there (the engine's α: a node is its own reference point, so the
    basis is centred on it). Returns (ok, origin, axes, radius, alpha)."""
    proj = surface.project(surface.nodes[rows], keep_patch=True)
    p = proj.patch
    ok = (proj.status <= PENETRATION) & np.all(np.isfinite(proj.alpha), axis=1)
    return ok, p.origin, p.axes, p.radius, proj.alpha


class RigidTarget:
    """The fixed smooth surface S of a rigid target and the gap to it (module docstring).

    Parameters
    ----------
    surface : DiffuseSurface
        The target: its nodes, basis, weight, frame choice and radius define the local
        approximations blended into S.
    beta : float
        Radius of each node's blending weight, in node spacings (`BLEND_SPACINGS`).
    """

    def __init__(self, surface: DiffuseSurface, *, beta: float = BLEND_SPACINGS):
        if not isinstance(surface, DiffuseSurface):
            raise TypeError("a rigid target is built on a DiffuseSurface")
        self.basis = surface.basis
        self.exponents = np.array(_basis.EXPONENTS[surface.basis], dtype=np.int64)
        self.beta = float(beta)
        distinct = np.unique(surface.first)  # each position once
        chunks = [_fit_nodes(surface, distinct[lo:lo + FIT_CHUNK])  # bounded pairing memory
                  for lo in range(0, len(distinct), FIT_CHUNK)]
        ok, origin, axes, radius, alpha = (np.concatenate(c) for c in zip(*chunks))
        keep = distinct[ok]
        #: target node index of each blended local approximation
        self.node = keep
        self.position = np.ascontiguousarray(surface.nodes[keep])
        self.origin = np.ascontiguousarray(origin[ok])
        self.axes = np.ascontiguousarray(axes[ok])
        self.radius = np.ascontiguousarray(radius[ok])
        self.alpha = np.ascontiguousarray(alpha[ok])
        self.spacing = np.ascontiguousarray(surface.node_spacing[keep])
        self.reach = self.beta * self.spacing  # ρ_j: w_j vanishes beyond
        self.reach_max = float(self.reach.max()) if len(keep) else 0.0
        self._arrays = self._grid()
        # what `feet` needs: the surface's facets, or its projection (a weak reference: the
        # cache's value must not keep its key alive)
        self._surface = weakref.ref(surface)

    def _grid(self) -> dict:
        """Cells of the largest blending radius over the fitted nodes, as sorted cell keys."""
        cell = self.reach_max if self.reach_max > 0 else 1.0
        pos = self.position
        lo = pos.min(axis=0) - cell if len(pos) else np.zeros(3)
        hi = pos.max(axis=0) + cell if len(pos) else np.ones(3)
        dims = np.maximum(np.ceil((hi - lo) / cell), 1.0)
        while np.prod(dims) > 2.0**62:  # cell keys must fit an int64: coarser cells
            cell *= 2.0
            dims = np.maximum(np.ceil((hi - lo) / cell), 1.0)
        dims = dims.astype(np.int64)
        c = np.clip(np.floor((pos - lo) / cell).astype(np.int64), 0, dims - 1)
        keys = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
        order = np.argsort(keys, kind="stable")
        return {"position": self.position, "origin": self.origin, "axes": self.axes,
                "radius": self.radius, "alpha": self.alpha, "reach": self.reach,
                "spacing": self.spacing,
                "ea": np.ascontiguousarray(self.exponents[:, 0]),
                "eb": np.ascontiguousarray(self.exponents[:, 1]),
                "keys": np.ascontiguousarray(keys[order]), "order": order.astype(np.int64),
                "lo": np.ascontiguousarray(lo, dtype=np.float64), "dims": dims,
                "cell": float(cell), "reach_max": self.reach_max,
                "step_tol": tol.NEWTON_STEP, "max_iter": tol.NEWTON_MAX_ITER,
                "outside": tol.OUTSIDE_SPACINGS, "contact": tol.CONTACT,
                "hull": tol.HULL_SPACINGS,
                "sheet": float(np.cos(np.radians(tol.SHEET_ANGLE_DEG)))}

    @classmethod
    def for_surface(cls, surface: DiffuseSurface) -> RigidTarget:
        """One cached RigidTarget per surface object (built on first use)."""
        try:
            return _CACHE[surface]
        except KeyError:
            rigid = _CACHE[surface] = cls(surface)
            return rigid

    # -- the gap -----------------------------------------------------------------------------
    def evaluate(self, points, *, second: bool = True) -> RigidResult:
        """Gap, normal (= ∂g/∂x^c), proximal point, Hessian ∂²g/∂x^c², curvatures and
        status of each contactor (m, 3) on the fixed surface S.

        A contactor beyond the reach of every node's weight (deeper or farther than
        `BLEND_SPACINGS` node spacings) starts its search from its faceted foot (`feet`).
        'outside' (reason 'off-target'): no node's weight reaches even that foot, or y*
        past the target's edge as the projection decides it (farther than
        tol.OUTSIDE_SPACINGS spacings from every node, or tol.HULL_SPACINGS beyond the
        tangent-plane hull of the nodes that reach it); 'failed': NaN or inf
        contactors (bad-point), a Newton that did not converge, left the reach or found no
        minimum of the distance (no-convergence); NaNs in those rows."""
        x = np.ascontiguousarray(points, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"points must have shape (m, 3), got {x.shape}")
        m = len(x)
        res = RigidResult(np.full(m, np.nan), np.full((m, 3), np.nan), np.full((m, 3), np.nan),
                          np.full((m, 3, 3), np.nan) if second else None,
                          np.full((m, 2), np.nan), np.full(m, FAILED, np.int8),
                          np.full(m, BAD_POINT, np.int8), np.zeros(m, np.int64))
        finite = np.flatnonzero(np.all(np.isfinite(x), axis=1))
        if len(self.position) == 0:
            res.status[finite], res.reason[finite] = OUTSIDE, OFF_TARGET
            return res
        hess = res.hessian.reshape(m, 9) if second else np.empty((1, 9))
        outcome = np.empty(m, np.int8)
        cap = CANDIDATES
        # contactors in the order of their grid cells, so neighbours read the same nodes
        # (each answer is independent of the order)
        a = self._arrays
        c = np.clip(np.floor((x[finite] - a["lo"]) / a["cell"]), 0, a["dims"] - 1).astype(np.int64)
        todo = finite[np.argsort((c[:, 0] * a["dims"][1] + c[:, 1]) * a["dims"][2] + c[:, 2],
                                 kind="stable")]
        cap = self._solve(x, todo, res, hess, outcome, second, cap)
        # beyond the blend's reach (deep or far): start from the faceted foot instead, which
        # lies on the target near its nodes wherever x^c is
        beyond = finite[outcome[finite] == _BEYOND]
        if len(beyond):
            seeds = np.full_like(x, np.nan)
            seeds[beyond] = self.feet(x[beyond])
            self._solve(x, beyond[np.isfinite(seeds[beyond, 0])], res, hess, outcome, second,
                        cap, seeds)
        return res

    def _solve(self, x, todo, res, hess, outcome, second, cap, seeds=None) -> int:
        """Run the kernel on rows `todo` (with more candidate room where it ran out); returns
        the capacity reached."""
        while len(todo):
            _rigid.closest_points(self._arrays, x, todo, res.gap, res.normal,
                                  res.proximal_point, hess, res.curvature, res.status,
                                  res.reason, res.iterations, outcome, second, cap,
                                  seeds=seeds)
            todo = todo[outcome[todo] == _OVERFLOW]
            cap = max(min(4 * cap, len(self.position)), cap + 1)
        return cap

    def feet(self, points) -> np.ndarray:
        """The faceted foot of each point (its closest point on the target's facets,
        `DiffuseSurface.facet_surface`; with no facets, the projection's proximal point):
        where the search of a contactor beyond the blend's reach starts. NaN rows: none (the
        surface is gone)."""
        surface = self._surface()
        if surface is None:
            return np.full((len(points), 3), np.nan)
        facets = surface.facet_surface()
        return (facets if facets is not None else surface).project(points).proximal_point


#: The compiled kernel's outcomes: a contactor beyond the reach of every node's weight, and
#: one with more candidates than its scratch.
_BEYOND = 2
_OVERFLOW = 4
#: Initial capacity of the kernel's candidate list per contactor.
CANDIDATES = 256
