"""The slow, obvious reference of the rigid target's kernel (diffsurf_cli.element._rigid).

The same blended surface Φ = Σ w_j φ_j / Σ w_j (rigid.py's docstring) evaluated in numpy over
padded neighbour lists from scipy's cKDTree, the same Lagrange Newton, and the gap, normal,
curvatures and Hessian of g assembled in numpy. `evaluate(rigid, points)` returns a
RigidResult to compare with `rigid.evaluate(points)`. It reads only the node fits the
RigidTarget precomputed (position, origin, axes, radius, alpha, reach, spacing).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from diffsurf_cli import tol
from diffsurf_cli.element.rigid import RigidResult
from diffsurf_cli.projection import (
    BAD_POINT,
    CONTACT,
    FAILED,
    NO_CONVERGENCE,
    OFF_TARGET,
    OK,
    OPEN,
    OUTSIDE,
    PENETRATION,
)

CHUNK = 4096  # contactors per vectorised block


def field(rigid, y: np.ndarray, nb: np.ndarray, second: bool = True):
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
    exps = rigid.exponents
    for k in range(K):
        j = nb[:, k]
        live = j >= 0
        if not live.any():
            continue
        jj = np.where(live, j, 0)
        d = y - rigid.position[jj]
        dist = np.sqrt(np.einsum("mi,mi->m", d, d))
        dmin = np.where(live, np.minimum(dmin, dist), dmin)
        rho = rigid.reach[jj]
        r = dist / rho
        u = np.where(live, np.maximum(1.0 - r, 0.0), 0.0)
        u2 = u * u
        w = u2 * u2 * (4.0 * r + 1.0)  # Wendland C²: exact zeros beyond the reach
        gw = (-20.0 * u2 * u / (rho * rho))[:, None] * d  # ∇w
        # φ_j in frame j: Z = axes (y - o) / R, f and its derivatives in (s, t) = (Z1, Z2)
        A = rigid.axes[jj]
        R = rigid.radius[jj]
        Z = np.einsum("mij,mj->mi", A, y - rigid.origin[jj]) / R[:, None]
        s, t = Z[:, 0], Z[:, 1]
        al = rigid.alpha[jj]
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
        hw += w * rigid.spacing[jj]
        # ∇²w = −20/ρ² [(1−r)³ I − 3 (1−r)² d dᵀ / (|d| ρ)]
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = np.where(dist > 0, 3.0 * u2 / (np.where(dist > 0, dist, 1.0) * rho), 0.0)
        Hw = (-20.0 / (rho * rho))[:, None, None] * (
            (u2 * u)[:, None, None] * np.eye(3)
            - cross[:, None, None] * d[:, :, None] * d[:, None, :])
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

def candidates(rigid, x: np.ndarray, radius: float) -> np.ndarray:
    """Nodes within `radius` of each x (m, 3), ascending, −1 padded (m, K)."""
    n = len(rigid.position)
    m = len(x)
    k = min(n, 32)
    rows = np.arange(m)
    out = None
    while True:
        _, idx = cKDTree(rigid.position).query(x[rows], k=k, distance_upper_bound=radius)
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
def evaluate(rigid, points, *, second=True):
    """Gap, normal (= ∂g/∂x^c), proximal point, Hessian ∂²g/∂x^c², curvatures and
    status of each contactor (m, 3) on the fixed surface S.

    A contactor beyond the reach of every node's weight starts from its faceted foot
    (`RigidTarget.feet`). 'outside' (reason 'off-target'): that foot beyond every weight's
    reach too, or y* farther than tol.OUTSIDE_SPACINGS spacings from every node; 'failed':
    NaN or inf contactors (bad-point), Newton not converged (no-convergence); NaNs in those rows."""
    x = np.asarray(points, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3), got {x.shape}")
    m = len(x)
    res = RigidResult(np.full(m, np.nan), np.full((m, 3), np.nan), np.full((m, 3), np.nan),
                      np.full((m, 3, 3), np.nan) if second else None,
                      np.full((m, 2), np.nan), np.full(m, FAILED, np.int8),
                      np.full(m, BAD_POINT, np.int8), np.zeros(m, np.int64))
    finite = np.flatnonzero(np.all(np.isfinite(x), axis=1))
    if len(rigid.position) == 0:
        res.status[finite], res.reason[finite] = OUTSIDE, OFF_TARGET
        return res
    beyond = np.zeros(m, bool)
    for lo in range(0, len(finite), CHUNK):
        rows = finite[lo:lo + CHUNK]
        beyond[rows] = evaluate_chunk(rigid, x[rows], rows, res, second)
    # beyond every weight's reach at x^c: the search starts from the faceted foot
    rows = np.flatnonzero(beyond)
    if len(rows):
        feet = rigid.feet(x[rows])
        ok = np.isfinite(feet[:, 0])
        for lo in range(0, int(ok.sum()), CHUNK):
            evaluate_chunk(rigid, x[rows[ok]][lo:lo + CHUNK], rows[ok][lo:lo + CHUNK], res,
                           second, feet[ok][lo:lo + CHUNK])
    return res


def evaluate_chunk(rigid, x, rows, res, second, seed=None):
    """One block of finite contactors: Φ at the search's centre (x, or `seed`), the sheet,
    the projection step, Newton. Returns which rows no weight reaches at that centre."""
    centre = x if seed is None else seed
    # Φ at the centre: the nodes whose weight reaches it
    nb0 = candidates(rigid, centre, rigid.reach_max)
    # the sheet of the nearest node: nodes whose e3 is within the sheet angle of its e3
    d = np.where(nb0 >= 0,
                 np.linalg.norm(rigid.position[np.maximum(nb0, 0)] - centre[:, None], axis=2),
                 np.inf)
    ref = rigid.axes[nb0[np.arange(len(x)), np.argmin(d, axis=1)], 2]
    sheet = np.cos(np.radians(tol.SHEET_ANGLE_DEG))

    def one_sheet(nb, ref):
        e3 = rigid.axes[np.maximum(nb, 0), 2]
        return np.where((nb >= 0) & (np.einsum("mki,mi->mk", e3, ref) >= sheet), nb, -1)

    nb0 = one_sheet(nb0, ref)
    inside, Phi, g, _, h, _ = field(rigid, centre, nb0, second=False)
    out = ~inside
    res.status[rows[out]], res.reason[rows[out]] = OUTSIDE, OFF_TARGET
    live = np.flatnonzero(inside)
    if not len(live):
        return out
    x, centre = x[live], centre[live]
    rows = rows[live]
    Phi, g, h, ref = Phi[live], g[live], h[live], ref[live]
    gg = np.einsum("mi,mi->m", g, g)
    step = (Phi / gg)[:, None] * g
    y0 = centre - step
    # λ of y0 − x^c + λ∇Φ = 0 along ∇Φ (Φ/|∇Φ|² when the centre is x^c)
    lam0 = Phi / gg if seed is None else -np.einsum("mi,mi->m", y0 - x, g) / gg
    # candidates: every node whose weight can reach an iterate within `margin` of the centre
    # (rows whose iterates go farther are redone with a wider margin)
    margin = 2.0 * np.sqrt(np.einsum("mi,mi->m", step, step)) + 0.5 * h
    todo = np.arange(len(x))
    while len(todo):
        mg = float(margin[todo].max())
        nb = one_sheet(candidates(rigid, centre[todo], rigid.reach_max + mg), ref[todo])
        y, lam, its, conv, far, ins = newton(rigid, x[todo], y0[todo], lam0[todo], nb, h[todo],
                                             margin[todo], centre[todo])
        again = far & (margin[todo] < 1e3 * h[todo])
        done = ~again
        finish(rigid, x[todo[done]], y[done], lam[done], its[done], conv[done], ins[done],
               nb[done], h[todo[done]], rows[todo[done]], res, second, seed is not None)
        margin[todo[again]] *= 4.0
        todo = todo[again]
    return out

def newton(rigid, x, y, lam, nb, h, margin, centre):
    """Newton on the Lagrange system (y − x + λ∇Φ = 0, Φ = 0), to round-off; `far` where an
    iterate leaves `margin` of the search's centre."""
    m = len(x)
    its = np.zeros(m, np.int64)
    conv = np.zeros(m, bool)
    far = np.zeros(m, bool)
    ins = np.ones(m, bool)
    act = np.arange(m)
    for _ in range(tol.NEWTON_MAX_ITER):
        if not len(act):
            break
        inside, Phi, g, H, _, _ = field(rigid, y[act], nb[act])
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
        its[act] += 1
        size = np.sqrt(np.einsum("mi,mi->m", dz[:, :3], dz[:, :3]))
        stop = size <= tol.NEWTON_STEP * h[act]
        # converged: y* is this iterate (a step of round-off of h is not taken)
        move = np.where(stop, 0.0, 1.0)[:, None]
        y[act] -= move * dz[:, :3]
        lam[act] -= move[:, 0] * dz[:, 3]
        dist = np.sqrt(np.einsum("mi,mi->m", y[act] - centre[act], y[act] - centre[act]))
        far[act] |= ~stop & (dist > margin[act])
        ins[act] &= ~bad
        conv[act] = stop & ~bad
        act = act[~(stop | bad | far[act])]
    return y, lam, its, conv, far, ins

def finish(rigid, x, y, lam, its, conv, ins, nb, h, rows, res, second, seeded=False):
    """Gap, normal, curvatures, on-target test, status and Hessian of g at converged y*. A
    search from the faceted foot (`seeded`) whose iterate left every weight's reach is past
    the target's edge ('outside', 'off-target')."""
    inside, Phi, grad, H, h, dmin = field(rigid, y, nb)  # h: the spacing at y*
    nrm = np.sqrt(np.einsum("mi,mi->m", grad, grad))
    with np.errstate(invalid="ignore"):  # rows whose iterate left the reach: NaN, unused
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
    off = good & ((dmin > tol.OUTSIDE_SPACINGS * h)
                  | beyond_hull(rigid, y, t1, t2, nb, tol.HULL_SPACINGS * h))
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
    if seeded:
        left = ~ins | ~inside
        res.status[rows[left]], res.reason[rows[left]] = OUTSIDE, OFF_TARGET
    if second:
        # ∂²g/∂x² = L (I + g L)⁻¹ in the tangent plane (commuting: L and (I + gL)⁻¹)
        I2 = np.eye(2)
        Mg = np.linalg.solve(I2 + gap[:, None, None] * L, L)
        Mg = 0.5 * (Mg + np.transpose(Mg, (0, 2, 1)))
        hess = np.einsum("mia,mab,mjb->mij", T, Mg, T)
        res.hessian[r] = hess[ok]




#: Directions sampled for the support function of a hull (distance error below 1e-6 of it).
DIRECTIONS = 3600


def beyond_hull(rigid, y, t1, t2, nb, slack):
    """Whether each y is farther than `slack` from the convex hull of the nodes whose weight
    reaches it, in its tangent plane: the distance from a point outside a convex set is the
    largest, over unit directions u, of −max_j u·(x_j − y) (the support function), sampled."""
    angle = np.linspace(0.0, 2 * np.pi, DIRECTIONS, endpoint=False)
    U = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    out = np.zeros(len(y), dtype=bool)
    for lo in range(0, len(y), 16):
        sl = slice(lo, lo + 16)
        j = nb[sl]
        d = rigid.position[np.maximum(j, 0)] - y[sl, None, :]
        reach = (j >= 0) & (np.einsum("mki,mki->mk", d, d) < rigid.reach[np.maximum(j, 0)] ** 2)
        p = np.stack([np.einsum("mki,mi->mk", d, t1[sl]), np.einsum("mki,mi->mk", d, t2[sl])], 2)
        support = np.where(reach[..., None], np.einsum("mkc,dc->mkd", p, U), -np.inf).max(axis=1)
        out[sl] = (-support).max(axis=1) > slack[sl]
    return out
