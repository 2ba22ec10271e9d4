"""Exact reference surfaces with faceted meshes, for tests and benchmarks.

Each shape gives a faceted triangle mesh whose vertices lie exactly (to rounding) on the
surface, the exact closest point / outward unit normal / signed distance of query points,
and random points near the surface.  The signed distance is positive on the "outside" of
the surface and mesh faces are oriented (right-hand rule) so that their normals point
outside.  Pure numpy; no file I/O.
"""
from __future__ import annotations

import numpy as np

__all__ = [
    "Shape",
    "Sphere",
    "Cylinder",
    "HeightField",
    "Paraboloid",
    "Saddle",
    "Plane",
    "Torus",
    "random_rotation",
]

_TWO_PI = 2.0 * np.pi


# --------------------------------------------------------------------------- helpers
def _as_points(points):
    """Validate query points: return a finite ``(m, 3)`` float array."""
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (m, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("points must be finite")
    return p


def _as_vec3(x, name):
    v = np.asarray(x, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be a finite 3-vector, got {x!r}")
    return v


def _positive(x, name):
    x = float(x)
    if not (np.isfinite(x) and x > 0.0):
        raise ValueError(f"{name} must be a positive finite number, got {x!r}")
    return x


def _check_n(n, minimum=1, name="n"):
    try:
        ok = not isinstance(n, (bool, np.bool_)) and int(n) == n
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError(f"{name} must be an integer, got {n!r}")
    n = int(n)
    if n < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {n}")
    return n


def _rng(rng):
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _grid_quads(nu, nv, periodic_u=False, periodic_v=False):
    """Quads of a structured grid of ``(nu_nodes, nv_nodes)`` nodes, node ``k = i * nv_nodes + j``.

    ``nu``, ``nv`` are the numbers of cells; a periodic direction has as many nodes as cells.
    Quads are counter-clockwise in the ``(u, v)`` parameter plane.
    """
    nu_nodes = nu if periodic_u else nu + 1
    nv_nodes = nv if periodic_v else nv + 1
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    i, j = i.ravel(), j.ravel()
    i1 = (i + 1) % nu_nodes
    j1 = (j + 1) % nv_nodes
    quads = np.stack(
        [i * nv_nodes + j, i1 * nv_nodes + j, i1 * nv_nodes + j1, i * nv_nodes + j1], axis=1
    )
    return quads.astype(np.int64)


def _split_quads(quads, alternate=False):
    """Split quads ``(a, b, c, d)`` into triangles keeping the orientation.

    ``alternate`` is ``False`` (all quads split along ``a-c``) or a boolean mask of the
    quads split along ``b-d`` instead (e.g. the checkerboard of :func:`_checker`).
    """
    quads = np.asarray(quads)
    a, b, c, d = quads.T
    if alternate is False:
        flip = np.zeros(len(quads), dtype=bool)
    else:
        flip = np.asarray(alternate, dtype=bool)
    t1 = np.where(flip[:, None], np.stack([a, b, d], 1), np.stack([a, b, c], 1))
    t2 = np.where(flip[:, None], np.stack([b, c, d], 1), np.stack([a, c, d], 1))
    return np.concatenate([t1, t2]).astype(np.int64)


def _checker(nu, nv):
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    return ((i + j) % 2 == 1).ravel()


def random_rotation(rng=None):
    """Uniformly distributed (Haar) proper rotation matrix.

    Parameters
    ----------
    rng : numpy.random.Generator or int or None
        Random generator or seed.

    Returns
    -------
    rotation : (3, 3) float
        Orthogonal matrix with determinant +1.
    """
    rng = _rng(rng)
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.where(np.diag(r) < 0.0, -1.0, 1.0)  # Haar on O(3)
    if np.linalg.det(q) < 0.0:
        q[:, 0] = -q[:, 0]  # fixed reflection: Haar on SO(3)
    return q


# --------------------------------------------------------------------------- base class
class Shape:
    """Base class of the exact reference surfaces.

    Attributes
    ----------
    reach : float
        Distance below which a point has a unique closest point on the (unbounded) surface;
        ``closest`` is exact for ``|signed distance| < reach`` and ``sample_near`` requires
        ``max_offset < reach``.
    """

    reach = np.inf
    #: Smallest accepted resolution ``n`` of :meth:`mesh`.
    min_n = 1

    # subclasses implement: closest, mesh, spacing, _sample_surface, _default_margin
    def closest(self, points):  # pragma: no cover - abstract
        raise NotImplementedError

    def mesh(self, n):  # pragma: no cover - abstract
        raise NotImplementedError

    def spacing(self, n):  # pragma: no cover - abstract
        raise NotImplementedError

    def _sample_surface(self, m, margin, rng):  # pragma: no cover - abstract
        raise NotImplementedError

    def _default_margin(self):
        return 0.0

    def sample_near(self, m, max_offset, rng=None, margin=None):
        """Random points near the surface.

        Points are drawn on a region of the surface kept at least ``margin`` away from open
        boundaries (so their closest point is interior), then offset along the exact outward
        normal by a uniform random amount in ``[-max_offset, max_offset]``.

        Parameters
        ----------
        m : int
            Number of points.
        max_offset : float
            Largest normal offset; must be ``>= 0`` and ``< reach``.
        rng : numpy.random.Generator or int or None
            Random generator or seed.
        margin : float, optional
            Distance (along the surface parameters, see each shape) kept from open
            boundaries; default: 10 % of the patch half-size (0 for closed surfaces).

        Returns
        -------
        points : (m, 3) float
            Query points; use :meth:`closest` for the exact answers.
        """
        m = _check_n(m, minimum=0, name="m")
        max_offset = float(max_offset)
        if not (np.isfinite(max_offset) and max_offset >= 0.0):
            raise ValueError(f"max_offset must be a finite number >= 0, got {max_offset!r}")
        if max_offset >= self.reach:
            raise ValueError(f"max_offset={max_offset} must be below the reach {self.reach}")
        margin = self._default_margin() if margin is None else float(margin)
        if not (np.isfinite(margin) and margin >= 0.0):
            raise ValueError(f"margin must be a finite number >= 0, got {margin!r}")
        rng = _rng(rng)
        base, normal = self._sample_surface(m, margin, rng)
        offset = rng.uniform(-max_offset, max_offset, size=m)
        return base + offset[:, None] * normal

    def mesh_quads(self, n):
        """Structured quad mesh (not available for every shape)."""
        raise NotImplementedError(f"{type(self).__name__} has no quad mesh")


# --------------------------------------------------------------------------- sphere
_PHI = (1.0 + np.sqrt(5.0)) / 2.0
_ICO_V = np.array(
    [
        [-1, _PHI, 0], [1, _PHI, 0], [-1, -_PHI, 0], [1, -_PHI, 0],
        [0, -1, _PHI], [0, 1, _PHI], [0, -1, -_PHI], [0, 1, -_PHI],
        [_PHI, 0, -1], [_PHI, 0, 1], [-_PHI, 0, -1], [-_PHI, 0, 1],
    ],
    dtype=float,
) / np.sqrt(1.0 + _PHI**2)
_ICO_F = np.array(
    [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ]
)
#: Arc angle of an icosahedron edge seen from the centre (rad).
_ICO_ARC = float(np.arccos(_ICO_V[0] @ _ICO_V[1]))


class Sphere(Shape):
    """Sphere; the outside is the exterior.

    Parameters
    ----------
    center : (3,) float
        Centre.
    radius : float
        Radius ``R > 0``.

    Notes
    -----
    ``mesh(n)`` is a geodesic (class I) icosphere: each icosahedron edge is cut into ``n``
    segments and the grid points are pushed radially onto the sphere; ``10 n^2 + 2``
    vertices, ``20 n^2`` faces, edge length about ``spacing(n) = 1.107 R / n`` (chord
    lengths between 0.82 and 1.20 times that for any ``n``).  The reach is ``R`` (the centre is
    the only degenerate point).
    """

    def __init__(self, center=(0.0, 0.0, 0.0), radius=1.0):
        self.center = _as_vec3(center, "center")
        self.radius = _positive(radius, "radius")
        self.reach = self.radius

    def spacing(self, n):
        """Nominal node spacing ``R * 1.107 / n`` (arc of an icosahedron edge over ``n``)."""
        return self.radius * _ICO_ARC / _check_n(n)

    def closest(self, points):
        """Exact closest point, outward unit normal and signed distance.

        Parameters
        ----------
        points : (m, 3) float
            Query points, not at the centre.

        Returns
        -------
        closest : (m, 3) float
        normal : (m, 3) float
            Outward unit normal at ``closest``.
        signed_distance : (m,) float
            Positive outside.
        """
        p = _as_points(points)
        d = p - self.center
        r = np.linalg.norm(d, axis=1)
        if np.any(r <= 1e-300):
            raise ValueError("closest point undefined for points at the sphere centre")
        normal = d / r[:, None]
        return self.center + self.radius * normal, normal, r - self.radius

    def mesh(self, n):
        """Geodesic icosphere with ``n`` segments per icosahedron edge.

        Parameters
        ----------
        n : int
            Segments per icosahedron edge (``>= 1``).

        Returns
        -------
        vertices : (10 n^2 + 2, 3) float
        faces : (20 n^2, 3) int
            Outward oriented.
        """
        n = _check_n(n)
        index = {}
        unit = []

        def node(f, i, j):
            # barycentric weights on the corners of face f (integers summing to n)
            w = (n - i - j, i, j)
            key = tuple(sorted((int(_ICO_F[f, k]), w[k]) for k in range(3) if w[k]))
            k = index.get(key)
            if k is None:
                x = sum(wk * _ICO_V[c] for c, wk in key)
                k = index[key] = len(unit)
                unit.append(x / np.linalg.norm(x))
            return k

        faces = []
        for f in range(len(_ICO_F)):
            ids = {(i, j): node(f, i, j) for i in range(n + 1) for j in range(n + 1 - i)}
            for i in range(n):
                for j in range(n - i):
                    faces.append((ids[i, j], ids[i + 1, j], ids[i, j + 1]))
                    if i + j < n - 1:
                        faces.append((ids[i + 1, j], ids[i + 1, j + 1], ids[i, j + 1]))
        vertices = self.center + self.radius * np.array(unit)
        return vertices, np.array(faces, dtype=np.int64)

    def _sample_surface(self, m, margin, rng):
        u = rng.standard_normal((m, 3))
        u /= np.linalg.norm(u, axis=1)[:, None]
        return self.center + self.radius * u, u


# --------------------------------------------------------------------------- cylinder
class Cylinder(Shape):
    """Circular cylinder (open ends, no caps) with axis parallel to z; outside = exterior.

    Parameters
    ----------
    radius : float
        Radius ``R > 0``.
    length : float
        Axial length; the surface spans ``z`` in ``center[2] -+ length / 2``.
    theta_range : (2,) float
        Angular range ``(t0, t1)`` with ``0 < t1 - t0 <= 2 pi``; ``t1 - t0 == 2 pi`` is the
        full (periodic) cylinder, e.g. ``(pi, 2 pi)`` is the half with ``y <= center[1]``.
        A point is ``center + (R cos t, R sin t, z)``.
    center : (3,) float
        Centre of the axis segment.

    Notes
    -----
    ``mesh(n, m)``: ``n`` segments over ``theta_range`` (spacing ``R (t1 - t0) / n``) and
    ``m`` along the axis, by default ``m = max(1, round(length / (R (t1 - t0) / n)))`` so
    the cells are near square.  ``closest`` is relative to the unbounded full cylinder;
    the reach is ``R``.
    """

    def __init__(self, radius=1.0, length=2.0, theta_range=(0.0, _TWO_PI), center=(0.0, 0.0, 0.0)):
        self.radius = _positive(radius, "radius")
        self.length = _positive(length, "length")
        t = np.asarray(theta_range, dtype=float)
        if t.shape != (2,) or not np.all(np.isfinite(t)):
            raise ValueError(f"theta_range must be two finite angles, got {theta_range!r}")
        span = t[1] - t[0]
        if not (0.0 < span <= _TWO_PI * (1.0 + 1e-12)):
            raise ValueError(f"theta_range must satisfy 0 < t1 - t0 <= 2 pi, got {theta_range!r}")
        self.theta_range = (float(t[0]), float(t[1]))
        self.full = bool(abs(span - _TWO_PI) <= 1e-12 * _TWO_PI)
        self.min_n = 3 if self.full else 1
        self.center = _as_vec3(center, "center")
        self.reach = self.radius

    @property
    def _span(self):
        return _TWO_PI if self.full else self.theta_range[1] - self.theta_range[0]

    def spacing(self, n):
        """Node spacing around the circumference, ``R (t1 - t0) / n`` (arc length)."""
        return self.radius * self._span / _check_n(n)

    def _axial_cells(self, n, m):
        if m is None:
            return max(1, int(round(self.length / self.spacing(n))))
        return _check_n(m, name="m")

    def mesh_quads(self, n, m=None):
        """Structured quad mesh.

        Parameters
        ----------
        n : int
            Segments around the circumference (over ``theta_range``); ``>= 3`` if full.
        m : int, optional
            Segments along the axis (default: near-square cells).

        Returns
        -------
        vertices : (v, 3) float
            ``n * (m + 1)`` nodes (full) or ``(n + 1) * (m + 1)`` (partial), theta-major.
        quads : (n * m, 4) int
            Outward oriented.
        """
        n = _check_n(n, minimum=self.min_n)
        m = self._axial_cells(n, m)
        t0 = self.theta_range[0]
        nt = n if self.full else n + 1
        theta = t0 + self._span * np.arange(nt) / n
        if not self.full:
            theta[-1] = self.theta_range[1]
        z = self.center[2] + self.length * (np.arange(m + 1) / m - 0.5)
        tt, zz = np.meshgrid(theta, z, indexing="ij")
        tt, zz = tt.ravel(), zz.ravel()
        vertices = np.stack(
            [
                self.center[0] + self.radius * np.cos(tt),
                self.center[1] + self.radius * np.sin(tt),
                zz,
            ],
            axis=1,
        )
        # (theta, z) counter-clockwise: e_theta x e_z = e_r, outward
        return vertices, _grid_quads(n, m, periodic_u=self.full)

    def mesh(self, n, m=None):
        """Triangle mesh: :meth:`mesh_quads` with each quad split along one diagonal.

        Returns
        -------
        vertices : (v, 3) float
        faces : (2 n m, 3) int
        """
        vertices, quads = self.mesh_quads(n, m)
        return vertices, _split_quads(quads)

    def closest(self, points):
        """Exact closest point on the unbounded cylinder, outward normal, signed distance.

        Parameters
        ----------
        points : (m, 3) float
            Query points, not on the axis.

        Returns
        -------
        closest : (m, 3) float
        normal : (m, 3) float
            Radial outward unit normal.
        signed_distance : (m,) float
            Positive outside.
        """
        p = _as_points(points)
        d = p[:, :2] - self.center[:2]
        rho = np.hypot(d[:, 0], d[:, 1])
        if np.any(rho <= 1e-300):
            raise ValueError("closest point undefined for points on the cylinder axis")
        e = d / rho[:, None]
        normal = np.column_stack([e, np.zeros(len(p))])
        closest = np.column_stack([self.center[:2] + self.radius * e, p[:, 2]])
        return closest, normal, rho - self.radius

    def _default_margin(self):
        half = 0.5 * self.length
        if not self.full:
            half = min(half, 0.5 * self.radius * self._span)
        return 0.1 * half

    def _sample_surface(self, m, margin, rng):
        """Uniform in (theta, z); ``margin`` is an arc length from the theta edges and an
        axial distance from the open ends."""
        half = 0.5 * self.length - margin
        if half <= 0.0:
            raise ValueError(f"margin={margin} leaves no room along the axis")
        if self.full:
            t = rng.uniform(0.0, _TWO_PI, size=m)
        else:
            dt = margin / self.radius
            t0, t1 = self.theta_range[0] + dt, self.theta_range[1] - dt
            if t1 <= t0:
                raise ValueError(f"margin={margin} leaves no room around the circumference")
            t = rng.uniform(t0, t1, size=m)
        z = self.center[2] + rng.uniform(-half, half, size=m)
        e = np.column_stack([np.cos(t), np.sin(t), np.zeros(m)])
        base = np.column_stack([self.center[:2] + self.radius * e[:, :2], z])
        return base, e


# --------------------------------------------------------------------------- height fields
class HeightField(Shape):
    """Quadratic height field ``z = a x^2 + b x y + c y^2`` over ``[-size, size]^2``.

    The outside is the ``+z`` side; normal ``(-f_x, -f_y, 1) / |.|``.

    Parameters
    ----------
    a, b, c : float
        Coefficients.
    size : float
        Half-width of the square patch.

    Notes
    -----
    ``mesh(n)``: ``n x n`` cells of the square (``(n + 1)^2`` nodes), spacing in plan
    ``2 size / n`` (3-D edges are longer by the local slope factor), each cell split along
    alternating diagonals.  ``closest`` solves the closest-point problem on the unbounded
    surface by a safeguarded Newton method on ``(x, y)`` started from the vertical
    projection, converged to ``1e-14`` relative and checked (stationarity and a local
    minimum); the reach is ``1 / max |principal curvature| = 1 / max|eig(H)|`` (attained at
    the apex).  Points beyond it raise ``ValueError`` when the minimum is not strict.
    """

    def __init__(self, a=0.5, b=0.2, c=0.3, size=1.0):
        self.a, self.b, self.c = (float(v) for v in (a, b, c))
        if not np.all(np.isfinite([self.a, self.b, self.c])):
            raise ValueError("coefficients must be finite")
        self.size = _positive(size, "size")
        self.hessian = np.array([[2.0 * self.a, self.b], [self.b, 2.0 * self.c]])
        kmax = np.max(np.abs(np.linalg.eigvalsh(self.hessian)))
        self.reach = np.inf if kmax == 0.0 else 1.0 / kmax

    # f and its gradient
    def height(self, x, y):
        """Height ``z = f(x, y)``.

        Parameters
        ----------
        x, y : (k,) float

        Returns
        -------
        z : (k,) float
        """
        return self.a * x * x + self.b * x * y + self.c * y * y

    def _grad(self, x, y):
        return 2.0 * self.a * x + self.b * y, self.b * x + 2.0 * self.c * y

    def _normal(self, x, y):
        fx, fy = self._grad(x, y)
        nrm = np.column_stack([-fx, -fy, np.ones_like(fx)])
        return nrm / np.linalg.norm(nrm, axis=1)[:, None]

    def spacing(self, n):
        """Node spacing in plan, ``2 size / n``."""
        return 2.0 * self.size / _check_n(n)

    def mesh_quads(self, n):
        """Structured ``n x n`` quad mesh (x-major nodes).

        Returns
        -------
        vertices : ((n + 1)^2, 3) float
        quads : (n^2, 4) int
            Oriented towards ``+z``.
        """
        n = _check_n(n)
        s = self.size * np.linspace(-1.0, 1.0, n + 1)
        s[0], s[-1] = -self.size, self.size
        x, y = (g.ravel() for g in np.meshgrid(s, s, indexing="ij"))
        vertices = np.column_stack([x, y, self.height(x, y)])
        return vertices, _grid_quads(n, n)

    def mesh(self, n):
        """Triangle mesh: :meth:`mesh_quads` split along alternating diagonals.

        Returns
        -------
        vertices : ((n + 1)^2, 3) float
        faces : (2 n^2, 3) int
        """
        vertices, quads = self.mesh_quads(n)
        return vertices, _split_quads(quads, _checker(n, n))

    def closest(self, points):
        """Exact closest point, outward normal and signed distance (Newton on ``(x, y)``).

        Parameters
        ----------
        points : (m, 3) float
            Query points within the reach of the (unbounded) surface.

        Returns
        -------
        closest : (m, 3) float
        normal : (m, 3) float
            Unit normal towards ``+z``.
        signed_distance : (m,) float
            Positive on the ``+z`` side.

        Raises
        ------
        ValueError
            If a point is beyond the reach (no strict local minimum found).
        """
        p = _as_points(points)
        px, py, pz = p.T
        x, y = px.copy(), py.copy()
        hxx, hxy, hyy = self.hessian[0, 0], self.hessian[0, 1], self.hessian[1, 1]
        scale = self.size + np.abs(p).max(axis=1) if len(p) else np.zeros(0)
        tol = 1e-14 * scale

        def objective(i, x, y):
            return 0.5 * ((x - px[i]) ** 2 + (y - py[i]) ** 2 + (self.height(x, y) - pz[i]) ** 2)

        active = np.ones(len(p), dtype=bool)
        for _ in range(100):
            if not active.any():
                break
            i = np.flatnonzero(active)
            xi, yi = x[i], y[i]
            r = self.height(xi, yi) - pz[i]
            fx, fy = self._grad(xi, yi)
            gx = xi - px[i] + r * fx
            gy = yi - py[i] + r * fy
            kxx = 1.0 + fx * fx + r * hxx
            kxy = fx * fy + r * hxy
            kyy = 1.0 + fy * fy + r * hyy
            det = kxx * kyy - kxy * kxy
            pd = (det > 0.0) & (kxx > 0.0)
            safe = np.where(pd, det, 1.0)
            sx = np.where(pd, -(kyy * gx - kxy * gy) / safe, -gx)
            sy = np.where(pd, -(kxx * gy - kxy * gx) / safe, -gy)
            # safeguard: never move further than the distance to the vertical projection scale
            cap = np.maximum(np.abs(r), tol[i]) + np.hypot(xi - px[i], yi - py[i])
            slen = np.hypot(sx, sy)
            shrink = np.where(slen > cap, cap / np.maximum(slen, 1e-300), 1.0)
            sx, sy = sx * shrink, sy * shrink
            # backtracking on the objective for large steps only (the objective cannot
            # resolve position changes below ~sqrt(eps); near the solution the full
            # Newton step is taken)
            f0 = objective(i, xi, yi)
            t = np.ones_like(sx)
            big = np.hypot(sx, sy) > 1e-6 * scale[i]
            for _ls in range(40):
                fn = objective(i, xi + t * sx, yi + t * sy)
                bad = big & (fn > f0)
                if not bad.any():
                    break
                t = np.where(bad, 0.5 * t, t)
            x[i] = xi + t * sx
            y[i] = yi + t * sy
            done = (np.hypot(t * sx, t * sy) <= tol[i]) & pd
            active[i[done]] = False
        if active.any():
            raise ValueError(
                f"closest point not found for {active.sum()} point(s): beyond the reach "
                f"{self.reach:g} of the surface?"
            )
        c = np.column_stack([x, y, self.height(x, y)])
        normal = self._normal(x, y)
        diff = p - c
        dist = np.einsum("ij,ij->i", diff, normal)
        # check: the residual is normal to the surface, and the stationary point is a minimum
        tang = np.linalg.norm(diff - dist[:, None] * normal, axis=1)
        if np.any(tang > 1e-10 * scale):
            raise ValueError("closest point check failed (residual not normal to the surface)")
        fx, fy = self._grad(x, y)
        r = c[:, 2] - pz
        det = (1.0 + fx * fx + r * hxx) * (1.0 + fy * fy + r * hyy) - (fx * fy + r * hxy) ** 2
        if np.any(det <= 0.0):
            raise ValueError(f"point(s) beyond the reach {self.reach:g} of the surface")
        return c, normal, dist

    def _default_margin(self):
        return 0.1 * self.size

    def _sample_surface(self, m, margin, rng):
        """Uniform in ``(x, y)`` over ``[-size + margin, size - margin]^2``."""
        h = self.size - margin
        if h <= 0.0:
            raise ValueError(f"margin={margin} leaves no room in the patch")
        x = rng.uniform(-h, h, size=m)
        y = rng.uniform(-h, h, size=m)
        return np.column_stack([x, y, self.height(x, y)]), self._normal(x, y)


class Paraboloid(HeightField):
    """Quadratic height field ``z = a x^2 + b x y + c y^2`` over ``[-size, size]^2``.

    Reproduced exactly by a quadratic moving-least-squares basis.  See :class:`HeightField`.
    """

    def __init__(self, a=0.5, b=0.2, c=0.3, size=1.0):
        super().__init__(a, b, c, size)


class Saddle(HeightField):
    """Saddle ``z = a (x^2 - y^2)`` over ``[-size, size]^2``; outside = ``+z``.

    Reach ``1 / (2 |a|)``.  See :class:`HeightField`.
    """

    def __init__(self, a=0.5, size=1.0):
        super().__init__(a, 0.0, -float(a), size)


# --------------------------------------------------------------------------- plane
class Plane(Shape):
    """Square plane patch in any orientation; outside = the side ``normal`` points to.

    Parameters
    ----------
    origin : (3,) float
        Centre of the patch.
    normal : (3,) float
        Outward normal (normalised internally).
    size : float
        Half-width: the patch is ``origin + s u + t v`` for ``s, t`` in ``[-size, size]``
        with ``(u, v, normal)`` a right-handed orthonormal frame (``u``, ``v`` attributes).

    Notes
    -----
    ``mesh(n)``: ``n x n`` cells, spacing ``2 size / n``.  Reach infinite.
    """

    def __init__(self, origin=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), size=1.0):
        self.origin = _as_vec3(origin, "origin")
        nrm = _as_vec3(normal, "normal")
        length = np.linalg.norm(nrm)
        if length == 0.0:
            raise ValueError("normal must be non-zero")
        self.normal = nrm / length
        self.size = _positive(size, "size")
        axis = np.zeros(3)
        axis[np.argmin(np.abs(self.normal))] = 1.0
        u = axis - (axis @ self.normal) * self.normal
        self.u = u / np.linalg.norm(u)
        self.v = np.cross(self.normal, self.u)

    def spacing(self, n):
        """Node spacing ``2 size / n``."""
        return 2.0 * self.size / _check_n(n)

    def mesh_quads(self, n):
        """Structured ``n x n`` quad mesh.

        Returns
        -------
        vertices : ((n + 1)^2, 3) float
        quads : (n^2, 4) int
            Oriented along ``normal``.
        """
        n = _check_n(n)
        s = self.size * np.linspace(-1.0, 1.0, n + 1)
        a, b = (g.ravel() for g in np.meshgrid(s, s, indexing="ij"))
        vertices = self.origin + a[:, None] * self.u + b[:, None] * self.v
        return vertices, _grid_quads(n, n)

    mesh = HeightField.mesh  # the same split of the same n x n grid

    def closest(self, points):
        """Exact orthogonal projection onto the (unbounded) plane.

        Parameters
        ----------
        points : (m, 3) float

        Returns
        -------
        closest : (m, 3) float
        normal : (m, 3) float
        signed_distance : (m,) float
            Positive on the ``normal`` side.
        """
        p = _as_points(points)
        dist = (p - self.origin) @ self.normal
        normal = np.broadcast_to(self.normal, p.shape).copy()
        return p - dist[:, None] * self.normal, normal, dist

    def _default_margin(self):
        return 0.1 * self.size

    def _sample_surface(self, m, margin, rng):
        h = self.size - margin
        if h <= 0.0:
            raise ValueError(f"margin={margin} leaves no room in the patch")
        s = rng.uniform(-h, h, size=(m, 2))
        base = self.origin + s[:, :1] * self.u + s[:, 1:] * self.v
        return base, np.broadcast_to(self.normal, base.shape).copy()


# --------------------------------------------------------------------------- torus
class Torus(Shape):
    """Closed torus around the z axis; outside = exterior of the solid torus.

    Parameters
    ----------
    major : float
        Radius ``R`` of the core circle.
    minor : float
        Tube radius ``r``, ``0 < r < R``.
    center : (3,) float
        Centre.

    Notes
    -----
    A point is ``center + ((R + r cos psi) cos phi, (R + r cos psi) sin phi, r sin psi)``.
    ``mesh(n)``, ``n >= 8``: ``n`` segments around the core circle (spacing
    ``2 pi (R -+ r) / n`` on the inner / outer equator, ``2 pi R / n`` on the core) and
    ``k = max(8, round(n r / R))`` around the tube (spacing ``2 pi r / k``).  Reach
    ``min(r, R - r)``.
    """

    def __init__(self, major=1.0, minor=0.4, center=(0.0, 0.0, 0.0)):
        self.major = _positive(major, "major")
        self.minor = _positive(minor, "minor")
        if self.minor >= self.major:
            raise ValueError("minor radius must be smaller than the major radius")
        self.center = _as_vec3(center, "center")
        self.reach = min(self.minor, self.major - self.minor)

    min_n = 8

    def tube_segments(self, n):
        """Segments around the tube for resolution ``n``: ``max(8, round(n r / R))``."""
        return max(8, int(round(_check_n(n) * self.minor / self.major)))

    def spacing(self, n):
        """Nominal node spacing along the core circle, ``2 pi R / n``."""
        return _TWO_PI * self.major / _check_n(n)

    def _point(self, phi, psi):
        rho = self.major + self.minor * np.cos(psi)
        return self.center + np.column_stack(
            [rho * np.cos(phi), rho * np.sin(phi), self.minor * np.sin(psi)]
        )

    @staticmethod
    def _normal(phi, psi):
        return np.column_stack([np.cos(psi) * np.cos(phi), np.cos(psi) * np.sin(phi), np.sin(psi)])

    def mesh_quads(self, n):
        """Structured periodic quad mesh.

        Parameters
        ----------
        n : int
            Segments around the core circle (``>= 8``; coarser meshes have faces
            facing inwards on the hole side).

        Returns
        -------
        vertices : (n k, 3) float
            ``phi``-major nodes, ``k = tube_segments(n)``.
        quads : (n k, 4) int
            Outward oriented.
        """
        n = _check_n(n, minimum=self.min_n)
        k = self.tube_segments(n)
        phi = _TWO_PI * np.arange(n) / n
        psi = _TWO_PI * np.arange(k) / k
        pp, ss = (g.ravel() for g in np.meshgrid(phi, psi, indexing="ij"))
        # e_phi x e_psi = outward normal
        return self._point(pp, ss), _grid_quads(n, k, periodic_u=True, periodic_v=True)

    def mesh(self, n):
        """Triangle mesh: :meth:`mesh_quads` with each quad split along one diagonal.

        Returns
        -------
        vertices : (n k, 3) float
        faces : (2 n k, 3) int
        """
        vertices, quads = self.mesh_quads(n)
        return vertices, _split_quads(quads)

    def closest(self, points):
        """Exact closest point (closed form), outward normal and signed distance.

        Parameters
        ----------
        points : (m, 3) float
            Query points off the z axis and off the core circle.

        Returns
        -------
        closest : (m, 3) float
        normal : (m, 3) float
        signed_distance : (m,) float
            Positive outside the solid torus.
        """
        p = _as_points(points)
        d = p - self.center
        rho = np.hypot(d[:, 0], d[:, 1])
        if np.any(rho <= 1e-300):
            raise ValueError("closest point undefined for points on the torus axis")
        e = np.column_stack([d[:, 0] / rho, d[:, 1] / rho, np.zeros(len(p))])
        core = self.center + self.major * e
        w = p - core
        wn = np.linalg.norm(w, axis=1)
        if np.any(wn <= 1e-300):
            raise ValueError("closest point undefined for points on the core circle")
        normal = w / wn[:, None]
        return core + self.minor * normal, normal, wn - self.minor

    def _sample_surface(self, m, margin, rng):
        """Area-uniform on the torus (rejection on the ``phi`` circumference factor)."""
        phi = np.empty(0)
        psi = np.empty(0)
        while len(phi) < m:
            k = 2 * (m - len(phi)) + 8
            a = rng.uniform(0.0, _TWO_PI, size=k)
            b = rng.uniform(0.0, _TWO_PI, size=k)
            keep = rng.uniform(0.0, 1.0, size=k) * (self.major + self.minor) <= (
                self.major + self.minor * np.cos(b)
            )
            phi = np.concatenate([phi, a[keep]])
            psi = np.concatenate([psi, b[keep]])
        phi, psi = phi[:m], psi[:m]
        return self._point(phi, psi), self._normal(phi, psi)
