"""Segmentation of a target into smooth patches (method.md "Real targets: patches").

Facets are in one patch when they share an edge that is no crease (its dihedral angle,
between the facet normals, below the feature angle, or the bend of a coarse smooth curve:
`creases`) and carry the same face or region tag (a Gmsh entity, a
physical group, a cell set) where the file has tags, and neither or both are on one flat face
(so a file without tags, an STL, still gets its flat faces exact, apart from the fillets they
meet tangentially). An edge of one facet (an open boundary), or of more than two (a T
junction), joins nothing. Facets are taken by their corners (higher-order cells:
`frame.facet_corners`); the node identity, the edges and the groups of facets come from
linear compiled passes (`_topology.pyx`), the rest is numpy.
"""
from __future__ import annotations

from math import sqrt
from typing import NamedTuple

import numpy as np

from .. import tol
from ..mls import frame as _frame
from . import _edges, _topology

#: Default feature angle, degrees: edges whose facets' normals differ by more split patches.
#: Measured (`python benchmarks/feature_targets.py --angles`): the largest facet-to-facet
#: angle of smooth targets is 11.3° (sample cylinder), 23.4° (sample torus), 22.1° (gmsh
#: sphere at 2 elements per radius), 25.2° (side of a gmsh cylinder at 1.7 elements per
#: radius); CAD edges are 45° (chamfers) to 90° (boxes) and more. 40° sits between, with room
#: for coarser curved meshes (a cylinder of 9 facets around meets at 40°); coarser still (8
#: facets around, 45°), the pattern of the bends tells a curve from a crease (`creases`).
FEATURE_ANGLE_DEG = 40.0


class Edges(NamedTuple):
    """The facet edges of a target (`edge_table`): every corner edge of every facet (a
    half-edge), by facet, local edge and edge; computed once and shared by the winding check,
    the segmentation and the edges' classes."""

    fac: np.ndarray      # (e,) facet of each half-edge
    loc: np.ndarray      # (e,) its local edge j: from corner j to corner j + 1
    edge: np.ndarray     # (e,) its edge: edges numbered by their ends' (smaller, larger) identity
    ne: int              # the number of distinct edges
    order: np.ndarray    # (e,) the half-edges by edge, stable (argsort(edge, kind="stable"))
    start: np.ndarray    # (ne + 1,) edge i's half-edges are order[start[i]:start[i + 1]]
    ends: np.ndarray     # (ne, 2) its ends' identities, smaller first
    forward: np.ndarray  # (e,) int8: the half-edge runs from the smaller identity to the larger


class FacetRing(NamedTuple):
    """The vertex ring of each facet (`PatchedSurface.ring`): the facets sharing a node with
    it, itself included, as CSR rows sorted within (the compiled pass's fring_ptr, fring)."""

    indptr: np.ndarray   # (F + 1,) int32
    indices: np.ndarray  # int32


def edge_table(faces: list[np.ndarray], node_key: np.ndarray) -> Edges:
    """The facet edges (`Edges`) of facet blocks `faces` (facets numbered block after block,
    taken by their corners), `node_key` mapping nodes to their identity (coincident nodes
    share one): one compiled pass and two counting sorts, linear in the facets."""
    blocks = [np.ascontiguousarray(_frame.facet_corners(f), dtype=np.int64) for f in faces]
    return Edges(*_topology.edge_table(blocks, np.ascontiguousarray(node_key, dtype=np.int64)))


def facet_edges(faces: list[np.ndarray], node_key: np.ndarray):
    """Every corner edge of every facet: (facet (e,), local edge j (e,), edge id (e,), number
    of distinct edges). Edge j runs from corner j to corner j + 1; `node_key` maps nodes to
    their identity (coincident nodes share one), so an edge is one pair of identities,
    numbered in the order of (smaller, larger) identity (`edge_table`)."""
    t = edge_table(faces, node_key)
    return t.fac, t.loc, t.edge, t.ne


def node_identity(nodes: np.ndarray) -> np.ndarray:
    """(n,) the first node at each node's position: coincident nodes are one node (a hash
    over the coordinates, linear; -0.0 is 0.0, a node with a NaN coordinate is its own)."""
    nodes = np.ascontiguousarray(nodes, dtype=np.float64)
    if nodes.ndim != 2 or nodes.shape[1] != 3:
        raise ValueError(f"node_identity: nodes of shape {nodes.shape}, expected (n, 3)")
    return _topology.node_identity(nodes)


def segment(nodes, faces, feature_angle: float = FEATURE_ANGLE_DEG, tags=None,
            flat_faces: bool = True, smooth_tags: bool = False, *, key=None,
            edges: Edges | None = None, area: np.ndarray | None = None,
            refinement: Refinement | None = None, bends: np.ndarray | None = None) -> np.ndarray:
    """Patch label of each facet, (f,) int, labels 0..P-1 in order of first facet.

    Parameters
    ----------
    nodes : (n, 3) float
    faces : list of (f_b, k) int
        Facet blocks (corners first), indexing `nodes`; facets are numbered block after block.
    feature_angle : float
        Degrees; an edge whose two facets' normals differ by more splits them where it is a
        crease (`creases`: not where it is a bend of a coarse smooth curve). 180 or more:
        only tags and open or non-manifold edges split.
    tags : (f,) int, optional
        Face or region tag of each facet: facets of different tags are never joined.
    flat_faces : bool
        Split flat faces from what they meet, even tangentially (a face and its fillet in a
        file without face tags: an STL): `_flat_faces`.
    smooth_tags : bool
        The tags are CAD faces (Gmsh geometrical entities), smooth inside: facets of one tag
        are joined whatever their angle (a coarse fillet's facets meet at more than the
        feature angle, yet are no feature).
    key, edges, area : optional
        The nodes' identity (`node_identity`), the facet edges (`edge_table` of `faces` by
        `key`) and the facets' area vectors (`frame.facet_area_vectors` of `nodes` and
        `faces`) where the caller has them already (`PatchedSurface`): computed otherwise.
    refinement : Refinement, optional
        The target's split facets (`geometry_free`): never flat faces (issue 34).
    bends : (m,) bool, optional
        The manifold edges (`_two_facets`' order) past the feature angle that are bends of a
        coarse smooth curve (`coarse_bends`), where the caller has them.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        faces = [faces]
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    nf = sum(len(f) for f in faces)
    if nf == 0:
        return np.zeros(0, np.int64)
    if key is None:
        key = node_identity(nodes)
    if edges is None:
        edges = edge_table(faces, key)
    # manifold edges: exactly two facets (by edge, the first two half-edges' facets)
    fa, fb = _two_facets(edges)
    join = fa != fb
    if tags is not None:
        tags = np.asarray(tags).reshape(-1)
        if len(tags) != nf:
            raise ValueError(f"{len(tags)} facet tags for {nf} facets")
    # the cosine across each manifold edge of the facets' unit normals (each area vector
    # scaled by its largest component, then by its norm): the feature angle's and the flat
    # faces' test, in one compiled pass (`_edges.segment_cosines`, numpy's values bit for bit)
    cos = None
    if feature_angle < 180 or flat_faces:
        if area is None:
            area = _frame.facet_area_vectors(nodes, faces)
        cos = _edges.segment_cosines(np.ascontiguousarray(area, dtype=np.float64), fa, fb)
    if feature_angle < 180:
        limit = np.cos(np.radians(feature_angle))
        if bends is None:
            bends = coarse_bends(nodes, faces, key, edges, area, fa, fb, cos, limit)
        smooth = (cos >= limit) | bends   # no crease (`creases`)
        if smooth_tags and tags is not None:
            smooth |= tags[fa] == tags[fb]
        join &= smooth
    if tags is not None:
        join &= tags[fa] == tags[fb]
    if flat_faces:
        flat = _flat_faces(nodes, faces, fa, fb, nf, key, edges, cos)
        if refinement is not None:  # a facet cut in pieces is no flat face
            flat[refinement.split[refinement.group]] = -1
        join &= flat[fa] == flat[fb]
    # the patches: groups of facets joined, numbered in order of their first facet
    return components(nf, fa[join], fb[join])


def creases(nodes, faces, feature_angle: float = FEATURE_ANGLE_DEG, *, key=None,
            edges: Edges | None = None, area: np.ndarray | None = None) -> np.ndarray:
    """(ne,) bool over the edge table (`edge_table`): the creases, the manifold edges whose
    two facets' normals differ by more than `feature_angle` (degrees) and that are no bend of
    a coarse smooth curve (`coarse_bends`). Open and non-manifold edges are no creases (they
    are edges of their own class, and split patches whatever their angle).

    The rule (issue 35): a box's edge turns 90° between two flat faces; a tube of 8 facets
    around turns 45° at every edge, uniformly. The dihedral angle alone cannot tell them
    apart, its pattern can: an edge past the feature angle is a crease unless it turns by at
    most `tol.CURVE_MAX_DEG` and the facets on either side of it turn too, across themselves
    and about its line, by a comparable angle in the same sense (`tol.CURVE_RATIO`). A flat
    side (a box, a chamfer or a fillet meeting a flat face, a thin wall, a cap's rim) turns
    by nothing: a crease.

    key, edges, area: the nodes' identity, the facet edges and the facets' area vectors
    where the caller has them (computed otherwise).
    """
    nodes, faces, key, edges, area = _tables(nodes, faces, key, edges, area)
    out = np.zeros(edges.ne, bool)
    if edges.ne == 0:
        return out
    fa, fb = _two_facets(edges)
    cos = _edges.segment_cosines(_f64(area), fa, fb)
    limit = np.cos(np.radians(feature_angle))
    bends = coarse_bends(nodes, faces, key, edges, area, fa, fb, cos, limit)
    out[np.diff(edges.start) == 2] = (cos < limit) & ~bends
    return out


def coarse_bends(nodes, faces, key, edges: Edges, area, fa, fb, cos, limit) -> np.ndarray:
    """(m,) bool over the manifold edges (fa, fb: `_two_facets`; cos: their normals'
    cosine): the edges sharper than the cosine `limit` that are bends of a coarse smooth
    curve, no creases (`creases`: the rule; `bend_pattern`: the turns it reads)."""
    out = np.zeros(len(fa), bool)
    lo, hi = tol.CURVE_RATIO
    some = (cos < limit) & (cos >= np.cos(np.radians(tol.CURVE_MAX_DEG)))
    if not some.any():
        return out
    which = np.flatnonzero(some)
    _, side_a, side_b = bend_pattern(nodes, faces, key, edges, area, fa[which], fb[which],
                                     np.flatnonzero(np.diff(edges.start) == 2)[which],
                                     units=facet_units(len(area), fa, fb, cos, area))
    out[which] = ((side_a >= lo) & (side_a <= hi)).any(axis=1) & (
        (side_b >= lo) & (side_b <= hi)).any(axis=1)
    return out


def bend_pattern(nodes, faces, key, edges: Edges, area, fa, fb, which, units=None,
                 own_side=False, cut=None):
    """The bends read by the crease rule (`creases`) at the manifold edges `which` (indices
    into the edge table) of facets fa, fb: (theta (m,): each edge's angle, radians, the turn
    from fa's normal to fb's about the edge's line; side_a, side_b (m, k): the turn from
    each facet of fa's vertex ring to fa, and from fb to each facet of fb's ring, about the
    same line, over |theta| signed by it (1: the same turn in the same sense), NaN past a
    ring's end and where a facet's normal runs along the line (`tol.CURVE_AXIS_MIN`)).

    On a coarse tube, the facets before fa turn into it as fa turns into fb (about 1 on
    both sides); on a box, fa's own face does not turn (0; fb's ring turns the other way,
    negative). `units` (F,), optional: the polyhedron's facet of each facet (`facet_units`);
    where the units of fa and fb are alike (their areas within `SPLIT_AREA_RATIO` of each
    other: a coarse curve's facets, cut in pieces or not), a facet's ring is its unit's, the
    facets at any node of it, one a unit. Elsewhere (a flat face meeting a chamfer's strip)
    the facets' own: a face's far side is no neighbour of its edge. `own_side`: only the
    ring's facets on the side of the edge's line of its own facet (their centroids, across
    the line, on its side), NaN for the others (those across the edge). `cut` (m,) bool over
    the manifold edges (`_two_facets`' order), optional: the creases that bound a side, NaN
    for the facets at an end of the edge that lie past one from its own facet there (not in
    its fan: `corner_fans`)."""
    unit = area / np.maximum(np.linalg.norm(area, axis=1), tol.TINY)[:, None]
    ends = edges.ends[which]
    line = _unit(nodes[ends[:, 1]] - nodes[ends[:, 0]])
    na, nb = _unit(_across(unit[fa], line)), _unit(_across(unit[fb], line))
    theta = _turn(na, nb, line)
    sense = np.where(theta < 0, -1.0, 1.0) / np.maximum(np.abs(theta), tol.TINY)
    corners = np.concatenate([_pad4(_frame.facet_corners(f)) for f in faces])
    keyc = np.where(corners >= 0, key[np.maximum(corners, 0)], -1)
    ptr, fac = _node_facets(keyc, len(key))
    fans = None
    if cut is not None:
        a, b = _two_facets(edges)
        fans = corner_fans(keyc, a, b, edges.ends[np.diff(edges.start) == 2], ~cut)
    sides = []
    whole = np.zeros(len(fa), bool)
    if units is not None:  # where the units either side are alike (a coarse curve's facets)
        size = np.bincount(units, np.linalg.norm(area, axis=1))
        a, b = size[units[fa]], size[units[fb]]
        whole = np.maximum(a, b) <= SPLIT_AREA_RATIO * np.minimum(a, b)
    centre = None
    if own_side:  # each facet's centroid (its corners'), for the side of the line it is on
        real = corners >= 0
        centre = np.einsum("fk,fkx->fx", real, nodes[np.maximum(corners, 0)]) / real.sum(
            axis=1)[:, None]
    for own, first in ((fa, True), (fb, False)):
        row, other = _ring_pairs(keyc, ptr, fac, own[~whole])
        row = np.flatnonzero(~whole)[row]
        if whole.any():
            r, o = _unit_ring_pairs(keyc, ptr, fac, own[whole], units)
            row, other = np.concatenate([row, np.flatnonzero(whole)[r]]), np.concatenate([other, o])
            order = np.argsort(row, kind="stable")
            row, other = row[order], other[order]
        u = _across(unit[other], line[row])
        long = np.linalg.norm(u, axis=1) >= tol.CURVE_AXIS_MIN
        u = _unit(u)
        turn = _turn(u, na[row], line[row]) if first else _turn(nb[row], u, line[row])
        ratio = np.where(long, turn * sense[row], np.nan)
        if centre is not None:
            base = nodes[ends[row, 0]]
            away = _across(centre[own[row]] - base, line[row])
            ratio[np.einsum("ij,ij->i", _across(centre[other] - base, line[row]), away)
                  <= 0] = np.nan
        if fans is not None:
            ratio[~_same_fan(keyc, fans, own[row], other, ends[row])] = np.nan
        width = int(np.bincount(row, minlength=len(own)).max()) if len(row) else 0
        table = np.full((len(own), width), np.nan)
        start = np.searchsorted(row, np.arange(len(own)))
        table[row, np.arange(len(row)) - start[row]] = ratio
        sides.append(table)
    return theta, sides[0], sides[1]


def corner_fans(keyc, fa, fb, ends, join) -> np.ndarray:
    """(4 F,) the fan of each corner slot (4 f + j; keyc (F, 4) the corners' identities): the
    corners at one node joined across the manifold edges (facets fa, fb, end identities
    `ends`) where `join`."""
    j = np.flatnonzero(join)
    slots = [4 * f[j] + np.argmax(keyc[f[j]] == ends[j, e, None], axis=1)
             for f in (fa, fb) for e in (0, 1)]
    return components(4 * len(keyc), np.concatenate(slots[:2]), np.concatenate(slots[2:]))


def _same_fan(keyc, fans, own, other, ends) -> np.ndarray:
    """(p,) bool: facet other[p] is in facet own[p]'s fan (`corner_fans`) at each end of the
    edge `ends[p]` (identities; both own's corners) that it touches."""
    ok = np.ones(len(own), bool)
    for e in (0, 1):
        k = ends[:, e, None]
        at = keyc[other] == k
        mine = fans[4 * own + np.argmax(keyc[own] == k, axis=1)]
        ok &= ~at.any(axis=1) | (fans[4 * other + np.argmax(at, axis=1)] == mine)
    return ok


def flat_sided(nodes, faces, key, edges: Edges, area, fa, fb, which, cut=None) -> np.ndarray:
    """(m,) bool over the manifold edges `which` (indices into the edge table) of facets fa,
    fb: the edges at which neither side turns, a crease of the CAD (two faces meeting at an
    angle: a thread's flank and its core, a box's edge) and no fillet that one cell cannot
    resolve. No facet of either facet's vertex ring turns about the edge's line by
    `tol.CREASE_SIDE_RATIO` of its angle or more in the same sense (`bend_pattern`): across
    a fillet one cell wide, the facets past its strip turn again as much, the same way. The
    rings are the polyhedron's facets' (`facet_units`): a tube's facets cut in pieces are
    no flat sides.

    `cut` (m,) bool over the manifold edges, optional: the creases past the feature angle
    (no coarse curve's bends). A side is the facets that reach the edge across none of them:
    where a crease of the CAD runs into a face it meets at such a crease (a thread's flank
    and core against its turning end face), that face turns about the edge's line by 5
    times its angle, yet is neither side of it (issue 34)."""
    if len(which) == 0:
        return np.zeros(0, bool)
    a, b = _two_facets(edges)
    units = facet_units(len(area), a, b, _edges.segment_cosines(_f64(area), a, b), area)
    _, side_a, side_b = bend_pattern(nodes, faces, key, edges, area, fa, fb, which, units,
                                     cut=cut)
    r = tol.CREASE_SIDE_RATIO
    return ~((side_a >= r).any(axis=1) | (side_b >= r).any(axis=1))


def cad_creases(nodes, faces, key, edges: Edges, area, fa, fb, cos, limit,
                bends=None) -> np.ndarray:
    """(m,) bool over the manifold edges (fa, fb: `_two_facets`; cos: their normals'
    cosine): the creases of the CAD below the feature angle (cosine `limit`): edges that
    turn by `tol.CREASE_MIN_DEG` or more at which neither side turns (`flat_sided`) and
    not both turn back (a facet of each side's ring on its side of the edge turning by
    `tol.CREASE_SIDE_RATIO` of its angle the other way: `bend_pattern`, own_side, a zigzag):
    two flat faces meeting at an angle, sharp though no feature by their angle alone. Each
    side read in its fans, up to the creases past `limit` (`flat_sided`'s `cut`); `bends`:
    `coarse_bends` at `limit`, when the caller has them."""
    out = np.zeros(len(fa), bool)
    some = (cos >= limit) & (cos < np.cos(np.radians(tol.CREASE_MIN_DEG)))
    if not some.any():
        return out
    which = np.flatnonzero(some)
    at = np.flatnonzero(np.diff(edges.start) == 2)[which]
    if bends is None:
        bends = coarse_bends(nodes, faces, key, edges, area, fa, fb, cos, limit)
    cut = (cos < limit) & ~bends
    flat = flat_sided(nodes, faces, key, edges, area, fa[which], fb[which], at, cut)
    # ... nor turns back on both sides: a strip of facets that zigzag across a fillet one
    # cell wide (a second-order fillet's corner facets, alternately ±17°) meets at such
    # angles too, each facet's neighbour along the strip turning back as much (-1); a face
    # of the CAD narrower than a cell (a thread's flank) may turn back at its next crease,
    # on its own side only
    which, at = which[flat], at[flat]
    if len(which):
        units = facet_units(len(area), fa, fb, cos, area)
        _, side_a, side_b = bend_pattern(nodes, faces, key, edges, area, fa[which], fb[which],
                                         at, units, own_side=True)
        r = tol.CREASE_SIDE_RATIO
        out[which] = ~((side_a <= -r).any(axis=1) & (side_b <= -r).any(axis=1))
    return out


def _tables(nodes, faces, key, edges, area):
    """The target's nodes and facet blocks as arrays, and its identity, edges and area
    vectors where the caller has not given them."""
    nodes = np.asarray(nodes, dtype=np.float64)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        faces = [faces]
    faces = [np.asarray(f, dtype=np.int64) for f in faces]
    if key is None:
        key = node_identity(nodes)
    if edges is None:
        edges = edge_table(faces, key)
    if area is None:
        area = _frame.facet_area_vectors(nodes, faces)
    return nodes, faces, key, edges, area


def _node_facets(keyc, n):
    """CSR (ptr (n + 1,), facets) of the facets at each node identity (keyc: (F, 4) corner
    identities, -1 past a triangle's third)."""
    real = keyc >= 0
    node = keyc[real]
    fac = np.broadcast_to(np.arange(len(keyc))[:, None], keyc.shape)[real]
    order = np.argsort(node, kind="stable")
    return np.searchsorted(node[order], np.arange(n + 1)), fac[order]


def _ring_pairs(keyc, ptr, fac, own):
    """(row, facet): each facet of the vertex ring of facet own[row] (repeated where it
    shares several nodes with it; itself included), rows ascending."""
    rows, others = [], []
    for j in range(4):
        k = keyc[own, j]
        k0 = np.maximum(k, 0)
        count = np.where(k >= 0, ptr[k0 + 1] - ptr[k0], 0)
        row = np.repeat(np.arange(len(own)), count)
        offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        rows.append(row)
        others.append(fac[np.repeat(ptr[k0], count) + offset])
    row, other = np.concatenate(rows), np.concatenate(others)
    order = np.argsort(row, kind="stable")
    return row[order], other[order]


def facet_units(F: int, fa, fb, cos, area):
    """(F,) the facet of the polyhedron each facet is a piece of, None where every facet is
    its own (issue 34): a group of coplanar facets (normals within `tol.FLAT_COS` across
    their edges, the manifold edges fa, fb of cosine `cos`) no larger than
    `SPLIT_AREA_RATIO` times the largest coplanar group next to it (`_coplanar`) is one
    facet cut in pieces, and reads as one in the crease rule (`bend_pattern`): a tube of 8
    facets around refined linearly has facets half as wide, coplanar with their
    neighbours, whose own vertex rings do not reach the next bend. A larger group (a flat
    face, larger than the fillet's strip it meets) leaves its facets their own."""
    group, size, garea, neighbour = _coplanar(F, fa, fb, cos, area)
    split = (size >= 2) & (neighbour > 0) & (garea <= SPLIT_AREA_RATIO * neighbour)
    if not split.any():
        return None
    unit = np.where(split[group], group, len(size) + np.arange(F))
    return np.unique(unit, return_inverse=True)[1].reshape(-1)


def _coplanar(F: int, fa, fb, cos, area):
    """The coplanar groups of F facets (joined across the manifold edges fa, fb whose
    normals' cosine `cos` is within `tol.FLAT_COS`): (group (F,), size (G,): their facets,
    garea (G,): their area, neighbour (G,): the largest area of a group next to each)."""
    flat = cos >= tol.FLAT_COS
    group = components(F, fa[flat], fb[flat])
    G = int(group.max()) + 1 if F else 0
    size = np.bincount(group, minlength=G)
    garea = np.bincount(group, np.linalg.norm(area, axis=1), minlength=G)
    bd = group[fa] != group[fb]
    neighbour = np.zeros(G)
    np.maximum.at(neighbour, group[fa[bd]], garea[group[fb[bd]]])
    np.maximum.at(neighbour, group[fb[bd]], garea[group[fa[bd]]])
    return group, size, garea, neighbour


def _unit_ring_pairs(keyc, ptr, fac, own, unit):
    """(row, facet): the vertex ring of the unit (`facet_units`) of facet own[row], the
    facets at any node of it, one facet for each unit (its facets share one plane), rows
    ascending."""
    n = len(ptr) - 1
    U = int(unit.max()) + 1
    need = np.zeros(U, bool)
    need[unit[own]] = True
    rows = np.flatnonzero(need[unit])  # the facets of those units only
    k = keyc[rows]
    real = k >= 0
    pair = np.unique(np.broadcast_to(unit[rows][:, None], k.shape)[real] * n + k[real])
    uptr = np.searchsorted(pair // n, np.arange(U + 1))
    u = unit[own]
    row, at = _expand(uptr[u], uptr[u + 1] - uptr[u])
    node = pair[at] % n
    pick, at = _expand(ptr[node], ptr[node + 1] - ptr[node])
    row, other = row[pick], fac[at]
    _, first = np.unique(row * U + unit[other], return_index=True)
    return row[first], other[first]


def _expand(start, count):
    """(row, index): start[row] .. start[row] + count[row] - 1 for each row, in order."""
    row = np.repeat(np.arange(len(start)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return row, np.repeat(start, count) + offset


def _across(v, line):
    """v less its component along the unit `line` (rows)."""
    return v - np.einsum("ij,ij->i", v, line)[:, None] * line


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=1), tol.TINY)[:, None]


def _turn(a, b, line):
    """The signed angle from a to b about the unit `line` (rows; a, b across it)."""
    return np.arctan2(np.einsum("ij,ij->i", np.cross(a, b), line), np.einsum("ij,ij->i", a, b))


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def components(F: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F,) int64 the connected groups of F facets joined across the pairs (a, b), numbered in
    the order of their first facet (scipy's connected_components' numbering): a compiled
    union-find, linear."""
    return _topology.components(int(F), np.ascontiguousarray(a, dtype=np.int64),
                                np.ascontiguousarray(b, dtype=np.int64))


def facet_rings(corners: np.ndarray, key: np.ndarray, label: np.ndarray, npatches: int):
    """The vertex ring of each facet (`FacetRing`: the facets sharing a node with it by
    identity `key`, itself included, sorted) and the distinct patches (`label`) of each ring,
    sorted (CSR ring_ptr, ring_patches), all int32 (ValueError where they exceed it); corners
    (F, 4), -1 past a triangle's third. One compiled pass, linear in the ring entries
    (`_topology.rings`)."""
    indptr, indices, ring_ptr, ring_patches = _topology.rings(
        np.ascontiguousarray(corners, dtype=np.int64), np.ascontiguousarray(key, dtype=np.int64),
        len(key), np.ascontiguousarray(label, dtype=np.int64), int(npatches))
    return FacetRing(indptr, indices), ring_ptr, ring_patches


def _two_facets(edges: Edges):
    """(fa, fb) the two facets of each manifold edge (of exactly two half-edges), by edge:
    those of its first and second half-edge."""
    return _edges.two_facets(_i64(edges.start), _i64(edges.order), _i64(edges.fac))


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64)


def _flat_faces(nodes, faces, fa, fb, nf, key, edges, cos) -> np.ndarray:
    """(f,) the flat face of each facet, -1 for none: connected facets coplanar to round-off
    (normals within `tol.FLAT_COS` across their edges: `cos` of the nf facets' manifold edges
    fa, fb) forming a face with at least one node all of whose facets are in it, not on an
    open edge. Rows of coplanar facets on a curved surface (a strip between two rulings of a
    cylinder or a fillet) have no such node and stay curved. One compiled pass over the
    facets' corners (`_edges.flat_faces`), linear."""
    same = cos >= tol.FLAT_COS
    comp = components(nf, fa[same], fb[same])
    blocks = [_i64(_frame.facet_corners(f)) for f in faces]
    return _edges.flat_faces(blocks, _i64(key), len(nodes), comp, _i64(edges.start),
                             _i64(edges.ends))



#: The node order of a facet block reversed (its orientation flipped), by its node count:
#: corners reversed after the first, mid-side nodes with them, a centre kept.
_REVERSED = {3: [0, 2, 1], 4: [0, 3, 2, 1], 6: [0, 2, 1, 5, 4, 3], 7: [0, 2, 1, 5, 4, 3, 6],
             8: [0, 3, 2, 1, 7, 6, 5, 4], 9: [0, 3, 2, 1, 7, 6, 5, 4, 8]}


def consistent_winding(nodes, faces):
    """The facet blocks with every facet wound as its neighbours are (issue 22: 10% of a
    sphere's facets reversed gave wrong signs with status ok, the facets' too).

    Across every edge shared by two facets, a consistent surface runs the edge in opposite
    directions. Where some do not, each connected surface (across such edges) is oriented by
    a breadth-first walk from one facet, and its facets that disagree with the orientation
    of the larger part by area are reversed. A surface whose facets cannot all agree (a
    Möbius strip, a non-orientable join) is left as it is. Coincident nodes are one node.

    Returns (faces, reversed: the number of facets reversed, undecided: the number of facets
    on surfaces left as they are because no orientation is consistent).
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    key = node_identity(np.asarray(nodes))
    fac, loc, edge, ne = facet_edges(faces, key)
    if not ne:
        return faces, 0, 0
    blocks = [_frame.facet_corners(f) for f in faces]
    corners = np.concatenate([np.pad(c, ((0, 0), (0, 4 - c.shape[1])), constant_values=-1)
                              for c in blocks])
    kind = np.concatenate([np.full(len(c), c.shape[1]) for c in blocks])
    a = key[corners[fac, loc]]
    b = key[corners[fac, np.where(loc + 1 < kind[fac], loc + 1, 0)]]
    forward = a < b
    count = np.bincount(edge, minlength=ne)
    order = np.argsort(edge, kind="stable")
    two = np.flatnonzero(count == 2)
    starts = np.searchsorted(edge[order], two)
    e1, e2 = order[starts], order[starts + 1]
    f1, f2 = fac[e1], fac[e2]
    parity = (forward[e1] == forward[e2]).astype(np.int8)  # 1: the two run it alike
    if not parity.any():
        return faces, 0, 0
    F = len(kind)
    graph = coo_matrix((np.ones(len(f1)), (f1, f2)), shape=(F, F)).tocsr()
    ncomp, comp = connected_components(graph, directed=False)
    lookup = coo_matrix((parity.astype(np.float64) + 1.0, (f1, f2)), shape=(F, F)).tocsr()
    lookup = lookup + lookup.T
    flip = np.zeros(F, np.int8)
    area = np.linalg.norm(_frame.facet_area_vectors(nodes, faces), axis=1)
    undecided = 0
    for c in np.unique(comp[np.concatenate([f1[parity == 1], f2[parity == 1]])]):
        root = int(np.flatnonzero(comp == c)[0])
        visit, pred = breadth_first_order(graph, root, directed=False, return_predecessors=True)
        for f in visit[1:]:
            p = pred[f]
            flip[f] = flip[p] ^ (int(lookup[p, f]) - 1)
        inside = comp[f1] == c
        if np.any((flip[f1[inside]] ^ flip[f2[inside]]) != parity[inside]):
            flip[visit] = 0  # no orientation agrees everywhere: left as it is
            undecided += len(visit)
            continue
        if area[visit][flip[visit] == 1].sum() > 0.5 * area[visit].sum():
            flip[visit] ^= 1  # keep the orientation of the larger part
    out, start = [], 0
    for f in faces:
        f = np.asarray(f)
        rows = flip[start:start + len(f)].astype(bool)
        if rows.any():
            f = f.copy()
            f[rows] = f[rows][:, _REVERSED[f.shape[1]]]
        out.append(f)
        start += len(f)
    return out, int(flip.sum()), undecided


# -- nodes that add no geometry (issue 34) ---------------------------------------------------
#: A group of coplanar facets (normals within `tol.FLAT_COS`) bounded by smooth bends only is
#: one facet of the polyhedron cut in pieces (a split facet: a centroid split, a quad cut
#: into four, a linear refinement) where its area is at most this many times that of the
#: largest coplanar group next to it (a split facet is one of the polyhedron's facets, the
#: size of its neighbours); larger, it is a flat face (a face meeting its fillets
#: tangentially, larger than a fillet's strip of coplanar facets).
SPLIT_AREA_RATIO = 1.5
#: A node on a straight side of a split facet adds no geometry where that side (the straight
#: run of boundary edges through it, corner to corner) is a chord: the surface's normals at
#: its two ends (their smooth facets') turn along it by more than this (radians). Less, the
#: side is a ruling of a ruled surface (a strip of coplanar facets along a cylinder or a
#: cone: the normals along a ruling are one), whose nodes lie on the surface and stay.
RULING_BEND = 1e-6
#: Two boundary edges at a node are one straight side where the sine of their angle is below
#: this (round-off on a node put on the chord).
STRAIGHT_SIN = 1e-6


class Refinement(NamedTuple):
    """The nodes of a target that add no geometry to its polyhedron (`geometry_free`)."""

    group: np.ndarray     # (F,) the coplanar group of each facet
    split: np.ndarray     # (G,) bool: the group is a split facet
    free: np.ndarray      # (n,) bool: the node adds no geometry
    replaced: np.ndarray  # (F,) bool: the facet's group is fitted as `polygons`' triangles
    polygons: dict        # group -> (t, 3) int: its polygon over its other nodes, in triangles
    #: second order (`cut_on_map`): (F,) the parent cell of each facet cut from one, -1 else
    #: (parents numbered through `cells`), and the parent cells, one block a cell type
    parent: np.ndarray | None = None
    cells: tuple = ()

    @property
    def count(self) -> int:
        """The number of nodes that add no geometry."""
        return int(self.free.sum())

    def fit_over(self, ids):
        """The facets a diffuse surface over the facets `ids` (numbered block after block) is
        fitted over: (the facets of `ids` it keeps, the blocks that replace the others: the
        split facets' polygons, or the parent cells whose every child is in `ids`)."""
        ids = np.asarray(ids, dtype=np.int64)
        if self.parent is None:
            cut = self.replaced[ids]
            if not cut.any():
                return ids, []
            return ids[~cut], [np.concatenate([self.polygons[g]
                                               for g in np.unique(self.group[ids[cut]])])]
        own = self.parent[ids]
        count = np.bincount(own[own >= 0], minlength=len(self.parent))
        whole = np.zeros(len(count) + 1, bool)  # the last: -1, no parent
        whole[:-1] = (count > 0) & (count == np.bincount(self.parent[self.parent >= 0],
                                                         minlength=len(count)))
        extra, start = [], 0
        for block in self.cells:
            pick = np.flatnonzero(whole[start:start + len(block)])
            if len(pick):
                extra.append(block[pick])
            start += len(block)
        return ids[~whole[own]], extra


def no_refinement(F: int, n: int) -> Refinement:
    """A target whose every node adds geometry."""
    return Refinement(np.arange(F), np.zeros(F, bool), np.zeros(n, bool), np.zeros(F, bool),
                      {})


def geometry_free(nodes, faces, key, edges: Edges, area, feature_angle=FEATURE_ANGLE_DEG,
                  tags=None, bends=None) -> Refinement:
    """The nodes that add no geometry to a first-order target's polyhedron (issue 34).

    A split facet is a group of coplanar facets bounded by smooth bends only (no edge past
    `feature_angle`, no change of `tags`, no non-manifold edge; open edges allowed) that is
    no larger than `SPLIT_AREA_RATIO` times the largest coplanar group next to it: one facet
    of the polyhedron cut in pieces, not a flat face. A node adds no geometry where all of its
    facets are in one split facet and it is on none of its sides, or where it lies on a
    straight side of the split facets around it (at most two) that is a chord of the surface,
    not a ruling (`RULING_BEND`). The smooth surface is fitted over the polyhedron's own
    facets instead: each split facet holding such a node is its polygon over its other
    nodes, cut into triangles (`polygons`).

    nodes, faces, key, edges, area: the target's nodes, facet blocks, node identity, facet
    edges (`edge_table`) and facet area vectors; bends (m,) bool over the manifold edges,
    optional: the coarse smooth curves' bends past `feature_angle` (`coarse_bends`), no
    creases there either (a coarse tube refined linearly). Second-order targets: their
    mid-side nodes are the geometry, but for the cells cut in four on their own map
    (`cut_on_map`).
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    F, n = sum(len(f) for f in faces), len(nodes)
    if F and any(np.asarray(f).shape[1] in _CUT for f in faces):
        return cut_on_map(nodes, faces, key)
    if F == 0 or any(np.asarray(f).shape[1] not in (3, 4) for f in faces):
        return no_refinement(F, n)
    fa, fb = _two_facets(edges)
    cos = _edges.segment_cosines(np.ascontiguousarray(area, dtype=np.float64), fa, fb)
    group, size, garea, neighbour = _coplanar(F, fa, fb, cos, area)
    G = len(size)
    if not (size >= 2).any():
        return no_refinement(F, n)
    bd = group[fa] != group[fb]
    hard = np.zeros(len(cos), bool)
    if feature_angle is not None and feature_angle < 180:
        hard = cos < np.cos(np.radians(feature_angle))
        if bends is not None:  # a coarse smooth curve's bend is no crease (`creases`)
            hard &= ~bends
    if tags is not None:
        tags = np.asarray(tags).reshape(-1)
        hard |= tags[fa] != tags[fb]
    face = np.zeros(G, bool)
    face[group[fa[hard]]] = True
    face[group[fb[hard]]] = True
    count = np.diff(edges.start)
    for i in np.flatnonzero(count > 2):
        face[group[edges.fac[edges.order[edges.start[i]:edges.start[i + 1]]]]] = True
    split = (size >= 2) & ~face & (neighbour > 0) & (garea <= SPLIT_AREA_RATIO * neighbour)
    if not split.any():
        return no_refinement(F, n)
    corners = np.concatenate([_pad4(f) for f in faces])
    keyc = np.where(corners >= 0, key[np.maximum(corners, 0)], -1)
    if bends is not None and bends.any() and feature_angle is not None:
        feature_angle = max(feature_angle, tol.CURVE_MAX_DEG)  # a coarse curve's facets
    sides = _straight_sides(nodes, edges, count, group, area, fa, fb, bd, keyc,
                            feature_angle)
    for _ in range(2):  # a split facet whose polygon cannot be cut is a face: once more
        free = _free_nodes(keyc, group, split, *sides)
        polygons, failed = _polygons(nodes, corners, keyc, group, split, free)
        if not failed:
            break
        split = split.copy()
        split[failed] = False
    else:
        return no_refinement(F, n)
    replaced = np.zeros(G, bool)
    replaced[list(polygons)] = True
    return Refinement(group, split, free[key], replaced[group], polygons)


def _pad4(f) -> np.ndarray:
    f = np.asarray(f, dtype=np.int64)
    return np.pad(f, ((0, 0), (0, 4 - f.shape[1])), constant_values=-1)


def _straight_sides(nodes, edges, count, group, area, fa, fb, bd, keyc, feature_angle):
    """The boundary edges of the coplanar groups (and the open edges) at each node: (nbd (n,)
    their number at each node, straight (n,) bool: two of them on one line through it, cut
    (n,) bool: that line's side, corner to corner, is a facet's side cut on its chord, not a
    ruling (`RULING_BEND`))."""
    n = len(nodes)
    manifold = np.flatnonzero(count == 2)
    boundary = count == 1
    boundary[manifold[bd]] = True
    be = np.flatnonzero(boundary)
    u, v = edges.ends[be, 0], edges.ends[be, 1]
    nbd = np.bincount(np.concatenate([u, v]), minlength=n)
    at, other = np.concatenate([u, v]), np.concatenate([v, u])
    which = np.concatenate([np.arange(len(be))] * 2)
    order = np.argsort(at, kind="stable")
    at, other, which = at[order], other[order], which[order]
    start = np.searchsorted(at, np.arange(n + 1))
    two = np.flatnonzero(nbd == 2)
    d1 = nodes[other[start[two]]] - nodes[two]
    d2 = nodes[other[start[two] + 1]] - nodes[two]
    sine = np.linalg.norm(np.cross(d1, d2), axis=1)
    scale = np.linalg.norm(d1, axis=1) * np.linalg.norm(d2, axis=1)
    line = (sine <= STRAIGHT_SIN * scale) & (np.einsum("ij,ij->i", d1, d2) < 0)
    straight = np.zeros(n, bool)
    straight[two[line]] = True
    s = np.flatnonzero(straight)
    # the sides: runs of boundary edges joined at straight nodes, and their two ends
    run = components(len(be), which[start[s]], which[start[s] + 1])
    R = int(run.max()) + 1 if len(run) else 0
    ends, of = np.concatenate([u, v]), np.concatenate([run, run])
    keep = ~straight[ends]
    ends, of = ends[keep], of[keep]
    order = np.argsort(of, kind="stable")
    ends, of = ends[order], of[order]
    first = np.searchsorted(of, np.arange(R + 1))
    pair = np.flatnonzero(np.diff(first) == 2)
    a, b = ends[first[pair]], ends[first[pair] + 1]
    # each side's own facet (its first edge's first), whose smooth neighbours at its two ends
    # give their normals there
    lead = np.full(R, len(be))
    np.minimum.at(lead, run, np.arange(len(be)))
    facet = edges.fac[edges.order[edges.start[be[lead[pair]]]]]
    unit = area / np.maximum(np.linalg.norm(area, axis=1), 1e-300)[:, None]
    # the facets at an end within the feature angle of the side's own (a coarse curve's,
    # `tol.CURVE_MAX_DEG`, where it has bends past it: a tube of 8 facets around turns 45°)
    limit = np.cos(np.radians(FEATURE_ANGLE_DEG if feature_angle is None else feature_angle))
    na = _smooth_normals(keyc, area, unit, a, unit[facet], limit)
    nb = _smooth_normals(keyc, area, unit, b, unit[facet], limit)
    side = nodes[b] - nodes[a]
    along = np.einsum("ij,ij->i", nb - na, side) / np.linalg.norm(side, axis=1)
    chord = np.zeros(R, bool)
    chord[pair] = np.abs(along) > RULING_BEND
    cut = np.zeros(n, bool)
    cut[s] = chord[run[which[start[s]]]]
    return nbd, straight, cut


def _smooth_normals(keyc, area, unit, at, reference, limit) -> np.ndarray:
    """(m, 3) the unit area-weighted normal at each node `at` (m,) of its facets within the
    feature angle (cosine `limit`) of `reference` (m, 3): the surface's normal there on the
    side's own smooth side (not a cap's across a crease)."""
    real = keyc >= 0
    node = keyc[real]
    fac = np.broadcast_to(np.arange(len(keyc))[:, None], keyc.shape)[real]
    order = np.argsort(node, kind="stable")
    node, fac = node[order], fac[order]
    lo, hi = np.searchsorted(node, at), np.searchsorted(node, at, side="right")
    counts = hi - lo
    row = np.repeat(np.arange(len(at)), counts)
    offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    f = fac[np.repeat(lo, counts) + offset]
    near = np.einsum("ij,ij->i", unit[f], reference[row]) >= limit
    total = np.zeros((len(at), 3))
    np.add.at(total, row[near], area[f[near]])
    return total / np.maximum(np.linalg.norm(total, axis=1), 1e-300)[:, None]


def _free_nodes(keyc, group, split, nbd, straight, cut) -> np.ndarray:
    """(n,) bool by node identity: inside one split facet (on no boundary edge), or on a
    straight side cut on its chord (`_straight_sides`) between at most two groups, all
    split."""
    n = len(nbd)
    real = keyc >= 0
    pairs = np.unique(np.column_stack([keyc[real], np.broadcast_to(group[:, None],
                                                                  keyc.shape)[real]]), axis=0)
    groups = np.bincount(pairs[:, 0], minlength=n)
    unsplit = np.bincount(pairs[:, 0], ~split[pairs[:, 1]], minlength=n)
    ok = (groups >= 1) & (unsplit == 0)
    return (ok & (groups == 1) & (nbd == 0)) | (ok & (groups <= 2) & straight & cut)


def _polygons(nodes, corners, keyc, group, split, free):
    """Each split facet holding a node in `free`: its polygon (its boundary, one loop in its
    facets' winding) over its other nodes, cut into triangles (`_ears`). Returns (polygons:
    group -> (t, 3) node indices, failed: the groups whose boundary is no single loop or
    whose polygon cannot be cut)."""
    hit = (keyc >= 0) & free[np.maximum(keyc, 0)]
    has = np.zeros(len(split), bool)
    has[group[hit.any(axis=1)]] = True
    has &= split
    out, failed = {}, []
    rows = np.flatnonzero(has[group])
    rows = rows[np.argsort(group[rows], kind="stable")]
    cuts = np.searchsorted(group[rows], np.flatnonzero(has))
    cuts = np.append(cuts, len(rows))
    for i, g in enumerate(np.flatnonzero(has)):
        halves, node_of = set(), {}
        for f in rows[cuts[i]:cuts[i + 1]]:
            k = 4 if corners[f, 3] >= 0 else 3
            for j in range(k):
                a, b = int(keyc[f, j]), int(keyc[f, (j + 1) % k])
                node_of[a] = int(corners[f, j])
                halves.add((a, b))
        step = {a: b for a, b in halves if (b, a) not in halves}
        loop = _loop(step)
        tri = None if loop is None else _ears(nodes, [node_of[a] for a in loop if not free[a]])
        if tri is None:
            failed.append(int(g))
        else:
            out[int(g)] = tri
    return out, failed


def _loop(step: dict):
    """The one loop of a boundary (`step`: each node's next), None where it is not one."""
    if not step:
        return None
    a0 = next(iter(step))
    loop, a = [a0], step[a0]
    while a != a0 and a in step and len(loop) <= len(step):
        loop.append(a)
        a = step[a]
    return loop if a == a0 and len(loop) == len(step) else None


def _ears(nodes, poly):
    """A convex polygon (node indices, in order, its straight sides' nodes kept) cut into
    triangles of positive area in its winding: the smallest ear of positive area first (the
    largest could leave the rest on a line); None where it cannot be. Plain floats: a
    polygon is a few nodes, and a refined target has one a facet."""
    poly = list(poly)
    if len(poly) < 3:
        return None
    x = [tuple(map(float, nodes[i])) for i in poly]
    normal = [0.0, 0.0, 0.0]
    for k in range(len(x)):
        c = _cross(x[k], x[(k + 1) % len(x)])
        normal = [normal[0] + c[0], normal[1] + c[1], normal[2] + c[2]]
    scale = sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
    if not scale > 0:
        return None
    tris = []
    while len(poly) >= 3:
        m = len(poly)
        best, at = None, -1
        for k in range(m):
            p, q, r = x[k - 1], x[k], x[(k + 1) % m]
            c = _cross((q[0] - p[0], q[1] - p[1], q[2] - p[2]),
                       (r[0] - q[0], r[1] - q[1], r[2] - q[2]))
            ear = (c[0] * normal[0] + c[1] * normal[1] + c[2] * normal[2]) / scale
            if ear > 1e-12 * scale and (best is None or ear < best):
                best, at = ear, k
        if at < 0:
            return None
        tris.append([poly[at - 1], poly[at], poly[(at + 1) % m]])
        del poly[at], x[at]
        if len(poly) == 2:
            break
    return np.array(tris, dtype=np.int64)


def _cross(u, v):
    return (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])


# -- second-order cells cut in four on their own map (issue 34) -----------------------------
#: The parameters of a parent cell's nodes (gmsh's order): triangle6 over the unit triangle,
#: quad8 and quad9 over [-1, 1]² (quad8 with its centre, a node of its children only, last).
_PARAM = {
    6: np.array([[0, 0], [1, 0], [0, 1], [.5, 0], [.5, .5], [0, .5]]),
    8: np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [0, -1], [1, 0], [0, 1], [-1, 0], [0, 0]]),
    9: np.array([[-1, -1], [1, -1], [1, 1], [-1, 1], [0, -1], [1, 0], [0, 1], [-1, 0], [0, 0]]),
}
#: the cell types that `cut_on_map` reads: their corners
_CUT = {6: 3, 8: 4, 9: 4}
#: candidates measured at once (`_misfit`: some 2.6 kB each for quad9)
_CHUNK = 8192


def _shape2(width: int, xi: np.ndarray) -> np.ndarray:
    """(..., width) the shape functions of a triangle6, quad8 or quad9 at the parameters xi."""
    a, b = xi[..., 0], xi[..., 1]
    if width == 6:
        l0 = 1 - a - b
        return np.stack([l0 * (2 * l0 - 1), a * (2 * a - 1), b * (2 * b - 1), 4 * l0 * a,
                         4 * a * b, 4 * b * l0], axis=-1)
    p = _PARAM[9][:width]
    if width == 9:  # Lagrange: products of the quadratics through -1, 0, 1

        def q(s, at):
            return np.where(at == 0, 1 - s * s, s * (s + at) / 2)

        return q(a[..., None], p[:, 0]) * q(b[..., None], p[:, 1])
    s, t = a[..., None] * p[:, 0], b[..., None] * p[:, 1]  # serendipity
    corner = (1 + s) * (1 + t) * (s + t - 1) / 4
    side = np.where(p[:, 0] == 0, (1 - a[..., None] ** 2) * (1 + t),
                    (1 + s) * (1 - b[..., None] ** 2)) / 2
    return np.where((p[:, 0] != 0) & (p[:, 1] != 0), corner, side)


def cut_on_map(nodes, faces, key) -> Refinement:
    """The second-order cells that are one cell cut in four on its own map (issue 34: an FE
    code's uniform refinement without the CAD): their new nodes add no geometry.

    Found from the topology: a triangle6 whose three neighbours across its sides (same cell
    type) close it into a triangle, its corners the parent's mid-side nodes; four quad8 or
    quad9 around a node they all have as a corner, the parent's centre, their corners next
    to it its mid-side nodes. Kept where every node of the four is within `tol.CUT_ON_MAP`
    of the parent's size from the parent's map at its parameter (a child is its parent's map
    of a straight sub-cell of the parameters): a mesher that moved them onto the CAD added
    geometry; a flat parent is a flat face's cells, left as they are (a regular grid there is
    four cells of a larger one many ways over, and its plane is exact either way).
    Candidates sharing a cell are taken best first. The new nodes are the children's nodes
    that are not the parent's (and the quad8's centre), where no other facet holds them; the
    diffuse surface is fitted over the parents instead (`Refinement.fit_over`)."""
    F, n = sum(len(f) for f in faces), len(nodes)
    key = np.asarray(key, dtype=np.int64)
    starts = np.cumsum([0] + [len(f) for f in faces])
    found = []  # (misfit, global child facets (4,), parent cell, parent's node keys)
    for b, f in enumerate(faces):
        f = np.asarray(f, dtype=np.int64)
        if len(f) < 4 or f.shape[1] not in _CUT:
            continue
        take = _tri_candidates if f.shape[1] == 6 else _quad_candidates
        kids, parent, probe = take(f, key)
        # one new node first (a necessary condition, cheap): most cells are cut from none
        near = _off_map(nodes, f.shape[1], parent, probe) <= tol.CUT_ON_MAP
        near[near] = ~_flat(nodes, f.shape[1], parent[near])
        kids, parent = kids[near], parent[near]
        if not len(kids):
            continue
        misfit = np.concatenate([_misfit(nodes, f, key, kids[i:i + _CHUNK], parent[i:i + _CHUNK])
                                 for i in range(0, len(kids), _CHUNK)])
        for i in np.flatnonzero(misfit <= tol.CUT_ON_MAP):
            found.append((misfit[i], kids[i] + starts[b], parent[i], f.shape[1]))
    found.sort(key=lambda c: c[0])
    taken = np.zeros(F, bool)
    accepted = {w: [] for w in _CUT}
    for _, kids, parent, w in found:
        if not taken[kids].any() and len(set(kids)) == 4:
            taken[kids] = True
            accepted[w].append((kids, parent))
    if not taken.any():
        return no_refinement(F, n)
    parent_of = np.full(F, -1, np.int64)
    cells, count = [], 0
    parent_keys = []
    for w in sorted(accepted):
        if not accepted[w]:
            continue
        kids = np.array([k for k, _ in accepted[w]])
        block = np.array([p for _, p in accepted[w]])
        parent_of[kids] = count + np.arange(len(block))[:, None]
        count += len(block)
        cells.append(block[:, :w])
        parent_keys.append(key[block[:, :w]].ravel())
    held = np.zeros(n, bool)  # by identity: nodes of the facets kept, and of the parents
    for b, f in enumerate(faces):
        keep = ~taken[starts[b]:starts[b + 1]]
        held[key[np.asarray(f)[keep].ravel()]] = True
    held[np.concatenate(parent_keys)] = True
    child = np.zeros(n, bool)
    for b, f in enumerate(faces):
        child[key[np.asarray(f)[taken[starts[b]:starts[b + 1]]].ravel()]] = True
    free = child & ~held
    return Refinement(np.arange(F), np.zeros(F, bool), free[key], taken, {}, parent_of,
                      tuple(cells))


def _tri_candidates(f, key):
    """Triangle6 candidates of one block: (kids (c, 4): the centre child then those across its
    sides, local rows; parent (c, 6) node ids, its mid-side nodes the centre's corners; probe
    (c,): the centre's first mid-side node, at the parent's `_PROBE`)."""
    t = len(f)
    k = key[f[:, :3]]
    a, b = k, np.roll(k, -1, axis=1)  # side s from corner s to s + 1
    lo, hi = np.minimum(a, b).ravel(), np.maximum(a, b).ravel()
    pair = lo * (int(key.max()) + 1) + hi
    order = np.argsort(pair, kind="stable")
    ps = pair[order]
    # the other half-edge of each side, where exactly two share it
    first = np.searchsorted(ps, pair, side="left")
    last = np.searchsorted(ps, pair, side="right")
    two = last - first == 2
    other = np.where(order[first] == np.arange(3 * t), order[np.minimum(first + 1, 3 * t - 1)],
                     order[first])
    other = np.where(two, other, -1).reshape(t, 3)
    ok = (other >= 0).all(axis=1)
    nb = np.where(other >= 0, other // 3, -1)
    ok &= (nb[:, 0] != nb[:, 1]) & (nb[:, 1] != nb[:, 2]) & (nb[:, 0] != nb[:, 2])
    rows = np.flatnonzero(ok)
    nb, other = nb[rows], other[rows]
    # the neighbour's corner off the shared side: the one after its side's end
    opp = f[nb, (other[:, :] % 3 + 2) % 3]
    centre = f[rows]
    # parent: corners (across side 2, across side 0, across side 1), mid-side the centre's
    parent = np.column_stack([opp[:, 2], opp[:, 0], opp[:, 1], centre[:, :3]])
    return np.column_stack([rows, nb]), parent, centre[:, 3]


def _quad_candidates(f, key):
    """Quad8/quad9 candidates of one block: (kids (c, 4) local rows, parent (c, 9) node ids:
    its corners, mid-side nodes and centre, the node the four share; probe (c,): the first
    child's mid-side node from the centre to the parent's last mid-side node, at `_PROBE`)."""
    k = key[f[:, :4]]
    flat = k.ravel()
    counts = np.bincount(flat, minlength=int(key.max()) + 1)
    at = np.flatnonzero(counts[flat] == 4)
    if not len(at):
        return np.empty((0, 4), np.int64), np.empty((0, 9), np.int64), np.empty(0, np.int64)
    at = at[np.argsort(flat[at], kind="stable")].reshape(-1, 4)  # (c, 4) corner slots
    cell, j = at // 4, at % 4
    # each child turned so that the centre is its corner 2: corners x0 (the parent's), x1, x3
    turn = (j[..., None] + np.arange(-2, 2)) % 4
    x = f[cell[..., None], turn]  # (c, 4, 4) node ids
    xk = key[x]
    # the next child (the parent's winding): the one whose x3 is this one's x1
    match = xk[:, :, None, 1] == xk[:, None, :, 3]
    ok = (match.sum(axis=2) == 1).all(axis=1)
    nxt = np.argmax(match, axis=2)
    o = np.zeros((len(at), 4), np.int64)
    for i in range(1, 4):
        o[:, i] = nxt[np.arange(len(at)), o[:, i - 1]]
    ok &= nxt[np.arange(len(at)), o[:, 3]] == 0
    ok &= (np.diff(np.sort(cell, axis=1), axis=1) > 0).all(axis=1)
    c = np.arange(len(at))[:, None]
    corners = x[c, o, 0]
    mids = x[c, o, 1]
    parent = np.column_stack([corners, mids, x[:, 0, 2]])
    first = cell[:, 0]  # o starts at child 0: its centre is corner j, the last mid corner j + 1
    probe = f[first, 4 + j[:, 0]]
    return cell[c, o][ok], parent[ok], probe[ok]


#: the parameter of `_tri_candidates`' and `_quad_candidates`' probe in the parent
_PROBE = {6: (.5, .25), 8: (-.5, 0), 9: (-.5, 0)}


def _size(nodes, parent, nc) -> np.ndarray:
    """(c,) each parent's size: its corners' largest distance."""
    corner = nodes[parent[:, :nc]]
    return np.linalg.norm(corner[:, :, None] - corner[:, None], axis=3).max(axis=(1, 2))


def _off_map(nodes, w, parent, probe) -> np.ndarray:
    """(c,) the probe's distance from the parent's map at `_PROBE`, relative to its size."""
    want = nodes[parent[:, :w]].transpose(0, 2, 1) @ _shape2(w, np.array(_PROBE[w], float))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.linalg.norm(nodes[probe] - want, axis=1) / _size(nodes, parent, _CUT[w])
    return np.where(np.isfinite(out), out, np.inf)


def _flat(nodes, w, parent) -> np.ndarray:
    """(c,) bool: the parent's nodes are in one plane (within `tol.CUT_ON_MAP` of its size):
    a flat face's cells, which a regular grid groups in four many ways; left as they are
    (their plane is exact either way)."""
    X = nodes[parent[:, :w]]
    nc = _CUT[w]
    normal = np.cross(X[:, 2] - X[:, 0], X[:, nc - 1] - X[:, 1])  # a quad's diagonals
    with np.errstate(divide="ignore", invalid="ignore"):
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        off = np.abs(np.einsum("cwd,cd->cw", X - X[:, :nc].mean(axis=1, keepdims=True),
                               normal)).max(axis=1) / _size(nodes, parent, nc)
    return np.isfinite(off) & (off <= tol.CUT_ON_MAP)


def _misfit(nodes, f, key, kids, parent):
    """(c,) the largest distance of the four children's nodes from the parent's map at their
    parameters, relative to the parent's size (a quad8's centre, a corner of its children,
    is checked as theirs); inf where a child's corner is none of the parent's nodes."""
    w = f.shape[1]
    nc = _CUT[w]
    param = _PARAM[w]
    pk = key[parent]  # (c, 9 or 6)
    ch = f[kids]  # (c, 4, w)
    same = key[ch[..., :nc]][..., None] == pk[:, None, None, :]  # (c, 4, nc, 9|6)
    good = (same.sum(axis=3) == 1).all(axis=(1, 2))
    xi_c = param[np.argmax(same, axis=3)]  # (c, 4, nc, 2): the children's corners
    # the children's nodes: corners, mid-sides (between corners s and s + 1), quad9's centre
    xi = [xi_c, (xi_c + np.roll(xi_c, -1, axis=2)) / 2]
    if w == 9:
        xi.append(xi_c.mean(axis=2, keepdims=True))
    xi = np.concatenate(xi, axis=2)  # (c, 4, w, 2)
    X = nodes[parent[:, :w]]  # (c, w, 3)
    want = np.einsum("cknw,cwd->cknd", _shape2(w, xi), X)
    gap = np.linalg.norm(nodes[ch] - want, axis=3).max(axis=(1, 2))
    size = _size(nodes, parent, nc)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = gap / size
    return np.where(good & (size > 0) & np.isfinite(out), out, np.inf)
