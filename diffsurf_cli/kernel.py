"""Compiled projection kernel: `DiffuseSurface.select` and `DiffuseSurface._solve`, one contactor
at a time, in parallel over contactors (numba, compiled once and cached on disk).

The numpy path in surface.py is the slow, obvious reference; this kernel computes the same
quantities with the same rules, and tests/test_kernel.py checks one against the other. What
differs is only how, never what:

- neighbours come from a uniform grid of cells instead of a k-d tree (same sets: all nodes within
  a radius, or the k nearest);
- the weighted least squares [15]-[17] is solved by Householder QR of W^½ P (columns
  equilibrated as in fit.py) instead of an SVD, and the condition number comes from the
  singular values of the small triangular factor (one-sided Jacobi), which are those of W^½ P;
- the local frame's smallest-spread direction comes from a 3x3 Jacobi eigen-solver.

Everything is per point and allocation-free inside the loop, so memory is the outputs only.
"""
from __future__ import annotations

import math
import os

import numpy as np

from ._jit import numba as nb

from . import basis as _basis
from . import tol
from . import weight as weight_mod
from .frame import _E1_GUIDE, _E1_GUIDE_ALT

WEIGHT_CODES = {"wendland": 0, "gauss": 1, "singular": 2}
#: Grid cells per node at most (a dense grid over the bounding box of a sparse, elongated
#: target could otherwise be huge); the cell grows until the grid fits.
_MAX_CELLS_PER_NODE = 8
#: Grid cell size in node spacings (support balls are 2-5 spacings wide).
_CELL_SPACINGS = 2.0


# --------------------------------------------------------------------------------------------
# the grid of cells
# --------------------------------------------------------------------------------------------


def build_grid(coords: np.ndarray, cell: float):
    """A uniform grid over `coords` (n, 3): (lo, cell, dims, start, order).

    Nodes of cell c are ``order[start[c]:start[c + 1]]``; cell indices are
    (i * dims[1] + j) * dims[2] + k.
    """
    coords = np.ascontiguousarray(coords, dtype=np.float64)
    n = len(coords)
    lo = coords.min(axis=0)
    span = coords.max(axis=0) - lo
    cell = float(cell) if cell > 0 else 1.0
    limit = max(_MAX_CELLS_PER_NODE * n, 64)
    while True:
        dims = np.maximum(np.floor(span / cell).astype(np.int64) + 1, 1)
        if np.prod(dims.astype(np.float64)) <= limit:
            break
        cell *= 1.25
    ijk = np.minimum(((coords - lo) / cell).astype(np.int64), dims - 1)
    lin = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    order = np.argsort(lin, kind="stable").astype(np.int64)
    start = np.searchsorted(lin[order], np.arange(int(np.prod(dims)) + 1)).astype(np.int64)
    return lo, cell, dims, start, order


@nb.njit(cache=True, inline="always", error_model="numpy")
def _cell_index(x, lo, cell, dim):
    c = (x - lo) / cell
    c = min(max(c, 0.0), dim - 1.0)  # clamp as a float first: far points stay finite ints
    return int(c)


@nb.njit(cache=True, inline="always", error_model="numpy")
def _distance2(coords, node, p):
    """Squared distance from node `node` of `coords` to the point p."""
    d2 = 0.0
    for e in range(3):
        d = coords[node, e] - p[e]
        d2 += d * d
    return d2


@nb.njit(cache=True, inline="always", error_model="numpy")
def _insert_sorted(idx, d2s, pos, node, d2):
    """Insert (node, d2) into the list sorted by d2 whose first `pos` entries are filled (the
    entry at `pos`, if any, is overwritten)."""
    while pos > 0 and d2s[pos - 1] > d2:
        d2s[pos] = d2s[pos - 1]
        idx[pos] = idx[pos - 1]
        pos -= 1
    d2s[pos] = d2
    idx[pos] = node


@nb.njit(cache=True, error_model="numpy")
def _knn(coords, lo, cell, dims, start, order, p, k, best_i, best_d2):
    """The k nearest nodes of p, nearest first, in best_i/best_d2; returns how many (≤ k)."""
    ci = _cell_index(p[0], lo[0], cell, dims[0])
    cj = _cell_index(p[1], lo[1], cell, dims[1])
    ck = _cell_index(p[2], lo[2], cell, dims[2])
    count = 0
    layer = 0
    last = max(dims[0], max(dims[1], dims[2]))
    while True:
        for di in range(-layer, layer + 1):
            i = ci + di
            if i < 0 or i >= dims[0]:
                continue
            for dj in range(-layer, layer + 1):
                j = cj + dj
                if j < 0 or j >= dims[1]:
                    continue
                rim = abs(di) == layer or abs(dj) == layer
                step = 1 if rim else max(2 * layer, 1)
                for dk in range(-layer, layer + 1, step):
                    kk = ck + dk
                    if kk < 0 or kk >= dims[2]:
                        continue
                    c = (i * dims[1] + j) * dims[2] + kk
                    for a in range(start[c], start[c + 1]):
                        node = order[a]
                        d2 = _distance2(coords, node, p)
                        if count == k and d2 >= best_d2[k - 1]:
                            continue
                        _insert_sorted(best_i, best_d2, min(count, k - 1), node, d2)
                        if count < k:
                            count += 1
        # every cell of the next layer is at least `layer` cells away from p
        if count == k and best_d2[k - 1] <= (layer * cell) ** 2:
            break
        if layer >= last:
            break
        layer += 1
    return count


@nb.njit(cache=True, error_model="numpy")
def _ball(coords, lo, cell, dims, start, order, p, r, out_i, out_d2):
    """All nodes within r of p, nearest first; returns their number (only the first
    len(out_i) are stored: a larger return value means the scratch was too small)."""
    cap = len(out_i)
    i0 = _cell_index(p[0] - r, lo[0], cell, dims[0])
    i1 = _cell_index(p[0] + r, lo[0], cell, dims[0])
    j0 = _cell_index(p[1] - r, lo[1], cell, dims[1])
    j1 = _cell_index(p[1] + r, lo[1], cell, dims[1])
    k0 = _cell_index(p[2] - r, lo[2], cell, dims[2])
    k1 = _cell_index(p[2] + r, lo[2], cell, dims[2])
    r2 = r * r
    count = 0
    for i in range(i0, i1 + 1):
        for j in range(j0, j1 + 1):
            for kk in range(k0, k1 + 1):
                c = (i * dims[1] + j) * dims[2] + kk
                for a in range(start[c], start[c + 1]):
                    node = order[a]
                    d2 = _distance2(coords, node, p)
                    if d2 <= r2:
                        if count < cap:
                            _insert_sorted(out_i, out_d2, count, node, d2)
                        count += 1
    return count


# --------------------------------------------------------------------------------------------
# small dense linear algebra
# --------------------------------------------------------------------------------------------


def constants():
    """The tolerances and weight constants the kernel uses, as one array (passed in rather than
    read as globals, which numba would freeze into its on-disk cache)."""
    return np.array([weight_mod._GAUSS_C2, float(weight_mod._GAUSS_TAIL), tol.SINGULAR_FLOOR,
                     tol.NEWTON_STEP, float(tol.NEWTON_MAX_ITER), *_E1_GUIDE, *_E1_GUIDE_ALT,
                     tol.EQUILIBRATION_FLOOR])


@nb.njit(cache=True, error_model="numpy")
def _weight(code, q, k):
    """w(q), q = (ρ/R)² [15]: as weight.py (0 outside the domain of influence)."""
    if q >= 1.0:
        return 0.0
    if code == 1:
        return (math.exp(-q / k[0]) - k[1]) / (1.0 - k[1])
    r = math.sqrt(q)
    u = 1.0 - r
    w = u * u * u * u * (4.0 * r + 1.0)
    if code == 2:
        return w / max(q, k[2])
    return w


@nb.njit(cache=True, error_model="numpy")
def _smallest_eigenvector(c, out):
    """Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 `c` (cyclic Jacobi)."""
    a = c.copy()
    v = np.eye(3)
    for _ in range(50):
        off = a[0, 1] ** 2 + a[0, 2] ** 2 + a[1, 2] ** 2
        scale = a[0, 0] ** 2 + a[1, 1] ** 2 + a[2, 2] ** 2
        if off <= 1e-36 * scale or off == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p, q] == 0.0:
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * a[p, q])
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            cs = 1.0 / math.sqrt(t * t + 1.0)
            sn = t * cs
            for k in range(3):  # a <- Jᵀ a J
                akp, akq = a[k, p], a[k, q]
                a[k, p] = cs * akp - sn * akq
                a[k, q] = sn * akp + cs * akq
            for k in range(3):
                apk, aqk = a[p, k], a[q, k]
                a[p, k] = cs * apk - sn * aqk
                a[q, k] = sn * apk + cs * aqk
            for k in range(3):
                vkp, vkq = v[k, p], v[k, q]
                v[k, p] = cs * vkp - sn * vkq
                v[k, q] = sn * vkp + cs * vkq
    j = 0
    for i in range(1, 3):
        if a[i, i] < a[j, j]:
            j = i
    for k in range(3):
        out[k] = v[k, j]


@nb.njit(cache=True, error_model="numpy")
def _singular_values(r, n, sig):
    """Singular values of the n x n matrix r (destroyed), by one-sided Jacobi, into sig.

    Columns are rotated pairwise until all are orthogonal to 1e-9 (relative); the singular
    values are then the column norms, accurate to far better than that (the error is second
    order in the remaining off-orthogonality).
    """
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k, i] * r[k, i]
        sig[i] = acc  # squared column norms, kept up to date through the rotations
    for _ in range(60):
        rotated = False
        for i in range(n - 1):
            for j in range(i + 1, n):
                alpha = sig[i]
                beta = sig[j]
                gamma = 0.0
                for k in range(n):
                    gamma += r[k, i] * r[k, j]
                if gamma == 0.0 or abs(gamma) <= 1e-9 * math.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + math.sqrt(1.0 + zeta * zeta))
                cs = 1.0 / math.sqrt(1.0 + t * t)
                sn = cs * t
                for k in range(n):
                    x, y = r[k, i], r[k, j]
                    r[k, i] = cs * x - sn * y
                    r[k, j] = sn * x + cs * y
                sig[i] = alpha - t * gamma
                sig[j] = beta + t * gamma
        if not rotated:
            break
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += r[k, i] * r[k, i]
        sig[i] = math.sqrt(acc)


@nb.njit(cache=True, error_model="numpy")
def _qr_rcond(a, m, n, b, rfac, sig):
    """Householder QR of the m x n block of `a` (in place), applied to b[:m] when b is given;
    copies R into rfac and returns σ_min/σ_max (0 when m < n or all zero)."""
    if m < n:
        return 0.0
    for j in range(n):
        norm = 0.0
        for i in range(j, m):
            norm += a[i, j] * a[i, j]
        norm = math.sqrt(norm)
        if norm == 0.0:
            continue
        alpha = -norm if a[j, j] >= 0 else norm
        v0 = a[j, j] - alpha
        # v = (v0, a[j+1:, j]); H = I - 2 v vᵀ / vᵀv
        vtv = v0 * v0 + (norm * norm - a[j, j] * a[j, j])
        if vtv <= 0.0:
            continue
        a[j, j] = v0
        for c in range(j + 1, n):
            dot = 0.0
            for i in range(j, m):
                dot += a[i, j] * a[i, c]
            f = 2.0 * dot / vtv
            for i in range(j, m):
                a[i, c] -= f * a[i, j]
        if b.shape[0] > 0:
            dot = 0.0
            for i in range(j, m):
                dot += a[i, j] * b[i]
            f = 2.0 * dot / vtv
            for i in range(j, m):
                b[i] -= f * a[i, j]
        a[j, j] = alpha
        for i in range(j + 1, m):
            a[i, j] = 0.0
    for i in range(n):
        for j in range(n):
            rfac[i, j] = a[i, j] if j >= i else 0.0
    work = rfac.copy()
    _singular_values(work, n, sig)
    top = 0.0
    low = np.inf
    for i in range(n):
        top = max(top, sig[i])
        low = min(low, sig[i])
    return low / top if top > 0 else 0.0


@nb.njit(cache=True, error_model="numpy")
def _weighted_system(ea, eb, s, t, z, w, count, a, b, scale, floor):
    """The rows √(w/w_max) p(s, t) of the support nodes with w > 0 into `a` (and √(w/w_max) z
    into `b`, unless it is empty), columns equilibrated, their norms in `scale`, as fit.py;
    returns the number of rows."""
    n = len(ea)
    wmax = 0.0
    for r in range(count):
        wmax = max(wmax, w[r])
    rows = 0
    for r in range(count):
        if w[r] <= 0.0:
            continue
        root = math.sqrt(w[r] / wmax)
        for j in range(n):
            a[rows, j] = root * _ipow(s[r], ea[j]) * _ipow(t[r], eb[j])
        if b.shape[0] > 0:
            b[rows] = root * z[r]
        rows += 1
    top = 0.0
    for j in range(n):
        c = 0.0
        for i in range(rows):
            c += a[i, j] * a[i, j]
        scale[j] = math.sqrt(c)
        top = max(top, scale[j])
    for j in range(n):
        # floored: a column of round-off (a support on a line) must stay negligible
        scale[j] = max(scale[j], floor * top)
        if not scale[j] > 0:
            scale[j] = 1.0
        for i in range(rows):
            a[i, j] /= scale[j]
    return rows


@nb.njit(cache=True, error_model="numpy")
def _fit(ea, eb, s, t, z, w, geo, count, a, b, rfac, sig, alpha, scale, use_geo, floor):
    """Weighted least squares [17] of the support rows with w > 0 (the first `count` entries of
    s, t, z, w, geo): alpha (NaN when impossible) and rcond as fit.py computes them."""
    n = len(ea)
    rows = _weighted_system(ea, eb, s, t, z, w, count, a, b, scale, floor)
    rcond = _qr_rcond(a, rows, n, b, rfac, sig)
    if rcond > 0.0:
        for j in range(n - 1, -1, -1):  # back substitution R y = Qᵀ b
            acc = b[j]
            for c in range(j + 1, n):
                acc -= rfac[j, c] * alpha[c]
            alpha[j] = acc / rfac[j, j]
        for j in range(n):
            alpha[j] /= scale[j]
        for j in range(n):
            if not math.isfinite(alpha[j]):
                alpha[:] = np.nan
                break
    else:
        alpha[:] = np.nan
    if use_geo:
        # the singular weight is stiff by design: judge the support's geometry on the smooth
        # weight with the same support (as fit.py's `geometry`)
        rows = _weighted_system(ea, eb, s, t, z, geo, count, a, b[:0], scale, floor)
        rcond = _qr_rcond(a, rows, n, b[:0], rfac, sig)
    return rcond


@nb.njit(cache=True, inline="always", error_model="numpy")
def _ipow(x, n):
    """x**n for a small non-negative integer n, by multiplication (as basis.terms does)."""
    out = 1.0
    for _ in range(n):
        out *= x
    return out


@nb.njit(cache=True, error_model="numpy")
def _surface_derivatives(ea, eb, alpha, s, t, out):
    """f, f,s, f,t, f,ss, f,st, f,tt of the local approximation at (s, t)."""
    for d in range(6):
        out[d] = 0.0
    for j in range(len(ea)):
        a = ea[j]
        b = eb[j]
        sa = _ipow(s, a)
        tb = _ipow(t, b)
        sa1 = a * _ipow(s, a - 1) if a >= 1 else 0.0
        tb1 = b * _ipow(t, b - 1) if b >= 1 else 0.0
        sa2 = a * (a - 1) * _ipow(s, a - 2) if a >= 2 else 0.0
        tb2 = b * (b - 1) * _ipow(t, b - 2) if b >= 2 else 0.0
        out[0] += alpha[j] * sa * tb
        out[1] += alpha[j] * sa1 * tb
        out[2] += alpha[j] * sa * tb1
        out[3] += alpha[j] * sa2 * tb
        out[4] += alpha[j] * sa1 * tb1
        out[5] += alpha[j] * sa * tb2


@nb.njit(cache=True, error_model="numpy")
def _newton(ea, eb, alpha, c, f, st, k):
    """proximal_point() of surface.py for one point: returns (iterations, converged)."""
    st[0] = c[0]
    st[1] = c[1]
    for j in range(len(alpha)):
        if not math.isfinite(alpha[j]):
            return 0, False
    its = 0
    for _ in range(int(k[4])):
        _surface_derivatives(ea, eb, alpha, st[0], st[1], f)
        r = f[0] - c[2]
        fs, ft, fss, fst, ftt = f[1], f[2], f[3], f[4], f[5]
        g1 = st[0] - c[0] + r * fs
        g2 = st[1] - c[1] + r * ft
        h11 = 1 + fs * fs + r * fss
        h12 = fs * ft + r * fst
        h22 = 1 + ft * ft + r * ftt
        det = h11 * h22 - h12 * h12
        gn = not (det > 0 and h11 > 0)
        if gn:  # Gauss-Newton beyond a focal point
            h11, h12, h22 = 1 + fs * fs, fs * ft, 1 + ft * ft
            det = h11 * h22 - h12 * h12
        d1 = -(h22 * g1 - h12 * g2) / det
        d2 = -(h11 * g2 - h12 * g1) / det
        step = math.hypot(d1, d2)
        cap = 0.5 / step if step > 0.5 else 1.0
        st[0] += cap * d1
        st[1] += cap * d2
        its += 1
        if step < k[3] and not gn:
            return its, True
        if not math.isfinite(step):
            return its, False
    return its, False


@nb.njit(cache=True, error_model="numpy")
def _beyond_hull(s, t, w, count, s0, t0, slack, start, end):
    """surface._beyond_hull for one point at (s0, t0): whether it is farther than `slack` from
    the in-plane convex hull of the support nodes with w > 0 (free arc of directions ≥ π)."""
    # quick accept: a live node in each open quadrant around the point puts the point inside
    # their convex hull (no line through it has them all on one side)
    quadrants = 0
    for j in range(count):
        if w[j] > 0:
            ds = s[j] - s0
            dt = t[j] - t0
            if ds > 0 and dt > 0:
                quadrants |= 1
            elif ds < 0 and dt > 0:
                quadrants |= 2
            elif ds < 0 and dt < 0:
                quadrants |= 4
            elif ds > 0 and dt < 0:
                quadrants |= 8
    if quadrants == 15:
        return False
    two_pi = 2.0 * math.pi
    live = 0
    for j in range(count):
        if w[j] <= 0:
            continue
        ds = s[j] - s0
        dt = t[j] - t0
        r = math.hypot(ds, dt)
        if r <= slack:
            return False  # within the slack of a node
        half = math.asin(min(slack / r, 1.0))
        a = (math.atan2(dt, ds) - half) % two_pi
        # insertion by start angle
        pos = live
        while pos > 0 and start[pos - 1] > a:
            start[pos] = start[pos - 1]
            end[pos] = end[pos - 1]
            pos -= 1
        start[pos] = a
        end[pos] = a + 2.0 * half
        live += 1
    if live == 0:
        return False
    for j in range(1, live):  # running farthest end
        end[j] = max(end[j], end[j - 1])
    wrapped = end[live - 1] - two_pi
    free = start[0] - wrapped
    for j in range(1, live):
        free = max(free, start[j] - max(end[j - 1], wrapped))
    return free >= math.pi


# --------------------------------------------------------------------------------------------
# one contactor
# --------------------------------------------------------------------------------------------


@nb.njit(cache=True, error_model="numpy")
def _frame_e1(e3, out, k):
    """frame.in_plane_axis for one e3 (guides k[5:8] and k[8:11])."""
    g = k[5:8]
    dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    norm = math.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2)
    if not abs(dot) < 0.9 * norm:
        g = k[8:11]
    dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2]
    for k in range(3):
        out[k] = g[k] - dot * e3[k]


@nb.njit(cache=True, error_model="numpy")
def _right_handed(e1, e3, axes):
    """frame._right_handed: rows e1 (orthogonalised, unit), e2 = e3 x e1, e3."""
    dot = e1[0] * e3[0] + e1[1] * e3[1] + e1[2] * e3[2]
    for k in range(3):
        e1[k] -= dot * e3[k]
    norm = math.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    for k in range(3):
        axes[0, k] = e1[k] / norm
        axes[2, k] = e3[k]
    axes[1, 0] = e3[1] * axes[0, 2] - e3[2] * axes[0, 1]
    axes[1, 1] = e3[2] * axes[0, 0] - e3[0] * axes[0, 2]
    axes[1, 2] = e3[0] * axes[0, 1] - e3[1] * axes[0, 0]


@nb.njit(cache=True, parallel=True, error_model="numpy")
def project(nodes, normals, node_spacing, has_faces, first, duplicates,
            fold_normals, signed, steep, cos_fold,
            grid_lo, grid_cell, grid_dims, grid_start, grid_order,
            plane, plane_lo, plane_cell, plane_dims, plane_start, plane_order,
            frame_origin, frame_axes, global_frame,
            ea, eb, weight_code, knn, radius, k, frame_ball, knn_factor, sheet_cos,
            spacing_neighbours, rcond_min, contact_tol, outside_spacings, hull_spacings,
            consts,
            points, reference, centred, cap, threads,
            gap, normal, proximal, status, reason, support, iterations, rcond_out, curvature,
            origin_out, axes_out, radius_out, spacing_out, index_out, overflow):
    """Project `points` with supports selected around `reference` (see surface.py).

    Writes the Projection fields and the pairing (origin, axes, R, h, support index padded
    with -1 to `cap`); overflow[i] is set where the support had more than `cap` nodes (the
    caller retries those rows with a larger cap).
    """
    m = len(points)
    nterms = len(ea)
    nblocks = max(1, min(m, 64 * threads))
    for blk in nb.prange(nblocks):
        lo_row = blk * m // nblocks
        hi_row = (blk + 1) * m // nblocks
        # scratch, once per block
        cand_i = np.empty(cap, dtype=np.int64)
        cand_d2 = np.empty(cap)
        near_i = np.empty(spacing_neighbours, dtype=np.int64)
        near_d2 = np.empty(spacing_neighbours)
        s = np.empty(cap)
        t = np.empty(cap)
        z = np.empty(cap)
        w = np.empty(cap)
        geo = np.empty(cap)
        arc_start = np.empty(cap)
        arc_end = np.empty(cap)
        a = np.empty((max(cap, nterms), nterms))
        b = np.empty(max(cap, nterms))
        rfac = np.empty((nterms, nterms))
        sig = np.empty(nterms)
        alpha = np.empty(nterms)
        scale = np.empty(nterms)
        f = np.empty(6)
        st = np.empty(2)
        c = np.empty(3)
        foot = np.empty(3)
        axes = np.empty((3, 3))
        e1 = np.empty(3)
        e3 = np.empty(3)
        cov = np.empty((3, 3))
        pp = np.empty(3)
        for i in range(lo_row, hi_row):
            ref = reference[i]
            x = points[i]
            # -- local node spacing h: mean over the nearest nodes of their spacing
            got = _knn(nodes, grid_lo, grid_cell, grid_dims, grid_start, grid_order, ref,
                       spacing_neighbours, near_i, near_d2)
            h = 0.0
            for j in range(got):
                h += node_spacing[near_i[j]]
            h /= got
            # -- support and frame (surface.py `select`)
            count = 0
            if global_frame:
                for r in range(3):
                    for col in range(3):
                        axes[r, col] = frame_axes[r, col]
                for e in range(2):
                    pp[e] = 0.0
                    for col in range(3):
                        pp[e] += frame_axes[e, col] * (ref[col] - frame_origin[col])
                pp[2] = 0.0
                if knn:
                    count = _knn(plane, plane_lo, plane_cell, plane_dims, plane_start,
                                 plane_order, pp, k, cand_i, cand_d2)
                    R = knn_factor * math.sqrt(cand_d2[count - 1])
                else:
                    R = radius * h
                    count = _ball(plane, plane_lo, plane_cell, plane_dims, plane_start,
                                  plane_order, pp, R, cand_i, cand_d2)
                    if count > cap:
                        overflow[i] = True
                        count = cap
            else:
                # the reference's foot on the tangent plane of its nearest node
                n0 = near_i[0]
                dn = 0.0
                for e in range(3):
                    foot[e] = ref[e]
                    if has_faces:
                        dn += (ref[e] - nodes[n0, e]) * normals[n0, e]
                if has_faces:
                    for e in range(3):
                        foot[e] = ref[e] - dn * normals[n0, e]
                else:
                    for e in range(3):
                        foot[e] = nodes[n0, e]
                if knn:
                    count = _knn(nodes, grid_lo, grid_cell, grid_dims, grid_start, grid_order,
                                 foot, k, cand_i, cand_d2)
                    ball = 1.0001 * math.sqrt(cand_d2[count - 1])
                else:
                    R = radius * h
                    ball = frame_ball * R
                    count = _ball(nodes, grid_lo, grid_cell, grid_dims, grid_start, grid_order,
                                  foot, ball, cand_i, cand_d2)
                    if count > cap:
                        overflow[i] = True
                        count = cap
                if has_faces:
                    # drop the nodes of another sheet (far side of a thin tube or plate)
                    for e in range(3):
                        e3[e] = 0.0
                    for j in range(min(count, 3)):
                        for e in range(3):
                            e3[e] += normals[cand_i[j], e]
                    nn = max(math.sqrt(e3[0] ** 2 + e3[1] ** 2 + e3[2] ** 2), 1e-300)
                    kept = 0
                    for j in range(count):
                        node = cand_i[j]
                        facing = (normals[node, 0] * e3[0] + normals[node, 1] * e3[1]
                                  + normals[node, 2] * e3[2]) / nn
                        if facing >= sheet_cos:
                            cand_i[kept] = node
                            cand_d2[kept] = cand_d2[j]
                            kept += 1
                    count = kept
                # weighted PCA over the ball (frame.local_axes)
                wsum = 0.0
                for e in range(3):
                    pp[e] = 0.0
                for j in range(count):
                    wj = _weight(0, cand_d2[j] / (ball * ball), consts)
                    geo[j] = wj
                    wsum += wj
                    for e in range(3):
                        pp[e] += wj * (nodes[cand_i[j], e] - foot[e])
                if wsum > 0:
                    for e in range(3):
                        pp[e] /= wsum
                for r in range(3):
                    for col in range(3):
                        cov[r, col] = 0.0
                for j in range(count):
                    for r in range(3):
                        dr = nodes[cand_i[j], r] - foot[r] - pp[r]
                        for col in range(r, 3):
                            dc = nodes[cand_i[j], col] - foot[col] - pp[col]
                            cov[r, col] += geo[j] * dr * dc
                cov[1, 0] = cov[0, 1]
                cov[2, 0] = cov[0, 2]
                cov[2, 1] = cov[1, 2]
                _smallest_eigenvector(cov, e3)
                dot = 0.0
                for j in range(count):
                    for e in range(3):
                        guide = normals[cand_i[j], e] if has_faces else frame_axes[2, e]
                        dot += geo[j] * guide * e3[e]
                if dot < 0:
                    for e in range(3):
                        e3[e] = -e3[e]
                _frame_e1(e3, e1, consts)
                _right_handed(e1, e3, axes)
                if knn:
                    R = 0.0
                    for j in range(count):
                        u0 = 0.0
                        u1 = 0.0
                        for col in range(3):
                            d = nodes[cand_i[j], col] - ref[col]
                            u0 += axes[0, col] * d
                            u1 += axes[1, col] * d
                        R = max(R, math.sqrt(u0 * u0 + u1 * u1))
                    R = knn_factor * R if R > 0 else radius * h
            # -- fit and projection (surface.py `_solve`)
            if duplicates:  # each position once, as its first occurrence
                kept = 0
                for j in range(count):
                    node = first[cand_i[j]]
                    seen = False
                    for jj in range(kept):
                        if cand_i[jj] == node:
                            seen = True
                            break
                    if not seen:
                        cand_i[kept] = node
                        cand_d2[kept] = cand_d2[j]
                        kept += 1
                count = kept
            for e in range(3):
                c[e] = 0.0
                for col in range(3):
                    c[e] += axes[e, col] * (x[col] - ref[col])
                c[e] /= R
            c0 = c[0] if centred else 0.0
            c1 = c[1] if centred else 0.0
            positive = 0
            for j in range(count):
                X0 = 0.0
                X1 = 0.0
                X2 = 0.0
                for col in range(3):
                    d = nodes[cand_i[j], col] - ref[col]
                    X0 += axes[0, col] * d
                    X1 += axes[1, col] * d
                    X2 += axes[2, col] * d
                s[j] = X0 / R - c0
                t[j] = X1 / R - c1
                z[j] = X2 / R
                q = s[j] * s[j] + t[j] * t[j]
                w[j] = _weight(weight_code, q, consts)
                geo[j] = _weight(0, q, consts)
                if w[j] > 0:
                    positive += 1
            rc = _fit(ea, eb, s, t, z, w, geo, count, a, b, rfac, sig, alpha, scale,
                      weight_code == 2, consts[11])
            c[0] -= c0
            c[1] -= c1
            its, ok = _newton(ea, eb, alpha, c, f, st, consts)
            _surface_derivatives(ea, eb, alpha, st[0], st[1], f)
            # [29]: ν = (-f,1, -f,2, 1)/‖·‖ in the frame
            nrm = math.sqrt(f[1] * f[1] + f[2] * f[2] + 1.0)
            nu0, nu1, nu2 = -f[1] / nrm, -f[2] / nrm, 1.0 / nrm
            g = 0.0
            for col in range(3):
                normal[i, col] = axes[0, col] * nu0 + axes[1, col] * nu1 + axes[2, col] * nu2
                proximal[i, col] = ref[col] + R * (axes[0, col] * (st[0] + c0)
                                                   + axes[1, col] * (st[1] + c1)
                                                   + axes[2, col] * f[0])
                g += (x[col] - proximal[i, col]) * normal[i, col]
            gap[i] = g  # [32]
            code = 0 if g > 0 else 2  # open / penetration [33]
            if abs(g) <= contact_tol * h:
                code = 1
            why = 0
            # the proximal point must lie on the target: near a support node, inside the
            # domain of influence, within the in-plane hull of the support
            d2min = np.inf
            beyond = _beyond_hull(s, t, w, count, st[0], st[1], hull_spacings * h / R,
                                  arc_start, arc_end)
            for j in range(count):
                if w[j] > 0:
                    d2min = min(d2min, (s[j] - st[0]) ** 2 + (t[j] - st[1]) ** 2)
            if (math.sqrt(d2min) * R > outside_spacings * h
                    or st[0] * st[0] + st[1] * st[1] > 1.0 or beyond):
                code = 3
                why = 4  # off-target
            if not ok:
                code = 4
                why = 5  # no-convergence
            if not rc >= rcond_min:
                code = 3
                why = 3  # ill-conditioned
            if positive < nterms:
                code = 3
                why = 2  # few-nodes
            # a support reaching where the target turns vertical or folds over the frame
            for j in range(count):
                if w[j] <= 0:
                    continue
                node = cand_i[j]
                facing = (fold_normals[node, 0] * axes[2, 0] + fold_normals[node, 1] * axes[2, 1]
                          + fold_normals[node, 2] * axes[2, 2])
                if not signed[node]:
                    facing = abs(facing)
                if facing < cos_fold or steep[node]:
                    code = 3
                    why = 7  # steep
                    break
            status[i] = code
            reason[i] = why
            support[i] = positive
            iterations[i] = its
            rcond_out[i] = rc
            # principal curvatures (surface.principal_curvatures), divided by R
            fs, ft = f[1], f[2]
            E, F, G = 1 + fs * fs, fs * ft, 1 + ft * ft
            root = math.sqrt(1 + fs * fs + ft * ft)
            L, M, N = -f[3] / root, -f[4] / root, -f[5] / root
            det = E * G - F * F
            mean = (E * N + G * L - 2 * F * M) / (2 * det)
            gauss = (L * N - M * M) / det
            disc = math.sqrt(max(mean * mean - gauss, 0.0))
            curvature[i, 0] = (mean + disc) / R
            curvature[i, 1] = (mean - disc) / R
            if code >= 3:
                gap[i] = np.nan
                for col in range(3):
                    normal[i, col] = np.nan
                    proximal[i, col] = np.nan
                curvature[i, 0] = np.nan
                curvature[i, 1] = np.nan
            # the pairing
            for e in range(3):
                origin_out[i, e] = ref[e]
                for col in range(3):
                    axes_out[i, e, col] = axes[e, col]
            radius_out[i] = R
            spacing_out[i] = h
            kept = min(count, index_out.shape[1])
            for j in range(kept):
                index_out[i, j] = cand_i[j]
            for j in range(kept, index_out.shape[1]):
                index_out[i, j] = -1


@nb.njit(cache=True, parallel=True, error_model="numpy")
def _nearest_distances(coords, lo, cell, dims, start, order, k, out):
    for i in nb.prange(len(coords)):
        idx = np.empty(k, dtype=np.int64)
        d2 = np.empty(k)
        got = _knn(coords, lo, cell, dims, start, order, coords[i], k, idx, d2)
        for j in range(k):
            out[i, j] = math.sqrt(d2[j]) if j < got else np.inf


def nearest_distances(coords: np.ndarray, k: int) -> np.ndarray:
    """Distances (n, k) from each of `coords` to its k nearest (itself first), nearest first:
    what scipy's ``cKDTree(coords).query(coords, k)`` gives, without importing scipy."""
    coords = np.ascontiguousarray(coords, dtype=np.float64)
    span = float(np.ptp(coords, axis=0).max()) if len(coords) else 1.0
    # about k nodes per cell on a surface
    cell = span / max(np.sqrt(len(coords) / max(k, 1)), 1.0) if span > 0 else 1.0
    out = np.empty((len(coords), k))
    _nearest_distances(coords, *build_grid(coords, cell), k, out)
    return out


def compiled() -> bool:
    """Whether the projection kernel is in numba's on-disk cache already (best effort). After
    installing, numba compiles it on first use, which takes about half a minute once."""
    try:
        return os.path.exists(project._cache._cache_file._index_path)
    except AttributeError:  # numba's internals moved: say nothing rather than guess
        return True


def exponents(basis: str):
    """Exponent arrays (a, b) of the monomials s^a t^b of a basis, for the kernel."""
    e = np.array(_basis.EXPONENTS[basis], dtype=np.int64)
    return np.ascontiguousarray(e[:, 0]), np.ascontiguousarray(e[:, 1])
