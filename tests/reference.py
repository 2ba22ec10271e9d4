"""The slow, obvious reference of the projection, in numpy: what the compiled engine
(diffsurf_cli/mls/_engine.pyx) computes, by other means.

Vectorised over contactors; neighbours from scipy's k-d tree (the engine: a grid of cells);
the least squares by SVD (the engine: Householder QR); the frame by numpy's eigh (the engine:
Jacobi); the hull test over all support nodes at once. Same rules: the tie-free local node
spacing and foot, the sheet test, the rcond rule of tol.py, the retry with a wider support,
the re-centring loop. `project(surface, points)` takes a built DiffuseSurface (its normals,
spacings, frame choice and steep flags, which are numpy code of the package) and returns a
Projection; `project_with(surface, points, patch)` likewise with a frozen pairing.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

import reference_steps
from diffsurf_cli import tol
from diffsurf_cli.mls import basis as _basis
from diffsurf_cli.mls.frame import _right_handed
from diffsurf_cli.mls.surface import _merge_duplicates, principal_curvatures
from diffsurf_cli.projection import (
    BAD_POINT,
    CONTACT,
    FAILED,
    FEW_NODES,
    ILL_CONDITIONED,
    NO_CONVERGENCE,
    NOT_SETTLED,
    OFF_TARGET,
    OPEN,
    OUTSIDE,
    PENETRATION,
    STEEP,
    Patch,
    Projection,
)

_COS_FOLD = np.cos(np.radians(tol.FOLD_SLOPE_DEG))


# ------------------------------------------------------------------------------ the fit
def rcond_rule(sig: np.ndarray, rcond_min: float) -> np.ndarray:
    """tol.py's rcond from the singular values (m, k) of the equilibrated W^½P: the bound
    rcond_F = 1/(‖A‖_F ‖A⁺‖_F) (Frobenius norms from the singular values), exact σmin/σmax
    where the bound cannot decide, 0 where σmin = 0."""
    n = sig.shape[1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        bound = 1.0 / np.sqrt((sig**2).sum(axis=1) * (1.0 / sig**2).sum(axis=1))
        exact = sig[:, -1] / sig[:, 0]
    bound = np.where(sig[:, -1] > 0, bound, 0.0)
    exact = np.where(sig[:, -1] > 0, exact, 0.0)
    decided = (bound >= rcond_min) | (n * bound < rcond_min)
    return np.where(decided, bound, exact)


def _rows(w):
    top = w.max(axis=1, keepdims=True)
    return np.sqrt(w / np.where(top > 0, top, 1.0))


def _column_scale(B):
    scale = np.linalg.norm(B, axis=1)
    scale = np.maximum(scale, tol.EQUILIBRATION_FLOOR * scale.max(axis=1, keepdims=True))
    return np.where(scale > 0, scale, 1.0)


def _system(P, w):
    with np.errstate(invalid="ignore", over="ignore"):
        B = _rows(w)[..., None] * P
        scale = _column_scale(B)
        A = B / scale[:, None, :]
    A[~np.all(np.isfinite(A), axis=(1, 2))] = 0.0
    return A, scale


def fit(basis, s, t, z, w, rcond_min, geometry=None):
    """α (m, k) of [17] by SVD of W^½P (equilibrated columns), NaN where impossible, and
    rcond (m,) by `rcond_rule` (on `geometry`'s weights if given)."""
    P = reference_steps.basis(basis, s, t)
    k = P.shape[-1]
    if P.shape[1] < k:
        pad = k - P.shape[1]
        P = np.pad(P, ((0, 0), (0, pad), (0, 0)))
        z, w = np.pad(z, ((0, 0), (0, pad))), np.pad(w, ((0, 0), (0, pad)))
        if geometry is not None:
            geometry = np.pad(geometry, ((0, 0), (0, pad)))
    A, scale = _system(P, w)
    rows = (w > 0).sum(axis=1)
    u, sig, vt = np.linalg.svd(A, full_matrices=False)
    sig = np.where((rows >= k)[:, None], sig, 0.0)
    solvable = sig[:, -1] > 0
    rcond = rcond_rule(sig, rcond_min)
    if geometry is not None:
        G, _ = _system(P, geometry)
        gsig = np.linalg.svd(G, compute_uv=False)
        gsig = np.where(((geometry > 0).sum(axis=1) >= k)[:, None], gsig, 0.0)
        rcond = rcond_rule(gsig, rcond_min)
    else:
        solvable &= rcond > 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        coef = np.einsum("mKk,mK->mk", u, _rows(w) * z) / sig
        alpha = np.einsum("mkj,mk->mj", vt, coef) / scale
    alpha[~solvable | ~np.all(np.isfinite(alpha), axis=1)] = np.nan
    return alpha, rcond


def _monomials(exps, a, b):
    """a^i b^j of each (i, j) of `exps`, stacked on a last axis."""
    return np.stack([a**i * b**j for i, j in exps], axis=-1)


#: Generic in-plane points on which a reduced fit is rotated back into the full basis.
_BACK = np.random.default_rng(12).uniform(-1.0, 1.0, size=(10, 2))


def frame_fixed(local, valid):
    """Whether the in-plane spread of each frame's ball (local (m, K, 2) coordinates of its
    nodes, `valid` ones) spans two directions, the smaller variance at least tol.RULED_SPREAD
    of the larger (numpy's eigvalsh)."""
    n = valid.sum(axis=1)
    x = np.where(valid[..., None], local, 0.0)
    mean = x.sum(axis=1) / np.maximum(n, 1)[:, None]
    d = np.where(valid[..., None], x - mean[:, None], 0.0)
    ev = np.linalg.eigvalsh(np.einsum("mki,mkj->mij", d, d))
    return (n >= 3) & (ev[:, 0] >= tol.RULED_SPREAD * ev[:, 1]) & (ev[:, 1] > 0)


def strip_direction(s, t, pw):
    """The angle (m,) of the reduced bases' a axis (tol.ROW_VARIANCE, tol.STRIP_RANK), NaN
    where the support has none: along a row (numpy's eigh of the weighted in-plane covariance),
    else along two rows (the null direction of the quadratic part of the quadratic basis's
    least right singular vector, numpy's SVD)."""
    W = pw.sum(axis=1, keepdims=True)
    W = np.where(W > 0, W, 1.0)
    ms, mt = (pw * s).sum(axis=1, keepdims=True) / W, (pw * t).sum(axis=1, keepdims=True) / W
    ds, dt = np.where(pw > 0, s - ms, 0.0), np.where(pw > 0, t - mt, 0.0)
    cov = np.stack([np.stack([(pw * ds * ds).sum(1), (pw * ds * dt).sum(1)], -1),
                    np.stack([(pw * ds * dt).sum(1), (pw * dt * dt).sum(1)], -1)], -2)
    lam, vecs = np.linalg.eigh(cov)
    row = (lam[:, 0] <= tol.ROW_VARIANCE * lam[:, 1]) & (pw > 0).any(axis=1)
    angle = np.where(row, np.arctan2(vecs[:, 1, 1], vecs[:, 0, 1]), np.nan)
    P = reference_steps.basis("quadratic", s, t)
    weights = pw
    if P.shape[1] < 6:
        P = np.pad(P, ((0, 0), (0, 6 - P.shape[1]), (0, 0)))
        weights = np.pad(pw, ((0, 0), (0, 6 - pw.shape[1])))
    A, scale = _system(P, weights)
    x = np.linalg.svd(A)[2][:, -1, :] / scale
    Q = np.stack([np.stack([x[:, 3], 0.5 * x[:, 4]], -1),
                  np.stack([0.5 * x[:, 4], x[:, 5]], -1)], -2)
    mu, qv = np.linalg.eigh(Q)
    big = np.abs(mu).argmax(axis=1)
    across = np.take_along_axis(qv, big[:, None, None], axis=2)[:, :, 0]
    mags = np.sort(np.abs(mu), axis=1)
    two = ((mags[:, 0] <= tol.STRIP_RANK * mags[:, 1]) & (mags[:, 1] > 0)
           & ((pw > 0).sum(axis=1) >= 6))
    return np.where(row, angle, np.where(two & ~row,
                                         np.arctan2(across[:, 0], -across[:, 1]), np.nan))


def fit_reduced(basis, s, t, z, w, rcond_min, geometry=None, ruled=None, frozen=None):
    """The terms a support can determine (the engine's `fit_reduced`), by SVD: (a, b) along
    and across the principal direction of the weighted in-plane spread (numpy's eigh), the
    first of basis.REDUCED with enough nodes and an accepted rcond fitted, and rotated back
    into the full basis by interpolating it at generic points; those constant across only
    where `ruled` (m,) (`frame_fixed`), those other than [1, a, b] only where the support has
    a direction (`strip_direction`); `frozen` (reduced (m,), direction (m,)) a frozen pairing's
    basis and direction instead. Returns (α (m, k), terms (m,), direction (m,), reduced (m,))
    (NaN, 0 and -1 where even [1, a] cannot be fitted)."""
    m, k = len(s), _basis.size(basis)
    pw = geometry if geometry is not None else w
    if frozen is None:
        direction = strip_direction(s, t, pw)
        only = np.full(m, -1)
    else:
        only, direction = frozen
        ruled = np.ones(m, dtype=bool)
    directed = np.isfinite(direction) | (only >= 0)
    theta = np.where(np.isfinite(direction), direction, 0.0)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    a = u[:, :1] * s + u[:, 1:] * t
    b = u[:, :1] * t - u[:, 1:] * s
    alpha = np.full((m, k), np.nan)
    terms = np.zeros(m, dtype=np.int8)
    reduced = np.full(m, -1, dtype=np.int8)
    todo = np.ones(m, dtype=bool)
    count = (w > 0).sum(axis=1)
    P_back = reference_steps.basis(basis, _BACK[:k, 0], _BACK[:k, 1])
    for r, exps in enumerate(_basis.REDUCED[basis]):
        n = len(exps)
        across = any(j > 0 for _, j in exps)
        plane = _basis.complete(exps)
        rows = np.flatnonzero(todo & (count >= n) & (across | ruled) & (directed | plane)
                              & ((only < 0) | (only == r)))
        if not len(rows):
            continue
        P = _monomials(exps, a[rows], b[rows])
        A, scale = _system(P, w[rows])
        u_, sig, vt = np.linalg.svd(A, full_matrices=False)
        sig = sig[:, :n] if sig.shape[1] >= n else np.pad(sig, ((0, 0), (0, n - sig.shape[1])))
        ok = sig[:, -1] > 0
        if geometry is None:
            ok &= rcond_rule(sig, rcond_min) >= rcond_min
        else:
            G, _ = _system(P, geometry[rows])
            ok &= rcond_rule(np.linalg.svd(G, compute_uv=False)[:, :n], rcond_min) >= rcond_min
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            coef = np.einsum("mKk,mK->mk", u_[:, :, :n], _rows(w[rows]) * z[rows]) / sig
            beta = np.einsum("mkj,mk->mj", vt[:, :n], coef) / scale
        ok &= np.all(np.isfinite(beta), axis=1)
        rows, beta, ub = rows[ok], beta[ok], u[rows[ok]]
        # the reduced polynomial at the generic points, in (a, b) there; the full basis
        # through those values
        ab = _BACK[:k, 0][None] * ub[:, :1] + _BACK[:k, 1][None] * ub[:, 1:]
        bb = _BACK[:k, 1][None] * ub[:, :1] - _BACK[:k, 0][None] * ub[:, 1:]
        values = np.einsum("mpj,mj->mp", _monomials(exps, ab, bb), beta)
        alpha[rows] = np.linalg.solve(P_back, values.T).T
        terms[rows] = n
        reduced[rows] = r
        todo[rows] = False
    return alpha, terms, np.where(reduced >= 0, direction, np.nan), reduced


# ------------------------------------------------------------------------------ frames
def in_plane_axis(e3):
    g1, g2 = np.array(tol.E1_GUIDE), np.array(tol.E1_GUIDE_ALT)
    guide = np.where(np.abs(e3 @ g1)[:, None] < 0.9 * np.linalg.norm(g1), g1, g2)
    return guide - np.sum(guide * e3, axis=1, keepdims=True) * e3


def local_axes(offsets, weights, guides):
    """Rows e1, e2, e3 (m, 3, 3) by weighted PCA; e3 the least spread, turned to agree with
    the weighted guides."""
    wsum = weights.sum(axis=1)[:, None]
    centroid = np.einsum("mk,mkd->md", weights, offsets) / np.where(wsum > 0, wsum, 1.0)
    d = offsets - centroid[:, None, :]
    cov = np.einsum("mk,mki,mkj->mij", weights, d, d)
    _, vecs = np.linalg.eigh(cov)
    e3 = vecs[:, :, 0]
    flip = np.einsum("mk,mkd,md->m", weights, guides, e3) < 0
    e3[flip] *= -1.0
    return _right_handed(in_plane_axis(e3), e3)


# ------------------------------------------------------------------------------ searches
def neighbours(tree, centres, radius):
    """All tree points within `radius` (per centre): (index (m, K) -1 padded, distance)."""
    lists = tree.query_ball_point(centres, radius)
    K = max(max((len(a) for a in lists), default=0), 1)
    idx = np.full((len(centres), K), -1)
    for i, a in enumerate(lists):
        idx[i, :len(a)] = sorted(a)
    safe = np.maximum(idx, 0)
    dist = np.where(idx >= 0, np.sqrt(((tree.data[safe] - centres[:, None]) ** 2).sum(-1)),
                    np.inf)
    return idx, dist


def knn_ties(tree, centres, k):
    """The k nearest tree points of each centre and every point tied with the k-th (all at
    a squared distance <= the k-th's): (index (m, K) -1 padded, distance)."""
    data = tree.data
    if data.shape[1] == 2:  # a planar tree: the engine's plane grid has z = 0
        data = np.hstack([data, np.zeros((len(data), 1))])
        centres = np.hstack([centres, np.zeros((len(centres), 1))])
    _, idx = tree.query(centres[:, :tree.data.shape[1]], k=k)
    idx = idx.reshape(len(centres), k)
    d2k = ((data[idx] - centres[:, None]) ** 2).sum(-1).max(axis=1)
    lists = tree.query_ball_point(centres[:, :tree.data.shape[1]], np.sqrt(d2k) * (1 + 1e-9))
    K = max(len(a) for a in lists)
    out = np.full((len(centres), K), -1)
    for i, a in enumerate(lists):
        a = np.array(sorted(a), dtype=np.int64)
        a = a[((data[a] - centres[i]) ** 2).sum(-1) <= d2k[i]]
        out[i, :len(a)] = a
    safe = np.maximum(out, 0)
    dist = np.where(out >= 0, np.sqrt(((data[safe] - centres[:, None]) ** 2).sum(-1)), np.inf)
    return out, dist


class Reference:
    """The projection of `surface` (a DiffuseSurface), by numpy."""

    def __init__(self, surface):
        self.s = surface
        self.tree = cKDTree(surface.nodes)
        self.plane_tree = cKDTree((surface.nodes - surface.origin) @ surface.axes[:2].T)
        self.rcond_min = tol.RCOND_MIN[surface.basis]

    # -- spacing and foot: a weighted mean over the k + 1 nearest nodes, tie-free
    def spacing_at(self, x):
        s = self.s
        nodes = s.nodes
        k1 = min(tol.SPACING_NEIGHBOURS + 1, len(nodes))
        _, idx = self.tree.query(x, k=k1)
        idx = idx.reshape(len(x), k1)
        d2 = ((nodes[idx] - x[:, None, :]) ** 2).sum(-1)
        dmax = d2.max(axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            w = np.where(d2 < dmax, (1.0 - d2 / dmax) ** 2, 0.0)
        h = np.einsum("mk,mk->m", w, s.node_spacing[idx])
        xb = np.einsum("mk,mkd->md", w, nodes[idx])
        nb = np.einsum("mk,mkd->md", w, s.normals[idx])
        W = w.sum(axis=1)
        for i in np.flatnonzero(~(W > 0)):  # all k + 1 equidistant: every node within, once
            ball = np.flatnonzero(((nodes - x[i]) ** 2).sum(-1) <= dmax[i, 0])
            W[i] = len(ball)
            h[i] = s.node_spacing[ball].sum()
            xb[i] = nodes[ball].sum(axis=0)
            nb[i] = s.normals[ball].sum(axis=0)
        xb /= W[:, None]
        nb /= np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-300)
        if s.faces:
            foot = x - np.sum((x - xb) * nb, axis=1, keepdims=True) * nb
        else:
            foot = xb
        return h / W, foot, nb

    def select(self, reference, enlarge=1.0):
        s = self.s
        m = len(reference)
        h, foot, nbar = self.spacing_at(reference)
        radius = s.radius * enlarge
        k = min(int(np.ceil(s.k * enlarge**2)), len(s.nodes))
        if s.frame == "global":
            axes = np.broadcast_to(s.axes, (m, 3, 3))
            planar = (reference - s.origin) @ s.axes[:2].T
            if s.support == "radius":
                R = radius * h
                idx, _ = neighbours(self.plane_tree, planar, R)
            else:
                idx, dist = knn_ties(self.plane_tree, planar, k)
                R = tol.KNN_RADIUS_FACTOR * dist.max(axis=1, where=idx >= 0, initial=0)
            return Patch(reference.copy(), np.array(axes), R, h, idx)
        if s.support == "radius":
            R = radius * h
            ball = tol.FRAME_BALL * R
            idx, dist = neighbours(self.tree, foot, ball)
        else:
            idx, dist = knn_ties(self.tree, foot, k)
            ball = 1.0001 * dist.max(axis=1, where=idx >= 0, initial=0)
        if s.faces:  # another sheet: normals facing away from the normal near the reference
            facing = np.einsum("mkd,md->mk", s.normals[np.maximum(idx, 0)], nbar)
            other = facing < np.cos(np.radians(tol.SHEET_ANGLE_DEG))
            idx = np.where(other, -1, idx)
            dist = np.where(other, np.inf, dist)
        valid = idx >= 0
        safe = np.where(valid, idx, 0)
        q = (dist / ball[:, None]) ** 2
        w = np.where(valid, reference_steps.weight("wendland", np.where(valid, q, 1.0))[0], 0.0)
        guide = (s.normals[safe] if s.faces
                 else np.broadcast_to(s.axes[2], s.nodes[safe].shape))
        axes = local_axes(s.nodes[safe] - foot[:, None, :], w, guide)
        if s.support == "knn":
            offsets = s.nodes[safe] - reference[:, None, :]
            planar = np.einsum("mij,mkj->mki", axes[:, :2], offsets)
            rho = np.where(valid, np.sqrt((planar**2).sum(-1)), 0.0)
            R = tol.KNN_RADIUS_FACTOR * rho.max(axis=1)
            R = np.where(R > 0, R, s.radius * h)
        return Patch(reference.copy(), axes, R, h, idx)

    # -- fit and projection with a pairing
    @np.errstate(divide="ignore", invalid="ignore", over="ignore")
    def solve(self, points, patch, centred=True, frozen=False):
        s = self.s
        m = len(points)
        if s.duplicates:
            patch = Patch(patch.origin, patch.axes, patch.radius, patch.spacing,
                          _merge_duplicates(patch.index, s.first))
        valid = patch.index >= 0
        nodes = s.nodes[np.where(valid, patch.index, 0)]
        d = nodes - patch.origin[:, None, :]
        local = np.einsum("mij,mkj->mki", patch.axes, d) / patch.radius[:, None, None]
        c = np.einsum("mij,mj->mi", patch.axes, points - patch.origin) / patch.radius[:, None]
        centre = c[:, :2] if centred else np.zeros((m, 2))
        S = local[..., 0] - centre[:, :1]
        T = local[..., 1] - centre[:, 1:]
        Z = local[..., 2]
        q = np.where(valid, S**2 + T**2, 1.0)
        w = np.where(valid, reference_steps.weight(s.weight, q)[0], 0.0)
        count = (w > 0).sum(axis=1)
        geometry = (np.where(valid, reference_steps.weight("wendland", q)[0], 0.0)
                    if s.weight == "singular" else None)
        alpha, rcond = fit(s.basis, S, T, Z, w, self.rcond_min, geometry)
        terms = np.full(m, s.nterms, dtype=np.int8)
        direction = np.full(m, np.nan)
        reduced = np.full(m, -1, dtype=np.int8)
        held = np.zeros(m, dtype=bool)
        if frozen and patch.reduced is not None and patch.direction is not None:
            held = np.asarray(patch.reduced) >= 0  # the pairing's basis and direction
            rows = np.flatnonzero(held)
            if len(rows):
                alpha[rows], terms[rows], direction[rows], reduced[rows] = fit_reduced(
                    s.basis, S[rows], T[rows], Z[rows], w[rows], self.rcond_min,
                    None if geometry is None else geometry[rows],
                    frozen=(np.asarray(patch.reduced)[rows],
                            np.asarray(patch.direction)[rows]))
        thin = np.flatnonzero((~(rcond >= self.rcond_min) | (count < s.nterms)) & ~held)
        if len(thin):  # the support cannot determine the full basis: the terms it can
            ruled = (np.full(len(thin), s.ruled) if s.frame == "global"
                     else frame_fixed(local[thin, :, :2], valid[thin]))
            alpha[thin], terms[thin], direction[thin], reduced[thin] = fit_reduced(
                s.basis, S[thin], T[thin], Z[thin], w[thin], self.rcond_min,
                None if geometry is None else geometry[thin], ruled)
        c = c - np.concatenate([centre, np.zeros((m, 1))], axis=1)
        st, its, ok = proximal_point(s.basis, alpha, c)
        f = [np.einsum("mk,mk->m", reference_steps.basis(s.basis, st[:, 0], st[:, 1], ds, dt),
                       alpha)
             for ds, dt in ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))]
        nu = np.stack([-f[1], -f[2], np.ones(m)], axis=1)  # [29]
        nu /= np.linalg.norm(nu, axis=1, keepdims=True)
        normal = np.einsum("mji,mj->mi", patch.axes, nu)
        xd = np.stack([st[:, 0] + centre[:, 0], st[:, 1] + centre[:, 1], f[0]],
                      axis=1) * patch.radius[:, None]
        proximal = patch.origin + np.einsum("mji,mj->mi", patch.axes, xd)
        gap = np.einsum("mi,mi->m", points - proximal, normal)  # [32]
        status = np.where(gap > 0, OPEN, PENETRATION).astype(np.int8)
        status[np.abs(gap) <= tol.CONTACT * patch.spacing] = CONTACT
        ds_, dt_ = S - st[:, :1], T - st[:, 1:]
        d2 = np.where(w > 0, ds_**2 + dt_**2, np.inf).min(axis=1)
        # a strip or a row (a directed reduced fit): the distance along it
        along = (terms > 0) & (terms < s.nterms) & np.isfinite(direction)
        theta = np.where(along, direction, 0.0)[:, None]
        d2_along = np.where(w > 0, (np.cos(theta) * ds_ + np.sin(theta) * dt_)**2,
                            np.inf).min(axis=1)
        d2 = np.where(along, d2_along, d2)
        slack = tol.HULL_SPACINGS * patch.spacing / patch.radius
        off = ((np.sqrt(d2) * patch.radius > s.outside_spacings * patch.spacing)
               | ((st**2).sum(axis=1) > 1.0) | beyond_hull(ds_, dt_, w > 0, slack))
        reason = np.zeros(m, dtype=np.int8)
        status[off], reason[off] = OUTSIDE, OFF_TARGET
        status[~ok], reason[~ok] = FAILED, NO_CONVERGENCE
        ill = ~(rcond >= self.rcond_min) & (terms == 0)
        status[ill], reason[ill] = OUTSIDE, ILL_CONDITIONED
        few = (count < s.nterms) & (terms == 0)
        status[few], reason[few] = OUTSIDE, FEW_NODES
        near = np.where(valid, patch.index, 0)
        facing = np.einsum("mkd,md->mk", s.fold_normals[near], patch.axes[:, 2])
        facing = np.where(s.signed[near], facing, np.abs(facing))
        steep = ((w > 0) & ((facing < _COS_FOLD) | s.steep[near])).any(axis=1)
        status[steep], reason[steep] = OUTSIDE, STEEP
        curvature = principal_curvatures(*f[1:]) / patch.radius[:, None]
        result = Projection(points, gap, normal, proximal, status, count, its, rcond,
                            curvature, reason, terms, patch)
        _blank(result, status >= OUTSIDE)
        return result

    def project(self, points):
        """DiffuseSurface.project's rules: select and solve, retry thin or off-target rows
        `tol.ENLARGE` wider, flag bad points, re-centre; then a contactor without an answer
        that no node is within the support radius of (the nearest node's R, found by brute
        force) is outside, off-target, with NaN geometry and rcond. Returns a Projection with
        its patch."""
        result = self._project(points)
        s = self.s
        rows = np.flatnonzero((result.status >= OUTSIDE) & (result.reason != BAD_POINT))
        for i in rows:
            d = np.linalg.norm(s.nodes - result.points[i], axis=1)
            near = int(np.argmin(d))
            if d[near] > s.radius * s.node_spacing[near]:
                result.status[i], result.reason[i] = OUTSIDE, OFF_TARGET
                result.rcond[i] = np.nan
                result.terms[i] = 0
                _blank(result, [i])
        return result

    def _project(self, points):
        s = self.s
        points = np.asarray(points, dtype=np.float64)
        finite = np.all(np.isfinite(points), axis=1)
        safe = np.where(finite[:, None], points, s.origin)
        result = self.solve(safe, self.select(safe))
        retry = ((result.reason == FEW_NODES) | (result.reason == ILL_CONDITIONED)
                 | (result.reason == OFF_TARGET) | (result.terms < s.nterms)) & finite
        rows = np.flatnonzero(retry)
        if len(rows):
            again = self.solve(safe[rows], self.select(safe[rows], tol.ENLARGE))
            # kept where on the target, and where the first was on the target with a reduced
            # basis, only where it fits the full basis
            better = (again.status <= PENETRATION) & (
                (result.status[rows] > PENETRATION) | (again.terms == s.nterms))
            _assign(result, rows[better], again, better)
        bad = ~finite
        result.points = points
        result.status[bad], result.reason[bad] = FAILED, BAD_POINT
        result.support[bad] = 0
        result.iterations[bad] = 0
        result.rcond[bad] = np.nan
        result.terms[bad] = 0
        _blank(result, bad)
        if not s.recentre:
            return result
        iterations = result.iterations.copy()
        live = result.status <= PENETRATION
        previous = np.full(len(points), np.inf)
        for _ in range(tol.RECENTRE_MAX_ITER):
            if not live.any():
                break
            rows = np.flatnonzero(live)
            sub = self.solve(points[rows], self.select(result.proximal_point[rows]),
                             centred=False)
            move = np.linalg.norm(sub.proximal_point - result.proximal_point[rows], axis=1)
            iterations[rows] += sub.iterations
            _assign(result, rows, sub, slice(None))
            h = sub.patch.spacing
            with np.errstate(invalid="ignore"):
                stalled = (move >= 0.5 * previous[rows]) & (move < tol.RECENTRE_STALL * h)
                done = ~(move > tol.RECENTRE_STEP * h) | stalled
            previous[rows] = move
            live[rows[done]] = False
        result.status[live], result.reason[live] = FAILED, NOT_SETTLED
        _blank(result, live)
        result.iterations = iterations
        return result

    def project_with(self, points, patch):
        points = np.asarray(points, dtype=np.float64)
        finite = np.all(np.isfinite(points), axis=1)
        result = self.solve(np.where(finite[:, None], points, patch.origin), patch, frozen=True)
        bad = ~finite
        result.points = points
        result.status[bad], result.reason[bad] = FAILED, BAD_POINT
        result.support[bad] = 0
        result.iterations[bad] = 0
        result.rcond[bad] = np.nan
        result.terms[bad] = 0
        _blank(result, bad)
        return result


def _blank(result, rows):
    for arr in (result.gap, result.normal, result.proximal_point, result.curvature):
        arr[rows] = np.nan


def _assign(result, rows, sub, take):
    for name in ("gap", "normal", "proximal_point", "status", "support", "iterations", "rcond",
                 "curvature", "reason", "terms"):
        getattr(result, name)[rows] = getattr(sub, name)[take]
    p, q = result.patch, sub.patch
    K = max(p.index.shape[1], q.index.shape[1])
    p.index = np.pad(p.index, ((0, 0), (0, K - p.index.shape[1])), constant_values=-1)
    for name in ("origin", "axes", "radius", "spacing"):
        getattr(p, name)[rows] = getattr(q, name)[take]
    p.index[rows] = np.pad(q.index[take], ((0, 0), (0, K - q.index.shape[1])),
                           constant_values=-1)


def beyond_hull(ds, dt, live, slack):
    """Whether a point is farther than `slack` from the convex hull of its support, (m,) bool:
    iff the arcs of directions the discs of radius `slack` around the nodes cover leave a free
    arc of at least π."""
    r = np.hypot(ds, dt)
    inside = (live & (r <= slack[:, None])).any(axis=1)
    half = np.arcsin(np.minimum(slack[:, None] / np.where(r > 0, r, 1.0), 1.0))
    start = np.where(live, np.mod(np.arctan2(dt, ds) - half, 2 * np.pi), np.inf)
    order = np.argsort(start, axis=1)
    a = np.take_along_axis(start, order, axis=1)
    end = np.maximum.accumulate(
        np.take_along_axis(np.where(live, start + 2 * half, -np.inf), order, axis=1), axis=1)
    wrapped = end[:, -1:] - 2 * np.pi
    with np.errstate(invalid="ignore"):
        gaps = np.where(np.isfinite(a[:, 1:]), a[:, 1:] - np.maximum(end[:, :-1], wrapped),
                        -np.inf)
        free = np.maximum(gaps.max(axis=1, initial=-np.inf), a[:, 0] - wrapped[:, 0])
    return (free >= np.pi) & ~inside & live.any(axis=1)


def proximal_point(basis, alpha, contactor):
    """Newton on [30] for each local approximation (see _engine.newton): (st, its, ok)."""
    m = len(alpha)
    st = contactor[:, :2].copy()
    its = np.zeros(m, dtype=np.int64)
    converged = np.zeros(m, dtype=bool)
    live = np.all(np.isfinite(alpha), axis=1) & np.all(np.isfinite(contactor), axis=1)
    for _ in range(tol.NEWTON_MAX_ITER):
        rows = np.flatnonzero(live)
        if len(rows) == 0:
            break
        a, (s, t), c = alpha[rows], st[rows].T, contactor[rows]
        f, fs, ft, fss, fst, ftt = (
            np.einsum("mk,mk->m", reference_steps.basis(basis, s, t, ds, dt), a)
            for ds, dt in ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)))
        r = f - c[:, 2]
        g1 = s - c[:, 0] + r * fs
        g2 = t - c[:, 1] + r * ft
        h11, h12, h22 = 1 + fs * fs + r * fss, fs * ft + r * fst, 1 + ft * ft + r * ftt
        det = h11 * h22 - h12 * h12
        gn = ~((det > 0) & (h11 > 0))
        h11, h12, h22 = (np.where(gn, 1 + fs * fs, h11), np.where(gn, fs * ft, h12),
                         np.where(gn, 1 + ft * ft, h22))
        det = h11 * h22 - h12 * h12
        d1 = -(h22 * g1 - h12 * g2) / det
        d2 = -(h11 * g2 - h12 * g1) / det
        step = np.hypot(d1, d2)
        cap = np.where(step > 0.5, 0.5 / np.where(step > 0, step, 1.0), 1.0)
        st[rows, 0] += cap * d1
        st[rows, 1] += cap * d2
        its[rows] += 1
        done = (step < tol.NEWTON_STEP) & ~gn
        bad = ~np.isfinite(step)
        converged[rows[done]] = True
        live[rows[done | bad]] = False
    return st, its, converged


def project(surface, points):
    return Reference(surface).project(points)


def project_with(surface, points, patch):
    return Reference(surface).project_with(points, patch)
