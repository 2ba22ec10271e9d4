"""A target's diffuse surface built per smooth patch (method.md "Real targets: patches").

One `DiffuseSurface` per patch (`patches.segment`: bounded by sharp edges, the file's face or
region tags, open boundaries), so a support never straddles a sharp edge (flat patches get
their own mean plane and are exact) and never mixes the two sides of a thin wall. A contactor
is answered as node-to-facet contact picks its facet [§2]: the closest of the nearby patches.

Per contactor:
1. the exact closest facet over the whole target (`FacetSurface`, a BVH) gives its distance
   d0 and the local node spacing h;
2. candidate patches: those with a facet within d0 + `CANDIDATE_SPACINGS` h;
3. each candidate's diffuse proximal point x^d [25]-[30] is valid when the engine answers it
   (not 'outside' or 'failed') and it lies on that patch: its closest point on the patch's
   facets is not past a sharp edge by more than `OVERSHOOT_SPACINGS` h along the facet
   (`SMOOTH_OVERSHOOT_SPACINGS` past a smooth edge between patches split by their tags);
4. where the closest facet point is on a feature edge or vertex (the diffuse surfaces of the
   patches there cannot reach it: a sharp edge or corner), or where the closest facet's patch
   has no valid answer of its own (a patch too small or too narrow for the basis) and that
   point is not on an open boundary, the facets' own answer is a candidate too (exact on
   straight edges, gap signed by the pseudonormal there);
5. the answer is the candidate closest to x^c (smallest |x^c - x^d|), those past a smooth
   edge only where no other patch answers on itself. No candidate: the
   closest facet's patch's own answer ('outside' with its reason: beyond an open boundary).

Contactors are grouped by candidate patch: each patch's engine runs once per call.
"""
from __future__ import annotations

import numpy as np

from .. import tol
from ..mls import frame as _frame
from ..mls.surface import DiffuseSurface
from ..projection import (
    CONTACT,
    FAILED,
    FEW_NODES,
    OPEN,
    OUTSIDE,
    PENETRATION,
    Projection,
    as_target_nodes,
)
from ..projection import as_points as _as_points
from . import segment as _patches

#: Candidate patches: a facet within d0 + this many local node spacings of the contactor (d0
#: its distance to the closest facet). The diffuse surface departs from the facets by the
#: sagitta (h²κ/8, a fraction of h): one spacing is ample, two leave room for coarse patches.
CANDIDATE_SPACINGS = 0.5
#: A patch's proximal point whose closest point on the patch's facets is on a sharp edge and
#: off it, along the facet, by more than this many spacings is past the patch's edge
#: (invalid). Round-off scale: on a flat patch past a sharp edge the facets' edge point is the
#: exact answer.
OVERSHOOT_SPACINGS = 1e-6
#: The same past a smooth edge between two patches split by their tags only (a fillet's
#: tangent edge): the diffuse surface's offset from the facets there (the sagitta, curving
#: across the edge) gives an apparent overshoot of sagitta x sin(half the facet angle), and
#: the next patch continues the surface; a tenth of a spacing past it, a convex quadratic
#: departs from its tangent by κ h²/200 at most, below the fit's error.
SMOOTH_OVERSHOOT_SPACINGS = 0.1

#: Contactors per pass of `PatchedSurface.project` (memory and progress; each pass calls the
#: engines of every candidate patch, a fixed cost per call).
CHUNK = 1 << 20
#: frame 'auto' per patch: the global mean plane for a flat patch (every facet within this
#: angle of it: exact there), else local frames. Measured on the fillet box
#: (benchmarks/feature_targets.py): on its quarter-cylinder fillets, 7.5x the facets' accuracy
#: (RMS) with the global frame, 44x with local frames.
FLAT_PATCH_DEG = 1.0

_ANSWERED = np.array([OPEN, CONTACT, PENETRATION])
#: Classes of facet edges and vertices (`PatchedSurface._classify_edges`), by priority.
INSIDE, SMOOTH, OPEN_EDGE, SHARP = range(4)


class PatchedSurface:
    """The diffuse surface of a target with features: one `DiffuseSurface` per smooth patch.

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, k) int, or one such array
        Facet blocks indexing `nodes` (3, 6, 7 columns for triangles; 4, 8, 9 for quads,
        corners first); required: they define the patches.
    feature_angle : float
        Degrees (`patches.FEATURE_ANGLE_DEG` by default); 180 = tags and open boundaries only.
    tags : (f,) int, optional
        Face or region tag of each facet (facets numbered block after block).
    flip : bool
    **options
        DiffuseSurface options (basis, weight, support, radius, k, frame, recentre,
        outside_spacings), the same for every patch; frame 'auto' (the default) is the
        global mean plane on a flat patch (exact), local frames on a curved one.

    Attributes
    ----------
    label : (f,) int      patch of each facet
    surfaces : list       DiffuseSurface of each patch, None where the patch has too few
                          nodes for the basis (it is answered by its facets)
    patch_nodes : list    (n_p,) int of each patch: the target node of each of its
                          surface's nodes (its local node i is global node patch_nodes[p][i])
    One patch: `project` is that DiffuseSurface's, unchanged.
    """

    def __init__(self, nodes, faces, *, feature_angle=_patches.FEATURE_ANGLE_DEG, tags=None,
                 flip=False, **options):
        from ..facet.surface import FacetSurface

        self.nodes = as_target_nodes(nodes)
        if isinstance(faces, np.ndarray) and faces.ndim == 2:
            faces = [faces]
        faces = [np.asarray(f, dtype=np.int64) for f in faces if len(f)]
        if not faces:
            raise ValueError("patches need the target's facets (triangles or quads)")
        self.faces = faces
        self.flip = bool(flip)
        self.options = dict(options)
        self.feature_angle = float(feature_angle)
        self.label = _patches.segment(self.nodes, faces, self.feature_angle, tags)
        self.npatches = int(self.label.max()) + 1
        self.one = None
        if self.npatches == 1:  # today's surface, unchanged
            self.one = DiffuseSurface(self.nodes, faces, flip=flip, **options)
            self.surfaces = [self.one]
            self.patch_nodes = [np.arange(len(self.nodes))]
            self._describe(self.one)
            return
        corners = [_frame.facet_corners(f) for f in faces]
        self.corners = np.concatenate(
            [np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1) for f in corners])
        self.kind = np.where(self.corners[:, 3] < 0, 3, 4)
        self.facets = FacetSurface(self.nodes, corners, flip=flip)
        area = _frame.facet_area_vectors(self.nodes, corners)
        self.facet_normal = area / np.maximum(np.linalg.norm(area, axis=1, keepdims=True),
                                              1e-300)
        self._classify_edges(faces)
        starts = np.cumsum([0] + [len(f) for f in faces])
        self.surfaces, self.patch_facets, self.patch_ids, self.boxes = [], [], [], []
        self.patch_nodes = []
        for p in range(self.npatches):
            ids = np.flatnonzero(self.label == p)
            self.patch_ids.append(ids)
            blocks = []
            for b, f in enumerate(faces):
                sel = ids[(ids >= starts[b]) & (ids < starts[b + 1])] - starts[b]
                if len(sel):
                    blocks.append(f[sel])
            used = np.unique(np.concatenate([blk.ravel() for blk in blocks]))
            self.patch_nodes.append(used)
            local = [np.searchsorted(used, blk) for blk in blocks]
            pts = self.nodes[used]
            self.boxes.append((pts.min(axis=0), pts.max(axis=0)))
            try:
                self.patch_facets.append(FacetSurface(
                    pts, [_frame.facet_corners(f) for f in local], flip=flip))
            except ValueError:  # degenerate (its nodes coincide): the target's facets answer
                self.patch_facets.append(None)
                self.surfaces.append(None)
                continue
            opts = dict(options)
            if opts.get("frame", "auto") == "auto":
                opts["frame"] = "global" if _flat(pts, local) else "local"
            try:
                surf = DiffuseSurface(pts, local, flip=flip, **opts)
            except ValueError:  # too few distinct nodes for the basis: its facets answer it
                surf = None
            self.surfaces.append(surf)
        first = next((s for s in self.surfaces if s is not None), None)
        self._describe(first if first is not None else DiffuseSurface(
            self.nodes, faces, flip=flip, **options))
        self.frame = "per patch"

    def _describe(self, surf):
        self.basis, self.weight, self.support = surf.basis, surf.weight, surf.support
        self.frame, self.nterms = surf.frame, surf.nterms

    def _classify_edges(self, faces):
        """edge_class (F, 4) of each facet edge and vertex_class (n,) of each node (the highest
        class of the edges there): `INSIDE` within a patch, `SMOOTH` between two patches
        split by their tags only (the facets meet at less than the feature angle: a fillet's
        tangent edge), `OPEN_EDGE` an open or non-manifold edge, `SHARP` a feature edge."""
        key = _patches.node_identity(self.nodes)
        fac, loc, edge, ne = _patches.facet_edges(faces, key)
        count = np.bincount(edge, minlength=ne)
        lo = np.full(ne, np.iinfo(np.int64).max)
        hi = np.full(ne, -1)
        np.minimum.at(lo, edge, self.label[fac])
        np.maximum.at(hi, edge, self.label[fac])
        # the two facets' normals (manifold edges): smallest and largest facet of the edge
        flo = np.full(ne, np.iinfo(np.int64).max)
        fhi = np.full(ne, -1)
        np.minimum.at(flo, edge, fac)
        np.maximum.at(fhi, edge, fac)
        two = count == 2
        cos = np.ones(ne)
        cos[two] = np.einsum("ij,ij->i", self.facet_normal[flo[two]], self.facet_normal[fhi[two]])
        sharp = cos < np.cos(np.radians(min(self.feature_angle, 180.0)))
        cls = np.where(~two, OPEN_EDGE, np.where(lo == hi, INSIDE, np.where(sharp, SHARP, SMOOTH)))
        cls = cls.astype(np.int8)
        self.edge_class = np.zeros((len(self.corners), 4), np.int8)
        self.edge_class[fac, loc] = cls[edge]
        self.vertex_class = np.zeros(len(self.nodes), np.int8)
        a = self.corners[fac, loc]
        b = self.corners[fac, np.where(loc + 1 < self.kind[fac], loc + 1, 0)]
        for end in (a, b):
            np.maximum.at(self.vertex_class, key[end], cls[edge])
        self.vertex_class = self.vertex_class[key]

    def _where_class(self, facet, param) -> np.ndarray:
        """Class (`_classify_edges`) of the feature holding each facet point: INSIDE within a
        facet, else that of its edge or vertex."""
        out = np.zeros(len(facet), np.int8)
        ok = facet >= 0
        f, a, b = facet[ok], param[ok, 0], param[ok, 1]
        kind = self.kind[f]
        eps = tol.EDGE_EPS
        a0, b0, a1, b1 = a <= eps, b <= eps, a >= 1 - eps, b >= 1 - eps
        tri = kind == 3
        # vertex (corner index) or edge (local edge j), as the facet engine's _feature
        corner = np.full(len(f), -1)
        edge = np.full(len(f), -1)
        corner[tri & a0 & b0] = 0
        corner[tri & ~(a0 & b0) & a1] = 1
        corner[tri & ~(a0 & b0) & ~a1 & b1] = 2
        t_free = tri & (corner < 0)
        edge[t_free & b0] = 0
        edge[t_free & ~b0 & a0] = 2
        edge[t_free & ~b0 & ~a0 & (a + b >= 1 - eps)] = 1
        q = ~tri
        qc = q & (a0 | a1) & (b0 | b1)
        corner[qc] = (2 * b1 + (a1 != b1))[qc]
        qe = q & ~qc
        edge[qe & b0] = 0
        edge[qe & ~b0 & a1] = 1
        edge[qe & ~b0 & ~a1 & b1] = 2
        edge[qe & ~b0 & ~a1 & ~b1 & a0] = 3
        cls = np.zeros(len(f), np.int8)
        e = edge >= 0
        cls[e] = self.edge_class[f[e], edge[e]]
        c = corner >= 0
        cls[c] = self.vertex_class[self.corners[f[c], corner[c]]]
        out[ok] = cls
        return out

    # -- the projection ------------------------------------------------------------------------
    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        """Project contactors: the closest valid answer of the nearby patches (module doc).

        Returns a Projection (the DiffuseSurface contract) with also ``source`` (m,) int: the
        patch whose diffuse surface answered, -1 where the facets answered (a sharp edge or
        corner, a patch too small for the basis), -2 where nothing did."""
        if self.one is not None:
            res = self.one.project(points, keep_patch=keep_patch, progress=progress)
            res.source = np.where(np.isin(res.status, _ANSWERED), 0, -2)
            return res
        if keep_patch:
            raise ValueError("a frozen pairing (--save-pairs, --pairs) needs one "
                             "patch: --feature-angle 180 on a target without tags")
        points = np.ascontiguousarray(_as_points(points))
        if len(points) <= CHUNK:
            res = self._project(points)
        else:  # in chunks, to bound the memory (each call of an engine has a fixed cost)
            parts = []
            for lo in range(0, len(points), CHUNK):
                parts.append(self._project(points[lo:lo + CHUNK]))
                if progress is not None:
                    progress(min(lo + CHUNK, len(points)))
            res = _empty(points)
            for name in _FIELDS + ("terms", "source"):
                setattr(res, name, np.concatenate([getattr(q, name) for q in parts]))
        if progress is not None:
            progress(len(points))
        return res

    def _project(self, points) -> Projection:
        m = len(points)
        glob = self.facets.project(points)
        out = _empty(points)
        source = np.full(m, -2, np.int64)
        best = np.full(m, np.inf)  # |x^c - x^d| of the answer so far, and its rank: 0 on its
        rank = np.full(m, 2, np.int8)  # patch, 1 a little past a smooth edge of it
        live = glob.status != FAILED
        out_rows = np.flatnonzero(~live)
        _put(out, out_rows, glob, out_rows)  # NaN or inf contactors: failed (bad-point)
        d0 = np.linalg.norm(points - glob.proximal_point, axis=1)
        h = self.facets.node_spacing[self.corners[np.maximum(glob.facet, 0), 0]]
        reach = np.where(live, d0 + CANDIDATE_SPACINGS * h, -np.inf)
        home = np.where(live, self.label[np.maximum(glob.facet, 0)], -1)
        home_valid = np.zeros(m, bool)
        fallback_rows = []  # rows whose home patch answered 'outside': kept if nothing else does
        for p in range(self.npatches):
            if self.surfaces[p] is None:
                continue  # answered by the target's facets (step 4)
            lo, hi = self.boxes[p]
            gap_box = np.linalg.norm(np.maximum(np.maximum(lo - points, points - hi), 0), axis=1)
            rows = np.flatnonzero(live & (gap_box <= reach))
            if not len(rows):
                continue
            # the closest facet's patch is a candidate; another one where a facet of it is
            # within reach
            other = rows[home[rows] != p]
            if len(other):
                fp = self.patch_facets[p].project(points[other])
                near = np.linalg.norm(points[other] - fp.proximal_point, axis=1) <= reach[other]
                rows = np.sort(np.concatenate([rows[home[rows] == p], other[near]]))
            surf = self.surfaces[p]
            if not len(rows):
                continue
            dp = surf.project(points[rows])
            valid = np.isin(dp.status, _ANSWERED)
            tier = np.zeros(len(rows), np.int8)
            if valid.any():
                at = np.flatnonzero(valid)
                valid[at], tier[at] = self._on_patch(p, dp.proximal_point[at])
            dist = np.linalg.norm(points[rows] - dp.proximal_point, axis=1)
            take = valid & ((tier < rank[rows]) | (tier == rank[rows]) & (dist < best[rows]))
            _put(out, rows[take], dp, np.flatnonzero(take))
            best[rows[take]] = dist[take]
            rank[rows[take]] = tier[take]
            source[rows[take]] = p
            mine = home[rows] == p
            home_valid[rows[mine & valid]] = True
            rest = mine & ~valid
            fallback_rows.append((rows[rest], dp, np.flatnonzero(rest)))
        # the facets' own answer: at a feature edge or vertex, or where the closest facet's
        # patch could not answer (and the point is not on an open boundary)
        where = self._where_class(glob.facet, glob.param)
        facets_ok = live & ((where == SHARP) | (~home_valid & (where != OPEN_EDGE)))
        take = facets_ok & ((rank > 0) | (d0 < best))
        rows = np.flatnonzero(take)
        _put(out, rows, glob, rows)
        best[rows] = d0[rows]
        rank[rows] = 0
        source[rows] = -1
        # nothing answered: the home patch's own verdict ('outside' past an open boundary)
        verdict = np.zeros(m, bool)
        for rows, dp, sel in fallback_rows:
            left = source[rows] == -2
            _put(out, rows[left], dp, sel[left])
            verdict[rows[left]] = True
        nothing = np.flatnonzero(live & (source == -2) & ~verdict)
        if len(nothing):  # a home patch without a diffuse surface, on an open boundary
            out.status[nothing] = OUTSIDE
            out.reason[nothing] = FEW_NODES
        out.source = source
        return out

    def _on_patch(self, p, xd):
        """Whether proximal points xd of patch p lie on it (valid), and their rank: 0 on it,
        1 past a smooth edge by at most `SMOOTH_OVERSHOOT_SPACINGS` (valid, but an answer of
        rank 0 elsewhere is preferred: the next patch holds that point)."""
        fp = self.patch_facets[p].project(xd)
        glob_facet = self.patch_ids[p][np.maximum(fp.facet, 0)]
        cls = self._where_class(np.where(fp.facet >= 0, glob_facet, -1), fp.param)
        d = xd - fp.proximal_point
        n = self.facet_normal[glob_facet]  # the facet's own (at an edge fp.normal is d's)
        along = np.linalg.norm(d - np.einsum("ij,ij->i", d, n)[:, None] * n, axis=1)
        h = self.patch_facets[p].node_spacing[self.patch_facets[p].facets[
            np.maximum(fp.facet, 0), 0]]
        past = ((cls == SHARP) | (cls == SMOOTH)) & (along > OVERSHOOT_SPACINGS * h)
        valid = ~past | (cls == SMOOTH) & (along <= SMOOTH_OVERSHOOT_SPACINGS * h)
        return valid, past.astype(np.int8)

    def project_with(self, points, patch):
        if self.one is None:
            raise ValueError("a frozen pairing needs one patch: --feature-angle 180")
        return self.one.project_with(points, patch)


def _flat(nodes, faces) -> bool:
    """Whether a patch is flat: every facet within `FLAT_PATCH_DEG` of its mean plane."""
    _, axes = _frame.mean_plane(nodes)
    area = _frame.facet_area_vectors(nodes, faces)
    n = area / np.maximum(np.linalg.norm(area, axis=1, keepdims=True), 1e-300)
    return bool(np.min(np.abs(n @ axes[2])) >= np.cos(np.radians(FLAT_PATCH_DEG)))


def _empty(points) -> Projection:
    m = len(points)
    nan = np.full(m, np.nan)
    return Projection(points, nan.copy(), np.full((m, 3), np.nan), np.full((m, 3), np.nan),
                      np.full(m, FAILED, np.int8), np.zeros(m, np.int64),
                      np.zeros(m, np.int64), nan.copy(), np.full((m, 2), np.nan),
                      np.full(m, FEW_NODES, np.int8), np.zeros(m, np.int8))


_FIELDS = ("gap", "normal", "proximal_point", "status", "support", "iterations", "rcond",
           "curvature", "reason")


def _put(out: Projection, rows, src: Projection, sel) -> None:
    for name in _FIELDS:
        getattr(out, name)[rows] = getattr(src, name)[sel]
    # the basis terms fitted (Projection.terms): none where the facets answered
    out.terms[rows] = 0 if src.terms is None else src.terms[sel]
