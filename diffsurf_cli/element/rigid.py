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

Every sum runs over a contactor's candidate nodes in node order, one slot after another, so
a contactor's answer is bitwise the same whatever batch it is evaluated in.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .. import tol
from ..mls import basis as _basis
from ..mls import weight as _weight
from ..mls.surface import (CONTACT, FAILED, NO_CONVERGENCE, OFF_TARGET, OK, OPEN, OUTSIDE,
                           PENETRATION, BAD_POINT, DiffuseSurface)

#: Radius of each node's blending weight, in its node spacings (β): measured with
#: benchmarks/rigid_speed.py --beta (accuracy against cost).
BLEND_SPACINGS = 1.5
#: Contactors per vectorised block (bounds the memory of the neighbour arrays).
CHUNK = 4096

_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


@dataclass
class RigidResult:
    """The rigid-target gap of each contactor and its derivatives (one row per contactor).

    gap : (m,) float              g = (x^c − y*)·ν, > 0 open, < 0 penetration [32]
    normal : (m, 3) float         ν = ∂g/∂x^c, unit, out of the target
    proximal_point : (m, 3) float y*, the closest point of S
    hessian : (m, 3, 3) float or None   ∂²g/∂x^c² (None when second=False)
    curvature : (m, 2) float      principal curvatures κ1 ≥ κ2 of S at y*, > 0 convex
    status : (m,) int8            index into mls.surface.STATUS
    reason : (m,) int8            index into mls.surface.REASONS
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


def _fit_nodes(surface: DiffuseSurface, rows: np.ndarray):
    """α_j of the local approximation at nodes `rows`, with the projection's own frame,
    radius and support there. Returns (ok, origin, axes, radius, alpha)."""
    proj = surface.project(surface.nodes[rows], keep_patch=True)
    p = proj.patch
    ok = proj.status <= PENETRATION
    idx = p.index
    valid = idx >= 0
    pos = surface.nodes[np.where(valid, idx, 0)]  # (m, K, 3)
    Z = np.einsum("mij,mkj->mki", p.axes, pos - p.origin[:, None, :]) / p.radius[:, None, None]
    s, t, z = Z[..., 0], Z[..., 1], Z[..., 2]
    q = np.where(valid, s * s + t * t, 1.0)
    w = np.where(valid, _weight.evaluate(surface.weight, q)[0], 0.0)  # [15]
    P = _basis.evaluate(surface.basis, s, t)  # (m, K, k) [14]
    root = np.sqrt(w)
    A = root[..., None] * P
    b = root * z
    # (Pᵀ W P) α = Pᵀ W Z [17] by QR of the column-equilibrated W^½ P
    norms = np.linalg.norm(A, axis=1)
    norms = np.maximum(norms, tol.EQUILIBRATION_FLOOR * norms.max(axis=1, keepdims=True))
    norms[norms == 0] = 1.0
    Q, R = np.linalg.qr(A / norms[:, None, :])
    diag = np.abs(np.diagonal(R, axis1=1, axis2=2))
    ok &= diag.min(axis=1) > 1e-12 * diag.max(axis=1)  # the projection refused worse fits
    R = np.where(ok[:, None, None], R, np.eye(R.shape[-1]))
    rhs = np.einsum("mkj,mk->mj", Q, b)
    alpha = np.linalg.solve(R, rhs[..., None])[..., 0] / norms
    return ok, p.origin, p.axes, p.radius, alpha


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
        chunks = [_fit_nodes(surface, distinct[lo:lo + surface_chunk()])
                  for lo in range(0, len(distinct), surface_chunk())]
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
        self.tree = cKDTree(self.position)

    @classmethod
    def for_surface(cls, surface: DiffuseSurface) -> "RigidTarget":
        """One cached RigidTarget per surface object (built on first use)."""
        try:
            return _CACHE[surface]
        except KeyError:
            rigid = _CACHE[surface] = cls(surface)
            return rigid

    # -- Φ and its derivatives ------------------------------------------------------------------
    def _field(self, y: np.ndarray, nb: np.ndarray, second: bool = True):
        """Φ, ∇Φ, ∇²Φ, Σw and the blended spacing at points y (m, 3) over the candidate
        nodes nb (m, K) (−1 padded, ascending). Sums run slot after slot (bitwise the same
        for a row whatever the other rows and the padding)."""
        m, K = nb.shape
        S = np.zeros(m)
        T = np.zeros(m)
        gS = np.zeros((m, 3))
        gT = np.zeros((m, 3))
        HS = np.zeros((m, 3, 3))
        HT = np.zeros((m, 3, 3))
        hw = np.zeros(m)
        dmin = np.full(m, np.inf)
        exps = self.exponents
        for k in range(K):
            j = nb[:, k]
            live = j >= 0
            if not live.any():
                break
            jj = np.where(live, j, 0)
            d = y - self.position[jj]
            dist = np.sqrt(np.einsum("mi,mi->m", d, d))
            dmin = np.where(live, np.minimum(dmin, dist), dmin)
            rho = self.reach[jj]
            r = dist / rho
            u = np.where(live, np.maximum(1.0 - r, 0.0), 0.0)
            u2 = u * u
            w = u2 * u2 * (4.0 * r + 1.0)  # Wendland C²: exact zeros beyond the reach
            gw = (-20.0 * u2 * u / (rho * rho))[:, None] * d  # ∇w
            # φ_j in frame j: Z = axes (y - o) / R, f and its derivatives in (s, t) = (Z1, Z2)
            A = self.axes[jj]
            R = self.radius[jj]
            Z = np.einsum("mij,mj->mi", A, y - self.origin[jj]) / R[:, None]
            s, t = Z[:, 0], Z[:, 1]
            al = self.alpha[jj]
            f = np.zeros(m)
            fs = np.zeros(m)
            ft = np.zeros(m)
            fss = np.zeros(m)
            fst = np.zeros(m)
            ftt = np.zeros(m)
            spow = [np.ones(m), s, s * s, s * s * s]
            tpow = [np.ones(m), t, t * t, t * t * t]
            for n, (a, b) in enumerate(exps):
                c = al[:, n]
                f += c * spow[a] * tpow[b]
                if a >= 1:
                    fs += c * a * spow[a - 1] * tpow[b]
                if b >= 1:
                    ft += c * b * spow[a] * tpow[b - 1]
                if a >= 2:
                    fss += c * (a * (a - 1)) * spow[a - 2] * tpow[b]
                if a >= 1 and b >= 1:
                    fst += c * (a * b) * spow[a - 1] * tpow[b - 1]
                if b >= 2:
                    ftt += c * (b * (b - 1)) * spow[a] * tpow[b - 2]
            phi = R * (Z[:, 2] - f)
            e = A  # rows e1, e2, e3
            gphi = e[:, 2] - fs[:, None] * e[:, 0] - ft[:, None] * e[:, 1]
            S += w
            T += w * phi
            gS += gw
            gT += gw * phi[:, None] + w[:, None] * gphi
            hw += w * self.spacing[jj]
            # ∇²w = −20/ρ² [(1−r)³ I − 3 (1−r)² d dᵀ / (|d| ρ)]
            with np.errstate(divide="ignore", invalid="ignore"):
                cross = np.where(dist > 0, 3.0 * u2 / (np.where(dist > 0, dist, 1.0) * rho), 0.0)
            Hw = (-20.0 / (rho * rho))[:, None, None] * (
                (u2 * u)[:, None, None] * np.eye(3) - cross[:, None, None] * d[:, :, None] * d[:, None, :])
            # ∇²φ = −(1/R) axesᵀ [[fss, fst], [fst, ftt]] axes (in-plane block)
            e1, e2 = e[:, 0], e[:, 1]
            Hphi = -(fss[:, None, None] * e1[:, :, None] * e1[:, None, :]
                     + fst[:, None, None] * (e1[:, :, None] * e2[:, None, :]
                                             + e2[:, :, None] * e1[:, None, :])
                     + ftt[:, None, None] * e2[:, :, None] * e2[:, None, :]) / R[:, None, None]
            HS += Hw
            HT += (Hw * phi[:, None, None] + gw[:, :, None] * gphi[:, None, :]
                   + gphi[:, :, None] * gw[:, None, :] + w[:, None, None] * Hphi)
        inside = S > 0
        Sd = np.where(inside, S, 1.0)
        Phi = T / Sd
        gPhi = (gT - Phi[:, None] * gS) / Sd[:, None]
        HPhi = (HT - Phi[:, None, None] * HS - gPhi[:, :, None] * gS[:, None, :]
                - gS[:, :, None] * gPhi[:, None, :]) / Sd[:, None, None]
        return inside, Phi, gPhi, HPhi, hw / Sd, dmin

    def _candidates(self, x: np.ndarray, radius: float) -> np.ndarray:
        """Nodes within `radius` of each x (m, 3), ascending, −1 padded (m, K)."""
        n = len(self.position)
        m = len(x)
        k = min(n, 32)
        rows = np.arange(m)
        out = None
        while True:
            _, idx = self.tree.query(x[rows], k=k, distance_upper_bound=radius)
            idx = np.asarray(idx).reshape(len(rows), k)
            full = idx[:, -1] < n
            if out is None:
                out = np.full((m, k), n, np.int64)
            if out.shape[1] < k:
                out = np.hstack([out, np.full((m, k - out.shape[1]), n, np.int64)])
            out[rows, :k] = idx
            if not full.any() or k >= n:
                break
            rows = rows[full]
            k = min(n, 2 * k)
        out.sort(axis=1)
        width = int((out < n).sum(axis=1).max(initial=0))
        out = out[:, :max(width, 1)]
        return np.where(out < n, out, -1)

    # -- the gap -----------------------------------------------------------------------------
    def evaluate(self, points, *, second: bool = True) -> RigidResult:
        """Gap, normal (= ∂g/∂x^c), proximal point, Hessian ∂²g/∂x^c², curvatures and
        status of each contactor (m, 3) on the fixed surface S.

        'outside' (reason 'off-target'): x^c beyond the reach of every node's weight, or y*
        farther than tol.OUTSIDE_SPACINGS spacings from every node; 'failed': NaN or inf
        contactors (bad-point), Newton not converged (no-convergence); NaNs in those rows."""
        x = np.asarray(points, dtype=np.float64)
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
        for lo in range(0, len(finite), CHUNK):
            rows = finite[lo:lo + CHUNK]
            self._evaluate_chunk(x[rows], rows, res, second)
        return res

    def _evaluate_chunk(self, x, rows, res, second):
        m = len(x)
        # Φ at the contactor: the nodes whose weight reaches it
        nb0 = self._candidates(x, self.reach_max)
        inside, Phi, g, _, h, _ = self._field(x, nb0, second=False)
        out = ~inside
        res.status[rows[out]], res.reason[rows[out]] = OUTSIDE, OFF_TARGET
        live = np.flatnonzero(inside)
        if not len(live):
            return
        x = x[live]
        rows = rows[live]
        Phi, g, h = Phi[live], g[live], h[live]
        gg = np.einsum("mi,mi->m", g, g)
        step = (Phi / gg)[:, None] * g
        y0 = x - step
        lam0 = Phi / gg
        # candidates: every node whose weight can reach an iterate within `margin` of x^c
        # (rows whose iterates go farther are redone with a wider margin)
        margin = 2.0 * np.sqrt(np.einsum("mi,mi->m", step, step)) + 0.5 * h
        todo = np.arange(len(x))
        while len(todo):
            mg = float(margin[todo].max())
            nb = self._candidates(x[todo], self.reach_max + mg)
            y, lam, its, conv, far, ins = self._newton(x[todo], y0[todo], lam0[todo], nb, h[todo],
                                                       margin[todo])
            again = far & (margin[todo] < 1e3 * h[todo])
            done = ~again
            self._finish(x[todo[done]], y[done], lam[done], its[done], conv[done], ins[done],
                         nb[done], h[todo[done]], rows[todo[done]], res, second)
            margin[todo[again]] *= 4.0
            todo = todo[again]

    def _newton(self, x, y, lam, nb, h, margin):
        """Newton on the Lagrange system (y − x + λ∇Φ = 0, Φ = 0), to round-off."""
        m = len(x)
        its = np.zeros(m, np.int64)
        conv = np.zeros(m, bool)
        far = np.zeros(m, bool)
        ins = np.ones(m, bool)
        act = np.arange(m)
        for it in range(tol.NEWTON_MAX_ITER):
            if not len(act):
                break
            inside, Phi, g, H, _, _ = self._field(y[act], nb[act])
            J = np.zeros((len(act), 4, 4))
            J[:, :3, :3] = np.eye(3) + lam[act, None, None] * H
            J[:, :3, 3] = g
            J[:, 3, :3] = g
            F = np.empty((len(act), 4))
            F[:, :3] = y[act] - x[act] + lam[act, None] * g
            F[:, 3] = Phi
            bad = ~inside | ~np.all(np.isfinite(J), axis=(1, 2))
            J[bad] = np.eye(4)
            F[bad] = 0.0
            with np.errstate(all="ignore"):
                dz = np.linalg.solve(J, F[..., None])[..., 0]
            y[act] -= dz[:, :3]
            lam[act] -= dz[:, 3]
            its[act] += 1
            dist = np.sqrt(np.einsum("mi,mi->m", y[act] - x[act], y[act] - x[act]))
            far[act] |= dist > margin[act]
            ins[act] &= ~bad
            size = np.sqrt(np.einsum("mi,mi->m", dz[:, :3], dz[:, :3]))
            stop = size <= tol.NEWTON_STEP * h[act]
            conv[act] = stop & ~bad
            act = act[~(stop | bad | far[act])]
        return y, lam, its, conv, far, ins

    def _finish(self, x, y, lam, its, conv, ins, nb, h, rows, res, second):
        inside, Phi, grad, H, _, dmin = self._field(y, nb)
        nrm = np.sqrt(np.einsum("mi,mi->m", grad, grad))
        nu = grad / nrm[:, None]
        gap = np.einsum("mi,mi->m", x - y, nu)
        # the shape operator in the tangent plane: L2 = Tᵀ ∇²Φ T / |∇Φ|, T an orthonormal
        # tangent basis (deterministic in ν)
        guide = np.where((np.abs(nu[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
        t1 = guide - np.einsum("mi,mi->m", guide, nu)[:, None] * nu
        t1 /= np.sqrt(np.einsum("mi,mi->m", t1, t1))[:, None]
        t2 = np.cross(nu, t1)
        T = np.stack([t1, t2], axis=2)  # (m, 3, 2)
        L = np.einsum("mia,mij,mjb->mab", T, H, T) / nrm[:, None, None]
        L = 0.5 * (L + np.transpose(L, (0, 2, 1)))
        mean = 0.5 * (L[:, 0, 0] + L[:, 1, 1])
        disc = np.sqrt(0.25 * (L[:, 0, 0] - L[:, 1, 1]) ** 2 + L[:, 0, 1] ** 2)
        kappa = np.stack([mean + disc, mean - disc], axis=1)
        # the closest point is a minimum of the distance only where 1 + g κ_i > 0
        good = conv & ins & inside & np.all(1.0 + gap[:, None] * kappa > 0, axis=1)
        off = good & (dmin > tol.OUTSIDE_SPACINGS * h)
        ok = good & ~off
        r = rows[ok]
        res.gap[r] = gap[ok]
        res.normal[r] = nu[ok]
        res.proximal_point[r] = y[ok]
        res.curvature[r] = kappa[ok]
        res.iterations[rows] = its
        res.reason[r] = OK
        res.status[r] = np.where(np.abs(gap[ok]) <= tol.CONTACT * h[ok], CONTACT,
                                 np.where(gap[ok] > 0, OPEN, PENETRATION))
        res.status[rows[off]], res.reason[rows[off]] = OUTSIDE, OFF_TARGET
        bad = ~good
        res.status[rows[bad]], res.reason[rows[bad]] = FAILED, NO_CONVERGENCE
        if second:
            # ∂²g/∂x² = L (I + g L)⁻¹ in the tangent plane (commuting: L and (I + gL)⁻¹)
            I2 = np.eye(2)
            Mg = np.linalg.solve(I2 + gap[:, None, None] * L, L)
            Mg = 0.5 * (Mg + np.transpose(Mg, (0, 2, 1)))
            hess = np.einsum("mia,mab,mjb->mij", T, Mg, T)
            res.hessian[r] = hess[ok]


def surface_chunk() -> int:
    """Target nodes fitted per projection call (bounds the pairing's memory)."""
    from ..mls.surface import CHUNK as _chunk

    return _chunk
