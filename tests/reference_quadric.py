"""The quadric method's re-centring in numpy (issue 35): the loop `mls._quadric` compiles, kept
as the oracle of tests/test_quadric.py (the compiled answers, statuses and pairings equal to
round-off). The fit and the answer are `QuadricSurface`'s own numpy (`fit_patch`, `_answer`);
the loop over centres and the support's selection are here."""
import numpy as np

from diffsurf_cli.mls.quadric import (
    K_SEARCH,
    MAX_CENTRES,
    MIN_NODES,
    SETTLE,
    _axes,
    sheet_taper,
    wendland,
)
from diffsurf_cli.projection import BAD_POINT, FAILED, NOT_SETTLED, Patch, Projection


def project(surface, x):
    """`QuadricSurface.project(x, keep_patch=True)`, the numpy way."""
    x = np.asarray(x, dtype=np.float64)
    m = len(x)
    good = np.isfinite(x).all(axis=1)
    c, e3 = surface.first_centres(x, good)
    settled = ~good
    iterations = np.zeros(m, np.int64)
    patch = None
    for _ in range(MAX_CENTRES):
        rows = np.flatnonzero(~settled)
        if not len(rows):
            break
        index, h, R = support(surface, c[rows], e3[rows])
        p = Patch(c[rows], _axes(e3[rows]), R, h, index)
        res, _ = surface._answer(x[rows], p, good[rows], rcond=False)
        iterations[rows] += 1
        move = np.linalg.norm(res.proximal_point - c[rows], axis=1) / h
        stop = ~(move > SETTLE) | ~np.isfinite(move)
        if patch is None:
            patch, out = _blank_patch(m, index.shape[1]), _blank(x)
        _put(out, res, rows, stop)
        patch = _put_patch(patch, p, rows, stop)
        settled[rows[stop]] = True
        c[rows[~stop]] = res.proximal_point[~stop]
        e3[rows[~stop]] = res.normal[~stop]
    if patch is None:
        out, patch = _blank(x), _blank_patch(m, 0)
    answered = np.flatnonzero(settled & good)
    if len(answered):  # the last fit's conditioning
        out.rcond[answered] = surface.fit_patch(patch.take(answered))[1]
    late = ~settled
    out.status[late], out.reason[late] = FAILED, NOT_SETTLED
    for name in ("gap", "normal", "proximal_point", "curvature"):
        getattr(out, name)[late] = np.nan
    out.status[~good], out.reason[~good] = FAILED, BAD_POINT
    out.iterations = iterations
    out.patch = patch
    return out


def centre_spacing(d, idx_spacing):
    """h at a centre from its nearest nodes' distances d (m, k) and spacings (m, k): their
    mean weighted by W(d / (2 d_4)), continuous as the centre moves (the nearest node's own
    spacing jumps where another node becomes the nearest, and the centres cycled)."""
    rho = 2.0 * d[:, min(3, d.shape[1] - 1)]
    om = wendland(d / np.maximum(rho, 1e-300)[:, None])[0]
    return np.einsum("mk,mk->m", om, idx_spacing) / om.sum(axis=1)


def support(surface, centre, e3):
    """The support of each centre: (index (m, K) node ids -1 padded, h (m,), R (m,)), the
    sheet taper applied with the centre's normal e3 (`_quadric.one_centre`'s selection)."""
    m = len(centre)
    k = min(K_SEARCH, len(surface.distinct))
    d, idx = surface.tree.query(centre, k=k)
    h = centre_spacing(d, surface.node_spacing[surface.distinct[idx]])
    R = np.maximum(surface.radius * h, 1.05 * d[:, min(MIN_NODES, k) - 1])
    short = np.flatnonzero(d[:, -1] < R)
    if len(short) and k < len(surface.distinct):
        kk = min(len(surface.distinct), 8 * k)
        d2, i2 = surface.tree.query(centre[short], k=kk)
        d = np.concatenate([d, np.full((m, kk - k), np.inf)], axis=1)
        idx = np.concatenate([idx, np.full((m, kk - k), -1)], axis=1)
        d[short], idx[short] = d2, i2
    ids = np.where(idx >= 0, surface.distinct[np.maximum(idx, 0)], -1)
    cos = np.einsum("mkj,mj->mk", surface.normals[np.maximum(ids, 0)], e3)
    keep = (d < R[:, None]) & (sheet_taper(cos)[0] > 0) & (ids >= 0)
    width = int(keep.sum(axis=1).max(initial=0))
    order = np.argsort(~keep, axis=1, kind="stable")[:, :width]
    index = np.where(np.take_along_axis(keep, order, 1),
                     np.take_along_axis(ids, order, 1), -1)
    return index, h, R


FIELDS = ("gap", "normal", "proximal_point", "status", "support", "iterations", "rcond",
          "curvature", "reason", "terms")


def _blank(x):
    m = len(x)
    return Projection(x, np.full(m, np.nan), np.full((m, 3), np.nan), np.full((m, 3), np.nan),
                      np.full(m, FAILED, np.int8), np.zeros(m, np.int64), np.zeros(m, np.int64),
                      np.full(m, np.nan), np.full((m, 2), np.nan), np.full(m, NOT_SETTLED, np.int8),
                      terms=np.zeros(m, np.int8))


def _put(out, res, rows, stop):
    for name in FIELDS:
        getattr(out, name)[rows[stop]] = getattr(res, name)[stop]


def _blank_patch(m, K):
    return Patch(np.full((m, 3), np.nan), np.full((m, 3, 3), np.nan), np.full(m, np.nan),
                 np.full(m, np.nan), np.full((m, K), -1, np.int64))


def _put_patch(patch, p, rows, stop):
    K = max(patch.index.shape[1], p.index.shape[1])
    if patch.index.shape[1] < K:
        patch.index = np.concatenate(
            [patch.index, np.full((len(patch.index), K - patch.index.shape[1]), -1)], axis=1)
    r = rows[stop]
    patch.origin[r], patch.axes[r] = p.origin[stop], p.axes[stop]
    patch.radius[r], patch.spacing[r] = p.radius[stop], p.spacing[stop]
    patch.index[r] = -1
    patch.index[r, :p.index.shape[1]] = p.index[stop]
    return patch


