"""The quadric method's re-centring in numpy (issue 35): the loop `mls._quadric` compiles, kept
as the oracle of tests/test_quadric.py (the compiled answers, statuses and pairings equal to
round-off). Each step is `QuadricSurface`'s own numpy (`support`, `fit_patch`, `_answer`); only
the loop over centres is here."""
import numpy as np

from diffsurf_cli.mls.quadric import MAX_CENTRES, SETTLE, _axes
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
        index, h, R = surface.support(c[rows], e3[rows])
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


