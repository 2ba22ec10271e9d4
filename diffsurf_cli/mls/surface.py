"""The diffuse surface of a target and the projection of contactors onto it.

For each contactor x^c the pipeline is the paper's §3-§4.1, run per contactor by the compiled
engine (`_engine.pyx`, in parallel over the whole cloud):

1. support: the target nodes around the reference point (the contactor itself, or its last
   proximal point when re-centring), with radius R = `radius` x local node spacing;
2. frame R^d: the global mean plane or a local weighted-PCA frame (`frame.py`);
3. fit: weighted least squares (P^T W P) α = P^T W Z [15]-[17];
4. proximal point: Newton on (x^c - x^d)·τ_k = 0 [30], normal [29], gap [32], status [33].

This module builds the target (normals, node spacing, frame choice) and hands arrays to the
engine; the slow, obvious reference it is tested against is tests/reference.py.

Per-point trouble (too little support, an ill-conditioned fit, a Newton that does not
converge, a proximal point off the target) is reported as a status with NaNs, never raised.
"""
from __future__ import annotations

import numpy as np

from .. import tol
from ..projection import (
    PAIRING_RECORD,
    NearestNode,
    Patch,
    Projection,
    allocate,
    as_faces,
    as_moved_nodes,
    as_points,
    as_target_nodes,
    mark_far,
    recorded,
    warn_inside_out,
)
from . import _projection
from . import basis as _basis
from . import frame as _frame
from . import weight as _weight

SUPPORTS = ("radius", "knn")
# the projection's constants live in tol.py (the engine reads them there); their old names
# stay importable from here
OUTSIDE_SPACINGS = tol.OUTSIDE_SPACINGS
DEFAULT_RADIUS = tol.DEFAULT_RADIUS
ENLARGE = tol.ENLARGE
HULL_SPACINGS = tol.HULL_SPACINGS
KNN_RADIUS_FACTOR = tol.KNN_RADIUS_FACTOR
FRAME_BALL = tol.FRAME_BALL
SHEET_ANGLE_DEG = tol.SHEET_ANGLE_DEG
SPACING_NEIGHBOURS = tol.SPACING_NEIGHBOURS
#: Contactors per call of the engine: bounds the memory of the pairing (keep_patch) and sets
#: how often `project` reports progress.
CHUNK = 8192
#: Initial per-point support capacity of the engine's scratch (rows with more nodes in their
#: support are run again with a larger one).
ENGINE_CAP = 128
#: Grid cell size of the engine's searches, in (median) node spacings.
CELL_SPACINGS = 2.0


class TooFewNodes(ValueError):
    """Fewer distinct target nodes than the basis has terms; `fits`: the largest basis they
    determine (None: none), which the message names as the API's keyword (`text(fix)` names
    it otherwise: the command line's flag)."""

    def __init__(self, problem: str, fits: str | None):
        self.problem, self.fits = problem, fits
        super().__init__(self.text(f'basis="{fits}"'))

    def text(self, fix: str) -> str:
        """The message, naming `fix` (how to ask for the basis that fits)."""
        return self.problem + (f" (the {self.fits} basis fits them: {fix})" if self.fits else "")

    def __reduce__(self):  # pickles (a Dask worker's error) with its own arguments
        return type(self), (self.problem, self.fits)


class DiffuseSurface:
    """The diffuse (moving least squares) surface S_g^d of a faceted target.

    Built once from the target's nodes (and facets, for orientation and node spacing); then
    `project` any number of contactor points. The projection runs in the compiled engine
    (`_engine.pyx`), in parallel over contactors.

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
        Blocks of higher-order facets (6 or 7 columns for triangles, 8 or 9 for quads, corners
        first: `frame.cell_faces`) give their mid-side nodes the normal of their cells too;
        given by their corners only, mid-side nodes have no normal and the sheet test drops them.
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
        is off the target ('outside'); default `tol.OUTSIDE_SPACINGS`.
    check_winding : bool
        Warn (`projection.InsideOutWarning`, naming flip=True) where the facets hold a closed
        surface wound inside out (negative enclosed volume: its normals point into the
        target, every gap's sign reversed); not with `flip`. The surfaces built from another
        (`moved`, a PatchedSurface's patches) do not check again.
    shared : facet.surface.SharedNodes, optional
        The node identity and spacing of these nodes, measured by the caller (a
        `PatchedSurface`: its facets' too); ignored for other nodes.
    """

    def __init__(self, nodes, faces=None, *, basis="quadratic", weight="wendland",
                 support="radius", radius=None, k=None, frame="auto", recentre=False,
                 flip=False, outside_spacings=OUTSIDE_SPACINGS, check_winding=True,
                 shared=None):
        from ..nodes import SharedNodes

        self.nodes = as_target_nodes(nodes)
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
        self.flip = bool(flip)
        # exact duplicates are merged: `first[i]` is the first node at the position of node i;
        # the engine maps every support onto firsts, so each position enters the fit once.
        # `shared` (facet.surface.SharedNodes): the caller's identity and spacing of these
        # nodes (a PatchedSurface's), not measured again
        shared = SharedNodes.of(self.nodes, shared)
        first, inverse = shared.distinct, shared.group  # np.unique's index and inverse
        self.first = shared.first
        self.duplicates = len(first) < len(self.nodes)
        n = len(first)
        if n < self.nterms:
            raise TooFewNodes(
                f"the target has {n} {'distinct ' if self.duplicates else ''}nodes; the {basis} "
                f"basis needs at least {self.nterms}", _basis.smallest_fitting(n))
        if support == "knn" and self.k < self.nterms:
            raise ValueError(f"k={self.k} is below the {basis} basis size {self.nterms}")
        # integers indexing the nodes, blocks of (f, k): a -1 would wrap to the last node
        self.faces = as_faces(faces, len(self.nodes))
        if check_winding and not flip:  # a closed target wound inside out: say so
            warn_inside_out(self.nodes, self.faces, self.first)
        self.normals = _frame.node_normals(self.nodes, [self.first[f] for f in self.faces])
        self.normals = self.normals[self.first]  # copies share the normal of all their facets
        if flip:
            self.normals = -self.normals
        self.outside_spacings = float(outside_spacings)
        #: made by `moved`: a deformable target's positions (not a fixed, rigid one)
        self.deformed = False
        self._engine = None
        self._facets = None  # facet_surface(), built on first use
        self._nearest = None  # NearestNode: whether a contactor is far from every node
        distinct = self.nodes[first]
        # each node's own spacing: the mean distance to its nearest neighbours (distances are
        # values: no tie-break enters)
        self.node_spacing = shared.spacing
        if not self.node_spacing.min() > tol.SPACING_MIN:
            raise ValueError(f"the target's node spacing is down to {self.node_spacing.min():.3g}, "
                             f"below the supported {tol.SPACING_MIN:.0e}: rescale the mesh")
        self.origin, self.axes = _frame.mean_plane(
            distinct, self.normals[first] if self.faces else None)
        if flip and not self.faces:
            self.axes = self.axes * np.array([[1.0], [-1.0], [-1.0]])
        if frame == "auto":
            frame = "global" if _height_field(self.nodes, self.faces, self.axes, flip) \
                else "local"
        self.frame = frame
        # whether the global frame's e3 is fixed by more than a row of nodes (the reduced bases
        # constant across need it: tol.RULED_SPREAD)
        planar = (distinct - distinct.mean(axis=0)) @ self.axes[:2].T
        spread = np.linalg.eigvalsh(planar.T @ planar)
        self.ruled = bool(spread[0] >= tol.RULED_SPREAD * spread[1] and spread[1] > 0)
        # where X3 = f(X1, X2) turns vertical or folds over a frame (reason 'steep'): node
        # normals, signed where facets give them (facing away counts), else unsigned from the
        # nearest nodes (NaN, never steep, where those lie on a line); over the global frame
        # also steep chords (frame.steep_nodes)
        nrm = self.normals  # column by column: np.any(axis=1)'s booleans, 4x faster
        self.signed = (nrm[:, 0] != 0) | (nrm[:, 1] != 0) | (nrm[:, 2] != 0)
        self.fold_normals = self.normals
        if not self.signed.all():
            self.fold_normals = np.where(self.signed[:, None], self.normals,
                                         _frame.pca_normals(distinct)[inverse])
        self.steep = (_frame.steep_nodes(self.nodes, self.origin, self.axes, self.node_spacing)
                      if frame == "global" else np.zeros(len(self.nodes), dtype=bool))

    def facet_surface(self):
        """The target's own facets as a `FacetSurface` (their corners; built once), None for
        a target without facets (a point cloud): the faceted foot of a contactor, and the
        facets' verdict where this surface gives no answer."""
        if self._facets is None and any(f.size for f in self.faces):
            from ..facet.surface import FacetSurface

            self._facets = FacetSurface(self.nodes, [_frame.facet_corners(f) for f in self.faces
                                                     if f.size], flip=self.flip,
                                         check_winding=False)
        return self._facets

    def moved(self, nodes) -> DiffuseSurface:
        """The same target with its nodes at new positions (a deformable target, each
        iteration of a solver's step): the same facets, options and frame choice; a global
        frame keeps its mean plane (pinned, as a frozen pairing pins each contactor's frame
        [§4.2]). A pairing taken on this surface within the step applies to the moved one
        (`contact(moved, points, pairing=...)`)."""
        nodes = as_moved_nodes(nodes, self.nodes)
        new = DiffuseSurface(nodes, self.faces, basis=self.basis, weight=self.weight,
                             support=self.support, radius=self.radius, k=self.k,
                             frame=self.frame, recentre=self.recentre, flip=self.flip,
                             outside_spacings=self.outside_spacings, check_winding=False)
        new.deformed = True
        if self.frame == "global":
            new.origin, new.axes, new.ruled = self.origin, self.axes, self.ruled
            new.steep = _frame.steep_nodes(new.nodes, new.origin, new.axes, new.node_spacing)
        return new

    def __getstate__(self):
        # the compiled engine's view (grids) does not pickle; it is rebuilt on first use, so a
        # surface travels to other processes (a Dask cluster) after it has projected
        state = self.__dict__.copy()
        state["_engine"] = None
        return state

    @property
    def engine(self) -> _projection.Target:
        """The compiled engine's view of the target (node grids), built on first use."""
        if self._engine is None:
            self._engine = _projection.Target(
                self.nodes, self.normals, self.node_spacing, self.first, self.fold_normals,
                self.signed, self.steep, self.origin, self.axes, bool(self.faces),
                self.frame == "global", CELL_SPACINGS * float(np.median(self.node_spacing)))
        return self._engine

    def _options(self) -> dict:
        return {"basis": self.basis, "weight": self.weight, "support": self.support,
                "k": self.k, "radius": self.radius, "recentre": self.recentre,
                "outside_spacings": self.outside_spacings, "nodes": len(self.nodes),
                "ruled": self.ruled}

    # -- the projection ------------------------------------------------------------------------
    def project(self, points, *, keep_patch: bool = False, progress=None,
                h_min=None) -> Projection:
        """Project contactors onto the diffuse surface.

        For each contactor: its support, frame and radius around it, the fit, the proximal
        point, gap, normal and status; a support too thin for the basis, or whose fit carries
        the proximal point off the target, is tried once more `tol.ENLARGE` wider (kept where
        the retry is on the target); with `recentre`, the fit is re-centred on the proximal
        point until it settles. All in the compiled engine, contactors in the order of their
        grid cells (neighbours search the same cells), results in the order given.

        Parameters
        ----------
        points : (m, 3) float
            Contactors x^c. Rows with NaN or inf get status 'failed'.
        keep_patch : bool
            Keep the frozen pairing (frame, support, radius) of every contactor in
            ``result.patch`` (for the contact element and ``--save-pairs``), and the fit's
            coefficients α [17] in ``result.alpha`` ((m, nterms) float: the full basis in
            the pairing's scaled frame, centred at the contactor; NaN where not answered).
        progress : callable, optional
            Called as ``progress(0)`` when the work starts (after the setup), then as
            ``progress(done)`` with the number of contactors finished after each chunk of
            `CHUNK` contactors.
        h_min : (m,) float, optional
            Each contactor's floor of the local spacing (what a `PatchedSurface`'s pass
            gives its patch over elongated cells: `patches.surface.support_floor`), so that
            the contact element takes the support the patched projection took.

        Returns
        -------
        Projection
        """
        points = np.ascontiguousarray(as_points(points))
        m = len(points)
        out = allocate(m, PAIRING_RECORD)
        if m == 0:
            return _result(points, out, np.zeros((0, 1), np.int64) if keep_patch else None)
        if h_min is not None:
            h_min = np.ascontiguousarray(h_min, dtype=np.float64).reshape(-1)
            if len(h_min) != m:
                raise ValueError(f"h_min: {len(h_min)} values for {m} contactors")
        engine, options = self.engine, self._options()
        knn = self.support == "knn"
        kmax = min(int(np.ceil(self.k * ENLARGE**2)), len(self.nodes))
        order = np.argsort(engine.cell_keys(points), kind="stable")
        alpha = np.full((m, self.nterms), np.nan) if keep_patch else None
        blocks = []  # (rows, index) of each chunk's pairing
        # in chunks: a signal (Ctrl-C, SIGTERM) acts between two calls, so within one chunk's
        # work (a 2M cloud: 1.1-1.8 s as one call); progress is reported and the pairing's
        # memory bounded there too. Each call ends on a barrier of the threads: 8192
        # contactors a call cost no measurable time (1M points, one call or chunked)
        chunk = CHUNK
        if progress is not None:
            progress(0)  # the work starts: what came before was setup
        for lo in range(0, m, chunk):
            rows = order[lo:lo + chunk]
            cap = max(ENGINE_CAP, kmax if knn else 0)
            todo = rows
            while len(todo):
                index = np.empty((len(todo), cap if keep_patch else 0), np.int64)
                engine.project(options, points, todo, out, index, cap, alpha, h_min=h_min)
                over = out["overflow"][todo].view(bool)
                if keep_patch:  # row i's first count[todo[i]] entries are written
                    blocks.append((todo[~over], index[~over]))
                todo = todo[over]
                cap *= 4
            if progress is not None:
                progress(min(lo + chunk, m))
        index = None
        if keep_patch:  # the supports as wide as the widest, -1 padded
            count = out["count"]
            K = max(int(count.max(initial=0)), 1)
            index = np.full((m, K), -1, np.int64)
            for rows, ix in blocks:
                w = min(K, ix.shape[1])
                index[rows, :w] = np.where(np.arange(w) < count[rows, None], ix[:, :w], -1)
        res = _result(points, out, index, alpha)
        # no node within the support radius: off the target, with nothing that means anything
        far = mark_far(res, self.nearest_node)
        if alpha is not None:
            alpha[far] = np.nan
        return res

    @property
    def nearest_node(self) -> NearestNode:
        """Whether contactors are far from every node (`projection.mark_far`): the support
        radius R of the nearest node; built on first use."""
        if self._nearest is None:
            self._nearest = NearestNode(self.nodes, self.node_spacing, self.radius)
        return self._nearest

    def project_with(self, points, patch: Patch) -> Projection:
        """Project contactors with a given frozen pairing (frame, support and radius fixed).

        The same per-point code as `project` after the selection; a contactor with NaN or inf
        is solved at its patch origin, then flagged 'failed' (bad-point). Where the pairing
        has a reduced basis (`Patch.reduced`, a strip's support), that basis is fitted at its
        direction, held fixed as the frame is."""
        points = np.ascontiguousarray(as_points(points))
        m = len(points)
        if not isinstance(patch, Patch):
            raise ValueError(f"project_with: the pairing must be a Patch (the frames and "
                             f"supports of a DiffuseSurface), got {type(patch).__name__}")
        if len(np.asarray(patch.origin)) != m:
            raise ValueError(f"the pairing is for {len(np.asarray(patch.origin))} contactors, "
                             f"got {m}")
        index = np.ascontiguousarray(patch.index, dtype=np.int64).reshape(m, -1)
        if self.duplicates:  # each position once, as its first occurrence
            index = _merge_duplicates(index, self.first)
        given = patch
        patch = Patch(*(np.ascontiguousarray(a, dtype=np.float64) for a in
                        (patch.origin, patch.axes, patch.radius, patch.spacing)), index)
        frozen = {}
        if given.reduced is not None and given.direction is not None:  # held fixed [§4.2]
            frozen = dict(frozen_reduced=np.ascontiguousarray(given.reduced, dtype=np.int8),
                          frozen_direction=np.ascontiguousarray(given.direction,
                                                                dtype=np.float64))
        out = allocate(m, PAIRING_RECORD)
        self.engine.project_with(self._options(), points, patch.origin, patch.axes,
                                 patch.radius, patch.spacing, index, out, **frozen)
        patch.direction, patch.reduced = out["direction"], out["reduced"]
        return Projection(points, **recorded(out), patch=patch)


#: Every how many facets `_height_field` looks first (a closed part fails at once).
HEIGHT_FIELD_SAMPLE = 64


def _height_field(nodes, faces, axes, flip) -> bool:
    """frame='auto': whether the facets are a height field over the mean plane
    (`frame.is_height_field` of all their area vectors, oriented as the target). A sample
    first, every `HEIGHT_FIELD_SAMPLE`-th facet (its area vectors and cosines are the same
    rows' values as over all facets, to round-off in the product with e3): where one of them
    faces away from e3 by clearly more than the limit (1e-9 below its cosine, far beyond
    round-off), the answer is no without the other facets (issue 36: a closed part, the
    common target, some 30 ms at 163k nodes); else all of them decide, as before."""
    limit = np.cos(np.radians(_frame.AUTO_MAX_SLOPE_DEG))
    sign = -1.0 if flip else 1.0
    if sum(len(f) for f in faces) >= 16 * HEIGHT_FIELD_SAMPLE:
        few = [np.ascontiguousarray(f[::HEIGHT_FIELD_SAMPLE]) for f in faces if len(f)]
        least = _frame.least_facing(axes, sign * _frame.facet_area_vectors(nodes, few))
        if least is not None and least < limit - 1e-9:
            return False
    areas = _frame.facet_area_vectors(nodes, faces)
    if flip:
        areas = -areas
    return _frame.is_height_field(axes, areas)

def _result(points, out, index, alpha=None) -> Projection:
    """The Projection of the engine's arrays `out` (`projection.allocate`): with the pairing
    when its support indices `index` were kept, and the fit's coefficients `alpha`
    (keep_patch)."""
    patch = (None if index is None
             else Patch(out["origin"], out["axes"], out["radius"], out["spacing"], index,
                        out["reduced"], out["direction"]))
    return Projection(points, **recorded(out), patch=patch, alpha=alpha)


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
