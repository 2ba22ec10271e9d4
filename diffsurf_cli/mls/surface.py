"""The diffuse surface of a target and the projection of contactors onto it.

For each contactor x^c the pipeline is the paper's §3-§4.1, batched over chunks of contactors:

1. support: the target nodes around the reference point (the contactor itself, or its last
   proximal point when re-centring), with radius R = `radius` x local node spacing;
2. frame R^d: the global mean plane or a local weighted-PCA frame (`frame.py`);
3. fit: weighted least squares (P^T W P) α = P^T W Z [15]-[17] (`fit.py`);
4. proximal point: Newton on (x^c - x^d)·τ_k = 0 [30], normal [29], gap [32], status [33].

Per-point trouble (too little support, an ill-conditioned fit, a Newton that does not
converge, a proximal point off the target) is reported as a status with NaNs, never raised.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import basis as _basis
from . import frame as _frame
from .. import tol
from . import weight as _weight
from .fit import fit

#: Status codes [33], in the order of `STATUS`.
STATUS = ("open", "contact", "penetration", "outside", "failed")
OPEN, CONTACT, PENETRATION, OUTSIDE, FAILED = range(5)
#: Why a point is 'outside' or 'failed' (`Projection.reason`, in the order of `REASONS`):
#: 'ok' for the other statuses; 'bad-point' a contactor with NaN or inf; 'few-nodes' fewer
#: support nodes than basis terms; 'ill-conditioned' a support that cannot determine the basis
#: (collinear or one-sided nodes: reciprocal condition number below `tol.RCOND_MIN`);
#: 'off-target' a proximal point past the target's edge or beyond every support node;
#: 'no-convergence' Newton [30] did not converge; 'recentre' re-centring did not settle;
#: 'steep' the support holds a node where the target turns vertical or folds back over the
#: frame (`frame.FOLD_SLOPE_DEG`): X3 = f(X1, X2) cannot represent it there.
REASONS = ("ok", "bad-point", "few-nodes", "ill-conditioned", "off-target", "no-convergence",
           "recentre", "steep")
(OK, BAD_POINT, FEW_NODES, ILL_CONDITIONED, OFF_TARGET, NO_CONVERGENCE,
 NOT_SETTLED, STEEP) = range(len(REASONS))
SUPPORTS = ("radius", "knn")
#: A proximal point farther than this many local node spacings from every support node is off
#: the target (beyond an open boundary): status 'outside'.
OUTSIDE_SPACINGS = 1.0
#: Default domain of influence per basis, in local node spacings (measured: benchmarks/accuracy.py
#: and README "Defaults"): a cubic fit at 2.0 spacings has too few nodes near open edges.
DEFAULT_RADIUS = {"linear": 2.0, "quadratic": 2.0, "cubic": 3.0}
#: Factor on R for a second try when the first support is too thin for the basis, or its fit
#: carries the proximal point off the target.
ENLARGE = 1.5
#: A proximal point beyond the in-plane hull of its support by more than this many spacings
#: is past an open edge of the target: 'outside'.
HULL_SPACINGS = 0.25
#: With 'knn' support, R is this factor times the in-plane distance of the farthest of the k
#: nodes, so all k keep a positive weight.
KNN_RADIUS_FACTOR = 1.2
#: Local frames are fitted by PCA over a ball this many R wide, so the support does not change
#: abruptly with the frame.
FRAME_BALL = 1.5
#: With local frames, support nodes whose normal is more than this angle away from the normal
#: at the reference point belong to another sheet of the target (the far side of a thin tube
#: or plate) and are left out. Deliberately not a round angle: regular meshes (steps of 7.5°,
#: 15°, 30°, 45°, 60°) would put node normals exactly on the threshold, where round-off decides.
SHEET_ANGLE_DEG = 63.0
#: Node spacing at a point: mean over its nearest nodes of their mean distance to their
#: nearest neighbours (this many of each).
SPACING_NEIGHBOURS = 4
#: Contactors processed at once: bounds memory to a few hundred MB whatever the cloud size.
CHUNK = 8192
#: Engines of the projection: the compiled kernel, or the numpy reference implementation.
ENGINES = ("kernel", "numpy")
#: Initial per-point support capacity of the kernel's scratch (rows with more nodes in their
#: support are run again with a larger one).
KERNEL_CAP = 128


@dataclass
class Patch:
    """The frozen pairing of a chunk of contactors: what the paper holds fixed [§4.2].

    origin : (m, 3) float  reference point (basis centre) of each local approximation
    axes : (m, 3, 3) float  rows e1, e2, e3 of each diffuse frame
    radius : (m,) float     R, the radius of the domain of influence
    spacing : (m,) float    local node spacing h (tolerances and 'outside' are relative to it)
    index : (m, K) int      support node indices, -1 padded
    """

    origin: np.ndarray
    axes: np.ndarray
    radius: np.ndarray
    spacing: np.ndarray
    index: np.ndarray


@dataclass
class Projection:
    """Contact quantities of each contactor on the diffuse surface (arrays, one row per point).

    points : (m, 3) float           the contactors x^c
    gap : (m,) float                normal gap g [32], > 0 open, < 0 penetration
    normal : (m, 3) float           unit normal ν [29] at the proximal point, out of the target
    proximal_point : (m, 3) float   x^d [25]
    status : (m,) int8              index into `STATUS`
    support : (m,) int              number of support nodes with positive weight
    iterations : (m,) int           Newton iterations (summed over re-centrings)
    rcond : (m,) float              reciprocal condition number of the scaled fit
    curvature : (m, 2) float        principal curvatures κ1 ≥ κ2 of the local fit at x^d,
                                    > 0 where the surface bends away from ν (convex, as a
                                    sphere seen from outside)
    reason : (m,) int8              index into `REASONS`: why a point is outside or failed
    """

    points: np.ndarray
    gap: np.ndarray
    normal: np.ndarray
    proximal_point: np.ndarray
    status: np.ndarray
    support: np.ndarray
    iterations: np.ndarray
    rcond: np.ndarray
    curvature: np.ndarray
    reason: np.ndarray
    patch: Patch | None = field(default=None, repr=False)

    @property
    def status_names(self) -> np.ndarray:
        return np.asarray(STATUS, dtype=object)[self.status]

    @property
    def reason_names(self) -> np.ndarray:
        return np.asarray(REASONS, dtype=object)[self.reason]

    @property
    def thin(self) -> np.ndarray:
        """Rows whose support cannot carry the basis (too few nodes, or ill-conditioned)."""
        return (self.reason == FEW_NODES) | (self.reason == ILL_CONDITIONED)

    def columns(self) -> dict[str, np.ndarray]:
        """The output columns x,y,z,gap,nx,ny,nz,px,py,pz,status,support,iterations,rcond,
        reason."""
        p, n, d = self.points, self.normal, self.proximal_point
        return {
            "x": p[:, 0], "y": p[:, 1], "z": p[:, 2], "gap": self.gap,
            "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2],
            "px": d[:, 0], "py": d[:, 1], "pz": d[:, 2],
            "status": self.status, "support": self.support, "iterations": self.iterations,
            "rcond": self.rcond, "reason": self.reason,
        }


def _as_points(points, name="points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {arr.shape}")
    return arr


def _kdtree(points: np.ndarray):
    """scipy's k-d tree, imported on first use: the compiled kernel needs none, and scipy.spatial
    takes a fifth of a second to import."""
    from scipy.spatial import cKDTree

    return cKDTree(points)


def _neighbours(tree, centres: np.ndarray, radius: np.ndarray, k0: int):
    """All tree points within `radius` (per centre) of each centre, as padded arrays.

    Returns (index (m, K) with -1 padding, distance (m, K) with inf padding), nearest first.
    Queries k nearest and doubles k for the rows whose k-th neighbour is still inside.
    """
    n = tree.n
    m = len(centres)
    k = min(k0, n)
    dist, idx = tree.query(centres, k=k)
    dist, idx = dist.reshape(m, k), idx.reshape(m, k)
    while k < n:
        short = dist[:, -1] <= radius
        if not short.any():
            break
        k = min(2 * k, n)
        d2, i2 = tree.query(centres[short], k=k)
        pad = k - dist.shape[1]
        dist = np.pad(dist, ((0, 0), (0, pad)), constant_values=np.inf)
        idx = np.pad(idx, ((0, 0), (0, pad)), constant_values=n)
        dist[short], idx[short] = d2.reshape(-1, k), i2.reshape(-1, k)
    inside = dist <= radius[:, None]
    K = max(int(inside.sum(axis=1).max(initial=0)), 1)
    idx = np.where(inside, idx, -1)[:, :K]
    dist = np.where(inside, dist, np.inf)[:, :K]
    return idx, dist


class DiffuseSurface:
    """The diffuse (moving least squares) surface S_g^d of a faceted target.

    Built once from the target's nodes (and facets, for orientation and node spacing); then
    `project` any number of contactor points.

    Parameters
    ----------
    nodes : (n, 3) float
        Target nodes x^i (mid-side nodes of higher-order facets included). Exact duplicates
        (FE meshes repeat nodes along zone boundaries) are merged: each position enters a
        support once, as its first occurrence, which alone carries the contact element's
        derivatives; the facets of every copy orient it.
    faces : (f, 3) or (f, 4) int array, or a list of such blocks, optional
        Facet corners indexing `nodes`; orient the normals (+e3 out of the target). Without
        them the global mean plane's orientation is arbitrary and local frames follow it.
    basis : {'linear', 'quadratic', 'cubic'}
        Polynomial basis [14].
    weight : {'wendland', 'gauss', 'singular'}
        Weight function [15]; 'singular' interpolates the nodes.
    support : {'radius', 'knn'}
        'radius': nodes within R = `radius` x local spacing; 'knn': the `k` nearest nodes.
    radius : float, optional
        Domain of influence in units of the local node spacing (support='radius'); default
        `DEFAULT_RADIUS` of the basis (a cubic needs a wider support than a quadratic).
    k : int, optional
        Number of nearest nodes (support='knn'); default 3x the basis size.
    frame : {'auto', 'global', 'local'}
        'global': one mean plane [§3]; 'local': a PCA frame per point; 'auto': global when the
        target is a height field over its mean plane, else local. Points whose support reaches
        where the target turns vertical or folds over the frame (a forced global frame on a
        closed target; a support wrapping around a faceless one) are 'outside' (reason 'steep').
    recentre : bool
        Re-centre the fit on the proximal point until it stops moving (the MLS projection on
        S_g^d) instead of the paper's single fit centred at the contactor.
    flip : bool
        Reverse the orientation (+e3 into the target).
    outside_spacings : float
        A proximal point farther than this many local node spacings from every support node
        is off the target ('outside'); default `OUTSIDE_SPACINGS`.
    engine : {'kernel', 'numpy'}
        'kernel': the compiled kernel (kernel.py, fast, in parallel); 'numpy': the vectorised
        reference implementation (`select` and `_solve`). Both give the same results.
    """

    def __init__(self, nodes, faces=None, *, basis="quadratic", weight="wendland",
                 support="radius", radius=None, k=None, frame="auto", recentre=False,
                 flip=False, engine="kernel", outside_spacings=OUTSIDE_SPACINGS):
        self.nodes = _as_points(nodes, "nodes")
        if not np.all(np.isfinite(self.nodes)):
            raise ValueError("target nodes contain NaN or inf")
        top = np.abs(self.nodes).max(initial=0.0)
        if not top < tol.COORDINATE_MAX:
            raise ValueError(f"target coordinates reach {top:.3g}, beyond the supported "
                             f"{tol.COORDINATE_MAX:.0e}: rescale the mesh")
        self.basis = basis
        self.nterms = _basis.size(basis)
        self.weight = _weight.check(weight)
        if support not in SUPPORTS:
            raise ValueError(f"unknown support {support!r}: expected one of {', '.join(SUPPORTS)}")
        self.support = support
        if radius is None:
            radius = DEFAULT_RADIUS[basis]
        if not radius > 1.0:
            raise ValueError(f"radius must be > 1 node spacing, got {radius}")
        self.radius = float(radius)
        self.k = int(k) if k is not None else 3 * self.nterms
        if frame not in _frame.FRAMES:
            raise ValueError(f"unknown frame {frame!r}: expected one of {', '.join(_frame.FRAMES)}")
        self.recentre = bool(recentre)
        # exact duplicates are merged: `first[i]` is the first node at the position of node i;
        # `_solve` maps every support onto firsts, so each position enters the fit once
        _, first, inverse = np.unique(self.nodes, axis=0, return_index=True,
                                      return_inverse=True)
        self.first = first[inverse.ravel()]
        self.duplicates = len(first) < len(self.nodes)
        n = len(first)
        if n < self.nterms or (support == "knn" and self.k < self.nterms):
            raise ValueError(
                f"the target has {n} {'distinct ' if self.duplicates else ''}nodes; the {basis} "
                f"basis needs at least {self.nterms}" if n < self.nterms
                else f"k={self.k} is below the {basis} basis size {self.nterms}")
        if faces is None:
            faces = []
        elif isinstance(faces, np.ndarray) and faces.ndim == 2:
            faces = [faces]  # one block of facets, as a (f, 3) or (f, 4) array
        self.faces = [np.asarray(f, dtype=np.int64) for f in faces]
        self.normals = _frame.node_normals(self.nodes, [self.first[f] for f in self.faces])
        self.normals = self.normals[self.first]  # copies share the normal of all their facets
        if flip:
            self.normals = -self.normals
        if engine not in ENGINES:
            raise ValueError(f"unknown engine {engine!r}: expected one of {', '.join(ENGINES)}")
        self.engine = engine
        self.outside_spacings = float(outside_spacings)
        self._tree = self._plane_tree = self._grids = None
        distinct = self.nodes[first]
        k = min(SPACING_NEIGHBOURS + 1, n)
        if engine == "kernel":
            from .. import kernel
            dist = kernel.nearest_distances(distinct, k)
        else:
            dist, _ = _kdtree(distinct).query(distinct, k=k)
        self.node_spacing = dist.reshape(n, -1)[:, 1:].mean(axis=1)[inverse.ravel()]
        if not self.node_spacing.min() > tol.SPACING_MIN:
            raise ValueError(f"the target's node spacing is down to {self.node_spacing.min():.3g}, "
                             f"below the supported {tol.SPACING_MIN:.0e}: rescale the mesh")
        self.origin, self.axes = _frame.mean_plane(
            distinct, self.normals[first] if self.faces else None)
        if flip and not self.faces:
            self.axes = self.axes * np.array([[1.0], [-1.0], [-1.0]])
        if frame == "auto":
            areas = _frame.facet_area_vectors(self.nodes, self.faces)
            if flip:
                areas = -areas
            frame = "global" if _frame.is_height_field(self.axes, areas) else "local"
        self.frame = frame
        # where X3 = f(X1, X2) turns vertical or folds over a frame (reason 'steep'): node
        # normals, signed where facets give them (facing away counts), else unsigned from the
        # nearest nodes (NaN, never steep, where those lie on a line); over the global frame
        # also steep chords (frame.steep_nodes)
        self.signed = np.any(self.normals != 0, axis=1)
        self.fold_normals = self.normals
        if not self.signed.all():
            self.fold_normals = np.where(self.signed[:, None], self.normals,
                                         _frame.pca_normals(distinct)[inverse.ravel()])
        self.steep = (_frame.steep_nodes(self.nodes, self.origin, self.axes, self.node_spacing)
                      if frame == "global" else np.zeros(len(self.nodes), dtype=bool))

    @property
    def tree(self):
        """k-d tree of the nodes (the numpy reference path), built on first use."""
        if self._tree is None:
            self._tree = _kdtree(self.nodes)
        return self._tree

    @property
    def plane_tree(self):
        """k-d tree of the nodes' in-plane coordinates in the global frame, built on first use."""
        if self._plane_tree is None:
            self._plane_tree = _kdtree((self.nodes - self.origin) @ self.axes[:2].T)
        return self._plane_tree

    # -- support and frame -------------------------------------------------------------------
    def spacing_at(self, points: np.ndarray) -> np.ndarray:
        """Local node spacing h at `points`, (m,)."""
        _, idx = self.tree.query(points, k=min(SPACING_NEIGHBOURS, len(self.nodes)))
        return self.node_spacing[self._found(idx).reshape(len(points), -1)].mean(axis=1)

    def _found(self, idx: np.ndarray) -> np.ndarray:
        """k-d tree indices with 'no neighbour' (n, where distances overflow to inf) mapped
        onto a node: such far points come out 'outside' all the same."""
        return np.minimum(idx, len(self.nodes) - 1)

    def select(self, reference: np.ndarray, enlarge: float = 1.0) -> Patch:
        """Support, frame and radius of the local approximations centred at `reference`.

        `enlarge` widens the support (R, or k) for points whose first support was too thin.
        """
        m = len(reference)
        h = self.spacing_at(reference)
        radius = self.radius * enlarge
        k = int(np.ceil(self.k * enlarge**2))
        if self.frame == "global":
            axes = np.broadcast_to(self.axes, (m, 3, 3))
            planar = (reference - self.origin) @ self.axes[:2].T
            if self.support == "radius":
                R = radius * h
                idx, _ = _neighbours(self.plane_tree, planar, R, 2 * k)
            else:
                dist, idx = self.plane_tree.query(planar, k=min(k, len(self.nodes)))
                idx = self._found(idx.reshape(m, -1))
                R = KNN_RADIUS_FACTOR * dist.reshape(m, -1)[:, -1]
            return Patch(reference.copy(), np.array(axes), R, h, idx)
        # Search around the reference point's foot on the target (its projection on the tangent
        # plane of the nearest node), not around the point itself: a contactor several spacings
        # off the surface must still find the nodes under it.
        _, nearest = self.tree.query(reference, k=1)
        nearest = self._found(nearest)
        foot = self.nodes[nearest]
        if self.faces:
            n0 = self.normals[nearest]
            foot = reference - np.sum((reference - foot) * n0, axis=1, keepdims=True) * n0
        if self.support == "radius":
            R = radius * h
            idx, dist = _neighbours(self.tree, foot, FRAME_BALL * R, 2 * k)
            ball = FRAME_BALL * R
        else:
            dist, idx = self.tree.query(foot, k=min(k, len(self.nodes)))
            idx, dist = self._found(idx.reshape(m, -1)), dist.reshape(m, -1)
            ball = 1.0001 * dist[:, -1]
        if self.faces:
            # the sheet at the foot: the summed normals of its (up to) three nearest nodes
            first = idx[:, :3]
            near = np.where(first[..., None] >= 0, self.normals[np.maximum(first, 0)], 0.0)
            near = near.sum(axis=1)
            near /= np.maximum(np.linalg.norm(near, axis=1, keepdims=True), 1e-300)
            facing = np.einsum("mkd,md->mk", self.normals[np.maximum(idx, 0)], near)
            other = facing < np.cos(np.radians(SHEET_ANGLE_DEG))
            idx = np.where(other, -1, idx)
            dist = np.where(other, np.inf, dist)
        valid = idx >= 0
        safe = np.where(valid, idx, 0)
        q = (dist / ball[:, None]) ** 2
        w = np.where(valid, _weight.evaluate("wendland", np.where(valid, q, 1.0))[0], 0.0)
        # +e3 out of the target as the facets orient it; without facets, as the mean plane's
        # (so gaps keep one sign convention over the whole cloud)
        guide = (self.normals[safe] if self.faces
                 else np.broadcast_to(self.axes[2], self.nodes[safe].shape))
        axes = _frame.local_axes(self.nodes[safe] - foot[:, None, :], w, guide)
        offsets = self.nodes[safe] - reference[:, None, :]
        if self.support == "knn":
            planar = np.einsum("mij,mkj->mki", axes[:, :2], offsets)
            rho = np.where(valid, np.sqrt((planar**2).sum(-1)), 0.0)
            R = KNN_RADIUS_FACTOR * rho.max(axis=1)
            R = np.where(R > 0, R, self.radius * h)  # no support at all: any finite R
        return Patch(reference.copy(), axes, R, h, idx)

    # -- the projection ------------------------------------------------------------------------
    def local_coordinates(self, patch: Patch, points: np.ndarray) -> np.ndarray:
        """Coordinates of `points` (m, 3) or of node arrays (m, K, 3) in each patch's scaled frame."""
        d = points - (patch.origin if points.ndim == 2 else patch.origin[:, None, :])
        if points.ndim == 2:
            return np.einsum("mij,mj->mi", patch.axes, d) / patch.radius[:, None]
        return np.einsum("mij,mkj->mki", patch.axes, d) / patch.radius[:, None, None]

    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        """Project contactors onto the diffuse surface.

        Parameters
        ----------
        points : (m, 3) float
            Contactors x^c. Rows with NaN or inf get status 'failed'.
        keep_patch : bool
            Keep the frozen pairing (frame, support, radius) of every contactor in
            ``result.patch`` (for the contact element and ``--save-pairs``).
        progress : callable, optional
            Called as ``progress(done)`` with the number of contactors finished after each
            chunk of `CHUNK` contactors.

        Returns
        -------
        Projection
        """
        points = _as_points(points)
        m = len(points)
        if m == 0:
            return _empty(keep_patch)
        if keep_patch:  # supports differ in width from chunk to chunk: concatenate
            parts = []
            for i in range(0, m, CHUNK):
                parts.append(self._project_chunk(points[i:i + CHUNK], True))
                if progress is not None:
                    progress(min(i + CHUNK, m))
            return _concatenate(parts)
        # otherwise fill one preallocated result, so memory is the result plus one chunk
        result = None
        for i in range(0, m, CHUNK):
            part = self._project_chunk(points[i:i + CHUNK], False)
            if result is None:
                result = _allocate(points, part)
            _assign(result, np.arange(i, i + len(part.gap)), part)
            if progress is not None:
                progress(min(i + CHUNK, m))
        return result

    def project_with(self, points, patch: Patch) -> Projection:
        """Project contactors with a given frozen pairing (frame, support and radius fixed)."""
        points = _as_points(points)
        finite = np.all(np.isfinite(points), axis=1)
        # as in `project`: a contactor with NaN or inf is solved at its patch origin, then
        # flagged 'failed' (bad-point)
        result = self._solve(np.where(finite[:, None], points, patch.origin), patch,
                             keep_patch=True)
        _flag_bad_points(result, points, finite)
        return result

    def _project_chunk(self, points: np.ndarray, keep_patch: bool) -> Projection:
        finite = np.all(np.isfinite(points), axis=1)
        # a contactor with NaN or inf is 'failed'; it is solved at a harmless stand-in position
        # so that the batch stays finite, then blanked
        safe = np.where(finite[:, None], points, self.origin)
        result = self._select_solve(safe, safe, keep_patch or self.recentre)
        # a support too thin for the basis (an open edge or corner, a coarse mesh), or one so
        # one-sided that the fit tilts and carries the proximal point off the target (two rows
        # of nodes along an open edge), is tried once more with a wider radius before the
        # point is given up as 'outside'; the retry is kept only where it is on the target
        retry_rows = result.thin | (result.reason == OFF_TARGET)
        thin = np.flatnonzero(retry_rows & finite)
        if len(thin):
            retry = self._select_solve(safe[thin], safe[thin], True, enlarge=ENLARGE)
            better = retry.status <= PENETRATION
            _assign(result, thin[better], _subset(retry, better))
        _flag_bad_points(result, points, finite)
        if not self.recentre:
            if not keep_patch:
                result.patch = None
            return result
        # Re-centre the fit on the proximal point until it stops moving: the fixed point is the
        # projection onto S_g^d itself rather than onto the contactor's own local fit.
        iterations = result.iterations.copy()
        live = (result.status <= PENETRATION)
        previous = np.full(len(points), np.inf)
        for _ in range(tol.RECENTRE_MAX_ITER):
            if not live.any():
                break
            rows = np.flatnonzero(live)
            sub = self._select_solve(points[rows], result.proximal_point[rows], True,
                                     centred=False)
            move = np.linalg.norm(sub.proximal_point - result.proximal_point[rows], axis=1)
            iterations[rows] += sub.iterations
            _assign(result, rows, sub)
            h = sub.patch.spacing
            stalled = (move >= 0.5 * previous[rows]) & (move < tol.RECENTRE_STALL * h)
            done = ~(move > tol.RECENTRE_STEP * h) | stalled  # NaN (failed) counts as done
            previous[rows] = move
            live[rows[done]] = False
        if live.any():
            result.status[live] = FAILED
            result.reason[live] = NOT_SETTLED
            _blank(result, live)
        result.iterations = iterations
        if not keep_patch:
            result.patch = None
        return result

    def _select_solve(self, points: np.ndarray, reference: np.ndarray, keep_patch: bool,
                      enlarge: float = 1.0, centred: bool = True) -> Projection:
        """`select` around `reference`, then `_solve` for `points`: by the compiled kernel or
        by the numpy reference."""
        if self.engine == "numpy":
            return self._solve(points, self.select(reference, enlarge), keep_patch, centred)
        return self._kernel_solve(points, reference, keep_patch, enlarge, centred)

    def _kernel_arrays(self):
        """The kernel's view of the target: node grids (built on first use)."""
        if self._grids is None:
            from .. import kernel
            cell = kernel._CELL_SPACINGS * float(np.median(self.node_spacing))
            grid = kernel.build_grid(self.nodes, cell)
            if self.frame == "global":
                plane = np.zeros_like(self.nodes)
                plane[:, :2] = (self.nodes - self.origin) @ self.axes[:2].T
                pgrid = kernel.build_grid(plane, cell)
            else:
                plane = np.zeros((1, 3))
                pgrid = kernel.build_grid(plane, 1.0)
            self._grids = (grid, plane, pgrid, kernel.exponents(self.basis))
        return self._grids

    def _kernel_solve(self, points: np.ndarray, reference: np.ndarray, keep_patch: bool,
                      enlarge: float, centred: bool) -> Projection:
        from .. import _native, kernel
        (grid, plane, pgrid, (ea, eb)) = self._kernel_arrays()
        m, n = len(points), len(self.nodes)
        knn = self.support == "knn"
        k = min(int(np.ceil(self.k * enlarge**2)), n)
        cap = max(KERNEL_CAP, k if knn else 0)
        rows = np.arange(m)
        out = None
        while len(rows):
            width = cap if keep_patch else 0
            part = (np.empty(len(rows)), np.empty((len(rows), 3)), np.empty((len(rows), 3)),
                    np.empty(len(rows), np.int8), np.empty(len(rows), np.int8),
                    np.empty(len(rows), np.int64), np.empty(len(rows), np.int64),
                    np.empty(len(rows)), np.empty((len(rows), 2)),
                    np.empty((len(rows), 3)), np.empty((len(rows), 3, 3)),
                    np.empty(len(rows)), np.empty(len(rows)),
                    np.full((len(rows), width), -1, np.int64), np.zeros(len(rows), bool))
            kernel.project(
                self.nodes, self.normals, self.node_spacing, bool(self.faces),
                self.first, self.duplicates, self.fold_normals, self.signed, self.steep,
                _COS_FOLD, *grid,
                plane, *pgrid, self.origin, self.axes, self.frame == "global",
                ea, eb, kernel.WEIGHT_CODES[self.weight], knn, self.radius * enlarge, k,
                FRAME_BALL, KNN_RADIUS_FACTOR, np.cos(np.radians(SHEET_ANGLE_DEG)),
                min(SPACING_NEIGHBOURS, n), tol.RCOND_MIN[self.basis], tol.CONTACT,
                self.outside_spacings, HULL_SPACINGS, kernel.constants(),
                np.ascontiguousarray(points[rows]), np.ascontiguousarray(reference[rows]),
                centred, cap, _native.threads(), *part)
            if out is None:
                out = [np.array(a) for a in part]
                if keep_patch:
                    out[13] = np.full((m, 0), -1, np.int64)
            over = part[-1]
            done = ~over
            for a, b in zip(out[:13], part[:13]):
                a[rows[done]] = b[done]
            if keep_patch:
                got = part[13][done]
                K = max(out[13].shape[1], got.shape[1])
                out[13] = np.pad(out[13], ((0, 0), (0, K - out[13].shape[1])),
                                 constant_values=-1)
                out[13][rows[done], :got.shape[1]] = got
            rows = rows[over]
            cap *= 4
        (gap, normal, proximal, status, reason, support, its, rcond, curvature,
         origin, axes, radius, spacing) = out[:13]
        patch = None
        if keep_patch:
            index = out[13]
            K = max(int((index >= 0).sum(axis=1).max(initial=0)), 1)
            patch = Patch(origin, axes, radius, spacing, np.ascontiguousarray(index[:, :K]))
        return Projection(points, gap, normal, proximal, status, support, its, rcond,
                          curvature, reason, patch)

    @np.errstate(divide="ignore", invalid="ignore", over="ignore")  # rows get a status instead
    def _solve(self, points: np.ndarray, patch: Patch, keep_patch: bool,
               centred: bool = True) -> Projection:
        """Fit and project with a given pairing.

        The basis and the weights are centred at the contactor's in-plane position [14], [15]
        (`centred`), as the paper does, so a frozen pairing reused on moved nodes still centres
        the fit on the contactor; when re-centring, they are centred at the patch origin (the
        previous proximal point) instead.
        """
        m = len(points)
        if self.duplicates:  # each position once, as its first occurrence
            patch = Patch(patch.origin, patch.axes, patch.radius, patch.spacing,
                          _merge_duplicates(patch.index, self.first))
        valid = patch.index >= 0
        nodes = self.nodes[np.where(valid, patch.index, 0)]
        local = self.local_coordinates(patch, nodes)
        c = self.local_coordinates(patch, points)
        centre = c[:, :2] if centred else np.zeros((m, 2))
        s = local[..., 0] - centre[:, :1]
        t = local[..., 1] - centre[:, 1:]
        z = local[..., 2]
        q = np.where(valid, s**2 + t**2, 1.0)
        w = np.where(valid, _weight.evaluate(self.weight, q)[0], 0.0)
        count = (w > 0).sum(axis=1)
        # the singular weight is stiff by design; judge the support's geometry on the smooth
        # weight with the same support instead
        geometry = (np.where(valid, _weight.evaluate("wendland", q)[0], 0.0)
                    if self.weight == "singular" else None)
        alpha, rcond = fit(self.basis, s, t, z, w, geometry)
        c = c - np.concatenate([centre, np.zeros((m, 1))], axis=1)
        st, its, ok = proximal_point(self.basis, alpha, c)
        f = [np.einsum("mk,mk->m", _basis.evaluate(self.basis, st[:, 0], st[:, 1], ds, dt), alpha)
             for ds, dt in ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))]
        # [29]: ν = (-f,1, -f,2, 1)/‖·‖ in the frame (the scaling by R cancels in the slopes)
        nu = np.stack([-f[1], -f[2], np.ones(m)], axis=1)
        nu /= np.linalg.norm(nu, axis=1, keepdims=True)
        normal = np.einsum("mji,mj->mi", patch.axes, nu)
        xd_local = np.stack([st[:, 0] + centre[:, 0], st[:, 1] + centre[:, 1], f[0]],
                            axis=1) * patch.radius[:, None]
        proximal = patch.origin + np.einsum("mji,mj->mi", patch.axes, xd_local)
        gap = np.einsum("mi,mi->m", points - proximal, normal)  # [32]
        status = np.where(gap > 0, OPEN, PENETRATION).astype(np.int8)
        status[np.abs(gap) <= tol.CONTACT * patch.spacing] = CONTACT
        # the proximal point must lie on the target: near a support node, inside the domain of
        # influence, and within HULL_SPACINGS of the in-plane convex hull of the support (not
        # past an open edge, where the fit only extrapolates)
        ds_, dt_ = s - st[:, :1], t - st[:, 1:]
        d2 = np.where(w > 0, ds_**2 + dt_**2, np.inf).min(axis=1)
        slack = HULL_SPACINGS * patch.spacing / patch.radius
        off = ((np.sqrt(d2) * patch.radius > self.outside_spacings * patch.spacing)
               | ((st**2).sum(axis=1) > 1.0) | _beyond_hull(ds_, dt_, w > 0, slack))
        reason = np.zeros(m, dtype=np.int8)
        status[off] = OUTSIDE
        reason[off] = OFF_TARGET
        status[~ok] = FAILED
        reason[~ok] = NO_CONVERGENCE
        # too few nodes, or nodes that cannot determine the basis (collinear, as past an open
        # edge): no usable support
        ill = ~(rcond >= tol.RCOND_MIN[self.basis])
        status[ill] = OUTSIDE
        reason[ill] = ILL_CONDITIONED
        few = count < self.nterms
        status[few] = OUTSIDE
        reason[few] = FEW_NODES
        # a support reaching where the target turns vertical or folds over the frame: the root
        # cause of whatever else went wrong (the fix is a local frame, or a smaller support)
        near = np.where(valid, patch.index, 0)
        facing = np.einsum("mkd,md->mk", self.fold_normals[near], patch.axes[:, 2])
        facing = np.where(self.signed[near], facing, np.abs(facing))
        steep = ((w > 0) & ((facing < _COS_FOLD) | self.steep[near])).any(axis=1)
        status[steep] = OUTSIDE
        reason[steep] = STEEP
        curvature = principal_curvatures(*f[1:]) / patch.radius[:, None]
        result = Projection(points, gap, normal, proximal, status, count, its, rcond, curvature,
                            reason, patch if keep_patch else None)
        _blank(result, status >= OUTSIDE)
        return result


_COS_FOLD = np.cos(np.radians(_frame.FOLD_SLOPE_DEG))


def _merge_duplicates(index: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Support indices (m, K) mapped onto first occurrences, repeats in a row set to -1."""
    mapped = np.where(index >= 0, first[np.maximum(index, 0)], -1)
    order = np.argsort(mapped, axis=1, kind="stable")
    ranked = np.take_along_axis(mapped, order, axis=1)
    repeat = np.zeros(mapped.shape, dtype=bool)
    repeat[:, 1:] = (ranked[:, 1:] == ranked[:, :-1]) & (ranked[:, 1:] >= 0)
    again = np.empty_like(repeat)
    np.put_along_axis(again, order, repeat, axis=1)
    return np.where(again, -1, mapped)


def _beyond_hull(ds: np.ndarray, dt: np.ndarray, live: np.ndarray, slack: np.ndarray):
    """Whether a point is farther than `slack` from the convex hull of its support, (m,) bool.

    ds, dt : (m, K) in-plane offsets of the support nodes from the point; live : (m, K) the
    nodes that count; slack : (m,). Exact: the point is farther than the slack from the hull
    iff it is outside the hull of the discs of radius `slack` around the nodes, iff a line
    through it leaves every disc on one side, iff the arcs of directions the discs cover
    leave a free arc of at least π. The arcs are swept in order of their start angle in
    [0, 2π); a free arc is the gap from the farthest end so far (or the end of an arc that
    wrapped past 2π) to the next start.
    """
    r = np.hypot(ds, dt)
    inside = (live & (r <= slack[:, None])).any(axis=1)  # within the slack of a node
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


def proximal_point(basis: str, alpha: np.ndarray, contactor: np.ndarray):
    """Newton solve of [30] for the proximal point on each local approximation.

    Minimises D = ½‖(s, t, f(s, t)) - c‖² over (s, t), with c the contactor in the scaled
    frame; ∇D = 0 is [30], (x^c - x^d)·τ_k = 0 with τ1 = (1, 0, f,1), τ2 = (0, 1, f,2) [28].
    Full Newton while ∇²D is positive definite, Gauss-Newton otherwise (beyond a focal point);
    steps are capped at half the support radius.

    Parameters
    ----------
    basis : str
    alpha : (m, k) float  fit coefficients; rows with NaN are skipped (not converged)
    contactor : (m, 3) float  contactors in the scaled frame

    Returns
    -------
    st : (m, 2) float  in-plane coordinates (s̄, t̄) of x^d in the scaled frame
    iterations : (m,) int
    converged : (m,) bool
    """
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
            np.einsum("mk,mk->m", _basis.evaluate(basis, s, t, ds, dt), a)
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


def principal_curvatures(fs, ft, fss, fst, ftt) -> np.ndarray:
    """Principal curvatures (m, 2), κ1 ≥ κ2, of the graph X3 = f(X1, X2) with normal +e3.

    Eigenvalues of the shape operator I⁻¹ II (first and second fundamental forms), with the
    sign turned so a surface bending away from its normal (convex) is positive.
    """
    E, F, G = 1 + fs * fs, fs * ft, 1 + ft * ft
    root = np.sqrt(1 + fs * fs + ft * ft)
    L, M, N = -fss / root, -fst / root, -ftt / root
    det = E * G - F * F
    mean = (E * N + G * L - 2 * F * M) / (2 * det)
    gauss = (L * N - M * M) / det
    disc = np.sqrt(np.maximum(mean * mean - gauss, 0.0))
    return np.stack([mean + disc, mean - disc], axis=1)


def _flag_bad_points(result: Projection, points: np.ndarray, finite: np.ndarray) -> None:
    """Put back the original contactors and flag the non-finite ones 'failed' (bad-point),
    with no support, no iterations, no condition number and NaN geometry."""
    result.points = points
    bad = ~finite
    result.status[bad] = FAILED
    result.reason[bad] = BAD_POINT
    result.support[bad] = 0
    result.iterations[bad] = 0
    result.rcond[bad] = np.nan
    _blank(result, bad)


def _blank(result: Projection, rows: np.ndarray) -> None:
    """NaN out the geometric results of rows without a trustworthy answer."""
    for arr in (result.gap, result.normal, result.proximal_point, result.curvature):
        arr[rows] = np.nan


def _assign(result: Projection, rows: np.ndarray, sub: Projection) -> None:
    for name in ("gap", "normal", "proximal_point", "status", "support", "iterations", "rcond",
                 "curvature", "reason"):
        getattr(result, name)[rows] = getattr(sub, name)
    if result.patch is not None and sub.patch is not None:
        p, q = result.patch, sub.patch
        K = max(p.index.shape[1], q.index.shape[1])
        p.index = np.pad(p.index, ((0, 0), (0, K - p.index.shape[1])), constant_values=-1)
        for name in ("origin", "axes", "radius", "spacing"):
            getattr(p, name)[rows] = getattr(q, name)
        p.index[rows] = np.pad(q.index, ((0, 0), (0, K - q.index.shape[1])), constant_values=-1)


def _allocate(points: np.ndarray, like: Projection) -> Projection:
    """An uninitialised result for all of `points`, with the dtypes of `like`."""
    m = len(points)
    fields = [np.empty((m,) + getattr(like, n).shape[1:], getattr(like, n).dtype)
              for n in ("gap", "normal", "proximal_point", "status", "support", "iterations",
                        "rcond", "curvature", "reason")]
    return Projection(points, *fields)


def _empty(keep_patch: bool) -> Projection:
    z = np.zeros((0,))
    patch = (Patch(np.zeros((0, 3)), np.zeros((0, 3, 3)), z, z, np.zeros((0, 1), np.int64))
             if keep_patch else None)
    return Projection(np.zeros((0, 3)), z, np.zeros((0, 3)), np.zeros((0, 3)),
                      np.zeros(0, np.int8), np.zeros(0, np.int64), np.zeros(0, np.int64), z,
                      np.zeros((0, 2)), np.zeros(0, np.int8), patch)


def _subset(result: Projection, rows: np.ndarray) -> Projection:
    """The rows `rows` of a result (and of its patch)."""
    names = ("points", "gap", "normal", "proximal_point", "status", "support", "iterations",
             "rcond", "curvature", "reason")
    out = Projection(*(getattr(result, n)[rows] for n in names))
    if result.patch is not None:
        p = result.patch
        out.patch = Patch(p.origin[rows], p.axes[rows], p.radius[rows], p.spacing[rows],
                          p.index[rows])
    return out


def _concatenate(parts: list[Projection]) -> Projection:
    if len(parts) == 1:
        return parts[0]
    names = ("points", "gap", "normal", "proximal_point", "status", "support", "iterations",
             "rcond", "curvature", "reason")
    out = Projection(*(np.concatenate([getattr(p, n) for p in parts]) for n in names))
    if all(p.patch is not None for p in parts):
        K = max(p.patch.index.shape[1] for p in parts)
        out.patch = Patch(
            *(np.concatenate([getattr(p.patch, n) for p in parts])
              for n in ("origin", "axes", "radius", "spacing")),
            np.concatenate([np.pad(p.patch.index, ((0, 0), (0, K - p.patch.index.shape[1])),
                                   constant_values=-1) for p in parts]))
    return out
