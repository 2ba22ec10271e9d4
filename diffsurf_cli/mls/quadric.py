"""A diffuse surface fitted to positions and nodal normals: moving algebraic quadrics (issue 35).

Why. On a coarse curved target (a few elements per quarter circle) a height function
X3 = f(X1, X2) [16] fitted to positions alone cannot follow the arc its support spans (90° and
more), and the smooth surface falls behind MeshLab's APSS, which fits algebraic spheres to
positions and normals. Each node also knows its normal; an implicit quadric uses it.
benchmarks/coarse_fits.py chose this fit by measurement among height, Hermite, sphere, APSS
and quadric fits (results/coarse_fits.txt): the only one at most APSS's error on every coarse
target and more accurate than the height fit on the fine ones.

The fit. Around a centre c, in units of the centre's spacing h (y = (x - c)/h), the surface is
the zero set of u(y) = θ·b(y), b = [1, y1, y2, y3, y1², y1y2, y1y3, y2², y2y3, y3²] (the
general quadric: spheres, cylinders, cones, planes are special cases). θ minimises

    Σ_i w_i (u(y_i)² + β |∇u(y_i) - n_i|²)

over the support nodes i (the quadratic basis' moving least squares [17], with each node's
three normal conditions beside its position's): (A + ρI) θ = r, A = Σ w_i (b_i b_iᵀ +
β G_iᵀ G_i), r = β Σ w_i G_iᵀ n_i, G = ∂b/∂y (3 x 10), ρ = `RIDGE` (the least-norm quadric
where the rows leave a direction free, as a flat support does). The normal rows fix u's scale
and sign: ∇u ≈ n, so u is a signed distance near the nodes (> 0 outside).
w_i = Wendland(|x_i - c| / R) τ(n_i·e3): R = `radius` x h, enlarged to reach `MIN_NODES`
nodes, h the spacing at the centre (its nearest nodes' spacings, weighted so that it does not
jump as the centre moves, `_quadric.pyx`); τ tapers to 0 the nodes whose normal turns
`SHEET_DEG` from the centre's normal e3 (another sheet: a thin wall's far side).

Nodal normals n_i: the unit sum of the angle-weighted unit normals of the node's facet corners
(higher-order facets as their linear sub-facets; the study measured them 2x more accurate than
area weights on the coarse gmsh spheres). They depend on the node's ring, and the element
(`element.quadric`) differentiates through them (`normal_jets`).

The projection [30]. For a contactor x: the closest point y* of q = (x - c)/h on u = 0 (Newton
on the stationarity of ½|y - q|² + λ u(y)); the proximal point x^d = c + h y* becomes the next
centre, until the centre moves less than `SETTLE` x h (the moving surface's closest point: a
fixed point). The gap is g = h λ |∇u(y*)| (q - y* = λ ∇u), the normal ∇u/|∇u| at y* [29].
The first centre is the facets' foot of x. The re-centring runs compiled (`_quadric.pyx`, the
steps below per contactor; tests/reference_quadric.py is its numpy oracle). The element holds
c, h, R, e3 and the support fixed (the frozen pairing [§4.2], a `Patch`: origin c, axes (e3
last), radius R, spacing h, index).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .. import tol
from ..projection import (
    BAD_POINT,
    CONTACT,
    FAILED,
    FEW_NODES,
    ILL_CONDITIONED,
    NO_CONVERGENCE,
    OFF_TARGET,
    OK,
    OPEN,
    OUTSIDE,
    PENETRATION,
    NearestNode,
    Patch,
    Projection,
    as_faces,
    as_moved_nodes,
    as_points,
    as_target_nodes,
    warn_inside_out,
)
from . import frame as _frame

#: Support radius in node spacings and the weight of the normal rows (benchmarks/coarse_fits.py
#: --tune: rho 2.0, beta 0.03 met APSS on all 13 criterion rows)
DEFAULT_RADIUS = 2.0
DEFAULT_BETA = 0.03
#: nodes the support radius is enlarged to reach (the quadric's 10 terms)
MIN_NODES = 10
#: nodes with positive weight below which the fit is not attempted (4 nodes give 16 rows)
FEW = 4
#: a support node's weight tapers (smoothly, `sheet_taper`) from full where its normal turns
#: less than the first angle from the centre's to none past the second: another sheet (a thin
#: wall's far side); a hard cut at 63° (the study's) made the centres cycle
SHEET_DEG = (50.0, 75.0)
#: the centre has settled when it moves less than this, in spacings
SETTLE = 1e-10
#: re-centrings at most
MAX_CENTRES = 60
#: Newton iterations of the closest point at most, and its tolerance (in spacings)
MAX_NEWTON = 30
NEWTON_TOL = 1e-13
#: a proximal point farther than this many spacings from every support node is off the target
OFF_SPACINGS = 2.0
#: a constant ridge added to A (in units of the weights, y in spacings): it picks the
#: least-norm quadric where the rows leave a direction free (a flat support: the square of
#: its plane vanishes with its gradient at every node), and is differentiated as a constant
RIDGE = 1e-6
#: nearest nodes searched per centre first (more where the radius reaches past them)
K_SEARCH = 32
#: contactors per chunk of the projection (bounds its memory; a progress report a chunk)
CHUNK = 4096

NTERMS = 10
#: ∂²b_k/∂y_d∂y_e (constant: the basis is quadratic), (3, 3, 10)
BASIS_HESSIAN = np.zeros((3, 3, NTERMS))
for _k, (_d, _e) in zip(range(4, NTERMS), ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
    BASIS_HESSIAN[_d, _e, _k] = BASIS_HESSIAN[_e, _d, _k] = 2.0 if _d == _e else 1.0


def basis(y):
    """b(y) for y = (y1, y2, y3), arrays of any shape or jets: a list of the 10 terms."""
    y1, y2, y3 = y
    one = y1 * 0.0 + 1.0
    return [one, y1, y2, y3, y1 * y1, y1 * y2, y1 * y3, y2 * y2, y2 * y3, y3 * y3]


def basis_gradient(y):
    """∂b/∂y_d for d = 0, 1, 2 (lists of the 10 terms' derivatives, arrays or jets)."""
    y1, y2, y3 = y
    zero, one = y1 * 0.0, y1 * 0.0 + 1.0
    return [[zero, one, zero, zero, 2.0 * y1, y2, y3, zero, zero, zero],
            [zero, zero, one, zero, zero, y1, zero, 2.0 * y2, y3, zero],
            [zero, zero, zero, one, zero, zero, y1, zero, y2, 2.0 * y3]]


def basis_arrays(y: np.ndarray):
    """b (..., 10) and G = ∂b/∂y (..., 3, 10) of points y (..., 3)."""
    y1, y2, y3 = y[..., 0], y[..., 1], y[..., 2]
    b = np.empty((*y.shape[:-1], NTERMS))
    b[..., 0] = 1.0
    b[..., 1], b[..., 2], b[..., 3] = y1, y2, y3
    b[..., 4], b[..., 5], b[..., 6] = y1 * y1, y1 * y2, y1 * y3
    b[..., 7], b[..., 8], b[..., 9] = y2 * y2, y2 * y3, y3 * y3
    G = np.zeros((*y.shape[:-1], 3, NTERMS))
    for d in range(3):  # ∂b/∂y_d: the linear terms' 1, the quadratic terms' factors
        G[..., d, 1 + d] = 1.0
    G[..., 0, 4], G[..., 0, 5], G[..., 0, 6] = 2 * y1, y2, y3
    G[..., 1, 5], G[..., 1, 7], G[..., 1, 8] = y1, 2 * y2, y3
    G[..., 2, 6], G[..., 2, 8], G[..., 2, 9] = y1, y2, 2 * y3
    return b, G


def wendland(r):
    """W(r) = (1 - r)⁴ (4r + 1) on [0, 1], 0 beyond, and W'(r), W''(r)."""
    r = np.minimum(r, 1.0)
    s = 1.0 - r
    return s ** 4 * (4 * r + 1), -20.0 * r * s ** 3, 20.0 * s * s * (4 * r - 1)


def sheet_taper(cos):
    """τ (the smootherstep of the cosine between the `SHEET_DEG` angles), dτ/dcos and
    d²τ/dcos² (C² at both ends)."""
    lo, hi = np.cos(np.radians(SHEET_DEG[1])), np.cos(np.radians(SHEET_DEG[0]))
    t = np.clip((cos - lo) / (hi - lo), 0.0, 1.0)
    return (t ** 3 * (10 - 15 * t + 6 * t * t), 30 * t * t * (1 - t) ** 2 / (hi - lo),
            60 * t * (1 - t) * (1 - 2 * t) / (hi - lo) ** 2)


def weights(nodes_local, centre, R):
    """w_i, ∂w_i/∂x_i (..., 3) and ∂²w_i/∂x_i² (..., 3, 3) of support nodes at x_i (..., 3),
    weight W(|x_i - c| / R), in closed form (finite where a node sits at the centre)."""
    d = nodes_local - centre
    dist = np.sqrt(np.einsum("...j,...j->...", d, d))
    R = np.broadcast_to(R, dist.shape)
    r = dist / R
    w, w1, w2 = wendland(r)
    inside = r < 1.0
    w1, w2 = np.where(inside, w1, 0.0), np.where(inside, w2, 0.0)
    safe = np.where(dist > 0, dist, 1.0)
    e = d / safe[..., None]
    # W'(r)/(R d) = -20 (1 - r)³ / R² where the node sits at the centre
    over = np.where(dist > 0, w1 / (R * safe), np.where(inside, -20.0 / (R * R), 0.0))
    grad = (w1 / R)[..., None] * e
    eye = np.eye(3)
    hess = ((w2 / (R * R))[..., None, None] * e[..., :, None] * e[..., None, :]
            + over[..., None, None] * (eye - e[..., :, None] * e[..., None, :]))
    return w, grad, hess


# -- nodal normals --------------------------------------------------------------------------
def polygons(faces) -> list[np.ndarray]:
    """The linear facets (triangles, quads) of facet blocks, higher-order ones split into their
    linear sub-facets over all their nodes (`frame.linear_facets`): the polygons whose corners
    make the nodal normals."""
    return [np.asarray(f, dtype=np.int64) for f in _frame.linear_facets(list(faces)) if len(f)]


def corners(polys):
    """Every polygon corner as (node, next, prev) in the polygon's winding (C,) x 3."""
    node, nxt, prv = [], [], []
    for p in polys:
        k = p.shape[1]
        for j in range(k):
            node.append(p[:, j])
            nxt.append(p[:, (j + 1) % k])
            prv.append(p[:, (j - 1) % k])
    if not node:
        return (np.zeros(0, np.int64),) * 3
    return tuple(np.concatenate(a) for a in (node, nxt, prv))


def corner_vectors(a, b, c):
    """The angle-weighted unit normal of corners at a between b (next) and c (prev): α (b - a)
    x (c - a) / |(b - a) x (c - a)|, α the corner's angle (arrays (..., 3) or jets)."""
    cross = np.cross(b - a, c - a)
    s = np.sqrt(np.einsum("...j,...j->...", cross, cross))
    alpha = np.arctan2(s, np.einsum("...j,...j->...", b - a, c - a))
    return cross * (alpha / np.where(s > 0, s, 1.0))[..., None]


def angle_sums(nodes, table, n: int) -> np.ndarray:
    """N_i = Σ over the corners at node i of their angle-weighted unit normals (n, 3)."""
    node, nxt, prv = table
    v = corner_vectors(nodes[node], nodes[nxt], nodes[prv])
    return np.stack([np.bincount(node, v[:, d], minlength=n) for d in range(3)], axis=1)


def normal_jets(nodes, table, ptr, ids, sign=1.0):
    """The unit normals of nodes `ids` (m,) with their exact first and second derivatives with
    respect to the positions of their rings (the node, and each corner's next and prev):
    (ring (m, r) node ids, -1 padded, first the node itself; n (m, 3); J (m, 3, 3r) ∂n/∂x_ring
    (x_ring flattened node by node); H (m, 3, 3r, 3r) ∂²n/∂x_ring²)."""
    node, nxt, prv = table
    ids = np.asarray(ids, dtype=np.int64)
    m = len(ids)
    count = ptr[ids + 1] - ptr[ids]
    V = int(count.max(initial=0))
    take = ptr[ids][:, None] + np.arange(V)
    mask = np.arange(V) < count[:, None]
    take = np.where(mask, take, 0)
    B, C = np.where(mask, nxt[take], -1), np.where(mask, prv[take], -1)
    rings = [np.concatenate([[i], np.unique(np.concatenate([b[b >= 0], c[c >= 0]]))])
             for i, b, c in zip(ids, B, C)]
    r = max((len(x) for x in rings), default=1)
    ring = np.full((m, r), -1, np.int64)
    for k, x in enumerate(rings):
        ring[k, :len(x)] = x
    P = 3 * r

    def slot(v):  # (m, V) the ring slot of node ids v
        hit = ring[:, None, :] == v[:, :, None]
        return np.argmax(hit, axis=2)

    sb, sc = slot(B), slot(C)
    from .jet import Jet, atan2

    Ng = np.zeros((m, 3, P))
    NH = np.zeros((m, 3, P, P))
    Nv = np.zeros((m, 3))
    for v in range(V):
        at = np.flatnonzero(mask[:, v])  # the nodes with a v-th corner
        xa, xb, xc = nodes[ids[at]], nodes[B[at, v]], nodes[C[at, v]]
        var = Jet.variables(np.concatenate([xa, xb, xc], axis=1), 9)
        e1 = [var[3 + d] - var[d] for d in range(3)]
        e2 = [var[6 + d] - var[d] for d in range(3)]
        cr = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
              e1[0] * e2[1] - e1[1] * e2[0]]
        s_ = (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt()
        scale = atan2(s_, e1[0] * e2[0] + e1[1] * e2[1] + e1[2] * e2[2]) * s_.reciprocal()
        gidx = (3 * np.stack([np.zeros(len(at), np.int64), sb[at, v], sc[at, v]], 1)[:, :, None]
                + np.arange(3)).reshape(len(at), 9)
        for d in range(3):
            t = cr[d] * scale
            Nv[at, d] += t.v
            Ng[at[:, None], d, gidx] += t.g
            NH[at[:, None, None], d, gidx[:, :, None], gidx[:, None, :]] += t.H
    N = [Jet(sign * Nv[:, d], sign * Ng[:, d], sign * NH[:, d]) for d in range(3)]
    inv = (N[0] * N[0] + N[1] * N[1] + N[2] * N[2]).sqrt().reciprocal()
    n = [N[d] * inv for d in range(3)]
    return (ring, np.stack([x.v for x in n], 1), np.stack([x.g for x in n], 1),
            np.stack([x.H for x in n], 1))


# -- the fit and the closest point ----------------------------------------------------------
def fit(y, w, normals, beta, rcond=True):
    """θ (m, 10) of the supports y (m, K, 3) with weights w (m, K) and nodal normals (m, K, 3):
    (A + `RIDGE` I) θ = r; rcond (m,): 1/(‖As‖_F ‖As⁻¹‖_F) of A + `RIDGE` I equilibrated by
    its diagonal, a lower bound on its reciprocal condition number within a factor of 10 (NaN
    where no node weighs; all NaN unless `rcond`); and A + `RIDGE` I (the element's adjoints
    solve with it)."""
    m, K = w.shape
    b, G = basis_arrays(y)
    G = G.reshape(m, 3 * K, NTERMS)
    wG = np.repeat(w, 3, axis=1)[:, :, None] * G
    A = np.matmul(np.swapaxes(w[:, :, None] * b, 1, 2), b) + beta * np.matmul(
        np.swapaxes(wG, 1, 2), G)
    r = beta * np.matmul(np.swapaxes(wG, 1, 2), normals.reshape(m, 3 * K, 1))[..., 0]
    # no node weighs, or a non-finite row: no fit (a term the rows leave at 0, as y3² on a
    # flat support, is the ridge's: rcond 0 says so)
    bad = ~(w.sum(axis=1) > 0) | ~np.isfinite(A).all(axis=(1, 2)) | ~np.isfinite(r).all(1)
    A = A + RIDGE * np.eye(NTERMS)
    A[bad] = np.eye(NTERMS)
    cond = np.full(m, np.nan)
    if rcond and m:  # 1/(|As|_F |As⁻¹|_F) of the equilibrated A + ρI: within 10x of λmin/λmax
        scale = np.sqrt(np.einsum("mii->mi", A))
        As = A / scale[:, :, None] / scale[:, None, :]
        cond = 1.0 / (np.linalg.norm(As, axis=(1, 2)) * np.linalg.norm(np.linalg.inv(As),
                                                                      axis=(1, 2)))
        cond[bad] = np.nan
    theta = np.linalg.solve(A, np.where(bad[:, None], 0.0, r)[..., None])[..., 0]
    theta[bad] = np.nan
    return theta, cond, A


def value(y, theta):
    """u(y), ∇u(y) (m, 3) and the (constant) Hessian of u (m, 3, 3)."""
    b, G = basis_arrays(y)
    return (np.einsum("mi,mi->m", b, theta), np.einsum("mdi,mi->md", G, theta),
            np.einsum("dei,mi->mde", BASIS_HESSIAN, theta))


def closest_point(q, theta):
    """The closest point y* of q (m, 3) on u = 0 and its multiplier λ (q - y* = λ ∇u(y*)):
    (y, lam, ok). A line root along ∇u starts Newton on (y - q + λ∇u, u) = 0 [30]."""
    y = q.copy()
    with np.errstate(all="ignore"):
        for _ in range(2):  # the root along ∇u (exact on a sphere), then from x's foot on
            y = _line_root(y, theta)  # that root's tangent plane
            if _ == 0:
                _u, g, _h = value(y, theta)
                nu = g / np.linalg.norm(g, axis=1, keepdims=True)
                y = q - np.einsum("mj,mj->m", q - y, nu)[:, None] * nu
        u, g, H = value(y, theta)
        lam = np.einsum("mj,mj->m", q - y, g) / np.einsum("mj,mj->m", g, g)
        ok = np.zeros(len(q), bool)
        live = np.isfinite(lam) & np.isfinite(y).all(axis=1)
        for _ in range(MAX_NEWTON):
            rows = np.flatnonzero(live & ~ok)
            if not len(rows):
                break
            yr, lr, qr, tr = y[rows], lam[rows], q[rows], theta[rows]
            u, g, H = value(yr, tr)
            F = np.concatenate([yr - qr + lr[:, None] * g, u[:, None]], axis=1)
            J = np.zeros((len(rows), 4, 4))
            J[:, :3, :3] = np.eye(3) + lr[:, None, None] * H
            J[:, :3, 3] = g
            J[:, 3, :3] = g
            det = np.linalg.det(J)
            good = np.isfinite(det) & (np.abs(det) > 1e-300)
            step = np.full((len(rows), 4), np.nan)
            step[good] = np.linalg.solve(J[good], -F[good][..., None])[..., 0]
            y[rows] = yr + step[:, :3]
            lam[rows] = lr + step[:, 3]
            size = np.abs(step[:, :3]).max(axis=1)
            ok[rows] = size <= NEWTON_TOL * np.maximum(1.0, np.abs(yr).max(axis=1))
            live[rows] &= np.isfinite(step).all(axis=1)
    return y, lam, ok & live


def _line_root(q, theta):
    """The root of u(q + t d), d = ∇u(q)/|∇u(q)|, nearest q (u is quadratic in t)."""
    u0, g, H = value(q, theta)
    d = g / np.linalg.norm(g, axis=1, keepdims=True)
    B = np.einsum("mj,mj->m", g, d)
    A = 0.5 * np.einsum("mj,mjk,mk->m", d, H, d)
    disc = np.sqrt(np.maximum(B * B - 4 * A * u0, 0.0))
    t = -2 * u0 / (B + np.where(B >= 0, disc, -disc))
    return q + t[:, None] * d


def answer(q, theta):
    """The gap in spacings φ = λ |∇u(y*)|, the unit normal, y*, the principal curvatures (in
    1/spacings, > 0 bending away from the normal) and whether Newton converged."""
    y, lam, ok = closest_point(q, theta)
    _, g, H = value(y, theta)
    norm = np.linalg.norm(g, axis=1)
    nu = g / norm[:, None]
    P = np.eye(3) - nu[:, :, None] * nu[:, None, :]
    shape = P @ H @ P / norm[:, None, None]
    kappa = np.linalg.eigvalsh(np.where(np.isfinite(shape), shape, 0.0))
    # the tangent plane's two of the three eigenvalues: drop the one of the normal (0)
    order = np.argsort(np.abs(kappa), axis=1)
    curv = np.sort(np.take_along_axis(kappa, order[:, 1:], axis=1), axis=1)[:, ::-1]
    return lam * norm, nu, y, curv, ok


class QuadricSurface:
    """The diffuse surface of a target fitted as moving algebraic quadrics to its nodes'
    positions and normals (this module's docstring). For coarse curved targets, a few elements
    per quarter circle, where it reaches MeshLab's APSS and the height fit does not.

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, k) int
        Facet blocks (triangles, quads, second-order cells): their winding orients the
        normals (outward).
    radius : float
        Support radius R in node spacings (before the enlargement to `MIN_NODES` nodes).
    beta : float
        Weight of the normal rows against the position rows.
    flip : bool
        Reverse the orientation.

    It has no crease handling and no faceted guard: it is for smooth curved targets (the
    default surface, `build_surface`, keeps CAD edges and guards every answer).
    """

    #: the basis: the general quadric's 10 terms (never reduced: the normal rows determine it)
    basis = "quadric"
    nterms = NTERMS

    def __init__(self, nodes, faces, *, radius: float = DEFAULT_RADIUS,
                 beta: float = DEFAULT_BETA, flip: bool = False, check_winding: bool = True,
                 shared=None):
        from ..nodes import SharedNodes

        self.nodes = as_target_nodes(nodes)
        if not radius > 1.0:
            raise ValueError(f"radius must be > 1 node spacing, got {radius}")
        if not beta > 0:
            raise ValueError(f"beta must be > 0 (the normal rows' weight), got {beta}")
        self.radius, self.beta, self.flip = float(radius), float(beta), bool(flip)
        self.faces = as_faces(faces, len(self.nodes))
        if not any(len(f) for f in self.faces):
            raise ValueError("the quadric fit needs facets: its nodal normals come from them")
        shared = SharedNodes.of(self.nodes, shared)
        self.first, self.distinct = shared.first, shared.distinct
        if len(self.distinct) < FEW:
            raise ValueError(f"the target has {len(self.distinct)} distinct nodes; the quadric "
                             f"fit needs at least {FEW}")
        if check_winding and not flip:
            warn_inside_out(self.nodes, self.faces, self.first)
        self.node_spacing = shared.spacing
        #: linear facets over the distinct nodes: the nodal normals' polygons
        self.polygons = [self.first[p] for p in polygons(self.faces)]
        self.corners = corners(self.polygons)
        order = np.argsort(self.corners[0], kind="stable")
        self.corners = tuple(a[order] for a in self.corners)
        self.corner_ptr = np.concatenate([[0], np.cumsum(np.bincount(
            self.corners[0], minlength=len(self.nodes)))])
        self.sign = -1.0 if self.flip else 1.0
        self._geometry()
        self.deformed = False
        self._facets = None
        self._nearest = None
        self._compiled = None  # `compiled`, built on first use

    def _geometry(self):
        N = self.sign * angle_sums(self.nodes, self.corners, len(self.nodes))
        norm = np.linalg.norm(N, axis=1, keepdims=True)
        self.normals = np.divide(N, norm, out=np.zeros_like(N), where=norm > 0)[self.first]
        self.tree = cKDTree(self.nodes[self.distinct])

    # -- what every surface answers ----------------------------------------------------------
    def facet_surface(self):
        """The target's own facets (`FacetSurface`), built once: the first centres."""
        if self._facets is None:
            from ..facet.surface import FacetSurface

            self._facets = FacetSurface(self.nodes, [_frame.facet_corners(f) for f in self.faces
                                                     if f.size], flip=self.flip,
                                         check_winding=False)
        return self._facets

    @property
    def engine(self):
        """The search structures the projection uses (the facets' compiled search for the
        first centres, the nodes' tree), built on first use: a command builds them as part
        of its setup."""
        self.facet_surface().engine  # noqa: B018 - the property builds it
        return self.tree

    @property
    def nearest_node(self) -> NearestNode:
        if self._nearest is None:
            self._nearest = NearestNode(self.nodes, self.node_spacing, OFF_SPACINGS)
        return self._nearest

    def moved(self, nodes) -> QuadricSurface:
        """The same target with its nodes at new positions (a deformable target): the same
        facets and options, the spacing, normals and search measured again. A pairing taken
        on this surface applies to the moved one (`project_with`, `contact(pairing=)`)."""
        import copy

        from ..nodes import node_spacing

        new = copy.copy(self)
        new.nodes = as_moved_nodes(nodes, self.nodes)
        new.node_spacing = node_spacing(new.nodes)
        new._geometry()
        new.deformed = True
        new._facets = None if self._facets is None else self._facets.moved(new.nodes)
        new._nearest = None
        new._compiled = None
        return new

    # -- the fit at a frozen pairing ------------------------------------------------------
    def fit_patch(self, patch: Patch, rcond: bool = True, matrix: bool = False):
        """θ (m, 10), rcond (NaN unless `rcond`) and the support nodes of positive weight of
        the frozen pairing's fits, at the nodes' current positions; with `matrix`, also
        A + `RIDGE` I (`fit`)."""
        index = np.asarray(patch.index)
        c, h, R = patch.origin, patch.spacing, patch.radius
        x = self.nodes[np.maximum(index, 0)]
        n = self.normals[np.maximum(index, 0)]
        taper = sheet_taper(np.einsum("mkj,mj->mk", n, patch.axes[:, 2]))[0]
        d = x - c[:, None]
        w = wendland(np.sqrt(np.einsum("mkj,mkj->mk", d, d)) / R[:, None])[0] * taper * (
            index >= 0)
        theta, cond, A = fit(d / h[:, None, None], w, n, self.beta, rcond)
        return (theta, cond, (w > 0).sum(axis=1)) + ((A,) if matrix else ())

    # -- the projection ----------------------------------------------------------------------
    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        """Gap, normal, proximal point and status of each contactor (this module's
        docstring). `keep_patch`: the frozen pairing (`Projection.patch`) too."""
        points = as_points(points)
        if progress is not None:
            progress(0)  # the work starts: what came before was setup
        parts = []
        for lo in range(0, len(points), CHUNK):
            parts.append(self._project(points[lo:lo + CHUNK]))
            if progress is not None:
                progress(min(lo + CHUNK, len(points)))
        res = _concat(points, parts or [self._project(points[:0])])
        if not keep_patch:
            res.patch = None
        return res

    def project_with(self, points, patch) -> Projection:
        """The answer of a frozen pairing (`Patch`: centres, spacings, radii, supports) at the
        nodes' current positions, without searching or re-centring."""
        points = as_points(points)
        if isinstance(patch, Patch) is False:
            patch = patch.patch
        return self._answer(points, patch, np.ones(len(points), bool))[0]

    def first_centres(self, x, good):
        """Each contactor's first centre (its faceted foot; the nearest node where the facets
        give none) and sheet normal (the foot facet's own normal: the facets' answer's is the
        direction to x where the foot is on an edge or a corner, tangent beside an open
        edge)."""
        xs = np.where(good[:, None], x, 0.0)
        foot = self.facet_surface().project(xs)
        c = np.where(np.isfinite(foot.proximal_point), foot.proximal_point,
                     self.nodes[self.distinct[self.tree.query(xs)[1]]])
        e3 = self._facet_normals(foot.facet)
        nofoot = ~np.isfinite(e3).all(axis=1)
        if nofoot.any():
            e3[nofoot] = self.normals[self.distinct[self.tree.query(c[nofoot])[1]]]
        return c, e3

    def __getstate__(self):
        # the compiled view (its grid) does not pickle; it is rebuilt on first use
        state = self.__dict__.copy()
        state["_compiled"] = None
        return state

    @property
    def compiled(self):
        """The compiled projection's view of the nodes (`_quadric.Quadrics`), built once."""
        if self._compiled is None:
            from . import _quadric

            self._compiled = _quadric.Quadrics(self.nodes, self.distinct, self.normals,
                                               self.node_spacing)
        return self._compiled

    def _project(self, x):
        """The compiled re-centring (`_quadric`: this module's steps per contactor;
        tests/reference_quadric.py is the same loop in numpy)."""
        good = np.isfinite(x).all(axis=1)
        c, e3 = self.first_centres(x, good)
        out = self.compiled.project(_params(self),
                                    np.ascontiguousarray(np.where(good[:, None], x, 0.0)),
                                    np.ascontiguousarray(c), np.ascontiguousarray(e3))
        origin, e3, radius, spacing, index = (out.pop(k) for k in
                                              ("origin", "e3", "radius", "spacing", "index"))
        width = int((index >= 0).sum(axis=1).max(initial=0))
        patch = Patch(origin, np.where(np.isfinite(e3).all(axis=1)[:, None, None],
                                       _axes(np.where(np.isfinite(e3), e3, 1.0)), np.nan),
                      radius, spacing, np.ascontiguousarray(index[:, :width]))
        res = Projection(x, **out, patch=patch)
        res.status[~good], res.reason[~good] = FAILED, BAD_POINT
        for name in ("gap", "normal", "proximal_point", "curvature", "rcond"):
            getattr(res, name)[~good] = np.nan
        res.support[~good], res.terms[~good], res.iterations[~good] = 0, 0, 0
        return res

    def _facet_normals(self, facet):
        """The unit normals of facets (FacetSurface numbering; NaN for -1), oriented."""
        fs = self.facet_surface()
        corner = fs.facets[np.maximum(facet, 0)]
        count = np.where(corner[:, 3] >= 0, 4, 3)
        x = self.nodes[np.maximum(corner, 0)]
        rows = np.arange(len(facet))
        area = sum(np.cross(x[:, k], x[rows, (k + 1) % count]) * (k < count)[:, None]
                   for k in range(4))
        with np.errstate(all="ignore"):
            n = self.sign * area / np.linalg.norm(area, axis=1, keepdims=True)
        n[np.asarray(facet) < 0] = np.nan
        return n

    def _answer(self, x, patch, good, rcond=True):
        """Projection of x on the fits of a pairing; also y* (spacings). rcond NaN unless
        `rcond` (the re-centring's intermediate answers need none)."""
        m = len(x)
        theta, rcond, support = self.fit_patch(patch, rcond)
        index = np.asarray(patch.index)
        c, h = patch.origin, patch.spacing
        x_sup = self.nodes[np.maximum(index, 0)]
        q = (x - c) / h[:, None]
        with np.errstate(all="ignore"):
            phi, nu, y, curv, ok = answer(q, np.where(np.isfinite(theta), theta, 0.0))
        gap = h * phi
        prox = c + h[:, None] * y
        status = np.where(gap > 0, OPEN, PENETRATION).astype(np.int8)
        status[np.abs(gap) <= tol.CONTACT * h] = CONTACT
        reason = np.full(m, OK, np.int8)
        dmin = np.where(index >= 0, np.linalg.norm(x_sup - prox[:, None], axis=2), np.inf)
        far = dmin.min(axis=1, initial=np.inf) > OFF_SPACINGS * h
        status[far], reason[far] = OUTSIDE, OFF_TARGET
        nc = ~ok
        status[nc], reason[nc] = FAILED, NO_CONVERGENCE
        ill = ~np.isfinite(theta).all(axis=1)
        status[ill], reason[ill] = FAILED, ILL_CONDITIONED
        few = support < FEW
        status[few], reason[few] = FAILED, FEW_NODES
        status[~good], reason[~good] = FAILED, BAD_POINT
        lost = np.isin(status, (FAILED, OUTSIDE))
        gap[lost], nu[lost], prox[lost], curv[lost] = np.nan, np.nan, np.nan, np.nan
        res = Projection(x, gap, nu, prox, status, support.astype(np.int64),
                         np.ones(m, np.int64), rcond, curv / h[:, None], reason,
                         terms=np.where(lost & (reason != OFF_TARGET), 0, NTERMS).astype(np.int8),
                         patch=patch)
        return res, y


def _params(surface) -> dict:
    """The compiled projection's settings: this module's constants, read at call time."""
    return dict(radius=surface.radius, beta=surface.beta, ridge=RIDGE, settle=SETTLE,
                newton_tol=NEWTON_TOL, off=OFF_SPACINGS, sheet_deg=SHEET_DEG,
                k_search=K_SEARCH, min_nodes=MIN_NODES, few=FEW, max_centres=MAX_CENTRES,
                max_newton=MAX_NEWTON)


def _axes(e3):
    """(m, 3, 3) rows e1, e2, e3 of a frame whose third axis is e3 (a pairing's frame: the
    sheet filter's normal)."""
    e3 = e3 / np.linalg.norm(e3, axis=1, keepdims=True)
    t = np.where(np.abs(e3[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    e1 = t - e3 * np.sum(t * e3, axis=1, keepdims=True)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(e3, e1), e3], axis=1)


_FIELDS = ("gap", "normal", "proximal_point", "status", "support", "iterations", "rcond",
           "curvature", "reason", "terms")


def _concat(points, parts):
    if len(parts) == 1:
        part = parts[0]
        part.points = points
        return part
    K = max(p.patch.index.shape[1] for p in parts)
    index = np.concatenate([np.pad(p.patch.index, ((0, 0), (0, K - p.patch.index.shape[1])),
                                   constant_values=-1) for p in parts])
    patch = Patch(*(np.concatenate([getattr(p.patch, f) for p in parts])
                    for f in ("origin", "axes", "radius", "spacing")), index)
    fields = {name: np.concatenate([getattr(p, name) for p in parts]) for name in _FIELDS}
    return Projection(points, **fields, patch=patch)
