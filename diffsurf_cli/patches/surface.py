"""A target's diffuse surface built per smooth patch, checked at every point against its facets
(method.md "Real targets: patches" and "The facets bound the smooth surface").

One `DiffuseSurface` per patch (`patches.segment`: bounded by sharp edges, the file's face or
region tags, open boundaries), so a support never straddles a sharp edge (flat patches get
their own mean plane and are exact) and never mixes the two sides of a thin wall. Each
contactor is answered in one compiled pass (`_pass.pyx`):

1. its faceted closest point over the whole target [1]-[2] (facet f0, gap g_f);
2. the candidate patches: those of the facets sharing a node with f0;
3. each candidate's diffuse proximal point [25]-[30], valid where the engine answers it and
   it lies on that patch: its closest point on the patch's facets is not past a sharp edge by
   more than `tol.OVERSHOOT_SPACINGS` h along the facet (`tol.SMOOTH_OVERSHOOT_SPACINGS`
   past a smooth edge between patches split by their tags, then only where no patch answers
   inside its own boundary);
4. the valid answer closest to the contactor; the facets answer at a sharp edge or corner
   (the diffuse surfaces cannot reach it) and where f0's patch has no valid answer of its
   own (a patch too small or too narrow for the basis, a strip) and f0's foot is not on an
   open edge; nothing valid: f0's patch's own verdict ('outside' with its reason);
5. the guard: a diffuse answer may differ from the facets' by no more than what smoothing them
   can explain, or the facets answer, with reason 'guard' (`guard_bounds`);
6. wherever the facets would answer away from a sharp edge, the target's curved cells do
   where they can: its second-order cells, or its first-order facets curved through their
   corner normals (`cell_coefficients`, `_pass.cells_answer`).

A target of one patch (`feature_angle=None`, or a smooth closed target) runs the same pass:
its diffuse answers are those of its `DiffuseSurface`, bit for bit, wherever the guard
accepts them; the facets answer where it cannot.
"""
from __future__ import annotations

import copy

import numpy as np

from .. import tol
from ..mls import frame as _frame
from ..mls.surface import CHUNK as ENGINE_CHUNK
from ..mls.surface import ENGINE_CAP, DiffuseSurface
from ..projection import (
    PASS_RECORD,
    NearestNode,
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
from . import _cells, _edges, _guard, _pass
from . import segment as _segment

#: Classes of facet edges and vertices (`PatchedSurface.edge_class`), by priority: the
#: compiled pass's own codes.
INSIDE, SMOOTH, OPEN_EDGE, SHARP = (_pass.EDGE_CLASSES.index(c)
                                    for c in ("inside", "smooth", "open", "sharp"))
#: `Projection.source` of an answer of the facets, of none, and of the curved cells.
FACETS, NOTHING, CELLS = _pass.FACETS, _pass.NOTHING, _pass.CELLS


class PatchedSurface:
    """The diffuse surface of a real target: one `DiffuseSurface` per smooth patch, the facets
    at sharp edges, and a guard at every point (module docstring).

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f, k) int, or one such array
        Facet blocks indexing `nodes` (3, 6, 7 columns for triangles; 4, 8, 9 for quads,
        corners first); required: they define the patches and the facets.
    feature_angle : float or None
        Degrees (`segment.FEATURE_ANGLE_DEG` by default): edges whose facets differ by more
        split patches, as do the file's tags, flat faces and open boundaries; 180: tags and
        open boundaries only; None: one patch, one diffuse surface over the whole target.
    tags : (f,) int, optional
        Face or region tag of each facet (facets numbered block after block).
    smooth_tags : bool
        The tags are CAD faces (a mesh's Gmsh geometrical entities): smooth inside, so no
        edge inside one is a feature, whatever its angle (`segment.segment`).
    flip : bool
    guard : bool
        Check every diffuse answer against the facets (`guard_bounds`); on by default.
    check_winding : bool
        Warn (`projection.InsideOutWarning`, naming flip=True) where the facets hold a closed
        surface wound inside out; not with `flip` (`DiffuseSurface`).
    progress : callable, optional
        Called with the name of each stage of the build as it starts ('node identity' ...
        'diffuse surface': `targets.STAGES`): a sign of life on a large target.
    **options
        DiffuseSurface options (basis, weight, support, radius, k, frame, recentre,
        outside_spacings), the same for every patch; frame 'auto' (the default) is the
        global mean plane on a flat patch (exact), local frames on a curved one.

    Attributes
    ----------
    label : (F,) int           patch of each facet
    surfaces : list            DiffuseSurface of each patch, None where the patch cannot
                               carry one (its facets answer it)
    patch_nodes : list         (n_p,) int of each patch: the target node of each of its
                               surface's nodes (its local node i is global node
                               patch_nodes[p][i]); the nodes that add no geometry are not
                               among them (`geometry_free`)
    facet_nodes : list         (m_p,) int of each patch: the target node of each node of
                               its facets (`patch_facets`), all of them
    geometry_free : int        the number of nodes that add no geometry (issue 34: inside a
                               facet cut in pieces in its plane, on a straight side of one
                               cut on its chord; `segment.geometry_free`), out of every diffuse
                               surface's fit, which is fitted over the polyhedron's own facets
                               there
    refinement : segment.Refinement   which nodes, and the split facets
    facet_surface() : FacetSurface   the whole target's facets (every surface's method)
    node_spacing : (n,) float  the local spacing of each node, as the facets measure it
    gap_bound : (F,) float     the guard's bound on |g - g_f| at each facet (its envelope)
    gap_lo, gap_hi : (F,) float    ... on g - g_f, on the side the facets' bend explains
    normal_angle : (F,) float  ... and on the angle between the normals (radians)
    normal_turn : (F,) float   ... plus this times the distance between the two feet
    support_floor : (F,) float the least local spacing of a facet's patch over it
    """

    def __init__(self, nodes, faces, *, feature_angle=_segment.FEATURE_ANGLE_DEG, tags=None,
                 smooth_tags=False, flip=False, guard=True, check_winding=True, progress=None,
                 **options):
        from ..facet.surface import FacetSurface
        from ..nodes import SharedNodes

        # progress(stage): each stage's name as it starts (`targets.STAGES`), or nothing
        progress = progress if progress is not None else (lambda stage: None)
        progress("node identity")
        self.nodes = as_target_nodes(nodes)
        faces = [f for f in as_faces(faces, len(self.nodes)) if len(f)]
        if not faces:
            raise ValueError("patches need the target's facets (triangles or quads)")
        for f in faces:  # our own copies: read-only, so that the surfaces share, not copy them
            f.flags.writeable = False
        self.faces = faces
        self.flip = bool(flip)
        #: made by `moved`: a deformable target's positions (not a fixed, rigid one)
        self.deformed = False
        # the node identity and spacing, measured once: the whole target's facets and, for
        # one patch, its diffuse surface share them (`_build_patches`)
        shared = SharedNodes(self.nodes)
        self.key = shared.first  # segment.node_identity's (np.unique's first occurrences)
        progress("edges and patches")
        # the facet edges, once: the winding check, the segmentation and the edges' classes
        edges = _segment.edge_table(faces, self.key)
        if check_winding and not flip:  # once, for the target: its parts do not check again
            warn_inside_out(self.nodes, faces, self.key, edges=edges)
        self.guard = bool(guard)
        self.options = dict(options)
        self.feature_angle = None if feature_angle is None else float(feature_angle)
        nf = sum(len(f) for f in faces)
        corners = [_frame.facet_corners(f) for f in faces]
        # the facets' area vectors, once: the segmentation's normals and the facets' own
        area = _frame.facet_area_vectors(self.nodes, corners)
        #: (m,) bool over the manifold edges, None where none: the bends of coarse smooth
        #: curves past the feature angle (or the default one, if smaller), no creases (issue
        #: 35, `segment.creases`): for the patches, the edges' classes and the curved cells,
        #: and no crease around a split facet (a coarse tube refined linearly); and the
        #: creases of the CAD below that angle (`segment.cad_creases`), sharp edges where the
        #: target has patches (`_classify_edges`)
        self.coarse_bend, self.cad_crease = _bends_and_creases(
            self.nodes, faces, self.key, edges, area,
            min(self.feature_angle or 180.0, _segment.FEATURE_ANGLE_DEG))
        # the nodes that add no geometry (issue 34: a facet cut in pieces in its own plane, a
        # straight edge cut on its line): out of the diffuse surfaces' fits and of the flat
        # faces; the facets keep them. Creases as `_crease_normals` takes them: the default
        # feature angle's whatever the patches' (a box's faces are faces under one patch),
        # not a coarse curve's bends
        self.refinement = _segment.geometry_free(
            self.nodes, faces, self.key, edges, area,
            min(self.feature_angle or 180.0, _segment.FEATURE_ANGLE_DEG), tags,
            self.coarse_bend)
        #: the number of nodes that add no geometry, left out of the smooth surface's fit
        self.geometry_free = self.refinement.count
        if self.feature_angle is None:
            self.label = np.zeros(nf, np.int64)
        else:
            self.label = _segment.segment(self.nodes, faces, self.feature_angle, tags,
                                          smooth_tags=smooth_tags, key=self.key, edges=edges,
                                          area=area, refinement=self.refinement,
                                          bends=self._bends(edges))
        self.npatches = int(self.label.max()) + 1
        progress("facets")
        self._facets = FacetSurface(self.nodes, corners, flip=flip, check_winding=False,
                                   shared=shared)
        # the facets' own (F, 4) table of corners, triangles padded with -1: one copy
        self.corners = self._facets.facets
        self.kind = np.where(self.corners[:, 3] < 0, 3, 4)
        self.facet_normal = _unit_rows(area)
        del area
        self.tags = None if tags is None else np.asarray(tags).reshape(-1)
        self.smooth_tags = bool(smooth_tags) and self.tags is not None
        progress("edge classes")
        self._classify_edges(faces, edges)
        del edges
        progress("rings")
        self._rings()
        progress("guard bounds")
        self.corner_normal, self.edge_length, self.edge_bend = corner_normals(self)
        (self.gap_bound, self.gap_lo, self.gap_hi, self.normal_angle,
         self.normal_turn) = guard_bounds(self)
        self.support_floor = support_floor(self)
        progress("curved cells")
        self.has_cell, self._cell_table, cell_normal = cell_tables(self)
        self._keep_normals(cell_normal)
        del cell_normal
        progress("diffuse surface")
        self._build_patches(faces, options, shared)
        self._pass = None
        self._nearest = None  # NearestNode: whether a contactor is far from every node
        self._plain_fits = None  # `_deformable_fits`, built on the first `moved`

    # -- construction ------------------------------------------------------------------------
    def _build_patches(self, faces, options, shared=None):
        """One FacetSurface and one DiffuseSurface per patch. They share their nodes' identity
        and spacing (`facet.surface.SharedNodes`): the whole target's (`shared`) for one
        patch; a patch's identity follows from the target's (`SharedNodes.subset`), its
        spacing is its own nodes' (measured once for its facets and its surface)."""
        from ..facet.surface import FacetSurface
        from ..nodes import SharedNodes

        shared = SharedNodes.of(self.nodes, shared)
        #: {patch: (its own facets over `facet_nodes[patch]`, its options)} where its fit
        #: leaves nodes out (`_fit_faces`): what a deformable target fits (`moved`)
        self._plain_faces = {}
        #: per patch, None or (len(patch_nodes[p]), 3): the constant offsets a deformable
        #: target adds to its nodes' positions in that patch's fit (`_deformable_fits`)
        self.lift = [None] * self.npatches
        if self.npatches == 1:  # the whole target: its own surface, as DiffuseSurface builds it
            self.patch_ids = [np.arange(len(self.label))]
            self.patch_nodes = [np.arange(len(self.nodes))]
            self.facet_nodes = self.patch_nodes
            self.patch_facets = [self._facets]
            fit = self._fit_faces(faces, self.patch_ids[0])
            if fit is None:
                self.surfaces = [_diffuse(self.nodes, faces, self.flip, options, shared)]
            else:  # over the polyhedron's own facets, without the nodes that add no geometry
                used, local = fit
                self.patch_nodes = [used]
                self.surfaces = [_diffuse(self.nodes[used], local, self.flip, options,
                                          shared.subset(used))]
                self._plain_faces = {0: (list(faces), dict(options))}
            self.boxes = np.concatenate([self.nodes.min(axis=0), self.nodes.max(axis=0)])[None]
            if self.surfaces[0] is None:
                raise ValueError(f"the target has {len(shared.distinct)} "
                                 f"distinct nodes: not even a plane can be fitted")
            self._describe(self.surfaces[0])
            return
        starts = np.cumsum([0] + [len(f) for f in faces])
        self.surfaces, self.patch_facets, self.patch_ids, boxes = [], [], [], []
        self.patch_nodes, self.facet_nodes = [], []
        for p in range(self.npatches):
            ids = np.flatnonzero(self.label == p)
            self.patch_ids.append(ids)
            blocks = []
            for b, f in enumerate(faces):
                sel = ids[(ids >= starts[b]) & (ids < starts[b + 1])] - starts[b]
                if len(sel):
                    blocks.append(f[sel])
            used = np.unique(np.concatenate([blk.ravel() for blk in blocks]))
            self.facet_nodes.append(used)
            fit = self._fit_faces(faces, ids)
            self.patch_nodes.append(used if fit is None else fit[0])
            local = [np.searchsorted(used, blk) for blk in blocks]
            own = shared.subset(used)  # the patch's facets and surface measure it once
            pts = own.nodes
            boxes.append(np.concatenate([pts.min(axis=0), pts.max(axis=0)]))
            try:
                self.patch_facets.append(FacetSurface(
                    pts, [_frame.facet_corners(f) for f in local], flip=self.flip,
                    check_winding=False, shared=own))
            except ValueError:  # degenerate (its nodes coincide): the target's facets answer
                self.patch_facets.append(None)
                self.surfaces.append(None)
                continue
            plain = local
            if fit is not None:  # over the polyhedron's own facets (`_fit_faces`)
                own = shared.subset(fit[0])
                pts, local = own.nodes, fit[1]
            opts = dict(options)
            if opts.get("frame", "auto") == "auto":
                opts["frame"] = "global" if _flat(pts, local) else "local"
            self.surfaces.append(_diffuse(pts, local, self.flip, opts, own))
            if fit is not None:
                self._plain_faces[p] = (plain, opts)
        self.boxes = np.array(boxes)
        first = next((s for s in self.surfaces if s is not None), None)
        if first is None:
            raise ValueError("no patch of the target can carry a diffuse surface")
        self._describe(first)
        self.basis = options.get("basis", first.basis)
        self.frame = "per patch"

    def _fit_faces(self, faces, ids):
        """The facets a patch's diffuse surface is fitted over where some of its nodes add no
        geometry (`refinement`): its facets (`ids`, numbered block after block) with each
        split facet holding such a node replaced by its polygon's triangles (over its other
        nodes); (used: the target's nodes they hold, ascending; the blocks indexing `used`),
        or None where the patch has no such node. Second-order cells cut in four on their
        own map are replaced by their parent where all four are in the patch."""
        r = self.refinement
        if not r.replaced[ids].any():
            return None
        keep, extra = r.fit_over(ids)
        if not extra:
            return None
        starts = np.cumsum([0] + [len(f) for f in faces])
        blocks = []
        for b, f in enumerate(faces):
            sel = keep[(keep >= starts[b]) & (keep < starts[b + 1])] - starts[b]
            if len(sel):
                blocks.append(f[sel])
        blocks += extra
        used = np.unique(np.concatenate([blk.ravel() for blk in blocks]))
        return used, [np.searchsorted(used, blk) for blk in blocks]

    def _describe(self, surf):
        self.basis, self.weight, self.support = surf.basis, surf.weight, surf.support
        self.frame, self.nterms, self.recentre = surf.frame, surf.nterms, surf.recentre

    def _bends(self, edges):
        """`coarse_bend` as (m,) bool over the manifold edges of `edges`, zeros where it
        is None (none: the segmentation need not look again)."""
        if self.coarse_bend is not None:
            return self.coarse_bend
        return np.zeros(int(np.count_nonzero(np.diff(edges.start) == 2)), bool)

    def _classify_edges(self, faces, edges=None):
        """edge_class (F, 4) of each facet edge and vertex_class (n,) of each node (the highest
        class of the edges there): `INSIDE` within a patch, `SMOOTH` between two patches
        split by their tags only (the facets meet at less than the feature angle: a fillet's
        tangent edge), `OPEN_EDGE` an open or non-manifold edge, `SHARP` a feature edge.
        `edges`: the facet edges (`segment.edge_table` of `faces`), computed if not given."""
        if edges is None:
            edges = _segment.edge_table(faces, self.key)
        angle = 180.0 if self.feature_angle is None else min(self.feature_angle, 180.0)
        same_tag = None
        if self.smooth_tags:  # no edge inside a CAD face is a feature
            f1, f2 = _segment._two_facets(edges)
            same_tag = self.tags[np.minimum(f1, f2)] == self.tags[np.maximum(f1, f2)]
            del f1, f2
        if self.coarse_bend is not None:  # nor a coarse smooth curve's bend (`creases`)
            same_tag = self.coarse_bend if same_tag is None else same_tag | self.coarse_bend
        if len(self.corners) >= 2 ** 31:
            raise ValueError("the target's tables exceed int32 indices")
        # one compiled pass over the edges (`_edges.classify`): each manifold edge's two
        # facets (its first two half-edges', smallest first) and the cosine of their normals
        # (np.einsum's, bit for bit), sharp below the feature angle's; an edge's class by
        # priority (open, sharp, inside a patch, smooth: a sharp edge inside a patch, where a
        # crease ends where its faces meet tangentially, is a feature too, and the facets
        # answer on it); a node's the highest of its edges' (an edge's ends are its nodes'
        # identities). edge_facets int32: issue 36; edge_sharp is the guard's bounds' feature
        # (not inside a CAD face, whatever its angle).
        i64 = _segment._i64
        (self.edge_class, self.vertex_class, self.edge_facets,
         self.edge_sharp) = _edges.classify(
            i64(edges.start), i64(edges.order), i64(edges.fac), i64(edges.loc),
            i64(edges.edge), i64(edges.ends), _float64(self.facet_normal), i64(self.label),
            same_tag, float(np.cos(np.radians(angle))), len(self.corners), len(self.nodes),
            i64(self.key), INSIDE, SMOOTH, OPEN_EDGE, SHARP)
        if self.cad_crease is not None and angle < 180:
            self._cad_sharp(edges)
        flo, fhi = self.edge_facets[:, 0], self.edge_facets[:, 1]
        # the smooth regions: facets joined across edges that are no feature (a fillet and
        # the faces it meets tangentially are one region; a sharp edge splits), numbered in
        # order of their first facet as `_regions` numbers them
        smooth = ~self.edge_sharp
        self.smooth_region = _segment.components(len(self.corners), flo[smooth], fhi[smooth])

    def _cad_sharp(self, edges):
        """Make the creases of the CAD below the feature angle (`cad_crease`) sharp edges,
        in the edges' and the nodes' classes (not inside one CAD face: `smooth_tags`)."""
        new = self.cad_crease & ~self.edge_sharp
        if self.smooth_tags:
            a, b = self.edge_facets[:, 0], self.edge_facets[:, 1]
            new &= self.tags[a] != self.tags[b]
        if not new.any():
            return
        self.edge_sharp = self.edge_sharp | new
        which = np.flatnonzero(np.diff(edges.start) == 2)[new]
        for k in (0, 1):  # each of its two half-edges
            h = edges.order[edges.start[which] + k]
            self.edge_class[edges.fac[h], edges.loc[h]] = SHARP
        at = np.zeros(int(self.key.max()) + 1, bool)
        at[edges.ends[which].ravel()] = True
        self.vertex_class[at[self.key]] = SHARP

    def _rings(self):
        """The vertex ring of each facet (the facets sharing a node with it, by node identity,
        itself included) as CSR rows (`ring`: `segment.FacetRing`, indptr and indices, sorted
        within rows), and the candidate patches of each facet: the distinct patches of its
        ring (CSR ring_ptr, ring_patches).

        One compiled pass (`segment.facet_rings`): each node's facets, then each facet's ring
        as the sorted union of its corners' lists, then its ring's patches: linear, no
        (F, F) sparse product. int32, as the compiled passes (`_pass.pyx`, `_guard.pyx`) read
        them: half the memory of int64 (the ring is some 13 facets a facet, the largest
        index table of the target), no copy when the engine is built."""
        ring, ring_ptr, ring_patches = _segment.facet_rings(
            self.corners, self.key, self.label, self.npatches)
        self.ring = _segment.FacetRing(_int32(ring.indptr), _int32(ring.indices))
        del ring
        self.ring_ptr, self.ring_patches = _int32(ring_ptr), _int32(ring_patches)

    def facet_surface(self):
        """The whole target's facets, a `FacetSurface` (every surface's `facet_surface`): the
        faceted foot, the answer at sharp edges and the guard's reference."""
        return self._facets

    @property
    def node_spacing(self) -> np.ndarray:
        """(n,) float: the local node spacing of each node, as the facets measure it."""
        return self._facets.node_spacing

    @property
    def engine(self) -> _pass.PatchedPass:
        """The compiled pass over the patches, built on first use (not pickled)."""
        if self._pass is None:
            live = [s is not None and f is not None
                    for s, f in zip(self.surfaces, self.patch_facets)]
            arrays = {
                "label": self.label, "corners": self.corners, "kind": self.kind,
                "edge_class": self.edge_class, "vertex_class": self.vertex_class,
                # oriented as the target: the same bits as 1.0 * n, no copy unless flipped
                "facet_normal": -self.facet_normal if self.flip else self.facet_normal,
                "spacing": self.node_spacing[self.corners[:, 0]],
                "ring_ptr": self.ring_ptr, "ring": self.ring_patches,
                "gap_bound": self.gap_bound, "gap_lo": self.gap_lo, "gap_hi": self.gap_hi,
                "normal_angle": self.normal_angle, "normal_turn": self.normal_turn,
                "facet_size": self.support_floor,
                "has_cell": self.has_cell, "cell_coef": self._cell_table,
                "nodes": self.nodes,
                "cell_index": None if self._cell_normals is None else self._cell_normals[0],
                "cell_table": None if self._cell_normals is None else self._cell_normals[1],
                "cell_shape3": cell_shape(6), "cell_shape4": cell_shape(8),
                "fring_ptr": self.ring.indptr, "fring": self.ring.indices,
                "contact_tol": tol.CONTACT,
                "guard": self.guard, "candidate_spacings": tol.CANDIDATE_SPACINGS,
                "overshoot": tol.OVERSHOOT_SPACINGS,
                "smooth_overshoot": tol.SMOOTH_OVERSHOOT_SPACINGS,
                "edge_eps": tol.EDGE_EPS,
            }
            self._pass = _pass.PatchedPass(
                [s.engine if ok else None for s, ok in zip(self.surfaces, live)],
                [s._options() if ok else None for s, ok in zip(self.surfaces, live)],
                [f.engine if ok else None for f, ok in zip(self.patch_facets, live)],
                self.patch_ids, self.boxes, self._facets.engine, arrays)
        return self._pass

    def _keep_normals(self, cell_normal) -> None:
        """What the build keeps of its corner tables (issue 36: about 330 bytes a node less):
        the corner normals compacted (`_pass.compact_normals`: a node's normal in each of
        its smooth regions once, an int32 index a corner), those the curved cells follow
        (`cell_normal`, `cell_tables`: the same rows where they are the corner normals), and
        not the edges' lengths and bends (the guard's and the cells' inputs, recomputed on
        demand: `edge_length`, `edge_bend`)."""
        key, corners = _int64(self.key), _int64(self.corners)
        normals = self._corner_normal
        self._normals = _pass.compact_normals(_float64(normals), corners, key)
        if cell_normal is None:
            self._cell_normals = None
        elif cell_normal is normals:
            self._cell_normals = self._normals
        else:
            self._cell_normals = _pass.compact_normals(_float64(cell_normal), corners, key)
        self._corner_normal = self._edge_length = self._edge_bend = None

    @property
    def corner_normal(self) -> np.ndarray:
        """(F, 4, 3) each facet corner's normal (`corner_normals`; zero for a triangle's
        fourth): kept compacted after the build, expanded on each call."""
        if self._corner_normal is not None:
            return self._corner_normal
        return _expand_normals(*self._normals)

    @corner_normal.setter
    def corner_normal(self, value):
        self._corner_normal = value

    @property
    def edge_length(self) -> np.ndarray:
        """(F, 4) each facet edge's length (`corner_normals`; 0 for none): recomputed on each
        call after the build, the same bits."""
        if self._edge_length is not None:
            return self._edge_length
        return _edge_lengths(self.nodes, self.corners, self.kind)

    @edge_length.setter
    def edge_length(self, value):
        self._edge_length = value

    @property
    def edge_bend(self) -> np.ndarray:
        """(F, 4) each facet edge's bend (`corner_normals`): recomputed on each call after
        the build."""
        if self._edge_bend is not None:
            return self._edge_bend
        return corner_normals(self)[2]

    @edge_bend.setter
    def edge_bend(self, value):
        self._edge_bend = value

    @property
    def cell_coef(self) -> np.ndarray:
        """(F, 9, 3) the curved cells' monomial coefficients (`cell_coefficients`; (1, 9, 3)
        zeros where no cell is curved). Kept as a table only where the target has
        second-order cells; a first-order target's is computed on each call (its cells
        follow from the corners and `cell_normal`: `cell_rows` computes only the rows one
        needs)."""
        if self._cell_table is not None:
            return self._cell_table
        if not self.has_cell.any():
            return np.zeros((1, 9, 3))
        return self.cell_rows(np.arange(len(self.corners)))

    def cell_rows(self, cells) -> np.ndarray:
        """(m, 9, 3) the curved cells of facets `cells` (m,): `cell_coef[cells]`, the rows of
        the table where the target keeps one, else computed from the corners and their
        normals by the table's own routine (`_cells.facet_cells`: the same bits); zero rows
        where a facet has no curved cell."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1)
        if self._cell_table is not None:
            return self._cell_table[cells]
        out = np.zeros((len(cells), 9, 3))
        if not len(cells) or self._cell_normals is None:
            return out
        nodes = _float64(self.nodes)
        index, table = self._cell_normals
        kind = self.kind[cells]
        for k in (3, 4):
            rows = np.flatnonzero((kind == k) & (self.has_cell[cells] != 0))
            if not len(rows):
                continue
            sel = cells[rows]
            coef = np.zeros((len(rows), 9, 3))
            corners = _int64(self.corners[sel])
            _cells.facet_cells(nodes, corners, k, _expand_normals(index[sel], table),
                               _edge_lengths(nodes, corners, np.full(len(sel), k)),
                               cell_shape(2 * k), 0, len(rows), np.zeros(len(rows), np.int8),
                               coef)
            out[rows] = coef
        return out

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_pass"] = None
        return state

    def moved(self, nodes) -> PatchedSurface:
        """The same target with its nodes at new positions (a deformable target, each
        iteration of a solver's step): the patches, the edges' classes (sharp, open, smooth)
        and each patch's frame choice are kept (a global frame's mean plane pinned:
        `DiffuseSurface.moved`); the facets' normals, the guard's bounds and each patch's
        surface follow the nodes. A node that adds no geometry at the reference (issue 34),
        left out of the reference fit, is in the moved one: its displacement is its own
        (`_deformable_fits`)."""
        nodes = as_moved_nodes(nodes, self.nodes)
        new = copy.copy(self)
        new.nodes = nodes
        new.deformed = True
        new._facets = self._facets.moved(nodes)
        area = _frame.facet_area_vectors(nodes, self.faces)
        new.facet_normal = _unit_rows(area)
        new.corner_normal, new.edge_length, new.edge_bend = corner_normals(new)
        (new.gap_bound, new.gap_lo, new.gap_hi, new.normal_angle,
         new.normal_turn) = guard_bounds(new)
        new.support_floor = support_floor(new)
        new.has_cell, new._cell_table, cell_normal = cell_tables(new)
        new._keep_normals(cell_normal)
        new.patch_facets = [None if f is None else f.moved(nodes[ids])
                            for f, ids in zip(self.patch_facets, self.facet_nodes)]
        surfaces, new.patch_nodes, new.lift = self._deformable_fits()
        new.surfaces = [None if s is None else s.moved(nodes[ids] if up is None
                                                       else nodes[ids] + up)
                        for s, ids, up in zip(surfaces, new.patch_nodes, new.lift)]
        new._plain_faces = {}
        new.boxes = np.array([np.concatenate([nodes[ids].min(axis=0), nodes[ids].max(axis=0)])
                              for ids in self.facet_nodes])
        new._pass = None
        new._nearest = None
        return new

    def _deformable_fits(self):
        """(surfaces, patch_nodes, lift) a deformable target moves: each patch's own, but
        fitted over all its nodes where its fit leaves out nodes that add no geometry (issue
        34). Those nodes add none only at the reference: once the target deforms, each node's
        displacement is its own, and a surface that left one out would let it penetrate and
        give it no force. Each such node is lifted from its chord onto the reference surface
        (`lift`: a constant offset added to its moved position), so that at the reference
        positions the moved surface is the reference one's (a fit through points on it), and
        it moves with the node. The offset is constant, so the element's derivatives stay
        exact; under a large rotation it turns away from the normal and the fit tends to the
        chords' own (a smoothing of the same polyhedron, never past it). Built once, at the
        reference; a global frame's mean plane is the reference fit's."""
        if not self._plain_faces:
            return self.surfaces, self.patch_nodes, self.lift
        if self._plain_fits is None:
            surfaces, patch_nodes = list(self.surfaces), list(self.patch_nodes)
            lift = list(self.lift)
            for p, (faces, opts) in self._plain_faces.items():
                ids, ref = self.facet_nodes[p], self.surfaces[p]
                lift[p] = np.zeros((len(ids), 3))
                if ref is not None:
                    left = ~np.isin(ids, self.patch_nodes[p])
                    on = ref.project(self.nodes[ids[left]]).proximal_point - self.nodes[ids[left]]
                    lift[p][left] = np.where(np.isfinite(on), on, 0.0)
                full = _diffuse(self.nodes[ids] + lift[p], faces, self.flip, opts)
                if full is not None and ref is not None and full.frame == "global" \
                        and ref.frame == "global":
                    full.origin, full.axes, full.ruled = ref.origin, ref.axes, ref.ruled
                surfaces[p], patch_nodes[p] = full, ids
            self._plain_fits = surfaces, patch_nodes, lift
        return self._plain_fits

    # -- the projection ------------------------------------------------------------------------
    def project(self, points, *, keep_patch: bool = False, progress=None) -> Projection:
        """Project contactors: the closest valid answer of the nearby patches, or the facets
        (module docstring).

        Returns a Projection (the DiffuseSurface contract) with also ``source`` (m,) int: the
        patch whose diffuse surface answered, `FACETS` (-1) where the facets answered (a sharp
        edge or corner, a patch that cannot answer, the guard), `NOTHING` (-2) where nothing
        did, `CELLS` (-3) where the target's curved cells (`cell_coefficients`) answered in
        the facets' place (`_pass.cells_answer`); and the facets' own answer: ``facet`` (m,) int
        (-1: none), ``facet_gap`` (m,), ``facet_normal`` (m, 3); and the curved cell's:
        ``cell`` (m,) int, the facet whose cell answered (-1 elsewhere), ``cell_param``
        (m, 2) its closest point's parameters (NaN elsewhere).

        keep_patch : a frozen pairing of one diffuse surface (`DiffuseSurface.project`'s): a
            target of one patch only, without the facets or the guard.
        """
        if keep_patch:
            if self.npatches > 1 or self.surfaces[0] is None:
                raise ValueError("a frozen pairing (--save-pairs, --pairs) needs one "
                                 "patch: --feature-angle 180 on a target without tags")
            return self.surfaces[0].project(points, keep_patch=True, progress=progress)
        points = np.ascontiguousarray(as_points(points))
        m = len(points)
        out = allocate(m, PASS_RECORD)
        if m:
            order = np.argsort(self._facets._order_keys(points), kind="stable")
            chunk = ENGINE_CHUNK  # a signal acts between two calls (DiffuseSurface.project)
            if progress is not None:
                progress(0)  # the work starts: what came before was setup
            for lo in range(0, m, chunk):
                todo = order[lo:lo + chunk]
                cap = ENGINE_CAP
                while len(todo):
                    self.engine.project(points, todo, out, cap)  # threads: threads_for
                    todo = todo[out["overflow"][todo].view(bool)]
                    cap *= 4
                if progress is not None:
                    progress(min(lo + chunk, m))
        res = Projection(points, **recorded(out))
        # no node within the support radius: off the target, nothing answered it
        res.source[mark_far(res, self.nearest_node)] = NOTHING
        return res

    @property
    def nearest_node(self) -> NearestNode:
        """Whether contactors are far from every node (`projection.mark_far`): the support
        radius R (the patches' surfaces') of the nearest node; built on first use."""
        if self._nearest is None:
            radius = next((s.radius for s in self.surfaces if s is not None), None)
            if radius is None:  # no patch carries a surface: the basis's default
                radius = (self.options.get("radius")
                          or tol.DEFAULT_RADIUS[self.options.get("basis", "quadratic")])
            self._nearest = NearestNode(self.nodes, self.node_spacing, radius)
        return self._nearest

    def project_with(self, points, patch):
        """A frozen pairing's projection (`DiffuseSurface.project_with`): one patch only."""
        if self.npatches > 1 or self.surfaces[0] is None:
            raise ValueError("a frozen pairing needs one patch: --feature-angle 180")
        return self.surfaces[0].project_with(points, patch)

    def within_guard(self, gap, normal, facet, guard_gap, apart=0.0,
                     plane=None) -> np.ndarray:
        """Whether answers (gap (m,), normal (m, 3)) at contactors whose faceted answer is on
        `facet` (m,) pass the guard (`guard_bounds`): `guard_gap` (m,) the faceted gap the
        projection's guard measured from (`Projection.guard_gap`: past an open edge, the
        height over the foot facet's plane), their proximal points `apart` (m,) from the
        faceted feet, `plane` (m,) bool where fitted with the plane (None: none was). True
        where the guard is off or there is no faceted answer. The projection's own compiled
        guard (`_pass.guard_holds`), not a copy of it."""
        def rows(a, dtype, *shape):
            return np.ascontiguousarray(a, dtype=dtype).reshape(-1, *shape)

        gap = rows(gap, np.float64)
        return self.engine.within_guard(
            gap, rows(normal, np.float64, 3), rows(facet, np.int64), rows(guard_gap, np.float64),
            rows(np.broadcast_to(apart, gap.shape), np.float64), plane)


def corner_normals(surf: PatchedSurface):
    """Each facet corner's normal and each facet edge's length and bend.

    A corner's normal is its smooth region's own at the node (the area-weighted normals there
    of the facets joined to each other across no sharp edge: a sharp edge is no curvature, a
    smooth edge between two tagged faces is; area weights keep slivers' unreliable normals
    from counting).

    Returns
    -------
    normal : (F, 4, 3) float   unit, zero for a triangle's fourth
    length : (F, 4) float      edge j runs from corner j to corner j + 1 (0 for none)
    bend : (F, 4) float        (n_1 - n_0) . e: its ends' normals' difference along it,
                               L κ_e for a surface of normal curvature κ_e along the edge
                               (radians for small angles), positive where the surface
                               bulges toward the normals (convex), negative where it
                               bends away (concave). Not the angle between the normals:
                               across a cylinder's slivers that is the turn of the arc
                               they span, while along their length they are straight

    Where a crease of the CAD ends inside one smooth region (a thread's flank meeting its
    core, the thread running out: the region on both of its sides is one), the region's
    normal at a node of the crease would average faces some 60° apart, which the curved
    cells and the guard's sides follow: there each corner takes its fan's own normal, the
    facets at the node joined to it across no such crease (`_crease_fans`, issue 34). A
    fillet that one cell cannot resolve is sharp too, but no crease of the CAD
    (`segment.flat_sided`): its region's normals, which carry its bend, are kept.
    """
    # one compiled pass (`_guard.corner_tables`): the sums of each node's facet normals in
    # each smooth region, in corner order, then each edge's length and bend, bit for bit
    # numpy's former arithmetic (tests/reference_guard.py)
    F = len(surf.corners)
    normal = np.zeros((F, 4, 3))
    length = np.zeros((F, 4))
    bend = np.zeros((F, 4))
    _guard.corner_tables(_int64(surf.corners), _int64(surf.kind), _float64(surf.nodes),
                         _int64(surf.key), _int64(surf.smooth_region),
                         _float64(surf.facet_normal), normal, length, bend)
    fans = _crease_fans(surf)
    if fans is not None:
        _fan_normals(surf, fans, normal, length, bend)
    return normal, length, bend


def _crease_fans(surf: PatchedSurface):
    """(slots, fan): the corners (4 f + j) at the nodes of the creases of the CAD that end
    inside one smooth region (sharp edges between facets of one region, `flat_sided`), and
    the fan of each (0 .. k - 1): the corners at one node joined across every manifold edge
    but a crease or a sharp edge between regions; None where there is none. Where the
    region at such a node holds one fan, nothing changes (not in `slots`).

    Decided once from the target's edges (the sharp edges and regions are kept by `moved`,
    as the fans are): kept on the surface for the smooth regions it was decided with."""
    region = surf.smooth_region
    kept = surf.__dict__.get("_fans_of")
    if kept is not None and kept[0] is region:
        return kept[1]
    fans = None
    a, b = _int64(surf.edge_facets[:, 0]), _int64(surf.edge_facets[:, 1])
    sharp = np.asarray(surf.edge_sharp).astype(bool)
    inside = np.flatnonzero(sharp & (region[a] == region[b]))
    if len(inside):
        edges = _segment.edge_table(surf.faces, surf.key)
        fa, fb = _segment._two_facets(edges)
        which = np.flatnonzero(np.diff(edges.start) == 2)
        area = _frame.facet_area_vectors(surf.nodes, [_frame.facet_corners(f)
                                                       for f in surf.faces])
        # a side reaches the edge across no crease past the feature angle (`flat_sided`)
        feature = sharp if surf.cad_crease is None else sharp & ~surf.cad_crease
        crease = np.zeros(len(a), bool)
        crease[inside] = _segment.flat_sided(surf.nodes, surf.faces, surf.key, edges, area,
                                             fa[inside], fb[inside], which[inside], feature)
        if crease.any():  # a fillet's sharp edge joins its region's facets at its nodes
            cut = sharp.copy()
            cut[inside] = crease[inside]
            fans = _fans(surf, a, b, edges.ends[which], crease, cut)
    surf.__dict__["_fans_of"] = (region, fans)
    return fans


def _fans(surf: PatchedSurface, a, b, ends, crease, cut):
    """`_crease_fans`' corners and fans: the corners joined across the manifold edges
    (facets a, b, end identities `ends`) not `cut`, at the ends of a `crease`."""
    F = len(surf.corners)
    keyc = np.where(surf.corners >= 0, surf.key[np.maximum(surf.corners, 0)], -1)
    # each edge's end's corner in each of its facets
    join = np.flatnonzero(~cut)
    slot_a = [4 * a[join] + np.argmax(keyc[a[join]] == ends[join, e, None], axis=1)
              for e in (0, 1)]
    slot_b = [4 * b[join] + np.argmax(keyc[b[join]] == ends[join, e, None], axis=1)
              for e in (0, 1)]
    fan = _segment.components(4 * F, np.concatenate(slot_a), np.concatenate(slot_b))
    # the corners at a crease's ends whose node holds more than one fan in its region
    at = np.zeros(int(surf.key.max()) + 2, bool)
    at[ends[crease].ravel()] = True
    slots = np.flatnonzero((keyc >= 0).ravel() & at[keyc.ravel()])
    group = keyc.ravel()[slots] * (int(surf.smooth_region.max()) + 1) \
        + surf.smooth_region[slots // 4]
    pairs, inverse = np.unique(np.stack([group, fan[slots]], axis=1), axis=0,
                               return_inverse=True)
    count = np.unique(pairs[:, 0], return_counts=True)[1]
    many = np.repeat(count > 1, count)[inverse.reshape(-1)]
    if not many.any():
        return None
    return slots[many], inverse.reshape(-1)[many]


def _fan_normals(surf: PatchedSurface, fans, normal, length, bend) -> None:
    """Give the corners of `fans` (`_crease_fans`) their fan's normal (the area-weighted
    normals of its facets, as `_guard.corner_tables` sums a region's) in `normal`, and the
    bends of their facets' edges that follow, in place."""
    slots, fan = fans
    f = slots // 4
    c, x = surf.corners[f], surf.nodes
    area = np.cross(x[c[:, 1]] - x[c[:, 0]], x[c[:, 2]] - x[c[:, 0]])
    quad = c[:, 3] >= 0
    area[quad] += np.cross(x[c[quad, 2]] - x[c[quad, 0]], x[c[quad, 3]] - x[c[quad, 0]])
    weight = 0.5 * np.linalg.norm(area, axis=1)[:, None] * surf.facet_normal[f]
    total = np.zeros((int(fan.max()) + 1, 3))
    np.add.at(total, fan, weight)
    normal.reshape(-1, 3)[slots] = _unit_rows(total)[fan]
    # the bends of the edges of those facets: their ends' normals' difference along them
    rows = np.unique(f)
    nxt = _next_corner(surf.kind[rows])
    corners = surf.corners[rows]
    here = np.arange(len(rows))[:, None]
    edge = x[corners[here, nxt]] - x[np.maximum(corners, 0)]
    unit = _ratio(edge, length[rows][:, :, None])
    turn = normal[rows][here, nxt] - normal[rows]
    bend[rows] = np.where(corners >= 0, np.einsum("fjk,fjk->fj", turn, unit), 0.0)


def _split_sags(surf: PatchedSurface, edge_sag: np.ndarray) -> np.ndarray:
    """`edge_sag` (F, 4) with the facets of each split facet fitted as its polygon
    (`segment.Refinement.polygons`, issue 34) given the polygon's own sags: the sags of the
    edges of its triangles from the corner normals at their nodes. The polygon is the
    polyhedron's facet; its pieces' edges, half as long and bending half as much, would
    bound the smooth surface (fitted as if they were not cut) by their own sag, a quarter
    of the facet's: the guard took some 90% of a refined icosphere's answers. Each piece's
    first edge gets the polygon's largest bulge, its second its deepest hollow (its bulge
    again where it has none), the others the bulge: the guard's ring pass takes the largest
    of each over the facets around a foot."""
    r = surf.refinement
    if not r.polygons:
        return edge_sag
    out = edge_sag.copy()
    n = np.int64(len(surf.nodes))
    # each node's normal in a split facet: its corner's in any of the facet's pieces, found
    # by (group, node) among the pieces' corners
    rows = np.flatnonzero(r.replaced)
    real = surf.corners[rows] >= 0
    at = (r.group[rows][:, None] * n + surf.key[np.maximum(surf.corners[rows], 0)])[real]
    normal = surf.corner_normal[rows][real]
    order = np.argsort(at, kind="stable")
    at, normal = at[order], normal[order]
    groups = np.fromiter(r.polygons, dtype=np.int64, count=len(r.polygons))
    tri = [r.polygons[g] for g in groups]
    owner = np.repeat(groups, [len(t) for t in tri])
    tri = np.concatenate(tri)
    a, b = tri.ravel(), np.roll(tri, -1, axis=1).ravel()
    g = np.repeat(owner, 3)
    na = normal[np.searchsorted(at, g * n + surf.key[a])]
    nb = normal[np.searchsorted(at, g * n + surf.key[b])]
    sag = np.einsum("ij,ij->i", nb - na, surf.nodes[b] - surf.nodes[a]) / 8
    rank = np.argsort(groups)  # a group's row among `groups`

    def index(of):
        return rank[np.searchsorted(groups[rank], of)]

    bulge = np.zeros(len(groups))
    hollow = np.zeros(len(groups))
    np.maximum.at(bulge, index(g), sag)
    np.minimum.at(hollow, index(g), sag)
    place = index(r.group[rows])
    out[rows, :] = bulge[place][:, None]
    out[rows, 1] = np.where(hollow[place] < 0, hollow[place], bulge[place])
    return out


def _next_corner(kind: np.ndarray) -> np.ndarray:
    """(F, 4) the corner at the end of each facet edge: edge j runs from corner j to this."""
    return np.where(np.arange(4)[None] + 1 < kind[:, None], np.arange(1, 5)[None] % 4, 0)


def guard_bounds(surf: PatchedSurface):
    """The guard's bounds at each facet f (method.md, "The facets bound the smooth surface").

    Where the facets approximate a smooth surface, that surface lies within their chordal sag
    of them: an edge of length L departs from a surface of normal curvature κ_e along it by
    L² κ_e / 8 at its middle, and L κ_e is the difference of its ends' normals along it
    (`corner_normals`; over a second-order facet, its mid-side nodes give each edge's sag,
    `midside_sags`); the sag of a facet follows from its edges' (`_guard.facet_sag`). Edge by
    edge, the sag follows the bending of a sliver along its length and not across it, which
    dihedral angles alone miss (parallel slivers along a curved face meet at no angle), and
    a sliver's long diagonal across a cylinder counts the arc it spans as it projects on the
    diagonal (by cos² of the angle between them), not as the turn of the normals. An edge
    that does not resolve its surface (a fillet under one facet, its ends' normals 90° apart)
    counts its whole bend: the diffuse surface there departs from the facets as far as the
    arc does.

    A diffuse answer whose faceted foot is on f may differ from the facets' gap by no more
    than `tol.GUARD_SAG_MARGIN` times the largest sag of the facets sharing a node with f (the
    foot's neighbourhood) plus `tol.GUARD_FLOOR` node spacings (round-off), and its normal
    from f's by no more than `tol.GUARD_NORMAL_MARGIN` times the largest angle between f's
    normal and the corner normals of those of these facets that meet f below the feature
    angle (its smooth neighbourhood; in one CAD face, or one smooth region holding a coarse
    curve's bend, `coarse_bend`, all), plus `tol.GUARD_NORMAL_FLOOR_DEG`,
    plus the turn of the surface between the answer's proximal point and the faceted foot:
    their distance times the largest curvature the facets around f show (an edge's bend over
    its length). A point deep inside a small hole or boss has its proximal point and its
    faceted foot a fraction of a node spacing apart, where the normals differ by more than
    the spread around one facet (linkrods o2-tags of `benchmarks/real_parts.py`: 410 of the
    412 answers the guard took without it were the nearer to the CAD; `tests/test_guard.py`,
    a second-order fillet box).
    Measured on smooth targets (spheres, tori, cylinders, a saddle, gmsh spheres of first and
    second order, `tests/test_guard.py`): the facets' own error is at most 1.5 sags, a diffuse
    answer differs from the facets by at most 1.6 sags where it is the more accurate (1.7 on
    a cylinder of 6 facets around), its normal by at most 0.7 of the angle; on a torus of 8
    facets around, where the diffuse surface is 4x further from the torus than the facets,
    by up to 6 sags.

    On the side the facets do not bend, the answer may depart by only
    `tol.GUARD_OTHER_SIDE` of their sag: facets bending toward their normal (convex) lie
    under the smooth surface they interpolate, so a diffuse surface sinking under them is no
    smoothing of them (the other way round where they bend away; both where they bend both
    ways, a saddle). The sides come from the signed edge sags of the facets of f's own patch
    sharing a node with f; where f touches an open boundary, both sides get the envelope.

    Returns
    -------
    gap_bound : (F,) float      the envelope: |g - g_f| <= gap_bound
    gap_lo, gap_hi : (F,) float the side: gap_lo <= g - g_f <= gap_hi (within the envelope)
    normal_angle : (F,) float   radians
    normal_turn : (F,) float    radians per length: the largest |bend| / length of the edges
                                of the facets sharing a node with f
    """
    F = len(surf.corners)
    length, bend = surf.edge_length, surf.edge_bend
    edge_sag = _split_sags(surf, midside_sags(surf, length * bend / 8))    # signed
    # One compiled pass over each facet's vertex ring (`_guard.ring_tables`; bit for bit the
    # former numpy's, tests/reference_guard.py), no ring-sized temporary: the largest sags
    # (envelope; bulge and hollow over the ring's facets of f's own patch), the largest
    # turn, the least cosine between f's normal and its smooth neighbours' corner normals,
    # and whether f touches an open edge.
    limit = 180.0 if surf.feature_angle is None else min(surf.feature_angle, 180.0)
    tags = _tag_ids(surf.tags) if surf.smooth_tags else np.zeros(0, np.int64)
    smooth_tags = surf.smooth_tags
    if not smooth_tags and surf.coarse_bend is not None and limit < 180:
        # a coarse smooth curve (`coarse_bend`): its facets are each other's smooth
        # neighbours whatever their angle, as one CAD face's (and as under one patch)
        tags, smooth_tags = _curve_regions(surf), True
    ring = surf.ring
    envelope, bulge, hollow, normal_turn, cos_min, at_open = _guard.ring_tables(
        ring.indptr, ring.indices, _int64(surf.corners), _int64(surf.kind),
        _int64(surf.label), np.ascontiguousarray(surf.edge_class, np.int8), _float64(edge_sag),
        _float64(length), _float64(bend), _float64(surf.corner_normal),
        _float64(surf.facet_normal), tags, smooth_tags, np.cos(np.radians(limit)),
        _int64(surf.key), OPEN_EDGE)
    h = surf.node_spacing[surf.corners[:, 0]]
    floor = tol.GUARD_FLOOR * h
    gap_bound = tol.GUARD_SAG_MARGIN * envelope + floor
    # The side: a surface that the facets interpolate bulges past them toward their normal
    # where they bend that way (convex), lowering the gap of a point in front of them, and
    # sinks under them where they bend away (concave), raising it. From the facets of f's own
    # patch around it, whose nodes the patch's surface is fitted to (a concave fillet of the
    # next patch does not let this one sink); a crease's or an open edge's bend along itself
    # is no bend of either face (its ends' normals are a corner's).
    if surf.flip:  # in the gap's own direction: the facets' normal's opposite
        bulge, hollow = hollow, bulge
    m, r = tol.GUARD_SAG_MARGIN, tol.GUARD_OTHER_SIDE
    gap_lo = -(m * bulge + r * hollow) - floor
    gap_hi = m * hollow + r * bulge + floor
    # ... but not where the foot may lie on an open boundary: past it, the facets' gap is the
    # distance to the boundary's edge, which the surface continued past it (a diffuse answer)
    # undercuts whatever its bend. There, the envelope on either side.
    at_open = at_open.view(bool)
    gap_lo = np.where(at_open, -gap_bound, gap_lo)
    gap_hi = np.where(at_open, gap_bound, gap_hi)
    # the spread of the normals around f: f's normal against the corner normals of its
    # smooth neighbours (those meeting it below the feature angle; in one CAD face, any),
    # the arccos of the least cosine (arccos decreases: the largest of the angles)
    spread = np.zeros(F)
    some = cos_min <= 1.0
    spread[some] = np.arccos(cos_min[some])
    normal_angle = tol.GUARD_NORMAL_MARGIN * spread + np.radians(tol.GUARD_NORMAL_FLOOR_DEG)
    # normal_turn is a row of the ring pass's (4, F) block: a copy of its own, so that the
    # block's other rows (the sags, used above) are freed
    return gap_bound, gap_lo, gap_hi, normal_angle, normal_turn.copy()


#: The monomials a^i b^j of a second-order cell's geometry (`cell_coefficients`), in order:
#: the compiled pass's own table (`_cells.pxd`).
CELL_MONOMIALS = _cells.CELL_MONOMIALS
#: The parameters (a, b) of each node of a second-order cell, in the facets' own parameters
#: (a triangle's corners (0, 0), (1, 0), (0, 1); a quad's the unit square's), by node count:
#: corners, then the mid-side nodes of edges 01, 12, 20 (23, 30), then a triangle7's or a
#: quad9's centre.
CELL_NODES = {
    6: ((0, 0), (1, 0), (0, 1), (.5, 0), (.5, .5), (0, .5)),
    7: ((0, 0), (1, 0), (0, 1), (.5, 0), (.5, .5), (0, .5), (1 / 3, 1 / 3)),
    8: ((0, 0), (1, 0), (1, 1), (0, 1), (.5, 0), (1, .5), (.5, 1), (0, .5)),
    9: ((0, 0), (1, 0), (1, 1), (0, 1), (.5, 0), (1, .5), (.5, 1), (0, .5), (.5, .5)),
}


def cell_shape(k: int) -> np.ndarray:
    """(9, k) W: the monomial coefficients (`CELL_MONOMIALS`) of the shape functions of a
    cell of k nodes (`CELL_NODES`), so that a cell of nodes X is x(a, b) = Σ_m a^i b^j (W X)_m.
    Its space: the first k monomials (triangle6, quad8, quad9); a triangle7's, the quadratics
    and the bubble a b (1 - a - b) = ab - a²b - ab²."""
    basis = np.zeros((9, k))               # each basis function's monomial coefficients
    if k == 7:
        basis[:6, :6] = np.eye(6)
        basis[[4, 6, 7], 6] = 1.0, -1.0, -1.0
    else:
        basis[:k, :k] = np.eye(k)
    mono = np.array([[a ** i * b ** j for i, j in CELL_MONOMIALS] for a, b in CELL_NODES[k]])
    return basis @ np.linalg.inv(mono @ basis)


def cell_coefficients(surf: PatchedSurface):
    """The curved cells of a target, for the pass's `cells_answer`: x(a, b) = sum_k a^i b^j
    coef[f, k] over `CELL_MONOMIALS`, a cell's own shape functions in the parameters of its
    corner facet (`cell_shape` times its nodes).

    A second-order cell (triangle6, triangle7, quad8, quad9) is its own nodes'. A first-order
    facet is curved through its corners' normals (`corner_normal`, its smooth region's): each edge
    x0 -> x1 gets the mid-side node of the cubic Hermite curve whose end tangents are the
    edge's projection on each end's tangent plane, (x0 + x1) / 2 + (T0 - T1) / 8 with
    |T| = the edge's length (a circular arc of chord L and turn φ: L φ / 8 off the chord,
    its sag, to O(φ³)); one edge's mid-side node is the same from both of its facets within
    a smooth region (conforming there). A facet whose edges are all straight so (a flat
    face) has no cell: its facets answer, as exactly.

    Returns
    -------
    has_cell : (F,) int8       1 where facet f has a curved cell
    coef : (F, 9, 3) float     zero past a cell's monomials; (1, 9, 3) zeros where the
                               target has no curved cell
    """
    # Built with the surface (and again by `moved`), for every facet: the pass reads the cell
    # of each facet of the faceted foot's vertex ring wherever the facets would answer (the
    # guard, a patch that cannot answer, a strip: `_pass.cells_answer`), which the
    # contactors decide, so any facet may be asked. Sized to the scene: where no facet is
    # curved (flat faces only) no (F, 9, 3) table, one row of zeros. The compiled pass
    # (`_cells`) computes each facet's mid-side nodes and coefficients in place, no (F, 4, 3)
    # temporaries; its numbers are the former numpy code's bit for bit
    # (tests/reference_cells_setup.py).
    F = len(surf.corners)
    has = np.zeros(F, np.int8)
    coef = np.zeros((F, 9, 3))      # zero pages, written only where a cell is curved
    nodes = np.ascontiguousarray(surf.nodes, dtype=np.float64)
    first_order = any(f.shape[1] in (3, 4) for f in surf.faces)
    if first_order:
        normals = np.ascontiguousarray(_crease_normals(surf), dtype=np.float64)
        corners = np.ascontiguousarray(surf.corners, dtype=np.int64)
        length = np.ascontiguousarray(surf.edge_length, dtype=np.float64)
    start = 0
    for f in surf.faces:
        k = f.shape[1]
        if k in CELL_NODES:                     # a second-order cell: its own nodes
            _cells.node_cells(nodes, np.ascontiguousarray(f, dtype=np.int64), cell_shape(k),
                              start, has, coef)
        else:                                   # a first-order facet, curved by its normals
            _cells.facet_cells(nodes, corners, k, normals, length, cell_shape(2 * k), start,
                               start + len(f), has, coef)
        start += len(f)
    if not has.any():
        return has, np.zeros((1, 9, 3))
    return has, coef


def _expand_normals(index: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(f, 4, 3) the corner normals of a compacted table (`_pass.compact_normals`): row
    index[f, j] of the table, zero where index is -1 (a triangle's fourth corner)."""
    out = table[np.maximum(index, 0)]
    out[index < 0] = 0.0
    return out


def _edge_lengths(nodes: np.ndarray, corners: np.ndarray, kind: np.ndarray) -> np.ndarray:
    """(f, 4) each facet edge's length as `corner_normals` measures it (`_guard.corner_tables`:
    sqrt((x² + y²) + z²) of corner j + 1 less corner j, 0 past the last corner), bit for
    bit: each product and sum its own rounding, as there."""
    out = np.zeros((len(corners), 4))
    rows = np.arange(len(corners))
    for j in range(4):
        real = corners[:, j] >= 0
        nxt = np.where(j + 1 < kind, (j + 1) % 4, 0)
        end = corners[rows, nxt]
        d = nodes[np.where(end > 0, end, 0)] - nodes[np.maximum(corners[:, j], 0)]
        length = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
        out[:, j] = np.where(real, length, 0.0)
    return out


def cell_tables(surf: PatchedSurface):
    """The curved cells as the surface keeps them (issue 36: tables sized to the scene):
    has_cell (F,) int8 (`cell_coefficients`'), the (F, 9, 3) coefficient table only where
    the target has second-order cells (None else), and the corner normals a first-order
    facet's cell follows (`_crease_normals`; None where no facet is curved): the compiled
    pass computes such a cell where it needs it (`_pass.cell_of`), `cell_rows` too, the
    table's own bits. A first-order target's coefficients would be 432 bytes a node.

    Returns has_cell, table, normals."""
    if any(f.shape[1] in CELL_NODES for f in surf.faces):
        has, coef = cell_coefficients(surf)
        return has, (coef if has.any() else None), None
    # first-order facets only: which are curved (`_cells.facet_curved`: `facet_cells`' own
    # test, edge by edge up to the first curved one, no coefficients computed)
    F = len(surf.corners)
    has = np.zeros(F, np.int8)
    nodes = _float64(surf.nodes)
    normals = _float64(_crease_normals(surf))
    corners, length = _int64(surf.corners), _float64(surf.edge_length)
    start = 0
    for f in surf.faces:
        _cells.facet_curved(nodes, corners, f.shape[1], normals, length, start,
                            start + len(f), has)
        start += len(f)
    if not has.any():
        return has, None, None
    return has, None, normals


def hermite_midsides(surf: PatchedSurface) -> np.ndarray:
    """(F, 4, 3) the mid-side node of each facet edge's cubic Hermite curve through its ends
    with the ends' corner normals (`cell_coefficients`); an edge whose end normal lies along
    it (a degenerate normal) keeps its straight tangent there."""
    return _cells.midsides(np.ascontiguousarray(surf.nodes, dtype=np.float64),
                           np.ascontiguousarray(surf.corners, dtype=np.int64),
                           np.ascontiguousarray(surf.kind, dtype=np.int64),
                           np.ascontiguousarray(_crease_normals(surf), dtype=np.float64))


def _bends_and_creases(nodes, faces, key, edges, area, angle):
    """(coarse_bend, cad_crease), each (m,) bool over the manifold edges or None where there
    is none: the bends of coarse smooth curves sharper than `angle` (degrees), no creases
    (`segment.coarse_bends`), and the creases of the CAD below it (`segment.cad_creases`,
    given those bends); the edges' facets and cosines read once for both."""
    fa, fb = _segment._two_facets(edges)
    cos = _edges.segment_cosines(_float64(area), fa, fb)
    limit = np.cos(np.radians(angle))
    bends = _segment.coarse_bends(nodes, faces, key, edges, area, fa, fb, cos, limit)
    crease = _segment.cad_creases(nodes, faces, key, edges, area, fa, fb, cos, limit, bends)
    return (bends if bends.any() else None), (crease if crease.any() else None)


def _crease_normals(surf: PatchedSurface) -> np.ndarray:
    """(F, 4, 3) the corner normals the curved facets follow: the smooth regions' own
    (`corner_normal`), split also at every edge sharper than the default feature angle
    (`segment.FEATURE_ANGLE_DEG`; inside one CAD face, none) when the surface was built with
    a wider one (180, None: one patch over a box). A box's edge is a crease of its mesh
    whatever its patches: its faces stay flat. A coarse smooth curve's bend is none
    (`coarse_bend`, `segment.creases`): a tube of 8 facets around stays round."""
    limit = _segment.FEATURE_ANGLE_DEG
    if surf.feature_angle is not None and surf.feature_angle <= limit:
        return surf.corner_normal
    a, b = surf.edge_facets.T
    cos = np.einsum("ij,ij->i", surf.facet_normal[a], surf.facet_normal[b])
    crease = cos < np.cos(np.radians(limit))
    if surf.coarse_bend is not None:
        crease &= ~surf.coarse_bend
    if surf.cad_crease is not None:  # a crease of the CAD below the feature angle
        crease |= surf.cad_crease
    if surf.smooth_tags:
        crease &= surf.tags[a] != surf.tags[b]
    if np.array_equal(crease, surf.edge_sharp):
        # the creases split the smooth regions no further (a smooth target, no edge past the
        # default feature angle): its corner normals are the regions' own, bit for bit
        return surf.corner_normal
    split = copy.copy(surf)
    split.smooth_region = _regions(len(surf.corners), surf.edge_facets[~crease])
    return corner_normals(split)[0]


def _regions(F: int, joined: np.ndarray) -> np.ndarray:
    """(F,) the connected groups of F facets joined across the edges `joined` (e, 2): the
    two facets of each."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    a, b = joined.T
    graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(F, F))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def midside_sags(surf: PatchedSurface, estimate: np.ndarray) -> np.ndarray:
    """(F, 4) each facet edge's signed sag, positive where the surface bulges toward the
    facet's normal: over a second-order facet, its mid-side node's distance from the edge's
    middle (the cell's own curve departs from the edge by that much there), signed by its
    side of the facet; else `estimate` (from the corner normals, signed): `estimate` itself
    where no facet is of second order (no copy), a copy else."""
    if not any(f.shape[1] >= 2 * _frame.CORNERS[f.shape[1]] for f in surf.faces):
        return estimate
    sags, start = estimate.copy(), 0
    for f in surf.faces:
        k = _frame.CORNERS[f.shape[1]]
        if f.shape[1] >= 2 * k:                         # triangle6/7, quad8/9
            rows = slice(start, start + len(f))
            ends = f[:, (np.arange(k) + 1) % k]
            middle = 0.5 * (surf.nodes[f[:, :k]] + surf.nodes[ends])
            off = surf.nodes[f[:, k:2 * k]] - middle
            side = np.einsum("fkj,fj->fk", off, surf.facet_normal[rows])
            sags[rows, :k] = np.linalg.norm(off, axis=2) * np.where(side < 0, -1.0, 1.0)
        start += len(f)
    return sags


def support_floor(surf: PatchedSurface) -> np.ndarray:
    """(F,) the least local spacing of a facet's patch over it (issue 19, item 2): over a
    quad, `tol.SUPPORT_FACET_FRACTION` of its longest edge (its nearest nodes are across it:
    their support is one row, whose reduced basis cannot see the bending along the quad, and
    whose hull leaves the points between rows off the target), of its longest edge's half
    over a second-order quad (a node every half edge: quad8, quad9); 0 over a triangle."""
    quads = surf.kind == 4
    if not quads.any():  # triangles only: no edge's length is read (an (F, 4) max, 20 ms
        return np.zeros(len(quads))  # at 163k nodes), the same zeros
    nodes_per_edge = np.concatenate([np.full(len(f), 2 if f.shape[1] > 4 else 1)
                                     for f in surf.faces])
    return np.where(quads, tol.SUPPORT_FACET_FRACTION * surf.edge_length.max(axis=1)
                    / nodes_per_edge, 0.0)


def _int64(a) -> np.ndarray:
    """a as a contiguous int64 array (the compiled passes' indices; no copy where it is)."""
    return np.ascontiguousarray(a, dtype=np.int64)


def _int32(a) -> np.ndarray:
    """a (indices) as a contiguous int32 array, where every value fits (ValueError else: a
    target of some 500M facets)."""
    a = np.asarray(a)
    if a.dtype != np.int32 and a.size and not (-2 ** 31 <= a.min() and a.max() < 2 ** 31):
        raise ValueError("the target's tables exceed int32 indices")
    return np.ascontiguousarray(a, dtype=np.int32)


def _float64(a) -> np.ndarray:
    """a as a contiguous float64 array (no copy where it is)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def _curve_regions(surf: PatchedSurface) -> np.ndarray:
    """(F,) int64 equal where two facets are in one smooth region holding a coarse smooth
    curve's bend (`coarse_bend`); every other facet its own (`guard_bounds`)."""
    region = surf.smooth_region
    R, F = int(region.max()) + 1, len(region)
    has = np.zeros(R, bool)
    has[region[surf.edge_facets[surf.coarse_bend, 0]]] = True
    return np.where(has[region], region, R + np.arange(F, dtype=np.int64))


def _tag_ids(tags: np.ndarray) -> np.ndarray:
    """(F,) int64 equal where the facets' tags are equal (`guard_bounds`: a CAD face's
    facets are each other's smooth neighbours): the tags themselves where int64 holds them,
    else their rank (a NaN tag equal to none)."""
    tags = np.asarray(tags).reshape(-1)
    if tags.dtype.kind == "b" or (tags.dtype.kind in "iu" and tags.dtype.itemsize < 8) \
            or tags.dtype == np.int64:
        return _int64(tags)
    return np.unique(tags, return_inverse=True, equal_nan=False)[1].reshape(-1).astype(np.int64)



def _diffuse(nodes, faces, flip, options, shared=None):
    """A patch's DiffuseSurface; where its distinct nodes are fewer than the basis's terms, the
    largest basis they determine (down to the plane of one facet); None where not even that
    (its facets answer it). Other errors (options) are the caller's. `shared`: the nodes'
    `facet.surface.SharedNodes`, when the caller has measured them."""
    from ..nodes import SharedNodes

    shared = SharedNodes.of(nodes, shared)
    opts = _fewer_terms(options, nodes, len(shared.distinct))
    if opts is None:
        return None
    try:
        return DiffuseSurface(nodes, faces, flip=flip, check_winding=False, shared=shared,
                              **opts)
    except ValueError:
        if opts is options:
            raise
        return None


def _fewer_terms(options, nodes, distinct=None):
    """`options` itself where the distinct nodes determine its basis; else with the largest
    basis they determine (the plane: 3 nodes); None if not even that. `distinct`: their
    number, when the caller has it."""
    from ..mls import basis as _basis

    asked = options.get("basis", "quadratic")
    n = len(np.unique(np.asarray(nodes), axis=0)) if distinct is None else int(distinct)
    if n >= _basis.size(asked):
        return options
    for name in ("quadratic", "linear"):
        if _basis.size(name) <= n:
            opts = dict(options, basis=name)
            if opts.get("support") == "knn":
                opts["k"] = min(n, max(int(opts.get("k") or 0), 3 * _basis.size(name)))
            return opts
    return None


def _flat(nodes, faces) -> bool:
    """Whether a patch is flat: every facet within `tol.FLAT_PATCH_DEG` of its mean plane."""
    _, axes = _frame.mean_plane(nodes)
    area = _frame.facet_area_vectors(nodes, faces)
    n = _unit_rows(area)
    return bool(np.min(np.abs(n @ axes[2])) >= np.cos(np.radians(tol.FLAT_PATCH_DEG)))


def _ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a / b where b > 0, else 0 (broadcast): scale-free, where a floor on b (1e-300) would
    overflow a / b for a target 1e9 in size wherever b is 0 and a is not."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return np.divide(a, b, out=np.zeros(a.shape), where=b > 0)


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """Rows of v scaled to unit length; zero rows (a degenerate facet) stay zero. Rows of
    three (area vectors): their norms column by column (`nodes.row_norms`, np.linalg.norm's
    bits, without its reduction along the short axis: 6 ms at 163k nodes)."""
    if np.ndim(v) == 2 and np.shape(v)[1] == 3:
        from ..nodes import row_norms

        return _ratio(v, row_norms(v)[:, None])
    return _ratio(v, np.linalg.norm(v, axis=-1, keepdims=True))
